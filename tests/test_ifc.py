"""IFC 4 export: files read back with ifcopenshell, checked against the schema, and their geometry -- as
ifcopenshell builds it -- checked against canalsurf's own surface.

The networks are built here from known splines (no reconstruction): straight and bent pipes, a
tapering canal, a closed loop, a junction of three ends and a bend of two.  Tolerances: every vertex of
a segment within ``TOL`` = 0.5 % of the local radius of the branch's surface (footpoints of
:mod:`canalsurf.refine`, or the flat end caps); every vertex of a fitting within ``TOL`` of the
radius of the solid the fitting stands for (sphere, torus, cone, cylinder), computed here from the
piece's fields.
"""

from __future__ import annotations

import dataclasses
import doctest
import math
import os
import sys
import warnings
from dataclasses import dataclass

import ifcopenshell
import ifcopenshell.geom
import ifcopenshell.validate
import numpy as np
import pytest
from scipy.interpolate import BSpline, make_interp_spline

import canalsurf.ifc
from canalsurf.errors import InputError
from canalsurf.ifc import ARC_TOL, FAR_FROM_ORIGIN_EXTENTS, arc_chain, ifc_knots, write_ifc
from canalsurf.model import CanalModel
from canalsurf.network import Junction, Network
from canalsurf.piping import Piece, decompose
from canalsurf.refine import footpoints
from canalsurf.spine import constant_spline

#: The accuracy the export promises: 0.5 % of the radius.
TOL = 5e-3
#: Tessellation asked of ifcopenshell, as shares of the thinnest radius (linear) and radians: coarse,
#: for speed -- the vertices of a tessellated swept solid lie on its true surface whatever the spacing.
DEFLECTION_PER_RADIUS = 0.05
ANGULAR_DEFLECTION = 0.3
#: A georeferenced site: UTM-sized coordinates (zone 32N), its height not far from the origin.
UTM = np.array([512345.678, 5403210.123, 231.5])
R_MAIN, R_BENT, R_LOOP = 0.4, 0.25, 0.3
#: About the largest side of the bounding box of _network() (x from -5.4 to 12.1): the scale of round-off.
EXTENT = 17.5


# --------------------------------------------------------------------------------------------------
# networks from known splines


def _line(a, b, u=(0.0, 0.2, 0.45, 0.7, 1.0)) -> BSpline:
    """A straight spine, cubic, with uneven interior knots (so the knot conversion is exercised)."""
    a, b, u = np.asarray(a, float), np.asarray(b, float), np.asarray(u)
    return make_interp_spline(u, a + u[:, None] * (b - a), k=3)


def _curve(points) -> BSpline:
    points = np.asarray(points, float)
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    u = np.concatenate([[0.0], np.cumsum(step)]) / step.sum()
    return make_interp_spline(u, points, k=3)


def _loop(centre, radius) -> BSpline:
    """A periodic cubic spine through 12 points of a circle: a full, unclamped knot vector."""
    u = np.linspace(0.0, 1.0, 13)
    points = np.asarray(centre) + radius * np.column_stack([np.cos(2 * np.pi * u), np.sin(2 * np.pi * u),
                                                            np.zeros_like(u)])
    points[-1] = points[0]
    return make_interp_spline(u, points, k=3, bc_type="periodic")


def _network(offset=np.zeros(3), scale=1.0) -> Network:
    """Six branches: a junction of two straight pipes and a tapering canal, a bend of a straight and a
    bent pipe, and a closed pipe loop; ``scale`` then ``offset`` applied to every coordinate."""

    def at(p):
        return np.asarray(p, float) * scale + offset

    j0, j1 = at([1.0, 2.0, 0.5]), at([1.0, -4.0, 0.5])
    u = np.linspace(0.0, 1.0, 7)
    canal = j0 + scale * np.column_stack([0.5 * np.sin(3 * u), 5 * u, 1.5 * u**2])
    bent = j1 + scale * np.column_stack([3 * np.sin(u * np.pi / 2), 3 * (1 - np.cos(u * np.pi / 2)), 0.4 * u])
    branches = [
        CanalModel("pipe", _line(at([-5.0, 2.0, 0.5]), j0), constant_spline(R_MAIN * scale), False, id=0,
                   ends=(None, 0)),
        CanalModel("pipe", _line(j0, at([7.0, 2.0, 0.5])), constant_spline(R_MAIN * scale), False, id=1,
                   ends=(0, None)),
        CanalModel("canal", _curve(canal), make_interp_spline([0.0, 0.5, 1.0], np.array([0.3, 0.26, 0.2]) * scale,
                                                              k=2), False, id=2, ends=(0, None)),
        CanalModel("pipe", _line(at([1.0, -8.0, 0.5]), j1), constant_spline(R_BENT * scale), False, id=3,
                   ends=(None, 1)),
        CanalModel("pipe", _curve(bent), constant_spline(R_BENT * scale), False, id=4, ends=(1, None)),
        CanalModel("pipe", _loop(at([10.0, 0.0, 3.0]), 2.0 * scale), constant_spline(R_LOOP * scale), True, id=5),
    ]
    junctions = [Junction(0, j0, [(0, 1), (1, 0), (2, 0)]), Junction(1, j1, [(3, 1), (4, 0)])]
    return Network(branches, junctions)


