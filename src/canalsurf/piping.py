"""Piping semantics: a network's pipes as the pieces a piping designer draws.

Each branch's spine is fitted by a tangent-continuous chain of straight runs and elbows (torus
sections): a polyline of *work points* -- where the axes of consecutive straights meet -- with a bend
radius at each interior one, as a designer lays out a run.  The chain is continuous in its tangent by
construction (each elbow is the arc tangent to both of its legs), and it is chosen by a fit: the work
points and bend radii minimise the squared distances of dense spine samples from the chain, and a
chain is accepted only if no spine sample lies farther from it than the branch's accuracy
(:data:`TOLERANCE_RMS` times its inlier RMS residual, at least :data:`TOLERANCE_RADII` of its radius).
Work points come from the straight stretches of the spine (where their lines meet); where a chain with
them misses the spine, a work point is added at the worst sample of each stretch it misses (or the elbow
there is split in two), and afterwards every work point that can go without leaving the tolerance is
removed, so the chain has no more elbows than the spine shows.  A branch that no chain of a few elbows
per radius of its length follows is refused: it is not piping.

Sizes: a canal branch whose radius steps from one plateau to another holds a **reducer** (the stretch
of the step, fitted as constant - linear - constant).  A reducer is straight, and where the radius
changes a scan's spine is no better than its radius, so the chain is fitted to the spine outside the
reducers.  A junction of two branches is no joint for the chain: the branches are fitted as one run,
and a step of their radii there is a reducer.  A junction
of three branches is a **tee**: the two ends most nearly in line are its run, the third its outlet.
Every outside diameter is snapped to a catalogue (:func:`snap_size`) -- ASME B36.10M/B36.19M by NPS or
EN 10220 by DN -- when it lies within the catalogue tolerance, and the snap and its deviation are kept
on the piece (and in ``pipes.csv``, :func:`write_pipes_csv`), never applied silently.

* :func:`decompose` -- a :class:`~canalsurf.network.Network` to a list of :class:`Piece`;
* :func:`snap_size` -- one measured outside diameter against a catalogue, as a :class:`Snap`;
* :func:`write_pipes_csv` -- the pieces as ``pipes.csv``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ._validate import as_points, choice, positive
from .errors import InputError, ReconstructionError
from .spine import curve_length, polyline_arclength, sample_arclength

__all__ = ["Piece", "Snap", "decompose", "snap_size", "surface_ramp", "write_pipes_csv", "CATALOGUES", "UNITS",
           "PIECE_TYPES", "CSV_COLUMNS"]

#: Millimetres per unit of the model's coordinates (the catalogues are in millimetres).
UNITS = {"m": 1000.0, "mm": 1.0, "ft": 304.8, "in": 25.4}

#: ASME B36.10M (welded and seamless wrought steel pipe, Table 1) outside diameters in millimetres by
#: nominal pipe size, NPS 1/8 to NPS 48; ASME B36.19M (stainless steel pipe) uses the same outside
#: diameters for the sizes it covers (to NPS 30).  The metric column of the standard: NPS 14 and larger
#: have an outside diameter of the nominal size in inches.
ASME_OUTSIDE_DIAMETERS = (
    ("NPS 1/8", 10.3), ("NPS 1/4", 13.7), ("NPS 3/8", 17.1), ("NPS 1/2", 21.3), ("NPS 3/4", 26.7),
    ("NPS 1", 33.4), ("NPS 1 1/4", 42.2), ("NPS 1 1/2", 48.3), ("NPS 2", 60.3), ("NPS 2 1/2", 73.0),
    ("NPS 3", 88.9), ("NPS 3 1/2", 101.6), ("NPS 4", 114.3), ("NPS 5", 141.3), ("NPS 6", 168.3),
    ("NPS 8", 219.1), ("NPS 10", 273.0), ("NPS 12", 323.8), ("NPS 14", 355.6), ("NPS 16", 406.4),
    ("NPS 18", 457.0), ("NPS 20", 508.0), ("NPS 22", 559.0), ("NPS 24", 610.0), ("NPS 26", 660.0),
    ("NPS 28", 711.0), ("NPS 30", 762.0), ("NPS 32", 813.0), ("NPS 34", 864.0), ("NPS 36", 914.0),
    ("NPS 38", 965.0), ("NPS 40", 1016.0), ("NPS 42", 1067.0), ("NPS 44", 1118.0), ("NPS 46", 1168.0),
    ("NPS 48", 1219.0),
)
#: EN 10220 (seamless and welded steel tubes, dimensions) series 1 outside diameters in millimetres, by
#: the DN they carry in the European fitting standards (EN 10253, formerly DIN 2605/2615/2616), DN 6 to
#: DN 2000.
EN_OUTSIDE_DIAMETERS = (
    ("DN 6", 10.2), ("DN 8", 13.5), ("DN 10", 17.2), ("DN 15", 21.3), ("DN 20", 26.9), ("DN 25", 33.7),
    ("DN 32", 42.4), ("DN 40", 48.3), ("DN 50", 60.3), ("DN 65", 76.1), ("DN 80", 88.9), ("DN 100", 114.3),
    ("DN 125", 139.7), ("DN 150", 168.3), ("DN 200", 219.1), ("DN 250", 273.0), ("DN 300", 323.9),
    ("DN 350", 355.6), ("DN 400", 406.4), ("DN 450", 457.0), ("DN 500", 508.0), ("DN 600", 610.0),
    ("DN 700", 711.0), ("DN 800", 813.0), ("DN 900", 914.0), ("DN 1000", 1016.0), ("DN 1200", 1219.0),
    ("DN 1400", 1422.0), ("DN 1600", 1626.0), ("DN 1800", 1829.0), ("DN 2000", 2032.0),
)
#: ``catalogue`` option -> (nominal size, outside diameter in mm) pairs.
CATALOGUES = {"asme": ASME_OUTSIDE_DIAMETERS, "en": EN_OUTSIDE_DIAMETERS}
#: Types of :attr:`Piece.type`.
PIECE_TYPES = ("straight", "elbow", "tee", "reducer")

#: A measured outside diameter snaps to a catalogue size within this share of it: the order of the
#: manufacturing tolerance of an outside diameter (EN 10253-4 class D2 fittings: +-1 %, at least 0.5 mm).
#: Neighbouring catalogue sizes differ by 4.3 % or more, so at most one is ever in reach.
SNAP_RELATIVE = 0.01
#: ... or within this many standard uncertainties of the measured diameter, when that is larger.
SNAP_SIGMAS = 3.0
#: The chain of straights and elbows may leave the spine by this many times the branch's inlier RMS
#: residual (the scatter of its points about the fitted surface: a spine closer than that to the chain
#: cannot be told from it by the scan) ...
TOLERANCE_RMS = 3.0
#: ... and at least by this share of the branch's radius: a scan's spine (a smoothing spline) rounds the
#: corner where a straight meets an elbow, by up to 2.2 % of the radius from the true centreline on the
#: ``piping`` network's elbows (seeds 1 - 5); within 3 % each such corner stays one elbow.
TOLERANCE_RADII = 0.03
#: Spine samples of the fit, this share of the radius apart (at least MIN_SAMPLES per branch): a 1.5 D
#: elbow (bend radius 3 r) gets some 50 samples per 90 degrees.
SAMPLE_SPACING_RADII = 0.25
MIN_SAMPLES = 200
#: A sample is on a bend when its neighbours within this many radii on either side leave the chord
#: between them by more than half the tolerance (the sagitta of a bend of radius R over that window is
#: r^2 / 2R: 0.17 r for a 1.5 D elbow, 0.08 r for 3 D).
WINDOW_RADII = 1.0
#: Work points added at the worst sample before a branch is declared no chain of straights and elbows:
#: one per this many radii of its length (a plant's runs have a bend every few diameters at most).
MAX_VERTICES_PER_RADIUS = 0.25
#: Two fitted legs turning by less than this (degrees) are one straight for the first guess.
MIN_TURN_DEGREES = 1.0
#: Evaluations and relative tolerance of each least-squares fit of work points and bend radii: it
#: converges in a few dozen steps from the first guess; the distances are not smooth where the nearest
#: piece changes, so tighter tolerances only add steps.
MAX_FIT_EVALUATIONS = 60
FIT_TOLERANCE = 1e-10
#: A sample's distance from the chain is taken to depend on the bends this many places either side of the
#: piece it lies nearest to: its own, the bends sharing its legs (their tangent lengths share the room on a
#: leg) and, for margin while the fit moves, one more.
SPARSITY_REACH = 2
#: No bend is tighter than this many tube radii: a torus of smaller bend radius folds on itself (a
#: short-radius elbow bends at about 2 radii).
MIN_BEND_RADII = 1.0
#: With the scan's points (``decompose(..., points=...)``) the chain is fitted once more, to the points
#: around it: a scan's spine (a smoothing spline) rounds the corner where a straight meets an elbow, by up
#: to 2 % of the radius, and the bend radius and arc length follow it (up to 1.3 % and 1.6 % of the radius
#: on the ``piping`` network, seeds 1 - 5); its points do not round it.  Those used lie within this many
#: tolerances of the tube's surface (stray points and other tubes' points do not) ...
POINT_BAND_TOLERANCES = 3.0
#: ... at most this many per run (a seeded subsample: many more than the chain's few dozen unknowns need),
#: taken from at most BOX_POINTS about the run (which bounds the memory of measuring them).
FIT_POINTS = 20_000
BOX_POINTS = 200_000
#: ... and a reducer's cone is measured without this share of its length at either end, where its
#: knuckles round it.
KNUCKLE_SHARE = 0.25
#: The model's radius is still changing where it differs from both sizes of a step by more than this
#: share of the step.
RAMP_TAIL = 0.02
#: Fewest points about a reducer for its ramp from the points.
MIN_STEP_POINTS = 150
#: A canal branch holds a reducer when the two sizes of its radius' best step differ by more than this
#: share of the larger: less than the 4.3 % between the closest neighbouring catalogue sizes.
MIN_SIZE_STEP = 0.04
#: ... and by more than this many times the RMS wavering of the radius about the step: a scan's canal
#: radius rings about a size by a few per cent over a diameter or so.  On scans of the ``piping`` network
#: (seeds 1 - 5) the sizes of its 4 x 2 reducer stand out by 42 - 46 times their wavering, the best step
#: within the ringing on either side by 2.2 - 2.6 times; a reducer between neighbouring sizes (NPS 3 1/2
#: x 4, 12 %) would stand out by some 10.
STEP_SIGNIFICANCE = 8.0
#: Ramp positions tried by the fit of a size step (the best is then refined on every sample), and the
#: most samples of the radius the fit uses (a longer run's are thinned to these).
STEP_GRID = 200
STEP_SAMPLES = 2000
#: A size must hold for this many radii (of the smaller size) on either side of a reducer: a scan's radius
#: function wavers over a diameter or so, and a real reducer has a pipe or fitting of its size after it.
MIN_PLATEAU_RADII = 2.0
#: The ends of a tee's run point apart within this angle of a straight line (degrees); a junction whose
#: ends are all farther from in line is still called a tee, with a warning.
RUN_ANGLE_DEGREES = 30.0
#: Columns of ``pipes.csv`` (:func:`write_pipes_csv`).
CSV_COLUMNS = (
    "piece", "type", "branch", "branches", "units", "nominal", "measured_od", "catalogue_od", "nearest",
    "nearest_od", "deviation", "deviation_percent", "snap_tolerance", "end_nominal", "end_measured_od",
    "end_catalogue_od", "end_deviation", "outlet_nominal", "outlet_measured_od", "outlet_catalogue_od",
    "outlet_deviation", "length", "bend_radius", "angle", "start_x", "start_y", "start_z", "end_x", "end_y",
    "end_z", "centre_x", "centre_y", "centre_z", "fit_deviation", "fit_tolerance",
)


@dataclass(frozen=True)
class Snap:
    """A measured outside diameter against a catalogue.

    Attributes
    ----------
    diameter : float
        The measured outside diameter, in the model's units.
    nominal : str or None
        The catalogue size it snaps to (``"NPS 4"``, ``"DN 100"``); None when no size is within
        ``tolerance``.
    catalogue_diameter : float or None
        That size's outside diameter, in the model's units; None when it does not snap.
    nearest : str
        The catalogue size of the nearest outside diameter (== ``nominal`` when it snaps).
    nearest_diameter : float
        Its outside diameter, in the model's units.
    deviation : float
        ``diameter - nearest_diameter``, in the model's units.
    tolerance : float
        How far the measured diameter could be from the catalogue's and still snap, in the model's units.
    catalogue : str
        ``"asme"`` or ``"en"``.
    """

    diameter: float
    nominal: str | None
    catalogue_diameter: float | None
    nearest: str
    nearest_diameter: float
    deviation: float
    tolerance: float
    catalogue: str

    @property
    def relative_deviation(self) -> float:
        """``deviation`` as a share of the nearest catalogue diameter."""
        return self.deviation / self.nearest_diameter


@dataclass(eq=False)  # its points are arrays: compare pieces field by field
class Piece:
    """One piece of a piping run: a straight, an elbow, a tee or a reducer.

    Attributes
    ----------
    id : int
        0, 1, ... in order along each run, numbered through the whole network (the fittings at
        junctions, tees, after every run).
    type : {"straight", "elbow", "tee", "reducer"}
    branch : int
        Id of the branch the piece lies on (its middle); a tee: the lower id of its run's two branches.
    branches : tuple of int
        Ids of every branch the piece touches: ``(branch,)``, or two where a piece crosses a junction of
        two branches; a tee: ``(run, run, outlet)``.
    start, end : ndarray, shape (3,)
        Centreline ends, in the model's units (a tee: both are the junction point).
    outside_diameter : float
        Measured (twice the model's radius, averaged over the piece); a reducer: at its start (the mean
        over the stretch of that size before it); a tee: its run's (the first run branch's at the junction).
    end_diameter : float
        A reducer: at its end; otherwise equal to ``outside_diameter``.
    length : float
        Along the centreline (a tee: 0).
    bend_radius, angle : float or None
        An elbow's centreline bend radius and its bend angle in degrees.
    centre : ndarray or None
        An elbow's centre of bend; a tee's junction point.
    nominal : str or None
        Catalogue size of ``outside_diameter`` (``"NPS 4"``, ``"DN 100"``); None when no size is within
        the snapping tolerance (``snaps[0]`` gives the nearest and how far it is).
    catalogue_diameter : float or None
        That size's outside diameter, in the model's units.
    end_nominal, end_catalogue_diameter : str, float or None
        A reducer: the catalogue size at its end; otherwise the same as ``nominal`` and
        ``catalogue_diameter``.
    outlet_diameter, outlet_nominal, outlet_catalogue_diameter : float, str or None
        A tee: the measured outside diameter of its outlet (the third branch) and its catalogue size;
        None for the other pieces.
    snaps : tuple of Snap
        Every size of the piece against the catalogue: ``(start,)``; a reducer ``(start, end)``; a tee
        ``(run, outlet)``.
    fit_deviation : float or None
        Farthest distance of the branch's spine samples on this piece from the fitted chain, in the
        model's units (None for a tee), where the model's radius does not change: at most
        ``fit_tolerance``.  A reducer's is over all its samples: the chain is not held to the spine where
        the radius changes (module docstring), and this says how far the spine wanders there.
    fit_tolerance : float or None
        The tolerance the chain of its run was held to (None for a tee).
    """

    id: int
    type: str
    branch: int
    branches: tuple
    start: np.ndarray
    end: np.ndarray
    outside_diameter: float
    end_diameter: float
    length: float
    bend_radius: float | None
    angle: float | None
    centre: np.ndarray | None
    nominal: str | None
    catalogue_diameter: float | None
    end_nominal: str | None = None
    end_catalogue_diameter: float | None = None
    outlet_diameter: float | None = None
    outlet_nominal: str | None = None
    outlet_catalogue_diameter: float | None = None
    snaps: tuple = field(default=())
    fit_deviation: float | None = None
    fit_tolerance: float | None = None


# --------------------------------------------------------------------------------------------------
# catalogue sizes


def snap_size(diameter, *, catalogue: str = "asme", units: str = "m", uncertainty: float = 0.0) -> Snap:
    """Snap a measured outside diameter to the nearest catalogue size within tolerance.

    The tolerance is ``max(SNAP_RELATIVE x the catalogue diameter, SNAP_SIGMAS x uncertainty)``: the
    order of the manufacturing tolerance of an outside diameter (1 %), or three standard uncertainties
    of the measurement when these are larger.  The nearest size, the deviation from it and the
    tolerance are reported whether it snaps or not.

    Parameters
    ----------
    diameter : float
        Measured outside diameter, in ``units``.
    catalogue : {"asme", "en"}
        ASME B36.10M/B36.19M (nominal pipe sizes NPS 1/8 - 48) or EN 10220 series 1 (DN 6 - 2000).
    units : {"m", "mm", "ft", "in"}
        Units of ``diameter`` and ``uncertainty`` (and of the returned lengths).
    uncertainty : float
        Standard uncertainty of ``diameter``, in ``units`` (0: the 1 % tolerance alone).

    Returns
    -------
    Snap

    Raises
    ------
    InputError
        An unknown catalogue or unit, or a diameter that is not a positive number.

    Examples
    --------
    >>> snap = snap_size(0.1150, units="m")
    >>> snap.nominal, snap.catalogue_diameter, round(snap.deviation * 1000, 2)
    ('NPS 4', 0.1143, 0.7)
    >>> snap_size(120.0, units="mm").nominal is None  # 5 % above NPS 4: no size within 1 %
    True
    """
    catalogue = choice(catalogue, "catalogue", tuple(CATALOGUES))
    per_unit = UNITS[choice(units, "units", tuple(UNITS))]
    value = positive(diameter, "diameter")
    if value is None:
        raise InputError("diameter must be a positive number, got None")
    sigma = 0.0 if not uncertainty else positive(uncertainty, "uncertainty")
    names, sizes = zip(*CATALOGUES[catalogue])
    sizes = np.asarray(sizes) / per_unit
    i = int(np.argmin(np.abs(sizes - value)))
    tolerance = max(SNAP_RELATIVE * float(sizes[i]), SNAP_SIGMAS * float(sigma))
    deviation = value - float(sizes[i])
    snapped = abs(deviation) <= tolerance
    return Snap(value, names[i] if snapped else None, float(sizes[i]) if snapped else None, names[i],
                float(sizes[i]), deviation, tolerance, catalogue)


# --------------------------------------------------------------------------------------------------
# the chain of straights and elbows: geometry


@dataclass
class _Chain:
    """Straights and arcs of a polyline of work points with a bend radius at each interior one.

    ``vertices`` (m + 2, 3) and ``radii`` (m,) as given; the rest derived by :func:`_chain`: per bend
    its effective radius (shrunk where neighbouring bends would overlap on a leg), angle, centre, unit
    vector from the centre to its start ``u``, incoming direction ``a`` (the arc is
    ``centre + R (cos x u + sin x a)``, x in [0, angle]), tangent points ``t1``, ``t2``; per straight its
    ends; and where each primitive starts along the chain.
    """

    vertices: np.ndarray
    radii: np.ndarray
    bend_radius: np.ndarray
    angle: np.ndarray
    centre: np.ndarray
    u: np.ndarray
    a: np.ndarray
    t1: np.ndarray
    t2: np.ndarray
    seg_start: np.ndarray
    seg_end: np.ndarray

    @property
    def lengths(self) -> np.ndarray:
        """Lengths of the primitives in chain order: straight 0, arc 0, straight 1, ..., straight m."""
        seg = np.linalg.norm(self.seg_end - self.seg_start, axis=1)
        arc = self.bend_radius * self.angle
        out = np.empty(2 * len(arc) + 1)
        out[0::2], out[1::2] = seg, arc
        return out


def _chain(vertices: np.ndarray, radii: np.ndarray) -> _Chain:
    """The straights and arcs of the work points ``vertices`` with bend ``radii`` at the interior ones."""
    legs = np.diff(vertices, axis=0)
    leg_length = np.linalg.norm(legs, axis=1)
    unit = legs / np.maximum(leg_length, 1e-300)[:, None]
    a, b = unit[:-1], unit[1:]
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))
    # A U-turn has no work point: keep every bend short of it.
    angle = np.minimum(angle, np.radians(179.0))
    tau = radii * np.tan(angle / 2)
    need = np.zeros(len(legs))
    need[:-1] += tau
    need[1:] += tau
    room = np.minimum(1.0, leg_length / np.maximum(need, 1e-300))
    shrink = np.minimum(room[:-1], room[1:])
    tau, radius = tau * shrink, radii * shrink
    corner = vertices[1:-1]
    t1, t2 = corner - tau[:, None] * a, corner + tau[:, None] * b
    inward = b - a
    inward /= np.maximum(np.linalg.norm(inward, axis=1), 1e-300)[:, None]
    centre = corner + (radius / np.cos(angle / 2))[:, None] * inward
    u = (t1 - centre) / np.maximum(radius, 1e-300)[:, None]
    seg_start = np.vstack([vertices[:1], t2])
    seg_end = np.vstack([t1, vertices[-1:]])
    return _Chain(vertices, radii, radius, angle, centre, u, a, t1, t2, seg_start, seg_end)


def _project(points: np.ndarray, chain: _Chain) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distance of each point from the chain, where its nearest point lies along the chain, and on which
    primitive (straight 0, arc 0, straight 1, ...)."""
    lengths = chain.lengths
    offset = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    n_seg, n_arc = len(chain.seg_start), len(chain.angle)
    dist = np.empty((len(points), n_seg + n_arc))
    along = np.empty_like(dist)
    # straights
    d = chain.seg_end - chain.seg_start
    dd = np.einsum("ij,ij->i", d, d)
    rel = points[:, None, :] - chain.seg_start[None]
    t = np.clip(np.einsum("nij,ij->ni", rel, d) / np.maximum(dd, 1e-300), 0.0, 1.0)
    dist[:, 0::2] = np.linalg.norm(rel - t[..., None] * d[None], axis=2)
    along[:, 0::2] = offset[0::2] + t * lengths[0::2]
    if n_arc:
        w = points[:, None, :] - chain.centre[None]
        x = np.einsum("nij,ij->ni", w, chain.u)
        y = np.einsum("nij,ij->ni", w, chain.a)
        z2 = np.maximum(np.einsum("nij,nij->ni", w, w) - x * x - y * y, 0.0)
        alpha = np.arctan2(y, x)
        inside = (alpha >= 0) & (alpha <= chain.angle)
        on_arc = np.sqrt((np.hypot(x, y) - chain.bend_radius) ** 2 + z2)
        to_t1 = np.linalg.norm(points[:, None, :] - chain.t1[None], axis=2)
        to_t2 = np.linalg.norm(points[:, None, :] - chain.t2[None], axis=2)
        nearer_end = np.where(to_t1 <= to_t2, 0.0, chain.angle)
        dist[:, 1::2] = np.where(inside, on_arc, np.minimum(to_t1, to_t2))
        along[:, 1::2] = offset[1::2] + np.where(inside, alpha, nearer_end) * chain.bend_radius
    best = np.argmin(dist, axis=1)
    rows = np.arange(len(points))
    return dist[rows, best], along[rows, best], best


