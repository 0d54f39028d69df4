"""Whole scans, not one tube: networks, several tubes and clutter, against their ground truth.

The bar (no parameters, normals estimated, 30,000 points, 2 % noise, every seed):

* the right number of branches and junctions, the right branches meeting at each junction;
* every branch, away from junctions (beyond 2.5 of its radii): spine mean <= 2 % of its radius, radius
  mean error <= 2 %, >= 95 % of its true spine within half a radius of the model;
* every junction within half the largest radius meeting there;
* >= 95 % of the clutter points labelled -1 and >= 95 % of the tube points on their right branch.
"""

from __future__ import annotations

import numpy as np
import pytest

import canalsurf
from canalsurf.metrics import compare_network
from canalsurf.synth import make_network

#: Networks and the seeds each is reconstructed on (benchmarks/networks.py runs more).
NETWORKS = ("y-vessel", "t-junction", "tree", "rack", "crossing", "floor-clutter", "scene")
SEEDS = (11, 12)
N_POINTS = 30_000
NOISE = 0.02
SPINE_MEAN, RADIUS_MEAN, COVERED = 0.02, 0.02, 0.95
JUNCTION_RADII = 0.5
LABELS_RIGHT = 0.95


@pytest.fixture(scope="module", params=[(name, seed) for name in NETWORKS for seed in SEEDS],
                ids=lambda p: f"{p[0]}-{p[1]}")
def case(request):
    name, seed = request.param
    truth = make_network(name, n=N_POINTS, noise=NOISE, rng=seed)
    network = canalsurf.reconstruct(truth.points)
    return truth, network, compare_network(network, truth)


def test_branches_and_junctions_are_the_true_ones(case):
    truth, network, c = case
    assert len(network.branches) == len(truth.branches)
    assert len(network.junctions) == len(truth.junctions)
    assert c["one_to_one"], c["matched"]
    assert len(network.components) == len(truth.components)
    for j in c["junctions"]:
        assert j["same_branches"]
        assert j["distance"] <= JUNCTION_RADII * j["largest_radius"], j


def test_every_branch_meets_the_accuracy_bar(case):
    truth, network, c = case
    for i, b in enumerate(c["branches"]):
        assert b["spine_mean"] <= SPINE_MEAN, (i, b)
        assert b["radius_mean"] <= RADIUS_MEAN, (i, b)
        assert b["covered"] >= COVERED, (i, b)


def test_points_are_labelled_with_their_branch_or_as_clutter(case):
    truth, network, c = case
    assert c["clutter_right"] >= LABELS_RIGHT
    assert c["tube_right"] >= LABELS_RIGHT
    share = float(np.mean(truth.label < 0))
    assert network.diagnostics["no_tube_share"] == pytest.approx(share, abs=0.03)


def test_branch_ends_and_junctions_agree(case):
    """Each junction lists exactly the branch ends that name it, and those ends lie on its point."""
    _, network, _ = case
    for j in network.junctions:
        for bid, end in j.ends:
            branch = network.branches[bid]
            assert branch.ends[end] == j.id
            r = float(branch.radius(float(end)))
            assert np.linalg.norm(branch.spine(float(end)) - j.point) <= 1e-3 * r
    named = sorted((b.id, e) for b in network.branches for e, j in enumerate(b.ends) if j is not None)
    listed = sorted(end for j in network.junctions for end in j.ends)
    assert named == listed


def test_a_network_is_not_refused_for_its_clutter():
    """Clutter is left out (labelled -1), not a reason to refuse the tube in it."""
    truth = make_network("floor-clutter", n=20_000, clutter=0.5, rng=3)
    network = canalsurf.reconstruct(truth.points)
    assert len(network.branches) == 1
    assert network.diagnostics["no_tube_share"] == pytest.approx(0.5, abs=0.05)


def test_clutter_whose_fit_folds_is_left_out_not_cut_into_legs():
    """A fit to the boxes of a floor-clutter scene (seed 200 of docs/networks.md) that folds, and whose
    points do not lie on it, is no tube: cut into legs, one was written as a pipe of radius 2.1."""
    truth = make_network("floor-clutter", n=30_000, noise=0.02, rng=200)
    network = canalsurf.reconstruct(truth.points)
    assert len(network.branches) == 1 and network.branches[0].mean_radius == pytest.approx(1.0, abs=0.01)


def _box_surface(n: int, rng) -> np.ndarray:
    """Points on the surface of the cube [-1, 1]^3 (equal area per face), 1 % noise."""
    face = rng.integers(0, 6, n)
    uv = rng.uniform(-1.0, 1.0, (n, 2))
    points = np.empty((n, 3))
    axis, sign = face // 2, np.where(face % 2, 1.0, -1.0)
    for a in range(3):
        others = [b for b in range(3) if b != a]
        sel = axis == a
        points[sel, a] = sign[sel]
        points[np.ix_(sel, others)] = uv[sel]
    return points + rng.normal(0.0, 0.01, (n, 3))


@pytest.mark.parametrize("seed", [1, 2])
def test_a_box_is_not_a_tube(seed):
    with pytest.raises(canalsurf.ReconstructionError, match="not a tube|no part of the cloud is a tube"):
        canalsurf.reconstruct(_box_surface(5000, np.random.default_rng(seed)))


