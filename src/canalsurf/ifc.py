"""IFC 4 export: a network's tubes as pipe segments and fittings a BIM tool can open.

:func:`write_ifc` writes one ``.ifc`` file (IFC 4, STEP physical file) with ifcopenshell (extra ``ifc``).

Without pieces, every branch is one ``IfcPipeSegment`` and every junction one ``IfcPipeFitting``:

* every branch has the spine itself as its ``Axis`` representation: an ``IfcBSplineCurveWithKnots``
  with the model's degree, control points and knots (scipy's full knot vector as IFC's distinct knots
  and their multiplicities; a closed spine keeps its periodic knot vector, which IFC's B-spline -- that
  of ISO 10303-42 -- evaluates on the same inner domain [0, 1]).
* a **pipe** branch's body is an ``IfcSweptDiskSolid`` of its radius along a tangent-continuous chain
  of circular arcs (an ``IfcIndexedPolyCurve``, :func:`arc_chain`) within ``ARC_TOL`` of the radius of
  the spine.  Not along the B-spline: OpenCASCADE (ifcopenshell's kernel) sweeps a disk along a
  B-spline wrongly where it is straight or nearly so (see ``ARC_TOL``), while arcs and lines are
  swept exactly -- revolutions and extrusions -- by every kernel.  A viewer's tessellation puts its
  vertices on the arcs' tube, within ``ARC_TOL`` r of the model's surface.
* a **canal** branch (a radius that varies) is an ``IfcTriangulatedFaceSet``: canalsurf's own mesh of
  the branch (:func:`canalsurf.surface.surface_mesh`), whose vertices lie on the envelope of the
  spheres, with enough vertices per ring and rings that no face strays more than ``FACE_SAG`` of the
  radius from it in either direction.  A swept disk has one radius, so a canal would need a stretch
  per radius step -- 0.5 % of the radius per step is hundreds of stretches on a tapering vessel, and
  a disk normal to the spine is not the envelope's characteristic circle where the radius changes.
* a **junction** is an ``IfcPipeFitting`` (``JUNCTION`` where three or more branch ends meet, ``BEND``
  where two do) whose body is the sphere of the thickest end's radius about the junction point: the
  branch solids end flat at the junction, and the sphere fills the gaps between them as the envelope
  of the spheres along each spine does; it lies inside the thickest branch's envelope.

With ``pieces`` (the piping decomposition, :mod:`canalsurf.piping`) each piece is one element:
straight -> ``IfcPipeSegment`` ``RIGIDSEGMENT`` (a swept disk along a line), elbow -> ``IfcPipeFitting``
``BEND`` (a swept disk along a trimmed ``IfcCircle``), tee -> ``IfcPipeFitting`` ``JUNCTION`` (swept
disks from the junction point along each of its branches, and a sphere that closes the joint),
reducer -> ``IfcPipeFitting`` ``TRANSITION`` (a cone: an ``IfcExtrudedAreaSolidTapered`` of a circle).
Branches no piece belongs to, and the junctions among them, are written as without pieces.  Measured
and catalogue sizes go into ``Pset_PipeSegmentTypeCommon`` / ``Pset_PipeFittingTypeBend`` and the
project's own ``Canalsurf_Piece`` property set.

Every element sits in a spatial structure (IfcProject > IfcSite > IfcBuilding > IfcBuildingStorey, all
placed at the origin), so BIM tools list it.  Lengths are in the model's own units (``units``).  A
georeferenced scan stays georeferenced: coordinates farther from the origin than
``FAR_FROM_ORIGIN_EXTENTS`` times the network's extent are written relative to a rounded local
origin, which an ``IfcMapConversion`` (Eastings, Northings, OrthogonalHeight) on the model's
representation context records, with an ``IfcProjectedCRS`` naming the coordinate reference system
(``crs``, or ``UNKNOWN``).  The rounding makes ``local + offset`` give back every written coordinate
bit for bit.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import BSpline

from .errors import InputError
from .piping import Piece
from .io import PathLike, _as_path, _import_extra, atomic_write

__all__ = ["write_ifc", "ifc_knots", "arc_chain", "LENGTH_UNITS", "FAR_FROM_ORIGIN_EXTENTS", "FACE_SAG", "ARC_TOL",
           "PIECE_ENTITIES"]

#: Length units a model's coordinates may be in, and the metres in one: the SI metre and millimetre,
#: and the international foot and inch (exactly 0.3048 m and 0.0254 m since 1959).
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "ft": 0.3048, "in": 0.0254}
#: How each is written: an IfcSIUnit with this prefix, or an IfcConversionBasedUnit of this name (the
#: names IFC 4's documentation of IfcConversionBasedUnit lists).
_SI_PREFIX = {"m": None, "mm": "MILLI"}
_CONVERTED_NAME = {"ft": "FOOT", "in": "INCH"}

#: A coordinate axis whose centre lies farther from the origin than this many extents of the network is
#: written relative to a rounded local origin (recorded by IfcMapConversion).  A site's own coordinate
#: system has its origin on or beside the site, within a few extents; a map projection (UTM, a national
#: grid) puts it hundreds of kilometres away, thousands of extents of any plant; 100 lies between.
#: Viewers that hold coordinates in float32 (7 digits) also lose the shape's digits beyond that.
FAR_FROM_ORIGIN_EXTENTS = 100.0
#: The local origin is a whole multiple of a power of ten at least the extent (and at least 1 unit),
#: rounded towards zero: a whole number, so ``coordinate - origin`` is exact in float64 (see
#: :func:`_local_origin`) and the offset reads well (Eastings 512300, not 512345.678).
MIN_ORIGIN_STEP = 1.0

#: Most a face of a canal's tessellated body strays from the surface, as a share of the local radius,
#: around (a chord of the ring) and along (a chord between rings on the outer side of a bend) the
#: tube: a face strays at most twice this, 0.3 %, within the 0.5 % of the radius the export is held to.
FACE_SAG = 1.5e-3
#: Spine samples on which a canal's curvature and radius are read to space its rings.
_RING_SAMPLES = 2001

#: Most distance between a pipe's spine and the arcs its swept disk follows, as a share of its radius:
#: the disk's surface is then within this of the pipe's, a fifth of the 0.5 % the export is held to.
#: (The spine B-spline itself is the element's Axis; as a directrix it is swept wrongly -- OpenCASCADE's
#: pipe shell, which ifcopenshell 0.9 uses, loses its frame where the spine is straight: measured 26 % of
#: the radius off on a straight cubic spine, 20 % on a reconstructed one, no solid at all on a
#: straight-arc-straight one.  Arcs and lines are swept exactly, as revolutions and extrusions, by every
#: kernel, and are the directrix IFC 4's Reference View allows.)
ARC_TOL = 1e-3
#: An arc whose sagitta is below this share of the tolerance is written as its chord (a circle through
#: three nearly collinear points is ill-conditioned in a reader).
LINE_SAGITTA_PER_TOL = 0.01
#: Samples of the spine and of its biarc on each piece, compared as polylines: their chords sag by
#: (piece length)^2 x curvature / 8192, a small share of the tolerance on the short pieces a bend is
#: halved into (tests/test_ifc.py checks the swept solids themselves).
ARC_CHECK_SAMPLES = 33
#: Shortest parameter piece the halving makes (a guard: smooth spines stop far earlier).
ARC_MIN_PIECE = 1e-9

#: Precision of the representation context (IFC: the distance under which points are the same) as a
#: share of the thinnest radius (rounded down to a power of ten): far below the 0.5 % of the radius the
#: geometry is held to, and far above float64 rounding of coordinates in a local frame.
PRECISION_PER_RADIUS = 1e-5

#: Piece types of the piping decomposition and the IFC entity and predefined type of each.
PIECE_ENTITIES = {"straight": ("IfcPipeSegment", "RIGIDSEGMENT"), "elbow": ("IfcPipeFitting", "BEND"),
                  "tee": ("IfcPipeFitting", "JUNCTION"), "reducer": ("IfcPipeFitting", "TRANSITION")}
#: An elbow's start and end may lie off its bend circle by this share of the bend radius (rounding in the
#: decomposition; the arc written, from the centre and radius, then passes that close to them); farther,
#: the piece does not describe an arc.
ELBOW_RADIUS_TOL = 1e-4
#: A tee's branch whose direction lies within this angle (degrees) of another's is the same port.
TEE_SAME_PORT_DEGREES = 1.0

#: Name of the project when none is given.
DEFAULT_NAME = "canalsurf network"
#: Name of the map coordinate reference system when none is given.
UNKNOWN_CRS = "UNKNOWN"


#: Fields a piece may have beyond the interface (canalsurf.piping.Piece has them), written to its property
#: set when given: field -> (property, IFC measure type).
_OPTIONAL_FIELDS = {
    "end_nominal": ("EndNominalSize", "IfcLabel"),
    "end_catalogue_diameter": ("EndCatalogueOuterDiameter", "IfcPositiveLengthMeasure"),
    "outlet_diameter": ("OutletDiameter", "IfcPositiveLengthMeasure"),
    "outlet_nominal": ("OutletNominalSize", "IfcLabel"),
    "outlet_catalogue_diameter": ("OutletCatalogueOuterDiameter", "IfcPositiveLengthMeasure"),
    "fit_deviation": ("FitDeviation", "IfcLengthMeasure"),
    "fit_tolerance": ("FitTolerance", "IfcLengthMeasure"),
}


def write_ifc(path: PathLike, network, *, units: str = "m", pieces=None, name: str | None = None,
              crs: str | None = None) -> None:
    """Write a network as an IFC 4 file of pipe segments and fittings.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.ifc`` file to write (always a STEP physical file, whatever the suffix); written to a
        temporary file beside it first and moved into place once complete.
    network : Network or CanalModel
        The result of :func:`canalsurf.reconstruct` (or :func:`canalsurf.load_model`); a single
        :class:`~canalsurf.model.CanalModel` is written as a network of one branch.
    units : {"m", "mm", "ft", "in"}
        The unit the model's coordinates are in (that of the scan: canalsurf keeps the input's units).
        The file declares it (IfcSIUnit metre or millimetre, IfcConversionBasedUnit foot or inch) and
        keeps every coordinate as it is, so BIM tools scale the model correctly.
    pieces : sequence, optional
        The piping decomposition of this network (:mod:`canalsurf.piping`): objects with the fields
        ``id, type, branch, branches, start, end, outside_diameter, end_diameter, length, bend_radius,
        angle, centre, nominal, catalogue_diameter`` (see the module docstring for how each type is
        written).  By default each branch is one segment and each junction one fitting.
    name : str, optional
        The project's name (``IfcProject.Name``); default ``"canalsurf network"``.
    crs : str, optional
        The coordinate reference system of a georeferenced scan, e.g. ``"EPSG:25832"``, written as the
        ``IfcProjectedCRS`` name when the coordinates are far from the origin; default ``UNKNOWN``.

    Raises
    ------
    InputError
        ifcopenshell is not installed (the ``ifc`` extra), ``network`` is not a network, ``units`` is
        not one of the four, a piece lacks a field or does not describe its shape, or the file cannot
        be written there.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import numpy as np
    >>> from scipy.interpolate import make_interp_spline
    >>> from canalsurf.model import CanalModel
    >>> from canalsurf.spine import constant_spline
    >>> spine = make_interp_spline([0.0, 1.0], [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], k=1)
    >>> pipe = CanalModel("pipe", spine, constant_spline(0.1), False)
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "pipe.ifc"
    >>> write_ifc(target, pipe, units="m")
    >>> target.read_text().count("IFCPIPESEGMENT(")
    1
    """
    target = _as_path(path)
    branches, junctions = _as_network(network)
    units = _as_units(units)
    name = _as_label(DEFAULT_NAME if name is None else name, "name")
    crs = _as_label(UNKNOWN_CRS if crs is None else crs, "crs")
    pieces = [] if pieces is None else _as_pieces(pieces)
    ifcopenshell = _import_extra("ifcopenshell", ".ifc", "ifc", "writing")

    origin = _local_origin(_all_points(branches, junctions, pieces))
    thinnest = min([float(np.min(_radii(b))) for b in branches] + [p.outside_diameter / 2 for p in pieces])
    precision = 10.0 ** math.floor(math.log10(PRECISION_PER_RADIUS * thinnest))
    ifc = _new_file(ifcopenshell, name, units, origin, crs, precision)
    ifc.file.header.file_name.name = target.name

    covered = {p.branch for p in pieces} | {b for p in pieces for b in p.branches}
    for piece in pieces:
        _add_piece(ifc, piece, branches, junctions, origin)
    segments = {b.id: _add_branch(ifc, b, origin) for b in branches if b.id not in covered}
    for junction in junctions:
        if any(b not in covered for b, _ in junction.ends):
            _add_junction(ifc, junction, branches, segments, origin)

    ifc.file.createIfcRelContainedInSpatialStructure(_guid(ifc), None, None, None, ifc.elements, ifc.storey)
    atomic_write(target, lambda tmp: ifc.file.write(str(tmp), format=".ifc"))


# --------------------------------------------------------------------------------------------------
# checks at the boundary


def _as_network(network) -> tuple[list, list]:
    """The branches and junctions of a Network (or of a lone CanalModel), or InputError."""
    from .model import CanalModel
    from .network import Network

    if isinstance(network, CanalModel):
        return [network], []
    if not isinstance(network, Network):
        raise InputError(f"network must be a canalsurf Network (from canalsurf.reconstruct or load_model), "
                         f"got {type(network).__name__}")
    if not network.branches:
        raise InputError("network has no branches — there is nothing to write")
    ids = [b.id for b in network.branches]
    if len(set(ids)) != len(ids):
        raise InputError(f"network branch ids repeat ({ids}) — give a network from canalsurf.reconstruct")
    return list(network.branches), list(network.junctions)


def _as_units(units) -> str:
    if not isinstance(units, str) or units not in LENGTH_UNITS:
        raise InputError(f"units must be one of {', '.join(map(repr, LENGTH_UNITS))} (the unit of the model's "
                         f"coordinates), got {units!r}")
    return units


def _as_label(value, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise InputError(f"{what} must be a non-empty string, got {value!r}")
    return value


def _field(piece, key: str, index: int):
    try:
        return getattr(piece, key)
    except AttributeError:
        raise InputError(f"piece {index} has no field '{key}' — give the pieces canalsurf.piping made for "
                         "this network") from None


def _number(value, what: str, *, positive: bool = True, optional: bool = False) -> float | None:
    if value is None and optional:
        return None
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (positive and value <= 0):
        need = "a positive number" if positive else "a finite number"
        raise InputError(f"{what} must be {need}, got {value!r} — give the pieces canalsurf.piping made")
    return float(value)


def _whole(value, what: str, *, optional: bool = False) -> int | None:
    if value is None and optional:
        return None
    if not isinstance(value, numbers.Integral) or isinstance(value, bool):
        raise InputError(f"{what} must be a whole number, got {value!r} — give the pieces canalsurf.piping made")
    return int(value)


def _optional(value, what: str, kind: str):
    return str(value) if kind == "IfcLabel" else _number(value, what, positive=kind == "IfcPositiveLengthMeasure")


def _point(value, what: str, *, optional: bool = False) -> np.ndarray | None:
    if value is None and optional:
        return None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(1, np.nan)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise InputError(f"{what} must be a finite (x, y, z) point, got {value!r} — give the pieces "
                         "canalsurf.piping made")
    return arr


def _as_pieces(pieces) -> list[Piece]:
    """Each piece's fields, checked, as a :class:`~canalsurf.piping.Piece` with its points as float arrays:
    a one-line InputError names the piece and the field at fault."""
    if isinstance(pieces, (str, bytes)) or not hasattr(pieces, "__iter__"):
        raise InputError(f"pieces must be a sequence of pieces (canalsurf.piping), got {type(pieces).__name__}")
    checked = []
    for index, piece in enumerate(pieces):
        get = lambda key, piece=piece, index=index: _field(piece, key, index)  # noqa: E731
        kind = get("type")
        label = f"piece {index}"
        if kind not in PIECE_ENTITIES:
            raise InputError(f"{label} has type {kind!r}; a piece is one of {', '.join(map(repr, PIECE_ENTITIES))}")
        branch_ids = get("branches")
        if isinstance(branch_ids, (str, bytes)) or not hasattr(branch_ids or (), "__iter__"):
            raise InputError(f"{label} branches must be a tuple of branch ids, got {branch_ids!r}")
        branch_ids = tuple(_whole(b, f"{label} branches") for b in (branch_ids or ()))
        outside = _number(get("outside_diameter"), f"{label} outside_diameter")
        end_diameter = _number(get("end_diameter"), f"{label} end_diameter", optional=True) or outside
        item = Piece(
            id=_whole(get("id"), f"{label} id"), type=kind,
            branch=_whole(get("branch"), f"{label} branch", optional=True), branches=branch_ids,
            start=_point(get("start"), f"{label} start"), end=_point(get("end"), f"{label} end"),
            outside_diameter=outside, end_diameter=end_diameter,
            length=_number(get("length"), f"{label} length", positive=False),
            bend_radius=_number(get("bend_radius"), f"{label} bend_radius", optional=True),
            angle=_number(get("angle"), f"{label} angle", optional=True),
            centre=_point(get("centre"), f"{label} centre", optional=True),
            nominal=None if get("nominal") is None else str(get("nominal")),
            catalogue_diameter=_number(get("catalogue_diameter"), f"{label} catalogue_diameter", optional=True),
            **{key: _optional(getattr(piece, key, None), f"{label} {key}", kind)
               for key, (_, kind) in _OPTIONAL_FIELDS.items() if getattr(piece, key, None) is not None})
        _check_shape(item, label)
        checked.append(item)
    return checked


def _check_shape(piece: Piece, label: str) -> None:
    """Refuse a piece whose points do not describe its shape (an IFC file would hold a broken solid)."""
    span = float(np.linalg.norm(piece.end - piece.start))
    if piece.type in ("straight", "reducer") and span == 0:
        raise InputError(f"{label} ({piece.type}) starts where it ends — it has no length")
    if piece.type == "tee" and piece.centre is None:
        raise InputError(f"{label} (tee) has no centre — a tee needs its junction point")
    if piece.type != "elbow":
        return
    if piece.centre is None or piece.bend_radius is None:
        raise InputError(f"{label} (elbow) needs a centre and a bend_radius — give the pieces canalsurf.piping made")
    arms = np.linalg.norm([piece.start - piece.centre, piece.end - piece.centre], axis=1)
    if np.abs(arms - piece.bend_radius).max() > ELBOW_RADIUS_TOL * piece.bend_radius:
        raise InputError(f"{label} (elbow): start and end lie {arms[0]:.6g} and {arms[1]:.6g} from the centre, "
                         f"not on the bend radius {piece.bend_radius:.6g}")
    if np.linalg.norm(np.cross(piece.start - piece.centre, piece.end - piece.centre)) <= (
            ELBOW_RADIUS_TOL * piece.bend_radius**2):
        raise InputError(f"{label} (elbow): start, centre and end are in line, so the bend's plane is unknown "
                         "— split it into two elbows")


# --------------------------------------------------------------------------------------------------
# placement


def _all_points(branches: list, junctions: list, pieces: list[Piece]) -> np.ndarray:
    """Every point the file will hold (control points, spine samples, junctions, pieces), for the extent."""
    parts = []
    for b in branches:
        parts += [np.asarray(b.spine.c, dtype=float), b.spine(np.linspace(0.0, 1.0, 101))]
    parts += [np.reshape(j.point, (1, 3)) for j in junctions]
    parts += [np.array([p.start, p.end] + ([] if p.centre is None else [p.centre])) for p in pieces]
    return np.concatenate(parts)


def _local_origin(points: np.ndarray) -> np.ndarray:
    """The offset subtracted from every coordinate: zero, except on axes far from the origin.

    An axis whose centre ``c`` lies more than ``FAR_FROM_ORIGIN_EXTENTS`` extents ``e`` from zero gets
    ``sign(c) floor(|c| / step) step``, ``step`` the least power of ten >= max(e, ``MIN_ORIGIN_STEP``).
    Then every coordinate ``x`` on that axis has the offset's sign and ``|offset| <= |c| <= 2 |x|``, so
    ``|x - offset| <= |x|``; the offset, a whole number, is a multiple of the spacing of floats near
    ``x`` (``|x| < 2**52``), so ``x - offset`` is exact, and so is adding the offset back.
    """
    low, high = points.min(axis=0), points.max(axis=0)
    extent = float(np.max(high - low))
    centre = (low + high) / 2
    step = 10.0 ** math.ceil(math.log10(max(extent, MIN_ORIGIN_STEP)))
    far = np.abs(centre) > FAR_FROM_ORIGIN_EXTENTS * max(extent, np.finfo(float).tiny)
    return np.where(far, np.sign(centre) * np.floor(np.abs(centre) / step) * step, 0.0)


# --------------------------------------------------------------------------------------------------
# the file and its spatial structure


@dataclass
class _Ifc:
    """The file being built and the entities every element refers to."""

    file: Any
    guid: Any
    body: Any
    axis: Any
    placement: tuple  # (the storey's IfcLocalPlacement, the identity IfcAxis2Placement3D)
    storey: Any
    elements: list


def _guid(ifc: _Ifc) -> str:
    return ifc.guid.new()


def _new_file(ifcopenshell, name: str, units: str, origin: np.ndarray, crs: str, precision: float) -> _Ifc:
    """An IFC 4 file with units, the model context (georeferenced if ``origin`` is not zero) and the
    spatial structure project > site > building > storey, all at the origin."""
    import ifcopenshell.guid

    from . import __version__

    f = ifcopenshell.file(schema="IFC4")
    # B-spline axes, CSG spheres and tapered extrusions are in the Design Transfer View, not the Reference View.
    f.header.file_description.description = ("ViewDefinition [DesignTransferView_V1.0]",)
    f.header.file_name.originating_system = f"canalsurf {__version__}"

    length = _length_unit(f, units)
    angle = f.createIfcSIUnit(None, "PLANEANGLEUNIT", None, "RADIAN")
    axes = f.createIfcAxis2Placement3D(f.createIfcCartesianPoint((0.0, 0.0, 0.0)), None, None)
    model = f.createIfcGeometricRepresentationContext(None, "Model", 3, precision, axes, None)
    body = f.createIfcGeometricRepresentationSubContext("Body", "Model", None, None, None, None, model, None,
                                                        "MODEL_VIEW", None)
    axis = f.createIfcGeometricRepresentationSubContext("Axis", "Model", None, None, None, None, model, None,
                                                        "GRAPH_VIEW", None)
    if np.any(origin != 0):
        target = f.createIfcProjectedCRS(
            crs, "the scan's coordinate reference system" if crs != UNKNOWN_CRS else
            "the scan's coordinate reference system, not given: local + (Eastings, Northings, OrthogonalHeight) "
            "are its coordinates", None, None, None, None, length)
        f.createIfcMapConversion(model, target, *(float(x) for x in origin), 1.0, 0.0, None)

    ifc = _Ifc(f, ifcopenshell.guid, body, axis, None, None, [])
    project = f.createIfcProject(_guid(ifc), None, name, None, None, None, None, [model],
                                 f.createIfcUnitAssignment([length, angle]))
    site_at = f.createIfcLocalPlacement(None, axes)
    building_at = f.createIfcLocalPlacement(site_at, axes)
    storey_at = f.createIfcLocalPlacement(building_at, axes)
    site = f.createIfcSite(_guid(ifc), None, "site", None, None, site_at, None, None, "ELEMENT",
                           None, None, None, None, None)
    building = f.createIfcBuilding(_guid(ifc), None, "building", None, None, building_at, None, None, "ELEMENT",
                                   None, None, None)
    storey = f.createIfcBuildingStorey(_guid(ifc), None, "storey", None, None, storey_at, None, None, "ELEMENT",
                                       0.0)
    for whole, part in ((project, site), (site, building), (building, storey)):
        f.createIfcRelAggregates(_guid(ifc), None, None, None, whole, [part])
    ifc.placement = (storey_at, axes)
    ifc.storey = storey
    return ifc


def _length_unit(f, units: str):
    if units in _SI_PREFIX:
        return f.createIfcSIUnit(None, "LENGTHUNIT", _SI_PREFIX[units], "METRE")
    metre = f.createIfcSIUnit(None, "LENGTHUNIT", None, "METRE")
    factor = f.createIfcMeasureWithUnit(f.create_entity("IfcLengthMeasure", LENGTH_UNITS[units]), metre)
    return f.createIfcConversionBasedUnit(f.createIfcDimensionalExponents(1, 0, 0, 0, 0, 0, 0), "LENGTHUNIT",
                                          _CONVERTED_NAME[units], factor)


def _element(ifc: _Ifc, entity: str, predefined: str, items: list, kind: str, name: str, tag: str,
             object_type: str | None = None, axis=None):
    """An element at the storey's placement (identity: coordinates are the model's, less the offset), with
    its body and, if given, its centre line (an ``Axis`` representation)."""
    f = ifc.file
    shapes = [f.createIfcShapeRepresentation(ifc.body, "Body", kind, items)]
    if axis is not None:
        shapes.append(f.createIfcShapeRepresentation(ifc.axis, "Axis", "Curve3D", [axis]))
    # a placement of its own (editors move an element by its placement), relative to the storey's
    element = f.create_entity(entity, GlobalId=_guid(ifc), Name=name, ObjectType=object_type,
                              ObjectPlacement=f.createIfcLocalPlacement(*ifc.placement), Tag=tag,
                              PredefinedType=predefined,
                              Representation=f.createIfcProductDefinitionShape(None, None, shapes))
    ifc.elements.append(element)
    return element


def _properties(ifc: _Ifc, element, name: str, values: dict) -> None:
    """A property set of single values: ``{property: (IFC measure type, value or None)}``; None is left out."""
    f = ifc.file
    props = [f.createIfcPropertySingleValue(key, None, f.create_entity(kind, value), None)
             for key, (kind, value) in values.items() if value is not None]
    if props:
        pset = f.createIfcPropertySet(_guid(ifc), None, name, None, props)
        f.createIfcRelDefinesByProperties(_guid(ifc), None, None, None, [element], pset)


# --------------------------------------------------------------------------------------------------
# geometry


def _xyz(f, point) -> Any:
    return f.createIfcCartesianPoint(tuple(float(x) for x in point))


def _direction(f, vector) -> Any:
    return f.createIfcDirection(tuple(float(x) for x in vector))


def ifc_knots(knots: np.ndarray) -> tuple[list[float], list[int]]:
    """scipy's full knot vector as IFC's distinct knots (increasing) and their multiplicities.

    >>> ifc_knots(np.array([0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.0, 1.0, 1.0]))
    ([0.0, 0.5, 1.0], [4, 1, 4])
    """
    values, counts = np.unique(np.asarray(knots, dtype=np.float64), return_counts=True)
    return [float(v) for v in values], [int(c) for c in counts]


def _bspline_curve(f, spine: BSpline, origin: np.ndarray, closed: bool):
    """The spine as an IfcBSplineCurveWithKnots, control points less the local origin."""
    knots, multiplicities = ifc_knots(spine.t)
    points = [_xyz(f, c) for c in np.asarray(spine.c, dtype=float) - origin]
    return f.createIfcBSplineCurveWithKnots(int(spine.k), points, "UNSPECIFIED", bool(closed), False,
                                            multiplicities, knots, "UNSPECIFIED")


def _disk(f, directrix, radius: float):
    return f.createIfcSweptDiskSolid(directrix, float(radius), None, None, None)


def _line_disk(f, start: np.ndarray, end: np.ndarray, radius: float):
    return _disk(f, f.createIfcPolyline([_xyz(f, start), _xyz(f, end)]), radius)


def _sphere(f, centre: np.ndarray, radius: float):
    placement = f.createIfcAxis2Placement3D(_xyz(f, centre), None, None)
    return f.createIfcCsgSolid(f.createIfcSphere(placement, float(radius)))


def _radii(branch) -> np.ndarray:
    return np.asarray(branch.radius(np.linspace(0.0, 1.0, _RING_SAMPLES)), dtype=float).ravel()


def _canal_rings(spine: BSpline, radius: BSpline, *, closed: bool) -> tuple[int, int]:
    """Vertices per ring and rings of a canal's mesh whose faces stray at most ``FACE_SAG`` r each way.

    Around: a chord of a ring of ``n`` vertices lies ``r (1 - cos(pi / n))`` inside the circle.  Along:
    rings ``h`` apart on the spine (curvature ``kappa``) are ``h (1 + r kappa)`` apart on the outer side
    of a bend, on a circle of radius ``1 / kappa + r``: a chord ``h**2 kappa (1 + r kappa) / 8`` inside it.
    The rings are also at most half the outer-side radius apart (:mod:`canalsurf.surface`'s own rule),
    so they follow the radius function.
    """
    from .spine import curvature, curve_length
    from .surface import ALONG_SPACING_FRACTION, MIN_RINGS

    n_around = math.ceil(math.pi / math.acos(1.0 - FACE_SAG))
    t = np.linspace(0.0, 1.0, _RING_SAMPLES)
    kappa = curvature(spine, t)
    r = np.asarray(radius(t), dtype=float).ravel()
    outer = 1.0 + r * kappa
    with np.errstate(divide="ignore"):
        sag_step = np.sqrt(8.0 * FACE_SAG * r / (kappa * outer))
    step = float(np.min(np.minimum(ALONG_SPACING_FRACTION * r / outer, sag_step)))
    n_along = max(MIN_RINGS, math.ceil(curve_length(spine) / step) + (0 if closed else 1))
    return n_around, n_along


def _canal_body(f, spine: BSpline, branch):
    """A canal as an IfcTriangulatedFaceSet of its mesh about ``spine`` (the branch's, in local coordinates;
    capped at open ends: a closed shell)."""
    from .surface import surface_mesh

    n_around, n_along = _canal_rings(spine, branch.radius, closed=branch.closed)
    vertices, faces = surface_mesh(spine, branch.radius, closed=branch.closed, caps=True, n_around=n_around,
                                   n_along=n_along)
    points = f.createIfcCartesianPointList3D([tuple(map(float, v)) for v in vertices])
    return f.createIfcTriangulatedFaceSet(points, None, True, [tuple(int(i) + 1 for i in face) for face in faces],
                                          None)


def arc_chain(spine: BSpline, *, closed: bool, tol: float) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """The spine as a tangent-continuous chain of circular arcs (biarcs) within ``tol`` of it.

    Each piece ``[a, b]`` of the parameter (first the knot spans) gets the biarc of equal tangent lengths
    through ``C(a)`` and ``C(b)`` with the spine's tangents there; a piece whose biarc strays more than
    ``tol`` from the spine (symmetric distance of 33 samples of each, as polylines) is halved.  An arc
    whose sagitta is below ``LINE_SAGITTA_PER_TOL * tol`` is written as its chord.

    Parameters
    ----------
    spine : scipy.interpolate.BSpline
        A 3-D spine on [0, 1] whose speed does not vanish.
    closed : bool
        The spine is a loop: the chain ends on its first point.
    tol : float
        Most distance allowed between chain and spine (the export uses ``ARC_TOL`` times the radius).

    Returns
    -------
    points : ndarray, shape (M, 3)
    segments : list of tuple
        Indices into ``points`` (0-based): ``(i, j)`` a line, ``(i, k, j)`` an arc from ``i`` through ``k``
        to ``j``; each segment starts where the previous one ends.

    Examples
    --------
    >>> from scipy.interpolate import make_interp_spline
    >>> u = np.linspace(0.0, 1.0, 9)
    >>> quarter = make_interp_spline(u, np.column_stack([np.cos(u * np.pi / 2), np.sin(u * np.pi / 2), 0 * u]))
    >>> points, segments = arc_chain(quarter, closed=False, tol=1e-4)
    >>> bool(np.abs(np.linalg.norm(points, axis=1) - 1).max() < 1e-4), all(len(s) == 3 for s in segments)
    (True, True)
    """
    d1 = spine.derivative(1)
    knots = np.unique(np.clip(spine.t, 0.0, 1.0))
    pending = [(float(a), float(b)) for a, b in zip(knots[:-1], knots[1:]) if b > a][::-1]
    points, segments = [spine(0.0)], []
    while pending:
        a, b = pending.pop()
        # the tangent at b from within the piece (scipy evaluates a knot on the span after it)
        arcs = _biarc(spine(a), d1(a), spine(b), d1(np.nextafter(b, a)))
        if b - a > ARC_MIN_PIECE and (arcs is None or _chain_distance(spine, a, b, arcs) > tol):
            pending += [(0.5 * (a + b), b), (a, 0.5 * (a + b))]
            continue
        if arcs is None:  # a piece of ARC_MIN_PIECE with no biarc (a cusp): its chord, if it has one
            p0, p1 = spine(a), spine(b)
            if not np.any(p1 != p0):
                continue
            arcs = [(p0, _unit(p1 - p0), p0, p1)]
        for start, tangent, corner, end in arcs:
            first = len(points) - 1
            middle = _arc_middle(start, tangent, corner, end, LINE_SAGITTA_PER_TOL * tol)
            points += [] if middle is None else [middle]
            points.append(end)
            segments.append((first, len(points) - 1) if middle is None else (first, first + 1, len(points) - 1))
    if closed:  # end exactly where the chain starts
        points.pop()
        segments[-1] = segments[-1][:-1] + (0,)
    return np.array(points), segments


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _biarc(p0, d0, p1, d1) -> list | None:
    """Two arcs from ``p0`` (direction ``d0``) to ``p1`` (``d1``) with equal tangent lengths ``alpha``:
    ``(start, tangent, corner, end)`` each; None if there is none (the tangents turn away from the chord).

    The corners ``q0 = p0 + alpha t0`` and ``q1 = p1 - alpha t1`` are ``2 alpha`` apart, a quadratic in
    ``alpha`` with one positive root (solved in the form that stays exact as ``t0 -> t1``).
    """
    t0, t1 = _unit(np.asarray(d0, float)), _unit(np.asarray(d1, float))
    chord = p1 - p0
    a, b, c = 2.0 * (float(t0 @ t1) - 1.0), -2.0 * float(chord @ (t0 + t1)), float(chord @ chord)
    denominator = -b + math.sqrt(max(b * b - 4.0 * a * c, 0.0))
    if denominator <= 0:
        return None
    alpha = 2.0 * c / denominator
    q0, q1 = p0 + alpha * t0, p1 - alpha * t1
    joint = 0.5 * (q0 + q1)
    if not np.all(np.isfinite(joint)) or np.linalg.norm(q1 - q0) == 0:
        return None
    return [(p0, t0, q0, joint), (joint, _unit(q1 - q0), q1, p1)]


def _arc_geometry(start, tangent, corner, end) -> tuple[float, float, np.ndarray]:
    """Turning angle, radius and unit normal (towards the centre) of the arc with this corner."""
    out = end - corner
    alpha = float(np.linalg.norm(out))
    turn = math.atan2(float(np.linalg.norm(np.cross(tangent, out))), float(tangent @ out))
    inward = out - (out @ tangent) * tangent
    norm = float(np.linalg.norm(inward))
    if norm == 0 or turn == 0:
        return 0.0, math.inf, np.zeros(3)
    return turn, alpha / math.tan(turn / 2), inward / norm


def _arc_middle(start, tangent, corner, end, flat: float) -> np.ndarray | None:
    """The point halfway along the arc, or None if its sagitta is below ``flat`` (write the chord)."""
    turn, radius, normal = _arc_geometry(start, tangent, corner, end)
    if turn == 0 or radius * (1 - math.cos(turn / 2)) < flat:
        return None
    return start + radius * (math.sin(turn / 2) * tangent + (1 - math.cos(turn / 2)) * normal)


def _arc_samples(start, tangent, corner, end, n: int) -> np.ndarray:
    turn, radius, normal = _arc_geometry(start, tangent, corner, end)
    phi = np.linspace(0.0, turn, n)[:, None]
    if turn == 0:
        return start + np.linspace(0.0, 1.0, n)[:, None] * (end - start)
    return start + radius * (np.sin(phi) * tangent + (1 - np.cos(phi)) * normal)


def _chain_distance(spine: BSpline, a: float, b: float, arcs: list) -> float:
    """Symmetric distance between the spine on [a, b] and its biarc, as polylines of 33 samples each."""
    curve = spine(np.linspace(a, b, ARC_CHECK_SAMPLES))
    chain = np.concatenate([_arc_samples(*arc, ARC_CHECK_SAMPLES) for arc in arcs])
    return max(_to_polyline(curve, chain).max(), _to_polyline(chain, curve).max())


def _to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance of each point from a polyline."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), np.finfo(float).tiny)
    s = np.clip(np.einsum("pij,ij->pi", points[:, None, :] - a[None], ab) / length2, 0.0, 1.0)
    nearest = a[None] + s[..., None] * ab[None]
    return np.linalg.norm(points[:, None, :] - nearest, axis=2).min(axis=1)


def _indexed_curve(f, points: np.ndarray, segments: list):
    """An IfcIndexedPolyCurve of lines (IfcLineIndex) and arcs (IfcArcIndex through three points)."""
    point_list = f.createIfcCartesianPointList3D([tuple(map(float, p)) for p in points])
    index = [f.create_entity("IfcLineIndex" if len(seg) == 2 else "IfcArcIndex", tuple(i + 1 for i in seg))
             for seg in segments]
    return f.createIfcIndexedPolyCurve(point_list, index, False)


# --------------------------------------------------------------------------------------------------
# branches and junctions


def _add_branch(ifc: _Ifc, branch, origin: np.ndarray):
    """One IfcPipeSegment: a swept disk along arcs within ``ARC_TOL`` r of the spine (pipe) or the
    tessellated surface (canal), and the spine itself, the model's B-spline, as its axis."""
    from .spine import curve_length

    f = ifc.file
    r = _radii(branch)
    spine = BSpline(branch.spine.t, np.asarray(branch.spine.c, dtype=float) - origin, branch.spine.k)
    axis = _bspline_curve(f, branch.spine, origin, branch.closed)
    if branch.kind == "pipe":
        # the pipe's radius as model.json holds it (its spline's coefficient, not a rounded evaluation)
        radius = float(np.ravel(branch.radius.c)[0])
        points, segments = arc_chain(spine, closed=branch.closed, tol=ARC_TOL * radius)
        item = _disk(f, _indexed_curve(f, points, segments), radius)
        element = _element(ifc, "IfcPipeSegment", "RIGIDSEGMENT", [item], "AdvancedSweptSolid",
                           f"branch {branch.id} (pipe)", str(branch.id), axis=axis)
        _properties(ifc, element, "Pset_PipeSegmentTypeCommon",
                    {"OuterDiameter": ("IfcPositiveLengthMeasure", 2 * radius)})
    else:
        element = _element(ifc, "IfcPipeSegment", "USERDEFINED", [_canal_body(f, spine, branch)], "Tessellation",
                           f"branch {branch.id} (canal)", str(branch.id), "canal surface", axis=axis)
    start, end = (None if e is None else int(e) for e in branch.ends)
    _properties(ifc, element, "Canalsurf_Branch", {
        "BranchId": ("IfcInteger", int(branch.id)), "Kind": ("IfcLabel", branch.kind),
        "Closed": ("IfcBoolean", bool(branch.closed)),
        "Length": ("IfcPositiveLengthMeasure", curve_length(branch.spine)),
        "MinRadius": ("IfcPositiveLengthMeasure", float(r.min())),
        "MaxRadius": ("IfcPositiveLengthMeasure", float(r.max())),
        "StartJunction": ("IfcInteger", start), "EndJunction": ("IfcInteger", end)})
    return element


def _end_radius(branches: list, branch_id: int, end: int) -> float:
    branch = next(b for b in branches if b.id == branch_id)
    return float(np.ravel(branch.radius(float(end)))[0])


def _add_junction(ifc: _Ifc, junction, branches: list, segments: dict, origin: np.ndarray) -> None:
    """One IfcPipeFitting: the sphere of the thickest end's radius about the junction point."""
    f = ifc.file
    radius = max(_end_radius(branches, b, e) for b, e in junction.ends)
    predefined = "JUNCTION" if len(junction.ends) >= 3 else "BEND" if len(junction.ends) == 2 else "NOTDEFINED"
    point = np.asarray(junction.point, dtype=float) - origin
    element = _element(ifc, "IfcPipeFitting", predefined, [_sphere(f, point, radius)], "CSG",
                       f"junction {junction.id}", str(junction.id))
    _properties(ifc, element, "Canalsurf_Junction", {
        "JunctionId": ("IfcInteger", int(junction.id)),
        "Branches": ("IfcLabel", ", ".join(f"{b}:{e}" for b, e in junction.ends)),
        "Radius": ("IfcPositiveLengthMeasure", radius)})
    for b in dict.fromkeys(b for b, _ in junction.ends):
        if b in segments:
            f.createIfcRelConnectsElements(_guid(ifc), None, None, None, None, element, segments[b])


# --------------------------------------------------------------------------------------------------
# pieces


def _add_piece(ifc: _Ifc, piece: Piece, branches: list, junctions: list, origin: np.ndarray) -> None:
    """One element per piece (see the module docstring), with its sizes as properties."""
    f = ifc.file
    start, end = piece.start - origin, piece.end - origin
    r = piece.outside_diameter / 2
    # IFC 4 allows swept disks and tapered extrusions under 'AdvancedSweptSolid' only
    kind = "AdvancedSweptSolid"
    if piece.type == "straight":
        items = [_line_disk(f, start, end, r)]
    elif piece.type == "elbow":
        items = [_elbow(f, piece, origin, r)]
    elif piece.type == "reducer":
        items = [_cone(f, start, end, r, piece.end_diameter / 2)]
    else:
        items, kind = _tee(f, piece, branches, junctions, origin), "SolidModel"
    entity, predefined = PIECE_ENTITIES[piece.type]
    element = _element(ifc, entity, predefined, items, kind, f"{piece.type} {piece.id}", str(piece.id))
    if piece.type == "straight":
        _properties(ifc, element, "Pset_PipeSegmentTypeCommon", {
            "OuterDiameter": ("IfcPositiveLengthMeasure", piece.catalogue_diameter or piece.outside_diameter)})
    elif piece.type == "elbow":
        _properties(ifc, element, "Pset_PipeFittingTypeBend", {
            "BendAngle": ("IfcPositivePlaneAngleMeasure", _elbow_turn(piece)[1]),
            "BendRadius": ("IfcPositiveLengthMeasure", piece.bend_radius)})
    elif piece.type == "tee":
        _properties(ifc, element, "Pset_PipeFittingTypeJunction", {"JunctionType": ("IfcLabel", "TEE")})
    _properties(ifc, element, "Canalsurf_Piece", {
        "PieceId": ("IfcInteger", piece.id), "PieceType": ("IfcLabel", piece.type),
        "Branch": ("IfcInteger", piece.branch),
        "Branches": ("IfcLabel", ", ".join(map(str, piece.branches)) or None),
        "OutsideDiameter": ("IfcPositiveLengthMeasure", piece.outside_diameter),
        "EndDiameter": ("IfcPositiveLengthMeasure", piece.end_diameter),
        "Length": ("IfcLengthMeasure", piece.length),
        "NominalSize": ("IfcLabel", piece.nominal),
        "CatalogueOuterDiameter": ("IfcPositiveLengthMeasure", piece.catalogue_diameter),
        **{name: (kind, getattr(piece, key)) for key, (name, kind) in _OPTIONAL_FIELDS.items()
           if getattr(piece, key) is not None}})


def _elbow_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (radians) between two arms of a bend, well conditioned near 0 and pi."""
    return float(math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b))))


def _elbow_turn(piece: Piece) -> tuple[np.ndarray, float]:
    """The unit normal of an elbow's plane (the arc turns about it from start to end) and its angle in
    radians: the short way round, unless the piece's own angle says it bends more than 180 degrees."""
    a, b = piece.start - piece.centre, piece.end - piece.centre
    normal = np.cross(a, b)
    normal /= np.linalg.norm(normal)
    angle = _elbow_angle(a, b)
    if piece.angle is not None and piece.angle > 180.0:
        return -normal, 2 * math.pi - angle
    return normal, angle


def _elbow(f, piece: Piece, origin: np.ndarray, radius: float):
    """A swept disk along the elbow's arc: an IfcCircle about its centre trimmed from start to end."""
    normal, angle = _elbow_turn(piece)
    x_axis = (piece.start - piece.centre) / np.linalg.norm(piece.start - piece.centre)
    placement = f.createIfcAxis2Placement3D(_xyz(f, piece.centre - origin), _direction(f, normal),
                                            _direction(f, x_axis))
    circle = f.createIfcCircle(placement, float(piece.bend_radius))
    # The parameter of an IfcCircle is its angle in the plane angle unit (radians here); the points say
    # the same for readers that trim by them.
    trims = [[_xyz(f, p - origin), f.create_entity("IfcParameterValue", u)]
             for p, u in ((piece.start, 0.0), (piece.end, angle))]
    return _disk(f, f.createIfcTrimmedCurve(circle, trims[0], trims[1], True, "PARAMETER"), radius)


def _cone(f, start: np.ndarray, end: np.ndarray, r0: float, r1: float):
    """A truncated cone from radius ``r0`` at ``start`` to ``r1`` at ``end`` (a concentric reducer)."""
    axis = end - start
    depth = float(np.linalg.norm(axis))
    axis = axis / depth
    across = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    placement = f.createIfcAxis2Placement3D(_xyz(f, start), _direction(f, axis),
                                            _direction(f, across / np.linalg.norm(across)))
    profile = f.createIfcCircleProfileDef("AREA", None, None, float(r0))
    scale = f.createIfcCartesianTransformationOperator2D(None, None, f.createIfcCartesianPoint((0.0, 0.0)),
                                                         float(r1 / r0))
    end_profile = f.createIfcDerivedProfileDef("AREA", None, profile, scale, None)
    return f.createIfcExtrudedAreaSolidTapered(profile, placement, _direction(f, (0.0, 0.0, 1.0)), depth,
                                               end_profile)


def _tee_ports(piece: Piece, branches: list, junctions: list) -> list[tuple[np.ndarray, float]]:
    """The ports of a tee: ``(unit direction from its centre, radius)`` each.

    The junction at the tee's centre (within its run's radius) gives a port for each end of a branch of
    ``piece.branches`` there, along the branch's spine tangent: the run's radius (``outside_diameter``)
    for the first two branches, ``outlet_diameter`` (or the branch's own radius there) for the third, the
    outlet.  Without such a junction, the directions to ``start`` and ``end``, where they are not the
    centre, give ports of the outside and end radius.  A direction within ``TEE_SAME_PORT_DEGREES`` of
    one already found is the same port.
    """
    ports = []
    junction = min(junctions, key=lambda j: np.linalg.norm(np.asarray(j.point) - piece.centre), default=None)
    if junction is not None and np.linalg.norm(np.asarray(junction.point) - piece.centre) > piece.outside_diameter / 2:
        junction = None
    by_id = {b.id: b for b in branches}
    outlet = piece.branches[2] if len(piece.branches) >= 3 else None
    for b, e in ([] if junction is None else junction.ends):
        if b not in piece.branches or b not in by_id:
            continue
        tangent = np.asarray(by_id[b].spine.derivative(1)(float(e)), dtype=float) * (1.0 if e == 0 else -1.0)
        if b != outlet:
            radius = piece.outside_diameter / 2
        elif piece.outlet_diameter is not None:
            radius = piece.outlet_diameter / 2
        else:
            radius = _end_radius(branches, b, e)
        ports.append((tangent, radius))
    if not ports:
        ports = [(piece.start - piece.centre, piece.outside_diameter / 2),
                 (piece.end - piece.centre, piece.end_diameter / 2)]
    unique = []
    for direction, radius in ports:
        norm = float(np.linalg.norm(direction))
        if norm == 0:
            continue
        direction = direction / norm
        if all(np.dot(direction, d) < math.cos(math.radians(TEE_SAME_PORT_DEGREES)) for d, _ in unique):
            unique.append((direction, radius))
    return unique


def _tee(f, piece: Piece, branches: list, junctions: list, origin: np.ndarray) -> list:
    """A tee's body: a swept disk per port from the centre, out as far as the farther of start and end
    (or, for a tee drawn as a point, the largest port radius), and a sphere of that radius closing the
    joint (inside the run, which it fits)."""
    centre = piece.centre - origin
    ports = _tee_ports(piece, branches, junctions)
    largest = max([r for _, r in ports] + [piece.outside_diameter / 2])
    reach = max(np.linalg.norm(piece.start - piece.centre), np.linalg.norm(piece.end - piece.centre))
    reach = reach if reach > 0 else largest
    return [_sphere(f, centre, largest)] + [_line_disk(f, centre, centre + reach * d, r) for d, r in ports]
