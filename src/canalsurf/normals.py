"""Stage 1: point normals by local regression planes, oriented outward.

The paper estimates each normal as the normal of the regression plane of the neighbouring points and
assumes it points outward.  Orientation is not given by the plane; it is propagated over a minimum
spanning tree of the neighbour graph (Hoppe et al. 1992) so neighbouring normals agree, and one global
sign per connected part is chosen by a mean-curvature vote: on any regular tube -- partial scans
included -- outward normals diverge, so ``sum (n_j - n_i) . (p_j - p_i)`` over neighbour pairs is positive.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from ._rows import by_rows
from .constants import NORMAL_NEIGHBOURS, ORIENT_LINK_REACH, ORIENT_NEIGHBOURS

__all__ = ["estimate_normals", "orient_normals", "point_inward", "facing_inward", "on_planes", "scatter_matrices",
           "surface_noise"]

#: Coefficients of the local quadric of :func:`surface_noise`: h = a x^2 + b xy + c y^2 + d x + e y + f.
_QUADRIC_TERMS = 6
#: :func:`surface_noise` is taken where it is below this share of the neighbourhoods' reach (the distance
#: of the k-th neighbour): nearer the reach the quadrics take in the noise and read it low (on the dense
#: noisy cylinders of tests/test_normals.py the thinning keeps it within 10 %).
NOISE_PER_REACH = 0.1
#: ... thinning the points no further than this many.
NOISE_MIN_POINTS = 2_000
#: A reading this share of the next sparser level's or more reads the noise, not the shapes, there.
NOISE_STEADY = 0.5
#: ... where the neighbourhoods' reach shrinks by no more than this factor from that level, as on a surface
#: (by 2, against 4 along a line).
NOISE_SHRINK = 2.5


def scatter_matrices(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Scatter matrix of each neighbourhood about its centroid: ``sum (p - m)(p - m)^T`` over ``points[idx[i]]``.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    idx : ndarray of int, shape (M, k)
        The neighbours of each of M points.

    Returns
    -------
    ndarray, shape (M, 3, 3)
    """
    # Batched matrix products: numpy's einsum takes several times as long over this many small matrices.
    nbr = points[idx]  # (N, k, 3)
    centred = nbr - nbr.mean(axis=1, keepdims=True)
    return np.swapaxes(centred, 1, 2) @ centred


