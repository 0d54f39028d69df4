"""Tests of canalsurf.shrink: Algorithms 1 and 2 on tubes whose spine and radius are known exactly."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from canalsurf import synth
from canalsurf.constants import PATIENCE, TAU
from canalsurf.normals import estimate_normals
from canalsurf.shrink import break_mask, shrink, shrink_by_concentration

SEED = 11
#: The paper's canal tolerance, cos 80 deg.
COS80 = math.cos(math.radians(80.0))


def _radial(points):
    """Distance from the z axis (the spine of the test cylinders)."""
    return np.linalg.norm(points[:, :2], axis=1)


def _brute_break_mask(points, normals, R, tau):
    """The paper's Step 3, literally: i breaks if some j has |P_j - P_i| < R and N_j . N_i < tau."""
    n = len(points)
    mask = np.zeros(n, bool)
    for i in range(n):
        close = np.linalg.norm(points - points[i], axis=1) < R
        close[i] = False
        mask[i] = np.any(close & (normals @ normals[i] < tau))
    return mask


# --- Algorithm 1 on an exact cylinder ---------------------------------------------------------------

def test_exact_cylinder_shrinks_to_its_axis(cylinder):
    """Radius 1, exact normals: after m moves every point is at 1 - m delta from the axis.

    Two points at distance rho from the axis with opposite (N_i . N_j < 0, i.e. angles > 90 deg apart)
    normals are at least rho sqrt(2) apart, so no point may break while rho sqrt(2) >= R, and once
    rho sqrt(2) < R the densely sampled cloud breaks nearly everywhere: the stop is at the first move
    with 1 - m delta < R / sqrt(2).
    """
    points, normals, _, _ = cylinder(2000, radius=1.0, length=10.0, seed=SEED)
    R, delta, mu = 0.2, 0.05, 0.7
    res = shrink(points, normals, R=R, delta=delta, mu=mu, kind="pipe", max_distance=4.0)
    predicted = math.ceil((1.0 - R / math.sqrt(2)) / delta + 1e-9)
    assert res.iterations == predicted
    assert res.stop_rule == "mu" and res.converged
    rho = 1.0 - np.arange(len(res.break_counts)) * delta
    assert np.all(res.break_counts[rho * math.sqrt(2) >= R] == 0)
    assert res.break_counts[-1] >= mu * len(points)
    assert np.all(np.diff(res.break_counts) >= 0)
    # Every point is on the axis up to R, moved exactly iterations * delta along its normal.
    assert _radial(res.points).max() <= R
    assert abs(res.iterations * delta - 1.0) <= R
    np.testing.assert_allclose(res.distance, res.iterations * delta)
    np.testing.assert_allclose(res.points, points - res.iterations * delta * normals, atol=1e-12)
    np.testing.assert_allclose(res.points[:, 2], points[:, 2])  # moves are across the axis only
    assert res.keep.all()


def test_noisy_cylinder_with_estimated_normals(cylinder):
    """The paper's Figure 5 situation: the break count rises from 0 as the cloud collapses."""
    noise = 0.1
    points, _, _, _ = cylinder(2000, radius=1.0, length=10.0, noise=noise, seed=SEED)
    normals = estimate_normals(points)
    R, delta = 0.2, 0.05
    res = shrink(points, normals, R=R, delta=delta, mu=0.7, kind="pipe", max_distance=4.0)
    assert res.converged
    counts = res.break_counts
    assert counts[0] == 0 and counts[-1] >= 0.7 * len(points)
    assert np.all(np.diff(counts) >= 0)
    # The points moved by about the radius and gathered around the axis.
    assert 1.0 - R - noise <= res.iterations * delta <= 1.0 + noise
    assert _radial(res.points).mean() <= R
    assert np.median(_radial(res.points)) <= R


def test_callback_sees_every_check(cylinder):
    points, normals, _, _ = cylinder(1000, seed=SEED)
    seen = []
    res = shrink(points, normals, R=0.2, delta=0.1, mu=0.7, max_distance=4.0,
                 callback=lambda moves, count: seen.append((moves, count)))
    assert [m for m, _ in seen] == list(range(len(seen)))
    np.testing.assert_array_equal([c for _, c in seen], res.break_counts)