@pytest.fixture(scope="module")
def network():
    return _network()


@pytest.fixture(scope="module")
def written(network, tmp_path_factory):
    path = tmp_path_factory.mktemp("ifc") / "network.ifc"
    write_ifc(path, network, name="test plant")
    return ifcopenshell.open(str(path))


# --------------------------------------------------------------------------------------------------
# reading back


def _schema_errors(f, *, express_rules=False) -> list:
    logger = ifcopenshell.validate.json_logger()
    with warnings.catch_warnings():
        # ifcopenshell 0.9's rule executor reads its rules with open(...).read() and never closes the file
        warnings.simplefilter("ignore", ResourceWarning)
        ifcopenshell.validate.validate(f, logger, express_rules=express_rules)
    return logger.statements


def _settings(radius: float, metres_per_unit: float = 1.0):
    settings = ifcopenshell.geom.settings()
    settings.set("use-world-coords", True)
    settings.set("mesher-linear-deflection", DEFLECTION_PER_RADIUS * radius * metres_per_unit)
    settings.set("mesher-angular-deflection", ANGULAR_DEFLECTION)
    return settings


def _mesh(element, settings) -> tuple[np.ndarray, np.ndarray]:
    """The vertices and triangles ifcopenshell builds for an element (in metres unless told otherwise)."""
    shape = ifcopenshell.geom.create_shape(settings, element)
    return (np.asarray(shape.geometry.verts, dtype=float).reshape(-1, 3),
            np.asarray(shape.geometry.faces, dtype=int).reshape(-1, 3))


def _by_tag(f, entity: str) -> dict:
    return {int(e.Tag): e for e in f.by_type(entity)}


def _representation(element, identifier: str):
    """The single item of an element's representation of this identifier ("Body", "Axis")."""
    (shape,) = [r for r in element.Representation.Representations if r.RepresentationIdentifier == identifier]
    (item,) = shape.Items
    return item


def _pset(element, name: str) -> dict:
    for rel in element.IsDefinedBy:
        pset = rel.RelatingPropertyDefinition
        if pset.Name == name:
            return {p.Name: p.NominalValue.wrappedValue for p in pset.HasProperties}
    raise AssertionError(f"{element.Name} has no {name}")


def _surface_deviation(points, branch: CanalModel) -> np.ndarray:
    """Distance of each point from the branch's surface -- lateral, or a flat end cap -- over the radius."""
    t, d = footpoints(points, branch.spine, branch.radius, closed=branch.closed)
    deviation = np.abs(d) / branch.radius(t)
    if branch.closed:
        return deviation
    for end in (0.0, 1.0):
        c, dc = branch.spine(end), branch.spine.derivative(1)(end)
        tangent = dc / np.linalg.norm(dc)
        r = float(branch.radius(end))
        rho = float(branch.radius.derivative(1)(end)) / np.linalg.norm(dc)
        centre = c - r * rho * tangent  # the centre of the end's characteristic circle
        along = (points - centre) @ tangent
        across = np.linalg.norm(points - centre - along[:, None] * tangent, axis=1)
        on_cap = across <= r * math.sqrt(1 - rho**2) * (1 + TOL)
        deviation = np.where(on_cap, np.minimum(deviation, np.abs(along) / r), deviation)
    return deviation


# --------------------------------------------------------------------------------------------------
# the network without pieces


def test_knots_convert_to_distinct_values_and_multiplicities(network):
    for branch in network.branches:
        knots, multiplicities = ifc_knots(branch.spine.t)
        assert np.all(np.diff(knots) > 0)
        assert np.array_equal(np.repeat(knots, multiplicities), branch.spine.t)
    # a clamped cubic: end knots four times, the uneven interior knots once
    assert ifc_knots(network.branches[0].spine.t)[1] == [4, 1, 4]
    # the periodic loop keeps its unclamped knot vector, every knot once
    assert set(ifc_knots(network.branches[5].spine.t)[1]) == {1}


def test_file_is_valid_ifc4_with_a_spatial_structure(written):
    assert written.schema == "IFC4"
    assert _schema_errors(written) == []
    (project,) = written.by_type("IfcProject")
    assert project.Name == "test plant"
    (length,) = [u for u in project.UnitsInContext.Units if u.UnitType == "LENGTHUNIT"]
    assert (length.is_a(), length.Prefix, length.Name) == ("IfcSIUnit", None, "METRE")
    # project > site > building > storey, and the storey holds every element
    (site,) = [o for rel in project.IsDecomposedBy for o in rel.RelatedObjects]
    (building,) = [o for rel in site.IsDecomposedBy for o in rel.RelatedObjects]
    (storey,) = [o for rel in building.IsDecomposedBy for o in rel.RelatedObjects]
    assert (site.is_a(), building.is_a(), storey.is_a()) == ("IfcSite", "IfcBuilding", "IfcBuildingStorey")
    contained = {e.id() for rel in storey.ContainsElements for e in rel.RelatedElements}
    assert contained == {e.id() for e in written.by_type("IfcElement")}
    # near the origin: no map conversion
    assert written.by_type("IfcMapConversion") == ()


