"""Stage 4a: the thin point set as a skeleton graph -- branches between junctions and ends.

The paper orders the thin set of one tube by linking closest points.  A scan of a network (a tree, a
vessel, a plant's pipe runs) thins to several curves that meet at junctions, and to separate curves
for tubes that do not touch.  Here the thin set is averaged on a voxel grid, its k-nearest-neighbour
graph reduced to a minimum spanning forest, and links much longer than both the typical link and the
voxel size cut (stray points, gaps between separate tubes).  In each tree:

* **spurs** -- short side paths from a node where three or more ways meet to a leaf, left by the
  thickness of the thin set where tubes meet or end -- are pruned: shorter than ``SPUR_RADII`` local
  radii, or standing for fewer than ``MIN_BRANCH_POINTS`` thin points;
* nodes where three or more ways meet and which lie within ``JUNCTION_RADII`` local radii of each
  other along the tree are one **junction**;
* the paths between junctions and ends are the **branches**.  A tree that is a single path whose ends
  are no farther apart than a kept link (nor the two tubes' radii) is a closed loop (the tree had to
  break it somewhere).

Trees that stand for too few points or are shorter than a radius are left out (stray points).
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from .constants import ORDER_CUT_LINKS, ORDER_CUT_SPACINGS
from .errors import ReconstructionError
from .spine import polyline_arclength
from .thin import voxel_average

__all__ = ["Skeleton", "SkeletonBranch", "skeletonize"]

#: Neighbours per node of the graph the spanning tree is taken from.
GRAPH_NEIGHBOURS = 8
#: Links longer than this share of the sum of their two nodes' radii join separate tubes: cut.
SEPARATE_RADII = 0.9
#: A closed curve must be at least this many typical links long (fewer cannot make a loop).
MIN_LOOP_LINKS = 12
#: A leaf path from a junction shorter than this many local radii is a spur: where tubes meet, the
#: thin set is as thick as the smear of the junction, about one radius of the larger tube.
SPUR_RADII = 1.5
#: Junction nodes closer than this many local radii along the tree are one junction (a noisy
#: junction splits into two or three nearby ones in a spanning tree).
JUNCTION_RADII = 1.0
#: A branch must stand for at least this many thin points (fewer: stray points that crowded).
MIN_BRANCH_POINTS = 20
#: A tree shorter than this many local radii is no tube (a blob of stray points).
MIN_TREE_RADII = 1.0
#: Two branches left alone at a junction are one pipe run only if the way through it turns by at
#: most this much (degrees): a tee's run goes straight on, an elbow turns 90 degrees; two tubes that
#: end side by side (their ends linked by a dropped piece) would turn back on themselves, 180 degrees.
MAX_JOIN_TURN = 120.0
#: The direction in which a branch leaves a junction is that of its chord between these many radii
#: (of the larger tube there) from the junction: nearer, the thin set bends into the junction's smear.
END_DIRECTION_RADII = (2.0, 6.0)
#: A branch that turns back on itself (more than MAX_JOIN_TURN) with legs closer together than this
#: many of their radii is two tubes whose ends the thin set linked, and is cut apart: a 180-degree
#: return bend's legs are 4 radii apart (short radius), a hose's or a cable's more.
HAIRPIN_LEGS_RADII = 3.0
#: An open end that stops within this many of its radii of a corner of another branch, where that branch
#: turns by at least TEE_CORNER degrees, and that goes on straight into one leg of the corner (turning by at
#: most TEE_STRAIGHT) in line with it (its end within the larger radius of that leg's line) is the far
#: half of a tee's run, which the thin set broke off at the junction: the side branch and the near half of
#: the run then make one branch round the corner.  The three meet there.  An end beside that leg, as far
#: off its line as the sum of the radii, is another tube touching it.
BROKEN_TEE_RADII = 2.0
TEE_CORNER = 45.0
TEE_STRAIGHT = 30.0
#: An open end that stops within this many of its radii of another branch's tube, beside the straight
#: middle of it, and points into its axis (the continued end passes within that branch's radius of it,
#: at TEE_CORNER degrees or more to it) is a tee's side branch whose thin set broke short of the junction.
#: The three meet there.
SIDE_GAP_RADII = 2.0

#: Two tubes side by side (a rack's neighbours) whose thin sets a few stray points linked meet at a false
#: junction.  Seen between BRIDGE_WINDOW_RADII (of the largest tube there) from it, past the link, two
#: branches there that run parallel (within BRIDGE_PARALLEL degrees) and keep clear of each other (farther
#: apart than their two radii) are such tubes; the end of each whose line misses the junction by more than
#: its radius is linked to it, and is opened.  A real branch leaves a run at an angle, or overlaps it there.
BRIDGE_WINDOW_RADII = (3.0, 8.0)
BRIDGE_PARALLEL = 15.0
#: The graph's nodes round a junction lie where the tubes' thin sets merge, not where their axes meet,
#: and the points the fits leave out round a junction are measured from it.  So a junction is placed
#: where the lines of its branches meet, each line fitted to the branch's vertices between
#: JUNCTION_LINE_RADII (of the largest tube there) from the junction: past the merging, near enough for
#: a bending branch to be nearly straight.  Only branches that run past that stretch give a line (a
#: shorter one is a stub, or a link of the thin set between two tubes side by side, and its line goes
#: nowhere).  The junction is left where it is when fewer than two do, or when the lines meet farther
#: than JUNCTION_MOVE_RADII from it (a tangle of the thin set, not a junction misplaced).
JUNCTION_LINE_RADII = (1.5, 3.0)
JUNCTION_MOVE_RADII = 2.0
#: Along a direction that one line alone fixes (a tee's run, fixed by its side branch only), the thin set's
#: bias where a thin branch nears a thick one can swing that line by more than the graph's junction is
#: off; and that junction lies within the largest tube there.  So a line that alone would move it along
#: such a direction by more than the largest radius is left out.  The lines fix a direction v by the
#: eigenvalue of the sum of their projections across, the sum of sin^2 of their angles to v: one line
#: across gives 1, a Y's three lines 1.5.
JUNCTION_ONE_LINE = 1.25


@dataclass
class SkeletonBranch:
    """One branch of the skeleton as an ordered polyline.

    Attributes
    ----------
    points : ndarray, shape (K, 3)
        Vertices along the branch, from its first end to its last.
    weights : ndarray, shape (K,)
        Thin points represented by each vertex.
    radius : ndarray, shape (K,)
        Mean distance of the represented input points from their thin images (the paper's r_i).
    ends : tuple of (int or None, int or None)
        Junction index at the first and at the last vertex; ``None`` for an open end.
    closed : bool
        The branch is a loop (no ends).
    """

    points: np.ndarray
    weights: np.ndarray
    radius: np.ndarray
    ends: tuple
    closed: bool = False

    @property
    def length(self) -> float:
        """Length of the polyline."""
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())


@dataclass
class Skeleton:
    """Branches and junctions of a thin point set.

    Attributes
    ----------
    branches : list of SkeletonBranch
    junctions : ndarray, shape (J, 3)
        Junction points: where the lines of the branches meet (see JUNCTION_LINE_RADII), else the
        mean of the graph nodes merged into each.
    link : float
        Median link length of the spanning forest (its sampling step).
    """

    branches: list
    junctions: np.ndarray
    link: float


def _spanning_forest(nodes: np.ndarray, spacing: np.ndarray, node_r: np.ndarray) -> tuple:
    """Minimum spanning forest of the k-NN graph with long links cut; (symmetric CSR, median link, cut
    per node).

    A link is cut when it is much longer than the typical link and the voxel size of its nodes (stray
    points), or
    when it is longer than ``SEPARATE_RADII`` times the sum of its nodes' radii: the spines of two
    tubes that do not meet lie at least that sum apart, while gaps along one tube's thin set (a
    sparse scan of a long, thin tube) are about one radius.
    """
    k = min(GRAPH_NEIGHBOURS + 1, len(nodes))
    dist, idx = cKDTree(nodes).query(nodes, k=k)
    rows = np.repeat(np.arange(len(nodes)), k - 1)
    cols, d = idx[:, 1:].ravel(), dist[:, 1:].ravel()
    ok = d > 0
    graph = coo_matrix((d[ok], (rows[ok], cols[ok])), shape=(len(nodes),) * 2).tocsr()
    tree = minimum_spanning_tree(graph.maximum(graph.T)).tocoo()
    link = float(np.median(tree.data))
    # A sparse thin set (a long, thin tube) has gaps of a few voxels that are no break in the curve.
    cut = np.maximum(ORDER_CUT_LINKS * link, ORDER_CUT_SPACINGS * spacing)
    separate = tree.data > SEPARATE_RADII * (node_r[tree.row] + node_r[tree.col])
    keep = (tree.data <= np.maximum(cut[tree.row], cut[tree.col])) & ~separate
    forest = coo_matrix((tree.data[keep], (tree.row[keep], tree.col[keep])), shape=tree.shape).tocsr()
    return (forest + forest.T).tocsr(), link, cut


class _Tree:
    """Adjacency of a spanning forest whose nodes can be removed (pruning)."""

    def __init__(self, graph):
        self.indptr, self.indices = graph.indptr, graph.indices
        self.alive = np.ones(graph.shape[0], bool)

    def neighbours(self, u: int) -> list:
        nbr = self.indices[self.indptr[u]:self.indptr[u + 1]]
        return [int(v) for v in nbr if self.alive[v]]

    def degree(self) -> np.ndarray:
        counted = np.concatenate([[0], np.cumsum(self.alive[self.indices])])
        deg = counted[self.indptr[1:]] - counted[self.indptr[:-1]]
        return np.where(self.alive, deg, 0)

    def segments(self) -> list:
        """Paths between nodes of degree other than 2 (each once), as lists of node indices."""
        deg = self.degree()
        seen, out = set(), []
        for u in np.flatnonzero(self.alive & (deg != 2)):
            u = int(u)
            for v in self.neighbours(u):
                if (u, v) in seen:
                    continue
                path = [u, v]
                while deg[path[-1]] == 2:
                    a, b = self.neighbours(path[-1])
                    path.append(a if a != path[-2] else b)
                seen.add((path[-1], path[-2]))
                out.append(path)
        return out


def _length(nodes: np.ndarray, path) -> float:
    return float(np.linalg.norm(np.diff(nodes[path], axis=0), axis=1).sum())


def _prune_spurs(tree: _Tree, nodes, mass, node_r) -> None:
    """Remove leaf paths from junctions that are too short or too light, until none is left."""
    while True:
        deg = tree.degree()
        removed = False
        for path in tree.segments():
            if deg[path[0]] == 1 and deg[path[-1]] >= 3:
                path = path[::-1]
            if not (deg[path[0]] >= 3 and deg[path[-1]] == 1):
                continue
            local = max(float(node_r[path[0]]), float(np.median(node_r[path])))
            if _length(nodes, path) < SPUR_RADII * local or mass[path[1:]].sum() < MIN_BRANCH_POINTS:
                tree.alive[path[1:]] = False
                removed = True
        if not removed:
            return


def _junction_clusters(tree: _Tree, segments, nodes, node_r) -> dict:
    """Map each junction node to its junction index, merging junctions close along the tree."""
    deg = tree.degree()
    hubs = [int(u) for u in np.flatnonzero(deg >= 3)]
    parent = {u: u for u in hubs}

    def find(u):
        while parent[u] != u:
            parent[u] = parent[parent[u]]
            u = parent[u]
        return u

    for path in segments:
        a, b = path[0], path[-1]
        if a in parent and b in parent and a != b:
            local = max(float(node_r[a]), float(node_r[b]))
            if _length(nodes, path) < JUNCTION_RADII * local:
                parent[find(a)] = find(b)
    roots = sorted({find(u) for u in hubs})
    index = {r: i for i, r in enumerate(roots)}
    return {u: index[find(u)] for u in hubs}


def _voxel_average(points: np.ndarray, spacing) -> tuple:
    """:func:`~canalsurf.thin.voxel_average` on the grid of each point's spacing; also each node's spacing."""
    spacing = np.broadcast_to(np.asarray(spacing, float), (len(points),))
    nodes, mass, label, sizes = [np.empty((0, 3))], [np.empty(0, np.int64)], np.empty(len(points), np.int64), [
        np.empty(0)]
    for size in np.unique(spacing):
        mine = np.flatnonzero(spacing == size)
        centres, counts, lab = voxel_average(points[mine], size)
        label[mine] = lab + sum(len(c) for c in nodes)
        nodes.append(centres)
        mass.append(counts)
        sizes.append(np.full(len(counts), size))
    return np.concatenate(nodes), np.concatenate(mass), label, np.concatenate(sizes)


def skeletonize(points: np.ndarray, radius: np.ndarray, *, spacing) -> Skeleton:
    """The skeleton graph of a thin, curve-like cloud.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        The thin set S-tilde.
    radius : ndarray, shape (N,)
        Distance of each thin point's input point from it (the paper's r_i): the local tube radius,
        which sets the length of a spur and of a junction.
    spacing : float or ndarray, shape (N,)
        Voxel size the set is averaged on first: about half the MLS radius H, so a vertex stands for a
        short piece of curve and noise across the curve is averaged away.  Per point for a thin set
        gathered at several scales (each scale is averaged on its own grid).

    Returns
    -------
    Skeleton

    Raises
    ------
    ReconstructionError
        If no curve is left: the set collapsed to a point, or holds no tree long enough for a tube.
    """
    nodes, mass, label, node_spacing = _voxel_average(points, spacing)
    if len(nodes) < 4:
        raise ReconstructionError("the shrunk cloud collapsed to a point, not a curve — the input is not a tube")
    node_r = np.bincount(label, radius, len(nodes)) / mass
    graph, link, cut = _spanning_forest(nodes, node_spacing, node_r)
    tree = _Tree(graph)
    _prune_spurs(tree, nodes, mass, node_r)
    segments = tree.segments()
    junction_of = _junction_clusters(tree, segments, nodes, node_r)

    n_parts, part = connected_components(graph, directed=False)
    part_mass = np.bincount(part, mass * tree.alive, n_parts)
    raw = []
    for path in segments:
        a, b = path[0], path[-1]
        ja, jb = junction_of.get(a), junction_of.get(b)
        if ja is not None and ja == jb and _length(nodes, path) < JUNCTION_RADII * 2 * node_r[path].max():
            continue  # inside one junction
        raw.append((np.array(path), ja, jb))
    # Leave out trees that are too light or too short for a tube (stray points that crowded).
    kept = []
    for path, ja, jb in raw:
        p = part[path[0]]
        tree_len = sum(_length(nodes, q) for q, _, _ in raw if part[q[0]] == p)
        if part_mass[p] < MIN_BRANCH_POINTS or tree_len < MIN_TREE_RADII * np.median(node_r[path]):
            continue
        kept.append((path, ja, jb))
    if not kept:
        raise ReconstructionError("the thin point set has no long curve in it — the input is not a tube")

    # Junction indices renumbered to those still used; points from pruned nodes weigh on the
    # nearest kept vertex so no thin point is lost -- but not those of trees left out (strays).
    used = sorted({j for _, ja, jb in kept for j in (ja, jb) if j is not None})
    renumber = {j: i for i, j in enumerate(used)}
    hubs_of = {}
    for u, j in junction_of.items():
        hubs_of.setdefault(j, []).append(u)
    junctions = np.array([nodes[hubs_of[j]].mean(axis=0) for j in used]).reshape(-1, 3)
    vertices = np.concatenate([path for path, _, _ in kept])
    owner = np.repeat(np.arange(len(kept)), [len(p) for p, _, _ in kept])
    members = np.flatnonzero(np.isin(part, part[vertices]))
    near = cKDTree(nodes[vertices]).query(nodes[members])[1]
    weight = np.bincount(near, mass[members], len(vertices))
    rsum = np.bincount(near, (mass * node_r)[members], len(vertices))
    branches = []
    for b, (path, ja, jb) in enumerate(kept):
        sel = owner == b
        w = weight[sel]
        r = np.where(w > 0, rsum[sel] / np.maximum(w, 1e-300), node_r[path])
        closing = np.linalg.norm(nodes[path[0]] - nodes[path[-1]])
        loop = (ja is None and jb is None and len(path) >= MIN_LOOP_LINKS and closing <= cut[path].max()
                and closing <= SEPARATE_RADII * (node_r[path[0]] + node_r[path[-1]]))
        ends = (None, None) if loop else (None if ja is None else renumber[ja],
                                          None if jb is None else renumber[jb])
        branches += _cut_hairpins(SkeletonBranch(nodes[path], np.maximum(w, 0.0), r, ends, bool(loop)))
    return _junctions_placed(_bridges_parted(_broken_tees_mended(Skeleton(branches, junctions, link))))


def _junctions_placed(skeleton: Skeleton) -> Skeleton:
    """The skeleton with each junction moved to where the lines of its branches meet (least squares;
    see JUNCTION_LINE_RADII), and the branches that gave a line run from it: their vertices nearer the
    moved end than the lines' stretch are spread evenly on the straight line from the junction point to
    the first vertex beyond, keeping their thin points, and take that vertex's r_i (theirs took in the
    other tubes' points where the thin sets merge)."""
    branches, junctions = list(skeleton.branches), skeleton.junctions.copy()
    eq6 = [float(np.average(b.radius, weights=b.weights)) if b.weights.sum() > 0 else float(np.mean(b.radius))
           for b in branches]
    for j in range(len(junctions)):
        ends = [(i, e) for i, b in enumerate(branches) for e in (0, 1) if not b.closed and b.ends[e] == j]
        if len(ends) < 2:
            continue
        largest = max(eq6[i] for i, _ in ends)
        near, far = np.multiply(JUNCTION_LINE_RADII, largest)
        lines, lined = [], []
        for i, e in ends:
            pts = branches[i].points if e == 0 else branches[i].points[::-1]
            s = polyline_arclength(pts)
            window = pts[(s >= near) & (s <= far)]
            if len(window) < 3 or s[-1] < far:
                continue
            centre = window.mean(axis=0)
            d = np.linalg.svd(window - centre, full_matrices=False)[2][0]
            lines.append((np.eye(3) - np.outer(d, d), centre))
            lined.append((i, e))
        if len(lined) < 2:
            continue
        point = _lines_meet(lines, junctions[j], largest)
        if np.linalg.norm(point - junctions[j]) > JUNCTION_MOVE_RADII * largest:
            continue
        junctions[j] = point
        for i, e in lined:
            b = branches[i] if e == 0 else _reversed(branches[i])
            m = max(1, int(np.sum(polyline_arclength(b.points) < near)))
            pts = b.points.copy()
            pts[:m] = point + np.outer(np.arange(m) / m, pts[m] - point)
            radius = b.radius.copy()
            radius[:m] = radius[m]
            b = SkeletonBranch(pts, b.weights, radius, b.ends, b.closed)
            branches[i] = b if e == 0 else _reversed(b)
    return Skeleton(branches, junctions, skeleton.link)


