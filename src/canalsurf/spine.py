"""Stage 4b: smoothing cubic B-splines (the spine C(t), and the radius r(t) the same way).

Curves are penalised least-squares B-splines (P-splines, Eilers & Marx 1996) on uniform knots in a
parameter that is normalised arc length, t in [0, 1].  A closed spine is a periodic cubic spline: its
first three coefficients repeat at the end, so C, C' and C'' match at t = 0 and t = 1.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline

from .constants import SMOOTHING

__all__ = ["constant_spline", "knots", "local_basis", "design_matrix", "coefficients_to_spline", "pspline_fit",
           "sample_arclength", "arclength_reparametrize", "curve_length", "polyline_arclength"]

DEGREE = 3


def constant_spline(value: float) -> BSpline:
    """The constant ``value`` on [0, 1] as a cubic B-spline (so that every derivative exists and is 0)."""
    return BSpline(np.r_[np.zeros(DEGREE + 1), np.ones(DEGREE + 1)], np.full(DEGREE + 1, float(value)), DEGREE)


def reversed_spline(spline: BSpline) -> BSpline:
    """The same curve (or function) on [0, 1] run the other way: ``t`` becomes ``1 - t``."""
    return BSpline(1.0 - spline.t[::-1], spline.c[::-1], spline.k)


def knots(n_segments: int, closed: bool) -> np.ndarray:
    """Knot vector on [0, 1]: clamped for open curves, periodically extended for closed ones."""
    inner = np.linspace(0.0, 1.0, n_segments + 1)
    if closed:
        h = 1.0 / n_segments
        return np.concatenate([-h * np.arange(DEGREE, 0, -1), inner, 1 + h * np.arange(1, DEGREE + 1)])
    return np.concatenate([np.zeros(DEGREE), inner, np.ones(DEGREE)])


def n_coefficients(n_segments: int, closed: bool) -> int:
    """Free coefficients of a spline on ``n_segments`` (periodic ones wrap)."""
    return n_segments if closed else n_segments + DEGREE


def local_basis(u: np.ndarray, n_segments: int, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """The ``DEGREE + 1`` basis functions that do not vanish at each ``u`` (values in [0, 1]).

    Returns
    -------
    values : ndarray, shape (N, DEGREE + 1)
    columns : ndarray of int, shape (N, DEGREE + 1)
        Their free coefficients: consecutive, wrapped around when ``closed``.
    """
    u = np.clip(np.asarray(u, float), 0.0, 1.0)
    if closed:
        u = np.where(u >= 1.0, 0.0, u)
    # Cox-de Boor on the knot span each u falls in (The NURBS Book, A2.2), vectorised: on uniform knots
    # the span follows from u itself, and building scipy's sparse design matrix costs several times more.
    t = knots(n_segments, closed)
    mu = np.minimum((u * n_segments).astype(np.intp), n_segments - 1) + DEGREE
    # The knots are rounded: a u next to one may fall on its other side.
    mu += (u >= t[mu + 1]) & (mu < n_segments + DEGREE - 1)
    mu -= (u < t[mu]) & (mu > DEGREE)
    left = [u - t[mu + 1 - j] for j in range(DEGREE + 1)]
    right = [t[mu + j] - u for j in range(DEGREE + 1)]
    values = [np.ones_like(u)]
    for j in range(1, DEGREE + 1):
        saved = np.zeros_like(u)
        for r in range(j):
            share = values[r] / (right[r + 1] + left[j - r])
            values[r] = saved + right[r + 1] * share
            saved = left[j - r] * share
        values.append(saved)
    columns = (mu - DEGREE)[:, None] + np.arange(DEGREE + 1)
    return np.column_stack(values), columns % n_segments if closed else columns


def design_matrix(u: np.ndarray, n_segments: int, closed: bool) -> sparse.csr_matrix:
    """Sparse B-spline basis at ``u`` (values in [0, 1]) with periodic columns folded when ``closed``."""
    values, columns = local_basis(u, n_segments, closed)
    B = sparse.csr_matrix((values.ravel(), columns.ravel(), np.arange(0, values.size + 1, DEGREE + 1)),
                          shape=(len(values), n_coefficients(n_segments, closed)))
    B.sum_duplicates()  # a loop of fewer than DEGREE + 1 segments folds a column onto itself
    return B


def coefficients_to_spline(coef: np.ndarray, n_segments: int, closed: bool) -> BSpline:
    """The BSpline of free coefficients ``coef`` (repeat the first ``DEGREE`` when closed)."""
    coef = np.asarray(coef, float)
    if closed:
        coef = np.concatenate([coef, coef[:DEGREE]])
    return BSpline(knots(n_segments, closed), coef, DEGREE)


@functools.lru_cache(maxsize=64)
def penalty(n_segments: int, closed: bool) -> np.ndarray:
    """Second-difference penalty matrix D^T D on the free coefficients (cyclic when closed).

    Dense (splines here have at most a few hundred coefficients) and read-only: it is cached, as
    the refinement asks for the same few sizes over and over.
    """
    m = n_coefficients(n_segments, closed)
    rows = np.arange(m if closed else max(m - 2, 1))
    D = np.zeros((len(rows), m))
    for shift, weight in enumerate((1.0, -2.0, 1.0)):
        cols = (rows + shift) % m if closed else rows + shift
        inside = cols < m
        np.add.at(D, (rows[inside], cols[inside]), weight)
    P = D.T @ D
    P.setflags(write=False)
    return P


def pspline_fit(u: np.ndarray, values: np.ndarray, *, n_segments: int, closed: bool = False,
                weights: np.ndarray | None = None, smoothing: float = SMOOTHING) -> BSpline:
    """Penalised least-squares cubic B-spline through ``values`` at parameters ``u``.

    Parameters
    ----------
    u : ndarray, shape (N,)
        Parameters in [0, 1].
    values : ndarray, shape (N,) or (N, d)
    n_segments : int
        Uniform knot intervals.  More follow sharper features; each needs several data points.
    closed : bool
        Periodic spline.
    weights : ndarray, shape (N,), optional
    smoothing : float
        Weight of the second-difference penalty relative to the data (per coefficient).  It keeps
        segments with little data well posed; at the default it barely changes well-sampled curves.

    Returns
    -------
    scipy.interpolate.BSpline
    """
    values = np.asarray(values, float)
    flat = values.reshape(len(values), -1)
    w = np.ones(len(u)) if weights is None else np.asarray(weights, float)
    basis, columns = local_basis(u, n_segments, closed)
    m = n_coefficients(n_segments, closed)
    # The normal equations B^T W B c = B^T W v, summed from each point's non-zero basis functions
    # (a sparse B costs more in overhead than these few hundred unknowns take to solve densely).
    wb = w[:, None] * basis
    pairs = (columns[:, :, None] * m + columns[:, None, :]).ravel()
    BtWB = np.bincount(pairs, weights=(wb[:, :, None] * basis[:, None, :]).ravel(), minlength=m * m)
    BtWv = np.column_stack([np.bincount(columns.ravel(), weights=(wb * v[:, None]).ravel(), minlength=m)
                            for v in flat.T])
    lam = smoothing * w.sum() / m
    coef = np.linalg.solve(BtWB.reshape(m, m) + lam * penalty(n_segments, closed), BtWv)
    return coefficients_to_spline(coef.reshape((m,) + values.shape[1:]), n_segments, closed)


def polyline_arclength(pts: np.ndarray) -> np.ndarray:
    """Arc length along the polyline ``pts`` (N, d) at each of its vertices, from the first (0)."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])