def test_one_segment_per_branch_and_one_fitting_per_junction(written, network):
    segments, fittings = _by_tag(written, "IfcPipeSegment"), _by_tag(written, "IfcPipeFitting")
    assert sorted(segments) == [b.id for b in network.branches]
    assert {j: fittings[j].PredefinedType for j in fittings} == {0: "JUNCTION", 1: "BEND"}
    for branch in network.branches:
        segment = segments[branch.id]
        assert len(segment.Representation.Representations) == 2
        item = _representation(segment, "Body")
        assert _representation(segment, "Axis").is_a("IfcBSplineCurveWithKnots")
        props = _pset(segment, "Canalsurf_Branch")
        assert props["BranchId"] == branch.id and props["Kind"] == branch.kind
        if branch.kind == "pipe":
            # swept along lines and arcs: straight spines give lines only, curved ones arcs
            assert item.is_a("IfcSweptDiskSolid") and item.Directrix.is_a("IfcIndexedPolyCurve")
            kinds = {s.is_a() for s in item.Directrix.Segments}
            assert kinds == ({"IfcLineIndex"} if branch.id in (0, 1, 3) else {"IfcArcIndex"})
            assert item.Radius == float(branch.radius.c[0]) == {0: R_MAIN, 1: R_MAIN, 5: R_LOOP}.get(branch.id, R_BENT)
            assert _pset(segment, "Pset_PipeSegmentTypeCommon")["OuterDiameter"] == 2 * item.Radius
        else:
            assert item.is_a("IfcTriangulatedFaceSet") and item.Closed
    # the fitting of junction 0 is connected to the three segments that meet there
    related = {rel.RelatedElement.Tag for rel in fittings[0].ConnectedTo}
    assert related == {"0", "1", "2"}


def _curve_distance(points, spine: BSpline, closed: bool) -> np.ndarray:
    """Distance of each point from a spine: the nearest of 20001 samples, then Newton steps on the footpoint."""
    samples = np.linspace(0.0, 1.0, 20001)
    nearest = np.linalg.norm(spine(samples)[None] - points[:, None], axis=2).argmin(axis=1)
    u, d1, d2 = samples[nearest], spine.derivative(1), spine.derivative(2)
    for _ in range(8):
        gap = spine(u) - points
        u = u - np.sum(gap * d1(u), axis=1) / (np.sum(d1(u) ** 2, axis=1) + np.sum(gap * d2(u), axis=1))
        u = u % 1.0 if closed else np.clip(u, 0.0, 1.0)
    return np.linalg.norm(spine(u) - points, axis=1)


def test_axis_is_the_spine_bspline(written, network):
    """The axis holds the model's own degree, knots and control points, and the curve ifcopenshell
    (OpenCASCADE) evaluates from it -- an independent B-spline evaluator -- runs along the spine."""
    segments = _by_tag(written, "IfcPipeSegment")
    settings = ifcopenshell.geom.settings()
    for branch in network.branches:
        curve = _representation(segments[branch.id], "Axis")
        knots = np.repeat(curve.Knots, curve.KnotMultiplicities)
        control = np.array([p.Coordinates for p in curve.ControlPointsList])
        assert curve.Degree == branch.spine.k and bool(curve.ClosedCurve) == branch.closed
        assert np.array_equal(knots, branch.spine.t) and np.array_equal(control, branch.spine.c)
        polyline = np.asarray(ifcopenshell.geom.create_shape(settings, curve).verts, dtype=float).reshape(-1, 3)
        # from the spine's start (to its end, if open), through points between on the curved spines
        ends = polyline[[0]] if branch.closed else polyline[[0, -1]]
        assert np.abs(ends - branch.spine([0.0, 1.0][: len(ends)])).max() < 1e-12 * EXTENT
        assert len(polyline) >= (2 if branch.id in (0, 1, 3) else 20)
        assert _curve_distance(polyline, branch.spine, branch.closed).max() < 1e-12 * EXTENT


