"""Stage 3: moving least-squares thinning of the shrunk cloud (paper, Section 2.2).

For each point P* the neighbours within ``H`` are weighted by Eq. (3),
``w = 2 (r/H)^3 - 3 (r/H)^2 + 1``; a weighted regression plane K is fitted and the neighbours are projected
onto it; in K a weighted regression line gives the local x axis; in that frame (origin at P*) the local
quadratic ``y = a x^2 + b x + c`` (Eq. 4-5) is fitted and P* moves to (0, c) mapped back to 3D.

Two deliberate departures, both from NOTES: the plane is the weighted *principal* plane (the printed
``z = Ax + By + C`` fails for near-vertical planes) and the line is the weighted principal direction in K
(the same least-squares idea without a preferred axis).  The shrunk cloud is first averaged on a voxel grid
finer than H (counts kept as weights), so a neighbourhood never holds thousands of points at collapse.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .constants import MLS_VOXEL_PER_H
from .errors import InputError

__all__ = ["mls_thin", "voxel_average", "wyvill_weight"]


def wyvill_weight(r: np.ndarray, H: float) -> np.ndarray:
    """Eq. (3): ``2 (r/H)^3 - 3 (r/H)^2 + 1`` for ``r < H``, else 0."""
    q = np.minimum(np.asarray(r, float) / H, 1.0)
    return 2 * q**3 - 3 * q**2 + 1


def voxel_average(points: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Average the points of each occupied voxel of edge ``size``.

    Returns
    -------
    centres : ndarray, shape (M, 3)
    counts : ndarray, shape (M,)
        Points per voxel.
    label : ndarray, shape (N,)
        Voxel index of each input point.
    """
    keys = np.floor((points - points.min(axis=0)) / size).astype(np.int64)
    span = keys.max(axis=0, initial=0) + 1
    if float(np.prod(span, dtype=float)) < 2.0**62:
        # One integer per voxel, in the rows' lexicographic order: sorting it is many times faster.
        keys = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, label, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    label = label.ravel()
    centres = np.zeros((len(counts), 3))
    np.add.at(centres, label, points)
    return centres / counts[:, None], counts, label


def mls_thin(points: np.ndarray, *, H: float) -> np.ndarray:
    """Move every point onto the local quadratic of its weighted neighbourhood.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The shrunk cloud.
    H : float
        Weighting radius of Eq. (3).  Must exceed the thickness of the shrunk cloud (else the local fit
        follows the scatter); every extra unit adds bias where the spine bends, so keep it below ~0.6 r.

    Returns
    -------
    ndarray, shape (N, 3)
        The thin, curve-like cloud S-tilde, row i the image of input row i.
    """
    extent = float(np.ptp(points, axis=0).max()) if len(points) else 0.0
    # The support voxels are numbered by 64-bit integers: a weighting radius too small for the cloud's
    # extent overflows them.
    if not (H > 0 and extent < 2.0**62 * MLS_VOXEL_PER_H * H):
        raise InputError(f"H = {H:.3g} (relative to the scan's size) is too small for a shrunk cloud "
                         f"{extent:.3g} across — give an H of the order of the tube's radius")
    support, mass, _ = voxel_average(points, MLS_VOXEL_PER_H * H)
    dist = cKDTree(points).sparse_distance_matrix(cKDTree(support), H, output_type="coo_matrix")
    i, j = dist.row, dist.col
    w = wyvill_weight(dist.data, H) * mass[j]
    # Rows with the point's own voxel at distance exactly 0 are not stored by the sparse matrix;
    # the point itself carries no extra information beyond its voxel, so nothing is lost.
    n = len(points)
    wsum = np.bincount(i, w, n)
    alone = wsum <= 0
    wsum[alone] = 1.0

    q = support[j]
    mean = np.stack([np.bincount(i, w * q[:, a], n) for a in range(3)], axis=1) / wsum[:, None]
    d = q - mean[i]
    cov = np.zeros((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(i, w * d[:, a] * d[:, b], n)
    _, vecs = np.linalg.eigh(cov)
    e_x = vecs[:, :, 2]  # line direction: largest spread
    e_y = vecs[:, :, 1]  # in the plane K, across the line
    # Local frame with origin at P* projected onto K (Eq. 4-5 are written with P* as origin).
    rel = q - points[i]
    x = np.einsum("ij,ij->i", rel, e_x[i])
    y = np.einsum("ij,ij->i", rel, e_y[i])
    # Weighted moments sum w x^p (p < 5) and sum w y x^p (p < 3), the powers by repeated products
    # (``x**p`` goes through the general power function).
    wx, wyx = w.copy(), w * y
    s, t = [], []
    for p in range(5):
        s.append(np.bincount(i, wx, n))
        if p < 3:
            t.append(np.bincount(i, wyx, n))
            wyx *= x
        wx *= x
    # Normal equations of min sum w (a x^2 + b x + c - y)^2, unknowns (c, b, a).
    A = np.stack([np.stack([s[0], s[1], s[2]], -1), np.stack([s[1], s[2], s[3]], -1),
                  np.stack([s[2], s[3], s[4]], -1)], axis=1)
    rhs = np.stack(t, axis=-1)
    # A tiny ridge keeps neighbourhoods with too few distinct x values solvable (they fall back to
    # the weighted mean offset); it is negligible against any real spread.
    A = A + 1e-12 * (s[2] + s[0])[:, None, None] * np.eye(3)
    c = np.linalg.solve(A, rhs[..., None])[:, 0, 0]
    # Drop the component along the plane normal (projection onto K), then move across the line to c.
    normal_k = vecs[:, :, 0]
    off = np.einsum("ij,ij->i", points - mean, normal_k)
    thin = points - off[:, None] * normal_k + c[:, None] * e_y
    thin[alone] = points[alone]
    return thin
