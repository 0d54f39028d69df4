"""Tests of canalsurf.normals: regression-plane normals against the generators' exact normals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from canalsurf import synth
from canalsurf.constants import NORMAL_NEIGHBOURS, ORIENT_NEIGHBOURS
from canalsurf.normals import (NOISE_MIN_POINTS, NOISE_PER_REACH, _quadric_scatter, estimate_normals, facing_inward,
                               orient_normals, surface_noise)

SEED = 7
#: Share of estimated normals that must point the same way as the true ones (NOTES: MST orientation
#: flipped none on these surfaces; centroid heuristics flip 1-3 %).
MIN_SIGN_AGREEMENT = 0.99
#: Mean angle between estimated and true normal lines, degrees.  2000 points with 16 neighbours span a
#: patch comparable to the tube radius, so the plane tilts a few degrees; the Figure 15 pipe (r = 0.3 on
#: a 14.5 long spine: about 8 points around) is the worst case, measured 10.3 degrees.
MEAN_ANGLE_DEG = {"fig15-pipe": 12.0}
MEAN_ANGLE_DEFAULT_DEG = 9.0


def _outward_share(estimated, true):
    return float(np.mean(np.einsum("ij,ij->i", estimated, true) > 0))


#: Points per surface: 2000 as in the paper, more for the long tubes, which 2000 points sample only a
#: few around (the pipeline's conditions use the same counts).
N_POINTS = {"tight-helix": 5000, "trefoil": 5000, "long-thin": 20000}


@pytest.mark.parametrize("name", list(synth.SURFACES))
def test_estimated_normals_match_true_normals(name, angle_deg):
    n = N_POINTS.get(name, 2000)
    tube = synth.make_tube(name, n=n, rng=SEED)
    normals = estimate_normals(tube.points)
    assert normals.shape == (n, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert _outward_share(normals, tube.normals) >= MIN_SIGN_AGREEMENT
    assert angle_deg(normals, tube.normals).mean() <= MEAN_ANGLE_DEG.get(name, MEAN_ANGLE_DEFAULT_DEG)


def test_noise_free_cylinder_normals_are_accurate_and_outward(cylinder, angle_deg):
    points, true, _, _ = cylinder(2000, radius=1.0, length=10.0)
    normals = estimate_normals(points)
    assert _outward_share(normals, true) == 1.0
    # A symmetric 16-point patch of a cylinder gives the exact normal; random sampling tilts it a little.
    assert angle_deg(normals, true).mean() <= 5.0
    # Normals of a cylinder have no axial component beyond the tilt.
    assert np.abs(normals[:, 2]).mean() <= np.sin(np.radians(5.0))


def test_pca_matches_brute_force_reference(rng):
    """Fast path (KD-tree + batched eigh) against sorted full distances + SVD, point by point."""
    tube = synth.make_tube("fig9-pipe", n=600, rng=SEED)
    points = tube.points
    normals = estimate_normals(points)
    for i in rng.choice(len(points), 40, replace=False):
        nearest = np.argsort(np.linalg.norm(points - points[i], axis=1))[:NORMAL_NEIGHBOURS]
        patch = points[nearest] - points[nearest].mean(axis=0)
        reference = np.linalg.svd(patch)[2][-1]  # direction of least spread
        assert abs(abs(reference @ normals[i]) - 1.0) <= 1e-9


def test_sphere_normals_point_outward(rng, angle_deg):
    v = rng.normal(size=(2000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    normals = estimate_normals(2.0 * v + [1.0, -2.0, 3.0])
    assert _outward_share(normals, v) == 1.0
    assert angle_deg(normals, v).mean() <= 3.0


@pytest.mark.parametrize("arc", [np.pi, np.pi / 2])
def test_partial_cylinder_normals_point_outward(cylinder, arc):
    """A one-sided scan: no opposite side, orientation must still come out outward (mean-curvature vote)."""
    points, true, _, _ = cylinder(2000, radius=1.5, length=8.0, noise=0.03, arc=arc)
    assert _outward_share(estimate_normals(points), true) >= MIN_SIGN_AGREEMENT


def _flipped(normals, rng):
    return normals * np.where(rng.random(len(normals)) < 0.5, -1.0, 1.0)[:, None]


def _neighbours(points, k=9):
    return cKDTree(points).query(points, k=k)[1]


@pytest.mark.parametrize("shape", ["sphere", "half-cylinder", "fig16-canal", "two-tubes"])
def test_orient_normals_recovers_outward_after_random_flips(shape, cylinder, rng):
    if shape == "sphere":
        true = rng.normal(size=(1500, 3))
        true /= np.linalg.norm(true, axis=1, keepdims=True)
        points = 3.0 * true
    elif shape == "half-cylinder":
        points, true, _, _ = cylinder(1500, radius=1.0, length=6.0, arc=np.pi)
    elif shape == "fig16-canal":
        tube = synth.make_tube("fig16-canal", n=2000, rng=SEED)
        points, true = tube.points, tube.normals
    else:  # two separate tubes: each connected part gets its own global sign
        points, true, _, _ = cylinder(2000, radius=1.0, length=8.0)
        points = points.copy()
        points[1000:] += [20.0, 0.0, 0.0]
    given = _flipped(true, rng)
    before = given.copy()
    oriented = orient_normals(points, given, _neighbours(points))
    np.testing.assert_array_equal(given, before)  # input untouched
    # Only signs change, and every normal ends up outward.
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", oriented, given)), 1.0, atol=1e-12)
    assert _outward_share(oriented, true) == 1.0


def test_orient_normals_of_inward_input_turns_all_outward(cylinder):
    points, true, _, _ = cylinder(1500, radius=1.0, length=6.0)
    oriented = orient_normals(points, -true, _neighbours(points))
    np.testing.assert_allclose(oriented, true, atol=0)


@pytest.mark.parametrize("radii", [(1.0, 1.0), (1.0, 0.5), (1.0, 0.3), (1.0, 1.0, 1.0), (1.0, 0.6, 0.8)])
def test_a_tube_that_touches_another_and_faces_inward_is_found(radii):
    # The spanning tree crosses where the tubes touch: one of them faces inward (the middle one of three
    # in two halves), and their part's vote cannot tell.
    net = synth.make_network("bundle", n=5000, noise=0.02, rng=SEED, radii=radii)
    nbr = _neighbours(net.points, k=16)
    normals = estimate_normals(net.points, neighbours=nbr)
    wrong = np.einsum("ij,ij->i", normals, net.normals) < 0
    assert wrong.mean() > 0.2  # what is to be found
    found = facing_inward(net.points, normals, nbr[:, :ORIENT_NEIGHBOURS + 1])
    assert wrong[found].mean() >= 0.75
    assert found.sum() >= 0.6 * wrong.sum()


@pytest.mark.parametrize("name", ["fig9-pipe", "fig16-canal", "elbow", "t-junction", "tree", "floor-clutter",
                                  "rack"])
def test_tubes_that_face_outward_and_creases_are_not_found_facing_inward(name):
    cloud = (synth.make_network(name, n=5000, rng=SEED) if name in synth.NETWORKS
             else synth.make_tube(name, n=5000, rng=SEED))
    nbr = _neighbours(cloud.points, k=ORIENT_NEIGHBOURS + 1)
    assert not facing_inward(cloud.points, cloud.normals, nbr).any()


def test_same_input_same_output():
    points = synth.make_tube("helix", n=1500, rng=SEED).points
    np.testing.assert_array_equal(estimate_normals(points), estimate_normals(points.copy()))


def test_normals_are_equivariant_under_rotation_translation_and_permutation(rng):
    tube = synth.make_tube("fig14-canal", n=1500, rng=SEED)
    base = estimate_normals(tube.points)
    rot = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    moved = estimate_normals(tube.points @ rot.T + [100.0, -50.0, 7.0])
    np.testing.assert_allclose(moved, base @ rot.T, atol=1e-8)
    perm = rng.permutation(len(tube.points))
    np.testing.assert_allclose(estimate_normals(tube.points[perm]), base[perm], atol=1e-8)


def test_estimate_normals_does_not_change_its_input():
    points = synth.make_tube("torus", n=800, rng=SEED).points
    before = points.copy()
    estimate_normals(points, k=12)
    np.testing.assert_array_equal(points, before)


def test_larger_k_still_outward_and_accurate(angle_deg):
    tube = synth.make_tube("fig9-pipe", n=2000, rng=SEED)
    normals = estimate_normals(tube.points, k=30)
    assert _outward_share(normals, tube.normals) >= MIN_SIGN_AGREEMENT
    assert angle_deg(normals, tube.normals).mean() <= MEAN_ANGLE_DEFAULT_DEG


def test_on_planes_finds_the_floor_under_a_pipe_but_not_the_pipe():
    from canalsurf.normals import on_planes
    from canalsurf.synth import make_network

    scene = make_network("floor-clutter", n=8000, noise=0.01, rng=2)
    nrm = estimate_normals(scene.points)
    floor_z = scene.floor[4]
    flat = np.flatnonzero(np.abs(scene.points[:, 2] - floor_z) < 0.05)
    found = on_planes(scene.points, nrm, flat, 0.05)
    on_floor = np.abs(scene.points[found, 2] - floor_z) < 0.05
    assert on_floor.mean() > 0.99
    assert len(found) >= 0.9 * len(flat)
    tube = scene.label >= 0
    assert np.isin(np.flatnonzero(tube), found).mean() < 0.01


def _noisy_cylinder(radius: float, n: int, sigma: float, rng) -> np.ndarray:
    """``n`` points on a cylinder of length 10, moved along their normals by Gaussian noise ``sigma``."""
    angle, z = rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 10, n)
    r = radius + rng.normal(scale=sigma, size=n)
    return np.column_stack([r * np.cos(angle), r * np.sin(angle), z])


@pytest.mark.parametrize("radius, n, sigma", [(1.0, 20_000, 0.01), (1.0, 20_000, 0.05), (1.0, 200_000, 0.05),
                                              (0.5, 2500, 0.01)])
def test_surface_noise_is_the_noise_along_the_normal(radius, n, sigma):
    """True Gaussian noise within 10 %: also where it is near the spacing (the second and third case:
    the points are thinned), and where neighbourhoods reach half the radius (the last case: a
    regression plane there reads the curvature as noise)."""
    points = _noisy_cylinder(radius, n, sigma, np.random.default_rng(3))
    estimate = surface_noise(points, points[:2000])
    assert abs(estimate - sigma) < 0.1 * sigma, estimate
    reach = cKDTree(points).query(points[:2000], k=NORMAL_NEIGHBOURS)[0][:, -1].mean()
    if reach > radius / 4:
        planes = points[cKDTree(points).query(points[:2000], k=NORMAL_NEIGHBOURS)[1]]
        planes -= planes.mean(axis=1, keepdims=True)
        plane_scatter = np.sqrt(np.median(np.linalg.eigvalsh(np.einsum("nki,nkj->nij", planes, planes))[:, 0]
                                          / NORMAL_NEIGHBOURS))
        assert plane_scatter > 1.5 * sigma  # what the quadric avoids


def _thin_cylinders(radius: float, n: int, sigma: float, rng) -> np.ndarray:
    """``n`` points on twelve parallel cylinders of a small ``radius``, 1 apart, moved by noise ``sigma``."""
    points = _noisy_cylinder(radius, n, sigma, rng)
    return points + np.column_stack([rng.integers(0, 4, n), rng.integers(0, 3, n), np.zeros(n)])


def _densest_level_search(points, seeds, k=NORMAL_NEIGHBOURS):
    """:func:`surface_noise` as its docstring says: from every point, thinned a seeded quarter at a time
    until the noise read is below NOISE_PER_REACH of the reach."""
    order = np.random.default_rng(0).permutation(len(points))
    n = len(points)
    while True:
        level = points[order[:n]]
        reach, nbr = cKDTree(level).query(seeds, k=k)
        noise = _quadric_scatter(level[nbr], k)
        if noise <= NOISE_PER_REACH * np.median(reach[:, -1]) or n // 4 < NOISE_MIN_POINTS:
            return noise
        n //= 4


@pytest.mark.parametrize("points", [_noisy_cylinder(1.0, 200_000, 0.05, np.random.default_rng(5)),
                                    _thin_cylinders(0.05, 200_000, 0.0005, np.random.default_rng(6)),
                                    _thin_cylinders(0.01, 200_000, 0.0001, np.random.default_rng(1))],
                         ids=["noise read in full only where thinned", "thin tubes read as noise where thinned",
                              "thinned neighbourhoods reach along thin tubes"])
def test_surface_noise_reads_at_the_level_the_search_from_every_point_would(points):
    """The search starts where the three sparsest levels foresee (the first case, where they read the same
    noise) or from every point (the others, where the sparse neighbourhoods take in the thin tubes'
    curvature, or reach along them and read it the same); either way it ends at the same level as the
    search from every point."""
    assert surface_noise(points, points[:2000]) == pytest.approx(_densest_level_search(points, points[:2000]),
                                                                  rel=1e-9)


def test_surface_noise_of_a_noise_free_surface_is_near_zero_and_of_too_few_points_zero():
    points = _noisy_cylinder(1.0, 20_000, 0.0, np.random.default_rng(4))
    assert surface_noise(points, points[:500]) < 1e-3
    assert surface_noise(points[:10], points[:5]) == 0.0
    assert surface_noise(points, points[:0]) == 0.0