def _lines_meet(lines: list, graph: np.ndarray, radius: float) -> np.ndarray:
    """Where ``lines`` (pairs of a projection across a line and a point on it) meet in the least-squares
    sense, moving from ``graph`` only along the directions they fix.  A line that alone would move it
    along a direction that fewer than two lines fix (see JUNCTION_ONE_LINE) by more than ``radius`` is
    left out; ``graph`` itself when fewer than two lines are left."""
    lines = list(lines)
    while len(lines) >= 2:
        w, V = np.linalg.eigh(sum(P for P, _ in lines))
        # A light pull to ``graph`` holds it along lines that are (nearly) parallel (a tee's run).
        move = V.T @ sum(P @ (c - graph) for P, c in lines) / (w + 1e-3 * len(lines))
        wild = (w < JUNCTION_ONE_LINE) & (np.abs(move) > radius)
        if not wild.any():
            return graph + V @ move
        v = V[:, np.argmax(wild)]
        lines.pop(int(np.argmax([v @ P @ v for P, _ in lines])))
    return graph


def _broken_tees_mended(skeleton: Skeleton) -> Skeleton:
    """The skeleton with each broken tee (see BROKEN_TEE_RADII and SIDE_GAP_RADII) made a junction: the
    branch round the corner, or the run, is split there, and the broken-off branch ends there too."""
    branches, junctions = list(skeleton.branches), skeleton.junctions
    while (tee := _broken_tee(branches) or _detached_side(branches)) is not None:
        k, e, i, v = tee
        j = len(junctions)
        junctions = np.vstack([junctions, branches[i].points[v]])
        before, after = _split(branches[i], v, j)
        ends = list(branches[k].ends)
        ends[e] = j
        b = branches[k]
        branches[k] = SkeletonBranch(b.points, b.weights, b.radius, tuple(ends), b.closed)
        branches[i:i + 1] = [before, after]
    return Skeleton(branches, junctions, skeleton.link)