def test_shrink_does_not_change_its_inputs(cylinder):
    points, normals, _, _ = cylinder(800, noise=0.05, seed=SEED)
    p0, n0 = points.copy(), normals.copy()
    shrink(points, normals, R=0.2, delta=0.1, mu=0.9, kind="canal", tau=COS80, max_distance=3.0)
    shrink(points, normals, R=0.2, delta=0.1, mu=0.9, kind="pipe", neighbours="gauss", max_distance=3.0)
    np.testing.assert_array_equal(points, p0)
    np.testing.assert_array_equal(normals, n0)


def test_same_input_same_output():
    tube = synth.make_tube("fig9-pipe", n=1500, rng=SEED)
    a = shrink(tube.points, tube.normals, R=0.2, delta=0.1, mu=0.95, kind="canal", tau=COS80,
               max_distance=4.0)
    b = shrink(tube.points.copy(), tube.normals.copy(), R=0.2, delta=0.1, mu=0.95, kind="canal",
               tau=COS80, max_distance=4.0)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.break_counts, b.break_counts)
    np.testing.assert_array_equal(a.keep, b.keep)


# --- the break condition: fast paths against the literal double loop --------------------------------

@pytest.fixture(scope="module")
def half_shrunk():
    """400 noisy points of the Figure 9 pipe moved 0.85 r inward along their true normals, so the
    opposite sides are within reach in some places and not in others."""
    tube = synth.make_tube("fig9-pipe", n=400, rng=SEED)
    normals = estimate_normals(tube.points)
    return tube.points - 0.85 * normals, normals


@pytest.mark.parametrize("slabs", [1, 3])
@pytest.mark.parametrize("tau", [0.0, COS80])
@pytest.mark.parametrize("R", [0.2, 0.35])
def test_kdtree_break_mask_equals_brute_force(half_shrunk, tau, R, slabs, monkeypatch):
    """Searched as one cloud, or as slabs across it in threads (:func:`canalsurf._rows.slabs`)."""
    from canalsurf import _rows

    monkeypatch.setattr(_rows, "cores", lambda: slabs)
    monkeypatch.setattr(_rows, "MIN_SLAB_POINTS", 50)
    points, normals = half_shrunk
    fast = break_mask(points, normals, R, tau)
    slow = _brute_break_mask(points, normals, R, tau)
    assert 0 < slow.sum() < len(points)  # the case is not trivial
    np.testing.assert_array_equal(fast, slow)


@pytest.mark.parametrize("tau", [0.0, COS80])
def test_gauss_grouping_finds_only_true_breaks(half_shrunk, cylinder, tau):
    """The Gauss-map grouping only checks some pairs: it may miss a break, never invent one."""
    points, normals = half_shrunk
    exact = _brute_break_mask(points, normals, 0.35, tau)
    gauss = break_mask(points, normals, 0.35, tau, neighbours="gauss")
    assert not np.any(gauss & ~exact)
    assert gauss.sum() >= 0.5 * exact.sum()
    # On a cylinder collapsed to within 0.1 of its axis the antipodal cells hold nearly all breaks.
    cp, cn, _, _ = cylinder(1500, seed=SEED)
    collapsed = cp - 0.9 * cn
    exact = break_mask(collapsed, cn, 0.2, tau)
    gauss = break_mask(collapsed, cn, 0.2, tau, neighbours="gauss")
    assert not np.any(gauss & ~exact)
    assert gauss.sum() >= 0.9 * exact.sum()


def test_gauss_shrinking_stops_with_the_exact_one(cylinder):
    points, normals, _, _ = cylinder(2000, seed=SEED)
    kd = shrink(points, normals, R=0.2, delta=0.05, mu=0.7, max_distance=4.0)
    ga = shrink(points, normals, R=0.2, delta=0.05, mu=0.7, neighbours="gauss", max_distance=4.0)
    assert ga.converged
    assert kd.iterations <= ga.iterations <= kd.iterations + 2
    # Move by move both see the same cloud; the grouping counts a subset of the breaks.
    common = min(len(ga.break_counts), len(kd.break_counts))
    assert np.all(ga.break_counts[:common] <= kd.break_counts[:common])


def test_neighbour_radius_is_strict():
    """T_i = {P_j : |P_i - P_j| < R} (Section 2.1; the docstring says "closer than R"): a pair exactly R
    apart is not a neighbour."""
    points = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    normals = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(_brute_break_mask(points, normals, 0.5, 0.0), [False, False])
    np.testing.assert_array_equal(break_mask(points, normals, 0.5, 0.0), [False, False])
    np.testing.assert_array_equal(break_mask(points, normals, 0.5, 0.0, neighbours="gauss"), [False, False])
    np.testing.assert_array_equal(break_mask(points, normals, 0.5 + 1e-9, 0.0), [True, True])