def test_spines_continued_into_a_junction_do_not_hook():
    # A branch whose fitted end ran past its junction was continued by an arc that turned round to
    # reach it: a hook with r x curvature of about 8000 on a branch graded good.  Ends are now cut back
    # to their point nearest the junction, and a folded branch is never written.
    from canalsurf.quality import fold

    network = canalsurf.reconstruct(make_network("tree", n=20000, noise=0.01, rng=1).points)
    assert len(network.branches) == 7
    for b in network.branches:
        assert fold(b.spine, b.radius, b.closed) == "", b.id


@pytest.mark.parametrize("seed", [202, 204, 205, 207])
def test_branches_are_fitted_about_the_junction_their_fits_place(seed, caplog):
    """On these trees (30,000 points, 2 % noise) the thin set's fork lies up a fork, radii from the true
    junction: the stem above it left out radii of its points there, and the fit's taper ran off towards
    them (radius errors of 0.18 - 0.24 % r).  The junction placed from the fitted ends moves, and the
    branches meeting there are fitted again about it: every branch's radius within 0.15 % r."""
    truth = make_network("tree", n=N_POINTS, noise=NOISE, rng=seed)
    with caplog.at_level("INFO", logger="canalsurf"):
        network = canalsurf.reconstruct(truth.points)
    assert "junctions placed from the fits moved" in caplog.text
    c = compare_network(network, truth)
    assert c["one_to_one"]
    for i, b in enumerate(c["branches"]):
        assert b["radius_mean"] <= 0.0015, (i, b)
        assert b["spine_mean"] <= 0.005, (i, b)


def test_a_free_end_is_not_cut_short_where_the_thin_set_stops():
    """On this scan (the piping network, seed 10, 0.5 % noise) the thin set of an NPS 2 pipe stops 2.3 radii
    short of its free end, farther than the points first taken for its fit reach: the fit grows to the edge
    of its points, takes them again about itself and goes on.  Every free end within a tenth of a radius."""
    truth = make_network("piping", n=40_000, noise=0.005, rng=10)
    network = canalsurf.reconstruct(truth.points)
    true_ends = [(b.spine(float(e)), float(b.radius(float(e)))) for b in truth.branches for e in (0, 1)
                 if b.ends[e] is None]
    model_ends = np.array([b.spine(float(e)) for b in network.branches for e in (0, 1) if b.ends[e] is None])
    assert len(model_ends) == len(true_ends)
    for end, r in true_ends:
        assert np.linalg.norm(model_ends - end, axis=1).min() <= 0.1 * r


def test_branches_fitted_in_parallel_are_the_ones_fitted_one_by_one(monkeypatch):
    """A scene's branches are fitted in forked processes, each on its own task: the model is the same,
    whether many branches or a large scan sends them there."""
    import concurrent.futures

    from canalsurf import pipeline

    pools = []

    class Recorded(concurrent.futures.ProcessPoolExecutor):
        def __init__(self, *args, **kwargs):
            pools.append(kwargs["max_workers"])
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", Recorded)
    monkeypatch.setattr(pipeline, "_cores", lambda: 2)
    truth = make_network("rack", n=N_POINTS, noise=NOISE, rng=SEEDS[0])
    monkeypatch.setattr(pipeline, "PARALLEL_BRANCHES", 10**9)
    monkeypatch.setattr(pipeline, "PARALLEL_POINTS", 10**12)
    one_by_one = canalsurf.reconstruct(truth.points)
    assert len(one_by_one.branches) == len(truth.branches) >= 2 and not pools
    for many, large in ((2, 10**12), (10**9, 0)):
        monkeypatch.setattr(pipeline, "PARALLEL_BRANCHES", many)
        monkeypatch.setattr(pipeline, "PARALLEL_POINTS", large)
        pools.clear()
        assert canalsurf.reconstruct(truth.points).to_dict() == one_by_one.to_dict()
        assert pools and set(pools) == {2}


def test_a_plant_of_tubes_four_times_apart_in_radius_is_found_whole():
    """The plant (23 tubes of radii 0.5 - 2 on a floor, with boxes): one scale cannot serve it -- at the
    median radius the thinnest tubes read as flat -- so what the first pass leaves is run again at a
    finer one.  Every tube and junction is found, each to the networks' bar."""
    truth = make_network("plant", n=300_000, rng=SEEDS[0])
    network = canalsurf.reconstruct(truth.points)
    c = compare_network(network, truth)
    assert len(network.diagnostics["scale_radii"]) >= 2
    assert len(network.junctions) == len(truth.junctions)
    for i, b in enumerate(c["branches"]):
        assert b["covered"] >= COVERED, (i, b)
        assert b["spine_mean"] <= SPINE_MEAN, (i, b)
        assert b["radius_mean"] <= RADIUS_MEAN, (i, b)


#: Share of a sparse plant's tubes found (covered by a branch), at the least: with about 8,000 points per
#: tube, and with 2,000 - 2,500.
FOUND_SHARE, FOUND_SHARE_SPARSEST = 0.95, 0.9


@pytest.mark.parametrize(("bays", "n", "seed"), [(2, 120_000, 5), (2, 100_000, 1), (2, 400_000, 0),
                                               (2, 400_000, 4), (2, 400_000, 6), (2, 400_000, 7),
                                               (2, 400_000, 8)])
