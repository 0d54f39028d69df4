"""Tests of canalsurf.thin: moving least-squares thinning against the curve the noise was added to."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from canalsurf.thin import mls_thin, voxel_average, wyvill_weight

SEED = 5


def _helix(t):
    """Two turns of a helix of radius 3 and pitch 4 (length about 38.5, curvature radius about 3.1)."""
    a = 4 * np.pi * t
    return np.column_stack([3 * np.cos(a), 3 * np.sin(a), 8 * t])


def _circle(t, radius=2.0):
    a = 2 * np.pi * t
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros_like(a)])


# --- Eq. (3) -------------------------------------------------------------------------------------------

def test_wyvill_weight_is_eq3():
    H = 2.5
    r = np.array([0.0, H / 4, H / 2, 3 * H / 4, H, 1.5 * H, 100.0])
    q = np.minimum(r / H, 1.0)
    expected = np.where(r < H, 2 * q**3 - 3 * q**2 + 1, 0.0)
    np.testing.assert_allclose(wyvill_weight(r, H), expected, atol=1e-15)
    assert wyvill_weight(0.0, H) == 1.0
    assert wyvill_weight(H / 2, H) == pytest.approx(0.5, abs=1e-15)
    assert wyvill_weight(H, H) == 0.0
    assert wyvill_weight(3 * H, H) == 0.0


def test_wyvill_weight_is_smooth_and_decreasing():
    H = 1.0
    r = np.linspace(0.0, H, 1001)
    w = wyvill_weight(r, H)
    assert np.all(np.diff(w) <= 0) and np.all(w >= 0)
    # Flat at both ends (C1 where it meets the zero outside): the derivative 6 q^2 - 6 q vanishes.
    h = 1e-6
    assert abs(wyvill_weight(h, H) - 1.0) / h <= 1e-5
    assert abs(wyvill_weight(H - h, H)) / h <= 1e-5


# --- voxel averaging -----------------------------------------------------------------------------------

def test_voxel_average_preserves_mass_and_mean(rng):
    points = rng.normal(scale=3.0, size=(3000, 3)) + [1e3, -2e3, 5.0]
    centres, counts, label = voxel_average(points, 0.7)
    assert counts.sum() == len(points)
    np.testing.assert_allclose((centres * counts[:, None]).sum(axis=0) / counts.sum(), points.mean(axis=0),
                               rtol=1e-12)
    np.testing.assert_array_equal(np.bincount(label, minlength=len(counts)), counts)
    # Each centre is the mean of the points labelled with it.
    for a in range(3):
        np.testing.assert_allclose(np.bincount(label, points[:, a]) / counts, centres[:, a], rtol=1e-12)


def test_voxel_average_equals_dictionary_grouping(rng):
    """Against the obvious reference: group points by their integer voxel key in a dict."""
    points = rng.uniform(-2.0, 2.0, size=(1500, 3))
    size = 0.45
    centres, counts, label = voxel_average(points, size)
    groups = defaultdict(list)
    keys = np.floor((points - points.min(axis=0)) / size).astype(int)
    for i, key in enumerate(map(tuple, keys)):
        groups[key].append(i)
    assert len(groups) == len(counts)
    for members in groups.values():
        assert len(set(label[members])) == 1  # one voxel, one label
        c = label[members[0]]
        assert counts[c] == len(members)
        np.testing.assert_allclose(centres[c], points[members].mean(axis=0), rtol=1e-12, atol=1e-15)


def test_voxel_average_keeps_distinct_points_apart():
    points = np.array([[0.0, 0, 0], [10.0, 0, 0], [0.0, 10, 0]])
    centres, counts, label = voxel_average(points, 1.0)
    np.testing.assert_array_equal(counts, [1, 1, 1])
    np.testing.assert_allclose(centres[label], points)


# --- moving least squares -------------------------------------------------------------------------------

def _mean_distance(points, curve, curve_distance):
    return curve_distance(points, curve)[0].mean()


@pytest.mark.parametrize("seed", [SEED, SEED + 1])
def test_mls_thins_a_noisy_helix(seed, curve_distance):
    """3D Gaussian noise sigma = 0.1 around a helix; H = 1.0.  The thin set must be several times closer
    to the helix (measured 4.8 - 5.5x; the residual is the variance of a local quadratic fit)."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.0, 1.0, 2000)
    points = _helix(t) + rng.normal(scale=0.1, size=(2000, 3))
    before = points.copy()
    thin = mls_thin(points, H=1.0)
    np.testing.assert_array_equal(points, before)
    assert thin.shape == points.shape and np.isfinite(thin).all()
    d0, s0 = curve_distance(points, _helix)
    d1, s1 = curve_distance(thin, _helix)
    assert d0.mean() / d1.mean() >= 3.5
    assert np.percentile(d1, 95) <= 0.5 * np.percentile(d0, 95)
    # Row i is the image of row i: it moved across the curve, not along it.
    assert np.median(np.abs(s1 - s0)) <= 0.1
    assert np.abs(s1 - s0).max() <= 1.0


