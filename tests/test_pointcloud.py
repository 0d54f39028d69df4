"""Tests of :mod:`canalsurf.pointcloud`: crop, voxel_downsample and point_spacing, each against a slow,
obvious reference on small clouds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from canalsurf.errors import InputError
from scipy.spatial.transform import Rotation

from canalsurf import synth
from canalsurf.pointcloud import SPACING_SAMPLE, crop, point_spacing, quantisation_noise, voxel_downsample

SEED = 20240612


@pytest.fixture
def cloud():
    """300 points in a 10-unit cube around (2, -3, 1), with unit normals."""
    rng = np.random.default_rng(SEED)
    points = rng.uniform(-5, 5, size=(300, 3)) + [2.0, -3.0, 1.0]
    normals = rng.normal(size=(300, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, normals


# --- crop ------------------------------------------------------------------------------------------


def test_crop_keeps_exactly_the_points_inside(cloud):
    points, normals = cloud
    box = (0.0, -4.0, -1.0, 3.5, 0.0, 2.0)
    before = points.copy()
    kept, kept_normals = crop(points, box, normals=normals)
    inside = [i for i, p in enumerate(points) if all(box[a] <= p[a] <= box[a + 3] for a in range(3))]
    assert 10 < len(inside) < 290
    np.testing.assert_array_equal(kept, points[inside])  # the same rows, in the file's order
    np.testing.assert_array_equal(kept_normals, normals[inside])
    np.testing.assert_array_equal(points, before)  # the caller's array is not changed


def test_crop_faces_belong_to_the_box():
    points = np.array([[0.0, 0, 0], [1, 1, 1], [1, 0.5, 1.0000001]])
    np.testing.assert_array_equal(crop(points, (0, 0, 0, 1, 1, 1))[0], points[:2])
    np.testing.assert_array_equal(crop(points, (1, 1, 1, 1, 1, 1))[0], points[[1]])  # a box of no size: one point


def test_crop_outside_everything_is_empty(cloud):
    kept, normals = crop(cloud[0], (100, 100, 100, 101, 101, 101), normals=cloud[1])
    assert kept.shape == (0, 3) and normals.shape == (0, 3)
    assert crop(cloud[0], (100, 100, 100, 101, 101, 101))[1] is None


@pytest.mark.parametrize("box, message", [
    ((0, 0, 0, 1, 1), r"box must be 6 finite numbers \(xmin, ymin, zmin, xmax, ymax, zmax\), got \(0, 0, 0, 1, 1\)"),
    ((0, 0, 0, 1, 1, np.nan), r"box must be 6 finite numbers"),
    ("0,0,0,1,1,1", r"box must be 6 numbers"),
    ((0, 2, 0, 1, 1, 1), r"box ymin = 2 is larger than ymax = 1 — give the lower corner first"),
])
def test_crop_refuses_a_bad_box(cloud, box, message):
    with pytest.raises(InputError, match=message):
        crop(cloud[0], box)


def test_crop_refuses_non_finite_points_and_odd_normals(cloud):
    points = cloud[0].copy()
    points[7, 1] = np.inf
    with pytest.raises(InputError, match=r"points contain NaN or inf — remove those rows first"):
        crop(points, (0, 0, 0, 1, 1, 1))
    with pytest.raises(InputError, match=r"normals must have the shape of the points \(300, 3\), got \(299, 3\)"):
        crop(cloud[0], (0, 0, 0, 1, 1, 1), normals=cloud[1][1:])


# --- voxel_downsample ------------------------------------------------------------------------------


def _voxel_reference(points: np.ndarray, size: float) -> list[int]:
    """Per occupied voxel (anchored at the origin) the index of the point nearest the voxel's
    centroid, the first one on a tie; sorted."""
    cells: dict[tuple, list[int]] = {}
    for i, p in enumerate(points):
        cells.setdefault(tuple(int(c) for c in np.floor(p / size)), []).append(i)
    chosen = []
    for members in cells.values():
        centroid = points[members].mean(axis=0)
        gaps = [float(np.sum((points[i] - centroid) ** 2)) for i in members]
        chosen.append(members[int(np.argmin(gaps))])
    return sorted(chosen)


@pytest.mark.parametrize("size", [0.7, 1.5, 4.0, 50.0])
def test_voxel_keeps_the_point_nearest_each_centroid(cloud, size):
    points, normals = cloud
    before = (points.copy(), normals.copy())
    kept, kept_normals = voxel_downsample(points, size, normals=normals)
    expected = _voxel_reference(points, size)
    np.testing.assert_array_equal(kept, points[expected])
    np.testing.assert_array_equal(kept_normals, normals[expected])  # each kept point with its own normal
    cells = np.floor(kept / size)
    assert len(np.unique(cells, axis=0)) == len(kept)  # one point per voxel
    np.testing.assert_array_equal(points, before[0])
    np.testing.assert_array_equal(normals, before[1])


def test_voxel_grid_is_anchored_at_the_origin(cloud):
    """A point falls into the same voxel whatever else is in the cloud: cropping first changes nothing
    inside the kept region's voxels."""
    points = cloud[0]
    size = 2.0
    box = (0.0, -4.0, -2.0, 4.0, 0.0, 4.0)  # on voxel boundaries
    once = voxel_downsample(crop(points, box)[0], size)[0]
    inside = crop(voxel_downsample(points, size)[0], box)[0]
    np.testing.assert_array_equal(once, inside)


