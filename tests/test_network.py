"""Tests of canalsurf.network on hand-made networks whose geometry is known exactly.

* a T of three straight pipes at one junction (the tubes' union volume is a one-dimensional integral);
* a "bent T": the T's side branch a curved, tapering canal, plus a separate straight pipe and a closed
  loop (three components), for the model.json round trip and for classification, which is checked
  against a brute-force minimum of ``|P - C(t)| - r(t)`` over a dense parameter grid;
* two separate pipes (two components, no union).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.interpolate import BSpline, make_interp_spline

from canalsurf.constants import MIN_SIGMA_PER_RADIUS, OUTLIER_SIGMAS
from canalsurf.errors import InputError
from canalsurf.model import CanalModel
from canalsurf.network import (MIN_BRANCH_SAMPLES, NETWORK_VERSION, SAMPLE_SPACING_PER_RADIUS, Junction, Network,
                               classify_points, n_branch_samples, network_from_dict, network_mesh)
from canalsurf.spine import constant_spline
from canalsurf.surface import DEFAULT_N_AROUND

trimesh = pytest.importorskip("trimesh")

SEED = 11
#: The T: main pipe along x from -HALF to HALF (radius R_MAIN), side pipe along y from 0 to SIDE (R_SIDE).
HALF, SIDE, R_MAIN, R_SIDE = 4.0, 3.5, 1.0, 0.6
#: Noise of each hand-made branch's fit (diagnostics["noise_sigma"]) as a share of its radius: the
#: outlier cut of classification is OUTLIER_SIGMAS times it.
SIGMA_PER_RADIUS = 0.02
#: Largest distance of a mesh vertex from the true surface: the polygon of DEFAULT_N_AROUND vertices is
#: inscribed in each circle, so a point of a facet lies inside by at most the sagitta r (1 - cos(pi / n)).
SAGITTA = 1 - math.cos(math.pi / DEFAULT_N_AROUND)
#: Share of a circle's area its inscribed DEFAULT_N_AROUND-gon holds (about 0.994).
POLYGON_AREA = DEFAULT_N_AROUND * math.sin(2 * math.pi / DEFAULT_N_AROUND) / (2 * math.pi)


def _line(a, b):
    """A cubic B-spline along the segment from ``a`` to ``b``, parametrised by normalised arc length."""
    u = np.linspace(0.0, 1.0, 5)
    a, b = np.asarray(a, float), np.asarray(b, float)
    return make_interp_spline(u, a + u[:, None] * (b - a), k=3)


def _plain(spline):
    """The spline as the pipeline and model.json hold it: full periodic knot vector, default extrapolation
    (scipy's ``extrapolate="periodic"`` wraps t first, which changes the last bit of some values)."""
    return BSpline(spline.t, spline.c, spline.k)


def _pipe(a, b, radius, bid, ends=(None, None)) -> CanalModel:
    return CanalModel("pipe", _line(a, b), constant_spline(radius), False, {},
                      {"noise_sigma": SIGMA_PER_RADIUS * radius}, id=bid, ends=ends)


def _t_network() -> Network:
    branches = [_pipe([-HALF, 0, 0], [0, 0, 0], R_MAIN, 0, (None, 0)),
                _pipe([0, 0, 0], [HALF, 0, 0], R_MAIN, 1, (0, None)),
                _pipe([0, 0, 0], [0, SIDE, 0], R_SIDE, 2, (0, None))]
    return Network(branches, [Junction(0, np.zeros(3), [(0, 1), (1, 0), (2, 0)])], {"R": 0.2}, {"n_points": 5})


def _bent_t_network() -> Network:
    """The T's halves, a side branch bending from +y up to +z (a quarter circle of radius 3, the radius
    tapering 0.6 -> 0.4), a separate pipe and a closed canal loop (periodic splines)."""
    theta = np.linspace(0.0, np.pi / 2, 41)  # angle is proportional to arc length on a circle
    arc = np.column_stack([np.zeros_like(theta), 3 * np.sin(theta), 3 - 3 * np.cos(theta)])
    u = theta / theta[-1]
    side = CanalModel("canal", make_interp_spline(u, arc, k=3), make_interp_spline(u, 0.6 - 0.2 * u, k=3), False,
                      {}, {"noise_sigma": SIGMA_PER_RADIUS * 0.5}, id=2, ends=(0, None))
    a = np.linspace(0.0, 2 * np.pi, 61)
    ring = np.column_stack([2 * np.cos(a), 2 * np.sin(a), np.zeros_like(a)]) + [0.0, 10.0, 0.0]
    ring[-1] = ring[0]
    r = 0.3 + 0.05 * np.sin(a)
    r[-1] = r[0]
    loop = CanalModel("canal", _plain(make_interp_spline(a / a[-1], ring, k=3, bc_type="periodic")),
                      _plain(make_interp_spline(a / a[-1], r, k=3, bc_type="periodic")), True, {},
                      {"noise_sigma": SIGMA_PER_RADIUS * 0.3}, id=4)
    branches = [_pipe([-HALF, 0, 0], [0, 0, 0], R_MAIN, 0, (None, 0)),
                _pipe([0, 0, 0], [HALF, 0, 0], R_MAIN, 1, (0, None)),
                side,
                _pipe([8.0, 0.0, -3.0], [8.0, 0.0, 3.0], 0.5, 3),
                loop]
    return Network(branches, [Junction(0, np.zeros(3), [(0, 1), (1, 0), (2, 0)])],
                   {"R": 0.2, "H": np.float64(0.3)}, {"n_points": 5000, "no_tube_share": np.float64(0.01),
                                                      "seconds": {"fit": 1.0}})


def _two_pipes() -> Network:
    return Network([_pipe([0, 0, 0], [5, 0, 0], 0.5, 0), _pipe([0, 3, 1], [0, 3, 5], 0.8, 1)])


def _capped_cylinder_distance(points, a, b, r):
    """Exact signed distance from the solid cylinder of radius ``r`` on the segment a-b (flat caps)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = np.linalg.norm(b - a)
    axis = (b - a) / length
    s = (points - a) @ axis
    radial = np.linalg.norm(points - a - s[:, None] * axis, axis=1) - r
    axial = np.maximum(-s, s - length)
    outside = np.hypot(np.maximum(radial, 0.0), np.maximum(axial, 0.0))
    return outside + np.minimum(np.maximum(radial, axial), 0.0)


def _polish(points, branch, t0, h):
    """Golden-section minimum of ``|P - C(t)| - r(t)`` per point on ``[t0 - h, t0 + h]`` (vectorised)."""
    lo = t0 - h
    hi = t0 + h
    if not branch.closed:
        lo, hi = np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0)

    def f(t):
        tt = np.mod(t, 1.0) if branch.closed else t
        return np.linalg.norm(points - branch.spine(tt), axis=1) - branch.radius(tt)

    g = (math.sqrt(5) - 1) / 2
    c, d = hi - g * (hi - lo), lo + g * (hi - lo)
    fc, fd = f(c), f(d)
    for _ in range(80):  # the bracket shrinks by 0.618**80, far below float precision
        left = fc < fd
        hi = np.where(left, d, hi)
        lo = np.where(left, lo, c)
        c, d = hi - g * (hi - lo), lo + g * (hi - lo)
        fc, fd = f(c), f(d)
    t = (lo + hi) / 2
    return f(t)


def _brute_distances(points, network, envelope_distance):
    """Signed distance of every point from every branch (columns), by brute force: the best of 1001
    parameters, refined on 401 across the two grid steps around it (conftest), then polished by golden
    section across one refined step."""
    out = np.empty((len(points), len(network.branches)))
    for j, b in enumerate(network.branches):
        _, t = envelope_distance(points, b.spine, b.radius, closed=b.closed)
        out[:, j] = _polish(points, b, t, 2.0 / 1000 / 400)
    return out


def _cuts(network):
    return np.array([OUTLIER_SIGMAS * max(b.diagnostics["noise_sigma"], MIN_SIGMA_PER_RADIUS * b.mean_radius)
                     for b in network.branches])


# --------------------------------------------------------------------------------------------------
# structure and model.json


def test_components():
    assert _t_network().components == [[0, 1, 2]]
    assert _bent_t_network().components == [[0, 1, 2], [3], [4]]
    assert _two_pipes().components == [[0], [1]]
    # Two junctions in a chain are one component; the order of the ids does not matter.
    chain = Network([_pipe([0, 0, 0], [1, 0, 0], 0.1, 2, (None, 0)), _pipe([1, 0, 0], [2, 0, 0], 0.1, 0, (0, 1)),
                     _pipe([2, 0, 0], [3, 0, 0], 0.1, 1, (1, None)), _pipe([5, 0, 0], [6, 0, 0], 0.1, 3)],
                    [Junction(0, np.array([1.0, 0, 0]), [(2, 1), (0, 0)]),
                     Junction(1, np.array([2.0, 0, 0]), [(0, 1), (1, 0)])])
    assert chain.components == [[0, 1, 2], [3]]


@pytest.mark.parametrize("make", [_t_network, _bent_t_network])
def test_dict_round_trip_is_exact(make):
    """to_dict -> JSON text -> network_from_dict gives the same knots, control points, radii, ends and
    junctions bit for bit, and writing the result again gives the same content."""
    network = make()
    data = network.to_dict()
    assert data["version"] == NETWORK_VERSION
    assert data["components"] == network.components
    assert "seconds" not in data["diagnostics"]
    back = network_from_dict(json.loads(json.dumps(data)))
    assert len(back.branches) == len(network.branches)
    for b, original in zip(back.branches, network.branches):
        assert (b.id, b.kind, b.closed, b.ends) == (original.id, original.kind, original.closed, original.ends)
        np.testing.assert_array_equal(b.spine.t, original.spine.t)
        np.testing.assert_array_equal(b.spine.c, original.spine.c)
        assert b.spine.k == original.spine.k
        if b.kind == "pipe":
            assert b.radius.c[0] == original.radius.c[0]
        else:
            np.testing.assert_array_equal(b.radius.t, original.radius.t)
            np.testing.assert_array_equal(b.radius.c, original.radius.c)
        assert b.diagnostics == original.diagnostics
    assert [(j.id, j.ends) for j in back.junctions] == [(j.id, j.ends) for j in network.junctions]
    for j, original in zip(back.junctions, network.junctions):
        np.testing.assert_array_equal(j.point, original.point)
    assert back.components == network.components
    assert back.parameters == data["parameters"]
    assert back.to_dict() == data


def test_version_1_content_is_a_network_of_one_branch():
    pipe = _pipe([0, 0, 0], [3, 1, 0], 0.4, 0)
    pipe.parameters = {"R": 0.1}
    back = network_from_dict(json.loads(json.dumps(pipe.to_dict())))
    assert len(back.branches) == 1 and back.junctions == [] and back.components == [[0]]
    np.testing.assert_array_equal(back.spine.c, pipe.spine.c)
    assert back.kind == "pipe" and back.radius.c[0] == 0.4 and back.parameters == {"R": 0.1}


@pytest.mark.parametrize(("length", "radius"), [(2.0, 1.0), (37.3, 0.11), (6.0, 0.13)])
def test_branch_samples_are_at_least_50_and_half_a_radius_apart(length, radius):
    """n_branch_samples is the least count of at least MIN_BRANCH_SAMPLES whose arc-length steps are no
    longer than SAMPLE_SPACING_PER_RADIUS mean radii, and to_dict writes exactly that many samples."""
    branch = _pipe([0, 0, 0], [0.6 * length, 0.8 * length, 0], radius, 0)
    n = n_branch_samples(branch)
    assert n == max(MIN_BRANCH_SAMPLES, math.ceil(length / (SAMPLE_SPACING_PER_RADIUS * radius)) + 1)
    assert n >= MIN_BRANCH_SAMPLES
    assert length / (n - 1) <= SAMPLE_SPACING_PER_RADIUS * radius
    assert n == MIN_BRANCH_SAMPLES or length / (n - 2) > SAMPLE_SPACING_PER_RADIUS * radius  # the least such
    samples = Network([branch]).to_dict()["branches"][0]["samples"]
    assert len(samples["t"]) == len(samples["points"]) == len(samples["radius"]) == n
    steps = np.linalg.norm(np.diff(np.array(samples["points"]), axis=0), axis=1)
    np.testing.assert_allclose(steps, length / (n - 1), rtol=1e-6)
    np.testing.assert_allclose(samples["radius"], radius, rtol=1e-12)


def test_a_network_of_one_branch_answers_as_the_branch():
    branch = _bent_t_network().branches[2]
    one = Network([branch])
    assert one.kind == "canal" and one.closed is False
    assert one.spine is branch.spine and one.radius is branch.radius
    assert one.mean_radius == branch.mean_radius
    for got, want in zip(one.sample(), branch.sample()):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(one.sample(40), branch.sample(40)):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("name", ["kind", "spine", "radius", "closed", "mean_radius", "sample"])
def test_a_network_of_several_branches_has_no_single_branch_attributes(name):
    network = _t_network()
    with pytest.raises(AttributeError, match=rf"^a network of 3 branches has no single '{name}'; use \.branches$"):
        value = getattr(network, name)
        if name == "sample":
            value()
    assert not hasattr(network, "kind")


# --------------------------------------------------------------------------------------------------
# classification


def test_classify_points_against_brute_force(envelope, envelope_distance):
    """Points on each branch's surface (offset within its outlier cut) get that branch's id; points a few
    cuts off every surface get -1; and label and signed distance agree with a brute-force minimum of
    ``|P - C(t)| - r(t)`` over every branch, the distance to 1e-9."""
    network = _bent_t_network()
    rng = np.random.default_rng(SEED)
    cuts = _cuts(network)
    points, truth, offsets = [], [], []
    for b, cut in zip(network.branches, cuts):
        n = 400
        t, s = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 2 * np.pi, n)
        on = rng.uniform(-0.9, 0.9, n) * cut
        off = rng.choice([-1.0, 1.0], n) * rng.uniform(3.0, 0.5 * b.mean_radius / cut, n) * cut
        for offset, label in ((on, b.id), (off, -1)):
            points.append(envelope(b.spine, b.radius, t, s, offset)[0])
            truth.append(np.full(n, label))
            offsets.append(offset)
    points, truth = np.vstack(points), np.concatenate(truth)
    points = np.vstack([points, rng.uniform([-6, -3, -4], [12, 14, 5], size=(500, 3))])  # anywhere
    truth = np.r_[truth, np.full(500, -2)]  # -2: not known beforehand

    label, distance = classify_points(points, network.branches)
    brute = _brute_distances(points, network, envelope_distance)
    nearest = np.argmin(np.abs(brute), axis=1)
    rows = np.arange(len(points))
    best = brute[rows, nearest]
    expected = np.where(np.abs(best) <= cuts[nearest], nearest, -1)  # ids are the indices here
    # Near a junction a point can be about as near to two surfaces; the label is decided there only to
    # within the brute force's accuracy.
    second = np.sort(np.abs(brute), axis=1)[:, 1]
    clear = (second - np.abs(best) > 1e-6) & (np.abs(np.abs(best) - cuts[nearest]) > 1e-6)
    assert clear.mean() > 0.99
    np.testing.assert_array_equal(label[clear], expected[clear])
    np.testing.assert_allclose(distance, best, rtol=0, atol=1e-9)
    # Ground truth: a generated point where no other surface is within a cut of its own.
    other = np.abs(brute).copy()
    known = truth >= 0
    other[rows[known], truth[known]] = np.inf
    alone = other.min(axis=1) > 2 * cuts.max()
    assert (known & alone).sum() > 1500 and ((truth == -1) & alone).sum() > 1200
    np.testing.assert_array_equal(label[known & alone], truth[known & alone])
    np.testing.assert_array_equal(label[(truth == -1) & alone], -1)
    # Network.classify is classify_points on validated input.
    again = network.classify(points.tolist())
    np.testing.assert_array_equal(again[0], label)
    np.testing.assert_array_equal(again[1], distance)


def test_a_point_on_a_fat_tube_beside_a_thin_one_is_on_the_fat_one(envelope):
    """A T whose side pipe is thin (0.15 beside 1.0): near its root, the nearest spine samples of a point
    on the main pipe are all the side's, yet every point of the main pipe's surface outside the side
    tube is on the main pipe (either half), at distance 0."""
    network = _t_network()
    network.branches[2] = _pipe([0, 0, 0], [0, SIDE, 0], 0.15, 2, (0, None))
    rng = np.random.default_rng(SEED)
    n = 20000
    t = rng.uniform(0.8, 1.0, n)  # the last 0.8 of the left half, up to the junction
    points, _ = envelope(network.branches[0].spine, network.branches[0].radius, t, rng.uniform(0, 2 * np.pi, n))
    points = points[_capped_cylinder_distance(points, [0, 0, 0], [0, SIDE, 0], 0.15) > 1e-6]
    label, distance = classify_points(points, network.branches)
    assert np.isin(label, [0, 1]).all()
    np.testing.assert_allclose(distance, 0.0, atol=1e-9)


def test_classify_cut_overrides_the_diagnostics():
    """With ``cut`` the outlier limit per branch is the one given, not the fit's: points 0.5 outside and
    0.8 inside the main pipe's surface and one on the side pipe's axis (0.6 inside) are on no tube by the
    fits' noise, and each is on its nearest tube once that tube's cut reaches its distance."""
    network = _t_network()
    points = np.array([[-2.0, 0.0, 1.5], [-2.0, 0.0, 0.2], [0.0, 2.0, 0.0]])
    label, distance = classify_points(points, network.branches)
    np.testing.assert_array_equal(label, [-1, -1, -1])
    np.testing.assert_allclose(distance, [0.5, -0.8, -R_SIDE], atol=1e-9)
    label, _ = classify_points(points, network.branches, cut=[0.6, 0.6, 0.0])
    np.testing.assert_array_equal(label, [0, -1, -1])
    label, _ = classify_points(points, network.branches, cut=[0.9, 0.9, 0.9])
    np.testing.assert_array_equal(label, [0, 0, 2])


def test_classify_nothing():
    label, distance = classify_points(np.zeros((3, 3)), [])
    np.testing.assert_array_equal(label, -1)
    assert np.isinf(distance).all()
    label, distance = classify_points(np.empty((0, 3)), _t_network().branches)
    assert label.shape == distance.shape == (0,)


# --------------------------------------------------------------------------------------------------
# mesh


def _mesh(network):
    vertices, faces = network_mesh(network)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0
    return vertices, mesh


def test_t_mesh_is_the_union_of_the_tubes():
    """The T's mesh is one closed, outward surface of the union of the three pipes: its volume is the
    exact union volume less the polygon's share (within 2 %, never more), and every vertex lies on the
    union's surface to within the sagitta of the polygon."""
    vertices, mesh = _mesh(_t_network())
    # main cylinder + the side cylinder less what of it lies inside the main one: for a point (x, z) of
    # the side's cross-section, the side runs inside the main pipe up to y = sqrt(R_MAIN^2 - z^2).
    inside = quad(lambda z: 2 * math.sqrt(R_SIDE**2 - z**2) * math.sqrt(R_MAIN**2 - z**2), -R_SIDE, R_SIDE,
                  epsabs=1e-12)[0]
    exact = math.pi * R_MAIN**2 * 2 * HALF + math.pi * R_SIDE**2 * SIDE - inside
    assert mesh.volume <= exact
    assert mesh.volume == pytest.approx(exact, rel=0.02)
    assert mesh.volume == pytest.approx(POLYGON_AREA * exact, rel=2e-3)
    union = np.minimum(_capped_cylinder_distance(vertices, [-HALF, 0, 0], [HALF, 0, 0], R_MAIN),
                       _capped_cylinder_distance(vertices, [0, 0, 0], [0, SIDE, 0], R_SIDE))
    assert union.max() <= 1e-6
    assert union.min() >= -SAGITTA * R_MAIN - 1e-6
    # One piece: the tubes are united, not merely overlapping (their inner caps are gone, see above).
    assert len(mesh.split(only_watertight=False)) == 1


def test_separate_pipes_mesh_is_two_closed_tubes():
    network = _two_pipes()
    vertices, mesh = _mesh(network)
    exact = math.pi * 0.5**2 * 5 + math.pi * 0.8**2 * 4
    assert mesh.volume <= exact
    assert mesh.volume == pytest.approx(exact, rel=0.02)
    assert mesh.volume == pytest.approx(POLYGON_AREA * exact, rel=1e-6)
    parts = mesh.split(only_watertight=True)
    assert len(parts) == 2
    np.testing.assert_allclose(sorted(p.volume for p in parts),
                               sorted(POLYGON_AREA * math.pi * np.array([0.5**2 * 5, 0.8**2 * 4])), rtol=1e-6)
    d = np.minimum(_capped_cylinder_distance(vertices, [0, 0, 0], [5, 0, 0], 0.5),
                   _capped_cylinder_distance(vertices, [0, 3, 1], [0, 3, 5], 0.8))
    assert np.abs(d).max() <= 1e-9


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d["junctions"][0]["ends"].pop(), "disagree"),
    (lambda d: d["branches"][1].__setitem__("ends", [None, None]), "disagree"),
    (lambda d: d["junctions"][0]["ends"][0].__setitem__("branch", 1.0), "junction 0"),
    (lambda d: d["junctions"][0]["ends"][0].__setitem__("end", True), "junction 0"),
    (lambda d: d.__setitem__("version", 3), "reads versions 1 and 2"),
    (lambda d: d.__setitem__("version", True), "not supported"),
])
def test_inconsistent_network_files_are_refused(mutate, match):
    data = json.loads(json.dumps(_t_network().to_dict()))
    mutate(data)
    with pytest.raises(InputError, match=match):
        network_from_dict(data, "m.json")
