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