def with_tees_mended(skeleton: Skeleton) -> tuple[Skeleton, list]:
    """The skeleton with its broken tees mended (see :func:`_broken_tees_mended`).

    Dropping a branch can break a tee: where the thin set split a tee's junction in two, linked by a
    piece that is no tube, the side branch is left with an open end inside its run once that piece is
    dropped (:func:`without_branches`).

    Returns
    -------
    Skeleton
    origin : list of int or None
        For each new branch, the index of the old branch it is unchanged from, or ``None`` (a run split
        at a tee, or a side branch that now ends there).
    """
    mended = _broken_tees_mended(skeleton)
    index = {id(b): i for i, b in enumerate(skeleton.branches)}
    return mended, [index.get(id(b)) for b in mended.branches]


def _bridges_parted(skeleton: Skeleton) -> Skeleton:
    """The skeleton with each branch end at a false junction between tubes side by side opened (see
    BRIDGE_WINDOW_RADII), the two halves of a tube opened there joined as one branch, and the junctions
    left repaired (:func:`without_branches`)."""
    ends_at = {}
    for k, b in enumerate(skeleton.branches):
        for e, j in enumerate(b.ends):
            if j is not None and not b.closed:
                ends_at.setdefault(j, []).append((k, e))
    radius_of = [float(np.median(b.radius)) for b in skeleton.branches]
    opened, seen, pairs, taken = set(), {}, [], set()
    for j, members in ends_at.items():
        radius = max(radius_of[k] for k, _ in members)
        windows = {m: w for m in members if (w := _window(skeleton.branches[m[0]], m[1], radius)) is not None}
        seen.update(windows)
        here = set()
        for a, b in combinations(windows, 2):
            if a[0] != b[0] and _beside(windows[a], windows[b], radius_of[a[0]] + radius_of[b[0]]):
                # Of two tubes side by side, the one whose line misses the junction is linked to it.
                here |= {m for m in (a, b) if _off_line(skeleton.junctions[j][None], windows[m][0],
                                                        _axis(windows[m]))[0] > radius_of[m[0]]}
        opened |= here
        for a, b in combinations(sorted(here), 2):
            if not {a[0], b[0]} & taken and a[0] != b[0] and _in_line(windows[a], windows[b], radius):
                taken |= {a[0], b[0]}
                pairs.append((a, b))
    if not opened:
        return skeleton
    branches = list(skeleton.branches)
    for k, e in opened:
        branches[k] = _unlinked(branches[k], e, seen[k, e])
    joined, _ = with_ends_joined(Skeleton(branches, skeleton.junctions, skeleton.link), pairs)
    return without_branches(joined, ())[0]


