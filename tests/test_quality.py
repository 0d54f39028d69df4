"""Tests of canalsurf.quality: each reason raises the quality it names, and real reconstructions get
the quality their scans deserve."""

from __future__ import annotations

import numpy as np
import pytest

import canalsurf
from canalsurf.quality import (CHECK_GAP_RADII, CHECK_NO_TUBE_SHARE, POOR_COVERAGE_DEGREES, POOR_GAP_RADII,
                               branch_quality, scan_quality, support_gap)

#: A branch with nothing to doubt: radius 1, noise 0.01, seen all round, no gap, round.
CLEAN = {"rms": 0.01, "radius": 1.0, "noise": 0.01, "coverage": 340.0, "gap": 0.1, "out_of_round": 0.005}


def test_a_clean_branch_is_good():
    assert branch_quality(**CLEAN) == ("good", [])


@pytest.mark.parametrize("change, level, words", [
    ({"coverage": 180.0}, "check", "one side (180 degrees"),
    ({"coverage": POOR_COVERAGE_DEGREES - 1}, "poor", "one side only"),
    ({"coverage": float("nan")}, "check", "too few points"),
    ({"gap": 1.5 * CHECK_GAP_RADII}, "check", "gap of 1.5 radii"),
    ({"gap": 1.1 * POOR_GAP_RADII}, "poor", "gap of 3.3 radii"),
    ({"rms": 0.12}, "poor", "scatter 12% of the radius"),
    ({"rms": 0.05}, "check", "5.0 times the scan's noise"),
    ({"out_of_round": 0.06}, "check", "out of round by 6%"),
])
def test_each_reason_sets_its_level(change, level, words):
    quality, reasons = branch_quality(**{**CLEAN, **change})
    assert quality == level
    assert len(reasons) >= 1 and words in reasons[0]


@pytest.mark.parametrize("stretches, level", [
    # a quarter of its stretches seen over narrow arcs: poor, whatever the median
    ([109.0, 36.0, 214.0, 208.0, 226.0], "poor"), ([100.0, 340.0, 340.0, 340.0], "poor"),
    # one narrow stretch in five: the median's grade
    ([100.0, 340.0, 340.0, 340.0, 340.0], "good"), ([100.0, 200.0, 200.0, 200.0, 200.0], "check")])
def test_a_branch_seen_over_narrow_arcs_along_a_quarter_of_it_is_poor(stretches, level):
    """A tube fitted to the sides of different limbs (one stretch seen from below, the next from one
    flank) reads as seen over 208 degrees on the median alone."""
    median = float(np.median(stretches))
    quality, reasons = branch_quality(**{**CLEAN, "coverage": median}, stretches=np.array(stretches))
    assert quality == level
    assert any("less than 120 degrees" in r for r in reasons) == (level == "poor")


def test_random_noise_alone_is_no_reason():
    """Noise that the scan itself shows (its points scatter about their local planes as much) averages
    out in the fit: 6 % of the radius with the scan's noise at 6 % is good."""
    assert branch_quality(**{**CLEAN, "rms": 0.06, "noise": 0.06})[0] == "good"


def test_the_worst_reason_comes_first_and_sets_the_scan():
    q, reasons = scan_quality([(0, "good", []), (1, "check", ["a"]), (2, "poor", ["b"])], 0.1)
    assert q == "poor" and reasons == ["branch 2: b", "branch 1: a"]
    assert scan_quality([(0, "good", [])], CHECK_NO_TUBE_SHARE + 0.1) == ("check", ["60% of the points lie on no tube"])


def test_support_gap():
    t = np.array([0.0, 0.1, 0.2, 0.7, 0.8])
    assert support_gap(t, 10.0, closed=False) == pytest.approx(5.0)
    assert support_gap(np.array([0.1, 0.5, 0.6]), 10.0, closed=True) == pytest.approx(5.0)


@pytest.mark.parametrize("arc, level", [(360, "good"), (180, "check")])
def test_reconstructions_report_their_quality(arc, level):
    model = canalsurf.reconstruct(canalsurf.make_tube("fig9-pipe", arc=arc, rng=2).points)
    assert model.diagnostics["quality"] == level
    assert model.branches[0].diagnostics["quality"] == level
    assert (level == "good") == (model.diagnostics["quality_reasons"] == [])


def _polyline_spline(points):
    from scipy.interpolate import make_interp_spline

    from canalsurf.synth import _by_arclength

    u = np.linspace(0, 1, len(points))
    return _by_arclength(make_interp_spline(u, np.asarray(points, float), k=3)(np.linspace(0, 1, 400)))


