"""Stage 4a: ordering the thin point set into a curve (open, or closed when the spine is a loop).

The paper links closest points recursively; that walks through stray points and stops at gaps.
Here the thin set is averaged on a voxel grid, its k-nearest-neighbour graph reduced to a minimum
spanning tree, links much longer than both the typical link and the voxel size cut (stray points),
and the longest path of the heaviest remaining tree (its diameter) taken as the curve.  The curve is
closed when its two ends are no farther apart than a link that is kept: the tree had to break the
loop somewhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra, minimum_spanning_tree
from scipy.spatial import cKDTree

from .constants import ORDER_CUT_LINKS, ORDER_CUT_SPACINGS
from .errors import ReconstructionError
from .thin import voxel_average

__all__ = ["OrderedCurve", "order_curve"]

#: Neighbours per node of the graph the spanning tree is taken from.
GRAPH_NEIGHBOURS = 8
#: A closed curve must be at least this many typical links long (fewer cannot make a loop).
MIN_LOOP_LINKS = 12


@dataclass
class OrderedCurve:
    """The thin set as an ordered polyline.

    Attributes
    ----------
    points : ndarray, shape (M, 3)
        Vertices along the curve.
    weights : ndarray, shape (M,)
        Thin points represented by each vertex.
    closed : bool
    link : float
        Median link length of the spanning tree (the curve's sampling step).
    """

    points: np.ndarray
    weights: np.ndarray
    closed: bool
    link: float


def _farthest(tree, start: int) -> tuple[int, np.ndarray, np.ndarray]:
    dist, pred = dijkstra(tree, directed=False, indices=start, return_predecessors=True)
    dist = np.where(np.isfinite(dist), dist, -1.0)
    return int(np.argmax(dist)), dist, pred


def order_curve(points: np.ndarray, *, spacing: float) -> OrderedCurve:
    """Order a thin, curve-like cloud.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The thin set S-tilde.
    spacing : float
        Voxel size the set is averaged on first: about half the MLS radius H, so a vertex stands for a
        short piece of curve and noise across the curve is averaged away.

    Returns
    -------
    OrderedCurve

    Raises
    ------
    ReconstructionError
        If fewer than a handful of vertices remain, i.e. there is no curve to follow.
    """
    nodes, mass, _ = voxel_average(points, spacing)
    if len(nodes) < 4:
        raise ReconstructionError("the shrunk cloud collapsed to a point, not a curve — the input is not a tube")
    k = min(GRAPH_NEIGHBOURS + 1, len(nodes))
    dist, idx = cKDTree(nodes).query(nodes, k=k)
    rows = np.repeat(np.arange(len(nodes)), k - 1)
    cols, d = idx[:, 1:].ravel(), dist[:, 1:].ravel()
    ok = d > 0
    graph = coo_matrix((d[ok], (rows[ok], cols[ok])), shape=(len(nodes),) * 2).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T)).tocoo()
    link = float(np.median(tree.data))
    # A sparse thin set (a long, thin tube) has gaps of a few voxels that are no break in the curve.
    cut = max(ORDER_CUT_LINKS * link, ORDER_CUT_SPACINGS * spacing)
    keep = tree.data <= cut
    tree = coo_matrix((tree.data[keep], (tree.row[keep], tree.col[keep])), shape=tree.shape).tocsr()

    n_parts, label = connected_components(tree, directed=False)
    heaviest = int(np.argmax(np.bincount(label, mass, n_parts)))
    start = int(np.flatnonzero(label == heaviest)[0])
    u, _, _ = _farthest(tree, start)
    v, _, pred = _farthest(tree, u)
    path = [v]
    while path[-1] != u:
        path.append(int(pred[path[-1]]))
    path = np.array(path[::-1])
    if len(path) < 4:
        raise ReconstructionError("the thin point set has no long curve in it — the input is not a tube")

    # Give every vertex of the component to its nearest path vertex so no thin point is lost.
    members = np.flatnonzero(label == heaviest)
    _, near = cKDTree(nodes[path]).query(nodes[members])
    weights = np.bincount(near, mass[members], len(path))

    gap = float(np.linalg.norm(nodes[path[0]] - nodes[path[-1]]))
    closed = gap <= cut and len(path) >= MIN_LOOP_LINKS
    return OrderedCurve(nodes[path], weights, closed, link)
