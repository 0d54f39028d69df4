"""STEP export: each branch of a network as a B-spline solid for CAD tools (extra ``step``).

:func:`write_step` writes an ISO 10303-21 file (AP214) through OpenCASCADE (``cadquery-ocp-novtk``,
module ``OCP``): an assembly named after the network holding one solid per branch, named
``branch <id>``, in the length unit the model's coordinates are in.

Each branch's lateral surface is one NURBS surface built from canalsurf's own surface (the rings
of :func:`canalsurf.surface.surface_mesh`, so the CAD solid and canalsurf's mesh share their frames):

* around the spine (``u``), the exact circle: each characteristic circle is a periodic rational
  quadratic B-spline of 8 control points -- its points at 0, 90, 180 and 270 degrees and the
  corners of the circumscribed square between them, weighted cos 45 degrees (Piegl & Tiller,
  *The NURBS Book*, 2nd ed., section 7.5);
* along the spine (``v``, normalised arc length), a cubic B-spline interpolating the control points
  of circles a quarter radius apart (closer on bends), so the surface passes through every one.

This one construction serves pipes, canals and loops alike.  Sweeping a circle along the spine
(OpenCASCADE's pipe shell) was also tried: it is as accurate on an open pipe, but a canal's
envelope is no swept circle (its characteristic circles shrink by ``sqrt(1 - (dr/ds)**2)`` and sit
off the spine), and the sweep's frame does not come back to itself around a knotted loop, which
leaves an invalid solid.  An open tube is closed by a planar disc at each end.  Branches that meet at
a junction stay separate solids: a CAD user can unite them, and no boolean can then spoil one.
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
from typing import Any, Iterator

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.linalg import solve_circulant

from ._validate import choice
from .errors import InputError, ReconstructionError
from .io import _as_path, atomic_write
from .model import CanalModel
from .network import Network
from .surface import surface_mesh

__all__ = ["write_step", "STEP_UNITS"]

#: Length units a STEP file can declare: name -> (code of OpenCASCADE's ``write.step.unit`` setting,
#: metres per unit).  The foot and the inch are the international ones (exactly 0.3048 m and 0.0254 m
#: since 1959); STEP writes them as conversion-based units of the metre.
STEP_UNITS = {"m": ("M", 1.0), "mm": ("MM", 1e-3), "ft": ("FT", 0.3048), "in": ("INCH", 0.0254)}
#: Points per characteristic circle taken from the surface mesh: a rational quadratic circle has 8
#: control points (periodic), 4 on the circle and 4 at the corners of the square around it.
N_AROUND = 8
#: Weight of a corner control point: cos(45 degrees), half the angle each quadratic arc spans.
CORNER_WEIGHT = math.sqrt(0.5)
#: Circles are spaced this share of the smallest "outer-side radius" r / (1 + r kappa) apart (kappa the
#: spine's curvature), half the spacing of canalsurf's own mesh.  The cubic through them departs from
#: the surface by O(spacing**4) on a smooth spine (at most 2e-6 r on the helix of tests/test_step.py),
#: O(spacing**2) where the spine's curvature jumps (4e-4 r at the ends of an elbow's bend): far
#: inside the 0.5 % of the radius the export promises.
RING_SPACING_FRACTION = 0.25
#: Where r kappa reaches 1 the tube folds through itself (as canalsurf's mesh does there): no regular
#: surface is left to follow more closely, so the spacing is set as if r kappa were at most this.
MAX_R_KAPPA = 1.0
#: Fewest circles per branch: the cubic in v needs four, a short spine still gets a smooth surface.
MIN_RINGS = 8
#: Most circles per branch: a circle takes about 800 bytes of STEP file, so 100,000 make about 80 MB,
#: written in some 20 s.  With the spacing above a branch needs at most 8 circles per radius of
#: length, so only a branch over 12,500 radii long needs more.
MAX_RINGS = 100_000
#: Samples of the spine (and its curvature) from which the spacing of the circles is set.
SPACING_SAMPLES = 4001
#: Geometric tolerance of the topology (OpenCASCADE's Precision::Confusion, 1e-7 in the model's
#: unit), used where a face is made from a surface: the edges are then the surface's own boundaries.
TOLERANCE = 1e-7
#: The OpenCASCADE setting of the file's length unit, changed for a write and restored afterwards.  (The
#: unit of the shapes is the document's own, set alike; OpenCASCADE's process-wide shape unit,
#: ``xstep.cascade.unit``, is then not used by the writer.)
_UNIT_SETTING = "write.step.unit"


def write_step(path, network, *, units: str = "m", name: str | None = None) -> None:
    """Write a network's tubes as a STEP file: one named B-spline solid per branch.

    Parameters
    ----------
    path : str or os.PathLike
        Target file (``.step`` or ``.stp`` by convention); written atomically, so a failed export
        leaves no partial file and an existing file untouched.
    network : Network or CanalModel
        The result of :func:`canalsurf.reconstruct`, or a single tube.
    units : {"m", "mm", "ft", "in"}
        The length unit the model's coordinates are in -- the unit of the scan.  The file declares it
        and holds the coordinates unscaled, so a CAD tool shows the tubes at their true size.
    name : str, optional
        Name of the assembly holding the branches (CAD tools show it at the top of their tree);
        default the file's name without its suffix.

    Raises
    ------
    InputError
        An unknown unit, no branches, a branch with no surface (see
        :func:`canalsurf.surface.surface_mesh`), an unwritable folder, or the 'step' extra missing.
    ReconstructionError
        OpenCASCADE could not build a valid solid from a branch, or could not translate the solids.

    Notes
    -----
    Each solid's lateral face passes through canalsurf's own surface at circles a quarter radius
    apart and departs from it by less than 0.05 % of the radius between them (see
    ``RING_SPACING_FRACTION``); open ends are planar discs on the end circles.  Where a spine bends
    tighter than its radius (r kappa >= 1) the tube folds through itself, in canalsurf's mesh as in
    the solid, and there is no surface to follow: a CAD tool may then reject the solid.

    OpenCASCADE's STEP unit setting and its message printers are process-wide: they are changed for
    the duration of the call and restored afterwards, so do not use OpenCASCADE from another thread
    meanwhile.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from canalsurf.model import CanalModel
    >>> from canalsurf.synth import make_tube
    >>> truth = make_tube("helix", n=10)
    >>> tube = CanalModel("pipe", truth.spine, truth.radius, closed=False)
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "helix.step"
    >>> write_step(target, tube, units="mm")
    >>> target.read_text().count("MANIFOLD_SOLID_BREP")
    1
    """
    target = _as_path(path)
    branches = _branches(network)
    code, metres = STEP_UNITS[choice(units, "units", STEP_UNITS)]
    if name is not None and not isinstance(name, str):
        raise InputError(f"name must be a string, got {type(name).__name__}")
    _require_occ()
    solids = [(f"branch {b.id}", _branch_solid(b)) for b in branches]
    with _quiet(), _unit_setting(code):
        doc = _document(solids, target.stem if name is None else name, metres)
        atomic_write(target, lambda tmp: _write_document(doc, tmp))


def _branches(network) -> list:
    """The branches to export, or :class:`InputError`."""
    if isinstance(network, CanalModel):
        branches = [network]
    elif isinstance(network, Network):
        branches = list(network.branches)
    else:
        raise InputError(f"network must be a canalsurf Network or CanalModel, got {type(network).__name__}")
    if not branches:
        raise InputError("the network has no branches — there is nothing to write")
    for i, branch in enumerate(branches):
        if not isinstance(branch, CanalModel):
            raise InputError(f"network branch {i} must be a CanalModel, got {type(branch).__name__}")
        for part in ("spine", "radius"):
            if not isinstance(getattr(branch, part), BSpline):
                raise InputError(f"branch {branch.id}: its {part} must be a scipy.interpolate.BSpline, got "
                                 f"{type(getattr(branch, part)).__name__}")
    return branches


def _require_occ() -> None:
    """Raise :class:`InputError` naming the extra unless OpenCASCADE's bindings can be imported."""
    try:
        # the package first: a cached submodule would answer even with the package gone
        for module in ("OCP", "OCP.STEPCAFControl"):
            importlib.import_module(module)
    except ImportError:
        raise InputError("writing STEP files needs the 'step' extra — pip install 'canalsurf[step]'") from None