def _arc_ends(p0, pm, p1):
    """Unit tangents at the ends of the arc through three points (of the line, if they are in line)."""
    a, b = p0 - pm, p1 - pm
    normal = np.cross(a, b)
    if not np.linalg.norm(normal) > 1e-12 * np.linalg.norm(a) * np.linalg.norm(b):  # in line (or a line)
        t = (p1 - p0) / np.linalg.norm(p1 - p0)
        return t, t
    # the circumcentre of the triangle
    centre = pm + np.cross(np.dot(a, a) * b - np.dot(b, b) * a, normal) / (2 * np.dot(normal, normal))
    axis = np.cross(p0 - centre, pm - centre)
    axis /= np.linalg.norm(axis)
    return [np.cross(axis, p - centre) / np.linalg.norm(p - centre) for p in (p0, p1)]


def test_arc_chain_is_tangent_continuous_and_on_the_spine(network):
    """The arcs a pipe is swept along: each joint smooth (so the swept pieces meet flush), every point
    written -- ends and midpoints of arcs -- within ARC_TOL r of the spine, a loop closed on its start."""
    for branch in network.branches:
        r = float(branch.radius(0.0))
        points, segments = arc_chain(branch.spine, closed=branch.closed, tol=ARC_TOL * r)
        assert all(a[-1] == b[0] for a, b in zip(segments, segments[1:]))
        assert segments[0][0] == 0 and segments[-1][-1] == (0 if branch.closed else len(points) - 1)
        assert _curve_distance(points, branch.spine, branch.closed).max() < ARC_TOL * r
        tangents = [_arc_ends(*points[list(s)]) if len(s) == 3 else _arc_ends(points[s[0]], points[s[0]], points[s[1]])
                    for s in segments]
        joints = list(zip(tangents, tangents[1:])) + ([(tangents[-1], tangents[0])] if branch.closed else [])
        assert max(np.linalg.norm(a[1] - b[0]) for a, b in joints) < 1e-9
        start = branch.spine.derivative(1)(0.0)
        assert np.linalg.norm(tangents[0][0] - start / np.linalg.norm(start)) < 1e-9


