"""Stage 2: shrinking (paper, Section 2.1, Algorithm 1 for pipes and Algorithm 2 for canals).

Every point moves against its outward normal in steps of ``delta``.  After each move the points whose
neighbourhood of radius ``R`` holds a point with an (almost) opposite normal are counted: they have met
the other side of the tube, i.e. reached the spine.

* Algorithm 1 (``kind="pipe"``): all points move together; the break count is the number of points with
  an opposite neighbour (``N_i . N_j < 0``).
* Algorithm 2 (``kind="canal"``): a point stops for good when it meets a neighbour with ``N_i . N_j < tau``;
  the break count is the number of stopped points.

Stopping.  ``stop="paper"`` is the printed rule: stop once the break count reaches ``mu * n``.  As printed
it can fail to stop (the count may peak below ``mu * n``; with ``mu = 1`` a few points never meet the other
side).  ``stop="auto"`` (default) adds robust rules: Algorithm 1 also stops when the break count has passed
its peak and returns the state at the peak; Algorithm 2 also stops after ``PATIENCE`` moves that stop
(next to) no new point -- fewer than ``PATIENCE_SHARE`` of them -- and drops the points that never stopped.  The result records which rule fired.

Scans from one side.  Both algorithms need each point to meet one with an opposite normal, i.e. the
other side of the tube; a scan that saw only part of the circumference may have none.
:func:`shrink_by_concentration` needs none: it moves each point by the distance at which the shifted
points crowd together most (on a tube, the spine), and the pipeline falls back on it when the
algorithm of the paper does not stop.

Neighbours.  ``neighbours="kdtree"`` finds all pairs within ``R`` on a KD-tree;
``neighbours="gauss"`` is the paper's grouping: normals are hashed into latitude/longitude cells of the
Gauss map and a point is only checked against the points of the antipodal cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ._rows import in_threads, slabs
from .constants import PATIENCE, PATIENCE_SHARE, PEAK_DROP, PEAK_MIN_SHARE
from .errors import InputError

__all__ = ["ShrinkResult", "shrink", "shrink_by_concentration", "shrink_by_sections", "break_mask"]

#: Latitude x longitude cells of the paper's Gauss-map grouping (the paper leaves a, b open).
GAUSS_CELLS = (6, 12)
#: Most moves of ``delta`` a shrink may take to cover ``max_distance``.  Every move is a neighbour
#: search over all points, so the time grows as 1 / delta: the default (max_distance = 4 r0,
#: delta = r0 / 20) takes 80 moves, and 2,000 -- a step 25 times finer -- already takes minutes on a
#: large scan, while a finer step no longer locates the spine better than the thinning does.
MAX_MOVES = 2_000


@dataclass
class ShrinkResult:
    """Outcome of shrinking.

    Attributes
    ----------
    points : ndarray, shape (N, 3)
        The shrunk cloud S-hat (all input points; see ``keep``).
    keep : ndarray of bool, shape (N,)
        Points that reached the spine.  All true for Algorithm 1; for Algorithm 2 the stopped points.
    distance : ndarray, shape (N,)
        Distance each point moved: a first estimate of the radius there.
    iterations : int
        Number of delta moves ("iteration steps" in the paper).
    break_counts : ndarray of int
        Break count after 0, 1, ..., ``iterations`` moves.
    stop_rule : str
        ``"mu"`` (break count reached mu * n), ``"peak"``, ``"patience"``, ``"max-moves"`` (did not stop)
        ``"concentration"`` (:func:`shrink_by_concentration`) or ``"sections"`` (:func:`shrink_by_sections`).
    converged : bool
        False only when the iteration bound was hit.
    """

    points: np.ndarray
    keep: np.ndarray
    distance: np.ndarray
    iterations: int
    break_counts: np.ndarray
    stop_rule: str
    converged: bool
    history: list = field(default_factory=list, repr=False)


def _gauss_cells(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Latitude and longitude cell of each normal on the Gauss-map grid."""
    a, b = GAUSS_CELLS
    lat = np.arcsin(np.clip(normals[:, 2], -1, 1))
    lon = np.arctan2(normals[:, 1], normals[:, 0])
    k = np.clip(np.floor((lat + np.pi / 2) / np.pi * a).astype(int), 0, a - 1)
    l = np.floor((lon + np.pi) / (2 * np.pi) * b).astype(int) % b
    return k, l


