"""Seeded test surfaces: the paper's Section 4 experiments and a few more.

Every generator returns a :class:`SyntheticTube`: the sampled points with their true outward normals
and the ground truth (spine and radius as B-splines on ``t in [0, 1]``).  Points are drawn uniformly by
surface area (a scanner's even density) or, with ``sampling="parameter"``, uniformly in the surface
parameters ``(s, t)`` as the paper most likely did; each is perturbed by a uniform random offset in
``[-noise, noise]`` along the true normal (the paper's ``epsilon(s, t)``).

The paper's surfaces (Section 4, Tables 1-3):

``fig9-pipe``    Table 1 spine, knots (0,0,0,0,1,2,3,3,3,3), r = 1, epsilon = 0.1.
``fig15-pipe``   Table 2 spine, knots (0,0,0,0,1,...,6,7,7,7,7), epsilon = 0.05.  The text says r = 3, but the
                 paper's own result (Eq. 6 gives 0.298778, R = 0.1) and the spine's size (it fits in a 3x3x3 box,
                 smallest radius of curvature about 0.285) show the true radius is 0.3: r = 3 would
                 self-intersect everywhere.  We use r = 0.3.
``fig14-canal``  Table 1 spine; r(t) a quadratic B-spline, knots (0,0,0,1,2,3,4,4,4), coefficients
                 (2, 1.5, 1, 1.5, 2.5, 2); its parameter range [0, 4] is mapped linearly onto the spine's.
``fig16-canal``  Table 3 spine, knots (0,0,0,0,1,2,3,3,3,3); r(t) a cubic B-spline on the same knots with
                 coefficients (1.9999, 1.6666, 1.103463, 1.037336, 1.833333, 2.5); epsilon = 0.05.

Further shapes, for the conditions of real scans: ``helix`` (a pipe around a helical spine), ``torus``
(a closed spine), ``trefoil`` (a closed knot whose strands pass within four radii of each other),
``elbow`` (two straight legs joined by a bend of radius 2 r), ``tight-helix`` (turns three radii apart),
``long-thin`` (length 300 r) and ``canal-x3`` (a canal whose radius grows threefold).

Real-scan conditions are options of :func:`make_tube`: Gaussian instead of uniform noise, stray points
in the bounding box (``outliers``), density falling along the spine (``density_ratio``) and one-sided
scans (``arc``: only the part of each cross-section that faces one viewing direction).

Networks of tubes (:func:`make_network`, :data:`NETWORKS`) return a :class:`SyntheticNetwork`: the points
on the surface of the union of several tubes, each labelled with its branch (or -1 on clutter), and
the branches (spine, radius, the junctions at their ends).  A branch ends at a junction: a T is three
branches (the main pipe split at the junction, and the side pipe, whose spine starts on the main axis).
Noise there is relative to the local radius.  Layouts (branch indices in order):

``y-vessel``       0 parent canal ending at junction 0; 1, 2 daughters starting there (25 and 50 degrees).
``t-junction``     0, 1 the main pipe's halves (0 ends, 1 starts at junction 0); 2 the side pipe.
``tree``           0 - 3 the stem's pieces from the foot up, split at junctions 0, 1, 2 (heights 5, 10,
                   15); 4, 5, 6 the side branches from junctions 0, 1, 2.
``rack``           0 - 3 parallel pipes (radii 1, 1.5, 0.8, 2), no junctions.
``crossing``       0 along x, 1 along y above it, no junctions.
``floor-clutter``  0 the pipe; a floor and a box as clutter.
``scene``          0 - 2 a T (junction 0), 3 - 5 a rack, 6, 7 a crossing pair; a box and a floor.
``plant``          per bay (``size`` of them): 15 rack pipes, 2 elbow runs, 2 T's (3 branches each); a box;
                   one floor.
``piping``         in millimetres: 0 an NPS 4 run (straight, long-radius 90-degree elbow, straight, 3R
                   45-degree elbow, straight); 1 an NPS 2 run with a long-radius elbow; 2, 3 the NPS 4 run
                   of a reducing tee (junction 0), 4 its NPS 2 outlet; 5 NPS 4, a 4 x 2 reducer, NPS 2.
                   :func:`piping_truth` gives its pieces.

Simulated scans (:func:`scan`) show any surface or network as a terrestrial laser scanner sees it: from
one to a few positions, rays on an angular grid (so the spacing grows with range), the first hit of each
(a tube hides its far side and what stands behind it), noise along the ray growing with range,
coordinates rounded as in a LAS file, a ground plane under the scene; the truth is kept, with each
point's scanner and range.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline
from scipy.spatial import cKDTree

from ._validate import choice
from .spine import constant_spline, polyline_arclength
from .errors import InputError

__all__ = ["SyntheticTube", "SURFACES", "CONDITIONS", "make_tube", "sample_tube", "view_direction", "constant_spline",
           "SyntheticBranch", "SyntheticNetwork", "NETWORKS", "make_network", "MAX_SYNTH_POINTS", "scan",
           "ScanInfo", "SyntheticPiece", "piping_truth"]

_TABLE1 = [[-3.000, 6.660, 0.000], [-0.337, 5.660, -4.660], [0.410, 0.430, -8.052],
           [-2.037, -7.906, -3.354], [1.813, -6.807, -0.175], [6.760, -3.150, 0.000]]
_TABLE2 = [[0.000, 0.000, 0.000], [2.773, -0.234, 0.159], [3.091, 0.058, -0.043],
           [3.086, 2.917, -0.365], [2.939, 3.054, 0.247], [0.066, 3.159, -0.292],
           [-0.279, 2.959, 0.377], [0.411, 3.108, 2.569], [-0.045, 2.942, 2.928],
           [0.000, 0.000, 3.000]]
_TABLE3 = [[-4.000, 4.000, 0.000], [-0.478, 4.547, 0.000], [3.335, 2.618, 0.000],
           [1.428, -1.214, 0.000], [-3.543, -1.614, 0.000], [-4.257, -4.700, 0.000]]
_KNOTS_6 = [0, 0, 0, 0, 1, 2, 3, 3, 3, 3]
_KNOTS_10 = [0, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 7, 7, 7]
#: Most points a generator makes.  Sampling holds about 750 bytes per point at its peak (the rejection
#: sampler's candidates and their frames: measured 725 bytes per point for make_tube at 1 and 4 million
#: points), so 20 million points need some 15 GB, most of a 24 GB machine; more is refused before anything
#: is allocated.
MAX_SYNTH_POINTS = 20_000_000
#: A one-sided scan's viewing direction, projected on a cross-section's plane, shorter than this
#: (the spine points at the viewer) gives no side to face; such cross-sections keep an arbitrary one.
VIEW_MIN_PROJECTION = 0.1


@dataclass(frozen=True)
class SyntheticTube:
    """A sampled tube with its ground truth.

    Attributes
    ----------
    name : str
    points, normals : ndarray, shape (N, 3)
        Sampled (perturbed) points and the true outward unit normals there (in a simulated scan turned
        towards the scanner, so inwards on a tube's inside).
    spine : scipy.interpolate.BSpline
        True spine C(t), t in [0, 1] (periodic when ``closed``).
    radius : scipy.interpolate.BSpline
        True radius r(t) on the same parameter.
    closed : bool
    noise : float
        Half-width of the uniform perturbation along the normal (its standard deviation when
        ``noise_model`` is ``"gaussian"``).
    noise_model : {"uniform", "gaussian"}
        For a simulated scan (``noise_model="scan"``) the standard deviation at range 0, along the ray;
        ``scan`` gives each point's.
    noise_model : {"uniform", "gaussian", "scan"}
    outlier : ndarray of bool, shape (N,)
        Points not on the tube: stray points (their ``normals`` are random directions), or in a simulated
        scan the points on the ground.
    arc : float
        Degrees of each cross-section that were sampled (360 for a full scan; nan for a simulated scan,
        whose coverage varies along the tube).
    scan : ScanInfo, optional
        How a simulated scan (:func:`scan`) was made and where each point was seen from; None for a
        sampled cloud.
    """

    name: str
    points: np.ndarray
    normals: np.ndarray
    spine: BSpline
    radius: BSpline
    closed: bool
    noise: float
    noise_model: str = "uniform"
    outlier: np.ndarray | None = None
    arc: float = 360.0
    scan: "ScanInfo | None" = None

    @property
    def is_pipe(self) -> bool:
        """True when the radius is constant."""
        return bool(np.ptp(self.radius.c) == 0)


def _bspline(knots, coefs, k) -> BSpline:
    knots = np.asarray(knots, dtype=float)
    return BSpline(knots / knots[-1], np.asarray(coefs, dtype=float), k)


def _helix_spine(turns=2.0, radius=3.0, pitch=4.0) -> BSpline:
    t = np.linspace(0, 1, 200)
    a = 2 * np.pi * turns * t
    xyz = np.column_stack([radius * np.cos(a), radius * np.sin(a), pitch * turns * t])
    return make_interp_spline(t, xyz, k=3)


def _circle_spine(radius=4.0) -> BSpline:
    t = np.linspace(0, 1, 129)
    a = 2 * np.pi * t
    xyz = np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros_like(a)])
    xyz[-1] = xyz[0]
    return make_interp_spline(t, xyz, k=3, bc_type="periodic")


def _trefoil_spine(scale=1.0) -> BSpline:
    t = np.linspace(0, 1, 257)
    u = 2 * np.pi * t
    xyz = scale * np.column_stack([np.sin(u) + 2 * np.sin(2 * u), np.cos(u) - 2 * np.cos(2 * u), -np.sin(3 * u)])
    xyz[-1] = xyz[0]
    return make_interp_spline(t, xyz, k=3, bc_type="periodic")


def _by_arclength(xyz: np.ndarray) -> BSpline:
    """Interpolating cubic through dense samples of a path, parameterised by normalised chord length."""
    s = polyline_arclength(xyz)
    return make_interp_spline(s / s[-1], xyz, k=3)


def _elbow_spine(leg=6.0, bend=2.0) -> BSpline:
    u = np.linspace(0, 1, 120)[1:, None]
    a = np.linspace(0, np.pi / 2, 160)[:, None]
    zero = np.zeros_like(u)
    first = np.hstack([zero, -leg * u[::-1], zero])
    arc = np.hstack([bend * (1 - np.cos(a)), bend * np.sin(a), np.zeros_like(a)])
    second = np.hstack([bend + leg * u, np.full_like(u, bend), zero])
    return _by_arclength(np.vstack([first, arc, second]))


def _long_spine(length=30.0, amplitude=1.5) -> BSpline:
    x = np.linspace(0, length, 600)
    return _by_arclength(np.column_stack([x, amplitude * np.sin(2 * np.pi * x / length),
                                          0.5 * amplitude * np.sin(np.pi * x / length)]))


def _arc_spine(radius=12.0, rise=4.0) -> BSpline:
    a = np.linspace(0, np.pi / 2, 300)
    return _by_arclength(np.column_stack([radius * np.cos(a), radius * np.sin(a), rise * a / (np.pi / 2)]))


#: name -> (spine, radius, closed, default noise, description)
SURFACES = {
    "fig9-pipe": (lambda: _bspline(_KNOTS_6, _TABLE1, 3), lambda: constant_spline(1.0), False, 0.1,
                  "the paper's Figure 9 pipe: Table 1 spine, r = 1"),
    "fig15-pipe": (lambda: _bspline(_KNOTS_10, _TABLE2, 3), lambda: constant_spline(0.3), False, 0.05,
                   "the paper's Figure 15 pipe: Table 2 spine, r = 0.3 (the text's '3' is a typo)"),
    "fig14-canal": (lambda: _bspline(_KNOTS_6, _TABLE1, 3),
                    lambda: _bspline([0, 0, 0, 1, 2, 3, 4, 4, 4], [2, 1.5, 1, 1.5, 2.5, 2], 2), False, 0.05,
                    "the paper's Figure 14 canal: Table 1 spine, quadratic r(t) from 1.125 to 2.25"),
    "fig16-canal": (lambda: _bspline(_KNOTS_6, _TABLE3, 3),
                    lambda: _bspline(_KNOTS_6, [1.9999, 1.6666, 1.103463, 1.037336, 1.833333, 2.5], 3),
                    False, 0.05, "the paper's Figure 16 canal: Table 3 spine, cubic r(t)"),
    "helix": (_helix_spine, lambda: constant_spline(0.5), False, 0.025,
              "a pipe of radius 0.5 around two turns of a helix (radius 3, pitch 4)"),
    "torus": (_circle_spine, lambda: constant_spline(1.0), True, 0.05,
              "a torus: circular closed spine of radius 4, tube radius 1"),
    "trefoil": (_trefoil_spine, lambda: constant_spline(0.3), True, 0.015,
                "a pipe of radius 0.3 around a trefoil knot (closed; strands 1.2 apart)"),
    "elbow": (_elbow_spine, lambda: constant_spline(1.0), False, 0.05,
              "a pipe of radius 1: two straight legs of 6 joined by a 90-degree bend of radius 2"),
    "tight-helix": (lambda: _helix_spine(turns=3.0, radius=2.0, pitch=1.5), lambda: constant_spline(0.5), False,
                    0.025, "a pipe of radius 0.5 around three turns of a helix of pitch 1.5 (turns 3 r apart)"),
    "long-thin": (_long_spine, lambda: constant_spline(0.1), False, 0.005,
                  "a pipe of radius 0.1 along a gently curving spine of length about 30 (300 radii)"),
    "canal-x3": (_arc_spine, lambda: _bspline([0, 0, 0, 0, 1, 2, 3, 3, 3, 3], [0.5, 0.55, 0.9, 1.2, 1.45, 1.5], 3),
                 False, 0.025, "a canal around a rising quarter circle whose radius grows from 0.5 to 1.5"),
}


#: Real-scan conditions (the robustness tests and ``benchmarks/conditions.py`` run these):
#: name -> (surface, options of :func:`make_tube`).
CONDITIONS = {
    "uniform-noise-10pc": ("fig9-pipe", {"noise": 0.1}),
    "gaussian-noise-3pc": ("fig9-pipe", {"noise": 0.03, "noise_model": "gaussian"}),
    "gaussian-noise-canal": ("fig14-canal", {"noise": 0.05, "noise_model": "gaussian"}),
    "outliers-5pc-pipe": ("fig9-pipe", {"outliers": 0.05}),
    "outliers-5pc-canal": ("fig14-canal", {"outliers": 0.05}),
    "500-points": ("fig9-pipe", {"n": 500}),
    "density-x10": ("fig9-pipe", {"n": 4000, "density_ratio": 10}),
    "torus": ("torus", {}),
    "trefoil-knot": ("trefoil", {"n": 5000}),
    "elbow-bend-2r": ("elbow", {}),
    "tight-helix-3r": ("tight-helix", {"n": 5000}),
    "long-thin-300r": ("long-thin", {"n": 20000}),
    "canal-radius-x3": ("canal-x3", {}),
    "one-sided-180": ("fig9-pipe", {"arc": 180}),
    "one-sided-270": ("fig9-pipe", {"arc": 270}),
    "one-sided-120": ("fig9-pipe", {"arc": 120}),
    "one-sided-canal": ("fig14-canal", {"arc": 180}),
    "one-sided-elbow": ("elbow", {"arc": 200}),
}


def _frame(tangent: np.ndarray, view: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing each unit tangent to an orthonormal frame.

    With ``view``, the first points towards the viewer (``view`` projected on the normal plane),
    where that projection is not too short.
    """
    helper = np.where(np.abs(tangent[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    n1 = np.cross(tangent, helper)
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    if view is not None:
        towards = view - (tangent @ view)[:, None] * tangent
        size = np.linalg.norm(towards, axis=1, keepdims=True)
        n1 = np.where(size > VIEW_MIN_PROJECTION, towards / np.maximum(size, 1e-300), n1)
    return n1, np.cross(tangent, n1)


def _envelope(spine: BSpline, radius: BSpline, t: np.ndarray, s: np.ndarray, n1=None, n2=None, view=None):
    """Points and outward normals of the canal surface at (s, t), and the frame used."""
    d1 = spine.derivative()(t)
    speed = np.linalg.norm(d1, axis=1)
    tangent = d1 / speed[:, None]
    rho = radius.derivative()(t) / speed  # dr/ds: sine of the envelope's angle
    if np.any(np.abs(rho) >= 1):
        raise InputError("the radius changes faster than the spine advances (|dr/ds| >= 1): no envelope")
    if n1 is None:
        n1, n2 = _frame(tangent, view)
    else:  # keep the given frame, made orthogonal to this tangent
        n1 = n1 - np.einsum("ij,ij->i", n1, tangent)[:, None] * tangent
        n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
        n2 = np.cross(tangent, n1)
    normal = (-rho[:, None] * tangent
              + np.sqrt(1 - rho**2)[:, None] * (np.cos(s)[:, None] * n1 + np.sin(s)[:, None] * n2))
    return spine(t) + radius(t)[:, None] * normal, normal, n1, n2


def _area_element(spine: BSpline, radius: BSpline, t: np.ndarray, s: np.ndarray, view=None) -> np.ndarray:
    """|A_s x A_t| by finite differences (the frame is carried along so it does not jump)."""
    h = 1e-6
    a, _, n1, n2 = _envelope(spine, radius, t, s, view=view)
    a_s = (_envelope(spine, radius, t, s + h, n1, n2)[0] - a) / h
    a_t = (_envelope(spine, radius, np.minimum(t + h, 1.0), s, n1, n2)[0] - a) / h
    return np.linalg.norm(np.cross(a_s, a_t), axis=1)


def view_direction(spine: BSpline) -> np.ndarray:
    """The direction a one-sided scan looks from: the normal of the spine's best-fitting plane.

    It is perpendicular to every tangent of a planar spine, so each cross-section is seen from the side.
    """
    xyz = spine(np.linspace(0.0, 1.0, 512))
    return np.linalg.svd(xyz - xyz.mean(axis=0))[2][-1]


def _surface_parameters(spine: BSpline, radius: BSpline, n: int, rng, sampling: str = "area",
                        arc: tuple[float, float] = (0.0, 2 * np.pi), view=None, density_ratio: float = 1.0,
                        bound: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (t, s) of ``n`` points on the canal surface, drawn as :func:`sample_tube` describes.

    ``arc`` is the range of s; ``bound`` an upper bound of the area element (by default 1.2 times the
    largest of 20000 random samples of it).
    """
    lo, hi = arc
    if sampling == "parameter" and density_ratio == 1:
        return rng.uniform(0.0, 1.0, n), rng.uniform(lo, hi, n)
    if sampling == "area" and bound is None:
        bound = 1.2 * _area_element(spine, radius, rng.uniform(0, 1, 20000), rng.uniform(lo, hi, 20000),
                                    view).max()
    ts, ss = np.empty(0), np.empty(0)
    while len(ts) < n:
        t = rng.uniform(0.0, 1.0, 2 * n)
        s = rng.uniform(lo, hi, 2 * n)
        keep = np.ones(2 * n, bool)
        if sampling == "area":
            keep &= rng.uniform(0.0, bound, 2 * n) < _area_element(spine, radius, t, s, view)
        if density_ratio != 1:
            keep &= rng.uniform(0.0, 1.0, 2 * n) < density_ratio ** -t
        ts, ss = np.concatenate([ts, t[keep]]), np.concatenate([ss, s[keep]])
    return ts[:n], ss[:n]


def sample_tube(spine: BSpline, radius: BSpline, n: int, noise: float, rng, sampling: str = "area", *,
                noise_model: str = "uniform", arc: float = 360.0,
                density_ratio: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Sample ``n`` points on the canal surface of ``spine`` and ``radius``.

    Each point lies on the characteristic circle of its parameter t (the envelope of the spheres,
    not merely a circle of radius r(t)) and is moved along the true normal by U(-noise, noise), or by
    N(0, noise^2) when ``noise_model="gaussian"``.

    Parameters
    ----------
    sampling : {"area", "parameter"}
        ``"area"``: uniform by surface area, like a scanner's even density (rejection sampling on
        the area element).  ``"parameter"``: uniform in (s, t), as the paper most likely did; the
        density then follows the spine's parameter speed (the ends of Table 2's spine get a third of
        the average density).
    noise_model : {"uniform", "gaussian"}
    arc : float
        Degrees of each cross-section sampled, centred on the side facing :func:`view_direction`
        (360: all around; 180 - 270: a one-sided scan).
    density_ratio : float
        The density falls by this factor from t = 0 to t = 1 (exponentially in t).

    Returns
    -------
    points, normals : ndarray, shape (n, 3)
    """
    choice(sampling, "sampling", ("area", "parameter"))
    choice(noise_model, "noise_model", ("uniform", "gaussian"))
    if not 0 < arc <= 360:
        raise InputError(f"arc must be in (0, 360] degrees, got {arc!r}")
    if not density_ratio >= 1:
        raise InputError(f"density_ratio must be >= 1, got {density_ratio!r}")
    # A full scan draws s from [0, 2 pi), a one-sided one from the arc around the viewing side.
    lo, hi = (0.0, 2 * np.pi) if arc == 360 else (-np.radians(arc) / 2, np.radians(arc) / 2)
    view = None if arc == 360 else view_direction(spine)
    t, s = _surface_parameters(spine, radius, n, rng, sampling, (lo, hi), view, density_ratio)
    points, normal, _, _ = _envelope(spine, radius, t, s, view=view)
    if noise <= 0:
        eps = np.zeros(n)
    elif noise_model == "gaussian":
        eps = rng.normal(0.0, noise, n)
    else:
        eps = rng.uniform(-noise, noise, n)
    return points + eps[:, None] * normal, normal


def _generator(rng) -> np.random.Generator:
    """``rng`` as a generator: None is seed 0, an integer >= 0 a seed, a Generator itself."""
    if rng is None:
        return np.random.default_rng(0)
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng))
    raise InputError(f"rng must be None, a seed (an integer >= 0) or a numpy.random.Generator, got {rng!r}")


def _point_count(n) -> int:
    """``n`` as a number of points: a whole number in [1, MAX_SYNTH_POINTS]."""
    whole = isinstance(n, (int, np.integer)) or (isinstance(n, (float, np.floating)) and float(n).is_integer())
    if isinstance(n, bool) or not whole:
        raise InputError(f"n must be a whole number of points, got {n!r}")
    if n < 1:
        raise InputError(f"n must be a positive number of points, got {n!r}")
    if n > MAX_SYNTH_POINTS:
        raise InputError(f"n = {n!r} points would not fit in memory; at most {MAX_SYNTH_POINTS:,} can be "
                         "generated at once")
    return int(n)


def _number(value, name: str) -> float:
    """``value`` as a finite float."""
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return v


def _diagonal(spine: BSpline, radius: BSpline) -> float:
    """Diagonal of the bounding box of the tube around ``spine`` (its size)."""
    t = np.linspace(0.0, 1.0, 512)
    xyz, r = spine(t), radius(t)
    return float(np.linalg.norm(np.ptp(xyz, axis=0) + 2 * r.max()))


def make_tube(name: str = "fig9-pipe", *, n: int = 2000, noise: float | None = None, rng=None,
              sampling: str = "area", noise_model: str = "uniform", arc: float = 360.0,
              density_ratio: float = 1.0, outliers: float = 0.0) -> SyntheticTube:
    """Sample one of the named test surfaces (see :data:`SURFACES`), optionally as a real scan looks.

    Parameters
    ----------
    name : str
        One of ``SURFACES`` (``fig9-pipe``, ``fig15-pipe``, ``fig14-canal``, ``fig16-canal``, ``helix``,
        ``torus``, ``trefoil``, ``elbow``, ``tight-helix``, ``long-thin``, ``canal-x3``).
    n : int
        Number of points, stray points included (the paper used 2000); at most ``MAX_SYNTH_POINTS``.
    noise : float, optional
        Half-width of the uniform perturbation along the normal (the standard deviation for
        ``noise_model="gaussian"``), in the surface's units; default the surface's own value.  It may
        not exceed the diagonal of the surface's bounding box.
    rng : numpy.random.Generator or int, optional
        Random generator or seed, an integer >= 0 (default seed 0, so the same call gives the same cloud).
    sampling : {"area", "parameter"}
        Uniform by area (default), or uniform in the surface parameters (s, t) as the paper most
        likely sampled (see :func:`sample_tube`).
    noise_model : {"uniform", "gaussian"}
    arc : float
        Degrees of each cross-section seen (360: all around; 180 - 270: a one-sided scan).
    density_ratio : float
        Density falls by this factor from one end of the spine to the other.
    outliers : float
        Share of the ``n`` points that are stray, uniform in the bounding box of the others.

    Raises
    ------
    InputError
        An unknown name or an argument out of its range (checked before anything is allocated).

    Examples
    --------
    >>> tube = make_tube("fig9-pipe", rng=1)
    >>> tube.points.shape, tube.closed
    ((2000, 3), False)
    >>> int(make_tube("elbow", outliers=0.05, rng=1).outlier.sum())
    100
    """
    choice(name, "surface name", tuple(SURFACES))
    n = _point_count(n)
    if not 0 <= outliers < 1:
        raise InputError(f"outliers must be a share in [0, 1), got {outliers!r}")
    spine_f, radius_f, closed, default_noise, _ = SURFACES[name]
    noise = default_noise if noise is None else _number(noise, "noise")
    if noise < 0:
        raise InputError(f"noise must be >= 0, got {noise!r}")
    rng = _generator(rng)
    spine, radius = spine_f(), radius_f()
    size = _diagonal(spine, radius)
    if noise > size:
        raise InputError(f"noise {noise!r} is larger than the surface itself (the diagonal of its bounding box "
                         f"is {size:.3g}); give a noise well below the radius")
    n_stray = int(round(outliers * n))
    points, normals = sample_tube(spine, radius, n - n_stray, noise, rng, sampling,
                                  noise_model=noise_model, arc=float(arc), density_ratio=float(density_ratio))
    outlier = np.zeros(n, bool)
    if n_stray:
        stray = rng.uniform(points.min(axis=0), points.max(axis=0), (n_stray, 3))
        directions = rng.normal(size=(n_stray, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        order = rng.permutation(n)
        points = np.vstack([points, stray])[order]
        normals = np.vstack([normals, directions])[order]
        outlier[order >= len(order) - n_stray] = True
    return SyntheticTube(name, points, normals, spine, radius, closed, noise, noise_model, outlier, float(arc))


# --------------------------------------------------------------------------------------------------
# networks: several tubes joined at junctions, side by side, crossing, with clutter around them

#: A point of one tube counts as inside another only if it lies deeper than this share of that tube's
#: (largest) radius: the circle where the two halves of a split pipe meet is exactly on both surfaces, and rounding
#: (about 1e-15 r) must not remove it.
INSIDE_MARGIN = 1e-6
#: Relative noise of a network must stay below this share of the local radius: beyond it the offsets of
#: opposite sides of a thin tube overlap and the cloud stops looking like a surface.
MAX_NETWORK_NOISE = 0.5
#: Largest share of the points on clutter: at least a tenth stays on the tubes.
MAX_CLUTTER = 0.9
#: Largest ``size`` of the ``plant`` network, so that a mistyped size cannot ask for millions of tubes:
#: 100 bays are 2,300 tubes, which take about ten seconds to set up before any point is drawn.
MAX_PLANT_SIZE = 100
#: Gap between the surfaces of neighbouring pipes of a rack, in radii of the smaller one: real racks leave
#: one to two diameters for flanges and insulation; the middle of that range keeps neighbours close enough
#: to test their separation.
RACK_CLEARANCE = 1.5
#: Gap between the objects of a scene or plant (racks, tees, runs, boxes), in the scene's units: several
#: radii of its largest pipe (2), so that objects are clearly apart.
SCENE_GAP = 6.0
#: A floor reaches this many of the largest radius beyond the footprint of what stands on it.
FLOOR_MARGIN = 3.0
#: Golden-section steps of the inside test: they shrink the bracket (four spine samples, at most a
#: radius) by 0.618^32 = 2e-7, and the depth's error is quadratic in that: below 1e-12 radii.
GOLDEN_STEPS = 32
#: Candidate points drawn per point wanted, before the ones inside other tubes are removed (a first
#: guess; the sampler draws again with a larger share if too many were inside).
OVERSAMPLE = 1.15


@dataclass(frozen=True)
class SyntheticBranch:
    """One tube of a :class:`SyntheticNetwork`: its spine and radius between two ends.

    Attributes
    ----------
    spine : scipy.interpolate.BSpline
        True spine C(t), t in [0, 1], parameterised by normalised arc length; t = 0 and t = 1 are its ends.
    radius : scipy.interpolate.BSpline
        True radius r(t) on the same parameter (:func:`constant_spline` for a pipe).
    ends : tuple
        ``(junction at t = 0, junction at t = 1)``: an index into the network's ``junctions``, or None for
        a free (open) end.
    """

    spine: BSpline
    radius: BSpline
    ends: tuple = (None, None)


@dataclass(frozen=True)
class SyntheticNetwork:
    """A sampled network of tubes with its ground truth.

    Attributes
    ----------
    name : str
    points, normals : ndarray, shape (N, 3)
        Sampled (perturbed) points and the true outward unit normals there (on clutter: the face's normal;
        in a simulated scan turned towards the scanner).
    label : ndarray of int, shape (N,)
        Index into ``branches`` of the branch each point was sampled on; -1 for clutter (floor, boxes; in
        a simulated scan also the ground).
    branches : tuple of SyntheticBranch
    junctions : ndarray, shape (J, 3)
        Junction points; each lies exactly at the spine ends that list it.
    noise : float
        Relative noise: a tube point was moved along its normal by U(-noise r, noise r), r the radius of
        its branch there; a clutter point by the same share of the median radius of the branches.  For a
        simulated scan (``scan`` is set) the standard deviation at range 0 along the ray, in the scene's
        units; ``scan`` gives each point's.
    floor : tuple or None
        The floor the clutter stands on, ``(x0, x1, y0, y1, z)``: a horizontal rectangle; None when the
        cloud has no clutter.
    boxes : tuple
        The boxes standing on the floor, ``(low corner, high corner)`` each.
    scan : ScanInfo, optional
        How a simulated scan (:func:`scan`) was made and where each point was seen from; None for a
        sampled cloud.
    """

    name: str
    points: np.ndarray
    normals: np.ndarray
    label: np.ndarray
    branches: tuple
    junctions: np.ndarray
    noise: float
    floor: tuple | None = None
    boxes: tuple = ()
    scan: "ScanInfo | None" = None

    @property
    def components(self) -> list[list[int]]:
        """Branch indices of each connected network (branches joined through junctions), sorted."""
        parent = list(range(len(self.branches)))

        def root(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        first: dict[int, int] = {}
        for b, branch in enumerate(self.branches):
            for j in branch.ends:
                if j is not None:
                    parent[root(b)] = root(first.setdefault(j, b))
        groups: dict[int, list[int]] = {}
        for b in range(len(self.branches)):
            groups.setdefault(root(b), []).append(b)
        return sorted(groups.values())

    @property
    def clutter(self) -> np.ndarray:
        """True for the points on clutter (``label == -1``)."""
        return self.label == -1


@dataclass(frozen=True)
class _Layout:
    """What a network builder returns: the tubes, their junctions and the clutter around them.

    ``floor`` is ``(x0, x1, y0, y1, z)``, a horizontal rectangle; ``boxes`` are ``(low corner, high corner)``
    of axis-aligned boxes standing on the floor; ``clutter`` is the network's default share of points on
    them.
    """

    branches: tuple
    junctions: np.ndarray
    floor: tuple | None = None
    boxes: tuple = ()
    clutter: float = 0.0


# --- geometry helpers ------------------------------------------------------------------------------------

def _straight(a, b) -> BSpline:
    """The segment from ``a`` to ``b`` as a cubic spine on normalised arc length."""
    return _by_arclength(np.linspace(np.asarray(a, float), np.asarray(b, float), 8))


def _taper(r0: float, r1: float) -> BSpline:
    """A radius falling (or growing) linearly in t from ``r0`` to ``r1``."""
    return BSpline(np.r_[np.zeros(4), np.ones(4)], np.linspace(r0, r1, 4), 3)


def _turning(start, e1, e2, angle0: float, angle1: float, length: float) -> BSpline:
    """A planar spine from ``start`` whose heading turns evenly from ``angle0`` to ``angle1`` (degrees,
    measured from ``e1`` towards ``e2``) over ``length``: an arc of a circle, exactly integrated."""
    start, e1, e2 = (np.asarray(v, float) for v in (start, e1, e2))
    a0, a1 = np.radians(angle0), np.radians(angle1)
    s = np.linspace(0.0, length, 400)[:, None]
    if a1 == a0:
        x, y = s * np.cos(a0), s * np.sin(a0)
    else:
        k = (a1 - a0) / length
        x, y = (np.sin(a0 + k * s) - np.sin(a0)) / k, (np.cos(a0) - np.cos(a0 + k * s)) / k
    return _by_arclength(start + x * e1 + y * e2)


def _moved(spline: BSpline, offset=(0.0, 0.0, 0.0), turn: np.ndarray | None = None) -> BSpline:
    """``spline`` rotated by the matrix ``turn`` about the origin, then moved by ``offset`` (a B-spline's
    control points carry any affine map)."""
    c = spline.c if turn is None else spline.c @ np.asarray(turn).T
    return BSpline(spline.t, c + np.asarray(offset, float), spline.k)


def _tee(start, end, r_main: float, side, side_length: float, r_side: float) -> _Layout:
    """A straight main pipe split at its middle into two branches, and a side pipe from there."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    junction = (start + end) / 2
    side = np.asarray(side, float) / np.linalg.norm(side)
    return _Layout((SyntheticBranch(_straight(start, junction), constant_spline(r_main), (None, 0)),
                    SyntheticBranch(_straight(junction, end), constant_spline(r_main), (0, None)),
                    SyntheticBranch(_straight(junction, junction + side_length * side), constant_spline(r_side),
                                    (0, None))),
                   junction[None])


def _rack(radii, length: float, z: float, clearance: float = RACK_CLEARANCE) -> _Layout:
    """Parallel straight pipes along x (from 0 to ``length``) side by side in y, axes at height ``z``, the
    gap between neighbours ``clearance`` times the smaller radius."""
    y, branches = radii[0], []
    for i, r in enumerate(radii):
        if i:
            y += radii[i - 1] + clearance * min(r, radii[i - 1]) + r
        branches.append(SyntheticBranch(_straight([0.0, y, z], [length, y, z]), constant_spline(r)))
    return _Layout(tuple(branches), np.empty((0, 3)))


def _crossing(length: float, r: float, z: float) -> _Layout:
    """Two straight pipes crossing at right angles in their middles, axes ``2.75 r`` apart (a gap of
    0.75 r between the surfaces)."""
    h = length / 2
    return _Layout((SyntheticBranch(_straight([-h, 0.0, z], [h, 0.0, z]), constant_spline(r)),
                    SyntheticBranch(_straight([0.0, -h, z + 2.75 * r], [0.0, h, z + 2.75 * r]),
                                    constant_spline(r))),
                   np.empty((0, 3)))


def _box(low, size) -> _Layout:
    """A box standing with its low corner at ``low``."""
    low = np.asarray(low, float)
    return _Layout((), np.empty((0, 3)), boxes=((low, low + np.asarray(size, float)),))


def _footprint(layout: _Layout) -> tuple[np.ndarray, np.ndarray]:
    """Low and high corners of the bounding box of a layout's tubes and boxes."""
    t = np.linspace(0.0, 1.0, 256)
    corners = [b.spine(t) + s * b.radius(t)[:, None] for b in layout.branches for s in (-1.0, 1.0)]
    corners += [np.vstack(box) for box in layout.boxes]
    xyz = np.vstack(corners)
    return xyz.min(axis=0), xyz.max(axis=0)


def _placed(layout: _Layout, offset) -> _Layout:
    """``layout`` moved by ``offset``."""
    offset = np.asarray(offset, float)
    return _Layout(tuple(SyntheticBranch(_moved(b.spine, offset), b.radius, b.ends) for b in layout.branches),
                   layout.junctions + offset, None, tuple((lo + offset, hi + offset) for lo, hi in layout.boxes),
                   layout.clutter)


def _merged(layouts) -> _Layout:
    """Several layouts as one (their junction indices renumbered)."""
    branches, junctions, boxes = [], [], []
    for layout in layouts:
        shift = sum(len(j) for j in junctions)
        branches += [SyntheticBranch(b.spine, b.radius, tuple(None if j is None else j + shift for j in b.ends))
                     for b in layout.branches]
        junctions.append(layout.junctions)
        boxes += layout.boxes
    return _Layout(tuple(branches), np.vstack(junctions) if junctions else np.empty((0, 3)), None, tuple(boxes))


def _row(layouts, gap: float = SCENE_GAP, y: float = 0.0) -> _Layout:
    """Layouts placed one after another along x, ``gap`` apart, their low y edges at ``y``."""
    placed, x = [], 0.0
    for layout in layouts:
        lo, hi = _footprint(layout)
        placed.append(_placed(layout, [x - lo[0], y - lo[1], 0.0]))
        x += hi[0] - lo[0] + gap
    return _merged(placed)


def _on_floor(layout: _Layout, clutter: float, z: float | None = None) -> _Layout:
    """``layout`` on a floor that reaches ``FLOOR_MARGIN`` largest radii beyond it; by default one
    largest radius below its lowest point."""
    lo, hi = _footprint(layout)
    r_max = max((float(b.radius(np.linspace(0, 1, 64)).max()) for b in layout.branches), default=1.0)
    m = FLOOR_MARGIN * r_max
    z = lo[2] - r_max if z is None else z
    return _Layout(layout.branches, layout.junctions, (lo[0] - m, hi[0] + m, lo[1] - m, hi[1] + m, z),
                   layout.boxes, clutter)


# --- the networks ----------------------------------------------------------------------------------------

def _y_vessel() -> _Layout:
    x, y, z = np.eye(3)
    # The parent arrives along +x at the junction (the origin), sagging gently (its heading turns 8 degrees).
    parent = _turning([0.0, 0.0, 0.0], x, z, -8.0, 0.0, 8.0)
    parent = _moved(parent, -parent.c[-1])  # make_interp_spline's last control point is its end
    daughters = (_turning([0, 0, 0], x, y, 25.0, 10.0, 7.0), _turning([0, 0, 0], x, y, -50.0, -30.0, 7.0))
    return _Layout((SyntheticBranch(parent, _taper(1.0, 0.85), (None, 0)),
                    SyntheticBranch(daughters[0], _taper(0.75, 0.55), (0, None)),
                    SyntheticBranch(daughters[1], _taper(0.65, 0.5), (0, None))),
                   np.zeros((1, 3)))


def _t_junction() -> _Layout:
    return _tee([-8.0, 0.0, 0.0], [8.0, 0.0, 0.0], 1.0, [0.0, 1.0, 0.0], 7.0, 0.6)


#: The tree's stem: height, sideways sag, radius at its foot and top, heights of the side branches.
_STEM = (20.0, 0.8, 1.0, 0.6, (5.0, 10.0, 15.0))
#: The tree's side branches: (angle from the stem at the junction, angle at the tip, azimuth, length,
#: radius at the junction, at the tip); each turns gently upwards.
_SIDES = ((55.0, 45.0, 0.0, 8.0, 0.5, 0.35), (45.0, 35.0, 130.0, 7.0, 0.45, 0.3),
          (50.0, 40.0, 250.0, 6.0, 0.4, 0.28))


def _tree() -> _Layout:
    height, sag, r_foot, r_top, heights = _STEM

    def stem(z):  # a gentle bow in x
        return np.column_stack([sag * np.sin(np.pi * z / height), np.zeros_like(z), z])

    def tangent(z):
        d = np.array([sag * np.pi / height * np.cos(np.pi * z / height), 0.0, 1.0])
        return d / np.linalg.norm(d)

    dense = stem(np.linspace(0.0, height, 20001))
    arc = polyline_arclength(dense)
    cuts = [0.0, *heights, height]
    s_cut = np.interp(cuts, np.linspace(0.0, height, 20001), arc)
    r_cut = r_foot + (r_top - r_foot) * s_cut / arc[-1]  # radius linear in arc length along the whole stem
    branches = []
    for i in range(len(cuts) - 1):
        ends = (i - 1 if i else None, i if i < len(heights) else None)
        branches.append(SyntheticBranch(_by_arclength(stem(np.linspace(cuts[i], cuts[i + 1], 300))),
                                        _taper(r_cut[i], r_cut[i + 1]), ends))
    junctions = stem(np.asarray(heights, float))
    for j, (a0, a1, azimuth, length, r0, r1) in enumerate(_SIDES):
        up = tangent(heights[j])
        out = np.array([np.cos(np.radians(azimuth)), np.sin(np.radians(azimuth)), 0.0])
        out -= (out @ up) * up
        branches.append(SyntheticBranch(_turning(junctions[j], up, out / np.linalg.norm(out), a0, a1, length),
                                        _taper(r0, r1), (j, None)))
    return _Layout(tuple(branches), junctions)


def _rack_of_four() -> _Layout:
    return _rack((1.0, 1.5, 0.8, 2.0), 20.0, 0.0)


def _bundle(radii=(1.0, 1.0), gap: float = 0.0) -> _Layout:
    radii = tuple(_number(r, "a bundle's radius") for r in np.atleast_1d(np.asarray(radii, dtype=object)))
    if not 1 <= len(radii) <= 8 or min(radii) <= 0:
        raise InputError(f"a bundle takes 1 to 8 positive radii, got {radii!r}")
    if not 0 <= _number(gap, "gap") <= 10:
        raise InputError(f"a bundle's gap is a share of the smaller radius in [0, 10], got {gap!r}")
    return _rack(radii, 10.0, 0.0, clearance=float(gap))


def _crossing_pair() -> _Layout:
    return _crossing(16.0, 1.0, 0.0)


def _floor_clutter() -> _Layout:
    # A pipe of radius 1 bowing 1.5 sideways, its bottom one radius above the floor z = 0; a 3 x 3 x 3
    # box beside the middle of the bow, 2 radii from the pipe's surface.
    x = np.linspace(-8.0, 8.0, 400)
    pipe = _by_arclength(np.column_stack([x, 1.5 * np.cos(np.pi * x / 16.0), np.full_like(x, 2.0)]))
    layout = _Layout((SyntheticBranch(pipe, constant_spline(1.0)),), np.empty((0, 3)),
                     boxes=((np.array([-1.5, 1.5 + 1.0 + 2.0, 0.0]), np.array([1.5, 7.5, 3.0])),))
    return _on_floor(layout, 0.3, z=0.0)


def _scene() -> _Layout:
    tee = _tee([0.0, 0.0, 2.0], [16.0, 0.0, 2.0], 1.0, [0.0, 1.0, 0.0], 7.0, 0.6)
    rack = _rack((1.0, 0.6, 1.2), 16.0, 2.2)
    pair = _crossing(16.0, 1.0, 2.0)
    return _on_floor(_row([tee, rack, pair, _box([0.0, 0.0, 0.0], [3.0, 3.0, 3.0])]), 0.2, z=0.0)


#: One bay of the plant: racks (radii, length, along y?), elbow runs (radius, leg, rising?) and tees
#: (main radius, main length, side radius, side length, side upwards?).  Bay ``i`` rolls each rack's
#: radii by ``i``, so no two neighbouring bays are alike.
_PLANT_RACKS = (((0.5, 1.2, 2.0, 0.8), 20.0, False), ((0.6, 0.9, 1.5, 0.5, 1.1, 1.8), 24.0, False),
                ((1.0, 0.7, 1.3, 0.5, 1.6), 20.0, True))
_PLANT_ELBOWS = ((1.0, 8.0, False), (0.7, 6.0, True))
_PLANT_TEES = ((1.2, 14.0, 0.7, 5.0, True), (0.8, 12.0, 0.5, 5.0, False))
#: Height of the lowest pipe bottoms above the plant's floor.
_PLANT_CLEARANCE = 1.5


def _plant_bay(i: int) -> _Layout:
    parts = []
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # x -> y
    for radii, length, along_y in _PLANT_RACKS:
        radii = tuple(np.roll(radii, i))
        rack = _rack(radii, length, _PLANT_CLEARANCE + max(radii))
        if along_y:
            rack = _Layout(tuple(SyntheticBranch(_moved(b.spine, turn=quarter), b.radius) for b in rack.branches),
                           rack.junctions)
        parts.append(rack)
    for r, leg, rising in _PLANT_ELBOWS:
        spine = _elbow_spine(leg=leg, bend=2 * r)  # in the plane z = 0, from (0, -leg) to (2 r + leg, 2 r)
        if rising:  # turn it into the plane y = 0: the run comes along the floor and rises
            spine = _moved(spine, turn=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
            spine = _moved(spine, [0.0, 0.0, _PLANT_CLEARANCE + r])
        else:
            spine = _moved(spine, [0.0, 0.0, _PLANT_CLEARANCE + r])
        parts.append(_Layout((SyntheticBranch(spine, constant_spline(r)),), np.empty((0, 3))))
    for r, length, r_side, side_length, upwards in _PLANT_TEES:
        z = _PLANT_CLEARANCE + r
        parts.append(_tee([0.0, 0.0, z], [length, 0.0, z], r, [0.0, 0.0, 1.0] if upwards else [0.0, 1.0, 0.0],
                          side_length, r_side))
    parts.append(_box([0.0, 0.0, 0.0], [4.0, 3.0, 2.5]))
    return _row(parts)


def _plant(size: int = 1) -> _Layout:
    """``size`` bays of 23 tubes each, in a grid of about ``sqrt(size)`` columns."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 1 <= size <= MAX_PLANT_SIZE:
        raise InputError(f"size must be a whole number of bays in [1, {MAX_PLANT_SIZE}], got {size!r}")
    bays = [_plant_bay(i) for i in range(int(size))]
    extents = [np.subtract(*_footprint(bay)[::-1]) for bay in bays]
    width = max(e[0] for e in extents) + SCENE_GAP
    depth = max(e[1] for e in extents) + SCENE_GAP
    columns = int(np.ceil(np.sqrt(size)))
    placed = [_placed(bay, [width * (i % columns), depth * (i // columns), 0.0]) for i, bay in enumerate(bays)]
    return _on_floor(_merged(placed), 0.2, z=0.0)


# --- piping: a plant's runs in millimetres, with the pieces a piping designer would draw ----------------

#: Outside diameters (mm) of the piping network's two sizes, from ASME B36.10M (NPS 4 = DN 100 and
#: NPS 2 = DN 50; EN 10220 series 1 has the same two).
_NPS4_OD, _NPS2_OD = 114.3, 60.3
#: Bend radii of butt-welding elbows (ASME B16.9): long radius = 1.5 x the nominal size, 3R = 3 x it
#: (NPS 4: 152.4 and 304.8 mm; NPS 2: 76.2 mm).
_LR_NPS4, _3R_NPS4, _LR_NPS2 = 1.5 * 4 * 25.4, 3 * 4 * 25.4, 1.5 * 2 * 25.4
#: Length of a concentric reducer NPS 4 x 2 (ASME B16.9, dimension H), from where its cone meets one
#: size to where it meets the other; its knuckles round the corners over this many millimetres either side.
_REDUCER_4X2, _REDUCER_KNUCKLE = 102.0, 5.0
#: Centreline samples per millimetre of the piping runs: 2 mm apart, a 38th of the smallest bend radius.
_PIPING_SAMPLES_PER_MM = 0.5
#: Nominal sizes of the piping network's outside diameters: ASME NPS and the EN DN of the same OD.
_PIPING_SIZES = {_NPS4_OD: ("NPS 4", "DN 100"), _NPS2_OD: ("NPS 2", "DN 50")}


@dataclass(frozen=True, eq=False)
class SyntheticPiece:
    """One piece of the ``piping`` network's truth, as :func:`canalsurf.piping.decompose` describes a piece.

    Attributes
    ----------
    type : {"straight", "elbow", "tee", "reducer"}
    branch : int
        Index into the network's ``branches`` (a tee: the branch of its run that ends at it).
    start, end : ndarray, shape (3,)
        Centreline ends, in millimetres (a tee: both are the junction point).
    length : float
        Along the centreline (a tee: 0).
    outside_diameter, end_diameter : float
        At the start and the end (they differ on a reducer only).
    bend_radius, angle : float or None
        An elbow's centreline bend radius and its angle in degrees.
    centre : ndarray or None
        An elbow's centre of bend; a tee's junction point.
    nps, dn : str
        Nominal size (at the start) by ASME B36.10M and by EN 10220.
    """

    type: str
    branch: int
    start: np.ndarray
    end: np.ndarray
    length: float
    outside_diameter: float
    end_diameter: float
    bend_radius: float | None = None
    angle: float | None = None
    centre: np.ndarray | None = None
    nps: str = ""
    dn: str = ""


def _pipe_run(start, heading, pieces, branch: int, diameter: float):
    """Dense centreline samples of straights and circular bends, and each piece's truth.

    ``pieces`` are ``("straight", length)`` or ``("elbow", bend radius, angle in degrees, towards)``: the
    heading turns towards the part of ``towards`` normal to it.
    """
    p = np.asarray(start, float)
    d = np.asarray(heading, float) / np.linalg.norm(heading)
    xyz, truth = [p[None]], []
    nps, dn = _PIPING_SIZES[diameter]
    for kind, *spec in pieces:
        if kind == "straight":
            (length,) = spec
            u = np.linspace(0.0, length, int(np.ceil(length * _PIPING_SAMPLES_PER_MM)) + 1)[1:, None]
            q, centre, bend, angle = p + length * d, None, None, None
            xyz.append(p + u * d)
            new_d = d
        else:
            bend, angle, towards = spec
            towards = np.asarray(towards, float)
            n = towards - (towards @ d) * d
            n /= np.linalg.norm(n)
            centre = p + bend * n
            length = bend * np.radians(angle)
            a = np.linspace(0.0, np.radians(angle), int(np.ceil(length * _PIPING_SAMPLES_PER_MM)) + 1)[1:, None]
            xyz.append(centre + bend * (-np.cos(a) * n + np.sin(a) * d))
            q = xyz[-1][-1]
            new_d = np.cos(np.radians(angle)) * d + np.sin(np.radians(angle)) * n
        truth.append(SyntheticPiece(kind, branch, p, q, float(length), diameter, diameter, bend, angle, centre,
                                    nps, dn))
        p, d = q, new_d
    return _by_arclength(np.vstack(xyz)), truth


def _piping_parts():
    """The piping network's branches, junctions and true pieces (one builder for both)."""
    x, y, z = np.eye(3)
    r4, r2 = _NPS4_OD / 2, _NPS2_OD / 2
    branches, pieces = [], []
    # Branch 0, NPS 4: 1 m along x, a long-radius elbow to y, 0.6 m, a 3R 45-degree elbow rising, 0.5 m.
    spine, truth = _pipe_run([0.0, 0.0, 0.0], x, [("straight", 1000.0), ("elbow", _LR_NPS4, 90.0, y),
                                                  ("straight", 600.0), ("elbow", _3R_NPS4, 45.0, z),
                                                  ("straight", 500.0)], 0, _NPS4_OD)
    branches.append(SyntheticBranch(spine, constant_spline(r4)))
    pieces += truth
    # Branch 1, NPS 2: 0.8 m along y, a long-radius elbow to x, 0.6 m.
    spine, truth = _pipe_run([1700.0, 0.0, 0.0], y, [("straight", 800.0), ("elbow", _LR_NPS2, 90.0, x),
                                                     ("straight", 600.0)], 1, _NPS2_OD)
    branches.append(SyntheticBranch(spine, constant_spline(r2)))
    pieces += truth
    # Branches 2 - 4: a reducing tee, NPS 4 run of 1.2 m along y split at its middle, NPS 2 outlet along x
    # reaching 0.5 m from the run's axis.
    junction = np.array([2800.0, 600.0, 0.0])
    for b, (start, heading, length, diameter) in enumerate(((junction - 600.0 * y, y, 600.0, _NPS4_OD),
                                                             (junction, y, 600.0, _NPS4_OD),
                                                             (junction, x, 500.0, _NPS2_OD)), start=2):
        spine, truth = _pipe_run(start, heading, [("straight", length)], b, diameter)
        branches.append(SyntheticBranch(spine, constant_spline(diameter / 2), (None, 0) if b == 2 else (0, None)))
        pieces += truth
    nps, dn = _PIPING_SIZES[_NPS4_OD]
    pieces.append(SyntheticPiece("tee", 2, junction, junction, 0.0, _NPS4_OD, _NPS4_OD, centre=junction,
                                 nps=nps, dn=dn))
    # Branch 5: NPS 4 for 0.5 m, a concentric reducer to NPS 2, NPS 2 for 0.5 m, along y: one canal whose
    # radius is constant, linear over the reducer, constant.
    lengths = (500.0, _REDUCER_4X2, 500.0)
    spine, _ = _pipe_run([3800.0, 0.0, 0.0], y, [("straight", sum(lengths))], 5, _NPS4_OD)
    # The radius: a line between the two sizes, its corners rounded over _REDUCER_KNUCKLE either side (a
    # quadratic B-spline whose coefficients are the broken line at its Greville points), so that the
    # surface's normal turns smoothly there as a pressed reducer's knuckles do.  The surface, the envelope
    # of the spheres, is a cone steeper than that line and ahead of it: the line is placed so that the
    # cone meets the two sizes where the reducer's ends are.
    from .piping import surface_ramp

    ends = np.array([lengths[0], lengths[0] + lengths[1]])
    ramp = ends.copy()
    for _ in range(100):
        ramp += ends - surface_ramp(r4, r2, *ramp)
    a, b = ramp / sum(lengths)
    k = _REDUCER_KNUCKLE / sum(lengths)
    knots = np.array([0.0, 0.0, 0.0, a - k, a + k, b - k, b + k, 1.0, 1.0, 1.0])
    branches.append(SyntheticBranch(spine, BSpline(knots, np.array([r4, r4, r4, (r4 + r2) / 2, r2, r2, r2]), 2)))
    s, start = 0.0, np.array([3800.0, 0.0, 0.0])
    for kind, length, d0, d1 in (("straight", lengths[0], _NPS4_OD, _NPS4_OD),
                                 ("reducer", lengths[1], _NPS4_OD, _NPS2_OD),
                                 ("straight", lengths[2], _NPS2_OD, _NPS2_OD)):
        nps, dn = _PIPING_SIZES[d0]
        pieces.append(SyntheticPiece(kind, 5, start + s * y, start + (s + length) * y, length, d0, d1,
                                     nps=nps, dn=dn))
        s += length
    return _Layout(tuple(branches), junction[None]), tuple(pieces)


def _piping() -> _Layout:
    return _piping_parts()[0]


def piping_truth() -> tuple:
    """The true pieces of the ``piping`` network (see :data:`NETWORKS`), in millimetres.

    Returns
    -------
    tuple of SyntheticPiece
        Along each branch in order: branch 0 straight, elbow (long radius, 90 degrees), straight, elbow
        (3R, 45 degrees), straight; branch 1 straight, elbow, straight; branches 2 - 4 one straight each
        and the tee at junction 0; branch 5 straight, reducer, straight.

    Examples
    --------
    >>> [p.type for p in piping_truth()][:5]
    ['straight', 'elbow', 'straight', 'elbow', 'straight']
    >>> round(piping_truth()[1].bend_radius, 1), piping_truth()[1].nps
    (152.4, 'NPS 4')
    """
    return _piping_parts()[1]


#: name -> (builder, description).  ``builder(**options)`` returns the network's geometry (branches,
#: junctions, clutter and its default share of points); only ``plant`` takes an option (``size``).
NETWORKS = {
    "y-vessel": (_y_vessel, "a tapering canal (radius 1 to 0.85, length 8) forking into two tapering, gently "
                            "curving canals (0.75 to 0.55 and 0.65 to 0.5, length 7) at 25 and 50 degrees: "
                            "3 branches, 1 junction"),
    "t-junction": (_t_junction, "a straight pipe of radius 1 and length 16 with a perpendicular pipe of "
                                "radius 0.6 from its middle, reaching 7 beyond its axis: 3 branches, 1 junction"),
    "tree": (_tree, "a tapering, slightly bowed stem (radius 1 to 0.6, height 20) with tapering side branches "
                    "(radii 0.5, 0.45, 0.4) at heights 5, 10, 15, 45-55 degrees from it: 7 branches, "
                    "3 junctions"),
    "rack": (_rack_of_four, "4 parallel straight pipes (radii 1, 1.5, 0.8, 2; length 20) side by side, "
                            "1.5 smaller radii apart"),
    "bundle": (_bundle, "straight pipes of length 10 side by side and touching (options radii, default "
                        "(1, 1), and gap, the share of the smaller radius between neighbours' surfaces, "
                        "default 0): hoses or cables strapped together"),
    "crossing": (_crossing_pair, "two straight pipes of radius 1 and length 16 crossing at right angles, "
                                 "axes 2.75 apart (0.75 r between the surfaces)"),
    "floor-clutter": (_floor_clutter, "a gently curving pipe of radius 1 one radius above a floor, beside a "
                                      "3 x 3 x 3 box; 30 % of the points on floor and box"),
    "scene": (_scene, "a T junction, a rack of 3 pipes and a crossing pair, apart from each other, with a "
                      "box on a floor (20 % of the points): 8 branches, 1 junction"),
    "plant": (_plant, "a plant for benchmarks: per bay (option size, default 1) 3 racks of 4-6 pipes "
                      "(radii 0.5-2), 2 runs with a 90-degree elbow, 2 tees and a box, on a floor (20 % "
                      "of the points): 23 tubes per bay"),
    "piping": (_piping, "plant piping in millimetres (NPS 4 = 114.3 and NPS 2 = 60.3 mm OD): a run with a "
                        "long-radius 90-degree and a 3R 45-degree elbow, an NPS 2 run with an elbow, a "
                        "reducing tee and a 4 x 2 reducer; true pieces by piping_truth(): 6 branches, "
                        "1 junction"),
}


# --- sampling ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class _Tube:
    """A branch prepared for the inside test: dense spine samples, their KD-tree, its bounding box."""

    spine: BSpline
    radius: BSpline
    length: float
    step: float          # arc length between samples
    tree: cKDTree
    r_max: float
    slope: float         # largest |dr/ds|
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(cls, branch: SyntheticBranch) -> "_Tube":
        fine = np.linspace(0.0, 1.0, 2049)
        xyz, r = branch.spine(fine), branch.radius(fine)
        length = float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum())
        # Samples a quarter of the smallest radius apart: every point of the tube is within r + step / 2
        # of one of them.
        m = int(max(64, np.ceil(length / (0.25 * r.min())))) + 1
        t = np.linspace(0.0, 1.0, m)
        centres, radii = branch.spine(t), branch.radius(t)
        step = length / (m - 1)
        slope = float(np.abs(np.diff(r)).max() / (length / (len(fine) - 1)))
        return cls(branch.spine, branch.radius, length, step, cKDTree(centres), float(radii.max()), slope,
                   (centres - radii[:, None]).min(axis=0) - step, (centres + radii[:, None]).max(axis=0) + step)

    def depth(self, points: np.ndarray) -> np.ndarray:
        """``min_t |P - C(t)| - r(t)`` (negative inside the tube) where it is below ``step``; +inf elsewhere.

        The nearest spine sample brackets the minimum; a golden-section search narrows the bracket
        ``GOLDEN_STEPS`` times.
        """
        out = np.full(len(points), np.inf)
        d, i = self.tree.query(points, distance_upper_bound=self.r_max + self.step)
        near = np.flatnonzero(np.isfinite(d))
        if not len(near):
            return out
        p = points[near]
        n_samples = self.tree.n
        half = (2 * self.step + 2 * self.slope * (self.r_max + self.step)) / self.length
        t0 = i[near] / (n_samples - 1)
        a, b = np.clip(t0 - half, 0.0, 1.0), np.clip(t0 + half, 0.0, 1.0)

        def g(t):
            return np.linalg.norm(p - self.spine(t), axis=1) - self.radius(t)

        ratio = (np.sqrt(5.0) - 1) / 2
        c, e = b - ratio * (b - a), a + ratio * (b - a)
        fc, fe = g(c), g(e)
        for _ in range(GOLDEN_STEPS):
            left = fc < fe  # the minimum is in [a, e]
            b = np.where(left, e, b)
            a = np.where(left, a, c)
            new = np.where(left, b - ratio * (b - a), a + ratio * (b - a))
            fn = g(new)
            c, e, fc, fe = (np.where(left, new, e), np.where(left, c, new),
                            np.where(left, fn, fe), np.where(left, fc, fn))
        best = np.minimum(np.minimum(fc, fe), np.minimum(g(a), g(b)))
        out[near] = best
        return out


def _inside_other(points: np.ndarray, label: np.ndarray, tubes) -> np.ndarray:
    """True for each point inside a tube other than its own (deeper than INSIDE_MARGIN of its radius)."""
    return _container(points, label, tubes) >= 0


def _container(points: np.ndarray, label: np.ndarray, tubes) -> np.ndarray:
    """For each point the index of a tube other than its own that holds it (deeper than INSIDE_MARGIN of
    its radius), -1 where none does."""
    inside = np.full(len(points), -1, dtype=np.int64)
    if not len(points):
        return inside
    # Bin the points on a coarse grid in (x, y) so that each tube looks only at the points near it.
    cell = 4 * max(t.r_max for t in tubes)
    origin = points[:, :2].min(axis=0)
    ij = np.floor((points[:, :2] - origin) / cell).astype(np.int64)
    nx = int(ij[:, 0].max()) + 1
    key = ij[:, 1] * nx + ij[:, 0]
    order = np.argsort(key, kind="stable")
    keys = key[order]
    for b, tube in enumerate(tubes):
        i0, j0 = np.floor((tube.low[:2] - origin) / cell).astype(np.int64)
        i1, j1 = np.floor((tube.high[:2] - origin) / cell).astype(np.int64)
        i0, i1 = max(i0, 0), min(i1, nx - 1)
        if i1 < i0:
            continue
        rows = np.arange(max(j0, 0), j1 + 1)
        starts = np.searchsorted(keys, rows * nx + i0, side="left")
        stops = np.searchsorted(keys, rows * nx + i1, side="right")
        idx = np.concatenate([order[s:e] for s, e in zip(starts, stops)] or [np.empty(0, np.int64)])
        idx = idx[(label[idx] != b)
                  & np.all((points[idx] >= tube.low) & (points[idx] <= tube.high), axis=1)]
        if not len(idx):
            continue
        depth = tube.depth(points[idx])
        inside[idx[depth < -INSIDE_MARGIN * tube.r_max]] = b
    return inside


@dataclass(frozen=True)
class _Patch:
    """A piece of surface to sample: ``draw(m, rng) -> (points, normals, t)``, its area and label."""

    draw: object
    area: float
    label: int


def _lateral(index: int, branch: SyntheticBranch) -> _Patch:
    """The canal surface of a branch (its envelope of spheres, without the ends)."""
    spine, radius = branch.spine, branch.radius
    # Area and bound of the area element from a 128 x 16 grid in (t, s): the element changes over a
    # radius or more along the spine and like cos s around it (which 16 angles integrate exactly); the
    # bound's margin of 1.2, as in sample_tube, covers a maximum between grid points.
    t = (np.arange(128) + 0.5) / 128
    s = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
    tt, ss = np.repeat(t, len(s)), np.tile(s, len(t))
    element = _area_element(spine, radius, tt, ss)
    bound = 1.2 * element.max()

    def draw(m, rng):
        t, s = _surface_parameters(spine, radius, m, rng, bound=bound)
        points, normals, _, _ = _envelope(spine, radius, t, s)
        return points, normals, t

    return _Patch(draw, float(element.mean() * 2 * np.pi), index)


def _cap(index: int, branch: SyntheticBranch, end: int) -> _Patch:
    """The part of the sphere at an end of a branch that bounds the tube (beyond the last characteristic
    circle): it closes the tube where it meets others at a junction."""
    centre, r = branch.spine(float(end)), float(branch.radius(float(end)))
    velocity = branch.spine.derivative()(float(end))
    tangent = velocity / np.linalg.norm(velocity)
    rho = float(branch.radius.derivative()(float(end))) / np.linalg.norm(velocity)
    sign = 1.0 if end else -1.0  # the cap is u.T >= -rho at t = 1, u.T <= -rho at t = 0

    def draw(m, rng):
        found = [np.empty((0, 3))]
        while sum(len(f) for f in found) < m:
            u = rng.normal(size=(2 * m + 8, 3))
            u /= np.linalg.norm(u, axis=1, keepdims=True)
            found.append(u[sign * (u @ tangent + rho) >= 0])
        u = np.vstack(found)[:m]
        return centre + r * u, u, np.full(m, float(end))

    return _Patch(draw, float(2 * np.pi * r * r * (1 + sign * rho)), index)


def _faces(floor, boxes) -> list[_Patch]:
    """Clutter: the floor (without the boxes' footprints) and the top and sides of each box."""
    patches = []

    def rectangle(corner, e1, e2, normal, holes=()):
        corner, e1, e2, normal = (np.asarray(v, float) for v in (corner, e1, e2, normal))

        def draw(m, rng):
            found = [np.empty((0, 3))]
            while sum(len(f) for f in found) < m:
                uv = rng.uniform(0.0, 1.0, (2 * m + 8, 2))
                p = corner + uv[:, :1] * e1 + uv[:, 1:] * e2
                out = np.ones(len(p), bool)
                for lo, hi in holes:
                    out &= ~np.all((p[:, :2] > lo[:2]) & (p[:, :2] < hi[:2]), axis=1)
                found.append(p[out])
            return np.vstack(found)[:m], np.tile(normal, (m, 1)), np.full(m, np.nan)

        area = np.linalg.norm(np.cross(e1, e2)) - sum(np.prod(hi[:2] - lo[:2]) for lo, hi in holes)
        patches.append(_Patch(draw, float(area), -1))

    if floor is not None:
        x0, x1, y0, y1, z = floor
        rectangle([x0, y0, z], [x1 - x0, 0, 0], [0, y1 - y0, 0], [0, 0, 1],
                  holes=[box for box in boxes if abs(box[0][2] - z) < 1e-9])
    for lo, hi in boxes:
        dx, dy, dz = hi - lo
        rectangle([lo[0], lo[1], hi[2]], [dx, 0, 0], [0, dy, 0], [0, 0, 1])
        rectangle(lo, [0, dy, 0], [0, 0, dz], [-1, 0, 0])
        rectangle([hi[0], lo[1], lo[2]], [0, dy, 0], [0, 0, dz], [1, 0, 0])
        rectangle(lo, [dx, 0, 0], [0, 0, dz], [0, -1, 0])
        rectangle([lo[0], hi[1], lo[2]], [dx, 0, 0], [0, 0, dz], [0, 1, 0])
    return patches


def _sample_union(patches, n: int, rng, tubes):
    """``n`` points uniform by area on the parts of ``patches`` outside every tube but their own.

    Returns points, normals, labels and parameters t.
    """
    if n == 0 or not patches:
        return np.empty((0, 3)), np.empty((0, 3)), np.empty(0, np.int64), np.empty(0)
    area = np.array([p.area for p in patches])
    m = int(np.ceil(OVERSAMPLE * n))
    for _ in range(20):
        counts = rng.multinomial(m, area / area.sum())
        drawn = [p.draw(int(c), rng) for p, c in zip(patches, counts)]
        points = np.vstack([d[0] for d in drawn])
        normals = np.vstack([d[1] for d in drawn])
        t = np.concatenate([d[2] for d in drawn])
        label = np.repeat(np.array([p.label for p in patches], dtype=np.int64), counts)
        keep = np.flatnonzero(~_inside_other(points, label, tubes))
        if len(keep) >= n:
            pick = np.sort(rng.choice(keep, n, replace=False))
            return points[pick], normals[pick], label[pick], t[pick]
        m = int(np.ceil(OVERSAMPLE * m * n / max(len(keep), 1)))
    raise RuntimeError("the network's surfaces lie inside each other: no points could be kept")


def _build(name: str, options: dict) -> _Layout:
    """The layout of the network ``name`` built with ``options`` (checked against its builder's)."""
    builder = NETWORKS[name][0]
    accepted = set(inspect.signature(builder).parameters)
    for key in options:
        if key not in accepted:
            takes = f"it takes {', '.join(sorted(accepted))}" if accepted else "it takes none"
            raise InputError(f"the {name!r} network has no option {key!r}; {takes}")
    return builder(**options)


def make_network(name: str = "t-junction", *, n: int = 30_000, noise: float = 0.02, rng=None,
                 clutter: float | None = None, **options) -> SyntheticNetwork:
    """Sample one of the named tube networks (see :data:`NETWORKS`) with its ground truth.

    The cloud covers the surface of the union of the tubes: each branch's canal surface is sampled
    uniformly by area, and every point inside another branch's tube (closer to its spine than its radius
    there, the spine's ends included as balls) is removed, so a side branch shows only where it leaves its
    parent and crossing tubes show only their outsides.  A branch end at a junction is closed by the ball
    there (the part not inside the other branches: the crotch of a fork).  Free ends are open, like a cut
    pipe.  The density is the same on every tube; the clutter (floor, boxes) gets its own share of the
    points.  Noise is relative: each point moves along its true normal by U(-noise r, noise r), r the
    local radius (on clutter: the median radius of the branches).  Removal is decided before the noise,
    so a noise-free cloud has no point inside any tube, and a noisy one none deeper than its own noise.

    Parameters
    ----------
    name : str
        One of ``NETWORKS``: ``y-vessel``, ``t-junction``, ``tree``, ``rack``, ``bundle``, ``crossing``,
        ``floor-clutter``, ``scene``, ``plant``, ``piping``.
    n : int
        Number of points, clutter included (at most ``MAX_SYNTH_POINTS``).
    noise : float
        Half-width of the offset along the normal as a share of the local radius, in [0, 0.5).
    rng : numpy.random.Generator or int, optional
        Random generator or seed (default seed 0: the same call gives the same cloud).
    clutter : float, optional
        Share of the points on clutter, in [0, 0.9]; default the network's own (0.3 for
        ``floor-clutter``, 0.2 for ``scene`` and ``plant``, 0 for the others).  A network without clutter
        objects gets a floor one largest radius below its lowest point when ``clutter > 0``.
    **options
        Options of the network's builder: ``plant`` takes ``size`` (int, default 1, at most
        ``MAX_PLANT_SIZE``), the number of bays of 23 tubes; ``bundle`` takes ``radii`` (1 to 8 radii,
        default ``(1.0, 1.0)``) and ``gap`` (the gap between neighbours' surfaces in smaller radii, in
        [0, 10], default 0: they touch).

    Returns
    -------
    SyntheticNetwork
        Points in random order, with labels, normals and the branches and junctions.

    Raises
    ------
    InputError
        An unknown name or option, or an argument out of its range.

    Examples
    --------
    >>> net = make_network("t-junction", n=3000, rng=1)
    >>> net.points.shape, len(net.branches), len(net.junctions), net.components
    ((3000, 3), 3, 1, [[0, 1, 2]])
    >>> int(make_network("floor-clutter", n=1000, rng=1).clutter.sum())
    300
    """
    choice(name, "network name", tuple(NETWORKS))
    n = _point_count(n)
    noise = _number(noise, "noise")
    if not 0 <= noise < MAX_NETWORK_NOISE:
        raise InputError(f"noise must be a share of the radius in [0, {MAX_NETWORK_NOISE}), got {noise!r}")
    if clutter is not None:
        share = _number(clutter, "clutter")
        if not 0 <= share <= MAX_CLUTTER:
            raise InputError(f"clutter must be a share of the points in [0, {MAX_CLUTTER}], got {clutter!r}")
    rng = _generator(rng)
    layout = _build(name, options)
    share = layout.clutter if clutter is None else share
    if share > 0 and layout.floor is None and not layout.boxes:
        layout = _on_floor(layout, share)
    tubes = [_Tube.of(b) for b in layout.branches]
    patches = [_lateral(i, b) for i, b in enumerate(layout.branches)]
    patches += [_cap(i, b, end) for i, b in enumerate(layout.branches) for end in (0, 1) if b.ends[end] is not None]
    n_clutter = int(round(share * n))
    tube_part = _sample_union(patches, n - n_clutter, rng, tubes)
    clutter_part = _sample_union(_faces(layout.floor, layout.boxes), n_clutter, rng, tubes)
    points, normals, label, t = (np.concatenate(pair) for pair in zip(tube_part, clutter_part))
    scale = np.full(n, np.median([float(np.mean(b.radius(np.linspace(0, 1, 64)))) for b in layout.branches]))
    for b, branch in enumerate(layout.branches):
        mine = label == b
        scale[mine] = branch.radius(t[mine])
    points = points + (rng.uniform(-1.0, 1.0, n) * noise * scale)[:, None] * normals
    order = rng.permutation(n)
    return SyntheticNetwork(name, points[order], normals[order], label[order], layout.branches,
                            np.asarray(layout.junctions, float).reshape(-1, 3), noise,
                            layout.floor if share > 0 else None, layout.boxes if share > 0 else ())


# --------------------------------------------------------------------------------------------------
# simulated scans: what a terrestrial laser scanner sees of a surface or network

#: Default spacing of a scan's points on the scene's centre, as a share of the smallest radius: some 20
#: points across the visible half of a cross-section (pi r / 0.15 r), as many as a sampled cloud of the
#: paper's size has around the whole of it.
SCAN_SPACING_PER_RADIUS = 0.15
#: Default noise of a scan at range 0, as a share of the smallest radius: 1 % is 1 mm on a pipe of 10 cm
#: radius, a terrestrial scanner's range noise at short range.
SCAN_NOISE_PER_RADIUS = 0.01
#: Default scanners stand this many scene sizes (the diagonal of the scene's bounding box) from the
#: scene's centre: far enough to see all of it at once, near enough for the spacing to differ between
#: its near and far sides (by a factor of about 5 / 3).
SCANNER_DISTANCE = 2.0
#: The first default scanner looks across the scene's shorter horizontal side, turned by this many
#: degrees about the vertical, so that no pipe along x or y is seen exactly end on.
SCANNER_TURN = 30.0
#: The ground plane reaches this many scene sizes beyond the scene's footprint, so that the shadows the
#: scene casts behind it fall on the ground.
GROUND_MARGIN = 0.5
#: Vertices around each tube of the scene's mesh: a polygon of 64 sides lies within 0.12 % of the radius
#: of its circle, so occlusion and silhouettes are right to that.
SCAN_MESH_AROUND = 64
#: A ray's hit on the mesh of a tube is moved to the true surface along the ray (Newton's method in the
#: distance along the ray and the spine parameter, from the hit and the nearest spine sample); the root
#: must lie within this share of the branch's largest radius of the hit (the mesh is within 3 % of the
#: radius of the surface), else the ray is dropped as one that grazes the surface.
SNAP_REACH = 0.25
#: Newton steps; the start is within 3 % r of the root and convergence quadratic, so 12 are ample.
SNAP_STEPS = 12
#: A root counts when |P - C(t)| - r(t) is below this share of the radius.
SNAP_TOLERANCE = 1e-9
#: Default bound on the rays of a scan (the grid of directions around the scene's bounding box, from
#: every scanner): 1.5 million rays on a plant of 92 tubes took 9 s (2 cores, half of it in Embree), and
#: a dense grid holds some 100 bytes per ray.
MAX_SCAN_RAYS = 2_000_000


@dataclass(frozen=True)
class ScanInfo:
    """How a simulated scan was made (:func:`scan`), and where each of its points came from.

    Attributes
    ----------
    positions : ndarray, shape (S, 3)
        The scanners.
    step : float
        Angular step in degrees, in elevation and in azimuth (a scanner above, below or inside the
        scene's box turns all the way round and rounds its azimuth step down to a whole number of steps
        per turn).
    noise, range_noise : float
        Each point was moved along its ray by N(0, sigma^2), ``sigma = noise + range_noise * range``.
    quantum : float or None
        Coordinates are whole multiples of this (None: not quantised).
    ground : float or None
        Height of the ground plane (None: no ground).
    scanner : ndarray of int, shape (N,)
        Index into ``positions`` of the scanner that saw each point.
    range : ndarray, shape (N,)
        Distance from that scanner to the surface along the ray (before the noise).
    rays : int
        Rays cast: the grid directions that meet the scene's bounding box.
    dropped : int
        Rays that met the mesh of a tube but not the true surface within reach of it: they graze a
        silhouette (or touch it, a ray tangent to a pipe); a few per ten thousand.
    """

    positions: np.ndarray
    step: float
    noise: float
    range_noise: float
    quantum: float | None
    ground: float | None
    scanner: np.ndarray
    range: np.ndarray
    rays: int
    dropped: int

    @property
    def sigma(self) -> np.ndarray:
        """Standard deviation of each point's noise along its ray."""
        return self.noise + self.range_noise * self.range


@dataclass(frozen=True)
class _Scene:
    """What a scan looks at: the tubes (loops when ``closed``) and the clutter around them."""

    name: str
    branches: tuple
    closed: bool
    junctions: np.ndarray
    floor: tuple | None
    boxes: tuple
    network: bool

    @property
    def capped(self) -> tuple[bool, bool]:
        """Which ends of a tube are closed by their ball: both, unless the tube is closed (a loop)."""
        return (not self.closed, not self.closed)


def _scene(truth, options: dict) -> _Scene:
    """The scene of ``truth``: a name of SURFACES or NETWORKS, a SyntheticTube or a SyntheticNetwork."""
    if isinstance(truth, str) and truth in NETWORKS:
        layout = _build(truth, options)
        return _Scene(truth, layout.branches, False, np.asarray(layout.junctions, float).reshape(-1, 3),
                      layout.floor, layout.boxes, True)
    if options:
        raise InputError(f"option {next(iter(options))!r} is an option of a network's builder; "
                         f"{truth if isinstance(truth, str) else type(truth).__name__!r} takes none")
    if isinstance(truth, SyntheticNetwork):
        return _Scene(truth.name, tuple(truth.branches), False, np.asarray(truth.junctions, float).reshape(-1, 3),
                      truth.floor, tuple(truth.boxes), True)
    if isinstance(truth, SyntheticTube):
        return _Scene(truth.name, (SyntheticBranch(truth.spine, truth.radius),), bool(truth.closed),
                      np.empty((0, 3)), None, (), False)
    if isinstance(truth, str):
        choice(truth, "surface or network name", (*SURFACES, *NETWORKS))
        spine_f, radius_f, closed, _, _ = SURFACES[truth]
        return _Scene(truth, (SyntheticBranch(spine_f(), radius_f()),), closed, np.empty((0, 3)), None, (), False)
    raise InputError("scan needs a name of SURFACES or NETWORKS, a SyntheticTube or a SyntheticNetwork, "
                     f"got {type(truth).__name__}")


def _scene_box(scene: _Scene) -> tuple[np.ndarray, np.ndarray]:
    """Low and high corners of the bounding box of the scene's tubes, floor and boxes."""
    lo, hi = _footprint(_Layout(scene.branches, scene.junctions, boxes=scene.boxes))
    if scene.floor is not None:
        x0, x1, y0, y1, z = scene.floor
        lo, hi = np.minimum(lo, [x0, y0, z]), np.maximum(hi, [x1, y1, z])
    return lo, hi


def _scanner_positions(positions, lo: np.ndarray, hi: np.ndarray, size: float) -> np.ndarray:
    """The scanners: ``positions`` as given, or that many placed by the default rule (see :func:`scan`)."""
    if positions is None:
        positions = 1
    if isinstance(positions, (int, np.integer)) and not isinstance(positions, bool):
        if positions < 1:
            raise InputError(f"positions must be a number of scanners >= 1 or an array of shape (S, 3), "
                             f"got {positions!r}")
        centre = (lo + hi) / 2
        # Across the shorter horizontal side, from the low side, turned by SCANNER_TURN.
        across = -90.0 if hi[0] - lo[0] >= hi[1] - lo[1] else 180.0
        angle = np.radians(across + SCANNER_TURN + 360.0 * np.arange(int(positions)) / int(positions))
        xy = centre[:2] + SCANNER_DISTANCE * size * np.column_stack([np.cos(angle), np.sin(angle)])
        return np.column_stack([xy, np.full(len(xy), centre[2])])
    try:
        array = np.array(positions, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"positions must be a number of scanners or an array of shape (S, 3), "
                         f"got {positions!r}") from None
    if array.ndim == 1 and array.shape == (3,):
        array = array[None]
    if array.ndim != 2 or array.shape[1] != 3 or not len(array) or not np.all(np.isfinite(array)):
        raise InputError(f"positions must be a number of scanners or a finite array of shape (S, 3), got an "
                         f"array of shape {array.shape}")
    return array


@dataclass(frozen=True)
class _Fan:
    """A scanner's rays: from ``origin`` on a regular grid of azimuth ``azimuth0 + i * azimuth_step``
    (from +x towards +y) and elevation ``elevation0 + j * elevation_step`` (from the horizontal plane
    up), in radians, for ``i < n_azimuth`` and ``j < n_elevation``.  Ray ``k`` is ``j * n_azimuth + i``.
    A fan that ``wraps`` covers the full turn: ``n_azimuth * azimuth_step`` is 2 pi."""

    origin: np.ndarray
    azimuth0: float
    azimuth_step: float
    n_azimuth: int
    elevation0: float
    elevation_step: float
    n_elevation: int
    wraps: bool = False

    @property
    def size(self) -> int:
        """Number of rays."""
        return self.n_azimuth * self.n_elevation

    def directions(self, rays: np.ndarray | None = None) -> np.ndarray:
        """Unit directions of the rays ``rays`` (default all), shape (len(rays), 3)."""
        k = np.arange(self.size) if rays is None else np.asarray(rays)
        azimuth = self.azimuth0 + (k % self.n_azimuth) * self.azimuth_step
        elevation = self.elevation0 + (k // self.n_azimuth) * self.elevation_step
        flat = np.cos(elevation)
        return np.column_stack([flat * np.cos(azimuth), flat * np.sin(azimuth), np.sin(elevation)])


def _fan(origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, step: float) -> _Fan:
    """The rays from ``origin`` on the grid of angular ``step`` (radians) that cover the box [lo, hi]:
    azimuth and elevation whole multiples of ``step``, between the bounds of the box's directions."""
    near_xy = np.clip(origin[:2], lo[:2], hi[:2])
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    d_min = float(np.linalg.norm(near_xy - origin[:2]))
    d_max = float(np.linalg.norm(corners - origin[:2], axis=1).max())
    # atan2(dz, dh) grows with dz; it falls with dh above the scanner and grows with it below.
    top, bottom = hi[2] - origin[2], lo[2] - origin[2]
    high = np.arctan2(top, d_min if top > 0 else d_max)
    low = np.arctan2(bottom, d_min if bottom < 0 else d_max)
    j0, j1 = int(np.ceil(low / step - 1e-9)), int(np.floor(high / step + 1e-9))
    n_elevation = max(j1 - j0 + 1, 0)
    if d_min == 0:  # above, below or inside the box: every azimuth
        n = int(np.ceil(2 * np.pi / step - 1e-9))
        return _Fan(origin, 0.0, 2 * np.pi / n, n, j0 * step, step, n_elevation, wraps=True)
    middle = np.arctan2(*((lo[:2] + hi[:2]) / 2 - origin[:2])[::-1])
    around = middle + np.mod(np.arctan2(corners[:, 1] - origin[1], corners[:, 0] - origin[0]) - middle + np.pi,
                             2 * np.pi) - np.pi
    i0, i1 = int(np.ceil(around.min() / step - 1e-9)), int(np.floor(around.max() / step + 1e-9))
    return _Fan(origin, i0 * step, step, max(i1 - i0 + 1, 0), j0 * step, step, n_elevation)


def _through_box(origin: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """True for each ray that meets the box [lo, hi] (the slab test)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / directions
        a, b = (lo - origin) * inverse, (hi - origin) * inverse
    enter = np.nanmax(np.fmin(a, b), axis=1)
    leave = np.nanmin(np.fmax(a, b), axis=1)
    return leave >= np.maximum(enter, 0.0)


def _rectangle(corner, e1, e2) -> np.ndarray:
    """The rectangle ``corner + [0, 1] e1 + [0, 1] e2`` as two triangles, shape (2, 3, 3)."""
    c, e1, e2 = (np.asarray(v, float) for v in (corner, e1, e2))
    return np.array([[c, c + e1, c + e1 + e2], [c, c + e1 + e2, c + e2]])


def _dome(rim: np.ndarray, centre: np.ndarray, r: float, axis: np.ndarray) -> np.ndarray:
    """The part of the sphere (``centre``, ``r``) beyond the circle ``rim`` (its vertices, in order),
    towards ``axis``: triangles joined to the rim's vertices, so that the tube they close is watertight."""
    w = (rim - centre) / r
    polar = float(np.arccos(np.clip(np.mean(w @ axis), -1.0, 1.0)))
    across = w - (w @ axis)[:, None] * axis
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    n_rings = max(2, int(np.ceil(polar / (2 * np.pi / len(rim)))))
    rings = [rim]
    for k in range(1, n_rings):
        angle = polar * (1 - k / n_rings)
        rings.append(centre + r * (np.cos(angle) * axis + np.sin(angle) * across))
    pole = centre + r * axis
    j, nxt = np.arange(len(rim)), np.roll(np.arange(len(rim)), -1)
    triangles = []
    for a, b in zip(rings, rings[1:]):
        triangles += [np.stack([a[j], a[nxt], b[nxt]], 1), np.stack([a[j], b[nxt], b[j]], 1)]
    triangles.append(np.stack([rings[-1][j], rings[-1][nxt], np.broadcast_to(pole, (len(rim), 3))], 1))
    triangles = np.concatenate(triangles)
    # Outward: the normal of each triangle points away from the centre.
    normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    inward = np.einsum("ij,ij->i", normal, triangles.mean(axis=1) - centre) < 0
    triangles[inward] = triangles[inward][:, ::-1]
    return triangles


def _scene_mesh(scene: _Scene, ground: tuple | None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the scene, shape (F, 3, 3), and the branch of each (-1 on floor, boxes and ground).

    Each tube is closed at its ends by a dome joined to its end ring, so no ray gets into it."""
    from .surface import surface_mesh

    triangles, owner = [], []

    def add(tris, branch):
        triangles.append(tris)
        owner.append(np.full(len(tris), branch, dtype=np.int64))

    for b, branch in enumerate(scene.branches):
        vertices, faces = surface_mesh(branch.spine, branch.radius, closed=scene.closed, caps=False,
                                       n_around=SCAN_MESH_AROUND)
        add(vertices[faces], b)
        for end, capped in enumerate(scene.capped):
            if capped:  # the end ring (the first or last SCAN_MESH_AROUND vertices) closed by its ball
                t = float(end)
                rim = vertices[:SCAN_MESH_AROUND] if end == 0 else vertices[-SCAN_MESH_AROUND:]
                tangent = branch.spine.derivative()(t)
                axis = (1.0 if end else -1.0) * tangent / np.linalg.norm(tangent)
                add(_dome(rim, branch.spine(t), float(branch.radius(t)), axis), b)
    rectangles = []
    if scene.floor is not None:
        x0, x1, y0, y1, z = scene.floor
        rectangles.append(_rectangle([x0, y0, z], [x1 - x0, 0, 0], [0, y1 - y0, 0]))
    for lo, hi in scene.boxes:
        dx, dy, dz = np.asarray(hi, float) - np.asarray(lo, float)
        for corner, e1, e2 in (([lo[0], lo[1], hi[2]], [dx, 0, 0], [0, dy, 0]), (lo, [dx, 0, 0], [0, dy, 0]),
                               (lo, [0, dy, 0], [0, 0, dz]), ([hi[0], lo[1], lo[2]], [0, dy, 0], [0, 0, dz]),
                               (lo, [dx, 0, 0], [0, 0, dz]), ([lo[0], hi[1], lo[2]], [dx, 0, 0], [0, 0, dz])):
            rectangles.append(_rectangle(corner, e1, e2))
    if ground is not None:
        x0, x1, y0, y1, z = ground
        rectangles.append(_rectangle([x0, y0, z], [x1 - x0, 0, 0], [0, y1 - y0, 0]))
    if rectangles:
        add(np.concatenate(rectangles), -1)
    return np.concatenate(triangles), np.concatenate(owner)


def _derivative(spline: BSpline, nu: int) -> BSpline | None:
    """The ``nu``-th derivative of ``spline``, None where it vanishes (degree below ``nu``)."""
    return spline.derivative(nu) if spline.k >= nu else None


def _value(spline: BSpline | None, t: np.ndarray) -> np.ndarray:
    return np.zeros(len(t)) if spline is None else np.asarray(spline(t), float).reshape(-1)


def _onto_tube(tube: _Tube, closed: bool, capped, origin, directions, start, outward):
    """Where each ray meets the true surface of ``tube`` near the mesh's hit at distance ``start``.

    The surface is the canal surface (the envelope of the spheres) and the balls closing the ``capped``
    ends; of the roots within reach, the nearest counts.  ``outward`` says whether the rays come from
    outside the tube.  Returns the distance along each ray, the outward normal there and whether a root
    was found (on the side the rays come from).
    """
    reach = SNAP_REACH * tube.r_max
    spine, radius = tube.spine, tube.radius
    d1, d2 = spine.derivative(1), _derivative(spine, 2)
    r1, r2 = _derivative(radius, 1), _derivative(radius, 2)
    n = len(start)
    best = np.full(n, np.inf)
    normal = np.zeros((n, 3))
    # The canal surface: F1 = |P(s) - C(t)| - r(t) = 0 and F2 = (P - C) . C' + r' |P - C| = 0 (t is the
    # parameter of P's characteristic circle), by Newton's method in (s, t).
    s = start.copy()
    t = tube.tree.query(origin + s[:, None] * directions)[1] / (tube.tree.n - 1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for iteration in range(SNAP_STEPS + 1):
            d = origin + s[:, None] * directions - spine(t)
            length = np.linalg.norm(d, axis=1)
            c1, c2 = d1(t), (np.zeros((n, 3)) if d2 is None else d2(t))
            r, dr, ddr = _value(radius, t), _value(r1, t), _value(r2, t)
            du, dc1 = np.einsum("ij,ij->i", d, directions), np.einsum("ij,ij->i", d, c1)
            f1, f2 = length - r, dc1 + dr * length
            if iteration == SNAP_STEPS:
                break
            j11, j12 = du / length, -dc1 / length - dr
            j21 = np.einsum("ij,ij->i", directions, c1) + dr * du / length
            j22 = -np.einsum("ij,ij->i", c1, c1) + np.einsum("ij,ij->i", d, c2) + ddr * length - dr * dc1 / length
            det = j11 * j22 - j12 * j21
            s = s - (f1 * j22 - f2 * j12) / det
            t = t - (j11 * f2 - j21 * f1) / det
            t = np.mod(t, 1.0) if closed else np.clip(t, -0.05, 1.05)
        speed = np.linalg.norm(c1, axis=1)
        ok = ((np.abs(f1) <= SNAP_TOLERANCE * r) & (np.abs(f2) <= SNAP_TOLERANCE * r * speed)
              & (np.abs(s - start) <= reach) & np.isfinite(s))
        if not closed:
            ok &= (t >= 0) & (t <= 1)
        unit = d / length[:, None]
        ok &= (np.einsum("ij,ij->i", unit, directions) < 0) == outward
        best[ok], normal[ok] = s[ok], unit[ok]
    # The balls at the closed ends: only their part beyond the end's characteristic circle is surface.
    for end in (0, 1):
        if not capped[end]:
            continue
        t_end = float(end)
        centre, r = spine(t_end), float(radius(t_end))
        velocity = d1(t_end)
        tangent = velocity / np.linalg.norm(velocity)
        rho = float(_value(r1, np.array([t_end]))[0]) / np.linalg.norm(velocity)
        sign = 1.0 if end else -1.0
        b = (centre - origin) @ directions.T
        disc = b**2 - (np.sum((centre - origin) ** 2) - r * r)
        root = np.sqrt(np.maximum(disc, 0.0))
        for s_ball in (b - root, b + root):
            unit = (origin + s_ball[:, None] * directions - centre) / r
            ok = ((disc >= 0) & (np.abs(s_ball - start) <= reach) & (s_ball < best)
                  & (sign * (unit @ tangent + rho) >= 0)
                  & ((np.einsum("ij,ij->i", unit, directions) < 0) == outward))
            best[ok], normal[ok] = s_ball[ok], unit[ok]
    return best, normal, np.isfinite(best)


def _ray_caster(triangles: np.ndarray):
    """trimesh's Embree ray caster on the triangles (F, 3, 3), each its own face (numbered as given)."""
    try:
        import trimesh
        from trimesh.ray.ray_pyembree import RayMeshIntersector
    except ImportError:
        raise InputError("simulating a scan needs the 'scan' extra (trimesh with Embree) — "
                         "pip install 'canalsurf[scan]'") from None
    faces = np.arange(3 * len(triangles)).reshape(-1, 3)
    return RayMeshIntersector(trimesh.Trimesh(triangles.reshape(-1, 3), faces, process=False))


def _first_hits(caster, triangles: np.ndarray, fan: _Fan) -> tuple[np.ndarray, np.ndarray]:
    """The first triangle each ray of ``fan`` meets (-1: none) and the distance to it (inf: none).

    Embree works in single precision, so only the triangle is taken from it; the distance is recomputed
    on that triangle's plane in double precision."""
    directions = fan.directions()
    origins = np.broadcast_to(fan.origin, directions.shape)
    index_tri, index_ray = caster.intersects_id(origins, directions, multiple_hits=False)
    corner = triangles[index_tri, 0]
    normal = np.cross(triangles[index_tri, 1] - corner, triangles[index_tri, 2] - corner)
    along = np.einsum("ij,ij->i", normal, directions[index_ray])
    ok = along != 0
    triangle = np.full(fan.size, -1, dtype=np.int64)
    distance = np.full(fan.size, np.inf)
    triangle[index_ray[ok]] = index_tri[ok]
    distance[index_ray[ok]] = np.einsum("ij,ij->i", normal[ok], corner[ok] - fan.origin) / along[ok]
    return triangle, distance


def scan(truth, *, positions=None, step: float | None = None, noise: float | None = None,
         range_noise: float | None = None, quantum: float | None = None, ground: bool = True, rng=None,
         max_points: int = MAX_SCAN_RAYS, **options):
    """Simulate a terrestrial laser scan of a surface or network: one-sided, occluded, with its ground truth.

    The scene (the tubes, the network's floor and boxes, and a ground plane) is triangulated; each
    scanner sends rays on a regular grid of azimuth and elevation with the angular ``step`` (so the
    spacing of the points grows with their range) towards the scene's bounding box, and every ray keeps
    its first hit: a tube hides its own far side and whatever stands behind it.  The rays are cast by
    Embree through trimesh's ray module (``RayMeshIntersector``, first hits only; the 'scan' extra).  A
    hit on a tube is then moved from the mesh to the true surface along the ray (to about 1e-9 of the
    radius), so a noise-free scan lies exactly on the truth.  Each point is then
    moved along its ray by Gaussian noise of standard deviation ``noise + range_noise * range``, and its
    coordinates are rounded to whole multiples of ``quantum`` as a LAS file stores them.

    Each tube is closed at its ends by the ball there (a dished end, like a pipe cap; at a junction the
    same ball as in :func:`make_network`): the scene's tubes are the union of their spheres, the set
    ``min_t |P - C(t)| - r(t) <= 0`` of each branch, so no ray sees into a tube and every tube point of a
    noise-free scan lies on it.  (:func:`make_tube` and :func:`make_network` leave free ends open.)

    Parameters
    ----------
    truth : str, SyntheticTube or SyntheticNetwork
        A name of ``SURFACES`` or ``NETWORKS``, or a generated cloud, whose truth (spine and radius, or
        branches, junctions, floor and boxes) is scanned; its points are not used.
    positions : int or array_like of shape (S, 3), optional
        The scanners, or how many to place by the default rule (default 1; one to three is usual): level
        with the middle of the scene's box (ground included), ``SCANNER_DISTANCE`` = 2 scene sizes (the
        diagonal of the scene's bounding box) from its centre horizontally; the first across the scene's
        shorter horizontal side (from -y for a scene longer in x, else from -x) turned by
        ``SCANNER_TURN`` = 30 degrees, the others evenly around (two face each other).  Given as
        coordinates (one point of shape (3,) is one scanner), a scanner may stand anywhere, inside the
        scene or a tube too; one above, below or inside the scene's box turns all the way round.
    step : float, optional
        Angular step of the grid, in degrees.  Default: the angle under which ``SCAN_SPACING_PER_RADIUS``
        = 0.15 of the smallest radius is seen from the nearest scanner at the scene's centre.  The
        number of rays falls with the square of the step.
    noise : float, optional
        Standard deviation of the range noise at range 0, in the scene's units (default
        ``SCAN_NOISE_PER_RADIUS`` = 1 % of the smallest radius; 0 for a noise-free scan).
    range_noise : float, optional
        Growth of the standard deviation with range (noise per unit of range).  Default ``noise`` divided
        by the range of the scene's centre from the nearest scanner: the noise doubles from the scanner
        to the scene (0 when ``noise`` is 0).
    quantum : float, optional
        Round every coordinate to a whole multiple of this, as LAS files store coordinates (e.g. 0.01 for
        1 cm in metres); default None, no rounding.
    ground : bool
        Put a ground plane under the scene (default True): at the height of the network's floor, else
        one largest radius below the lowest tube, reaching ``GROUND_MARGIN`` = 0.5 scene sizes beyond the
        scene's footprint.
    rng : numpy.random.Generator or int, optional
        Random generator or seed for the noise (default seed 0: the same call gives the same scan).
    max_points : int
        Most rays the scan may cast (so most points it returns), at most ``MAX_SYNTH_POINTS``; default
        ``MAX_SCAN_RAYS`` = 2 million.  A larger grid is refused before it is allocated.
    **options
        Options of a network's builder (``size`` for ``plant``), as in :func:`make_network`.

    Returns
    -------
    SyntheticTube or SyntheticNetwork
        For a surface a :class:`SyntheticTube` (``noise_model="scan"``; ``outlier`` marks the ground
        points), for a network a :class:`SyntheticNetwork` (``label`` -1 on floor, boxes and ground).
        ``normals`` are the true normals at the hits, turned towards the scanner that saw them.
        ``scan`` (:class:`ScanInfo`) holds the settings used and, per point, its scanner and range.
        Points are in scan order: by scanner, then elevation, then azimuth.

    Raises
    ------
    InputError
        An unknown name or option, an argument out of its range, a grid of more rays than
        ``max_points``, a scan in which no ray met the scene, or trimesh or embreex not installed.

    Examples
    --------
    >>> cloud = scan("fig9-pipe", rng=1)
    >>> cloud.scan.positions.shape, cloud.noise_model, round(cloud.scan.step, 4)
    ((1, 3), 'scan', 0.2033)
    >>> net = scan("t-junction", positions=2, noise=0.0)
    >>> sorted(set(net.label.tolist()))
    [-1, 0, 1, 2]
    """
    scene = _scene(truth, options)
    t = np.linspace(0.0, 1.0, 64)
    radii = np.concatenate([branch.radius(t) for branch in scene.branches])
    r_min, r_max = float(radii.min()), float(radii.max())
    lo, hi = _scene_box(scene)
    size = float(np.linalg.norm(hi - lo))
    if ground is not True and ground is not False:
        raise InputError(f"ground must be True or False, got {ground!r}")
    level = (scene.floor[4] if scene.floor is not None else lo[2] - r_max) if ground else None
    box_lo = lo.copy() if level is None else np.append(lo[:2], min(lo[2], level))
    positions = _scanner_positions(positions, box_lo, hi, size)
    centre = (lo + hi) / 2
    distance = max(float(np.linalg.norm(positions - centre, axis=1).min()), r_min)
    step = np.degrees(SCAN_SPACING_PER_RADIUS * r_min / distance) if step is None else _number(step, "step")
    if not 0 < step <= 90:
        raise InputError(f"step must be an angle in (0, 90] degrees, got {step!r}")
    noise = SCAN_NOISE_PER_RADIUS * r_min if noise is None else _number(noise, "noise")
    if noise < 0:
        raise InputError(f"noise must be >= 0, got {noise!r}")
    range_noise = noise / distance if range_noise is None else _number(range_noise, "range_noise")
    if range_noise < 0:
        raise InputError(f"range_noise must be >= 0, got {range_noise!r}")
    if quantum is not None:
        quantum = _number(quantum, "quantum")
        if not quantum > 0:
            raise InputError(f"quantum must be > 0, got {quantum!r}")
    if isinstance(max_points, bool) or not isinstance(max_points, (int, np.integer)) \
            or not 1 <= max_points <= MAX_SYNTH_POINTS:
        raise InputError(f"max_points must be a whole number in [1, {MAX_SYNTH_POINTS:,}], got {max_points!r}")
    rng = _generator(rng)

    fans = [_fan(p, box_lo, hi, np.radians(step)) for p in positions]
    n_rays = sum(fan.size for fan in fans)
    if n_rays > max_points:
        wider = step * np.sqrt(n_rays / max_points)
        raise InputError(f"a scan from {len(fans)} scanner{'s' * (len(fans) != 1)} with a step of {step:.4g} "
                         f"degrees would cast {n_rays:,} rays, more than max_points = {max_points:,}; give a "
                         f"larger step (about {wider:.3g} degrees or more: the rays fall with its square) or "
                         "raise max_points")

    if level is not None:
        margin = GROUND_MARGIN * size
        ground_rectangle = (lo[0] - margin, hi[0] + margin, lo[1] - margin, hi[1] + margin, level)
    else:
        ground_rectangle = None
    triangles, owner = _scene_mesh(scene, ground_rectangle)
    face_normal = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    face_normal /= np.linalg.norm(face_normal, axis=1, keepdims=True)
    caster = _ray_caster(triangles)
    tubes = [_Tube.of(branch) for branch in scene.branches]
    found = []  # per scanner that saw anything: its index, ranges, directions, labels, normals
    cast = dropped = 0
    for index, fan in enumerate(fans):
        if not fan.size:
            continue
        hit, reach = _first_hits(caster, triangles, fan)
        through = _through_box(fan.origin, fan.directions(), box_lo, hi)
        if fan.wraps:  # straight up or down every azimuth is the same ray: cast it once
            row = np.arange(fan.size) // fan.n_azimuth
            pole = np.abs(fan.elevation0 + row * fan.elevation_step) >= np.pi / 2 - 1e-12
            through &= ~pole | (np.arange(fan.size) % fan.n_azimuth == 0)
        cast += int(through.sum())
        rays = np.flatnonzero((hit >= 0) & through)
        directions = fan.directions(rays)
        tri, s = hit[rays], reach[rays]
        label = owner[tri]
        normal = face_normal[tri].copy()
        keep = np.ones(len(rays), bool)
        # Every tube is closed, so a ray meets it from outside unless the scanner stands in it.
        outside = np.array([tube.depth(fan.origin[None])[0] >= 0 for tube in tubes])
        for b in np.unique(label[label >= 0]):
            mine = np.flatnonzero(label == b)
            s[mine], normal[mine], keep[mine] = _onto_tube(tubes[b], scene.closed, scene.capped, fan.origin,
                                                           directions[mine], s[mine], outside[b])
        # Where tubes meet, the mesh of one can stand out of the other by its accuracy: a point inside
        # another tube belongs on that tube, where the ray enters it.
        for _ in range(2):
            holder = np.full(len(s), -1)
            holder[keep] = _container(fan.origin + s[keep, None] * directions[keep], label[keep], tubes)
            for c in np.unique(holder[holder >= 0]):
                moved = np.flatnonzero(holder == c)
                s[moved], normal[moved], keep[moved] = _onto_tube(
                    tubes[c], scene.closed, scene.capped, fan.origin, directions[moved], s[moved], outside[c])
                label[moved] = c
        holder = np.full(len(s), -1)
        holder[keep] = _container(fan.origin + s[keep, None] * directions[keep], label[keep], tubes)
        keep &= holder < 0
        dropped += int((~keep).sum())
        s, directions, label, normal = s[keep], directions[keep], label[keep], normal[keep]
        # Normals towards the scanner (inwards on a tube the scanner stands in).
        facing = np.einsum("ij,ij->i", normal, directions) > 0
        normal[facing] *= -1
        found.append((index, s, directions, label, normal))
    if not found or not sum(len(f[1]) for f in found):
        raise InputError(f"no ray of the scan met the scene (step {step:.4g} degrees from {len(positions)} "
                         "scanner(s)): give a smaller step or place the scanners nearer")
    scanner = np.concatenate([np.full(len(f[1]), f[0]) for f in found])
    origin = positions[scanner]
    s = np.concatenate([f[1] for f in found])
    directions = np.concatenate([f[2] for f in found])
    label = np.concatenate([f[3] for f in found])
    normals = np.concatenate([f[4] for f in found])
    sigma = noise + range_noise * s
    points = origin + (s + sigma * rng.standard_normal(len(s)))[:, None] * directions
    if quantum is not None:
        points = np.round(points / quantum) * quantum
    info = ScanInfo(positions, float(step), float(noise), float(range_noise), quantum,
                    None if level is None else float(level), scanner, s, cast, dropped)
    if scene.network:
        return SyntheticNetwork(scene.name, points, normals, label, scene.branches, scene.junctions, float(noise),
                                scene.floor, scene.boxes, info)
    branch = scene.branches[0]
    return SyntheticTube(scene.name, points, normals, branch.spine, branch.radius, scene.closed, float(noise),
                         "scan", label < 0, float("nan"), info)


# --------------------------------------------------------------------------------------------------
# cases real scans hold that a whole named surface does not: short obliquely cut segments, flared
# trunks, thin poles scanned from one side

#: A segment's spine runs on this many radii past each cut, so the cut surface ends inside the truth.
SEGMENT_OVERRUN = 1.5


def _straightish_spine(rng, length: float, bend: float, direction=None) -> BSpline:
    """A spine of ``length`` along a random (or the given) direction, bowed sideways by ``bend``."""
    d = rng.normal(size=3) if direction is None else np.asarray(direction, float)
    d /= np.linalg.norm(d)
    side = np.cross(d, rng.normal(size=3))
    side /= np.linalg.norm(side)
    s = np.linspace(0.0, 1.0, 7)
    vertices = (s * length)[:, None] * d + (4 * bend * s * (1 - s))[:, None] * side
    return _by_arclength(make_interp_spline(s, vertices, k=3)(np.linspace(0.0, 1.0, 300)))


def _flared(t: np.ndarray, radius: float, flare: tuple, width: float) -> np.ndarray:
    """Radius ``radius`` growing by ``flare[0]``, ``flare[1]`` (shares) over ``width`` of t at each end."""
    return radius * (1 + flare[0] * np.clip((width - t) / width, 0, 1) ** 2
                     + flare[1] * np.clip((t - 1 + width) / width, 0, 1) ** 2)


def make_segment(*, length: float = 4.0, cut: tuple = (30.0, 30.0), flare: tuple = (0.2, 0.2),
                 n: int = 3000, noise: float = 0.02, rng=None) -> SyntheticTube:
    """A short tube of radius 1 cut off obliquely at both ends, flaring towards them.

    So a vessel segment looks where it left a bifurcation, or a pipe stub between two fittings: the
    tube runs ``length`` radii between the centres of its two cut planes, each tilted by ``cut``
    degrees from square (about a random axis), and its radius grows by the shares ``flare`` over the
    last radius or two before each end.

    Parameters
    ----------
    length : float
        Between the cut centres, in radii (3 - 6 is short).
    cut : (float, float)
        Tilt of each cut plane in degrees, in [0, 60].
    flare : (float, float)
        Growth of the radius at each end, as shares of it.
    n, noise, rng
        Points sampled on the whole tube before the cuts (by area), uniform noise half-width along
        the normals, seed.

    Returns
    -------
    SyntheticTube
        Its ``spine`` and ``radius`` run ``SEGMENT_OVERRUN`` radii past each cut (the points stop at
        the cuts).
    """
    rng = _generator(rng)
    if not (0 < length and all(0 <= c <= 60 for c in cut) and all(f >= 0 for f in flare)):
        raise InputError(f"make_segment needs length > 0, cuts in [0, 60] degrees and flares >= 0, "
                         f"got {length!r}, {cut!r}, {flare!r}")
    total = length + 2 * SEGMENT_OVERRUN
    spine = _straightish_spine(rng, total, rng.uniform(0.0, 0.2) * length)
    t = np.linspace(0.0, 1.0, 200)
    width = rng.uniform(1.0, 2.0) / total
    radius = make_interp_spline(t, _flared(t, 1.0, flare, width), k=3)
    points, normals = sample_tube(spine, radius, _point_count(n), noise, rng)
    keep = np.ones(len(points), bool)
    for tc, sign, tilt in ((SEGMENT_OVERRUN / total, 1.0, cut[0]), (1 - SEGMENT_OVERRUN / total, -1.0, cut[1])):
        tangent = spine.derivative()(tc)
        tangent /= np.linalg.norm(tangent)
        axis = np.cross(tangent, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        plane = np.cos(np.radians(tilt)) * tangent + np.sin(np.radians(tilt)) * axis
        keep &= sign * ((points - spine(tc)) @ plane) > 0
    return SyntheticTube("segment", points[keep], normals[keep], spine, radius, False, noise,
                         outlier=np.zeros(int(keep.sum()), bool))


def make_trunk(*, radius: float = 0.2, height: float = 3.0, flare: float = 0.5, n: int = 20000,
               noise: float | None = None, ground: float = 0.3, rng=None) -> SyntheticTube:
    """A tree trunk standing on the ground, its base flaring out: a canal whose radius falls fast.

    The radius is ``radius (1 + flare exp(-z / w)) (1 - 0.05 z / height)`` at height ``z`` (``w`` 0.2
    - 0.5 of the height's units, drawn), the trunk leans a little, and ``ground`` (a share of ``n``)
    points lie on the ground around it (marked in ``outlier``).

    Parameters
    ----------
    radius, height : float
        Radius above the flare and height of the trunk (metres, say).
    flare : float
        How much wider the base is, as a share of ``radius``.
    n : int
        Points on the trunk; ``ground * n`` more on the ground.
    noise : float, optional
        Standard deviation of Gaussian noise along the normals; default 1 % of ``radius``.
    ground : float
        Ground points per trunk point.
    rng
        Seed or generator.
    """
    rng = _generator(rng)
    if not (radius > 0 and height > 0 and flare >= 0 and ground >= 0):
        raise InputError(f"make_trunk needs radius, height > 0 and flare, ground >= 0, got "
                         f"{radius!r}, {height!r}, {flare!r}, {ground!r}")
    noise = 0.01 * radius if noise is None else float(noise)
    lean = np.r_[rng.normal(size=2) * 0.05, 1.0]
    spine = _by_arclength(np.linspace(0.0, height, 200)[:, None] * lean / lean[2])
    t = np.linspace(0.0, 1.0, 200)
    w = rng.uniform(0.2, 0.5) / height
    r = radius * (1 + flare * np.exp(-t / w)) * (1 - 0.05 * t)
    radius_f = make_interp_spline(t, r, k=3)
    points, normals = sample_tube(spine, radius_f, _point_count(n), noise, rng, noise_model="gaussian")
    m = int(ground * n)
    reach = 2.0 * height
    g = np.column_stack([rng.uniform(-reach, reach, (m, 2)), rng.normal(0.0, noise, m)])
    g = g[np.linalg.norm(g[:, :2], axis=1) > r[0] + 3 * noise]
    up = np.tile([0.0, 0.0, 1.0], (len(g), 1))
    return SyntheticTube("trunk", np.vstack([points, g]), np.vstack([normals, up]), spine, radius_f, False,
                         noise, "gaussian", np.r_[np.zeros(len(points), bool), np.ones(len(g), bool)])


def make_pole_scan(*, radius: float = 0.08, length: float = 2.0, vertical: bool = True, points: int = 2000,
                   distance: float = 6.0, quantum: float | None = 0.01, noise: float = 0.003,
                   rng=None) -> SyntheticTube:
    """A thin pole or pipe (metres) scanned once from one side, as mobile mapping sees street furniture.

    One scanner 1.6 m above the ground at ``distance`` from the tube's middle, its angular step chosen
    so that about ``points`` rays hit the tube; a ground plane; coordinates quantised to ``quantum``
    as a LAS file stores them (see :func:`scan`).  A vertical tube stands 0.3 m above the ground; a
    horizontal one lies 0.3 m above it.  The spine bows sideways by up to 30 % of the length.
    """
    rng = _generator(rng)
    if not (radius > 0 and length > 0 and points > 0 and distance > 0):
        raise InputError(f"make_pole_scan needs positive radius, length, points and distance, got "
                         f"{radius!r}, {length!r}, {points!r}, {distance!r}")
    axis = [0.0, 0.0, 1.0] if vertical else [1.0, 0.0, 0.0]
    spine = _straightish_spine(rng, length, rng.uniform(0.0, 0.3) * length, axis)
    low = spine(np.linspace(0, 1, 64))[:, 2].min()
    spine = BSpline(spine.t, spine.c + [0.0, 0.0, 0.3 - low + (0 if vertical else radius)], spine.k)
    truth = SyntheticTube("pole", np.zeros((1, 3)), np.zeros((1, 3)), spine, constant_spline(radius), False, 0.0)
    heading = rng.uniform(0, 2 * np.pi)
    position = spine(0.5) + distance * np.array([np.cos(heading), np.sin(heading), 0.0])
    position[2] = 1.6
    spacing = np.sqrt(length * 2 * radius / points)
    return scan(truth, positions=position[None], step=np.degrees(spacing / distance), noise=noise,
                range_noise=0.0, quantum=quantum, rng=rng)


#: Families of :func:`random_case`.
CASE_FAMILIES = ("tube", "segment", "trunk", "pole", "network", "plant")
#: Networks :func:`random_case` draws from for ``network`` (the plant is a family of its own).
_CASE_NETWORKS = ("y-vessel", "t-junction", "tree", "rack", "bundle", "crossing", "floor-clutter", "scene")


def random_case(family: str, seed: int):
    """A random scan of one of ``CASE_FAMILIES``, with its truth: what the trust checks run on.

    * ``tube``: a named surface, 800 - 5000 points, up to its default noise, seen all round or over
      270 or 180 degrees;
    * ``segment``: :func:`make_segment`, 3 - 6 radii long, cuts up to 45 degrees, flares up to 35 %;
    * ``trunk``: :func:`make_trunk`, radius 0.1 - 0.3, flare 20 - 70 %;
    * ``pole``: :func:`make_pole_scan`, radius 4 - 15 cm, 1,000 - 3,000 points on it, one scanner,
      1 cm quantisation;
    * ``network``: a named network (not the plant), 15,000 - 40,000 points, noise 0.5 - 3 %; a bundle of
      2 - 5 pipes of radii 0.3 - 2, touching or up to a radius apart;
    * ``plant``: one bay of the plant (23 tubes of radii 0.5 - 2, racks, elbows, tees, a floor),
      40,000 - 160,000 points, noise 0.5 - 3 %.

    Returns
    -------
    SyntheticTube or SyntheticNetwork
    """
    choice(family, "case family", CASE_FAMILIES)
    rng = _generator(seed)
    if family == "tube":
        name = str(rng.choice(sorted(SURFACES)))
        return make_tube(name, n=int(rng.integers(800, 5001)), noise=SURFACES[name][3] * rng.uniform(0.0, 1.0),
                         arc=float(rng.choice([360.0, 360.0, 270.0, 180.0])), rng=rng)
    if family == "segment":
        return make_segment(length=rng.uniform(3.0, 6.0), cut=tuple(rng.uniform(0.0, 45.0, 2)),
                            flare=tuple(rng.uniform(0.0, 0.35, 2)), n=int(rng.integers(1500, 6001)),
                            noise=rng.uniform(0.0, 0.05), rng=rng)
    if family == "trunk":
        return make_trunk(radius=rng.uniform(0.1, 0.3), height=rng.uniform(2.0, 4.0), flare=rng.uniform(0.2, 0.7),
                          n=int(rng.integers(5000, 20001)), rng=rng)
    if family == "pole":
        return make_pole_scan(radius=rng.uniform(0.04, 0.15), length=rng.uniform(1.0, 3.0),
                              vertical=bool(rng.integers(2)), points=int(rng.integers(1000, 3001)),
                              distance=rng.uniform(3.0, 10.0), rng=rng)
    if family == "plant":
        return make_network("plant", n=int(rng.integers(40000, 160001)), noise=rng.uniform(0.005, 0.03), rng=rng)
    name, n, noise = str(rng.choice(_CASE_NETWORKS)), int(rng.integers(15000, 40001)), rng.uniform(0.005, 0.03)
    options = {} if name != "bundle" else {"radii": tuple(rng.uniform(0.3, 2.0, int(rng.integers(2, 6)))),
                                           "gap": float(rng.choice([0.0, rng.uniform(0.0, 1.0)]))}
    return make_network(name, n=n, noise=noise, rng=rng, **options)