def test_a_sparse_plant_writes_no_tube_outside_its_claim(bays, n, seed):
    """Plants scanned sparsely for their size, where wrong tubes were written: a tube six times wider
    than the pipes (fitted to the tops of a rack, graded check), one branch turning back between two
    pipes that end side by side (graded good), canals from a pipe's end through clutter (poor, half a
    radius and more off; seed 0), and canals through clutter that misfit twenty times the other tubes,
    accepted against a scan noise the sparse subset inflated (seed 6); a wavy pipe graded good against
    that noise (seed 7: the noise is now taken about quadrics, on the whole scan); a pipe whose end grew
    across a gap into thinner tubes' points (seed 8).  Every tube written is within what its quality
    claims, and most tubes are found: a first subset too sparse for the scene is drawn denser before its
    normals are given up for cross-sections (which found 2 - 5 of these 46 tubes), and a further pass may
    run at the scene's own scale after a finer one (seed 4: three rack pipes of radius 0.7 - 1.6 that the
    first pass missed were left, 43 found)."""
    from canalsurf.metrics import model_error
    from canalsurf.quality import CLAIMS

    truth = make_network("plant", n=n, size=bays, rng=seed)
    network = canalsurf.reconstruct(truth.points)
    for e in model_error(network, truth.branches, truth.junctions):
        claim = CLAIMS[e["quality"]]
        assert e["spine_mean"] <= claim["spine"] and e["radius_mean"] <= claim["radius"], e
    found = sum(b["covered"] >= COVERED for b in compare_network(network, truth)["branches"])
    share = FOUND_SHARE if n / len(truth.branches) > 5_000 else FOUND_SHARE_SPARSEST
    assert found >= share * len(truth.branches), found


def test_a_link_across_the_ends_of_two_pipes_is_no_tube():
    """Two rack pipes ending side by side, a short branch across their ends (their end caps thinned to a
    link), a T's side branch, and a pipe found twice (by two passes): only the link, whose spine lies
    inside the pipes, and the copy with fewer points are no tubes."""
    from types import SimpleNamespace

    from canalsurf.pipeline import _inside_others
    from canalsurf.skeleton import Skeleton, SkeletonBranch
    from canalsurf.spine import constant_spline, pspline_fit

    def branch(a, b, r, ends=(None, None), n_points=1000):
        u = np.linspace(0.0, 1.0, 50)
        spine = pspline_fit(u, np.asarray(a, float) + u[:, None] * (np.subtract(b, a)), n_segments=4)
        return (SimpleNamespace(spine=spine, radius=constant_spline(r), eq6=r, points=np.zeros((n_points, 3))),
                SkeletonBranch(np.array([a, b], float), np.ones(2), np.full(2, r), ends))

    parts = [branch([0, 0, 0], [0, 20, 0], 1.3), branch([2.55, 0, 0], [2.55, 20, 0], 0.5),
             branch([0, 0, 0], [2.55, 0, 0], 0.9),
             # a T: a main pipe in two halves and a side branch from their junction at (10, 10, 8)
             branch([0, 10, 8], [10, 10, 8], 1.2, (None, 0)), branch([10, 10, 8], [20, 10, 8], 1.2, (0, None)),
             branch([10, 10, 8], [10, 16, 8], 0.7, (0, None)),
             branch([0, 0, 20], [0, 20, 20], 1.0, n_points=900), branch([0.02, 0, 20], [0.02, 20, 20], 1.0)]
    fits = [f for f, _ in parts]
    skel = Skeleton([b for _, b in parts], np.array([[10.0, 10.0, 8.0]]), 0.1)
    assert sorted(_inside_others(fits, skel)) == [2, 6]


def test_of_a_pipe_found_twice_the_copy_with_more_points_stays_though_the_other_wanders_off():
    """A pipe found twice: one copy follows it end to end on 800 points; the other, on 460, leaves it for
    its last third (a one-sided arc of few points at a far end does not pin a circle) and so lies less
    inside the first than the first lies inside it.  The copy with more points stays: dropping the more
    inside one kept the copy that wandered off (a pole scanned from one side, turned by 30 degrees: its
    model 28 % r off the truth, beyond what its grade claims)."""
    from types import SimpleNamespace

    from canalsurf.pipeline import _inside_others
    from canalsurf.skeleton import Skeleton, SkeletonBranch
    from canalsurf.spine import constant_spline, pspline_fit

    u = np.linspace(0.0, 1.0, 60)
    x = 20.0 * u
    off = np.column_stack([x, 3.0 * np.clip((x - 13.0) / 7.0, 0.0, None) ** 2, 0 * x])
    copies = [np.column_stack([x, 0 * x, 0 * x]), off]
    fits = [SimpleNamespace(spine=pspline_fit(u, c, n_segments=6), radius=constant_spline(1.0), eq6=1.0,
                            points=np.zeros((n, 3))) for c, n in zip(copies, (800, 460))]
    skel = Skeleton([SkeletonBranch(c, np.ones(len(c)), np.ones(len(c)), (None, None)) for c in copies],
                    np.empty((0, 3)), 0.1)
    assert _inside_others(fits, skel) == [1]