def _dense(spline: BSpline, a: float, b: float, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.linspace(a, b, n)
    pts = spline(t)
    return t, pts, polyline_arclength(pts)


def curve_length(spline: BSpline, a: float = 0.0, b: float = 1.0, n: int = 4001) -> float:
    """Length of ``spline`` on [a, b] (polyline of ``n`` samples)."""
    return float(_dense(spline, a, b, n)[2][-1])


def curvature(spline: BSpline, t: np.ndarray) -> np.ndarray:
    """Curvature ``|C' x C''| / |C'|^3`` of a space curve at parameters ``t``."""
    d1, d2 = spline(t, 1), spline(t, 2)
    return np.linalg.norm(np.cross(d1, d2), axis=1) / np.maximum(np.linalg.norm(d1, axis=1) ** 3, 1e-300)


def sample_arclength(spline: BSpline, n: int, *, oversample: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Parameters and points of ``n`` samples evenly spaced in arc length over [0, 1].

    Returns
    -------
    t : ndarray, shape (n,)
    points : ndarray, shape (n, d)
    """
    t, _, s = _dense(spline, 0.0, 1.0, max(n * oversample, 2001))
    ti = np.interp(np.linspace(0.0, s[-1], n), s, t)
    return ti, spline(ti)


#: Samples per knot interval (at least 801 in all) that :func:`arclength_reparametrize` fits the new spline
#: to: on a 3-turn helix of 40 intervals the refit lies 8.1e-5 radii from the old curve with 16, 8.0e-5 with
#: 40 (the arc-length parameter, not the samples, sets that); the refinement refits twice per pass.
REPARAMETRIZE_SAMPLES = 16


def arclength_reparametrize(spline: BSpline, *, n_segments: int, closed: bool, a: float = 0.0,
                            b: float = 1.0, extra: tuple = ()) -> tuple[BSpline, list, callable]:
    """Refit ``spline`` restricted to [a, b] as a function of normalised arc length.

    Parameters
    ----------
    spline : BSpline
    n_segments : int
        Knot intervals of the new spline.
    closed : bool
    a, b : float
        Old parameter range kept (a trimmed or extended open curve).
    extra : tuple of (BSpline, int)
        Functions of the same old parameter (e.g. the radius) with the segment count to refit them on.

    Returns
    -------
    new_spline : BSpline
    new_extra : list of BSpline
    to_new : callable
        Maps old parameters to new ones.
    """
    t, pts, s = _dense(spline, a, b, max(REPARAMETRIZE_SAMPLES * n_segments, 801))
    u = s / s[-1]
    new = pspline_fit(u, pts, n_segments=n_segments, closed=closed, smoothing=1e-9)
    new_extra = [pspline_fit(u, f(t), n_segments=m, closed=closed, smoothing=1e-9) for f, m in extra]

    def to_new(told):
        return np.interp(told, t, u)

    return new, new_extra, to_new
