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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from ._validate import choice
from .spine import constant_spline
from .errors import InputError

__all__ = ["SyntheticTube", "SURFACES", "CONDITIONS", "make_tube", "sample_tube", "view_direction", "constant_spline"]

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
        Sampled (perturbed) points and the true outward unit normals there.
    spine : scipy.interpolate.BSpline
        True spine C(t), t in [0, 1] (periodic when ``closed``).
    radius : scipy.interpolate.BSpline
        True radius r(t) on the same parameter.
    closed : bool
    noise : float
        Half-width of the uniform perturbation along the normal (its standard deviation when
        ``noise_model`` is ``"gaussian"``).
    noise_model : {"uniform", "gaussian"}
    outlier : ndarray of bool, shape (N,)
        Stray points (their ``normals`` are random directions).
    arc : float
        Degrees of each cross-section that were sampled (360 for a full scan).
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
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xyz, axis=0), axis=1))])
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
                    "the paper's Figure 14 canal: Table 1 spine, quadratic r(t) from 1 to 2.5"),
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
    if sampling == "parameter" and density_ratio == 1:
        t = rng.uniform(0.0, 1.0, n)
        s = rng.uniform(lo, hi, n)
    else:
        if sampling == "area":
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
        t, s = ts[:n], ss[:n]
    points, normal, _, _ = _envelope(spine, radius, t, s, view=view)
    if noise <= 0:
        eps = np.zeros(n)
    elif noise_model == "gaussian":
        eps = rng.normal(0.0, noise, n)
    else:
        eps = rng.uniform(-noise, noise, n)
    return points + eps[:, None] * normal, normal


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
        Number of points, stray points included (the paper used 2000).
    noise : float, optional
        Half-width of the uniform perturbation along the normal (the standard deviation for
        ``noise_model="gaussian"``); default the surface's own value.
    rng : numpy.random.Generator or int, optional
        Random generator or seed (default seed 0, so the same call gives the same cloud).
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

    Examples
    --------
    >>> tube = make_tube("fig9-pipe", rng=1)
    >>> tube.points.shape, tube.closed
    ((2000, 3), False)
    >>> make_tube("elbow", outliers=0.05, rng=1).outlier.sum()
    100
    """
    choice(name, "surface name", tuple(SURFACES))
    if int(n) < 1:
        raise InputError(f"n must be a positive number of points, got {n!r}")
    if not 0 <= outliers < 1:
        raise InputError(f"outliers must be a share in [0, 1), got {outliers!r}")
    spine_f, radius_f, closed, default_noise, _ = SURFACES[name]
    noise = default_noise if noise is None else float(noise)
    if noise < 0:
        raise InputError(f"noise must be >= 0, got {noise!r}")
    rng = np.random.default_rng(0 if rng is None else rng)
    spine, radius = spine_f(), radius_f()
    n_stray = int(round(outliers * int(n)))
    points, normals = sample_tube(spine, radius, int(n) - n_stray, noise, rng, sampling,
                                  noise_model=noise_model, arc=float(arc), density_ratio=float(density_ratio))
    outlier = np.zeros(int(n), bool)
    if n_stray:
        stray = rng.uniform(points.min(axis=0), points.max(axis=0), (n_stray, 3))
        directions = rng.normal(size=(n_stray, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        order = rng.permutation(int(n))
        points = np.vstack([points, stray])[order]
        normals = np.vstack([normals, directions])[order]
        outlier[order >= len(order) - n_stray] = True
    return SyntheticTube(name, points, normals, spine, radius, closed, noise, noise_model, outlier, float(arc))