def test_mls_thins_a_noisy_circle(rng, curve_distance):
    t = rng.uniform(0.0, 1.0, 2000)
    points = _circle(t) + rng.normal(scale=0.1, size=(2000, 3))
    thin = mls_thin(points, H=0.5)
    assert (_mean_distance(points, _circle, curve_distance)
            >= 3.0 * _mean_distance(thin, _circle, curve_distance))
    # No shrinkage towards the circle's centre beyond a small curvature bias.
    assert abs(np.linalg.norm(thin[:, :2], axis=1).mean() - 2.0) <= 0.02


def test_mls_keeps_points_that_are_on_a_circle(rng, curve_distance):
    """Noise-free data: the local quadratic nearly interpolates a circle of radius 2 (H = 0.5)."""
    points = _circle(rng.uniform(0.0, 1.0, 2000))
    thin = mls_thin(points, H=0.5)
    assert curve_distance(thin, _circle)[0].max() <= 1e-3 * 2.0
    assert np.linalg.norm(thin - points, axis=1).max() <= 1e-3 * 2.0


def test_mls_keeps_points_that_are_on_a_line(rng):
    direction = np.array([1.0, 2.0, -2.0]) / 3.0
    points = rng.uniform(0.0, 10.0, 1000)[:, None] * direction + [1.0, 1.0, 1.0]
    thin = mls_thin(points, H=0.8)
    np.testing.assert_allclose(thin, points, atol=1e-9)


def test_mls_leaves_isolated_points_alone(rng):
    """A point with no neighbour within H has nothing to regress on and stays where it is."""
    t = rng.uniform(0.0, 1.0, 500)
    points = np.vstack([_circle(t), [[50.0, 50.0, 50.0]]])
    thin = mls_thin(points, H=0.5)
    np.testing.assert_array_equal(thin[-1], points[-1])


def test_mls_same_input_same_output(rng):
    points = _helix(rng.uniform(0.0, 1.0, 1500)) + rng.normal(scale=0.1, size=(1500, 3))
    np.testing.assert_array_equal(mls_thin(points, H=0.8), mls_thin(points.copy(), H=0.8))


def test_a_weighting_radius_too_small_for_the_cloud_is_refused_in_one_line(rng):
    """H = 1e-300 on a cloud 10 across numbers its voxels past 64-bit integers: refused, not a singular
    matrix from the regressions."""
    from canalsurf.errors import InputError

    points = _circle(rng.uniform(0.0, 1.0, 500), radius=5.0)
    with pytest.raises(InputError, match=r"^H = 1e-300 .* too small for a shrunk cloud 10 across — give an H"):
        mls_thin(points, H=1e-300)
    assert np.isfinite(mls_thin(points, H=1e-12)).all()  # small, but numbered and weighted in float64
