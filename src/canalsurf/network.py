"""Stage 6: branches and junctions as one result -- the network, its labels, mesh and model.json.

A scan of a tree, a vessel or a plant's pipe runs is a **network**: branches (each a pipe or canal
surface, the model of a single tube) that end at junctions or open ends, grouped into components
(networks that do not touch).  A single tube is a network of one branch.

* :class:`Network` -- the result of :func:`canalsurf.reconstruct`;
* :func:`classify_points` -- which branch each point lies on (or none) and its signed distance;
* :func:`network_mesh` -- one watertight mesh per component, the branch tubes united at the
  junctions by a robust mesh boolean (manifold3d);
* :func:`network_from_dict` -- ``model.json`` content (version 1 or 2) back to a :class:`Network`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from ._rows import workers
from .errors import InputError
from .model import FORMAT, CanalModel, model_from_dict, _plain
from .refine import footpoints
from .spine import curve_length, polyline_arclength, pspline_fit, sample_arclength

__all__ = ["Network", "Junction", "classify_points", "network_mesh", "network_from_dict",
           "NETWORK_VERSION", "n_branch_samples"]

NETWORK_VERSION = 2
#: Samples written per branch: at least this many ...
MIN_BRANCH_SAMPLES = 50
#: ... and no coarser than this share of the branch's mean radius apart.
SAMPLE_SPACING_PER_RADIUS = 0.5
#: Candidate branches per point in :func:`classify_points`: the branches of the nearest spine samples.
CLASSIFY_NEIGHBOURS = 16
#: Spine samples per branch radius in :func:`classify_points` (the candidates are then refined exactly).
CLASSIFY_SAMPLES_PER_RADIUS = 2.0
#: At a junction each tube of the mesh runs on this many of its radii past the junction point, so the
#: tubes overlap instead of touching face to face (a boolean of coplanar faces leaves slivers).
MESH_OVERLAP_RADII = 0.5


@dataclass
class Junction:
    """Where branch ends meet.

    Attributes
    ----------
    id : int
    point : ndarray, shape (3,)
    ends : list of (int, int)
        ``(branch id, end)`` of the branch ends that meet here; end 0 is the branch's ``t = 0``,
        end 1 its ``t = 1``.
    """

    id: int
    point: np.ndarray
    ends: list


@dataclass
class Network:
    """Tubes of a scan: branches between junctions and open ends.

    Attributes
    ----------
    branches : list of CanalModel
        One pipe or canal surface per branch (``.spine(t)``, ``.radius(t)``, ``.sample(n)``), with its
        ``id``, ``ends`` (the junction id at ``t = 0`` and ``t = 1``, or ``None``) and per-branch
        ``diagnostics`` (points, inlier RMS, angular coverage, ...).
    junctions : list of Junction
    parameters : dict
        The paper's parameters actually used, in the input's units.
    diagnostics : dict
        Whole-scan diagnostics, including ``no_tube_share``: the share of points on no tube.
    stages : dict, optional
        Intermediate clouds for figures; not saved.

    A network of one branch (a single tube) also answers ``kind``, ``spine``, ``radius``, ``closed``,
    ``sample`` and ``mean_radius`` as that branch does.
    """

    branches: list
    junctions: list = field(default_factory=list)
    parameters: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    stages: dict | None = field(default=None, repr=False, compare=False)

    # A single tube is a network of one branch: let it be used as that branch.
    def _single(self, name: str):
        if len(self.branches) != 1:
            raise AttributeError(f"a network of {len(self.branches)} branches has no single '{name}'; "
                                 "use .branches")
        return self.branches[0]

    kind = property(lambda self: self._single("kind").kind, doc="The single branch's kind.")
    spine = property(lambda self: self._single("spine").spine, doc="The single branch's spine.")
    radius = property(lambda self: self._single("radius").radius, doc="The single branch's radius.")
    closed = property(lambda self: self._single("closed").closed, doc="The single branch is a loop.")
    mean_radius = property(lambda self: self._single("mean_radius").mean_radius,
                           doc="The single branch's mean radius.")

    def sample(self, n: int | None = None):
        """The single branch's :meth:`CanalModel.sample`."""
        branch = self._single("sample")
        return branch.sample() if n is None else branch.sample(n)

    @property
    def components(self) -> list:
        """Branch ids of each connected network (branches joined through junctions), sorted."""
        parent = {b.id: b.id for b in self.branches}

        def find(u):
            while parent[u] != u:
                parent[u] = parent[parent[u]]
                u = parent[u]
            return u

        for j in self.junctions:
            ids = [b for b, _ in j.ends]
            for b in ids[1:]:
                parent[find(b)] = find(ids[0])
        groups = {}
        for b in sorted(parent):
            groups.setdefault(find(b), []).append(b)
        return sorted(groups.values())

    def classify(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Branch id of each point (-1: on no tube) and its signed distance from that branch's surface.

        See :func:`classify_points`.
        """
        from ._validate import as_points

        return classify_points(as_points(points, min_points=1), self.branches)

    def to_dict(self) -> dict:
        """The ``model.json`` content (version 2); timings are left out, as they vary by run."""
        branches = []
        for b in self.branches:
            data = b.to_dict(n_samples=n_branch_samples(b))
            branches.append({"id": int(b.id), "kind": data["kind"], "closed": data["spine"]["closed"],
                             "spine": data["spine"], "radius": data["radius"], "samples": data["samples"],
                             "ends": [None if e is None else int(e) for e in b.ends],
                             "diagnostics": data["diagnostics"]})
        return {
            "format": FORMAT,
            "version": NETWORK_VERSION,
            "branches": branches,
            "junctions": [{"id": int(j.id), "point": [float(x) for x in j.point],
                           "ends": [{"branch": int(b), "end": int(e)} for b, e in j.ends]}
                          for j in self.junctions],
            "components": self.components,
            "parameters": _plain(self.parameters),
            "diagnostics": _plain({k: v for k, v in self.diagnostics.items() if k != "seconds"}),
        }

    def save(self, path) -> None:
        """Write ``model.json`` atomically (a failed write leaves no partial file)."""
        from .io import write_json

        write_json(path, self.to_dict())


def n_branch_samples(branch: CanalModel) -> int:
    """Samples written for a branch: at least 50, no coarser than half its mean radius."""
    length = curve_length(branch.spine)
    return max(MIN_BRANCH_SAMPLES, math.ceil(length / (SAMPLE_SPACING_PER_RADIUS * branch.mean_radius)) + 1)


def classify_points(points: np.ndarray, branches: list, *, cut: list | None = None, far: bool = True
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Which branch each point lies on, and its signed distance from that branch's surface.

    The candidate branches of a point are those of its nearest spine samples, and any other branch whose
    surface may lie nearer (by the distance to its samples); on each candidate the exact footpoint gives
    ``|P - C(t)| - r(t)``, and the branch of the smallest absolute distance wins.
    A point farther from it than the branch's outlier cut (three robust deviations of the branch's
    own fit, at least 3 % of its radius) lies on no tube: label -1.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    branches : list of CanalModel
        Each with ``diagnostics["noise_sigma"]`` (the robust deviation of its fit), unless ``cut``.
    cut : list of float, optional
        Outlier cut per branch, overriding the one from the diagnostics.
    far : bool, default True
        Also find the nearest surface of the points that lie on no tube.  With False their distance is
        that from the nearest surface among the branches of their nearest samples only: the labels are
        the same, and a scan that is mostly clutter is labelled far faster.

    Returns
    -------
    label : ndarray of int, shape (N,)
        The branch's ``id``, or -1.
    distance : ndarray, shape (N,)
        Signed distance from the nearest branch surface (positive outside).
    """
    n = len(points)
    if not branches or n == 0:
        return np.full(n, -1), np.full(n, np.inf)
    samples, owner, reach = [], [], []
    for i, b in enumerate(branches):
        length = curve_length(b.spine)
        m = max(32, math.ceil(CLASSIFY_SAMPLES_PER_RADIUS * length / b.mean_radius))
        samples.append(sample_arclength(b.spine, m)[1])
        owner.append(np.full(m, i))
        # The spine is within half a sample step of a sample, the surface within the largest radius of
        # the spine: |P - C(t)| - r(t) >= (distance to the nearest sample) - reach.
        reach.append(length / (m - 1) / 2 + float(b.radius(np.linspace(0.0, 1.0, 2 * m)).max()))
    if len(branches) == 1:
        # Every point's one candidate: a search of the samples would only say so, at a cost.
        candidates = np.zeros((n, 1), np.intp)
    else:
        k = min(CLASSIFY_NEIGHBOURS, sum(len(s) for s in samples))
        _, idx = cKDTree(np.concatenate(samples)).query(points, k=k, workers=workers(len(points)))
        candidates = np.concatenate(owner)[idx.reshape(n, -1)]
    best = np.full(n, np.inf)
    distance = np.full(n, np.inf)
    label = np.full(n, -1)

    def try_branch(i, which):
        if not len(which):
            return
        b = branches[i]
        _, d = footpoints(points[which], b.spine, b.radius, closed=b.closed)
        better = np.abs(d) < best[which]
        best[which[better]] = np.abs(d[better])
        distance[which[better]] = d[better]
        label[which[better]] = i

    # The points of each candidate branch, in order: the rows of the transposed point-by-branch
    # incidence (a counting sort; sorting the (branch, point) pairs takes many times longer on a scene).
    width = candidates.shape[1]
    incidence = sparse.csr_matrix((np.ones(candidates.size, bool), candidates.ravel(),
                                   np.arange(0, candidates.size + 1, width)), shape=(n, len(branches))).T.tocsr()
    incidence.sum_duplicates()
    for i in range(len(branches)):
        try_branch(i, incidence.indices[incidence.indptr[i]:incidence.indptr[i + 1]])
    cuts = np.array(cut if cut is not None else [_branch_cut(b) for b in branches])
    # The nearest samples favour thin branches (sampled densely, and their spines lie nearer): a point on
    # a fat tube beside a thin one may see only the thin one's samples.  Every other branch whose
    # surface may lie nearer than the best so far is tried too, so the nearest surface of all is found;
    # the search is bounded by the largest cut for the points already on a tube.
    # Only points near a branch's samples are looked at for it: those within the bound of the ball
    # about the samples' box, found in a tree of the points; and, for the points on no tube, those
    # whose distance from the box (no more than from any sample) leaves the branch a chance.
    limit = float(np.max(cuts))
    lost = np.flatnonzero(best > limit) if far else np.empty(0, np.intp)
    # With one branch every point has tried it already (and a tree of a large scan is costly).
    others = range(len(branches)) if len(branches) > 1 else range(0)
    index = cKDTree(points) if others else None
    for i in others:
        low, high = samples[i].min(axis=0), samples[i].max(axis=0)
        ball = np.asarray(index.query_ball_point((low + high) / 2, np.linalg.norm(high - low) / 2 + reach[i] + limit),
                          dtype=np.intp)
        if far:
            ball = ball[best[ball] <= limit]
            lost = lost[best[lost] > limit]
            box = np.linalg.norm(np.maximum(np.maximum(low - points[lost], points[lost] - high), 0.0), axis=1)
            ball = np.concatenate([ball, lost[box - reach[i] < best[lost]]])
        ball = ball[~(candidates[ball] == i).any(axis=1)]
        if not len(ball):
            continue
        bound = np.where(best[ball] <= limit, reach[i] + limit, np.inf) if far else reach[i] + limit
        near = cKDTree(samples[i]).query(points[ball], workers=workers(len(ball)))[0]
        near[near > bound] = np.inf
        try_branch(i, np.sort(ball[near - reach[i] < best[ball]]))
    on = (label >= 0) & (best <= cuts[np.maximum(label, 0)])
    ids = np.array([b.id for b in branches])
    return np.where(on, ids[np.maximum(label, 0)], -1), distance


def _branch_cut(branch: CanalModel) -> float:
    """Outlier cut of a branch from its fit's robust deviation (see :func:`canalsurf.refine.outlier_cut`)."""
    from .constants import MIN_SIGMA_PER_RADIUS, OUTLIER_SIGMAS

    sigma = float(branch.diagnostics.get("noise_sigma", 0.0) or 0.0)
    return OUTLIER_SIGMAS * max(sigma, MIN_SIGMA_PER_RADIUS * branch.mean_radius)


def _overlapping(branch: CanalModel, overlap: tuple) -> tuple[BSpline, BSpline]:
    """The branch's spine and radius continued straight by ``overlap[e]`` (length) past end ``e``."""
    if not any(overlap):
        return branch.spine, branch.radius
    length = curve_length(branch.spine)
    a, b = -overlap[0] / length, 1 + overlap[1] / length
    n = 400
    t = np.linspace(a, b, n)
    inside = np.clip(t, 0.0, 1.0)
    d = branch.spine.derivative()(inside)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = branch.spine(inside) + ((t - inside) * length)[:, None] * d
    r = branch.radius(inside)
    s = polyline_arclength(pts)
    u = s / s[-1]
    segs = max(8, len(branch.spine.t) - 2 * branch.spine.k)
    return (pspline_fit(u, pts, n_segments=segs, smoothing=1e-9),
            pspline_fit(u, r, n_segments=max(4, len(branch.radius.t) - 2 * branch.radius.k), smoothing=1e-9))


def network_mesh(network: Network, *, caps: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """One triangle mesh of all tubes: per component the branch tubes united at the junctions.

    Open ends are capped (unless ``caps`` is false); at a junction each tube runs on past the
    junction point so the tubes overlap, and their union (manifold3d, exact and robust) is watertight
    and outward-oriented.  A single branch needs no union.

    Returns
    -------
    vertices : ndarray, shape (V, 3)
    faces : ndarray of int, shape (F, 3)
    """
    from .surface import surface_mesh

    meshes = []
    for component in network.components:
        parts = []
        for bid in component:
            b = next(x for x in network.branches if x.id == bid)
            overlap = tuple(0.0 if e is None else MESH_OVERLAP_RADII * _max_radius_at(network, e)
                            for e in b.ends)
            spine, radius = _overlapping(b, overlap) if not b.closed else (b.spine, b.radius)
            parts.append(surface_mesh(spine, radius, closed=b.closed, caps=caps or any(overlap)))
        meshes.append(parts[0] if len(parts) == 1 else _union(parts))
    offset = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    vertices = np.concatenate([v for v, _ in meshes])
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, offset)])
    return vertices, faces