def _window(b: SkeletonBranch, end: int, radius: float) -> np.ndarray | None:
    """The branch's vertices between BRIDGE_WINDOW_RADII ``radius`` from its end ``end``, in order away
    from it; ``None`` if it does not reach twice the first."""
    pts = b.points if end == 0 else b.points[::-1]
    s = polyline_arclength(pts)
    near, far = np.multiply(BRIDGE_WINDOW_RADII, radius)
    inside = (s >= near) & (s <= far)
    return pts[inside] if s[-1] >= 2 * near and inside.sum() >= 2 else None


def _unlinked(b: SkeletonBranch, end: int, window: np.ndarray) -> SkeletonBranch:
    """Branch ``b`` with its end ``end`` opened, less the vertices at that end that stray farther than its
    radius from the line of its ``window`` (the link to the false junction); their thin points weigh on
    the first vertex kept."""
    a = b if end == 1 else _reversed(b)
    off = _off_line(a.points, window[0], _axis(window)) > float(np.median(b.radius))
    keep = len(off) - int(np.argmin(off[::-1]))  # window[0] lies on the line, so it is kept
    weights = a.weights[:keep].copy()
    weights[-1] += a.weights[keep:].sum()
    a = SkeletonBranch(a.points[:keep], weights, a.radius[:keep], (a.ends[0], None), a.closed)
    return a if end == 1 else _reversed(a)