def test_tau_decides_the_opposite_condition():
    points = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    perpendicular = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    assert not break_mask(points, perpendicular, 0.5, 0.0).any()  # N.N = 0 is not < 0
    assert break_mask(points, perpendicular, 0.5, COS80).all()  # 0 < cos 80 deg
    assert TAU == pytest.approx(COS80)


# --- stop rules ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def noisy_canal():
    """The Figure 16 canal with estimated normals: a few percent of the points miss the spine."""
    tube = synth.make_tube("fig16-canal", n=2000, rng=SEED)
    return tube.points, estimate_normals(tube.points)


def test_paper_stop_with_mu_one_cannot_stop(noisy_canal):
    points, normals = noisy_canal
    delta, max_distance = 0.1, 6.0
    res = shrink(points, normals, R=0.1, delta=delta, mu=1.0, tau=COS80, kind="canal", stop="paper",
                 max_distance=max_distance)
    assert res.stop_rule == "max-moves"
    assert res.converged is False
    assert res.iterations == math.ceil(max_distance / delta)
    assert res.break_counts[-1] < len(points)
    assert res.keep.all()  # the printed rule returns every point
    # Points that never stopped moved the whole way (a point stopping at the very last check did too).
    moved_all = res.distance >= max_distance - 1e-9
    last_stopped = res.break_counts[-1] - res.break_counts[-2]
    assert 0 <= moved_all.sum() - (len(points) - res.break_counts[-1]) <= last_stopped


def test_auto_stop_ends_by_patience_and_drops_unstopped_points(noisy_canal):
    points, normals = noisy_canal
    res = shrink(points, normals, R=0.1, delta=0.1, mu=1.0, tau=COS80, kind="canal", stop="auto",
                 max_distance=6.0)
    assert res.stop_rule == "patience"
    assert res.converged is True
    counts = res.break_counts
    assert np.all(counts[-(PATIENCE + 1):] == counts[-1])  # no point stopped during the last moves
    assert counts[-1] >= 0.5 * len(points)
    assert res.keep.sum() == counts[-1] < len(points)
    assert res.keep.sum() >= 0.9 * len(points)
    # Kept points stopped short of the bound; dropped ones were still moving.
    assert res.distance[res.keep].max() < res.iterations * 0.1
    np.testing.assert_allclose(res.distance[~res.keep], res.iterations * 0.1)


def test_algorithm1_peak_rule_returns_the_peak():
    """Figure 15 pipe with mu = 0.999: the break count peaks below mu n.  The printed rule runs to the
    move bound; the automatic rule returns the state at the peak."""
    tube = synth.make_tube("fig15-pipe", n=2000, rng=SEED)
    normals = estimate_normals(tube.points)
    kw = dict(R=0.1, delta=0.05, mu=0.999, kind="pipe", max_distance=1.2)
    paper = shrink(tube.points, normals, stop="paper", **kw)
    auto = shrink(tube.points, normals, stop="auto", **kw)
    assert paper.stop_rule == "max-moves" and not paper.converged
    assert auto.stop_rule == "peak" and auto.converged
    peak = int(np.argmax(paper.break_counts))
    assert auto.iterations == peak
    np.testing.assert_array_equal(auto.break_counts, paper.break_counts[: peak + 1])
    np.testing.assert_allclose(auto.points, tube.points - peak * 0.05 * normals, atol=1e-12)
    # The peak is the collapse: all points moved about r = 0.3.
    assert abs(peak * 0.05 - 0.3) <= 0.1 + 0.05


# --- Algorithm 2: per-point distances are the radius ----------------------------------------------