def test_voxel_smaller_than_the_spacing_keeps_everything(cloud):
    points, normals = cloud
    kept, kept_normals = voxel_downsample(points, 1e-6, normals=normals)
    np.testing.assert_array_equal(kept, points)
    np.testing.assert_array_equal(kept_normals, normals)


def test_voxel_of_a_tube_keeps_its_radius():
    """A measured point per voxel stays on the surface; centroids would move inside a curved one."""
    rng = np.random.default_rng(SEED)
    n = 20_000
    t, s = rng.uniform(0, 10, n), rng.uniform(0, 2 * np.pi, n)
    points = np.column_stack([t, np.cos(s), np.sin(s)])  # radius exactly 1
    kept, _ = voxel_downsample(points, 0.4)
    assert 300 < len(kept) < 1_000  # 25 voxels along, about 20 around
    np.testing.assert_allclose(np.hypot(kept[:, 1], kept[:, 2]), 1.0, rtol=1e-12)


def test_voxel_duplicates_and_ties_go_to_the_first_point():
    points = np.array([[0.25, 0.5, 0.5], [0.75, 0.5, 0.5], [0.25, 0.5, 0.5], [2.5, 0.5, 0.5]])
    kept, _ = voxel_downsample(points, 1.0)
    np.testing.assert_array_equal(kept, points[[0, 3]])  # 0 and 2 tie (both nearest the centroid 0.417)


@pytest.mark.parametrize("size, message", [
    (0.0, r"voxel size must be a positive number, got 0.0"),
    (-1.0, r"voxel size must be a positive number"),
    (np.nan, r"voxel size must be a positive number"),
    (None, r"voxel size must be a positive number, got None"),
    (1e-300, r"voxel size 1e-300 is too small for coordinates as large as 7.\d+ — give a larger size"),
])
def test_voxel_refuses_a_bad_size(cloud, size, message):
    with pytest.raises(InputError, match=message):
        voxel_downsample(cloud[0], size)


def test_voxel_of_no_points():
    kept, normals = voxel_downsample(np.empty((0, 3)), 1.0, normals=np.empty((0, 3)))
    assert kept.shape == normals.shape == (0, 3)


def test_voxel_far_from_the_origin_uses_the_wide_grid():
    """Survey coordinates and a fine voxel: more voxels in the bounding box than one int64 can count."""
    rng = np.random.default_rng(SEED)
    points = rng.uniform(0, 1, size=(200, 3)) * [1e6, 1e6, 1e6] + 1e6
    size = 1e-3
    kept, _ = voxel_downsample(points, size)
    np.testing.assert_array_equal(kept, points[_voxel_reference(points, size)])


# --- point_spacing ---------------------------------------------------------------------------------


def test_spacing_of_a_grid_is_its_step():
    grid = np.stack(np.meshgrid(*[np.arange(12.0)] * 3), axis=-1).reshape(-1, 3) * 0.25
    assert point_spacing(grid) == pytest.approx(0.25, rel=1e-12)
    # duplicated points (a LAS grid rounds them together) do not make the spacing 0
    assert point_spacing(np.vstack([grid, grid[:500]])) == pytest.approx(0.25, rel=1e-12)