def _max_radius_at(network: Network, junction_id: int) -> float:
    j = next(x for x in network.junctions if x.id == junction_id)
    return max(float(network.branches[_index(network, b)].radius(float(e))) for b, e in j.ends)


def _index(network: Network, branch_id: int) -> int:
    return next(i for i, b in enumerate(network.branches) if b.id == branch_id)


def _union(parts: list) -> tuple[np.ndarray, np.ndarray]:
    """Boolean union of closed triangle meshes with manifold3d, in double precision about their centre."""
    try:
        import manifold3d
    except ImportError:  # pragma: no cover -- a core dependency
        raise InputError("uniting the tubes of a network needs manifold3d — pip install manifold3d") from None
    centre = np.mean([v.mean(axis=0) for v, _ in parts], axis=0)
    solids = [manifold3d.Manifold(manifold3d.Mesh64(
        vert_properties=np.ascontiguousarray(v - centre, dtype=np.float64),
        tri_verts=np.ascontiguousarray(f, dtype=np.uint64))) for v, f in parts]
    union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add)
    mesh = union.to_mesh64()
    return (np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3] + centre,
            np.asarray(mesh.tri_verts, dtype=np.int64))


def network_from_dict(data: dict, source: str = "model") -> Network:
    """A :class:`Network` from ``model.json`` content: version 2, or version 1 (one branch)."""
    if isinstance(data, dict) and data.get("format") == FORMAT:
        version = data.get("version")
        if type(version) is int and version == NETWORK_VERSION:
            return _network_v2(data, source)
        if not (type(version) is int and version == 1):
            raise InputError(f"{source}: model version {json.dumps(version)} is not supported (this canalsurf reads "
                             f"versions 1 and {NETWORK_VERSION}) — re-run the reconstruction")
    model = model_from_dict(data, source)
    network = Network([model], [], dict(model.parameters), dict(model.diagnostics))
    model.diagnostics = {}  # a version 1 file's diagnostics are the scan's, kept once
    return network