def test_fold_finds_a_hairpin_and_a_kink_but_not_a_tube():
    from canalsurf.quality import fold
    from canalsurf.spine import constant_spline

    # A spine that comes round to run over its own start (380 degrees of a circle of radius 3): two
    # tubes in one place, though it bends gently everywhere.
    a = np.radians(np.linspace(0, 380, 80))
    over = _polyline_spline(np.column_stack([3 * np.cos(a), 3 * np.sin(a), 0.05 * a]))
    assert "passes within" in fold(over, constant_spline(1.0), False)
    # Run to the far end and back (a hairpin): it turns round at its tip.
    hairpin = _polyline_spline([[0, 0, 0], [4, 0, 0], [5, 0.25, 0], [4, 0.5, 0], [0, 0.5, 0]])
    assert "turns back" in fold(hairpin, constant_spline(1.0), False)
    # A U-turn of radius 0.3 on a tube of radius 1 (its legs 0.6 apart): a hook.
    t = np.linspace(0, np.pi, 50)
    hook = _polyline_spline(np.column_stack([np.r_[np.linspace(-3, 0, 10)[:-1], 0.3 * np.sin(t)],
                                             np.r_[np.zeros(9), 0.3 - 0.3 * np.cos(t)], np.zeros(59)]))
    assert "turns back" in fold(hook, constant_spline(1.0), False)
    for name in ("elbow", "torus", "tight-helix", "fig16-canal"):
        tube = canalsurf.make_tube(name, n=500, rng=1)
        assert fold(tube.spine, tube.radius, tube.closed) == "", name
    # The torus's ring (radius 4) round a tube of radius 6 (a fit to a blob of clutter): it passes through
    # itself, though it bends gently.
    torus = canalsurf.make_tube("torus", n=500, rng=1)
    assert "too short" in fold(torus.spine, constant_spline(6.0), True)


def test_fold_finds_a_hairpin_whose_legs_touch_but_not_a_coil_or_an_elbow():
    from canalsurf.quality import fold
    from canalsurf.spine import constant_spline

    def u_turn(bend, legs=6.0):
        t = np.linspace(0, np.pi, 60)
        x = np.r_[np.linspace(-legs, 0, 30)[:-1], bend * np.sin(t), np.linspace(0, -legs, 30)[1:]]
        y = np.r_[np.zeros(29), bend - bend * np.cos(t), np.full(29, 2 * bend)]
        return _polyline_spline(np.column_stack([x, y, np.zeros(len(x))]))

    # Legs 2 radii apart: the tubes about them touch, past the clearance, and the tip turns round
    # within 2 radii.  A bend of radius 1 D (legs 4 radii apart) is a pipe's tightest elbow.
    why = fold(u_turn(1.0), constant_spline(1.0), False)
    assert "hairpin whose legs touch" in why and "runs back 2.0 radii" in why
    assert fold(u_turn(2.0), constant_spline(1.0), False) == ""
    # A coil whose turns touch (pitch 2 radii) runs alongside itself but never turns round.
    a = np.linspace(0, 6 * np.pi, 400)
    coil = _polyline_spline(np.column_stack([3 * np.cos(a), 3 * np.sin(a), 2 * a / (2 * np.pi)]))
    assert fold(coil, constant_spline(1.0), False) == ""


def test_fold_finds_a_spine_that_bends_more_tightly_than_its_radius():
    """A spine wiggling 0.05 to either side every unit of length bends with curvature up to 2: round a tube
    of radius 1 it does so more tightly than the radius along two thirds of it (the surface passes through
    itself), round one of radius 0.3 nowhere."""
    from canalsurf.quality import FOLD_BEND_SHARE, fold
    from canalsurf.spine import constant_spline

    s = np.linspace(0, 8, 400)
    wiggle = _polyline_spline(np.column_stack([s, 0.05 * np.sin(2 * np.pi * s), np.zeros_like(s)]))
    why = fold(wiggle, constant_spline(1.0), False)
    assert why.startswith("the spine bends more tightly than the tube's radius along ") and "passes through itself" in why
    assert int(why.split("along ")[1].split("%")[0]) / 100 > FOLD_BEND_SHARE
    assert fold(wiggle, constant_spline(0.3), False) == ""


def test_inside_others_finds_a_spine_inside_another_tube_but_not_beside_it():
    from canalsurf.quality import inside_others, longest_inside
    from canalsurf.spine import constant_spline

    line = lambda y: _polyline_spline([[x, y, 0] for x in range(11)])  # noqa: E731
    # Touching pipes (axes a sum of radii apart) pass through each other nowhere.
    touching = inside_others([(line(0.0), constant_spline(1.0)), (line(1.5), constant_spline(0.5))])
    assert all((other < 0).all() for *_, other in touching)
    # A thin pipe whose second half swerves to 0.6 from the axis of a wide one runs inside it there,
    # about 8 of its radii; the wide one's axis stays outside the thin tube.
    x = np.linspace(0, 10, 41)
    swerve = _polyline_spline(np.column_stack([x, 1.5 - 0.9 * np.clip(x - 5, 0, 1), np.zeros_like(x)]))
    (_, s, other), (_, _, wide) = inside_others([(swerve, constant_spline(0.5)), (line(0.0), constant_spline(1.0))])
    length, which = longest_inside(s, other)
    assert which == 1 and 4.0 <= length / 0.5 <= 11.0 and other[-1] == 1
    assert (wide < 0).all()
    # Within a junction's reach the tubes meeting there are one.
    met = [[(np.array([10.0, 0.6, 0.0]), 6.0)], []]
    _, s, other = inside_others([(swerve, constant_spline(0.5)), (line(0.0), constant_spline(1.0))], met)[0]
    assert longest_inside(s, other) == (0.0, -1)


def test_a_branch_inside_another_tube_is_poor():
    quality, reasons = branch_quality(**CLEAN, inside=(2.0, 3))
    assert quality == "poor" and "inside the tube of branch 3 along 2.0 radii" in reasons[0]