def test_spacing_matches_brute_force(cloud):
    points = cloud[0]
    distance = cdist(points, points)
    np.fill_diagonal(distance, np.inf)
    assert point_spacing(points) == pytest.approx(np.median(distance.min(axis=1)), rel=1e-12)


def test_spacing_on_a_sample_is_seeded_and_close():
    rng = np.random.default_rng(SEED)
    points = rng.uniform(0, 1, size=(3 * SPACING_SAMPLE, 3))
    full = point_spacing(points, sample=len(points))
    sampled = point_spacing(points)
    assert sampled == point_spacing(points)  # the same seed, the same sample
    assert sampled != point_spacing(points, rng=1)
    assert sampled == pytest.approx(full, rel=0.02)


def test_spacing_of_too_few_distinct_points_is_nan():
    assert np.isnan(point_spacing(np.zeros((1, 3))))
    assert np.isnan(point_spacing(np.zeros((5, 3))))  # one place, five times


# --- quantisation_noise ----------------------------------------------------------------------------

#: The stored tube's grid: x in steps of 2 cm, y of 1 cm, z not rounded; the noise that adds along a
#: normal of random direction (quantisation_noise's docstring).
STEPS = (0.02, 0.01)
GRID_NOISE = float(np.sqrt(sum(q * q for q in STEPS) / 36.0))


def _tube(noise: float = 0.001, seed: int = SEED) -> np.ndarray:
    """6,000 points on a slanted tube of radius 0.1 m and length 2 m, with Gaussian ``noise``."""
    rng = np.random.default_rng(seed)
    angle, along = rng.uniform(0, 2 * np.pi, 6000), rng.uniform(0, 2, 6000)
    radius = 0.1 + rng.normal(0, noise, 6000)
    tube = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), along])
    return tube @ Rotation.from_euler("xy", [20, 35], degrees=True).as_matrix().T + [3.0, -1.0, 0.5]


def _stored(points: np.ndarray) -> np.ndarray:
    return np.column_stack([np.round(points[:, 0] / STEPS[0]) * STEPS[0],
                            np.round(points[:, 1] / STEPS[1]) * STEPS[1], points[:, 2]])


def _turned(points: np.ndarray, seed: int) -> np.ndarray:
    return points @ Rotation.random(random_state=seed).as_matrix().T


def test_quantisation_noise_of_a_grid_along_the_axes():
    assert quantisation_noise(_stored(_tube())) == pytest.approx(GRID_NOISE, rel=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_quantisation_noise_finds_a_turned_grid(seed):
    # A scan rounded as stored, then registered: its grid no longer lies along x, y and z.
    assert quantisation_noise(_turned(_stored(_tube()), seed)) == pytest.approx(GRID_NOISE, rel=1e-6)


def test_quantisation_noise_finds_a_turned_grid_under_light_noise():
    stored = _turned(_stored(_tube()), 1)
    moved = stored + np.random.default_rng(SEED).normal(0, STEPS[1] / 20, stored.shape)
    assert quantisation_noise(moved) == pytest.approx(GRID_NOISE, rel=0.02)


@pytest.mark.parametrize("points", [
    _tube(),                                                                       # never rounded
    _turned(_stored(_tube()), 2) + np.random.default_rng(SEED).normal(0, STEPS[0] / 3, (6000, 3)),  # drowned
], ids=["not rounded", "noise of a third of the step"])
def test_quantisation_noise_of_points_on_no_grid_is_zero(points):
    assert quantisation_noise(points) == 0.0


def test_quantisation_noise_takes_a_scanners_rows_for_no_grid():
    # Rows and columns of a raster scan are as regular as a grid between neighbours, not across the
    # scan; rounded to 5 cm as stored and then turned, the same scan is on a grid.
    assert quantisation_noise(synth.scan("fig9-pipe", rng=0).points) == 0.0
    stored = synth.scan("fig9-pipe", quantum=0.05, rng=0).points
    assert quantisation_noise(_turned(stored, 3)) == pytest.approx(quantisation_noise(stored), rel=1e-6)
    assert quantisation_noise(stored) == pytest.approx(0.05 / np.sqrt(12), rel=1e-9)
