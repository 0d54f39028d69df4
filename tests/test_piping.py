"""Tests of canalsurf.piping: straights, elbows, tees and reducers with catalogue sizes.

Ground truth is the ``piping`` network of :mod:`canalsurf.synth` (millimetres: NPS 4 and NPS 2 runs with
a long-radius 90-degree and a 3R 45-degree elbow, a reducing tee, a 4 x 2 reducer) and its pieces,
:func:`canalsurf.synth.piping_truth`:

* on the true spines the decomposition is exact (to the sampling of the spines);
* end to end, on a reconstructed scan of it, every piece is found with its type and catalogue size,
  with the tolerances stated at the constants below (and what the reconstruction itself allows);
* unit tests: the catalogue tables, snapping and not snapping, ``pipes.csv`` round trip, bad input.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline
from scipy.spatial.transform import Rotation

import canalsurf
from canalsurf import synth
from canalsurf.errors import InputError, ReconstructionError
from canalsurf.model import CanalModel
from canalsurf.network import Junction, Network
from canalsurf.piping import (ASME_OUTSIDE_DIAMETERS, CATALOGUES, CSV_COLUMNS, EN_OUTSIDE_DIAMETERS, SNAP_RELATIVE,
                              SNAP_SIGMAS, Piece, decompose, snap_size, write_pipes_csv)
from canalsurf.spine import constant_spline

TRUTH = synth.piping_truth()
(REDUCER,) = [t for t in TRUTH if t.type == "reducer"]
#: On the true spines every length, point and diameter is right to this share of the radius: the spines
#: interpolate samples 2 mm apart, and the reducer's knuckles (5 mm either side) shift the best
#: constant - linear - constant fit of its radius by 0.02 mm (measured 0.024 mm on its 102 mm).
EXACT_RADII = 1e-3
#: ... and every bend angle to this many degrees.
EXACT_DEGREES = 1e-3
#: End to end: a scan of 40,000 points (a plant-like density: some 27 points around an NPS 2 pipe, 7 mm
#: apart) with noise of 0.5 % of the radius (0.3 mm on NPS 4), decomposed with its points.  Every length
#: and end within 1 % of the radius of the truth: the ends of every piece at a fitting (an elbow's tangent
#: points, the tee's junction), a straight's length between two fittings or from a fitting to where the
#: model's spine is cut, an elbow's bend radius and arc length, a reducer's ends and length.
N_SCAN, NOISE, SEED = 40_000, 0.005, 1
PIECE_RADII = 0.01
#: ... bend angles within 1 degree;
ANGLE_DEGREES = 1.0
#: ... a free (cut) end lies where the model's spine ends, which the reconstruction puts within a few per
#: cent of the radius of the true end (up to 5.6 % on the canal of the reducer): checked to this share.
FREE_END_RADII = 0.1


# --- helpers ---------------------------------------------------------------------------------------------


def _network(branches, junctions, *, transform=None, scale=1.0, radius_factor=1.0) -> Network:
    """A Network of the synthetic branches (``transform``: a rotation matrix, then a shift)."""
    models = []
    for i, b in enumerate(branches):
        spine = b.spine
        c = spine.c * scale
        if transform is not None:
            turn, shift = transform
            c = c @ turn.T + shift
        spine = type(spine)(spine.t, c, spine.k)
        radius = type(b.radius)(b.radius.t, b.radius.c * scale * radius_factor, b.radius.k)
        kind = "pipe" if np.ptp(b.radius.c) == 0 else "canal"
        models.append(CanalModel(kind, spine, radius, False, id=i, ends=b.ends))
    points = np.asarray(junctions, float).reshape(-1, 3) * scale
    if transform is not None:
        points = points @ transform[0].T + transform[1]
    return Network(models, [Junction(j, p, [(m.id, e) for m in models for e, jj in enumerate(m.ends) if jj == j])
                            for j, p in enumerate(points)])


def _layout():
    return synth.NETWORKS["piping"][0]()


def _true_network(**options) -> Network:
    layout = _layout()
    return _network(layout.branches, layout.junctions, **options)


def _middle(piece) -> np.ndarray:
    return (np.asarray(piece.start) + np.asarray(piece.end)) / 2


def _matched(pieces, truth=TRUTH):
    """Each true piece with the found piece of its type nearest to it; every found piece used once."""
    pairs, used = [], set()
    for t in truth:
        candidates = [p for p in pieces if p.type == t.type and p.id not in used]
        assert candidates, f"no {t.type} found for the one on branch {t.branch}"
        p = min(candidates, key=lambda p: np.linalg.norm(_middle(p) - _middle(t)))
        used.add(p.id)
        pairs.append((t, p))
    assert len(pieces) == len(truth), f"{len(pieces) - len(truth)} pieces more than the truth's {len(truth)}"
    return pairs


def _ends(t, p):
    """The found piece's ends in the order of the true piece's (a run may be reconstructed reversed)."""
    same = np.linalg.norm(p.start - t.start) + np.linalg.norm(p.end - t.end)
    swapped = np.linalg.norm(p.start - t.end) + np.linalg.norm(p.end - t.start)
    return (p.start, p.end) if same <= swapped else (p.end, p.start)


def _free_ends() -> np.ndarray:
    return np.array([b.spine(float(e)) for b in _layout().branches for e in (0, 1) if b.ends[e] is None])


# --- the generator's truth ---------------------------------------------------------------------------------


def test_piping_truth_lies_on_the_generated_spines():
    """Each true piece lies on its branch's spine, end to end, and adds up to the branch's length."""
    layout = _layout()
    assert len(layout.branches) == 6 and layout.junctions.shape == (1, 3)
    for b, branch in enumerate(layout.branches):
        mine = [t for t in TRUTH if t.branch == b and t.type != "tee"]
        t = np.linspace(0.0, 1.0, 20001)
        dense = branch.spine(t)
        length = np.linalg.norm(np.diff(dense, axis=0), axis=1).sum()
        assert sum(p.length for p in mine) == pytest.approx(length, rel=1e-6)
        np.testing.assert_allclose(mine[0].start, branch.spine(0.0), atol=1e-6)
        np.testing.assert_allclose(mine[-1].end, branch.spine(1.0), atol=1e-6)
        for p, q in zip(mine, mine[1:]):
            np.testing.assert_array_equal(p.end, q.start)
        for p in mine:
            for point in (p.start, p.end, _middle(p) if p.type != "elbow" else p.centre
                          + p.bend_radius * (_middle(p) - p.centre) / np.linalg.norm(_middle(p) - p.centre)):
                # within half a sample step of the dense samples (it lies on the curve between two of them)
                assert np.linalg.norm(dense - point, axis=1).min() <= length / 20000 / 2 + 1e-6
    tee = [t for t in TRUTH if t.type == "tee"]
    assert len(tee) == 1 and np.array_equal(tee[0].centre, layout.junctions[0])


# --- the decomposition of the true spines --------------------------------------------------------------------


@pytest.mark.parametrize("catalogue, size", [("asme", "nps"), ("en", "dn")])
def test_true_spines_decompose_exactly(catalogue, size):
    pieces = decompose(_true_network(), units="mm", catalogue=catalogue)
    assert [p.id for p in pieces] == list(range(len(pieces)))
    for t, p in _matched(pieces):
        r = t.outside_diameter / 2
        assert p.branch == t.branch
        np.testing.assert_allclose(p.start, t.start, rtol=0, atol=EXACT_RADII * r)
        np.testing.assert_allclose(p.end, t.end, rtol=0, atol=EXACT_RADII * r)
        assert p.length == pytest.approx(t.length, abs=EXACT_RADII * r)
        assert p.outside_diameter == pytest.approx(t.outside_diameter, abs=EXACT_RADII * r)
        assert p.end_diameter == pytest.approx(t.end_diameter, abs=EXACT_RADII * r)
        assert p.nominal == getattr(t, size)
        if t.type == "elbow":
            assert p.bend_radius == pytest.approx(t.bend_radius, abs=EXACT_RADII * r)
            assert p.angle == pytest.approx(t.angle, abs=EXACT_DEGREES)
            np.testing.assert_allclose(p.centre, t.centre, rtol=0, atol=EXACT_RADII * r)
        else:
            assert p.bend_radius is None and p.angle is None
        if t.type == "reducer":
            assert p.end_nominal == {"asme": "NPS 2", "en": "DN 50"}[catalogue]
            assert p.end_catalogue_diameter == 60.3
        else:
            assert p.end_nominal == p.nominal
        if t.type == "tee":
            assert p.branches == (2, 3, 4) and p.length == 0.0
            np.testing.assert_array_equal(p.centre, p.start)
            assert p.outlet_nominal == {"asme": "NPS 2", "en": "DN 50"}[catalogue]
            assert p.outlet_diameter == pytest.approx(60.3, abs=EXACT_RADII * r)
        else:
            assert p.branches == (t.branch,) and p.outlet_diameter is None
            assert p.fit_deviation <= EXACT_RADII * r and p.fit_tolerance > 0


def test_pieces_join_tangent_continuously():
    """Along a run each piece starts where the last ended; an elbow is an arc of its bend radius about
    its centre, leaving and entering along the straights next to it."""
    pieces = [p for p in decompose(_true_network(), units="mm") if p.type != "tee"]
    for p in pieces:
        if p.type == "elbow":
            u, v = p.start - p.centre, p.end - p.centre
            np.testing.assert_allclose(np.linalg.norm([u, v], axis=1), p.bend_radius, rtol=1e-9)
            cos = u @ v / (np.linalg.norm(u) * np.linalg.norm(v))
            assert math.degrees(math.acos(cos)) == pytest.approx(p.angle, abs=1e-6)
            assert p.length == pytest.approx(p.bend_radius * math.radians(p.angle), rel=1e-9)
        else:
            assert p.length == pytest.approx(np.linalg.norm(p.end - p.start), rel=1e-9)
    for p, q in zip(pieces, pieces[1:]):
        if p.branch != q.branch:
            continue
        np.testing.assert_allclose(p.end, q.start, rtol=0, atol=1e-9)
        if {p.type, q.type} == {"straight", "elbow"}:
            straight, elbow = (p, q) if p.type == "straight" else (q, p)
            at = elbow.start if straight is p else elbow.end
            direction = (straight.end - straight.start) / straight.length
            assert abs(direction @ (at - elbow.centre)) <= 1e-9 * elbow.bend_radius


def test_units_rotation_and_placement_do_not_matter():
    """The network in metres, turned and moved: the same pieces, sizes and angles, lengths / 1000.

    The fit stops at its tolerance, and a gentle elbow's bend radius hardly moves the chain (the 3R 45-degree
    elbow's middle by 0.08 of a change of it), so the two fits agree to about 1e-5 of the radius (measured
    at most 0.5 micrometres on its 57 mm): checked to 1e-4, a hundredth of the accuracy asked of a piece.
    """
    turn = Rotation.from_euler("zyx", [30.0, -20.0, 50.0], degrees=True).as_matrix()
    shift = np.array([512.0, -40.0, 7.5])
    reference = decompose(_true_network(), units="mm")
    moved = decompose(_true_network(scale=1e-3, transform=(turn, shift)), units="m")
    assert [p.type for p in moved] == [p.type for p in reference]
    for p, q in zip(reference, moved):
        tol = 1e-4 * p.outside_diameter / 2 / 1000
        assert (q.nominal, q.end_nominal, q.branches) == (p.nominal, p.end_nominal, p.branches)
        assert q.length == pytest.approx(p.length / 1000, rel=0, abs=tol)
        np.testing.assert_allclose(q.start, p.start / 1000 @ turn.T + shift, rtol=0, atol=tol)
        if p.type == "elbow":
            assert q.angle == pytest.approx(p.angle, abs=1e-4)  # the fit converges to about 1e-6 degrees
            assert q.bend_radius == pytest.approx(p.bend_radius / 1000, rel=0, abs=tol)
        assert q.catalogue_diameter == pytest.approx(p.catalogue_diameter / 1000, rel=1e-12)


def _split(spine, at: float):
    """The spine cut at normalised arc length ``at`` into two interpolating cubics on normalised arc length."""
    parts = []
    for a, b in ((0.0, at), (at, 1.0)):
        xyz = spine(np.linspace(a, b, 2001))
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
        parts.append(make_interp_spline(s / s[-1], xyz, k=3))
    return parts


@pytest.mark.parametrize("at", [250.0, 1100.0])
def test_a_junction_of_two_branches_is_no_joint(at):
    """Branch 0 cut in its first straight or in its first elbow (1000 - 1239 mm along it), the two halves
    joined at a junction of two: the same pieces, the cut one touching both branches."""
    layout = _layout()
    first = layout.branches[0]
    length = sum(t.length for t in TRUTH if t.branch == 0)
    head, tail = _split(first.spine, at / length)
    branches = [synth.SyntheticBranch(head, first.radius, (None, 1)), *layout.branches[1:],
                synth.SyntheticBranch(tail, first.radius, (1, None))]
    pieces = decompose(_network(branches, np.vstack([layout.junctions, head(1.0)])), units="mm")
    reference = decompose(_true_network(), units="mm")
    assert [p.type for p in pieces] == [p.type for p in reference]
    for p, q in zip(pieces, reference):
        assert p.length == pytest.approx(q.length, abs=1e-3)
        np.testing.assert_allclose(p.start, q.start, rtol=0, atol=1e-3)
        if q.type == "elbow":
            assert p.angle == pytest.approx(q.angle, abs=1e-3)
    cut = [p for p in pieces if len(p.branches) == 2 and p.type != "tee"]
    assert len(cut) == 1 and set(cut[0].branches) == {0, 6}
    assert cut[0].type == ("straight" if at < 1000 else "elbow")


def test_two_sizes_meeting_at_a_junction_make_a_reducer():
    """An NPS 4 pipe ending where an NPS 2 pipe starts: a reducer of no length at the junction."""
    a, j, b = np.array([0.0, 0.0, 0.0]), np.array([600.0, 0.0, 0.0]), np.array([1200.0, 0.0, 0.0])
    branches = [synth.SyntheticBranch(synth._straight(a, j), constant_spline(57.15), (None, 0)),
                synth.SyntheticBranch(synth._straight(j, b), constant_spline(30.15), (0, None))]
    pieces = decompose(_network(branches, j), units="mm")
    assert [p.type for p in pieces] == ["straight", "reducer", "straight"]
    reducer = pieces[1]
    assert (reducer.nominal, reducer.end_nominal) == ("NPS 4", "NPS 2")
    assert reducer.length <= 0.25 * 30.15  # the step lies between two spine samples
    np.testing.assert_allclose(reducer.start, j, atol=0.25 * 30.15)
    assert set(reducer.branches) == {0, 1}
    assert pieces[0].length + reducer.length + pieces[2].length == pytest.approx(1200.0, abs=1e-6)


def _star(angles, radius=1.0, length=8.0):
    """Branches leaving the origin in the xy plane at ``angles`` (degrees), one junction."""
    out = []
    for a in angles:
        d = np.array([math.cos(math.radians(a)), math.sin(math.radians(a)), 0.0])
        out.append(synth.SyntheticBranch(synth._straight([0.0, 0.0, 0.0], length * d), constant_spline(radius),
                                         (0, None)))
    return out


def test_a_wye_is_called_a_tee_with_a_warning():
    with pytest.warns(UserWarning, match=r"^junction 0: no two of its branches are in line \(the straightest "
                                         r"pair is 60 degrees off\); called a tee"):
        pieces = decompose(_network(_star([0.0, 120.0, 240.0], radius=0.0572), np.zeros(3)), units="m")
    assert [p.type for p in pieces] == ["straight"] * 3 + ["tee"]
    assert pieces[-1].nominal == "NPS 4"


def test_a_cross_gets_no_fitting_and_a_warning():
    with pytest.warns(UserWarning, match=r"^junction 0: 4 branches meet there; only tees"):
        pieces = decompose(_network(_star([0.0, 90.0, 180.0, 270.0]), np.zeros(3)), units="m")
    assert [p.type for p in pieces] == ["straight"] * 4


def test_a_run_that_is_not_piping_is_refused():
    spine_f, radius_f, closed, *_ = synth.SURFACES["fig9-pipe"]
    with pytest.raises(ReconstructionError, match=r"^branch 0 is no chain of straights and elbows: with \d+ "
                                                  r"elbows its spine is still .* — it is not piping"):
        decompose(CanalModel("pipe", spine_f(), radius_f(), closed), units="m")


def test_a_run_that_is_not_piping_is_left_out_with_a_warning():
    """A coil beside the piping: its run is left out (named, with why), the rest decomposed as without it."""
    spine_f, radius_f, closed, *_ = synth.SURFACES["fig9-pipe"]
    network = _true_network()
    coil = CanalModel("pipe", spine_f(), radius_f(), closed, id=len(network.branches))
    with pytest.warns(UserWarning, match=rf"^branch {coil.id} is no chain of straights and elbows: .* — it is "
                                         r"not piping, .*; it is left out of the pieces$"):
        pieces = decompose(Network([*network.branches, coil], network.junctions), units="mm")
    reference = decompose(network, units="mm")
    assert [(p.type, p.branch, p.nominal) for p in pieces] == [(p.type, p.branch, p.nominal) for p in reference]


def test_a_single_branch_is_decomposed():
    b = _layout().branches[1]
    pieces = decompose(CanalModel("pipe", b.spine, b.radius, False), units="mm")
    assert [(p.type, p.nominal) for p in pieces] == [("straight", "NPS 2"), ("elbow", "NPS 2"),
                                                     ("straight", "NPS 2")]
    assert pieces[1].angle == pytest.approx(90.0, abs=EXACT_DEGREES)


# --- catalogues and snapping --------------------------------------------------------------------------------

#: ASME B36.10M outside diameters in inches of NPS 1/8 - 12 (the standard's inch column): the metric
#: column must be these, rounded to 0.1 mm.
ASME_INCHES = (0.405, 0.540, 0.675, 0.840, 1.050, 1.315, 1.660, 1.900, 2.375, 2.875, 3.500, 4.000, 4.500, 5.563,
               6.625, 8.625, 10.750, 12.750)


def test_catalogues_hold_the_published_outside_diameters():
    names, sizes = zip(*ASME_OUTSIDE_DIAMETERS)
    assert len(names) == len(set(names)) == 36 and names[0] == "NPS 1/8" and names[-1] == "NPS 48"
    assert all(a < b for a, b in zip(sizes, sizes[1:]))
    np.testing.assert_allclose(sizes[:18], np.asarray(ASME_INCHES) * 25.4, rtol=0, atol=0.051)
    # NPS 14 and larger: the outside diameter is the nominal size in inches, in whole millimetres.
    for name, od in ASME_OUTSIDE_DIAMETERS[18:]:
        assert abs(od - 25.4 * int(name.split()[1])) <= 0.5
    en = dict(EN_OUTSIDE_DIAMETERS)
    assert en["DN 50"] == 60.3 and en["DN 65"] == 76.1 and en["DN 100"] == 114.3 and en["DN 125"] == 139.7
    assert en["DN 300"] == 323.9 and en["DN 2000"] == 2032.0
    assert all(a < b for a, b in zip(list(en.values()), list(en.values())[1:]))
    # Neighbouring sizes are at least 4.4 % apart, so at most one is ever within the 1 % tolerance.
    for table in CATALOGUES.values():
        od = np.array([v for _, v in table])
        assert (od[1:] / od[:-1] - 1).min() > 2 * SNAP_RELATIVE


@pytest.mark.parametrize("diameter, units, catalogue, nominal, size", [
    (114.3, "mm", "asme", "NPS 4", 114.3), (0.1150, "m", "asme", "NPS 4", 0.1143),
    (4.5, "in", "asme", "NPS 4", 4.5), (8.625 / 12, "ft", "asme", "NPS 8", 219.1 / 304.8),
    (114.3, "mm", "en", "DN 100", 114.3), (76.4, "mm", "en", "DN 65", 76.1), (60.0, "mm", "en", "DN 50", 60.3),
])
def test_snap_within_tolerance(diameter, units, catalogue, nominal, size):
    snap = snap_size(diameter, units=units, catalogue=catalogue)
    assert (snap.nominal, snap.nearest, snap.catalogue) == (nominal, nominal, catalogue)
    assert snap.catalogue_diameter == pytest.approx(size, rel=1e-12) == snap.nearest_diameter
    assert snap.deviation == pytest.approx(diameter - size, abs=1e-12)
    assert snap.tolerance == pytest.approx(SNAP_RELATIVE * size, rel=1e-12)
    assert abs(snap.relative_deviation) <= SNAP_RELATIVE


def test_no_snap_still_reports_the_nearest_size_and_deviation():
    snap = snap_size(76.1, units="mm", catalogue="asme")  # DN 65 in EN 10220; in ASME 4.2 % above NPS 2 1/2
    assert snap.nominal is None and snap.catalogue_diameter is None
    assert (snap.nearest, snap.nearest_diameter) == ("NPS 2 1/2", 73.0)
    assert snap.deviation == pytest.approx(3.1, abs=1e-9)
    assert snap.relative_deviation == pytest.approx(3.1 / 73.0)
    assert snap.tolerance == pytest.approx(0.73)
    # A wide enough uncertainty of the measurement lets it snap: three of its standard deviations.
    wide = snap_size(76.1, units="mm", catalogue="asme", uncertainty=1.1)
    assert wide.nominal == "NPS 2 1/2" and wide.tolerance == pytest.approx(SNAP_SIGMAS * 1.1)


def test_pieces_off_every_size_are_not_snapped_but_reported():
    """The network 3 % fatter than its catalogue sizes: no piece snaps, each says how far it is off."""
    pieces = decompose(_true_network(radius_factor=1.03), units="mm")
    for t, p in _matched(pieces):
        assert p.nominal is None and p.catalogue_diameter is None and p.end_nominal is None
        assert p.snaps[0].nearest == t.nps
        off = 0.03 * t.outside_diameter
        assert p.snaps[0].deviation == pytest.approx(off, abs=EXACT_RADII * t.outside_diameter)
        if t.type == "tee":
            assert p.outlet_nominal is None and p.snaps[1].nearest == "NPS 2"


# --- pipes.csv -------------------------------------------------------------------------------------------------


def _read_csv(path):
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        return reader.fieldnames, list(reader)


def _number(text):
    return None if text == "" else float(text)


@pytest.mark.parametrize("radius_factor", [1.0, 1.03])
def test_pipes_csv_round_trip(radius_factor, tmp_path):
    pieces = decompose(_true_network(radius_factor=radius_factor), units="mm")
    path = tmp_path / "pipes.csv"
    write_pipes_csv(path, pieces, units="mm")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipes.csv"]  # no temporary file left
    header, rows = _read_csv(path)
    assert tuple(header) == CSV_COLUMNS and len(rows) == len(pieces)
    for p, row in zip(pieces, rows):
        assert (int(row["piece"]), row["type"], int(row["branch"]), row["units"]) == (p.id, p.type, p.branch, "mm")
        assert tuple(int(b) for b in row["branches"].split(";")) == p.branches
        assert (row["nominal"] or None) == p.nominal
        assert _number(row["measured_od"]) == p.outside_diameter
        assert _number(row["catalogue_od"]) == p.catalogue_diameter
        assert row["nearest"] == p.snaps[0].nearest and _number(row["nearest_od"]) == p.snaps[0].nearest_diameter
        assert _number(row["deviation"]) == p.snaps[0].deviation
        assert _number(row["deviation_percent"]) == pytest.approx(100 * p.snaps[0].relative_deviation, rel=1e-15)
        assert _number(row["snap_tolerance"]) == p.snaps[0].tolerance
        for column, value in (("length", p.length), ("bend_radius", p.bend_radius), ("angle", p.angle),
                              ("fit_deviation", p.fit_deviation), ("fit_tolerance", p.fit_tolerance)):
            assert _number(row[column]) == value
        for name, point in (("start", p.start), ("end", p.end), ("centre", p.centre)):
            got = [_number(row[f"{name}_{axis}"]) for axis in "xyz"]
            assert got == ([None] * 3 if point is None else list(np.asarray(point, float)))
        if p.type == "reducer":
            assert (row["end_nominal"] or None) == p.end_nominal
            assert _number(row["end_measured_od"]) == p.end_diameter
            assert _number(row["end_deviation"]) == p.snaps[1].deviation
        else:
            assert row["end_nominal"] == row["end_measured_od"] == ""
        if p.type == "tee":
            assert (row["outlet_nominal"] or None) == p.outlet_nominal
            assert _number(row["outlet_measured_od"]) == p.outlet_diameter
        else:
            assert row["outlet_nominal"] == row["outlet_measured_od"] == ""
    if radius_factor != 1.0:
        assert all(row["nominal"] == "" and row["nearest"].startswith("NPS") for row in rows)
        assert all(float(row["deviation_percent"]) == pytest.approx(3.0, abs=100 * EXACT_RADII) for row in rows)


# --- bad input -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("call, message", [
    (lambda: decompose(object()), r"^network must be a canalsurf Network or CanalModel, got object$"),
    (lambda: decompose(Network([])), r"^the network has no branches — nothing to decompose$"),
    (lambda: decompose(_true_network(), units="cm"),
     r"^units must be one of 'm', 'mm', 'ft', 'in', got 'cm'$"),
    (lambda: decompose(_true_network(), catalogue="din"), r"^catalogue must be one of 'asme', 'en', got 'din'$"),
    (lambda: snap_size(-1.0), r"^diameter must be a positive number, got -1.0$"),
    (lambda: snap_size("4 in"), r"^diameter must be a real number, got str '4 in'$"),
    (lambda: snap_size(float("nan")), r"^diameter must be a positive number, got nan$"),
    (lambda: snap_size(0.1, units="yd"), r"^units must be one of 'm', 'mm', 'ft', 'in', got 'yd'$"),
    (lambda: snap_size(0.1, uncertainty=-1.0), r"^uncertainty must be a positive number, got -1.0$"),
    (lambda: write_pipes_csv("pipes.csv", [1, 2]),
     r"^pieces must be a list of canalsurf.piping.Piece, as decompose returns$"),
    (lambda: write_pipes_csv("pipes.csv", [], units="furlong"),
     r"^units must be one of 'm', 'mm', 'ft', 'in', got 'furlong'$"),
])
def test_bad_input_is_one_line(call, message):
    with pytest.raises(InputError, match=message):
        call()


def test_csv_into_a_missing_folder_is_refused(tmp_path):
    with pytest.raises(InputError, match="does not exist — create it first"):
        write_pipes_csv(tmp_path / "missing" / "pipes.csv", [], units="m")


# --- end to end: a reconstructed scan ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def scanned():
    cloud = synth.make_network("piping", n=N_SCAN, noise=NOISE, rng=SEED)
    return cloud.points, canalsurf.reconstruct(cloud.points)


def test_reconstruction_finds_the_piping_branches(scanned):
    _, network = scanned
    assert len(network.branches) == 6 and len(network.junctions) == 1
    assert len(network.junctions[0].ends) == 3
    assert sorted(b.kind for b in network.branches) == ["canal"] + ["pipe"] * 5


@pytest.mark.parametrize("catalogue, size", [("asme", "nps"), ("en", "dn")])
def test_end_to_end_every_piece_found(scanned, catalogue, size):
    points, network = scanned
    pieces = decompose(network, points, units="mm", catalogue=catalogue)
    assert all(isinstance(p, Piece) for p in pieces)
    free = _free_ends()
    model_ends = np.array([b.spine(float(e)) for b in network.branches for e in (0, 1) if b.ends[e] is None])
    small = {"asme": "NPS 2", "en": "DN 50"}[catalogue]
    for t, p in _matched(pieces):
        r = t.outside_diameter / 2
        if t.type == "reducer":
            # Its sizes are the plateaus' either side, in the order of the run (which the reconstruction
            # may have turned round).
            lo, hi = _ends(t, p)
            np.testing.assert_allclose([lo, hi], [t.start, t.end], rtol=0, atol=PIECE_RADII * r)
            assert p.length == pytest.approx(t.length, abs=PIECE_RADII * r)
            sizes = (p.nominal, p.end_nominal) if lo is p.start else (p.end_nominal, p.nominal)
            assert sizes == (getattr(t, size), small)
            continue
        assert p.nominal == getattr(t, size), f"{t.type} on branch {t.branch}"
        if t.type == "tee":
            np.testing.assert_allclose(p.start, t.start, rtol=0, atol=PIECE_RADII * r)
            assert p.outlet_nominal == small and p.end_nominal == p.nominal
            run = {b.id for b in network.branches if b.kind == "pipe" and abs(b.mean_radius - 57.15) < 1}
            assert set(p.branches[:2]) <= run and len(set(p.branches)) == 3
            continue
        ends = _ends(t, p)
        at_free = [np.linalg.norm(free - e, axis=1).min() < 1e-6 for e in (t.start, t.end)]
        at_reducer = [min(np.linalg.norm(e - REDUCER.start), np.linalg.norm(e - REDUCER.end)) < 1e-6
                      for e in (t.start, t.end)]
        for true_end, end, cut, reducer in zip((t.start, t.end), ends, at_free, at_reducer):
            if cut:  # where the model's spine ends
                assert np.linalg.norm(model_ends - end, axis=1).min() <= 1e-9 * r
                assert np.linalg.norm(end - true_end) <= FREE_END_RADII * r
            elif not reducer:  # the reducer's ends are checked with it
                assert np.linalg.norm(end - true_end) <= PIECE_RADII * r, f"{t.type} on branch {t.branch}"
        if t.type == "elbow":
            assert p.angle == pytest.approx(t.angle, abs=ANGLE_DEGREES)
            assert p.bend_radius == pytest.approx(t.bend_radius, abs=PIECE_RADII * r)
            assert p.length == pytest.approx(t.length, abs=PIECE_RADII * r)
        elif not any(at_free):
            assert p.length == pytest.approx(t.length, abs=PIECE_RADII * r)
        elif not any(at_reducer):
            # Up to the model's cut end: as long as the truth from its other end to there.
            cut_end, other = (ends[0], t.end) if at_free[0] else (ends[1], t.start)
            assert p.length == pytest.approx(np.linalg.norm(cut_end - other), abs=PIECE_RADII * r)
        assert p.fit_deviation <= p.fit_tolerance


def test_examples_in_the_docstrings_run():
    import doctest

    import canalsurf.piping

    result = doctest.testmod(canalsurf.piping, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted >= 8
    runner = doctest.DocTestRunner(optionflags=doctest.NORMALIZE_WHITESPACE)
    for test in doctest.DocTestFinder().find(synth.piping_truth, "piping_truth", globs=vars(synth)):
        runner.run(test)
    assert runner.failures == 0 and runner.tries == 2