def test_a_piece_of_a_pipe_found_twice_keeps_its_part_outside_with_the_junction_it_leaves_open():
    """A rack pipe of radius 0.6 found as two pieces (a 10-million-point plant's pipe so): the long one from
    x = 4 on, and one from the pipe's start, x = 0, to a false junction at x = 8, its last 4 inside the
    long one.  The first piece keeps its part outside, x = 0 to 3.4, with the end it cut off open; dropped
    whole, it lost 3.4 of the pipe.  A piece with less than four radii outside is still dropped."""
    from types import SimpleNamespace

    from canalsurf.pipeline import OWN_PART_RADII, _own_part
    from canalsurf.skeleton import SkeletonBranch
    from canalsurf.spine import constant_spline, pspline_fit

    u = np.linspace(0.0, 1.0, 50)
    long = SimpleNamespace(spine=pspline_fit(u, np.column_stack([4.0 + 20.0 * u, 0 * u, 0 * u]), n_segments=4),
                           radius=constant_spline(0.6))
    x = np.linspace(0.0, 8.0, 81)
    piece = SkeletonBranch(np.column_stack([x, 0 * x, 0 * x]), np.ones(81), np.full(81, 0.6), (None, 0))
    part = _own_part([long], piece, 0.6)
    assert part is not None and part.ends == (None, None)
    assert part.points[0, 0] == 0.0 and part.points[-1, 0] == pytest.approx(4.0 - 0.6, abs=0.15)
    short = SkeletonBranch(piece.points[20:], piece.weights[20:], piece.radius[20:], (None, 0))
    assert 4.0 - 0.6 - short.points[0, 0] < OWN_PART_RADII * 0.6  # its part outside, x = 2 to 3.4
    assert _own_part([long], short, 0.6) is None


def test_a_reducer_in_a_piping_scan_is_fitted_as_a_canal_whole():
    """Of the piping network (seed 201, 2 % noise) the 4" x 2" reducer: a pipe fit takes its wide half and
    leaves the narrow half out as outliers, so whether a canal is worth fitting is judged on every point
    (clipped), not on the pipe's inliers -- which once left it a pipe over half of it, 71 % r off."""
    from canalsurf.metrics import compare_network

    truth = make_network("piping", n=30_000, noise=0.02, rng=201)
    network = canalsurf.reconstruct(truth.points)
    assert sum(b.kind == "canal" for b in network.branches) == 1
    for b in compare_network(network, truth)["branches"]:
        assert b["covered"] >= COVERED and b["spine_mean"] <= SPINE_MEAN, b


def test_the_first_estimate_takes_the_points_past_a_thin_set_that_ends_with_scattered_radii():
    """A tube of radius 1 from z = 0 to 8 whose thin set stops at z = 6, its last r_i scattered (0.55, then
    1.25): the estimate's radius function slopes steeply there.  Continued by that slope, its stand-in
    widened to about twice the radius a radius past the end and took none of the tube's points there
    (a short stub of a 2-million-point plant was lost so); held at its end value, it takes them."""
    from canalsurf.pipeline import ASSIGN_END_RADII, _assign, _Estimates, _Fittable, _first_guess
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    z = np.linspace(0.0, 6.0, 13)
    radius = np.ones_like(z)
    radius[-2:] = 0.55, 1.25
    weights = np.full(len(z), 4.0)
    weights[-1] = 13.0
    branch = SkeletonBranch(np.column_stack([np.zeros_like(z), np.zeros_like(z), z]), weights, radius, (None, None))
    skel = Skeleton([branch], np.empty((0, 3)), 0.5)
    rng = np.random.default_rng(0)
    angle, height = rng.uniform(0.0, 2 * np.pi, 20_000), rng.uniform(0.0, 8.0, 20_000)
    points = np.column_stack([np.cos(angle), np.sin(angle), height])
    guess = _first_guess(branch)
    assert guess["radius"](1.0) > 1.1  # the slope the test is about
    taken = _assign(points, _Estimates(skel, {}), _Fittable(points, np.ones(len(points), bool)), 0)
    past = (points[:, 2] > 6.0) & (points[:, 2] < 6.0 + ASSIGN_END_RADII)
    assert np.isin(np.flatnonzero(past), taken).mean() > 0.95


def test_a_junction_of_other_tubes_takes_no_points_of_a_pipe_that_passes_it():
    """A rack pipe of radius 0.5 beside a neighbour of radius 1.3 (surfaces 0.75 apart) whose skeleton meets a
    fat branch at a junction near the pipe's end (a coarse pass's bridge across a rack of a plant so): the
    junction's reach takes 3.15 round it.  Its own branches' points there go to none, but the pipe, which
    does not meet there, keeps its own; once they went to none, its fit stopped 3.3 short of its end."""
    from canalsurf.pipeline import JUNCTION_EXCLUSION_RADII, _assign, _Estimates, _Fittable
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    def branch(a, b, r, ends=(None, None)):
        pts = np.linspace(a, b, 40)
        return SkeletonBranch(pts, np.full(40, 4.0), np.full(40, r), ends)

    def cylinder(x, r, rng):
        angle, y = rng.uniform(0.0, 2 * np.pi, 20_000), rng.uniform(0.0, 20.0, 20_000)
        return np.column_stack([x + r * np.cos(angle), y, r * np.sin(angle)])

    junction = np.array([2.55, 18.0, 0.0])
    branches = [branch([0.0, 0.0, 0.0], [0.0, 20.0, 0.0], 0.5),
                branch([2.55, 0.0, 0.0], junction, 1.3, (None, 0)),
                branch(junction, [2.55, 20.0, 0.0], 1.3, (0, None)),
                branch(junction, [6.0, 18.0, 0.0], 2.1, (0, None))]
    skel = Skeleton(branches, junction[None], 0.5)
    rng = np.random.default_rng(0)
    points = np.vstack([cylinder(0.0, 0.5, rng), cylinder(2.55, 1.3, rng)])
    estimates = _Estimates(skel, {})
    reach = estimates.junction_reach[0]
    assert reach == pytest.approx(JUNCTION_EXCLUSION_RADII * 2.1, rel=0.05)
    fittable = _Fittable(points, np.ones(len(points), bool))
    near = np.linalg.norm(points - junction, axis=1) < reach
    pipe = np.flatnonzero(near[:20_000])
    assert len(pipe) > 500  # the pipe's points the junction reaches
    assert np.isin(pipe, _assign(points, estimates, fittable, 0)).mean() > 0.95
    for i in (1, 2):
        assert not np.isin(np.flatnonzero(near), _assign(points, estimates, fittable, i)).any()