def _pca_normals(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    def normals(rows):
        _, vecs = np.linalg.eigh(scatter_matrices(points, idx[rows]))  # ascending: column 0 is the normal
        return vecs[:, :, 0]

    return by_rows(normals, len(idx))


def estimate_normals(points: np.ndarray, *, k: int | None = None, neighbours: np.ndarray | None = None) -> np.ndarray:
    """Unit normals of the regression planes of the ``k`` nearest neighbours, oriented outward.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    k : int, optional
        Neighbourhood size (default 16).  Raise it for noisy or dense scans so that a neighbourhood
        spans clearly more than the noise; lower it for tubes only a few points around.
    neighbours : ndarray of int, shape (N, k), optional
        Each point's ``k`` nearest points (itself first), from a search already made; ``k`` is then
        their number.

    Returns
    -------
    ndarray, shape (N, 3)
    """
    if neighbours is None:
        k = min(NORMAL_NEIGHBOURS if k is None else int(k), len(points))
        neighbours = cKDTree(points).query(points, k=k, workers=-1)[1]
    return orient_normals(points, _pca_normals(points, neighbours), neighbours[:, :ORIENT_NEIGHBOURS + 1])


def _divergence(points, normals, rows, cols) -> np.ndarray:
    """``(n_j - n_i) . (p_j - p_i)`` of each neighbour pair: summed, positive for outward normals."""
    return np.einsum("ij,ij->i", normals[cols] - normals[rows], points[cols] - points[rows])


def point_inward(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> bool:
    """Whether given normals point inward on the whole (their mean-curvature vote is negative).

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
    neighbours : ndarray of int, shape (N, k)
        Neighbour indices of each point.
    """
    rows = np.repeat(np.arange(len(points)), neighbours.shape[1])
    return bool(_divergence(points, normals, rows, neighbours.ravel()).sum() < 0)


#: :func:`facing_inward`: a point's convexity vote, averaged over its neighbours this many times, below
#: minus this share of the median vote's size ...
INWARD_VOTE = 0.5
VOTE_SMOOTHING = 3
#: ... in a region of at least this share of the points, whose normals turn around an axis further than a
#: concave crease's do (their mean is shorter than this) ...
INWARD_MIN_SHARE = 0.01
INWARD_MEAN_NORMAL = 0.5
#: ... or turn at all (mean shorter than this) and meet at one axis they face: each point lies the same
#: distance r behind its normal from one line, within this share of r (root mean square).  Half tubes of
#: three touching in a row, at 5,000 - 10,000 points, measured 0.18 - 0.26; concave creases 1.5 - 2.3.
INWARD_TURNING_NORMAL = 0.9
INWARD_AXIS_FIT = 0.4


def facing_inward(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Which points lie on a tube their normals face into.

    The spanning tree of :func:`orient_normals` carries one orientation across the line where two tubes
    touch (their normals are parallel there, which the tree prefers), so a tube touching another can
    face inward whole while the vote of their part stays positive.  Such a tube is a wide region of
    points that curve the wrong way (their convexity vote, averaged over their neighbourhoods, is
    negative) whose normals turn all around its axis.  A concave crease (where a box stands on a floor)
    curves the wrong way too, but its normals turn through a right angle, and at a corner point three
    ways: their mean stays long.  A tube between two others it touches faces inward in two halves, each
    turning too little to tell from a crease by that mean; but a half tube's normals meet at its axis,
    one line at one distance before every point, where a crease's two faces' normals are parallel.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
    neighbours : ndarray of int, shape (N, k)
        Each point's nearest points, itself first.

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    n = len(points)
    offset = points[neighbours[:, 1:]] - points[:, None]
    turn = np.einsum("nkj,nkj->n", normals[neighbours[:, 1:]] - normals[:, None], offset)
    length = np.linalg.norm(offset, axis=2)
    # Divided by the spread of the neighbourhood and times its reach: the vote of a point on a tube of
    # radius r is about reach / 2r, whatever the density.
    spread = (length ** 2).sum(axis=1)
    vote = np.divide(turn * length.max(axis=1), spread, out=np.zeros(n), where=spread > 0)
    for _ in range(VOTE_SMOOTHING):
        vote = vote[neighbours].mean(axis=1)
    inward = np.flatnonzero(vote < -INWARD_VOTE * np.median(np.abs(vote)))
    found = np.zeros(n, bool)
    if len(inward) < INWARD_MIN_SHARE * n:
        return found
    at = np.full(n, -1)
    at[inward] = np.arange(len(inward))
    linked = at[neighbours[inward]]  # the neighbours' places among the inward points, -1 if not one
    rows, cols = np.nonzero(linked >= 0)
    links = coo_matrix((np.ones(len(rows)), (rows, linked[rows, cols])), shape=(len(inward), len(inward)))
    region = connected_components(links, directed=False)[1]
    for label in np.flatnonzero(np.bincount(region) >= INWARD_MIN_SHARE * n):
        members = inward[region == label]
        mean = np.linalg.norm(normals[members].mean(axis=0))
        if mean < INWARD_MEAN_NORMAL or (mean < INWARD_TURNING_NORMAL
                                         and _meet_at_an_axis(points[members], normals[members])):
            found[members] = True
    return found


def _meet_at_an_axis(points: np.ndarray, normals: np.ndarray) -> bool:
    """Whether each point lies one distance r > 0 behind its normal from one line (INWARD_AXIS_FIT).

    The line runs along the direction the normals are most nearly perpendicular to; across it, the
    points ``p`` and normals ``n`` are fitted by least squares to ``p = c - r n``.
    """
    axis = np.linalg.eigh(normals.T @ normals)[1][:, 0]
    across = np.eye(3) - np.outer(axis, axis)
    p, nrm = points @ across, normals @ across
    m = len(p)
    design = np.zeros((3 * m, 4))
    design[:, :3] = np.tile(np.eye(3), (m, 1))
    design[:, 3] = -nrm.ravel()
    fit, residual = np.linalg.lstsq(design, p.ravel(), rcond=None)[:2]
    r = fit[3]
    return bool(r > 0 and residual.size and np.sqrt(residual[0] / m) < INWARD_AXIS_FIT * r)


def _propagated_signs(parent: np.ndarray, flip: np.ndarray) -> np.ndarray:
    """Product of ``flip`` along each node's path to its root, by pointer jumping (log depth passes)."""
    sign = flip.copy()
    anc = parent.copy()
    while True:
        done = anc == parent[anc]  # anc is a root (its own parent)
        if done.all():
            break
        nxt = ~done
        sign[nxt] *= sign[anc[nxt]]
        anc[nxt] = anc[anc[nxt]]
    return sign


def orient_normals(points: np.ndarray, normals: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """Flip ``normals`` so they agree along a spanning tree and point outward.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
    neighbours : ndarray of int, shape (N, k)
        Neighbour indices of each point (the first column may be the point itself).

    Returns
    -------
    ndarray, shape (N, 3)
        A new array; the input is not changed.
    """
    n = len(points)
    # Row by row, in threads (:func:`canalsurf._rows.by_rows`): each link's length, each point's reach
    # (the distance to its farthest listed neighbour).
    length = by_rows(lambda r: np.linalg.norm(points[r, None, :] - points[neighbours[r]], axis=2), n)
    reach = length.max(axis=1)
    # A link far longer than the neighbourhoods at both of its ends bridges two surfaces (a sparse
    # floor under a pipe lists the pipe's underside among its neighbours): orientation must not
    # travel across it -- the normals there are parallel, so the spanning tree would prefer it.
    rows, slot = np.nonzero((neighbours != np.arange(n)[:, None])
                         & (length <= ORIENT_LINK_REACH * np.minimum(reach[:, None], reach[neighbours])))
    cols = neighbours[rows, slot]
    # Weight 1 - |cos| prefers links between nearly parallel normals; the floor keeps zero-weight
    # links (which sparse graphs would drop) in the graph.
    weight = by_rows(lambda e: 1.0 - np.abs(np.einsum("ij,ij->i", normals[rows[e]], normals[cols[e]])) + 1e-6,
                     len(rows))
    graph = coo_matrix((weight, (rows, cols)), shape=(n, n)).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T))
    n_parts, label = connected_components(tree, directed=False)

    # Each part's first point is its root.  One search from an extra node linked to every root gives
    # each point its parent in the tree (in a tree the parent is the same whatever the order of search).
    roots = np.unique(label, return_index=True)[1]
    tree = tree.tocoo()
    linked = coo_matrix((np.r_[tree.data, np.ones(n_parts)],
                         (np.r_[tree.row, np.full(n_parts, n)], np.r_[tree.col, roots])), shape=(n + 1, n + 1))
    _, pred = breadth_first_order(linked.tocsr(), n, directed=False, return_predecessors=True)
    parent = np.where(pred[:n] == n, np.arange(n), pred[:n])
    flip = np.ones(n)
    child = parent != np.arange(n)
    flip[child] = np.sign(np.einsum("ij,ij->i", normals[child], normals[parent[child]]))
    flip[flip == 0] = 1.0
    oriented = normals * _propagated_signs(parent, flip)[:, None]

    turn = by_rows(lambda e: _divergence(points, oriented, rows[e], cols[e]), len(rows))
    part_vote = np.bincount(label[rows], weights=turn, minlength=n_parts)
    oriented *= np.where(part_vote[label] < 0, -1.0, 1.0)[:, None]
    return oriented


#: RANSAC trials per plane in :func:`on_planes` (seeded): with half of the flat points on the plane,
#: 64 trials miss it with probability (1 - 1/8)^64 < 1e-3.
PLANE_TRIALS = 64
#: Planes looked for, largest first (ground, a wall or two, a sign).
MAX_PLANES = 4
#: A plane counts when this share of the flat points (and at least MIN_PLANE_POINTS) lie on it.
MIN_PLANE_SHARE = 0.05
MIN_PLANE_POINTS = 30
#: A point on a plane must face along its normal within this many degrees.
PLANE_NORMAL_DEGREES = 30.0


def on_planes(points: np.ndarray, normals: np.ndarray, flat: np.ndarray, tolerance: float) -> np.ndarray:
    """Indices of the points that lie on large planes (ground, walls, signs) found among ``flat``.

    Planes are found one after the other by RANSAC over the points of ``flat`` (indices of points
    whose surface is flat); every point within ``tolerance`` of a plane whose normal is within
    ``PLANE_NORMAL_DEGREES`` of the plane's is on it -- also points whose neighbourhood reaches a
    tube and so reads as curved, which would otherwise join the tube's fit.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
    flat : ndarray of int
    tolerance : float
        Largest distance from a plane, e.g. three times the scan's noise.

    Returns
    -------
    ndarray of int
    """
    rng = np.random.default_rng(0)
    left = np.asarray(flat)
    found = np.zeros(len(points), bool)
    cos_min = np.cos(np.radians(PLANE_NORMAL_DEGREES))
    for _ in range(MAX_PLANES):
        need = max(MIN_PLANE_POINTS, MIN_PLANE_SHARE * len(flat))
        if len(left) < need or not tolerance > 0:
            break
        best, best_count = None, 0
        candidates = points[left]
        for _ in range(PLANE_TRIALS):
            a, b, c = points[rng.choice(left, 3, replace=False)]
            n = np.cross(b - a, c - a)
            norm = np.linalg.norm(n)
            if norm == 0:
                continue
            n /= norm
            count = int((np.abs((candidates - a) @ n) < tolerance).sum())
            if count > best_count:
                best, best_count = (a, n), count
        if best is None or best_count < need:
            break
        a, n = best
        found |= (np.abs((points - a) @ n) < tolerance) & (np.abs(normals @ n) > cos_min)
        left = left[~found[left]]
    return np.flatnonzero(found)


def surface_noise(points: np.ndarray, seeds: np.ndarray, *, k: int = NORMAL_NEIGHBOURS, rng=0) -> float:
    """The scan's noise along the surface normal: the median scatter about a local quadric.

    About each seed, its ``k`` nearest ``points`` are fitted by a quadric height field over their
    regression plane; the scatter is the median of ``RSS / (k - 6)`` over the seeds, corrected for the
    median's bias, under its root.  A plane would take in the surface's curvature -- ``d^2 / 2r`` over a
    neighbourhood of reach ``d`` on a tube of radius ``r``, many times the noise where the points are
    sparse beside thin tubes -- the quadric follows it.  Where the noise comes near the neighbourhoods'
    reach (a dense, noisy scan) the quadrics fit the noise too and read it low: the points are then
    thinned (a seeded quarter at a time) until the noise is below ``NOISE_PER_REACH`` of the reach.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The scan, as dense as it is: the denser, the smaller the neighbourhoods.
    seeds : ndarray, shape (M, 3)
        Where to measure: points on the surfaces of interest (a few thousand are plenty).
    k : int
        Neighbourhood size, more than 6.
    rng : int or numpy.random.Generator
        Seed of the thinning.

    Returns
    -------
    float
        In the points' units; 0 for fewer than ``k`` points or no seeds.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> angle, z = rng.uniform(0, 2 * np.pi, 20_000), rng.uniform(0, 10, 20_000)
    >>> r = 1 + rng.normal(scale=0.01, size=20_000)
    >>> tube = np.column_stack([r * np.cos(angle), r * np.sin(angle), z])
    >>> round(surface_noise(tube, tube[:2000]), 3)
    0.01
    """
    if len(points) < k or not len(seeds) or k <= _QUADRIC_TERMS:
        return 0.0
    order = np.random.default_rng(rng).permutation(len(points))
    levels = [len(points)]
    while levels[-1] // 4 >= NOISE_MIN_POINTS:
        levels.append(levels[-1] // 4)

    def measure(n):
        level = points[order[:n]] if n < len(points) else points
        # An unbalanced tree builds in half the time; a few thousand queries do not feel the difference.
        reach, nbr = cKDTree(level, balanced_tree=False, compact_nodes=False).query(seeds, k=k, workers=-1)
        return _quadric_scatter(level[nbr], k), float(np.median(reach[:, -1]))

    read, start = {}, 0
    if len(levels) > 3:
        # A tree of every point of a dense scan costs more than those of all sparser levels together.
        # Where the three sparsest levels read about the same noise in neighbourhoods that shrink as on a
        # surface (as 1 / sqrt(n), not 1 / n as along thin tubes they reach beyond), they read the noise in
        # full, not the shapes (those a denser level reads far less of); the densest level that still
        # reads it is then foreseen from the densest of the three (``n <= most``: a noise read low
        # foresees it denser), and the search starts one level denser.
        read[levels[-1]] = measure(levels[-1])
        for sparser, n in zip(levels[:-3:-1], levels[-2:-4:-1]):
            read[n] = measure(n)
            if read[n][0] < NOISE_STEADY * read[sparser][0] or read[sparser][1] > NOISE_SHRINK * read[n][1]:
                break
        else:
            noise, reach = read[levels[-3]]
            most = levels[-3] * (NOISE_PER_REACH * reach / max(noise, 1e-300)) ** 2
            start = max(0, sum(n > most for n in levels) - 1)
    for n in levels[start:]:
        noise, reach = read[n] if n in read else measure(n)
        if noise <= NOISE_PER_REACH * reach or n == levels[-1]:
            return noise


def _quadric_scatter(patch: np.ndarray, k: int) -> float:
    """The median scatter of ``(M, k, 3)`` neighbourhoods about their quadrics (:func:`surface_noise`)."""
    patch = patch - patch.mean(axis=1, keepdims=True)
    _, frame = np.linalg.eigh(np.einsum("nki,nkj->nij", patch, patch))
    local = np.einsum("nki,nij->nkj", patch, frame)  # (height along the normal, then in-plane)
    h, y, x = local[..., 0], local[..., 1], local[..., 2]
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=-1)
    AtA = np.einsum("nki,nkj->nij", A, A)
    AtA += 1e-12 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] * np.eye(_QUADRIC_TERMS)
    coef = np.linalg.solve(AtA, np.einsum("nki,nk->ni", A, h)[..., None])[..., 0]
    rss = ((h - np.einsum("nki,ni->nk", A, coef)) ** 2).sum(axis=1)
    # The median of sigma^2 chi^2_dof / dof is about sigma^2 (1 - 2 / 9 dof)^3 (Wilson-Hilferty).
    dof = k - _QUADRIC_TERMS
    return float(np.sqrt(np.median(rss) / dof / (1.0 - 2.0 / (9.0 * dof)) ** 3))