# --------------------------------------------------------------------------------------------------
# one branch


def _branch_solid(branch: CanalModel):
    """The branch as an OpenCASCADE solid: its NURBS surface, closed by end discs unless a loop."""
    from OCP.BRep import BRep_Builder
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakeSolid, BRepBuilderAPI_MakeWire
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepLib import BRepLib
    from OCP.TopoDS import TopoDS, TopoDS_Shell

    face = BRepBuilderAPI_MakeFace(_branch_surface(branch), TOLERANCE).Face()
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    builder.Add(shell, face)
    if not branch.closed:
        for edge in _end_edges(face):
            # A closed shell runs each edge once each way: the disc takes the end circle reversed.
            wire = BRepBuilderAPI_MakeWire(TopoDS.Edge(edge.Reversed())).Wire()
            builder.Add(shell, BRepBuilderAPI_MakeFace(wire, True).Face())
    shell.Closed(True)
    solid = BRepBuilderAPI_MakeSolid(shell).Solid()
    # Turn the shell outward if the surface's (u, v) orientation made it face inward.
    oriented = BRepLib.OrientClosedSolid_s(solid)
    if not oriented or not BRepCheck_Analyzer(solid).IsValid():
        raise ReconstructionError(f"branch {branch.id}: OpenCASCADE finds the solid of its surface invalid — "
                                  "check the branch in canalsurf's mesh, or leave it out")
    return solid