def test_estimates_are_made_once_per_branch_and_open_ends():
    """A skeleton remade with a branch dropped keeps the others' estimates, renumbered; a branch whose end
    was opened (the same arrays) gets a new one, continued past that end; each is what making it afresh
    gives."""
    from dataclasses import replace

    from canalsurf.pipeline import _Estimates
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    def leg(a, b, r, ends):
        return SkeletonBranch(np.linspace(a, b, 40), np.full(40, 4.0), np.full(40, r), ends)

    junction = np.array([10.0, 0.0, 0.0])
    branches = [leg([0.0, 0.0, 0.0], junction, 1.0, (None, 0)), leg(junction, [20.0, 0.0, 0.0], 1.0, (0, None)),
                leg(junction, [10.0, 8.0, 0.0], 0.6, (0, None))]
    made = {}
    first = _Estimates(Skeleton(branches, junction[None], 0.5), made)
    dropped = Skeleton([branches[0], branches[2]], junction[None], 0.5)
    opened = Skeleton([replace(branches[0], ends=(None, None)), branches[1]], junction[None], 0.5)
    t = np.linspace(0.0, 1.0, 50)
    # (skeleton, {its branch: the first skeleton's branch whose estimate it keeps})
    for skel, kept in ((dropped, {0: 0, 1: 2}), (opened, {1: 1})):
        again, fresh = _Estimates(skel, made), _Estimates(skel, {})
        for i in range(len(skel.branches)):
            model, box, _, band = again.model(i)
            assert model.id == i
            assert (model.spine is first.model(kept.get(i, i))[0].spine) == (i in kept)
            np.testing.assert_array_equal(model.spine(t), fresh.model(i)[0].spine(t))
            np.testing.assert_array_equal(box, fresh.model(i)[1])
            assert band == fresh.model(i)[3]
    assert opened.branches[0].points is branches[0].points
    assert _Estimates(opened, made).model(0)[1][1, 0] > first.model(0)[1][1, 0]  # continued past x = 10


def test_a_branch_takes_the_points_it_would_take_were_its_whole_box_classified():
    """Two pipes side by side along a diagonal (radii 0.5 and 1.3, axes 2.55 apart), their points scattered
    by up to 0.35 off the surface, past the thin one's assign cut (0.25): the box of the thin one's band
    holds many of the fat one's points.  Only the points within the band's reach of its spine are
    classified for it; it must take exactly those that classifying all of its box gives it."""
    from canalsurf.network import classify_points
    from canalsurf.pipeline import ASSIGN_RADII, _assign, _Estimates, _Fittable
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    along, across = np.array([1.0, 1.0, 0.0]) / np.sqrt(2), np.array([1.0, -1.0, 0.0]) / np.sqrt(2)
    up = np.array([0.0, 0.0, 1.0])
    rng = np.random.default_rng(0)
    branches, clouds = [], []
    for offset, r in ((0.0, 0.5), (2.55, 1.3)):
        axis = offset * across + np.linspace(0.0, 20.0, 40)[:, None] * along
        branches.append(SkeletonBranch(axis, np.full(40, 4.0), np.full(40, r), (None, None)))
        angle, s = rng.uniform(0.0, 2 * np.pi, 20_000), rng.uniform(0.0, 20.0, 20_000)
        rho = r + rng.uniform(-0.35, 0.35, 20_000)
        clouds.append(offset * across + s[:, None] * along
                      + rho[:, None] * (np.cos(angle)[:, None] * across + np.sin(angle)[:, None] * up))
    points = np.vstack(clouds)
    estimates = _Estimates(Skeleton(branches, np.empty((0, 3)), 0.5), {})
    fittable = _Fittable(points, np.ones(len(points), bool))
    box = fittable.in_box(points, estimates.model(0)[1])
    assert (box >= 20_000).sum() > 5_000  # the fat pipe's points in the thin one's box
    label, _ = classify_points(points[box], [estimates.model(j)[0] for j in (0, 1)],
                               cut=[ASSIGN_RADII * g["eq6"] for g in estimates.guesses], far=False)
    taken = _assign(points, estimates, fittable, 0)
    assert len(taken) > 12_000
    np.testing.assert_array_equal(taken, box[label == 0])