def test_the_examples_in_the_docstrings_run():
    result = doctest.testmod(canalsurf.ifc, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted >= 8


def test_geometry_lies_on_canalsurfs_surface(written, network):
    """Every vertex ifcopenshell builds: segments within 0.5 % r of their branch's surface, junctions on
    the sphere of the thickest end; the canal's faces (centroids) within 0.5 % r too."""
    settings = _settings(min(R_MAIN, R_BENT, R_LOOP, 0.2))
    worst = {}
    for branch_id, segment in _by_tag(written, "IfcPipeSegment").items():
        branch = network.branches[branch_id]
        vertices, faces = _mesh(segment, settings)
        assert len(vertices) > 100
        worst[branch_id] = float(_surface_deviation(vertices, branch).max())
        if branch.kind == "canal":
            centroids = vertices[faces].mean(axis=1)
            worst["canal faces"] = float(_surface_deviation(centroids, branch).max())
    assert max(worst.values()) < TOL, worst
    fittings = _by_tag(written, "IfcPipeFitting")
    for junction in network.junctions:
        radius = max(float(network.branches[b].radius(e)) for b, e in junction.ends)
        vertices, _ = _mesh(fittings[junction.id], settings)
        assert np.abs(np.linalg.norm(vertices - junction.point, axis=1) - radius).max() < TOL * radius
    # the junction of straight pipes of radius 0.4 and a canal of radius 0.3 there: the pipes' sphere
    assert _pset(fittings[0], "Canalsurf_Junction")["Radius"] == R_MAIN


# --------------------------------------------------------------------------------------------------
# placement and units


@pytest.mark.parametrize("crs", [None, "EPSG:25832"])
def test_georeferenced_scan_stays_georeferenced(tmp_path, crs):
    network = _network(offset=UTM)
    path = tmp_path / "utm.ifc"
    write_ifc(path, network, crs=crs)
    f = ifcopenshell.open(str(path))
    assert _schema_errors(f) == []
    (conversion,) = f.by_type("IfcMapConversion")
    (context,) = f.by_type("IfcGeometricRepresentationContext", include_subtypes=False)
    assert conversion.SourceCRS == context
    assert conversion.TargetCRS.Name == (crs or "UNKNOWN")
    assert conversion.TargetCRS.MapUnit.Name == "METRE"
    offset = np.array([conversion.Eastings, conversion.Northings, conversion.OrthogonalHeight])
    # x and y lie thousands of extents from the origin, the height 231.5 only ~20 extents: not moved;
    # the offset is rounded to hundreds (the extent is ~17)
    assert list(offset) == [512300.0, 5403200.0, 0.0]
    assert (conversion.XAxisAbscissa, conversion.XAxisOrdinate) == (1.0, 0.0)
    # every coordinate comes back bit for bit: control points and junction points
    segments = _by_tag(f, "IfcPipeSegment")
    for branch in network.branches:
        curve = _representation(segments[branch.id], "Axis")
        local = np.array([p.Coordinates for p in curve.ControlPointsList])
        assert np.abs(local[:, :2]).max() < 100.0
        assert np.array_equal(local + offset, branch.spine.c)
    for fitting in f.by_type("IfcPipeFitting"):
        sphere = _representation(fitting, "Body").TreeRootExpression
        point = np.array(sphere.Position.Location.Coordinates) + offset
        assert np.array_equal(point, network.junctions[int(fitting.Tag)].point)
    # the built geometry, moved back by the offset, lies on the surface of the georeferenced model
    settings = _settings(R_BENT)
    for branch_id in (2, 4):
        vertices, _ = _mesh(segments[branch_id], settings)
        assert _surface_deviation(vertices + offset, network.branches[branch_id]).max() < TOL


@pytest.mark.parametrize("share", [0.99, 1.01])
def test_far_from_origin_threshold(tmp_path, share):
    """The rule: an axis whose centre lies more than FAR_FROM_ORIGIN_EXTENTS extents from the origin is
    written relative to the centre rounded down to a whole hundred (the power of ten above the extent)."""
    control = np.concatenate([b.spine.c for b in _network().branches])  # their hull holds the spines
    low, high = control.min(axis=0), control.max(axis=0)
    extent, centre = (high - low).max(), (low + high) / 2
    assert 10 < extent < 100
    shift = share * FAR_FROM_ORIGIN_EXTENTS * extent - centre[0]
    path = tmp_path / "site.ifc"
    write_ifc(path, _network(offset=np.array([shift, 0.0, 0.0])))
    conversions = ifcopenshell.open(str(path)).by_type("IfcMapConversion")
    if share < 1:
        assert conversions == ()
    else:
        (conversion,) = conversions
        expected = math.floor((centre[0] + shift) / 100) * 100
        assert (conversion.Eastings, conversion.Northings, conversion.OrthogonalHeight) == (expected, 0.0, 0.0)


@pytest.mark.parametrize(("units", "metres"), [("mm", 1e-3), ("ft", 0.3048)])
def test_units(tmp_path, units, metres):
    """A model in millimetres or feet: the unit is declared, the coordinates kept, and ifcopenshell
    (which builds geometry in metres) scales it right."""
    scale = 1.0 / metres  # the same plant, its coordinates in this unit
    network = _network(scale=scale)
    path = tmp_path / f"{units}.ifc"
    write_ifc(path, network, units=units)
    f = ifcopenshell.open(str(path))
    assert _schema_errors(f) == []
    (length,) = [u for u in f.by_type("IfcProject")[0].UnitsInContext.Units if u.UnitType == "LENGTHUNIT"]
    if units == "mm":
        assert (length.is_a(), length.Prefix, length.Name) == ("IfcSIUnit", "MILLI", "METRE")
    else:
        assert (length.is_a(), length.Name) == ("IfcConversionBasedUnit", "FOOT")
        assert length.ConversionFactor.ValueComponent.wrappedValue == 0.3048
        assert length.ConversionFactor.UnitComponent.Name == "METRE"
    segments = _by_tag(f, "IfcPipeSegment")
    assert _representation(segments[0], "Body").Radius == R_MAIN * scale
    settings = _settings(R_BENT * scale, metres)
    for branch_id in (2, 4):
        vertices, _ = _mesh(segments[branch_id], settings)
        assert _surface_deviation(vertices / metres, network.branches[branch_id]).max() < TOL


# --------------------------------------------------------------------------------------------------
# pieces


R_RUN, R_OUTLET, BEND_RADIUS = 0.1, 0.05, 0.45


def _piped_network() -> tuple[Network, list[Piece]]:
    """A tee of three straight pipes at the origin (run along x, outlet along y), an L-shaped pipe (a
    straight, a 90 degree elbow, a straight, a reducer), a 270 degree elbow, and a canal no piece covers.

    The pieces are laid out as canalsurf.piping lays them out: straights from the junction point, a tee
    as a point (start = end = centre) with its branches (run, run, outlet).
    """
    o = np.zeros(3)
    x, y, z = np.eye(3)
    corner, bend_centre = np.array([4.0, 0.0, 1.0]), np.array([4.0, BEND_RADIUS, 1.0])
    arc_end = corner + BEND_RADIUS * (x + y)
    reduced = arc_end + 2.0 * y
    u = np.linspace(0.0, 1.0, 65)
    l_path = np.concatenate([
        corner + np.outer(u, x) - x * 2.0,
        bend_centre + BEND_RADIUS * np.column_stack([np.sin(u * np.pi / 2), -np.cos(u * np.pi / 2), 0 * u]),
        arc_end + np.outer(u, 2.0 * y)])
    l_path = l_path[np.r_[True, np.linalg.norm(np.diff(l_path, axis=0), axis=1) > 0]]
    branches = [
        CanalModel("pipe", _line(-3 * x, o), constant_spline(R_RUN), False, id=0, ends=(None, 0)),
        CanalModel("pipe", _line(o, 3 * x), constant_spline(R_RUN), False, id=1, ends=(0, None)),
        CanalModel("pipe", _line(o, 2 * y), constant_spline(R_OUTLET), False, id=2, ends=(0, None)),
        CanalModel("pipe", _curve(l_path), constant_spline(R_RUN), False, id=3),
        CanalModel("canal", _line([0.0, 0.0, 3.0], [3.0, 0.0, 3.0]), make_interp_spline([0.0, 1.0], [0.2, 0.15], k=1),
                   False, id=4),
    ]
    network = Network(branches, [Junction(0, o, [(0, 1), (1, 0), (2, 0)])])
    d, d_out = 2 * R_RUN, 2 * R_OUTLET
    three_quarter = np.array([6.0, 0.0, 0.0])  # a 270 degree bend about this centre, from -y round to +x
    pieces = [
        Piece(0, "straight", 0, (0,), -3 * x, o, d, d, 3.0, None, None, None, "DN 200", 0.2191),
        Piece(1, "straight", 1, (1,), o, 3 * x, d, d, 3.0, None, None, None, None, None),
        Piece(2, "straight", 2, (2,), o, 2 * y, d_out, d_out, 2.0, None, None, None, None, None),
        Piece(3, "straight", 3, (3,), corner - 2 * x, corner, d, d, 2.0, None, None, None, None, None),
        Piece(4, "elbow", 3, (3,), corner, arc_end, d, d, BEND_RADIUS * np.pi / 2, BEND_RADIUS, 90.0, bend_centre,
              None, None),
        Piece(5, "straight", 3, (3,), arc_end, reduced - 0.3 * y, d, d, 1.7, None, None, None, None, None),
        Piece(6, "reducer", 3, (3,), reduced - 0.3 * y, reduced, d, d_out, 0.3, None, None, None, None, None),
        Piece(7, "elbow", 3, (3,), three_quarter - BEND_RADIUS * y, three_quarter + BEND_RADIUS * x, d, d,
              BEND_RADIUS * 1.5 * np.pi, BEND_RADIUS, 270.0, three_quarter, None, None),
        Piece(8, "tee", 0, (0, 1, 2), o, o, d, d, 0.0, None, None, o.copy(), "DN 200", 0.2191, outlet_diameter=d_out,
              outlet_nominal="DN 100"),
    ]
    return network, pieces


@pytest.fixture(scope="module")
def piped(tmp_path_factory):
    network, pieces = _piped_network()
    path = tmp_path_factory.mktemp("ifc") / "pieces.ifc"
    write_ifc(path, network, pieces=pieces)
    return network, pieces, ifcopenshell.open(str(path))


def test_pieces_entities_and_properties(piped):
    network, pieces, f = piped
    # the schema's where rules too (IfcIndexedPolyCurve, IfcMapConversion, representation types ...)
    assert _schema_errors(f, express_rules=True) == []
    elements = {e.Name: e for e in f.by_type("IfcElement")}
    kinds = {name: (e.is_a(), e.PredefinedType) for name, e in elements.items()}
    segment, bend = ("IfcPipeSegment", "RIGIDSEGMENT"), ("IfcPipeFitting", "BEND")
    assert kinds == {
        "straight 0": segment, "straight 1": segment, "straight 2": segment, "straight 3": segment,
        "elbow 4": bend, "straight 5": segment, "reducer 6": ("IfcPipeFitting", "TRANSITION"), "elbow 7": bend,
        "tee 8": ("IfcPipeFitting", "JUNCTION"),
        # the canal no piece covers is written as a branch, and no junction sphere (its branches are pieces)
        "branch 4 (canal)": ("IfcPipeSegment", "USERDEFINED")}
    first = _pset(elements["straight 0"], "Canalsurf_Piece")
    assert (first["NominalSize"], first["CatalogueOuterDiameter"], first["OutsideDiameter"]) == ("DN 200", 0.2191, 0.2)
    assert _pset(elements["straight 0"], "Pset_PipeSegmentTypeCommon")["OuterDiameter"] == 0.2191
    assert _pset(elements["straight 1"], "Pset_PipeSegmentTypeCommon")["OuterDiameter"] == 0.2
    for name, angle in (("elbow 4", np.pi / 2), ("elbow 7", 1.5 * np.pi)):
        props = _pset(elements[name], "Pset_PipeFittingTypeBend")
        assert props["BendRadius"] == BEND_RADIUS and abs(props["BendAngle"] - angle) < 1e-12
    assert _pset(elements["tee 8"], "Pset_PipeFittingTypeJunction")["JunctionType"] == "TEE"
    tee = _pset(elements["tee 8"], "Canalsurf_Piece")
    assert (tee["OutletDiameter"], tee["OutletNominalSize"], tee["Branches"]) == (0.1, "DN 100", "0, 1, 2")
    assert _pset(elements["reducer 6"], "Canalsurf_Piece")["EndDiameter"] == 0.1
    # the elbow's directrix is an arc of a circle, trimmed by angle (radians) and by its end points
    arc = _representation(elements["elbow 4"], "Body").Directrix
    assert arc.is_a("IfcTrimmedCurve") and arc.BasisCurve.is_a("IfcCircle")
    assert arc.BasisCurve.Radius == BEND_RADIUS
    assert [v.wrappedValue for v in arc.Trim2 if v.is_a("IfcParameterValue")] == [pytest.approx(np.pi / 2)]


def _cylinder_deviation(points, a, b, radius):
    """Distance from the capped cylinder of axis a -> b, over its radius (inf off its length)."""
    axis = (b - a) / np.linalg.norm(b - a)
    along = (points - a) @ axis
    across = np.linalg.norm(points - a - along[:, None] * axis, axis=1)
    length = np.linalg.norm(b - a)
    lateral = np.where((along > -TOL * radius) & (along < length + TOL * radius), np.abs(across - radius), np.inf)
    caps = np.where(across <= radius * (1 + TOL), np.minimum(np.abs(along), np.abs(along - length)), np.inf)
    return np.minimum(lateral, caps) / radius


def _disc_deviation(points, centre, normal, radius):
    """Distance from the disc of ``radius`` about ``centre`` with this normal, over the radius (inf off it)."""
    normal = normal / np.linalg.norm(normal)
    along = (points - centre) @ normal
    across = np.linalg.norm(points - centre - along[:, None] * normal, axis=1)
    return np.where(across <= radius * (1 + TOL), np.abs(along) / radius, np.inf)


def _elbow_deviation(points, piece, turn_degrees):
    """Distance from the elbow's torus (between its end discs) over the tube radius; asserts that every
    point lies within the turn from start to end."""
    r = piece.outside_diameter / 2
    arm = piece.start - piece.centre
    normal = np.cross(arm, piece.end - piece.centre) * (1 if turn_degrees < 180 else -1)
    normal /= np.linalg.norm(normal)
    rel = points - piece.centre
    height = rel @ normal
    planar = np.linalg.norm(rel - height[:, None] * normal, axis=1)
    deviation = np.abs(np.hypot(planar - piece.bend_radius, height) - r) / r
    ends = [_disc_deviation(points, p, np.cross(normal, p - piece.centre), r) for p in (piece.start, piece.end)]
    x_axis = arm / np.linalg.norm(arm)
    turned = np.degrees(np.arctan2(rel @ np.cross(normal, x_axis), rel @ x_axis)) % 360
    turned[turned > 359.99] -= 360  # the start disc, on either side of 0
    assert turned.min() > -0.01 and turned.max() < turn_degrees + 0.01
    return np.minimum.reduce([deviation] + ends)


def test_pieces_geometry(piped):
    """Each piece's solid, as ifcopenshell builds it, is the shape its fields describe (within 0.5 % of
    its radius), and the pieces of the pipes lie on the network's own tubes."""
    network, pieces, f = piped
    settings = _settings(R_OUTLET)
    elements = {e.Name: e for e in f.by_type("IfcElement")}
    x, y = np.eye(3)[:2]
    for piece in pieces:
        vertices, _ = _mesh(elements[f"{piece.type} {piece.id}"], settings)
        r = piece.outside_diameter / 2
        if piece.type == "straight":
            deviation = _cylinder_deviation(vertices, piece.start, piece.end, r)
        elif piece.type == "elbow":
            deviation = _elbow_deviation(vertices, piece, piece.angle)
        elif piece.type == "reducer":
            axis = (piece.end - piece.start) / np.linalg.norm(piece.end - piece.start)
            along = (vertices - piece.start) @ axis
            across = np.linalg.norm(vertices - piece.start - along[:, None] * axis, axis=1)
            cone = r + (piece.end_diameter / 2 - r) * along / piece.length
            deviation = np.minimum(np.abs(across - cone) / r, _cylinder_deviation(vertices, piece.start, piece.end, r))
            assert along.min() > -TOL * r and along.max() < piece.length + TOL * r
            assert across.max() == pytest.approx(r, rel=TOL) and across[along > piece.length / 2].max() < 0.8 * r
        else:
            # a tee drawn as a point: stubs of the run's radius out to it along the branches' tangents (the
            # run along x, the outlet along y, of the outlet's radius), and a sphere of it closing the joint
            run = _cylinder_deviation(vertices, -r * x, r * x, r)
            outlet = _cylinder_deviation(vertices, piece.centre, r * y, R_OUTLET) * (R_OUTLET / r)
            sphere = np.abs(np.linalg.norm(vertices - piece.centre, axis=1) - r) / r
            deviation = np.minimum.reduce([run, outlet, sphere])
            # the run's stubs end a radius from the centre either way along x, the outlet's along y
            assert np.abs(vertices[:, 0]).max() == pytest.approx(r) and vertices[:, 1].max() == pytest.approx(r)
            # the outlet's stub, where it leaves the sphere, lies on the outlet branch's tube
            off_axis = np.hypot(vertices[:, 0], vertices[:, 2])
            outside = (vertices[:, 1] > math.sqrt(r**2 - R_OUTLET**2) * (1 + TOL))
            stub = vertices[outside & (np.abs(off_axis - R_OUTLET) < TOL * R_OUTLET)]
            assert len(stub) >= 16 and _surface_deviation(stub, network.branches[2]).max() < TOL
        assert deviation.max() < TOL, (piece.type, piece.id, float(deviation.max()))
    # the straights of the T are the network's tubes, not only the pieces' idea of them
    for piece in pieces[:3]:
        vertices, _ = _mesh(elements[f"straight {piece.id}"], settings)
        assert _surface_deviation(vertices, network.branches[piece.branch]).max() < TOL


def test_pieces_of_the_decomposition(tmp_path):
    """canalsurf.piping's own pieces of a network: one element each, valid, on the network's tubes within
    the decomposition's tolerance (the pieces, not the export, decide that accuracy)."""
    network, _ = _piped_network()
    network = Network(network.branches[:4], network.junctions)  # the pipes
    pieces = decompose(network)
    path = tmp_path / "decomposed.ifc"
    write_ifc(path, network, pieces=pieces)
    f = ifcopenshell.open(str(path))
    assert _schema_errors(f) == []
    elements = {int(e.Tag): e for e in f.by_type("IfcElement")}
    assert sorted(elements) == [p.id for p in pieces]
    settings = _settings(R_OUTLET)
    for piece in pieces:
        if piece.type == "tee":
            continue  # a point: its stubs run along the branches, the sphere inside the run
        vertices, _ = _mesh(elements[piece.id], settings)
        branch = network.branches[piece.branch]
        r = float(branch.radius.c[0])
        assert _surface_deviation(vertices, branch).max() * r < piece.fit_tolerance + TOL * r, piece


# --------------------------------------------------------------------------------------------------
# bad input and the missing extra


def test_missing_extra_names_it(tmp_path, monkeypatch, network):
    monkeypatch.setitem(sys.modules, "ifcopenshell", None)
    message = r"^writing \.ifc files needs the 'ifc' extra — pip install 'canalsurf\[ifc\]'$"
    with pytest.raises(InputError, match=message):
        write_ifc(tmp_path / "x.ifc", network)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"units": "km"}, r"units must be one of 'm', 'mm', 'ft', 'in' \(the unit of the model's coordinates\), got 'km'"),
    ({"name": ""}, r"name must be a non-empty string, got ''"),
    ({"pieces": "straight"}, r"pieces must be a sequence of pieces"),
])
def test_bad_options(tmp_path, network, kwargs, message):
    with pytest.raises(InputError, match=message):
        write_ifc(tmp_path / "x.ifc", network, **kwargs)
    assert os.listdir(tmp_path) == []


