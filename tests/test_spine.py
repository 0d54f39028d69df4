"""Tests of canalsurf.spine: P-spline fits, periodic splines and arc-length parameterisation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from canalsurf import synth
from canalsurf.metrics import closest_point_distance
from canalsurf.spine import (
    DEGREE,
    arclength_reparametrize,
    coefficients_to_spline,
    constant_spline,
    curvature,
    curve_length,
    design_matrix,
    knots,
    n_coefficients,
    pspline_fit,
    sample_arclength,
)

SEED = 17
U = np.linspace(0.0, 1.0, 2001)
FINE = np.linspace(0.0, 1.0, 5001)


def _surface(name):
    spine_f, radius_f, closed, _, _ = synth.SURFACES[name]
    return spine_f(), radius_f(), closed


@pytest.fixture
def random_spline(rng):
    """A cubic B-spline curve on 8 uniform clamped segments with random control points."""
    return BSpline(knots(8, False), rng.normal(size=(n_coefficients(8, False), 3)), DEGREE)


# --- fitting ---------------------------------------------------------------------------------------------

def test_pspline_recovers_a_spline_of_its_own_space(random_spline):
    """Without the penalty the fit is plain least squares: data from a spline of the same knots come back
    exactly, coefficients included."""
    fit = pspline_fit(U, random_spline(U), n_segments=8, smoothing=0.0)
    np.testing.assert_allclose(fit.t, random_spline.t)
    np.testing.assert_allclose(fit.c, random_spline.c, atol=1e-10)
    np.testing.assert_allclose(fit(FINE), random_spline(FINE), atol=1e-10)


def test_penalty_leaves_constants_alone_and_lines_straight():
    """The second-difference penalty vanishes on constant coefficients, so a constant is reproduced
    exactly, open or periodic.  On clamped knots the coefficients of a linear function are not evenly
    spaced near the ends (Greville abscissae 0, h/3, h, 2h, ...), so the default penalty shifts the
    parameterisation there slightly -- but every coefficient stays on the data's line, so the fitted
    curve is still exactly straight."""
    for closed in (False, True):
        u = np.linspace(0.0, 1.0, 400, endpoint=not closed)
        const = np.tile([2.0, -1.0, 0.5], (len(u), 1))
        np.testing.assert_allclose(pspline_fit(u, const, n_segments=10, closed=closed)(u), const, atol=1e-12)
    u = np.linspace(0.0, 1.0, 400)
    origin, direction = np.array([2.0, -1.0, 0.5]), np.array([3.0, 1.0, -4.0])
    line = origin + np.outer(u, direction)
    fit = pspline_fit(u, line, n_segments=10)(FINE)
    off_line = np.cross(fit - origin, direction) / np.linalg.norm(direction)
    assert np.abs(off_line).max() <= 1e-10
    assert np.abs(fit - (origin + np.outer(FINE, direction))).max() <= 2e-3 * np.linalg.norm(direction)
    assert np.abs(pspline_fit(u, line, n_segments=10, smoothing=0.0)(FINE)
                  - (origin + np.outer(FINE, direction))).max() <= 1e-10


def test_default_smoothing_barely_changes_a_well_sampled_curve():
    """The docstring's promise, on the Figure 9 spine (length 27.7, r = 1) with 36 segments."""
    spine, _, _ = _surface("fig9-pipe")
    u, pts = sample_arclength(spine, 2000)
    s = np.linspace(0.0, 1.0, 2000)
    exact = pspline_fit(s, pts, n_segments=36, smoothing=0.0)
    default = pspline_fit(s, pts, n_segments=36)
    assert np.abs(exact(s) - pts).max() <= 1e-3
    assert np.abs(default(s) - pts).max() <= 0.01  # 1 % of the radius


def test_zero_weights_are_the_same_as_no_points(rng):
    u = np.sort(rng.uniform(0.0, 1.0, 600))
    values = np.column_stack([np.sin(4 * u), np.cos(3 * u), u**2]) + rng.normal(scale=0.01, size=(600, 3))
    outliers = rng.random(600) < 0.1
    values[outliers] += 50.0
    weights = (~outliers).astype(float)
    with_zero = pspline_fit(u, values, n_segments=12, weights=weights)
    without = pspline_fit(u[~outliers], values[~outliers], n_segments=12)
    # lambda scales with the total weight, which is the same in both fits.
    np.testing.assert_allclose(with_zero(FINE), without(FINE), atol=1e-9)


def test_scalar_values_fit_a_scalar_function(rng):
    u = np.sort(rng.uniform(0.0, 1.0, 500))
    r = 1.0 + 0.5 * np.sin(2 * np.pi * u)
    fit = pspline_fit(u, r, n_segments=10)
    assert fit(FINE).shape == FINE.shape
    assert np.abs(fit(FINE) - (1.0 + 0.5 * np.sin(2 * np.pi * FINE))).max() <= 0.01


def test_periodic_fit_of_a_circle_is_c2_at_the_seam():
    u = np.linspace(0.0, 1.0, 500, endpoint=False)
    circle = np.column_stack([np.cos(2 * np.pi * u), np.sin(2 * np.pi * u), np.zeros_like(u)])
    fit = pspline_fit(u, circle, n_segments=12, closed=True)
    # Tolerances of the match with the true circle: a 12-segment cubic approximates the k-th derivative
    # to O(h^(4-k)); the second derivative (curvature) measured 2.3 % off.
    for order, scale, tol in ((0, 1.0, 1e-3), (1, 2 * np.pi, 5e-3), (2, (2 * np.pi) ** 2, 5e-2)):
        f = fit if order == 0 else fit.derivative(order)
        np.testing.assert_allclose(f(1.0), f(0.0), atol=1e-9 * scale)
        # ... and it is the circle's own derivative there, not just equal at both ends.
        expected = scale * np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]][order])
        np.testing.assert_allclose(f(0.0), expected, atol=tol * scale)
    assert np.abs(np.linalg.norm(fit(FINE), axis=1) - 1.0).max() <= 1e-3


