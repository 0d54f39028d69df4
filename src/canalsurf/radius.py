"""Stage 5: the radius -- a first estimate from curvature, Eq. (6) for a pipe, r(t) for a canal.

A first radius ``r0`` sets the scale of every automatic parameter.  It is the median over the points
of ``1 / kappa_max``, the larger principal curvature of the normal field (on a tube the curvature
around the tube), from a least-squares fit of the normal differences of each neighbourhood.

After shrinking and thinning, the paper's radius is the mean distance between each input point and
its thinned image (Eq. 6); for a canal the per-point radii ``r_i`` are fitted by a smoothing spline.
Whether a tube is a pipe or a canal is decided by the Bayesian information criterion of the two fits,
and a radius function must also vary by more than ``CANAL_MIN_VARIATION`` of its mean, and by no more
than ``MAX_RADIUS_RATIO`` times.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ._rows import by_rows
from .constants import CANAL_MIN_VARIATION, MAX_RADIUS_RATIO

__all__ = ["principal_curvature", "curvature_radius", "pipe_radius", "prefer_canal", "plausible_radius"]


def principal_curvature(points: np.ndarray, normals: np.ndarray, *, k: int = 16,
                        neighbours: np.ndarray | None = None) -> np.ndarray:
    """The larger principal curvature ``kappa_max`` of the normal field at each point.

    On a tube it is the curvature around the tube, ``1 / r``; on a plane it is about 0 (the noise's).

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Points and consistently oriented unit normals.
    k : int
        Neighbourhood size of the curvature fit.
    neighbours : ndarray of int, shape (N, k), optional
        Each point's ``k`` nearest points, from a search already made (``k`` is then their number).

    Returns
    -------
    ndarray, shape (N,)
    """
    idx = cKDTree(points).query(points, k=min(k, len(points)), workers=-1)[1] if neighbours is None else neighbours
    return by_rows(lambda rows: _kappa_max(points[idx[rows]] - points[rows, None, :],
                                           normals[idx[rows]] - normals[rows, None, :], normals[rows]), len(idx))


def _kappa_max(dp: np.ndarray, dn: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """:func:`principal_curvature` from each point's offsets ``dp`` to its neighbours and the differences
    ``dn`` of their normals from its own, ``normals``."""
    # Tangent basis of each point: any two unit vectors orthogonal to the normal.
    helper = np.where(np.abs(normals[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    basis = np.stack([e1, e2], axis=2)  # (N, 3, 2)
    # Batched matrix products: numpy's einsum takes several times as long over this many small matrices.
    a = dp @ basis
    b = dn @ basis
    # Shape operator W with dn = W dp in the tangent plane: least squares, then symmetrised.
    ata = np.swapaxes(a, 1, 2) @ a + 1e-12 * np.eye(2)
    atb = np.swapaxes(a, 1, 2) @ b
    W = np.linalg.solve(ata, atb)
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    return np.linalg.eigvalsh(W)[:, -1]


def curvature_radius(points: np.ndarray, normals: np.ndarray, *, k: int = 16,
                     kappa: np.ndarray | None = None) -> float:
    """Median of ``1 / kappa_max`` over the points: a first estimate of the tube radius.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Points and consistently oriented unit normals.
    k : int
        Neighbourhood size of the curvature fit.
    kappa : ndarray, shape (N,), optional
        :func:`principal_curvature` of the points, if already known.

    Returns
    -------
    float
    """
    if kappa is None:
        kappa = principal_curvature(points, normals, k=k)
    kappa = kappa[np.isfinite(kappa) & (kappa > 0)]
    if len(kappa) == 0:
        return float("inf")
    return float(1.0 / np.median(kappa))


def pipe_radius(points: np.ndarray, thin: np.ndarray) -> float:
    """Eq. (6): the mean distance between each point and its thinned image."""
    return float(np.linalg.norm(points - thin, axis=1).mean())


def prefer_canal(rss_pipe: float, rss_canal: float, n: int, extra_parameters: int,
                 radius_samples: np.ndarray) -> bool:
    """True when a radius function explains the data clearly better than a constant radius.

    Parameters
    ----------
    rss_pipe, rss_canal : float
        Residual sums of squares of the two fits on the same points.
    n : int
        Number of those points.
    extra_parameters : int
        Coefficients the radius function has beyond the constant.
    radius_samples : ndarray
        The fitted radius function sampled along the spine.

    Returns
    -------
    bool
    """
    if rss_canal <= 0:
        return True
    bic_gain = n * np.log(max(rss_pipe, 1e-300) / rss_canal) - extra_parameters * np.log(n)
    variation = np.ptp(radius_samples) / np.mean(radius_samples)
    return bool(bic_gain > 0 and variation > CANAL_MIN_VARIATION and plausible_radius(radius_samples))


def plausible_radius(radius_samples: np.ndarray) -> bool:
    """Whether a radius sampled along a tube stays positive and within ``MAX_RADIUS_RATIO`` of itself."""
    low = float(np.min(radius_samples))
    return low > 0 and float(np.max(radius_samples)) <= MAX_RADIUS_RATIO * low