def _point_at(chain: _Chain, position: float) -> np.ndarray:
    """The point of the chain ``position`` along it."""
    lengths = chain.lengths
    ends = np.cumsum(lengths)
    k = int(min(np.searchsorted(ends, position), len(lengths) - 1))
    local = float(np.clip(position - (ends[k] - lengths[k]), 0.0, lengths[k]))
    if k % 2 == 0:
        start, end = chain.seg_start[k // 2], chain.seg_end[k // 2]
        return start + (end - start) * (local / lengths[k] if lengths[k] > 0 else 0.0)
    j = k // 2
    x = local / chain.bend_radius[j] if chain.bend_radius[j] > 0 else 0.0
    return chain.centre[j] + chain.bend_radius[j] * (np.cos(x) * chain.u[j] + np.sin(x) * chain.a[j])


# --------------------------------------------------------------------------------------------------
# the chain of straights and elbows: the fit


def _fit(points: np.ndarray, vertices: np.ndarray, radii: np.ndarray, offsets=0.0,
         spread: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Interior work points and bend radii minimising the squared distances of ``points`` from the chain
    less ``offsets`` (the end work points stay where the spine ends; lengths in units of the tube's
    radius, so a bend radius stays at least ``MIN_BEND_RADII``).

    Spine samples lie on the chain (``offsets`` 0); a scan's points lie on the tube around it (``offsets``
    the tube's radius at each), and with ``spread`` (their scatter) a point farther off than that counts
    less and less (the soft-L1 loss): a stray point or one of another tube next to it does not pull.
    """
    m = len(radii)
    if m == 0:
        return vertices, radii
    ends = vertices[[0, -1]]

    def unpack(x):
        v = np.vstack([ends[:1], x[: 3 * m].reshape(m, 3), ends[1:]])
        return v, np.exp(x[3 * m:])

    def residual(x):
        return _project(points, _chain(*unpack(x)))[0] - offsets

    # A sample's distance depends only on the bends near the piece it is nearest to (a bend's tangent
    # points share their legs with the neighbouring bends'): finite differences need only a few
    # evaluations per step, however many bends the run has.
    near = _project(points, _chain(vertices, radii))[2] // 2
    bend = np.arange(m)
    touches = np.abs(near[:, None] - bend[None, :]) <= SPARSITY_REACH
    sparsity = np.hstack([np.repeat(touches, 3, axis=1), touches])
    lowest = math.log(MIN_BEND_RADII)
    x0 = np.concatenate([vertices[1:-1].ravel(), np.maximum(np.log(np.maximum(radii, 1e-300)), lowest + 1e-9)])
    bounds = (np.r_[np.full(3 * m, -np.inf), np.full(m, lowest)], np.full(4 * m, np.inf))
    robust = {} if spread is None else {"loss": "soft_l1", "f_scale": spread}
    result = least_squares(residual, x0, bounds=bounds, method="trf", xtol=FIT_TOLERANCE, ftol=FIT_TOLERANCE,
                           gtol=FIT_TOLERANCE, max_nfev=MAX_FIT_EVALUATIONS, jac_sparsity=sparsity, **robust)
    return unpack(result.x)


def _windowed_sagitta(points: np.ndarray, half: int) -> np.ndarray:
    """Per sample, the farthest of its neighbours within ``half`` samples on either side from the chord
    between the outermost two."""
    n = len(points)
    i = np.arange(n)
    lo, hi = np.maximum(i - half, 0), np.minimum(i + half, n - 1)
    out = np.zeros(n)
    chord = points[hi] - points[lo]
    size = np.maximum(np.linalg.norm(chord, axis=1), 1e-300)
    direction = chord / size[:, None]
    for k in range(-half, half + 1):
        j = np.clip(i + k, lo, hi)
        rel = points[j] - points[lo]
        off = rel - np.einsum("ij,ij->i", rel, direction)[:, None] * direction
        out = np.maximum(out, np.linalg.norm(off, axis=1))
    return out


def _line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares line through ``points``: a point on it and its unit direction (first to last)."""
    centre = points.mean(axis=0)
    direction = np.linalg.svd(points - centre, full_matrices=False)[2][0]
    if direction @ (points[-1] - points[0]) < 0:
        direction = -direction
    return centre, direction


def _meet(p1, d1, p2, d2) -> np.ndarray | None:
    """Where two lines come closest (the middle of their common perpendicular); None when parallel."""
    w = p1 - p2
    b = d1 @ d2
    den = 1.0 - b * b
    if den < np.sin(np.radians(MIN_TURN_DEGREES)) ** 2:
        return None
    s = (b * (d2 @ w) - (d1 @ w)) / den
    t = ((d2 @ w) - b * (d1 @ w)) / den
    return (p1 + s * d1 + p2 + t * d2) / 2


def _first_guess(points: np.ndarray, tangents: np.ndarray, spacing: float, radius: float,
                 tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Work points where the lines of the spine's straight stretches meet, and a bend radius for each
    from how far the spine passes inside its work point."""
    half = max(1, int(round(WINDOW_RADII * radius / spacing)))
    bent = _windowed_sagitta(points, half) > tol / 2
    n = len(points)
    # Lines: the least-squares line of each straight stretch at least a window long (a shorter one is
    # the spine wavering on a bend); at an end that lies on a bend, the tangent there.
    edges = np.flatnonzero(np.diff(np.r_[0, (~bent).astype(int), 0]))
    lines = [(_line(points[a:b]), a, b - 1) for a, b in zip(edges[0::2], edges[1::2]) if b - a > half]
    if not lines or lines[0][1] > 0:
        lines.insert(0, ((points[0], tangents[0]), 0, 0))
    if lines[-1][2] < n - 1:
        lines.append(((points[-1], tangents[-1]), n - 1, n - 1))
    vertices, radii = [points[0]], []

    def corner(line1, line2, depth=0):
        (p1, d1), _, i1 = line1
        (p2, d2), i2, _ = line2
        turn = math.acos(float(np.clip(d1 @ d2, -1.0, 1.0)))
        if turn < math.radians(MIN_TURN_DEGREES) and np.linalg.norm(np.cross(p2 - p1, d1)) <= tol:
            return  # one straight
        work = _meet(p1, d1, p2, d2)
        if work is None or depth == 0 and _skew(p1, d1, p2, d2) > tol:
            # An offset between parallel straights, or a turn out of one plane: split the stretch at its
            # middle sample, with the tangent there.
            if i2 - i1 >= 2 and depth < 2:
                k = (i1 + i2) // 2
                middle = ((points[k], tangents[k]), k, k)
                corner(line1, middle, depth + 1)
                corner(middle, line2, depth + 1)
            return
        # The spine passes R (1 / cos(turn / 2) - 1) inside the work point of a bend of radius R; the
        # bend's tangent points lie no farther from it than the stretch between the lines reaches.
        inside = float(np.min(np.linalg.norm(points[i1:i2 + 1] - work, axis=1)))
        reach = max(np.linalg.norm(points[i1] - work), np.linalg.norm(points[i2] - work))
        bend = inside / (1.0 / math.cos(turn / 2) - 1.0)
        vertices.append(work)
        radii.append(float(np.clip(bend, MIN_BEND_RADII * radius,
                                   max(reach / math.tan(turn / 2), MIN_BEND_RADII * radius))))

    for line1, line2 in zip(lines[:-1], lines[1:]):
        corner(line1, line2)
    vertices.append(points[-1])
    return np.asarray(vertices), np.asarray(radii, float)


def _skew(p1, d1, p2, d2) -> float:
    """Shortest distance between two lines that are not parallel."""
    n = np.cross(d1, d2)
    size = np.linalg.norm(n)
    return float(abs((p2 - p1) @ n) / size) if size > 0 else 0.0


def _refined(chain: _Chain, worst: np.ndarray, position: float) -> tuple[np.ndarray, np.ndarray]:
    """One work point more, for the spine sample ``worst`` that the chain misses (``position`` along it).

    Near an elbow, the elbow is split into two halves (the same arc with one work point more, for the
    fit to bend apart); on a straight, a work point at the sample starts a new bend there.
    """
    lengths = chain.lengths
    k = int(min(np.searchsorted(np.cumsum(lengths), position), len(lengths) - 1))
    vertices, radii = chain.vertices, chain.bend_radius
    if k % 2 == 1 and chain.angle[k // 2] > 0:
        j = k // 2
        half = chain.bend_radius[j] * math.tan(chain.angle[j] / 4)
        b = vertices[j + 2] - vertices[j + 1]
        b /= max(np.linalg.norm(b), 1e-300)
        pair = np.vstack([chain.t1[j] + half * chain.a[j], chain.t2[j] - half * b])
        return (np.vstack([vertices[:j + 1], pair, vertices[j + 2:]]),
                np.r_[radii[:j], chain.bend_radius[j], chain.bend_radius[j], radii[j + 1:]])
    j = k // 2  # the straight between bends j - 1 and j
    return np.insert(vertices, j + 1, worst, axis=0), np.insert(radii, j, MIN_BEND_RADII)


def _fit_chain(points: np.ndarray, tangents: np.ndarray, spacing: float, radius: float, tol: float,
               length: float, what: str) -> _Chain:
    """The chain of straights and elbows with the fewest work points found that stays within ``tol``
    of ``points`` (the spine samples, in order)."""
    vertices, radii = _fit(points, *_first_guess(points, tangents, spacing, radius, tol))
    most = max(4, int(MAX_VERTICES_PER_RADIUS * length / radius))
    while True:
        dist, along, _ = _project(points, _chain(vertices, radii))
        if dist.max() <= tol:
            break
        if len(radii) >= most:
            raise ReconstructionError(
                f"{what} is no chain of straights and elbows: with {len(radii)} elbows its spine is still "
                f"{dist.max():.3g} from the chain, more than the tolerance {tol:.3g} — it is not piping, "
                "or its model is too rough (check its quality)")
        # One work point more at the worst sample of each stretch the chain misses, from the last (so that
        # the positions of the earlier ones stay valid).
        out = np.flatnonzero(np.diff(np.r_[0, (dist > tol).astype(int), 0]))
        worst = [a + int(np.argmax(dist[a:b])) for a, b in zip(out[0::2], out[1::2])]
        for i in sorted(worst, key=lambda i: -along[i])[: most - len(radii)]:
            vertices, radii = _refined(_chain(vertices, radii), points[i], along[i])
        vertices, radii = _fit(points, vertices, radii)
    # Drop every work point the chain can do without, the gentlest bends first.
    for angle in np.sort(_chain(vertices, radii).angle):
        k = int(np.argmin(np.abs(_chain(vertices, radii).angle - angle)))
        v, r = _fit(points, np.delete(vertices, k + 1, axis=0), np.delete(radii, k))
        if _project(points, _chain(v, r))[0].max() <= tol:
            vertices, radii = v, r
    return _chain(vertices, radii)


def _fit_to_points(chain: _Chain, cloud: np.ndarray, radius, holes: list, spine: np.ndarray, tol: float) -> _Chain:
    """The chain fitted again to the scan's points ``cloud`` around it (unit coordinates of the run).

    A point's distance from the chain less the tube's radius there (``radius``, a function of the
    position along the chain) is its residual; points along the ``holes`` (positions along the chain:
    reducers, whose radius the model smooths) and those farther than ``POINT_BAND_TOLERANCES`` tolerances
    from the tube's surface are left out.  The new chain is taken only if it stays within ``tol`` of the
    ``spine`` samples, as the first did; otherwise the first is kept.
    """
    dist, along, _ = _project(cloud, chain)
    offset = radius(along)
    use = np.abs(dist - offset) <= POINT_BAND_TOLERANCES * tol
    for a, b in holes:
        use &= (along < a) | (along > b)
    use = np.flatnonzero(use)
    if len(use) < 4 * len(chain.vertices):
        return chain
    if len(use) > FIT_POINTS:
        use = np.sort(np.random.default_rng(0).choice(use, FIT_POINTS, replace=False))
    vertices, radii = _fit(cloud[use], chain.vertices, chain.radii, offset[use], spread=tol / TOLERANCE_RMS)
    fitted = _chain(vertices, radii)
    return fitted if _project(spine, fitted)[0].max() <= tol else chain


# --------------------------------------------------------------------------------------------------
# sizes along a run: plateaus and reducers


def _two_sizes(s: np.ndarray, r: np.ndarray, a: np.ndarray, b: np.ndarray):
    """For ramps from each ``a`` to each ``b`` (arrays of one shape), the least-squares sizes before and
    after and the sum of squared residuals."""
    width = np.maximum(b - a, 1e-9 * max(float(s[-1] - s[0]), 1e-300))
    h = np.clip((s - a[..., None]) / width[..., None], 0.0, 1.0)
    g = 1.0 - h
    a11, a12, a22 = (g * g).sum(-1), (g * h).sum(-1), (h * h).sum(-1)
    b1, b2 = (g * r).sum(-1), (h * r).sum(-1)
    det = np.maximum(a11 * a22 - a12 * a12, 1e-300)
    r1, r2 = (a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det
    sse = ((r1[..., None] * g + r2[..., None] * h - r) ** 2).sum(-1)
    return r1, r2, sse


def _step(s: np.ndarray, r: np.ndarray) -> tuple[float, float, float, float]:
    """The best constant - linear - constant fit to the radius ``r`` at arc lengths ``s``: (r1, r2, a, b),
    the two sizes and where the ramp between them starts and ends.

    Every ramp between ``STEP_GRID`` positions along the run is tried (the sizes are linear least squares
    for each), then every ramp between the samples near the best one's ends, then its ends are refined
    between the samples.
    """
    if len(s) > STEP_SAMPLES:  # a model's radius is a smooth spline: a subsample keeps its steps
        keep = np.unique(np.linspace(0, len(s) - 1, STEP_SAMPLES).round().astype(int))
        s, r = s[keep], r[keep]
    n = len(s)
    pick = np.unique(np.linspace(0, n - 1, min(n, STEP_GRID)).round().astype(int))

    def best_of(starts, stops, on):
        a, b = np.meshgrid(s[starts], s[stops], indexing="ij")
        ok = b >= a
        sse = np.full(a.shape, np.inf)
        sse[ok] = _two_sizes(s[on], r[on], a[ok], b[ok])[2]
        i, j = np.unravel_index(int(np.argmin(sse)), sse.shape)
        return int(starts[i]), int(stops[j]), float(sse[i, j])

    i, j, _ = best_of(pick, pick, pick)
    reach = int(np.ceil(n / len(pick))) + 1
    every = np.arange(n)
    i, j, sse = best_of(every[max(i - reach, 0):i + reach + 1], every[max(j - reach, 0):j + reach + 1], every)
    a, b = float(s[i]), float(s[j])
    span = float(s[-1] - s[0])

    def residual(x):
        r1, r2, _ = _two_sizes(s, r, np.array([x[0]]), np.array([x[0] + abs(x[1])]))
        return r1[0] + (r2[0] - r1[0]) * np.clip((s - x[0]) / max(abs(x[1]), 1e-9 * span), 0.0, 1.0) - r

    x = least_squares(residual, [a, max(b - a, 1e-6 * span)], method="trf", xtol=1e-10, ftol=1e-10).x
    refined = float(np.clip(x[0], s[0], s[-1])), float(np.clip(x[0] + abs(x[1]), s[0], s[-1]))
    if _two_sizes(s, r, np.array([refined[0]]), np.array([refined[1]]))[2][0] < sse:
        a, b = refined
    r1, r2, _ = _two_sizes(s, r, np.array([a]), np.array([b]))
    return float(r1[0]), float(r2[0]), a, b


def _corners(s: np.ndarray, r: np.ndarray, step: tuple) -> tuple[float, float, float, float]:
    """A size ``step`` (r1, r2, a, b) of :func:`_step` with its ramp's ends where its knuckles do not pull.

    Knuckles round the corners of a reducer's profile, and unevenly (a canal surface rounds its convex
    corner more), which pulls the corners of a constant - linear - constant fit: the ends are where the
    line of the ramp's middle (without ``KNUCKLE_SHARE`` of its length at either end) meets the two sizes
    (means over a ramp's length either side, without as much next to it).
    """
    r1, r2, a, b = step
    cut, width = KNUCKLE_SHARE * (b - a), b - a
    before = (s > a - cut - width) & (s < a - cut)
    cone = (s > a + cut) & (s < b - cut)
    after = (s > b + cut) & (s < b + cut + width)
    if min(before.sum(), cone.sum(), after.sum()) < 3:
        return step
    slope, level = np.polyfit(s[cone], r[cone], 1)
    if slope == 0:
        return step
    r1, r2 = float(np.mean(r[before])), float(np.mean(r[after]))
    a, b = sorted(((r1 - level) / slope, (r2 - level) / slope))
    return r1, r2, a, b


def surface_ramp(r1: float, r2: float, a: float, b: float) -> tuple[float, float]:
    """Where the surface of a canal whose radius runs linearly from ``r1`` at ``a`` to ``r2`` at ``b``
    (arc lengths along a straight spine) meets its two sizes.

    A canal surface is the envelope of its spheres: where the radius changes with slope ``k``, the
    sphere at ``s`` touches the surface at ``s - r k`` (ahead of it, towards the smaller size) on a circle
    of radius ``r sqrt(1 - k^2)``.  Its cone is therefore steeper than the ramp of the radius and shifted
    towards the smaller size: a 4 x 2 reducer's by some 0.13 of either radius.  Returns the arc lengths
    where the lines ``r1`` and ``r2`` meet that cone; ``(a, b)`` when the radius does not change or changes
    too fast for an envelope (``|k| >= 1``).
    """
    if not b > a or r1 == r2:
        return a, b
    k = (r2 - r1) / (b - a)
    if abs(k) >= 1.0:
        return a, b
    c = math.sqrt(1.0 - k * k)
    # The contact circle of the sphere of radius r lies at a + (r - r1) / k - r k with radius r c.
    return tuple(a + (r / c - r1) / k - r * k / c for r in (r1, r2))


def _reducers(s: np.ndarray, r: np.ndarray, *, shortest: float) -> list:
    """Where along a run (arc lengths) its size steps, in order: per reducer the step of the model's
    radius ``(r1, r2, a, b)`` (:func:`_step`) and the ramp of its surface ``(a, b)`` (:func:`_corners`,
    :func:`surface_ramp`).

    A step counts when its two sizes differ by more than ``MIN_SIZE_STEP`` of the larger and by more
    than ``STEP_SIGNIFICANCE`` times the RMS wavering of the radius about the step, and each size holds
    for ``shortest`` or more; the stretches either side are then searched again.
    """
    if len(s) < 8 or s[-1] - s[0] < 2 * shortest or np.ptp(r) <= MIN_SIZE_STEP * r.max():
        return []
    r1, r2, a, b = _step(s, r)
    _, _, sse = _two_sizes(s, r, np.array([a]), np.array([b]))
    wavering = math.sqrt(float(sse[0]) / len(s))
    if (abs(r1 - r2) <= max(MIN_SIZE_STEP * max(r1, r2), STEP_SIGNIFICANCE * wavering) or min(r1, r2) <= 0
            or a - s[0] < shortest or s[-1] - b < shortest):
        return []
    left, right = s <= a, s >= b
    surface = surface_ramp(*_corners(s, r, (r1, r2, a, b)))
    return [*_reducers(s[left], r[left], shortest=shortest), ((r1, r2, a, b), surface),
            *_reducers(s[right], r[right], shortest=shortest)]


def _ramp_from_points(cloud: np.ndarray, chain: _Chain, ramp: tuple, sizes: tuple, margin: float) -> tuple:
    """A reducer's ramp (positions along the chain) from the scan's points ``cloud`` about it.

    The distances of the points from the chain (the straight reducer's axis) within ``margin`` of the
    ``ramp`` found on the model's radius, against their positions along it, are fitted as constant -
    linear - constant (:func:`_step`): the model's radius function spreads a step over its knot spacing,
    the points do not.  The ramp must lie within the margin and the sizes either side within
    ``MIN_SIZE_STEP`` of the model's ``sizes``; otherwise the model's ``ramp`` is kept.
    """
    lo, hi = ramp[0] - margin, ramp[1] + margin
    dist, along, _ = _project(cloud, chain)
    small, large = min(sizes), max(sizes)
    near = (along > lo) & (along < hi) & (dist > small / 2) & (dist < large * 1.5)
    if near.sum() < MIN_STEP_POINTS:
        return ramp
    order = np.argsort(along[near], kind="stable")
    x, y = along[near][order], dist[near][order]
    r1, r2, a, b = _corners(x, y, _step(x, y))
    if lo < a < b < hi and all(abs(x - y) <= MIN_SIZE_STEP * large for x, y in zip((r1, r2), sizes)):
        return a, b
    return ramp


# --------------------------------------------------------------------------------------------------
# runs: branches joined through junctions of two


def _runs(branches: dict, junction_ends: dict) -> list[list]:
    """Maximal chains of branches joined at junctions where exactly two ends meet: per run its branches
    in order, each ``(branch id, traversed from t = 1 to t = 0)``, the run in the direction of its lowest
    branch id.  A loop is cut at the t = 0 end of its lowest branch id."""
    through = {j: ends for j, ends in junction_ends.items() if len(ends) == 2}

    def beyond(b: int, end: int):
        """The branch end met at the junction of ``b``'s ``end``, if that junction joins just two."""
        j = branches[b].ends[end]
        others = [e for e in through.get(j, ()) if e != (b, end)]
        return others[0] if others else None

    seen, runs = set(), []
    for first in sorted(branches):
        if first in seen:
            continue
        # Walk back from the first branch's t = 0 end to the run's start (a junction of two branches
        # joins them end to end, so this is a path or a loop), then forward along the run.
        start = (first, False)
        for _ in range(len(branches)):
            b, backwards = start
            other = beyond(b, 1 if backwards else 0)
            if other is None:
                break
            if other[0] == first:
                start = (first, False)
                break
            start = (other[0], other[1] == 0)  # left through its end at the junction
        parts, part = [], start
        for _ in range(len(branches)):
            parts.append(part)
            seen.add(part[0])
            b, backwards = part
            other = beyond(b, 0 if backwards else 1)
            if other is None or other[0] in seen:
                break
            part = (other[0], other[1] == 1)  # entered through its end at the junction
        runs.append(parts)
    return runs


# --------------------------------------------------------------------------------------------------
# the public functions


def decompose(network, points=None, *, units: str = "m", catalogue: str = "asme") -> list[Piece]:
    """Decompose a network's pipes into straights, elbows, tees and reducers with catalogue sizes.

    Each run (a branch, or branches joined at junctions of two) is fitted by a tangent-continuous chain
    of straights and elbows that stays within the run's accuracy of its spine (module docstring): the
    tolerance is ``max(TOLERANCE_RMS x inlier RMS residual, TOLERANCE_RADII x radius)`` of its branches.
    A size step of the radius along a run is a reducer; a junction of three branches a tee.  Every
    outside diameter is snapped to ``catalogue`` by :func:`snap_size`, its uncertainty taken as
    ``2 x noise_sigma / sqrt(points)`` of the branch (the standard error of a fitted radius).

    Parameters
    ----------
    network : Network or CanalModel
        The reconstruction (:func:`canalsurf.reconstruct`), or a single branch.
    points : array_like, shape (N, 3), optional
        The scan it was reconstructed from.  With them the chain of each run is fitted once more, to the
        points around it, and each reducer's ramp is found from them: a scan's spine rounds the corner
        where a straight meets an elbow and its radius function spreads a reducer's step, the points do
        not.  Without them the pieces follow the model alone.
    units : {"m", "mm", "ft", "in"}
        Units of the model's coordinates (the catalogues are in millimetres).
    catalogue : {"asme", "en"}
        ASME B36.10M/B36.19M outside diameters by NPS (1/8 - 48), or EN 10220 series 1 by DN (6 - 2000).

    Returns
    -------
    list of Piece
        Along each run in order, the runs in the order of their first branch id; then the tees, by
        junction id.  Lengths and points are in the model's units.

    Raises
    ------
    InputError
        ``network`` is not a network or branch, or ``units`` or ``catalogue`` is unknown.
    ReconstructionError
        No run is piping: no chain of straights and elbows follows its spine within its tolerance (it is
        not piping, or its model is too rough).

    Warns
    -----
    UserWarning
        A run that is not piping (it is left out, and so are the tees it meets), a junction of three whose
        ends are none in line (still called a tee), or of four or more branches (no fitting is made for it).

    Notes
    -----
    A piece shorter than the tolerance is left out (two elbows welded together have no straight between
    them).  Without ``points`` a reducer's length is that of the model's radius step, which a scan's
    smoothing spline spreads over its knot spacing: a short reducer comes out longer than it is (its sizes
    and middle are sound).  A free end of a run is where the model's spine ends.  A loop is cut at the t = 0 end of its
    lowest branch id, so its first and last pieces may be two parts of one.

    Examples
    --------
    >>> from canalsurf import synth
    >>> net = synth.make_network("piping", n=500)  # the true branches are enough here
    >>> from canalsurf.model import CanalModel
    >>> elbow_run = CanalModel("pipe", net.branches[0].spine, net.branches[0].radius, False)
    >>> pieces = decompose(elbow_run, units="mm")
    >>> [(p.type, p.nominal) for p in pieces][:3]
    [('straight', 'NPS 4'), ('elbow', 'NPS 4'), ('straight', 'NPS 4')]
    >>> round(pieces[1].bend_radius, 1), round(pieces[1].angle, 2)
    (152.4, 90.0)
    """
    units = choice(units, "units", tuple(UNITS))
    catalogue = choice(catalogue, "catalogue", tuple(CATALOGUES))
    if points is not None:
        points = as_points(points, min_points=1)
    branches, junctions = _parts(network)
    junction_ends: dict = {}
    for b in branches.values():
        for e, j in enumerate(b.ends):
            if j is not None:
                junction_ends.setdefault(j, []).append((b.id, e))
    pieces: list[Piece] = []
    ends = {}  # (branch, end) -> (the Snap of the branch's size there, the direction into it), for the tees
    refusals = []
    for run in _runs(branches, junction_ends):
        try:
            pieces += _run_pieces(run, branches, units, catalogue, len(pieces), ends, points)
        except ReconstructionError as exc:
            refusals.append(str(exc))
    if not pieces:
        raise ReconstructionError(refusals[0] if len(refusals) == 1 else
                                  f"no run of the {len(branches)} branches is piping: " + "; ".join(refusals))
    for reason in refusals:
        warnings.warn(f"{reason}; it is left out of the pieces", stacklevel=2)
    points = {j.id: np.asarray(j.point, float) for j in junctions}
    for j in sorted(junction_ends):
        meeting = junction_ends[j]
        if len(meeting) == 3 and any(end not in ends for end in meeting):
            warnings.warn(f"junction {j}: a branch of it is not piping, so it gets no tee", stacklevel=2)
        elif len(meeting) == 3:
            pieces.append(_tee(len(pieces), j, points.get(j), meeting, branches, ends))
        elif len(meeting) > 3:
            warnings.warn(f"junction {j}: {len(meeting)} branches meet there; only tees (three) are made into "
                          "fittings, so it has no piece", stacklevel=2)
    return pieces


def _parts(network) -> tuple[dict, list]:
    """The branches (by id) and junctions of a network, or of a single branch."""
    from .model import CanalModel

    if isinstance(network, CanalModel):
        return {network.id: network}, []
    branches = getattr(network, "branches", None)
    if branches is None or not all(isinstance(b, CanalModel) for b in branches):
        raise InputError(f"network must be a canalsurf Network or CanalModel, got {type(network).__name__}")
    if not branches:
        raise InputError("the network has no branches — nothing to decompose")
    return {b.id: b for b in branches}, list(getattr(network, "junctions", []))


def _samples(branch, reverse: bool, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points and radii of a branch's spine, about ``spacing`` apart, in the run's direction."""
    n = max(MIN_SAMPLES, int(math.ceil(curve_length(branch.spine) / spacing)) + 1)
    t, pts = sample_arclength(branch.spine, n)
    r = np.asarray(branch.radius(t), float).reshape(-1)
    return (pts[::-1], r[::-1]) if reverse else (pts, r)


def _tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents of a polyline by central differences (one-sided at its ends)."""
    d = np.gradient(points, axis=0)
    return d / np.maximum(np.linalg.norm(d, axis=1), 1e-300)[:, None]


def _branch_tolerance(branch, radius: float) -> float:
    """How far a branch's chain may leave its spine: ``TOLERANCE_RMS`` inlier RMS residuals, at least
    ``TOLERANCE_RADII`` radii."""
    rms = (branch.diagnostics or {}).get("inlier_rms_residual")
    rms = float(rms) if rms is not None and math.isfinite(float(rms)) else 0.0
    return max(TOLERANCE_RMS * rms, TOLERANCE_RADII * radius)


def _uncertainty(branch, share: float) -> float:
    """Standard uncertainty of the outside diameter measured on ``share`` of a branch's length: twice
    the standard error of a radius fitted to its points there."""
    d = branch.diagnostics or {}
    sigma, n = d.get("noise_sigma"), d.get("n_points")
    if sigma is None or not n or not math.isfinite(float(sigma)):
        return 0.0
    return 2.0 * float(sigma) / math.sqrt(max(float(n) * share, 1.0))


def _intervals(lo: float, hi: float, holes: list) -> list:
    """[lo, hi] without the intervals ``holes`` (sorted, not overlapping)."""
    out, x = [], lo
    for a, b in holes:
        if b <= x or a >= hi:
            continue
        if a > x:
            out.append((x, a))
        x = max(x, b)
    if x < hi:
        out.append((x, hi))
    return out


def _run_pieces(run: list, branches: dict, units: str, catalogue: str, first_id: int, ends: dict,
                points: np.ndarray | None) -> list:
    """The pieces of one run, numbered from ``first_id``, fitted to ``points`` too if given; records in
    ``ends`` the size of each branch at each of its ends (for the tees)."""
    radius = min(float(np.min(branches[b].radius(np.linspace(0.0, 1.0, 64)))) for b, _ in run)
    if not radius > 0:
        raise ReconstructionError(f"branch {run[0][0]} has no positive radius — it cannot be piping")
    spacing = SAMPLE_SPACING_RADII * radius
    pts, r, owner = [], [], []
    for b, rev in run:
        p, rr = _samples(branches[b], rev, spacing)
        if pts:  # the junction is the last sample of one branch and the first of the next
            p, rr = p[1:], rr[1:]
        pts.append(p), r.append(rr), owner.append(np.full(len(p), b))
    pts, r, owner = (np.concatenate(x) for x in (pts, r, owner))
    s = polyline_arclength(pts)
    tol = max(_branch_tolerance(branches[b], radius) for b, _ in run)
    names = " + ".join(f"branch {b}" for b, _ in run)
    # Fit in units of the radius about the run's first point, so that the fit sees the same numbers in
    # any unit and placement.
    origin, scale = pts[0], radius
    unit_pts = (pts - origin) / scale
    shortest = MIN_PLATEAU_RADII * radius
    steps = _reducers(s, r, shortest=shortest)
    # A reducer is straight; where the radius changes, a scan's spine is no better than its radius
    # function (a canal fitted to a cone wanders off the axis), so the chain is fitted to, and held to
    # its tolerance on, the spine outside the model's radius steps -- and their tails, which the model's
    # smoothing spreads (within the plateaus' least length).
    fitted = np.ones(len(s), bool)
    for (r1, r2, a, b), _ in steps:
        margin = RAMP_TAIL * abs(r2 - r1)
        changing = (np.abs(r - r1) > margin) & (np.abs(r - r2) > margin)
        fitted &= ((s < a) | (s > b)) & ~(changing & (s > a - shortest) & (s < b + shortest))
    steps = [surface for _, surface in steps]
    chain = _fit_chain(unit_pts[fitted], _tangents(unit_pts)[fitted], spacing / scale, 1.0, tol / scale,
                       s[-1] / scale, names)

    def placed(chain):  # the spine samples projected on a chain, and the reducers' ramps along it
        dist, along, _ = _project(unit_pts, chain)
        return dist, along, [(float(np.interp(a, s, along)), float(np.interp(b, s, along))) for a, b in steps]

    dist, along, ramps = placed(chain)
    if points is not None:
        # The points in a box about the run (which holds its tube), in the run's unit coordinates.
        reach = 2.0 * float(r.max())
        inside = np.flatnonzero(np.all((points >= pts.min(axis=0) - reach) & (points <= pts.max(axis=0) + reach),
                                       axis=1))
        if len(inside) > BOX_POINTS:  # every point is measured against every piece of the run
            inside = np.sort(np.random.default_rng(0).choice(inside, BOX_POINTS, replace=False))
        cloud = (points[inside] - origin) / scale
        order = np.argsort(along, kind="stable")
        at, radii = along[order], r[order] / scale

        def size(x):  # the model's radius at positions x along the first chain, in units of the run's radius
            return np.interp(x, at, radii)

        margin = shortest / scale
        chain = _fit_to_points(chain, cloud, size, [(a - margin, b + margin) for a, b in ramps],
                               unit_pts[fitted], tol / scale)
        dist, along, ramps = placed(chain)
        ramps = [_ramp_from_points(cloud, chain, ramp, (size(ramp[0] - margin), size(ramp[1] + margin)), margin)
                 for ramp in ramps]
    dist, along = dist * scale, along * scale
    ramps = [(a * scale, b * scale) for a, b in ramps]
    lengths = chain.lengths * scale
    total = float(lengths.sum())

    def nearest(x):  # the spine sample nearest to a position along the chain
        return int(np.argmin(np.abs(along - x)))

    def diameter(x0, x1):  # the model's mean, where its radius is not changing if it holds anywhere there
        i0, i1 = sorted((nearest(x0), nearest(x1)))
        held = fitted[i0:i1 + 1]
        return 2.0 * float(np.mean(r[i0:i1 + 1][held] if held.any() else r[i0:i1 + 1]))

    def snap(d, x0, x1):
        b = branches[int(owner[nearest((x0 + x1) / 2)])]
        share = max(x1 - x0, spacing) / total
        return snap_size(d, catalogue=catalogue, units=units, uncertainty=_uncertainty(b, share))

    def point(x):
        return _point_at(chain, x / scale) * scale + origin

    # Pieces: each straight and arc of the chain less the reducers' ramps, and the ramps.
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    items = [(lo, hi, k) for k in range(len(lengths))
             for lo, hi in _intervals(starts[k], starts[k] + lengths[k], ramps)]
    items += [(a, b, None) for a, b in ramps]
    plateaus = _intervals(0.0, total, ramps)
    out, spans = [], []
    for lo, hi, k in sorted(items, key=lambda item: (item[0], item[1])):
        if k is not None and hi - lo <= tol:
            continue  # shorter than the accuracy: no piece
        # The chain is held to the spine where the model's radius does not change (a reducer is measured
        # by how far the spine wanders from it there).
        near = (along >= lo) & (along <= hi) & (fitted | (k is None))
        middle = int(owner[nearest((lo + hi) / 2)])
        # The branches it touches: those of the samples inside it; a reducer (which may have no length, at
        # a junction of two sizes) also the samples just either side of it.
        inside = np.flatnonzero((along > lo) & (along < hi))
        if k is None:
            inside = np.r_[inside, np.flatnonzero(along < lo)[-1:], np.flatnonzero(along > hi)[:1]]
        touched = sorted({middle, *(int(b) for b in owner[inside])}, key=lambda b: (b != middle, b))
        fields = dict(start=point(lo), end=point(hi), length=hi - lo, bend_radius=None, angle=None, centre=None,
                      branch=middle, branches=tuple(touched),
                      fit_deviation=float(dist[near].max()) if near.any() else float(dist[nearest(lo)]))
        if k is None:
            # A reducer joins the sizes of the plateaus on either side of it.
            before = [p for p in plateaus if p[1] <= lo + 1e-9 * total]
            after = [p for p in plateaus if p[0] >= hi - 1e-9 * total]
            d0 = diameter(*before[-1]) if before else 2.0 * float(r[nearest(lo)])
            d1 = diameter(*after[0]) if after else 2.0 * float(r[nearest(hi)])
            snaps = (snap(d0, lo, hi), snap(d1, lo, hi))
            kind = "reducer"
        else:
            d0 = d1 = diameter(lo, hi)
            snaps = (snap(d0, lo, hi),)
            kind = "straight" if k % 2 == 0 else "elbow"
            if kind == "elbow":
                j = k // 2
                fields.update(bend_radius=float(chain.bend_radius[j] * scale),
                              angle=float(np.degrees((hi - lo) / (chain.bend_radius[j] * scale))),
                              centre=chain.centre[j] * scale + origin)
        out.append(Piece(first_id + len(out), kind, fields["branch"], fields["branches"], fields["start"],
                         fields["end"], d0, d1, fields["length"], fields["bend_radius"], fields["angle"],
                         fields["centre"], snaps[0].nominal, snaps[0].catalogue_diameter, snaps[-1].nominal,
                         snaps[-1].catalogue_diameter, snaps=snaps, fit_deviation=fields["fit_deviation"],
                         fit_tolerance=tol))
        spans.append((lo, hi))
    # Each branch end's size (of the piece there) and the direction into the branch from that end.
    for b, rev in run:
        branch = branches[b]
        here = np.flatnonzero(owner == b)
        step = min(0.5, 2.0 * radius / max(curve_length(branch.spine), 1e-300))
        for e in (0, 1):
            x = along[here[0] if (e == 0) != rev else here[-1]]
            k = min(range(len(out)), key=lambda i: max(spans[i][0] - x, x - spans[i][1], 0.0), default=None)
            size = snap_size(2.0 * float(branch.radius(float(e))), catalogue=catalogue, units=units)
            if k is not None:
                piece = out[k]
                at_end = abs(x - spans[k][1]) < abs(x - spans[k][0])
                size = piece.snaps[-1] if piece.type == "reducer" and at_end else piece.snaps[0]
            into = branch.spine(abs(e - step)) - branch.spine(float(e))
            ends[(b, e)] = (size, into / max(np.linalg.norm(into), 1e-300))
    return out


def _tee(piece_id: int, j: int, point, meeting: list, branches: dict, ends: dict) -> Piece:
    """The tee where three branch ends meet: the two most nearly in line are its run."""
    into = [ends[end][1] for end in meeting]  # from the junction into each branch
    # The two ends of a run leave the junction in opposite directions.
    a, b, c = min(((0, 1, 2), (0, 2, 1), (1, 2, 0)), key=lambda p: float(into[p[0]] @ into[p[1]]))
    off_line = math.degrees(math.acos(float(np.clip(-into[a] @ into[b], -1.0, 1.0))))
    if off_line > RUN_ANGLE_DEGREES:
        warnings.warn(f"junction {j}: no two of its branches are in line (the straightest pair is "
                      f"{off_line:.0f} degrees off); called a tee with branches {meeting[a][0]} and "
                      f"{meeting[b][0]} as its run", stacklevel=3)
    run = sorted((meeting[a], meeting[b]))
    outlet = meeting[c]
    run_snaps = [ends[end][0] for end in run]
    outlet_snap = ends[outlet][0]
    if point is None:
        point = branches[run[0][0]].spine(float(run[0][1]))
    point = np.asarray(point, float)
    main = run_snaps[0]
    diameter = main.diameter
    return Piece(piece_id, "tee", run[0][0], (run[0][0], run[1][0], outlet[0]), point.copy(), point.copy(),
                 diameter, diameter, 0.0, None, None, point.copy(), main.nominal, main.catalogue_diameter,
                 main.nominal, main.catalogue_diameter, outlet_snap.diameter, outlet_snap.nominal,
                 outlet_snap.catalogue_diameter, snaps=(main, outlet_snap))


def write_pipes_csv(path, pieces, *, units: str = "m") -> None:
    """Write the pieces as ``pipes.csv``, atomically: one row per piece, columns ``CSV_COLUMNS``.

    Each row gives the piece's id, type, branch and the branches it touches (separated by ``;``), the
    units of its lengths, its catalogue size (empty when none is within tolerance), the measured,
    catalogue and nearest catalogue outside diameters with the deviation from the nearest (absolute and
    in per cent) and the snapping tolerance; for a reducer its end size, for a tee its outlet's, the same
    way; length, bend radius and angle (degrees), start, end and centre points; how far the spine is
    from the piece and the tolerance it was held to.  Numbers are written with the fewest digits that
    read back to the same float64; missing values are empty.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (its folder must exist).
    pieces : list of Piece
        As :func:`decompose` returns them.
    units : {"m", "mm", "ft", "in"}
        Units of the pieces' lengths (written in the ``units`` column).

    Raises
    ------
    InputError
        Unknown units, something other than pieces, or a path that cannot be written.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from canalsurf import synth
    >>> from canalsurf.model import CanalModel
    >>> b = synth.make_network("piping", n=500).branches[1]
    >>> target = pathlib.Path(tempfile.mkdtemp()) / "pipes.csv"
    >>> write_pipes_csv(target, decompose(CanalModel("pipe", b.spine, b.radius, False), units="mm"), units="mm")
    >>> target.read_text().splitlines()[2].split(",")[:6]
    ['1', 'elbow', '0', '0', 'mm', 'NPS 2']
    """
    from .io import atomic_write

    units = choice(units, "units", tuple(UNITS))
    pieces = list(pieces)
    if not all(isinstance(p, Piece) for p in pieces):
        raise InputError("pieces must be a list of canalsurf.piping.Piece, as decompose returns")
    rows = [_csv_row(p, units) for p in pieces]

    def write(tmp):
        with open(tmp, "w", encoding="utf-8", newline="\n") as f:
            f.write(",".join(CSV_COLUMNS) + "\n")
            for row in rows:
                f.write(",".join(row) + "\n")

    atomic_write(path, write)


def _text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    return repr(float(value))


def _csv_row(p: Piece, units: str) -> list[str]:
    main = p.snaps[0] if p.snaps else None
    end = p.snaps[1] if p.type == "reducer" and len(p.snaps) > 1 else None
    outlet = p.snaps[1] if p.type == "tee" and len(p.snaps) > 1 else None
    values = {
        "piece": str(p.id), "type": p.type, "branch": str(p.branch),
        "branches": ";".join(str(b) for b in p.branches), "units": units,
        "nominal": p.nominal, "measured_od": p.outside_diameter, "catalogue_od": p.catalogue_diameter,
        "nearest": main.nearest if main else None, "nearest_od": main.nearest_diameter if main else None,
        "deviation": main.deviation if main else None,
        "deviation_percent": 100 * main.relative_deviation if main else None,
        "snap_tolerance": main.tolerance if main else None,
        "end_nominal": end.nominal if end else None, "end_measured_od": end.diameter if end else None,
        "end_catalogue_od": end.catalogue_diameter if end else None,
        "end_deviation": end.deviation if end else None,
        "outlet_nominal": outlet.nominal if outlet else None,
        "outlet_measured_od": outlet.diameter if outlet else None,
        "outlet_catalogue_od": outlet.catalogue_diameter if outlet else None,
        "outlet_deviation": outlet.deviation if outlet else None,
        "length": p.length, "bend_radius": p.bend_radius, "angle": p.angle,
        "fit_deviation": p.fit_deviation, "fit_tolerance": p.fit_tolerance,
    }
    for name, v in (("start", p.start), ("end", p.end), ("centre", p.centre)):
        for axis in range(3):
            values[f"{name}_{'xyz'[axis]}"] = None if v is None else float(np.asarray(v, float)[axis])
    return [_text(values[column]) for column in CSV_COLUMNS]