def test_bad_network_and_pieces(tmp_path, network):
    with pytest.raises(InputError, match=r"network must be a canalsurf Network .* got ndarray"):
        write_ifc(tmp_path / "x.ifc", np.zeros((10, 3)))
    _, pieces = _piped_network()
    elbow = pieces[4]

    @dataclass
    class Partial:
        id: int = 0
        type: str = "straight"

    with pytest.raises(InputError, match=r"^piece 0 has no field 'branches' — give the pieces canalsurf.piping made "
                                         r"for this network$"):
        write_ifc(tmp_path / "x.ifc", network, pieces=[Partial()])
    with pytest.raises(InputError, match=r"^piece 0 has type 'bend'; a piece is one of 'straight', 'elbow', 'tee', "
                                         r"'reducer'$"):
        write_ifc(tmp_path / "x.ifc", network, pieces=[Partial(type="bend")])
    off_arc = dataclasses.replace(elbow, end=elbow.end + 0.01)
    with pytest.raises(InputError, match=r"piece 0 \(elbow\): start and end lie .* not on the bend radius 0.45"):
        write_ifc(tmp_path / "x.ifc", network, pieces=[off_arc])
    nan_start = dataclasses.replace(pieces[0], start=np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(InputError, match=r"piece 0 start must be a finite \(x, y, z\) point"):
        write_ifc(tmp_path / "x.ifc", network, pieces=[nan_start])
    with pytest.raises(InputError, match=r"does not exist — create it first"):
        write_ifc(tmp_path / "missing" / "x.ifc", network)
    assert os.listdir(tmp_path) == []


def test_write_replaces_atomically(tmp_path):
    pipe = CanalModel("pipe", _line([0.0, 0.0, 0.0], [2.0, 0.0, 0.0]), constant_spline(0.1), False)
    path = tmp_path / "pipe.ifc"
    path.write_text("old")
    write_ifc(path, pipe)
    assert os.listdir(tmp_path) == ["pipe.ifc"]
    f = ifcopenshell.open(str(path))
    assert len(f.by_type("IfcPipeSegment")) == 1 and f.by_type("IfcPipeFitting") == ()