def _whole(value) -> bool:
    return type(value) is int


def _network_v2(data: dict, source: str) -> Network:
    def bad(what):
        return InputError(f"{source}: corrupted model ({what}) — re-run the reconstruction")

    branches_data, junctions_data = data.get("branches"), data.get("junctions", [])
    if not isinstance(branches_data, list) or not branches_data or not isinstance(junctions_data, list):
        raise bad("no list of branches")
    branches = []
    for i, item in enumerate(branches_data):
        if not isinstance(item, dict):
            raise bad(f"branch {i} is not an object")
        as_v1 = {"format": FORMAT, "version": 1, "kind": item.get("kind"), "spine": item.get("spine"),
                 "radius": item.get("radius"), "parameters": {}, "diagnostics": item.get("diagnostics") or {}}
        model = model_from_dict(as_v1, f"{source}: branch {i}")
        ends = item.get("ends", [None, None])
        if not isinstance(ends, list) or len(ends) != 2 or any(e is not None and not _whole(e) for e in ends):
            raise bad(f"branch {i} ends")
        if not _whole(item.get("id", i)) or item.get("id", i) != i:
            raise bad(f"branch {i} has id {item.get('id')!r}")
        if item.get("closed", model.closed) is not model.closed or (model.closed and ends != [None, None]):
            raise bad(f"branch {i}: closed disagrees with its spine or its ends")
        model.id, model.ends = i, tuple(ends)
        branches.append(model)
    junctions = []
    for i, item in enumerate(junctions_data):
        try:
            point = np.asarray(item["point"], dtype=float)
            ends = [(e["branch"], e["end"]) for e in item["ends"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise bad(f"junction {i}: {exc}") from None
        if (point.shape != (3,) or not np.isfinite(point).all() or item.get("id", i) != i or not ends
                or any(not (_whole(b) and _whole(e) and 0 <= b < len(branches) and e in (0, 1))
                       for b, e in ends)):
            raise bad(f"junction {i}")
        junctions.append(Junction(i, point, ends))
    named = sorted((b.id, e) for b in branches for e, j in enumerate(b.ends) if j is not None)
    listed = sorted(end for j in junctions for end in j.ends)
    if named != listed or any(branches[b].ends[e] != j.id for j in junctions for b, e in j.ends):
        raise bad("the junctions' branch ends and the branches' junctions disagree")
    parameters, diagnostics = data.get("parameters", {}), data.get("diagnostics", {})
    if not isinstance(parameters, dict) or not isinstance(diagnostics, dict):
        raise bad("parameters or diagnostics are not objects")
    return Network(branches, junctions, dict(parameters), dict(diagnostics))
