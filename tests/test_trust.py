"""Trust: a model is right within the accuracy its quality claims, or the scan is refused.

The random scans of ``canalsurf.synth.random_case`` (one-sided, short and flared, quantised, networks
with clutter) are held to ``canalsurf.quality.CLAIMS``; ``benchmarks/trust.py`` runs hundreds of them,
these tests a sample (hypothesis profile ``fast`` by default; ``--hypothesis-profile=thorough`` runs
as many as the benchmark).  Then the bars of the shapes real scans showed wrong: short obliquely cut
segments must not fold, a flared trunk is a canal, thin poles seen once from one side are measured.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import canalsurf
from canalsurf.metrics import compare_network, model_error
from canalsurf.quality import CLAIMS
from canalsurf.spine import curve_length
from canalsurf.synth import (CASE_FAMILIES, SyntheticNetwork, make_network, make_pole_scan, make_segment, make_trunk,
                             random_case)

settings.register_profile("fast", max_examples=10, deadline=None, derandomize=True)
settings.register_profile("thorough", max_examples=500, deadline=None, derandomize=True)


def errors_of(case):
    """Per-branch errors of the model of ``case``, or None when it was refused with one line."""
    try:
        network = canalsurf.reconstruct(case.points)
    except canalsurf.ReconstructionError as exc:
        assert str(exc).strip() and "\n" not in str(exc)
        return None, None
    if isinstance(case, SyntheticNetwork):
        return network, model_error(network, case.branches, case.junctions)
    return network, model_error(network, [case])


@settings(settings.get_profile("fast"))
@given(family=st.sampled_from(CASE_FAMILIES), seed=st.integers(0, 2**31 - 1))
def test_every_written_branch_is_within_its_claim(family, seed):
    _, errors = errors_of(random_case(family, seed))
    for e in errors or ():
        if np.isfinite(e["spine_mean"]):
            claim = CLAIMS[e["quality"]]
            assert e["spine_mean"] <= claim["spine"], (family, seed, e)
            assert e["radius_mean"] <= claim["radius"], (family, seed, e)


@pytest.mark.parametrize("seed", range(6))
def test_short_oblique_flared_segments_do_not_fold(seed):
    rng = np.random.default_rng(seed)
    length = rng.uniform(3.0, 6.0)
    case = make_segment(length=length, cut=tuple(rng.uniform(0, 45, 2)), flare=tuple(rng.uniform(0, 0.35, 2)),
                        n=int(rng.integers(1500, 6000)), rng=rng)
    network, errors = errors_of(case)
    assert network is not None, "a short segment must be reconstructed"
    assert len(network.branches) == 1
    # A fold runs the spine to the far end and back: twice the length.  The points reach at most
    # one radius past each cut centre (a 45-degree cut), so the spine is at most length + 2.
    assert curve_length(network.branches[0].spine) <= length + 2.0 + 0.2
    (e,) = errors
    assert e["spine_mean"] <= 0.05, e
    assert e["radius_mean"] <= 0.03, e


@pytest.mark.parametrize("seed", range(3))
def test_flared_trunk_is_a_canal_within_three_percent(seed):
    case = make_trunk(flare=0.3 + 0.15 * seed, rng=seed)
    network = canalsurf.reconstruct(case.points)
    assert len(network.branches) == 1 and network.kind == "canal"
    b = network.branches[0]
    t = np.linspace(0.0, 1.0, 400)
    model_r, pts = b.radius(t), b.spine(t)
    # The true radius at each model point's height along the trunk.
    truth_t = np.linspace(0.0, 1.0, 4001)
    nearest = np.argmin(np.linalg.norm(pts[:, None] - case.spine(truth_t)[None], axis=2), axis=1)
    assert np.abs(model_r / case.radius(truth_t[nearest]) - 1).max() <= 0.03
    # And the whole height is covered, the flare included.
    assert truth_t[nearest].min() <= 0.03 and truth_t[nearest].max() >= 0.97


def test_thin_poles_seen_from_one_side_are_measured():
    # One scanner, 1 cm quantisation, 1-3 k points per tube, radius 4-15 cm: the bar is 9 of 10 within
    # 10 % of the radius, the rest refused -- none wrong.
    within = 0
    for seed in range(10):
        rng = np.random.default_rng(1000 + seed)
        case = make_pole_scan(radius=rng.uniform(0.04, 0.15), length=rng.uniform(1.0, 3.0),
                              vertical=bool(seed % 2), points=int(rng.integers(1000, 3001)),
                              distance=rng.uniform(3.0, 10.0), rng=rng)
        network, errors = errors_of(case)
        if network is None:
            continue
        for e in errors:
            assert e["radius_mean"] <= 0.10, (seed, e)
        assert network.diagnostics["quality"] != "good"  # seen from one side: never claimed good
        within += 1
    assert within >= 9


def test_the_ground_under_a_one_sided_pole_is_no_tube():
    # The trust benchmark's pole of seed 65: a 1 cm grid leaves its ground in two layers, and a tube
    # touching that ground from below fits a strip of it within the grid's rounding -- a 2 m "tube"
    # meandering under the pole, which only the flatness of its points tells from one.
    network, errors = errors_of(random_case("pole", 65))
    assert network is not None and len(network.branches) == 1
    (e,) = errors
    assert e["spine_mean"] <= CLAIMS[e["quality"]]["spine"], e


def test_a_pipe_lying_a_radius_above_the_ground_is_no_canal():
    # The trust benchmark's pole of seed 1011: a 7 cm pole whose ground lies 8 cm under it.  A canal fit
    # swelled its radius to 12 cm to take in the ground, closed in on the pole's capped end, and so
    # fitted the points better than the pipe, which left both out: the model was off by 26 % of the
    # radius, and graded check.
    network, errors = errors_of(random_case("pole", 1011))
    assert network is not None and len(network.branches) == 1
    assert network.branches[0].kind == "pipe"
    (e,) = errors
    assert e["spine_mean"] <= CLAIMS[e["quality"]]["spine"], e
    assert e["radius_mean"] <= CLAIMS[e["quality"]]["radius"], e


@pytest.mark.parametrize("seed", [1004, 1022])
def test_a_pole_read_by_cross_sections_is_fitted_to_all_its_points(seed):
    # Poles of the trust benchmark's seeds from 1000 whose normals do not gather on a 1 cm grid: their
    # cross-sections were found at a quarter (1004) and a half (1022) of their points, and a fit to
    # those alone was off by 31 % and 10 % of the radius.
    network, errors = errors_of(random_case("pole", seed))
    assert network is not None and network.diagnostics["stop_rule"] == "sections"
    (e,) = errors
    assert e["spine_mean"] <= CLAIMS[e["quality"]]["spine"], e
    assert e["radius_mean"] <= CLAIMS[e["quality"]]["radius"], e


def test_a_further_pass_that_resolves_no_tube_leaves_the_first_whole():
    # The trust benchmark's trunk of seed 34: the first pass's own skeleton explains almost none of its
    # curved points (a flared trunk on the ground), the further pass none of its own.  Had the first been
    # trimmed to what it explains, as under a further pass that resolves tubes, no tube would be left.
    # Its fit, from a short stretch of thin set, grew on to the trunk's top once the network was settled
    # (it stopped a seventh of the way up, graded good); the pass beside that fit found no network, and
    # must leave the one without it.
    case = random_case("trunk", 34)
    network, errors = errors_of(case)
    assert network is not None and len(network.branches) == 1
    (e,) = errors
    assert e["quality"] == "good" and e["spine_mean"] <= CLAIMS["good"]["spine"], e
    assert curve_length(network.spine) >= 0.95 * curve_length(case.spine)


def test_the_crease_where_two_wide_pipes_touch_is_no_tube():
    # The trust benchmark's network of seed 1069 (``trust.py --family network --first 1000``): a bundle
    # of five pipes, two of radii 1.7 and 1.3 touching.  The crease below where they touch, seen from its
    # open side, was fitted as a pipe of radius 0.5 whose points were all theirs, graded check (one-sided)
    # and 138 % of a radius from the nearest true spine.
    case = random_case("network", 1069)
    network, errors = errors_of(case)
    assert network is not None and len(network.branches) == len(case.branches) == 5
    for e in errors:
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e


def test_the_gap_between_two_pipes_facing_surfaces_is_no_tube():
    # Two pipes of radii 1.26 and 0.43 with a gap of 0.24 between them (a random bundle, seed 127 of a
    # wider draw than the benchmark's): a pipe of radius 0.16 was fitted in the gap to the points of both
    # facing surfaces, which surround it over 273 degrees, graded check and 129 % of a radius from any
    # true spine.
    truth = make_network("bundle", n=36_648, noise=0.011018952322629373, rng=127, radii=(1.262, 0.429),
                         gap=0.5572732179543446)
    network, errors = errors_of(truth)
    assert network is not None and len(network.branches) == len(truth.branches) == 2
    for e in errors:
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e


def test_a_thin_pipe_whose_fit_ran_round_a_neighbours_end_is_found():
    # Five pipes side by side, touching (a random bundle, seed 150 of a wider draw than the benchmark's):
    # the fit of the r = 0.86 pipe grew round the end of the r = 1.24 pipe beside it and back along it,
    # and was left out as a hairpin; the r = 0.55 pipe's end then veered into its points, graded check
    # and 16 % of a radius off.  The folded fit is fitted again as its legs.
    truth = make_network("bundle", n=20_544, noise=0.02757490674477871, rng=150,
                         radii=(1.325, 1.937, 1.239, 0.861, 0.553), gap=0.0)
    network, errors = errors_of(truth)
    assert network is not None and len(network.branches) == len(truth.branches) == 5
    for e in errors:
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e


@pytest.mark.parametrize("n, noise, seed, radii", [
    (21_117, 0.021404128176283465, 44, (1.759, 0.355, 1.872)),
    (12_251, 0.009634123923089127, 181, (1.623, 0.512, 1.336, 1.337, 0.965))])
def test_a_thin_pipe_squeezed_between_two_wider_ones_it_touches_is_found(n, noise, seed, radii):
    # Pipes side by side, touching (random bundles of a wider draw than the benchmark's): the thin pipe
    # between two wider ones lies within a quarter of their radius of their surfaces all round, where the
    # paper's stages count its points as theirs; it was missing, and the scan graded good.  The points the
    # fits leave beside their surfaces are run through the stages again on their own.
    truth = make_network("bundle", n=n, noise=noise, rng=seed, radii=radii, gap=0.0)
    network, errors = errors_of(truth)
    assert network is not None and len(network.branches) == len(truth.branches)
    found = compare_network(network, truth)
    assert found["one_to_one"] and min(b["covered"] for b in found["branches"]) >= 0.95, found["branches"]
    for e in errors:
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e


def _random_bundle(seed: int):
    """Random bundle ``seed`` of benchmarks/bundles.py, drawn as there: its network and errors (as
    :func:`errors_of`), each branch held to its claim, and every pipe found whole."""
    rng = np.random.default_rng(seed)
    radii = tuple(rng.uniform(0.3, 2.0, int(rng.integers(2, 6))))
    truth = make_network("bundle", n=int(rng.integers(15_000, 40_001)), noise=rng.uniform(0.005, 0.03), rng=rng,
                         radii=radii, gap=0.0)
    network, errors = errors_of(truth)
    assert network is not None
    found = compare_network(network, truth)
    assert found["one_to_one"] and min(b["covered"] for b in found["branches"]) >= 0.95, found["branches"]
    for e in errors:
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e
    return network


@pytest.mark.parametrize("seed", [7, 106])
def test_pipes_whose_thin_sets_meet_where_they_touch_make_no_junction(seed):
    # Where two touching pipes' thin sets met, the skeleton read a junction, too near the pipes' ends to be
    # parted from afar; the wider pipe's fit stopped short of its end, the thinner one was cut in two, and
    # the junction drew a tee between them, every branch within its claim away from it.  Their fits run
    # parallel, a radius sum apart.
    assert not _random_bundle(seed).junctions


def test_a_fragment_of_a_tube_left_out_ahead_of_its_end_leaves_the_tube_its_points():
    # Random bundle 68: a 2-point skeleton branch on the r = 1.37 pipe's wall, a ninth of its radius, lay
    # just past the end of the pipe's thin set.  Its stand-in took the pipe's points about it, and the pipe's
    # end stopped a radius short of the pipe's (94 % covered); the stub itself was then left out as no tube.
    # The pipe is fitted again once the stub is gone, and grows to its end.
    assert len(_random_bundle(68).branches) == 3


def _oval_duct(a: float, b: float, seed: int, n: int = 20_000, length: float = 10.0) -> np.ndarray:
    """Points on a straight duct of elliptic section, semi-axes ``a`` and ``b``, spread evenly round it,
    with noise of 0.5 % of ``a``."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0.0, 2 * np.pi, 4 * n)
    speed = np.hypot(a * np.sin(angle), b * np.cos(angle))
    angle = angle[rng.uniform(0.0, speed.max(), 4 * n) < speed][:n]
    points = np.column_stack([a * np.cos(angle), b * np.sin(angle), rng.uniform(0.0, length, len(angle))])
    return points + rng.normal(0.0, 0.005 * a, points.shape)