def test_the_fittable_points_in_a_box_are_those_a_test_of_every_point_finds():
    """Boxes long along each axis in turn, and one round the whole cloud: the fittable points inside,
    found from the box's thinnest slab, are exactly those found by testing every point, in order."""
    from canalsurf.pipeline import _Fittable

    rng = np.random.default_rng(3)
    points = rng.uniform(0.0, [40.0, 10.0, 5.0], (20_000, 3))
    curved = rng.random(len(points)) < 0.7
    fittable = _Fittable(points, curved)
    centre = np.array([20.0, 5.0, 2.5])
    for half in ([30.0, 1.0, 1.0], [2.0, 8.0, 0.5], [1.0, 2.0, 9.0], [50.0, 50.0, 50.0]):
        box = np.array([centre - half, centre + half])
        inside = np.flatnonzero(curved & np.all((points >= box[0]) & (points <= box[1]), axis=1))
        assert len(inside) > 100
        np.testing.assert_array_equal(fittable.in_box(points, box), inside)

def test_a_fit_grows_past_an_end_where_the_thin_set_strays_sideways():
    """A tube of radius 1 from z = 0 to 8 whose thin set stops at z = 6 with its last vertices straying
    sideways and back (a 10-million-point plant's pipe so): the first estimate hooks there, its end tangent
    turned back.  The fit, straight on past the hook, must count as grown and take the points beyond it to
    the tube's end -- measured along the hook, it had not grown, and the tube stopped 1.2 radii short."""
    from canalsurf.pipeline import _Estimates, _Fittable, _first_guess, _fit_one
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    z = np.linspace(0.0, 6.0, 13)
    axis = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
    stray = np.array([[0.8, 0.3, 5.9], [1.0, 0.1, 5.95], [1.2, -0.7, 6.4]])
    branch = SkeletonBranch(np.vstack([axis, stray]), np.full(16, 4.0), np.r_[np.ones(13), 0.5, 0.2, 1.3],
                            (None, None))
    skel = Skeleton([branch], np.empty((0, 3)), 0.5)
    rng = np.random.default_rng(0)
    angle, height = rng.uniform(0.0, 2 * np.pi, 20_000), rng.uniform(0.0, 8.0, 20_000)
    points = np.column_stack([np.cos(angle), np.sin(angle), height]) + rng.normal(0.0, 0.005, (20_000, 3))
    guess = _first_guess(branch)
    tangent = guess["spine"].derivative()(1.0)
    assert tangent[2] < 0.5 * np.linalg.norm(tangent)  # the hook the test is about
    job = {"points": points, "estimates": _Estimates(skel, {}),
           "fittable": _Fittable(points, np.ones(20_000, bool)),
           "kappa": np.ones(20_000), "kind": "pipe", "refine": True, "noise": 0.005, "quantum": 0.0, "loose": None}
    fit = _fit_one(0, job)
    assert not isinstance(fit, str), fit
    ends = fit.spine(np.array([0.0, 1.0]))
    assert abs(ends[:, 2].max() - 8.0) < 0.1 and abs(ends[:, 2].min()) < 0.1, ends
    assert np.abs(fit.spine(np.linspace(0.0, 1.0, 50))[:, :2]).max() < 0.02


def _tube_along_z(thin_to: float, length: float, n: int):
    """A skeleton branch along the z axis from 0 to ``thin_to`` (vertices half a radius apart), and ``n``
    points on the tube of radius 1 about it from z = 0 to ``length``, with noise of 0.005."""
    from canalsurf.skeleton import SkeletonBranch

    z = np.linspace(0.0, thin_to, int(round(2 * thin_to)) + 1)
    branch = SkeletonBranch(np.column_stack([np.zeros_like(z), np.zeros_like(z), z]), np.full(len(z), 4.0),
                            np.ones(len(z)), (None, None))
    rng = np.random.default_rng(0)
    angle, height = rng.uniform(0.0, 2 * np.pi, n), rng.uniform(0.0, length, n)
    return branch, np.column_stack([np.cos(angle), np.sin(angle), height]) + rng.normal(0.0, 0.005, (n, 3))


def test_a_fit_grows_on_to_the_end_of_a_tube_its_thin_set_covers_a_tenth_of():
    """A tube of radius 1 from z = 0 to 30 whose thin set stops at z = 3 (a thin pipe's thin set, tangled
    where it touched its wider neighbours, stopped so in a random bundle of touching pipes).  Each round of
    growth takes the points a radius past the fit's end: after MAX_GROW_ROUNDS the fit stopped near z = 12,
    18 radii short of the tube's end with nothing to show it.  Once the network is settled, it grows on."""
    from canalsurf.pipeline import _fit_network
    from canalsurf.skeleton import Skeleton

    branch, points = _tube_along_z(3.0, 30.0, 30_000)
    _, (fit,) = _fit_network(points, Skeleton([branch], np.empty((0, 3)), 0.5), kind="pipe", refine=True,
                             noise=0.005, quantum=0.0, curved=np.ones(30_000, bool), kappa=np.ones(30_000))
    ends = np.sort(fit.spine(np.array([0.0, 1.0]))[:, 2])
    assert abs(ends[0]) < 0.1 and abs(ends[1] - 30.0) < 0.1, ends
    assert np.abs(fit.spine(np.linspace(0.0, 1.0, 50))[:, :2]).max() < 0.02