def test_curvature_of_a_helix_and_a_line():
    """A helix of radius a and pitch 2 pi b curves by a / (a^2 + b^2) whatever its parameter speed; a
    line not at all."""
    u = np.linspace(0.0, 1.0, 2000)
    a, b, turns = 2.0, 0.5, 3
    angle = 2 * np.pi * turns * u**1.5  # an uneven parameter speed
    helix = pspline_fit(u, np.column_stack([a * np.cos(angle), a * np.sin(angle), b * angle]), n_segments=120)
    inner = np.linspace(0.1, 0.9, 50)  # the ends of a fit are looser
    np.testing.assert_allclose(curvature(helix, inner), a / (a**2 + b**2), rtol=0.01)
    line = pspline_fit(u, np.outer(u + u**2, [1.0, 2.0, -1.0]), n_segments=8)
    assert curvature(line, inner).max() < 1e-9


def test_design_matrix_is_a_partition_of_unity():
    u = np.linspace(0.0, 1.0, 301)
    for closed in (False, True):
        B = design_matrix(u, 7, closed)
        assert B.shape == (301, n_coefficients(7, closed))
        np.testing.assert_allclose(np.asarray(B.sum(axis=1)).ravel(), 1.0, atol=1e-14)
    # Folding makes the periodic basis at 1 the basis at 0.
    B = design_matrix(np.array([0.0, 1.0]), 7, True).toarray()
    np.testing.assert_allclose(B[0], B[1])


def test_coefficients_to_spline_matches_design_matrix(rng):
    for closed in (False, True):
        coef = rng.normal(size=(n_coefficients(9, closed), 3))
        spline = coefficients_to_spline(coef, 9, closed)
        np.testing.assert_allclose(spline(U), design_matrix(U, 9, closed) @ coef, atol=1e-12)


def test_knots():
    np.testing.assert_allclose(knots(4, False), [0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1, 1])
    closed = knots(4, True)
    np.testing.assert_allclose(np.diff(closed), 0.25)
    assert closed[DEGREE] == 0.0 and closed[-DEGREE - 1] == 1.0


# --- arc length ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["fig9-pipe", "helix", "torus"])
def test_sample_arclength_is_evenly_spaced(name):
    spine, _, _ = _surface(name)
    t, pts = sample_arclength(spine, 300)
    assert t[0] == 0.0 and t[-1] == 1.0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(pts, spine(t))
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    length = curve_length(spine)
    # Chords of equal arcs: equal up to the chord/arc difference (curvature) and the table resolution.
    assert np.abs(step - length / 299).max() <= 2e-3 * length / 299


def test_curve_length_of_known_curves():
    line = BSpline(np.array([0.0, 0.0, 1.0, 1.0]), np.array([[0.0, 0, 0], [3.0, 4.0, 12.0]]), 1)
    assert curve_length(line) == pytest.approx(13.0, rel=1e-12)
    torus_spine, _, _ = _surface("torus")
    assert curve_length(torus_spine) == pytest.approx(2 * np.pi * 4.0, rel=1e-5)
    assert curve_length(line, 0.25, 0.75) == pytest.approx(6.5, rel=1e-12)


@pytest.mark.parametrize("name", ["fig9-pipe", "fig16-canal", "torus"])
def test_arclength_reparametrize_keeps_shape_and_gives_unit_speed(name):
    spine, radius, closed = _surface(name)
    length = curve_length(spine)
    new, (new_radius,), to_new = arclength_reparametrize(spine, n_segments=40, closed=closed,
                                                         extra=[(radius, 12)])
    # The shape is kept ...
    assert closest_point_distance(spine, new)["max"] <= 1e-3
    # ... and |C'(u)| is the length everywhere: u is normalised arc length.
    speed = np.linalg.norm(new.derivative()(FINE), axis=1)
    assert np.abs(speed / length - 1.0).max() <= 1e-3
    assert curve_length(new) == pytest.approx(length, rel=1e-4)
    # to_new maps an old parameter onto the new parameter of the same point, for the radius as well.
    np.testing.assert_allclose(new(to_new(FINE)), spine(FINE), atol=1e-3)
    np.testing.assert_allclose(new_radius(to_new(FINE)), radius(FINE), atol=5e-3)
    assert to_new(0.0) == 0.0 and to_new(1.0) == pytest.approx(1.0)


def test_arclength_reparametrize_of_a_piece():
    spine, _, _ = _surface("fig9-pipe")
    new, _, to_new = arclength_reparametrize(spine, n_segments=30, closed=False, a=0.2, b=0.7)
    np.testing.assert_allclose(new(0.0), spine(0.2), atol=1e-4)
    np.testing.assert_allclose(new(1.0), spine(0.7), atol=1e-4)
    assert curve_length(new) == pytest.approx(curve_length(spine, 0.2, 0.7), rel=1e-4)
    speed = np.linalg.norm(new.derivative()(FINE), axis=1)
    assert np.ptp(speed) / speed.mean() <= 2e-3


def test_constant_spline_has_zero_derivatives():
    c = constant_spline(2.5)
    x = np.linspace(0.0, 1.0, 11)
    np.testing.assert_allclose(c(x), 2.5, rtol=1e-15)
    for order in (1, 2, 3):
        np.testing.assert_allclose(c.derivative(order)(x), 0.0, atol=1e-12)
    assert c.k == DEGREE