@pytest.mark.parametrize("b, seed", [(0.8, 2), (0.7, 0)])
def test_an_oval_duct_is_no_round_tube(b, seed):
    # An oval duct (a = 1) has no round model: the one tube through its points is off its axis or its mean
    # radius by at least (a - b) / 2.  These draws were each fitted as the round tube of the oval's
    # tighter side, off the mean radius and the axis by more than their grade claims, graded check.
    # The surface goes on past the arc those points cover, and the scan is refused.
    with pytest.raises(canalsurf.ReconstructionError, match="oval or flattened"):
        canalsurf.reconstruct(_oval_duct(1.0, b, seed))


@pytest.mark.parametrize("against", ["floor", "wall"])
def test_a_pipe_against_a_floor_or_a_wall_is_kept(against):
    # The floor or wall beside a pipe lying on it goes on past the arc of the pipe seen, as an oval's
    # surface does -- but it is flat.
    rng = np.random.default_rng(0)
    density, length = 200.0, 10.0
    n = int(density * 2 * np.pi * length)
    angle, x = rng.uniform(0.0, 2 * np.pi, n), rng.uniform(0.0, length, n)
    pipe = np.column_stack([x, np.cos(angle), np.sin(angle) + 1.0])  # radius 1, on the plane z = 0
    m = int(density * (length + 4.0) * 8.0)  # as dense as the pipe
    plane = np.column_stack([rng.uniform(-2.0, length + 2.0, m), rng.uniform(-4.0, 4.0, m)])
    if against == "floor":
        pipe = pipe[pipe[:, 2] > 0.3]  # the underside hidden
        plane = np.column_stack([plane, np.zeros(len(plane))])
        plane = plane[np.abs(plane[:, 1]) > 0.5]
    else:
        pipe = pipe[pipe[:, 1] > -0.7]  # the back hidden
        plane = np.column_stack([plane[:, 0], np.full(len(plane), -1.0), plane[:, 1] + 1.0])
        plane = plane[np.abs(plane[:, 2] - 1.0) > 0.5]
    points = np.vstack([pipe, plane]) + rng.normal(0.0, 0.005, (len(pipe) + len(plane), 3))
    network = canalsurf.reconstruct(points)
    (branch,) = network.branches
    axis = branch.spine(np.linspace(0.1, 0.9, 50))
    assert np.abs(axis[:, 1:] - [0.0, 1.0]).max() < 0.02
    assert abs(branch.radius(0.5) - 1.0) < 0.01
