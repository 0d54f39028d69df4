"""Tests of canalsurf.order: an unordered thin cloud becomes a polyline that follows the true curve."""

from __future__ import annotations

import numpy as np
import pytest

from canalsurf.errors import ReconstructionError
from canalsurf.order import order_curve

SEED = 3
N = 2000
SPACING = 0.05


def _curve(t):
    """An open space curve of length about 6.8 with bends in two planes."""
    return np.column_stack([6 * t, 1.5 * np.sin(3 * t), 0.5 * np.cos(2 * t)])


def _arc_positions(vertices, curve, curve_distance):
    """Arc length of the nearest true-curve point of each vertex (oriented to increase), and distances."""
    dist, s = curve_distance(vertices, curve)
    if s[-1] < s[0]:
        s = s[::-1]
    return s, dist


def _assert_follows(s, back=SPACING / 2, displacement=2):
    """Vertices advance along the curve: where a cross-section splits into two voxels side by side the
    path may visit them in either order, so allow back-steps of up to half a voxel and let no vertex sit
    more than ``displacement`` places from its rank along the curve."""
    assert np.diff(s).min() >= -back
    rank = np.argsort(np.argsort(s, kind="stable"), kind="stable")
    assert np.abs(rank - np.arange(len(s))).max() <= displacement


def _shuffled_curve(seed, sigma, n=N):
    rng = np.random.default_rng(seed)
    points = _curve(rng.uniform(0.0, 1.0, n)) + rng.normal(scale=sigma, size=(n, 3))
    return points[rng.permutation(n)], rng


@pytest.mark.parametrize("seed", [SEED, SEED + 1, SEED + 2])
def test_thin_shuffled_curve_is_ordered_end_to_end(seed, curve_distance, dense_curve):
    """A thin set (noise well below the voxel spacing, as after MLS) is ordered exactly."""
    points, _ = _shuffled_curve(seed, sigma=SPACING / 25)
    curve = order_curve(points, spacing=SPACING)
    assert curve.closed is False
    s, dist = _arc_positions(curve.points, _curve, curve_distance)
    _assert_follows(s)
    assert np.mean(np.diff(s) > 0) >= 0.95  # nearly every step goes forward
    length = dense_curve(_curve)[2][-1]
    assert s[0] <= 2 * SPACING and s[-1] >= length - 2 * SPACING  # runs from end to end
    assert dist.max() <= SPACING
    # No thin point is lost: the vertex weights are the points they stand for.
    assert curve.weights.sum() == N
    assert curve.weights.min() >= 1
    steps = np.linalg.norm(np.diff(curve.points, axis=0), axis=1)
    assert steps.max() <= 3 * SPACING  # no jumps


@pytest.mark.parametrize("strays", [False, True])
def test_link_is_the_sampling_step(strays):
    """``OrderedCurve.link`` is documented as the median link of the spanning tree, "the curve's sampling
    step"; the cut of stray links and the closed-curve test are multiples of it.  On a thin curve the
    tree's links are the steps between neighbouring voxels, so it must equal the median polyline step.
    Strays (5 % of the points, but a third of the voxels) add long links to the tree and may raise the
    median somewhat, not double it."""
    points, rng = _shuffled_curve(SEED, sigma=SPACING / 25)
    if strays:
        points = np.vstack([points, rng.uniform(-5.0, 10.0, size=(N // 20, 3))])
    curve = order_curve(points, spacing=SPACING)
    steps = np.linalg.norm(np.diff(curve.points, axis=0), axis=1)
    assert curve.link == pytest.approx(np.median(steps), rel=0.5 if strays else 0.1)


def test_thicker_cloud_is_ordered_up_to_a_voxel(curve_distance):
    """Noise of a fifth of the spacing: voxels lie side by side across the curve and the path may step
    back, but never by more than one voxel."""
    points, _ = _shuffled_curve(SEED, sigma=SPACING / 5)
    curve = order_curve(points, spacing=SPACING)
    assert curve.closed is False
    s, dist = _arc_positions(curve.points, _curve, curve_distance)
    _assert_follows(s, back=SPACING, displacement=4)
    assert s[-1] - s[0] >= 6.0
    assert dist.max() <= 2 * SPACING


def test_noisy_circle_is_closed():
    rng = np.random.default_rng(SEED)
    a = rng.uniform(0.0, 2 * np.pi, N)
    points = np.column_stack([3 * np.cos(a), 3 * np.sin(a), np.zeros(N)]) + rng.normal(scale=0.002,
                                                                                      size=(N, 3))
    curve = order_curve(points, spacing=SPACING)
    assert curve.closed is True
    angle = np.unwrap(np.arctan2(curve.points[:, 1], curve.points[:, 0]))
    step = np.diff(angle)
    assert np.all(step > 0) or np.all(step < 0)
    assert np.ptp(angle) >= 2 * np.pi - 4 * SPACING / 3  # all the way round but the closing link
    assert np.abs(np.linalg.norm(curve.points[:, :2], axis=1) - 3).max() <= SPACING


def test_open_arc_is_not_closed():
    """300 degrees of a circle: the ends are 3 apart, far more than a link."""
    rng = np.random.default_rng(SEED)
    a = rng.uniform(0.0, np.radians(300), N)
    points = np.column_stack([3 * np.cos(a), 3 * np.sin(a), np.zeros(N)])
    curve = order_curve(points, spacing=SPACING)
    assert curve.closed is False
    angle = np.unwrap(np.arctan2(curve.points[:, 1], curve.points[:, 0]))
    assert np.ptp(angle) >= np.radians(300) - 4 * SPACING / 3


def test_stray_points_are_excluded(curve_distance):
    """5 % of the points scattered far off the curve: the order follows the curve, strays are left out."""
    points, rng = _shuffled_curve(SEED, sigma=SPACING / 25)
    m = N // 20
    strays = rng.uniform(-5.0, 10.0, size=(m, 3)) + [0.0, 0.0, 5.0]
    mixed = np.vstack([points, strays])[rng.permutation(N + m)]
    curve = order_curve(mixed, spacing=SPACING)
    assert curve.closed is False
    s, dist = _arc_positions(curve.points, _curve, curve_distance)
    _assert_follows(s)
    assert dist.max() <= SPACING  # no vertex on a stray
    assert s[-1] - s[0] >= 6.5
    assert N <= curve.weights.sum() < N + m


def test_same_input_same_output():
    points, _ = _shuffled_curve(SEED, sigma=0.005)
    a, b = order_curve(points, spacing=SPACING), order_curve(points.copy(), spacing=SPACING)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.weights, b.weights)


def test_a_blob_is_not_a_curve():
    rng = np.random.default_rng(SEED)
    blob = rng.normal(scale=0.01, size=(200, 3))
    with pytest.raises(ReconstructionError, match=r"^the shrunk cloud collapsed to a point, not a curve — "
                                                  r"the input is not a tube$"):
        order_curve(blob, spacing=1.0)