def test_a_fit_whose_growth_fails_keeps_the_tube_it_grew_from(monkeypatch):
    """A tube of radius 1 from z = 0 to 8 whose thin set stops at z = 5: its open end grows.  Where a
    round of growth cannot be fitted (here every fit to more points than the first; on a tree scan, a
    stem's end grown into the fork, whose fit shrank to a point), the branch keeps the fit it had: the
    failed round made it no less a tube.  It was dropped, and the stem's foot with it."""
    import canalsurf.pipeline as pipeline
    from canalsurf.errors import ReconstructionError
    from canalsurf.pipeline import _Estimates, _Fittable, _first_guess, _fit_one
    from canalsurf.skeleton import Skeleton

    branch, points = _tube_along_z(5.0, 8.0, 20_000)
    fit_branch, sizes = pipeline._fit_branch, []

    def failing_to_grow(pts, guess, **kwargs):
        sizes.append(len(pts))
        if len(pts) > sizes[0]:
            raise ReconstructionError("the fitted spine shrank to a point: the points do not follow a curve")
        return fit_branch(pts, guess, **kwargs)

    monkeypatch.setattr(pipeline, "_fit_branch", failing_to_grow)
    job = {"points": points, "estimates": _Estimates(Skeleton([branch], np.empty((0, 3)), 0.5), {}),
           "fittable": _Fittable(points, np.ones(20_000, bool)),
           "kappa": np.ones(20_000), "kind": "pipe", "refine": True, "noise": 0.005, "quantum": 0.0, "loose": None}
    fit = _fit_one(0, job)
    assert len(sizes) > 1  # it tried to grow
    assert not isinstance(fit, str), fit
    assert len(fit.points) == sizes[0]
    ends = np.sort(fit.spine(np.array([0.0, 1.0]))[:, 2])
    assert abs(ends[0]) < 0.1 and 5.0 < ends[1] < 8.0, ends


def test_a_junction_the_thin_set_made_between_two_tubes_side_by_side_is_opened_and_each_tube_is_one_branch():
    """Two pipes side by side (radii 0.8 and 0.5, their surfaces 0.75 apart) whose thin sets met for a stretch:
    the skeleton joins them at a junction on the thinner one's axis, from which two branches cross over to
    the other's (a 10-million-point plant's rack so).  Each fit runs along its own tube, past that junction;
    joined there, the one that ran past it folded and was left out, and neither tube was found whole."""
    from canalsurf.pipeline import _fit_network
    from canalsurf.skeleton import Skeleton, SkeletonBranch

    def line(a, b, n):
        return np.linspace(a, b, n)

    junction = np.array([9.3, 2.05, 0.0])
    paths = [(np.vstack([line(junction, [12.0, 0.3, 0.0], 7), line([12.5, 0.0, 0.0], [19.8, 0.0, 0.0], 15)]), (0, None)),
             (np.vstack([line(junction, [7.0, 0.3, 0.0], 6), line([6.5, 0.0, 0.0], [0.2, 0.0, 0.0], 13)]), (0, None)),
             (line(junction, [11.7, 2.05, 0.0], 6), (0, None)),
             (line([12.5, 2.05, 0.0], [19.8, 2.05, 0.0], 15), (None, None)),
             (line([0.2, 2.05, 0.0], [8.0, 2.05, 0.0], 16), (None, None))]
    radius = lambda p: np.where(p[:, 1] > 1.0, 0.5, 0.8)  # noqa: E731
    skel = Skeleton([SkeletonBranch(p, np.full(len(p), 4.0), radius(p), ends) for p, ends in paths],
                    junction[None], 0.5)
    rng = np.random.default_rng(0)
    pts = []
    for y, r in ((0.0, 0.8), (2.05, 0.5)):
        angle, x = rng.uniform(0.0, 2 * np.pi, 20_000), rng.uniform(0.0, 20.0, 20_000)
        pts.append(np.column_stack([x, y + r * np.cos(angle), r * np.sin(angle)]))
    points = np.vstack(pts) + rng.normal(0.0, 0.005, (40_000, 3))
    skel, fits = _fit_network(points, skel, kind="pipe", refine=True, noise=0.005, quantum=0.0,
                              curved=np.ones(40_000, bool), kappa=np.full(40_000, 1.5))
    assert len(skel.junctions) == 0 and all(b.ends == (None, None) for b in skel.branches)
    for y, r in ((0.0, 0.8), (2.05, 0.5)):
        own = [f for f in fits if abs(float(f.spine(0.5)[1]) - y) < r]
        assert len(own) == 1, [f.spine(np.array([0.0, 1.0])).round(2).tolist() for f in fits]
        along = own[0].spine(np.linspace(0.0, 1.0, 200))
        assert along[:, 0].min() < 0.1 and along[:, 0].max() > 19.9
        assert np.abs(along[:, 1:] - [y, 0.0]).max() < 0.02


@pytest.mark.parametrize(("radii", "n"), [((1.0, 1.0), 5_000), ((1.0, 1.0), 10_000), ((1.0, 0.5), 10_000),
                                          ((1.0, 0.3), 8_000), ((1.0, 1.0, 1.0), 5_000),
                                          ((1.0, 1.0, 1.0), 10_000), ((1.0, 0.6, 0.8), 5_000),
                                          ((1.0, 1.0, 1.0, 1.0), 6_000)])