def _end_edges(face) -> list:
    """The two end circles of an open tube's face: every edge but the seam."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_EDGE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    edges = []
    explorer = TopExp_Explorer(face, TopAbs_EDGE)
    while explorer.More():
        edge = TopoDS.Edge(explorer.Current())
        if not BRep_Tool.IsClosed_s(edge, face):  # the seam, met twice, is closed on the face
            edges.append(edge)
        explorer.Next()
    return edges


def _branch_surface(branch: CanalModel):
    """The branch's lateral surface as a Geom_BSplineSurface (u around, periodic; v along)."""
    from OCP.Geom import Geom_BSplineSurface

    closed = bool(branch.closed)
    n_rings = _ring_count(branch)
    try:
        vertices, _ = surface_mesh(branch.spine, branch.radius, closed=closed, caps=False, n_around=N_AROUND,
                                   n_along=n_rings)
    except InputError as exc:
        raise InputError(f"branch {branch.id}: {exc}") from None
    rings = vertices.reshape(-1, N_AROUND, 3)
    centre = rings.mean(axis=1, keepdims=True)
    # Mesh vertices 1, 3, 5, 7 sit at 45, 135, ... degrees on the circle; the control points there are
    # the corners of the circumscribed square, sqrt(2) times as far from the centre.
    stretch = np.where(np.arange(N_AROUND) % 2 == 0, 1.0, math.sqrt(2.0))[None, :, None]
    poles, v_knots, v_mults = _interpolate_along(centre + (rings - centre) * stretch, closed)
    u_knots = np.linspace(0.0, 1.0, N_AROUND // 2 + 1)
    weights = np.where(np.arange(N_AROUND) % 2 == 0, 1.0, CORNER_WEIGHT)
    arrays = _Arrays()
    return Geom_BSplineSurface(
        arrays.points(poles.transpose(1, 0, 2)),
        arrays.reals2(np.broadcast_to(weights[:, None], (N_AROUND, len(poles)))),
        arrays.reals(u_knots), arrays.reals(v_knots), arrays.ints(np.full(len(u_knots), 2)), arrays.ints(v_mults),
        2, 3, True, closed)


def _ring_count(branch: CanalModel) -> int:
    """Circles along a branch: ``RING_SPACING_FRACTION`` of the smallest outer-side radius apart."""
    spine = branch.spine
    t = np.linspace(0.0, 1.0, SPACING_SAMPLES)
    d1 = np.asarray(spine.derivative(1)(t), dtype=float)
    d2 = np.asarray(spine.derivative(2)(t), dtype=float) if spine.k >= 2 else np.zeros_like(d1)
    speed = np.linalg.norm(d1, axis=1)
    length = float(np.sum((speed[1:] + speed[:-1]) / 2) * (t[1] - t[0]))
    r = np.asarray(branch.radius(t), dtype=float).reshape(len(t), -1)[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r_kappa = r * np.linalg.norm(np.cross(d1, d2), axis=1) / speed**3
    outer = r / (1 + np.minimum(r_kappa, MAX_R_KAPPA))
    if not (np.isfinite(length) and length > 0 and np.all(np.isfinite(outer)) and outer.min() > 0):
        return MIN_RINGS  # surface_mesh then says what is wrong (a spine that stops, a radius <= 0)
    count = math.ceil(length / (RING_SPACING_FRACTION * float(outer.min()))) + (0 if branch.closed else 1)
    if count > MAX_RINGS:
        raise InputError(f"branch {branch.id}: its surface would need {count:,} circles, more than the "
                         f"{MAX_RINGS:,} a STEP solid may take (it is {length / float(r.min()):,.0f} radii "
                         "long) — split the branch, or leave it out")
    return max(MIN_RINGS, count)


def _interpolate_along(poles: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cubic interpolation of the circles' control points along the spine, in OpenCASCADE's form.

    Returns the control points ``(n, N_AROUND, 3)``, the distinct knots and their multiplicities.  The
    circles are evenly spaced in arc length, so the parameter is normalised arc length.
    """
    m = len(poles)
    flat = poles.reshape(m, -1)
    if not closed:
        spline = make_interp_spline(np.linspace(0.0, 1.0, m), flat, k=3)  # not-a-knot ends
        knots, mults = np.unique(spline.t, return_counts=True)
        return spline.c.reshape(-1, N_AROUND, 3), knots, mults
    # A loop: the periodic cubic with a knot at each circle (v = i / m).  There the B-splines centred on
    # the knot and its two neighbours weigh 4/6, 1/6 and 1/6, so the control points solve a circulant
    # system (by FFT; scipy's periodic interpolation solves it densely, in O(m^3)).  OpenCASCADE's
    # periodic B-spline counts its control points from the one centred one knot before v = 0.
    kernel = np.zeros(m)
    kernel[[0, 1, -1]] = 4 / 6, 1 / 6, 1 / 6
    centred = solve_circulant(kernel, flat)
    return np.roll(centred, 1, axis=0).reshape(m, N_AROUND, 3), np.linspace(0.0, 1.0, m + 1), np.ones(m + 1, int)


class _Arrays:
    """Numpy arrays as OpenCASCADE's 1-based arrays, by the type names of OCP 8 or OCP 7.9."""

    def __init__(self) -> None:
        try:
            from OCP.collections import Array1_double, Array1_int, Array2_double, Array2_gp_Pnt
        except ImportError:  # OCP 7.9 names the OCCT typedefs
            from OCP.TColgp import TColgp_Array2OfPnt as Array2_gp_Pnt
            from OCP.TColStd import (TColStd_Array1OfInteger as Array1_int,
                                     TColStd_Array1OfReal as Array1_double, TColStd_Array2OfReal as Array2_double)
        from OCP.gp import gp_Pnt

        self._real1, self._int1, self._real2, self._pnt2, self._pnt = (
            Array1_double, Array1_int, Array2_double, Array2_gp_Pnt, gp_Pnt)

    def reals(self, values) -> Any:
        return self._fill1(self._real1, [float(v) for v in values])

    def ints(self, values) -> Any:
        return self._fill1(self._int1, [int(v) for v in values])

    @staticmethod
    def _fill1(kind, values: list) -> Any:
        array = kind(1, len(values))
        for i, v in enumerate(values, start=1):
            array.SetValue(i, v)
        return array

    def reals2(self, values: np.ndarray) -> Any:
        rows, cols = values.shape
        array = self._real2(1, rows, 1, cols)
        for i, row in enumerate(values.tolist(), start=1):
            for j, v in enumerate(row, start=1):
                array.SetValue(i, j, v)
        return array

    def points(self, points: np.ndarray) -> Any:
        rows, cols, _ = points.shape
        array = self._pnt2(1, rows, 1, cols)
        for i, row in enumerate(points.tolist(), start=1):
            for j, (x, y, z) in enumerate(row, start=1):
                array.SetValue(i, j, self._pnt(x, y, z))
        return array


# --------------------------------------------------------------------------------------------------
# the file


def _document(solids: list, title: str, metres: float):
    """An XCAF document: the assembly ``title`` holding each named solid, in a unit of ``metres``."""
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.TopLoc import TopLoc_Location
    from OCP.XCAFApp import XCAFApp_Application
    from OCP.XCAFDoc import XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    XCAFApp_Application.GetApplication_s().InitDocument(doc)
    # The shapes' unit: the same as the file's, so OpenCASCADE writes the coordinates as they are.
    XCAFDoc_DocumentTool.SetLengthUnit_s(doc, metres)
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    assembly = shapes.NewShape()
    TDataStd_Name.Set_s(assembly, TCollection_ExtendedString(title))
    for label, solid in solids:
        part = shapes.AddShape(solid, False)
        TDataStd_Name.Set_s(part, TCollection_ExtendedString(label))
        component = shapes.AddComponent(assembly, part, TopLoc_Location())
        TDataStd_Name.Set_s(component, TCollection_ExtendedString(label))
    shapes.UpdateAssemblies()
    return doc


def _write_document(doc, tmp) -> None:
    from OCP.IFSelect import IFSelect_ReturnStatus
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_StepModelType

    writer = STEPCAFControl_Writer()
    if not writer.Transfer(doc, STEPControl_StepModelType.STEPControl_AsIs):
        raise ReconstructionError("OpenCASCADE could not translate the solids to STEP — export a mesh instead")
    status = writer.Write(os.fspath(tmp))
    if status != IFSelect_ReturnStatus.IFSelect_RetDone:
        raise InputError(f"{tmp}: OpenCASCADE could not write the STEP file ({status.name}) — check the folder "
                         "and the free space")


@contextlib.contextmanager
def _unit_setting(code: str) -> Iterator[None]:
    """OpenCASCADE's STEP file unit set to ``code`` for the duration, then restored."""
    from OCP.Interface import Interface_Static
    from OCP.STEPControl import STEPControl_Controller

    STEPControl_Controller.Init_s()  # registers the STEP settings
    before = Interface_Static.CVal_s(_UNIT_SETTING)
    try:
        if not Interface_Static.SetCVal_s(_UNIT_SETTING, code):
            raise ReconstructionError(f"OpenCASCADE does not take the STEP unit {code!r} — update the 'step' "
                                      "extra: pip install -U 'canalsurf[step]'")
        yield
    finally:
        Interface_Static.SetCVal_s(_UNIT_SETTING, before)


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """OpenCASCADE's console messages switched off for the duration."""
    from OCP.Message import Message

    # The library is silent; OpenCASCADE prints its transfer statistics to stdout through its messenger.
    messenger = Message.DefaultMessenger_s()
    printers = list(messenger.Printers())
    for printer in printers:
        messenger.RemovePrinter(printer)
    try:
        yield
    finally:
        for printer in printers:
            messenger.AddPrinter(printer)