def _pairs_gauss(points: np.ndarray, R: float, cells: tuple[np.ndarray, np.ndarray]):
    # A point of cell (k, l) is checked against the antipodal cell and the cells around it: the
    # antipodal cell alone misses opposite normals that fall just across a cell border (and the
    # tilted symmetric normals of a canal surface, Figure 10).
    a, b = GAUSS_CELLS
    k, l = cells
    cell = k * b + l
    rows, cols = [], []
    for c in np.unique(cell):
        ck, cl = divmod(int(c), b)
        mine = np.flatnonzero(cell == c)
        ak, al = a - 1 - ck, (cl + b // 2) % b
        near = ((np.abs(k - ak) <= 1)
                & (np.minimum((l - al) % b, (al - l) % b) <= 1))
        theirs = np.flatnonzero(near)
        if len(theirs) == 0:
            continue
        hits = cKDTree(points[theirs]).query_ball_point(points[mine], np.nextafter(R, 0.0), workers=-1)
        counts = np.fromiter((len(h) for h in hits), int, len(hits))
        if counts.any():
            rows.append(np.repeat(mine, counts))
            cols.append(theirs[np.concatenate([h for h in hits if h])])
    if not rows:
        return np.empty(0, int), np.empty(0, int)
    return np.concatenate(rows), np.concatenate(cols)


def break_mask(points: np.ndarray, normals: np.ndarray, R: float, tau: float = 0.0,
               neighbours: str = "kdtree", cells=None) -> np.ndarray:
    """Points with a neighbour closer than ``R`` whose normal makes ``N_i . N_j < tau``.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
    R : float
    tau : float
        0 for the pipe condition (Eq. 1), ``cos(80 deg)`` in the paper's canal examples.
    neighbours : {"kdtree", "gauss"}
    cells : tuple, optional
        Precomputed Gauss-map cells (``neighbours="gauss"`` only).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    def marked(pairs):
        i, j = pairs
        opposite = np.einsum("ij,ij->i", normals[i], normals[j]) < tau
        return np.concatenate([i[opposite], j[opposite]])

    if neighbours == "gauss":
        hits = marked(_pairs_gauss(points, R, cells if cells is not None else _gauss_cells(normals)))
    else:
        # T_i holds the points strictly closer than R; the tree's query includes distance == R.  Each
        # slab is searched in a thread; a pair in two slabs' overlap is marked twice.
        reach = np.nextafter(R, 0.0)
        hits = np.concatenate(in_threads(
            lambda rows: marked(rows[cKDTree(points[rows]).query_pairs(reach, output_type="ndarray").T]),
            slabs(points, reach)))
    mask = np.zeros(len(points), bool)
    mask[hits] = True
    return mask


def _move_count(max_distance: float, delta: float, R: float) -> int:
    """Moves of ``delta`` that cover ``max_distance``, or :class:`InputError` if the numbers cannot work."""
    tiny = np.finfo(np.float64).tiny
    for name, value in (("delta", delta), ("R", R), ("max_distance", max_distance)):
        try:
            v = float(value)
        except (TypeError, ValueError, OverflowError):
            raise InputError(f"{name} must be a positive number, got {value!r}") from None
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"{name} must be a positive finite number, got {v!r} (relative to the scan's "
                             f"size) — give a {name} of the order of the tube's radius")
        if v < tiny:
            raise InputError(f"{name} = {v:.3g} (relative to the scan's size) is too small for float64 "
                             f"arithmetic — give a larger {name}")
    ratio = float(max_distance) / float(delta)
    if not ratio <= MAX_MOVES:
        raise InputError(f"delta is {ratio:.3g} times smaller than the shrink distance, so shrinking could take "
                         f"{ratio:.3g} moves (at most {MAX_MOVES:,}) — give a larger delta (the default, "
                         "r0 / 20, takes 80)")
    return int(np.ceil(ratio))


def shrink(points: np.ndarray, normals: np.ndarray, *, R: float, delta: float, mu: float,
           tau: float = 0.0, kind: str = "pipe", stop: str = "auto", neighbours: str = "kdtree",
           max_distance: float, callback=None) -> ShrinkResult:
    """Shrink a tube's points towards its spine (Algorithm 1 or 2).

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Points and outward unit normals.
    R : float
        Neighbour radius.  Larger than the gaps of the collapsed cloud and than the normal error times
        the radius plus the noise; well below the radius.
    delta : float
        Step length.  Smaller steps locate the spine better at the cost of more iterations.
    mu : float
        Share of points that must break for the printed stop rule (paper: 0.7 - 1.0).
    tau : float
        Normal-angle tolerance of Algorithm 2 (``kind="canal"``); ignored for pipes (the condition is < 0).
    kind : {"pipe", "canal"}
        Algorithm 1 or Algorithm 2.
    stop : {"auto", "paper"}
        ``"paper"``: only the printed ``mu`` rule; ``"auto"``: also the peak / patience rules.
    neighbours : {"kdtree", "gauss"}
    max_distance : float
        No point moves farther than this (bounds the iterations when no rule fires).  At most
        ``MAX_MOVES`` = 2,000 moves of ``delta`` may cover it.
    callback : callable, optional
        Called as ``callback(moves, break_count)`` after each check.

    Returns
    -------
    ShrinkResult

    Raises
    ------
    InputError
        ``delta``, ``R`` or ``max_distance`` not a positive float64 of normal size, or
        ``max_distance / delta`` above ``MAX_MOVES``.
    """
    n = len(points)
    max_moves = _move_count(max_distance, delta, R)
    cells = _gauss_cells(normals) if neighbours == "gauss" else None
    target = mu * n
    counts: list[int] = []

    if kind == "pipe":
        for moves in range(max_moves + 1):
            current = points - (moves * delta) * normals
            count = int(break_mask(current, normals, R, 0.0, neighbours, cells).sum())
            counts.append(count)
            if callback:
                callback(moves, count)
            if count >= target:
                rule, best = "mu", moves
                break
            peak = int(np.argmax(counts))
            if (stop == "auto" and counts[peak] >= PEAK_MIN_SHARE * n
                    and count < PEAK_DROP * counts[peak]):
                rule, best = "peak", peak
                break
        else:
            rule, best = "max-moves", max_moves
        dist = np.full(n, best * delta)
        return ShrinkResult(points - best * delta * normals, np.ones(n, bool), dist, best,
                            np.array(counts[: best + 1] if rule == "peak" else counts), rule,
                            rule != "max-moves")

    stopped = np.zeros(n, bool)
    dist = np.zeros(n)
    quiet = 0
    for moves in range(max_moves + 1):
        current = points - dist[:, None] * normals
        newly = break_mask(current, normals, R, tau, neighbours, cells) & ~stopped
        stopped |= newly
        count = int(stopped.sum())
        counts.append(count)
        if callback:
            callback(moves, count)
        if count >= target:
            rule = "mu"
            break
        quiet = 0 if newly.sum() >= PATIENCE_SHARE * n else quiet + 1
        if stop == "auto" and quiet >= PATIENCE and count >= 0.5 * n:
            rule = "patience"
            break
        if moves < max_moves:
            dist[~stopped] += delta
    else:
        rule = "max-moves"
    keep = stopped if stop == "auto" else np.ones(n, bool)
    return ShrinkResult(points - dist[:, None] * normals, keep, dist, len(counts) - 1,
                        np.array(counts), rule, rule != "max-moves")


def shrink_by_concentration(points: np.ndarray, normals: np.ndarray, *, R: float, delta: float,
                            max_distance: float, neighbours: np.ndarray) -> ShrinkResult:
    """Move each point by the distance at which the shifted points concentrate most.

    For each move ``m delta`` all points are shifted against their normals and each point's count of
    shifted points within ``R`` is taken; shifted by its own radius, a point lands on the spine with
    the points of its cross-section, so its count peaks there whether or not the other side of the tube
    was scanned.  The counts are averaged over each point's ``neighbours`` on the surface (they share
    its radius) before the peak is picked, which steadies the choice on sparse scans.

    Parameters
    ----------
    points, normals : ndarray, shape (N, 3)
        Points and outward unit normals.
    R : float
        Radius of the count (as in :func:`shrink`).
    delta : float
        Step of the distances tried.
    max_distance : float
        Largest distance tried; at most ``MAX_MOVES`` = 2,000 steps of ``delta``.
    neighbours : ndarray of int, shape (N, k)
        Each point's nearest neighbours on the surface (the first column may be the point itself).

    Returns
    -------
    ShrinkResult
        ``break_counts`` holds the total count after each move; every point is kept.

    Raises
    ------
    InputError
        As :func:`shrink`, for ``delta``, ``R`` and ``max_distance``.
    """
    moves = _move_count(max_distance, delta, R)
    counts = np.empty((moves + 1, len(points)))
    for m in range(moves + 1):
        shifted = points - (m * delta) * normals
        counts[m] = cKDTree(shifted).query_ball_point(shifted, np.nextafter(R, 0.0), return_length=True,
                                                      workers=-1)
    local = counts[:, neighbours].mean(axis=2)
    best = np.argmax(local, axis=0)
    dist = best * delta
    return ShrinkResult(points - dist[:, None] * normals, np.ones(len(points), bool), dist, int(best.max()),
                        counts.sum(axis=1).astype(int), "concentration", True)


#: Neighbours of each point whose cross-section :func:`shrink_by_sections` fits a circle to: on a thin
#: tube scanned sparsely from one side (a street pole, 4 cm radius, 2 cm spacing) they reach some
#: five radii along it and across all of its visible side.
SECTION_NEIGHBOURS = 64
#: A neighbourhood counts as a piece of tube when it is at least this many times longer (standard
#: deviation along its main axis) than wide: a patch of a plane or a blob is not.
MIN_SECTION_ELONGATION = 1.5


def shrink_by_sections(points: np.ndarray, *, k: int = SECTION_NEIGHBOURS) -> tuple[ShrinkResult, np.ndarray]:
    """Move each point to the centre of the circle fitted to its neighbourhood's cross-section.

    The last resort when normals cannot be trusted: coordinates quantised to steps near the radius (a
    mobile-mapping pole stored in 1.6 and 3.1 cm steps on a 4 cm radius) give normals, curvature and
    the concentration of shifted points (:func:`shrink_by_concentration`) nothing to go on, while a
    circle fitted to some sixty points across a cross-section still finds the axis.  Each point's
    ``k`` nearest neighbours give the local axis (their main direction), are projected onto the plane
    across it and fitted with a circle (least squares in the algebraic distance, Kasa's method); the
    point moves to the circle's centre at its own place along the axis.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    k : int
        Neighbours per cross-section.

    Returns
    -------
    ShrinkResult
        ``distance`` holds each fitted circle's radius; ``stop_rule`` is ``"sections"``.
    tube : ndarray of bool, shape (N,)
        Points whose neighbourhood is elongated like a piece of tube (:data:`MIN_SECTION_ELONGATION`).
    """
    k = min(int(k), len(points))
    _, nbr = cKDTree(points).query(points, k=k, workers=-1)
    centroid = points[nbr].mean(axis=1)
    patch = points[nbr] - centroid[:, None]
    spread, frame = np.linalg.eigh(np.einsum("nki,nkj->nij", patch, patch) / k)
    axis, across = frame[:, :, 2], frame[:, :, :2]
    uv = np.einsum("nki,nij->nkj", patch, across)
    A = np.concatenate([uv, np.ones((len(points), k, 1))], axis=2)
    rhs = -(uv**2).sum(axis=2)
    AtA = np.einsum("nki,nkj->nij", A, A) + 1e-12 * np.eye(3)
    coef = np.linalg.solve(AtA, np.einsum("nki,nk->ni", A, rhs)[..., None])[..., 0]
    centre2 = -coef[:, :2] / 2
    radius = np.sqrt(np.maximum((centre2**2).sum(axis=1) - coef[:, 2], 0.0))
    along = np.einsum("ni,ni->n", points - centroid, axis)
    moved = centroid + np.einsum("nij,nj->ni", across, centre2) + along[:, None] * axis
    tube = spread[:, 2] >= MIN_SECTION_ELONGATION**2 * spread[:, 1]
    result = ShrinkResult(moved, np.ones(len(points), bool), radius, 0, np.zeros(1, int), "sections", True)
    return result, tube