def test_every_one_of_touching_pipes_is_found(radii, n):
    """Pipes that touch along their length.  The spanning tree of the normals crosses where they touch,
    so the normals face into one of them (the middle one of three in two halves), and its points shrink
    outward to nothing; too few are left for a further pass, or none is drawn from a scan this small.
    One runs since a tube is left that the normals faced into, with normals of its own (and of four in
    a row, that pass may face into the next)."""
    truth = make_network("bundle", n=n, noise=NOISE, rng=3, radii=radii)
    network = canalsurf.reconstruct(truth.points)
    c = compare_network(network, truth)
    assert len(network.branches) == len(radii) and c["one_to_one"]
    for b in c["branches"]:
        assert b["spine_mean"] <= SPINE_MEAN and b["radius_mean"] <= RADIUS_MEAN and b["covered"] >= COVERED, b


@pytest.mark.parametrize(("radii", "gap"), [((0.5, 1.0, 0.5), 0.5), ((0.5, 0.5, 1.0, 0.5), 2.0)])
def test_a_pipe_twice_as_wide_as_the_pipes_around_it_is_found(radii, gap):
    """The first pass works at the median radius, the thinner pipes': it stops shrinking once they have
    met, before the wider pipe's sides do.  A further pass finds it, though wider than the first scale
    (a pass was once refused for that, as clutter)."""
    truth = make_network("bundle", n=30_000, noise=NOISE, rng=3, radii=radii, gap=gap)
    network = canalsurf.reconstruct(truth.points)
    c = compare_network(network, truth)
    assert len(network.branches) == len(radii) and c["one_to_one"]
    for b in c["branches"]:
        assert b["spine_mean"] <= SPINE_MEAN and b["radius_mean"] <= RADIUS_MEAN and b["covered"] >= COVERED, b


@pytest.mark.parametrize("seed", [200, 202])
def test_touching_pipes_leave_no_false_tube_past_a_skeleton_end(seed):
    """A pipe's points past the end of its skeleton, left to a later pass and faced into there, are no
    tube to look for: a further pass made a false one of them (seed 202)."""
    truth = make_network("bundle", n=30_000, noise=NOISE, rng=seed)
    network = canalsurf.reconstruct(truth.points)
    assert len(network.branches) == 2 and compare_network(network, truth)["one_to_one"]


@pytest.mark.parametrize("seed", [203, 204])
def test_touching_pipes_are_not_drawn_towards_each_other(seed):
    """Where two pipes touch, each one's points lie within the other's outlier cut: a fit that took in
    its neighbour's was drawn towards it by 0.18 - 0.20 % of its radius and swelled by 0.1 % (seeds 203,
    204), 4 - 5 times what the best fit to the pipe's own points is off.  Both fits leave the line of
    contact out."""
    truth = make_network("bundle", n=30_000, noise=NOISE, rng=seed)
    network = canalsurf.reconstruct(truth.points)
    assert len(network.branches) == 2
    axes = [b.spine(np.linspace(0.0, 1.0, 2)) for b in truth.branches]
    for k, (a, b) in enumerate(axes):
        along = (b - a) / np.linalg.norm(b - a)
        towards = axes[1 - k].mean(axis=0) - (a + b) / 2
        towards /= np.linalg.norm(towards)
        model = min(network.branches, key=lambda m: np.linalg.norm(m.spine(0.5) - (a + b) / 2))
        spine = model.spine(np.linspace(0.1, 0.9, 200)) - a
        offset = float(np.mean((spine - np.outer(spine @ along, along)) @ towards))
        r = float(truth.branches[k].radius(0.5))
        assert abs(offset) <= 7e-4 * r and abs(model.mean_radius - r) <= 4e-4 * r, (offset / r, model.mean_radius / r)


def test_a_thin_pipe_ending_beside_a_wide_one_it_touches_keeps_to_its_own_axis():
    """The end of a thin pipe (r = 0.61) between two wider ones followed the points of one of them into
    its tube, 24 % of its radius off on the mean: fitted again from its end continued straight, it
    keeps to its own."""
    truth = make_network("bundle", n=8142, noise=0.0116, rng=42, radii=(0.933, 1.279, 1.57, 0.614, 1.294))
    network = canalsurf.reconstruct(truth.points)
    c = compare_network(network, truth)
    assert len(network.branches) == 5 and c["one_to_one"]
    for b in c["branches"]:
        assert b["spine_mean"] <= SPINE_MEAN and b["radius_mean"] <= RADIUS_MEAN and b["covered"] >= COVERED, b


def test_pieces_of_a_pipe_are_not_joined_through_its_neighbour():
    """Two touching pipes of one radius: the fit of one's two pieces joined took to the other's points
    and dipped onto its axis for 4.5 radii (10.6 % of its radius off on the mean, more than ``check``
    claims).  A joined fit that leaves the tube of one of its pieces is refused."""
    truth = make_network("bundle", n=32854, noise=0.022998999021212337, rng=118,
                         radii=(1.763, 0.316, 0.316, 0.511, 1.316))
    network = canalsurf.reconstruct(truth.points)
    c = compare_network(network, truth)
    assert len(network.branches) == 5 and c["one_to_one"]
    for b in c["branches"]:
        assert b["spine_mean"] <= SPINE_MEAN and b["radius_mean"] <= RADIUS_MEAN and b["covered"] >= COVERED, b