def _axis(window: np.ndarray) -> np.ndarray:
    d = window[-1] - window[0]
    return d / max(float(np.linalg.norm(d)), 1e-300)


def _in_line(a: np.ndarray, b: np.ndarray, radius: float) -> bool:
    """Whether two windows leaving one junction go on one from the other: opposed, and ``b`` on ``a``'s
    line within ``radius``."""
    da, db = _axis(a), _axis(b)
    return bool(_turn(da, db) <= BRIDGE_PARALLEL and _off_line(b, a[0], da).max() <= radius)


def _beside(window: np.ndarray, run: np.ndarray, clearance: float) -> bool:
    """Whether a window runs parallel to a run's window and keeps farther than ``clearance`` from its line."""
    d = _axis(run)
    parallel = min(_turn(_axis(window), d), _turn(_axis(window), -d)) <= BRIDGE_PARALLEL
    return bool(parallel and _off_line(window, run[0], d).min() > clearance)


def _off_line(pts: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> np.ndarray:
    rel = pts - origin
    return np.linalg.norm(rel - np.outer(rel @ direction, direction), axis=1)


def _split(b: SkeletonBranch, v: int, junction: int) -> tuple[SkeletonBranch, SkeletonBranch]:
    """Branch ``b`` split at its vertex ``v`` into two that meet at ``junction`` (the vertex is in
    both; its thin points weigh on the first only, so that none is counted twice)."""
    return (SkeletonBranch(b.points[:v + 1], b.weights[:v + 1], b.radius[:v + 1], (b.ends[0], junction)),
            SkeletonBranch(b.points[v:], np.r_[0.0, b.weights[v + 1:]], b.radius[v:], (junction, b.ends[1])))


def _broken_tee(branches: list) -> tuple | None:
    """``(k, e, i, v)``: branch ``k``'s open end ``e`` is the broken-off half of a tee's run at vertex
    ``v`` of branch ``i`` (see BROKEN_TEE_RADII); ``None`` if there is none."""
    radii = [float(np.median(b.radius)) for b in branches]
    for k, e, i, v, s in _ends_beside(branches, BROKEN_TEE_RADII * np.array(radii)):
        b, c = branches[k], branches[i]
        if min(s[v], s[-1] - s[v]) < END_DIRECTION_RADII[1] * float(c.radius[v]):
            continue  # near an end of c: no corner to tell
        radius = max(radii[k], radii[i])
        before, after = _split(c, v, -1)
        legs = (_inward(before, 1, radius), _inward(after, 0, radius))
        straight = [leg for leg in legs if _turn(_inward(b, e, radius), leg) <= TEE_STRAIGHT]
        if _turn(*legs) >= TEE_CORNER and straight:
            off = b.points[0 if e == 0 else -1] - c.points[v]
            if np.linalg.norm(off - (off @ straight[0]) * straight[0]) <= radius:
                return k, e, i, v
    return None


def _detached_side(branches: list) -> tuple | None:
    """``(k, e, i, v)``: branch ``k``'s open end ``e`` is a tee's side branch that stops short of the
    straight run ``i`` at its vertex ``v`` (see SIDE_GAP_RADII); ``None`` if there is none."""
    radii = [float(np.median(b.radius)) for b in branches]
    for k, e, i, v, s in _ends_beside(branches, max(radii, default=0.0) + SIDE_GAP_RADII * np.array(radii)):
        b, c = branches[k], branches[i]
        end, out = b.points[0 if e == 0 else -1], -_inward(b, e, radii[k])
        axis = c.points[v]
        if np.linalg.norm(axis - end) > radii[i] + SIDE_GAP_RADII * radii[k]:
            continue
        if min(s[v], s[-1] - s[v]) < END_DIRECTION_RADII[1] * radii[i]:
            continue  # near an end of c: an elbow or two ends, not a run
        before, after = _split(c, v, -1)
        legs = (_inward(before, 1, radii[i]), _inward(after, 0, radii[i]))
        ahead = float((axis - end) @ out)
        aim = float(np.linalg.norm(axis - end - ahead * out))
        if (_turn(*legs) < TEE_CORNER and ahead > 0 and aim <= radii[i]
                and abs(float(out @ legs[1])) <= np.cos(np.radians(TEE_CORNER))):
            return k, e, i, v
    return None


def _ends_beside(branches: list, reach: np.ndarray):
    """``(k, e, i, v, s)`` for each open end ``e`` of branch ``k`` and each other open branch ``i`` with a
    vertex within ``reach[k]`` of that end: ``v`` is i's vertex nearest the end, ``s`` i's arc lengths."""
    open_ends = [(k, e) for k, b in enumerate(branches) if not b.closed for e in (0, 1) if b.ends[e] is None]
    if not open_ends or len(branches) < 2:
        return
    owner = np.repeat(np.arange(len(branches)), [len(b.points) for b in branches])
    tree = cKDTree(np.vstack([b.points for b in branches]))
    for k, e in open_ends:
        end = branches[k].points[0 if e == 0 else -1]
        for i in np.unique(owner[np.asarray(tree.query_ball_point(end, reach[k]), int)]):
            c = branches[i]
            if i == k or c.closed:
                continue
            v = int(np.argmin(np.linalg.norm(c.points - end, axis=1)))
            yield k, e, int(i), v, polyline_arclength(c.points)


def _turn(into_before: np.ndarray, into_after: np.ndarray) -> np.ndarray:
    """Degrees by which a path turns where it goes from the way ``into_before`` points back along it
    to the way ``into_after`` points on (unit vectors, rows): 0 straight on, 180 turned back."""
    cos = np.einsum("...i,...i->...", into_before, into_after)
    return 180.0 - np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _inward(b: SkeletonBranch, end: int, radius: float) -> np.ndarray:
    """Unit direction from the branch's end ``end`` (0 or 1) into it (see END_DIRECTION_RADII)."""
    pts = b.points if end == 0 else b.points[::-1]
    s = polyline_arclength(pts)
    near, far = np.minimum(np.searchsorted(s, np.multiply(END_DIRECTION_RADII, radius)), len(pts) - 1)
    d = pts[far] - pts[near if near < far else 0]
    return d / max(float(np.linalg.norm(d)), 1e-300)


def _continues(first: tuple, second: tuple) -> bool:
    """Whether two (branch, end) meeting at a junction go on one from the other (see MAX_JOIN_TURN)."""
    radius = max(float(np.median(b.radius)) for b, _ in (first, second))
    return bool(_turn(_inward(*first, radius), _inward(*second, radius)) <= MAX_JOIN_TURN)


def _hairpins(branch: SkeletonBranch) -> list:
    """Vertices where an open branch turns back on itself between legs closer than a bend's.

    It turns by more than ``MAX_JOIN_TURN`` between its chords over ``END_DIRECTION_RADII`` of its
    (median) radius before and after the vertex, and those chords' far ends lie less than
    ``HAIRPIN_LEGS_RADII`` of the larger radius there apart across the legs.  Both legs reach past the
    chords: a short hook at an end is a fold of one tube (``quality.fold``), not two tubes.
    """
    if branch.closed:
        return []
    pts, radius = branch.points, float(np.median(branch.radius))
    s = polyline_arclength(pts)
    near, far = END_DIRECTION_RADII[0] * radius, END_DIRECTION_RADII[1] * radius
    inner = np.flatnonzero((s >= far) & (s[-1] - s >= far))
    if not len(inner):
        return []
    a = np.searchsorted(s, s[inner] - far)
    b = np.searchsorted(s, s[inner] + far)
    before = pts[a] - pts[np.searchsorted(s, s[inner] - near, side="right") - 1]
    after = pts[b] - pts[np.searchsorted(s, s[inner] + near)]
    before /= np.maximum(np.linalg.norm(before, axis=1, keepdims=True), 1e-300)
    after /= np.maximum(np.linalg.norm(after, axis=1, keepdims=True), 1e-300)
    turn = _turn(before, after)
    along = before + after
    along /= np.maximum(np.linalg.norm(along, axis=1, keepdims=True), 1e-300)
    apart = pts[a] - pts[b]
    across = np.linalg.norm(apart - np.einsum("ij,ij->i", apart, along)[:, None] * along, axis=1)
    local = np.maximum(branch.radius[a], branch.radius[b])
    tight = (turn > MAX_JOIN_TURN) & (across < HAIRPIN_LEGS_RADII * local)
    runs = np.split(np.arange(len(inner)), np.flatnonzero(np.diff(tight.astype(int))) + 1)
    return [int(inner[run[np.argmax(turn[run])]]) for run in runs if tight[run[0]]]


def _cut_hairpins(branch: SkeletonBranch) -> list:
    """The branch cut apart at its :func:`_hairpins`, less the vertices within ``END_DIRECTION_RADII[0]``
    of its radius of each cut (there the thin set bends from one piece into the other); the pieces get
    open ends at the cuts."""
    cuts = _hairpins(branch)
    if not cuts:
        return [branch]
    s = polyline_arclength(branch.points)
    keep = np.ones(len(s), bool)
    for k in cuts:
        keep &= np.abs(s - s[k]) >= END_DIRECTION_RADII[0] * float(np.median(branch.radius))
    pieces = np.split(np.arange(len(s)), np.flatnonzero(np.diff(keep.astype(int))) + 1)
    last = len(s) - 1
    return [SkeletonBranch(branch.points[p], branch.weights[p], branch.radius[p],
                           (branch.ends[0] if p[0] == 0 else None, branch.ends[1] if p[-1] == last else None))
            for p in pieces if keep[p[0]] and len(p) >= 2]


def with_ends_joined(skeleton: Skeleton, pairs, ends: dict | None = None) -> tuple[Skeleton, list]:
    """The skeleton with each pair ``((a, ea), (b, eb))`` of open ends joined: branch ``a`` goes on from
    its end ``ea`` into branch ``b`` at its end ``eb``, as one branch in ``a``'s place.

    For the two pieces of one tube: where the thin set broke along it, or two passes each found a part
    of it.  The vertices of ``b`` behind ``a``'s end (where the pieces overlap) are left out, so that
    the joined polyline does not double back.  No branch may be in more than one pair.

    ``ends`` may give, for ``(a, ea)``, the outward direction of that end to measure "behind" along
    (from its last vertex) -- a fitted spine's, surer than the thin set's own where it hooks at its end.
    (Not the fitted end's point: a fit grown far past its thin set would leave out the vertices between.)

    Returns
    -------
    Skeleton
    origin : list of int or None
        For each new branch, the index of the old branch it is unchanged from, or ``None`` (joined).
    """
    joined, taken = {}, set()
    for (a, ea), (b, eb) in pairs:
        if {a, b} & taken or a == b:
            raise ValueError(f"branches {a} and {b}: a branch can be joined only once")
        taken |= {a, b}
        first = skeleton.branches[a] if ea == 1 else _reversed(skeleton.branches[a])
        second = skeleton.branches[b] if eb == 0 else _reversed(skeleton.branches[b])
        if first.ends[1] is not None or second.ends[0] is not None:
            raise ValueError(f"branches {a} and {b}: only open ends can be joined")
        radius = max(float(np.median(first.radius)), float(np.median(second.radius)))
        out = (ends or {}).get((a, ea))
        out = -_inward(first, 1, radius) if out is None else out
        ahead = (second.points - first.points[-1]) @ out >= 0
        second = SkeletonBranch(second.points[ahead], second.weights[ahead], second.radius[ahead], second.ends)
        joined[a] = _joined(first, second) if ahead.any() else SkeletonBranch(
            first.points, first.weights, first.radius, (first.ends[0], second.ends[1]))
    branches, origin = [], []
    for i, branch in enumerate(skeleton.branches):
        if i in joined:
            branches.append(joined[i])
            origin.append(None)
        elif i not in taken:
            branches.append(branch)
            origin.append(i)
    return Skeleton(branches, skeleton.junctions, skeleton.link), origin


def _reversed(b: SkeletonBranch) -> SkeletonBranch:
    return SkeletonBranch(b.points[::-1], b.weights[::-1], b.radius[::-1], b.ends[::-1], b.closed)


def _joined(a: SkeletonBranch, c: SkeletonBranch) -> SkeletonBranch:
    """``a`` (ending at a junction) followed by ``c`` (starting there) as one branch.

    Where both end on the same graph node, that vertex is kept once, with the weight both copies carry
    (the node's points weigh on only one of them); where they end on different nodes of a merged
    junction, both vertices are kept.  Either way no thin point is lost.
    """
    if not np.array_equal(a.points[-1], c.points[0]):
        return SkeletonBranch(np.vstack([a.points, c.points]), np.r_[a.weights, c.weights],
                              np.r_[a.radius, c.radius], (a.ends[0], c.ends[1]))
    w = a.weights[-1] + c.weights[0]
    r = (a.weights[-1] * a.radius[-1] + c.weights[0] * c.radius[0]) / w if w > 0 else a.radius[-1]
    return SkeletonBranch(np.vstack([a.points, c.points[1:]]), np.r_[a.weights[:-1], w, c.weights[1:]],
                          np.r_[a.radius[:-1], r, c.radius[1:]], (a.ends[0], c.ends[1]))


def without_branches(skeleton: Skeleton, drop) -> tuple[Skeleton, list]:
    """The skeleton less the branches ``drop`` (indices, may be none), with the junctions left with fewer
    than three branch ends repaired.

    A junction left with two branch ends joins those branches into one where one goes on from the
    other (``MAX_JOIN_TURN``), else both ends are opened; a junction left with one end becomes an open
    end of that branch; with none it disappears.

    Returns
    -------
    Skeleton
    origin : list of int or None
        For each new branch, the index of the old branch it is unchanged from, or ``None``.
    """
    drop = {int(d) for d in drop}
    live = [(b, i) for i, b in enumerate(skeleton.branches) if i not in drop]
    while True:
        ends_at = {}
        for n, (b, _) in enumerate(live):
            for e, j in enumerate(b.ends):
                if j is not None:
                    ends_at.setdefault(j, []).append((n, e))
        opened = next((j for j, m in ends_at.items() if len(m) == 1 or (
            len(m) == 2 and m[0][0] != m[1][0] and not _continues(*[(live[n][0], e) for n, e in m]))), None)
        pair = next((j for j, m in ends_at.items() if len(m) == 2 and m[0][0] != m[1][0]), None)
        if opened is not None:
            for n, e in ends_at[opened]:
                b, _ = live[n]
                ends = list(b.ends)
                ends[e] = None
                live[n] = (SkeletonBranch(b.points, b.weights, b.radius, tuple(ends), b.closed), None)
        elif pair is not None:
            (n, en), (m, em) = ends_at[pair]
            a, c = live[n][0], live[m][0]
            a = _reversed(a) if en == 0 else a  # a now ends at the junction ...
            c = _reversed(c) if em == 1 else c  # ... and c starts there
            joined = _joined(a, c)
            live = [x for k, x in enumerate(live) if k not in (n, m)] + [(joined, None)]
        else:
            break
    return _renumbered([b for b, _ in live], skeleton), [i for _, i in live]


def with_ends_opened(skeleton: Skeleton, opened) -> Skeleton:
    """The skeleton with the branch ends ``opened`` (``(branch, end)`` pairs) made open ends; a junction
    left with one branch end opens it too, and one left with none disappears.  The branches keep their
    order and their points."""
    ends = [list(b.ends) for b in skeleton.branches]
    for i, e in opened:
        ends[i][e] = None
    count = np.bincount([j for es in ends for j in es if j is not None], minlength=len(skeleton.junctions))
    branches = [SkeletonBranch(b.points, b.weights, b.radius,
                               tuple(None if j is None or count[j] < 2 else j for j in es), b.closed)
                for b, es in zip(skeleton.branches, ends)]
    return _renumbered(branches, skeleton)


def _renumbered(branches: list, skeleton: Skeleton) -> Skeleton:
    """A skeleton of ``branches`` (whose ends index ``skeleton``'s junctions) with only the junctions
    they end at, numbered in order."""
    used = sorted({j for b in branches for j in b.ends if j is not None})
    renumber = {j: n for n, j in enumerate(used)}
    branches = [SkeletonBranch(b.points, b.weights, b.radius,
                               tuple(None if j is None else renumber[j] for j in b.ends), b.closed)
                for b in branches]
    junctions = skeleton.junctions[used] if used else np.empty((0, 3))
    return Skeleton(branches, junctions, skeleton.link)