def test_algorithm2_distances_track_the_true_radius(envelope):
    """Figure 16 canal (r from 1 to 2.5), noise-free, exact normals, known t of every point.

    A point stops at its first move within R of an opposite point, so it stops at most R + delta short
    of the spine and never overshoots it by more than delta.
    """
    spine_f, radius_f, *_ = synth.SURFACES["fig16-canal"]
    spine, radius = spine_f(), radius_f()
    rng = np.random.default_rng(SEED)
    t = rng.uniform(0.0, 1.0, 2000)
    points, normals = envelope(spine, radius, t, rng.uniform(0.0, 2 * np.pi, 2000))
    R, delta = 0.1, 0.05
    res = shrink(points, normals, R=R, delta=delta, mu=0.98, tau=COS80, kind="canal", max_distance=6.0)
    assert res.converged
    kept = res.keep
    assert kept.sum() >= 0.98 * len(points)
    err = res.distance - radius(t)
    assert err[kept].max() <= delta + 1e-9
    assert err[kept].min() >= -(R + delta)
    assert np.abs(err[kept]).mean() <= 0.05 * radius(t).mean()
    # The distance moved is a multiple of delta and the point moved along its own normal.
    np.testing.assert_allclose(res.distance / delta, np.round(res.distance / delta), atol=1e-9)
    np.testing.assert_allclose(res.points, points - res.distance[:, None] * normals, atol=1e-12)
    # The thin and thick ends of the canal stop at their own radii: the radius function is resolved.
    thick, thin = kept & (t > 0.9), kept & (np.abs(t - 0.55) < 0.05)
    assert res.distance[thick].mean() - res.distance[thin].mean() == pytest.approx(
        radius(t[thick]).mean() - radius(t[thin]).mean(), abs=2 * delta)


@pytest.mark.parametrize("arc_deg", [120.0, 200.0, 360.0])
def test_concentration_moves_a_partial_cylinder_to_its_axis(cylinder, arc_deg):
    """No opposite normals needed: a scan of only part of the circumference still reaches the axis."""
    points, normals, _, _ = cylinder(2000, radius=1.0, length=10.0, noise=0.02, arc=np.radians(arc_deg))
    neighbours = cKDTree(points).query(points, k=16)[1]
    result = shrink_by_concentration(points, normals, R=0.2, delta=0.05, max_distance=4.0,
                                     neighbours=neighbours)
    assert result.stop_rule == "concentration" and result.converged and result.keep.all()
    # Each point moves by its radius to within a step; the points land on the axis.
    assert np.abs(result.distance - 1.0).max() <= 0.05 + 0.02 + 1e-9
    assert np.median(np.linalg.norm(result.points[:, :2], axis=1)) <= 0.05


def test_concentration_follows_a_varying_radius(envelope):
    """On a cone-like canal each point moves by the radius of its own cross-section."""
    spine = BSpline(np.array([0.0, 0, 1, 1]), np.array([[0.0, 0, 0], [0, 0, 20.0]]), 1)
    radius = BSpline(np.array([0.0, 0, 1, 1]), np.array([1.0, 2.0]), 1)
    rng = np.random.default_rng(3)
    t, s = rng.uniform(0.05, 0.95, 4000), rng.uniform(0.0, np.pi, 4000)  # one side only
    points, normals = envelope(spine, radius, t, s)
    neighbours = cKDTree(points).query(points, k=16)[1]
    result = shrink_by_concentration(points, normals, R=0.2, delta=0.05, max_distance=4.0,
                                     neighbours=neighbours)
    # The distance to the spine along the envelope's normal is r sqrt(1 + r'^2 / |C'|^2) ~ r here.
    expected = radius(t) * np.sqrt(1 + (1.0 / 20.0) ** 2)
    assert np.median(np.abs(result.distance - expected)) <= 0.05
    assert np.percentile(np.abs(result.distance - expected), 95) <= 0.15


@pytest.mark.parametrize("grid, off_axis, radius", [(None, 0.05, 0.05), (0.4, 0.5, 0.3)])
def test_sections_find_the_axis_of_a_sparse_one_sided_pole(grid, off_axis, radius):
    # A pole of radius 1 seen over 150 degrees, sparse (spacing 0.36 r), and also stored on a grid of
    # 0.4 r as a mobile-mapping pole is: normals are noise there, but circles through each
    # neighbourhood's cross-section still find the axis -- closely on exact coordinates, well enough to
    # start the final fit from on the grid.
    from canalsurf.shrink import shrink_by_sections
    from canalsurf.spine import constant_spline
    from canalsurf.synth import sample_tube

    rng = np.random.default_rng(3)
    spine = BSpline(np.array([0, 0, 1, 1.0]), np.array([[0, 0, 0], [0, 0, 20.0]]), 1)
    points, _ = sample_tube(spine, constant_spline(1.0), 400, 0.05, rng, arc=150)
    if grid:
        points = np.round(points / grid) * grid
    result, tube = shrink_by_sections(points)
    assert tube.mean() > 0.6  # all but the ends, where a neighbourhood is as wide as it is long
    assert np.median(np.hypot(result.points[tube, 0], result.points[tube, 1])) < off_axis
    assert abs(np.median(result.distance[tube]) - 1.0) < radius
    assert result.stop_rule == "sections"
