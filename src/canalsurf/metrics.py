"""Accuracy measures against ground truth, and the surface residual.

* :func:`closest_point_distance` -- the geometric (parameter-free) distance between two curves: from
  each point of one to the nearest point of the other, both directions.  This is the honest spine error.
* :func:`paper_distance` -- the paper's ``|C(t) - C_a(t)|`` at equal parameters, both curves
  parameterised by normalised arc length on [0, 1] (and the reconstruction's direction matched to the
  truth).  It mixes position error with parameterisation drift, so it is much larger.
* :func:`radius_error` -- radius difference at corresponding spine points (nearest reconstructed spine
  point to each true spine point).
* :func:`angular_coverage` -- how much of the circumference the scan saw around each stretch of the
  spine (360 degrees all around; 180 - 270 for a scan from one side).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .spine import sample_arclength

__all__ = ["model_error", "closest_point_distance", "paper_distance", "radius_error", "compare", "compare_network",
           "angular_coverage"]

#: Samples per curve for the distance measures (dense enough that sampling error is < 1e-4 length).
N_DENSE = 20000
#: Points per stretch of spine for the angular coverage: with 100 points spread all around, the largest
#: angular gap is about 2 pi ln(100) / 100, i.e. a full scan reads about 340 degrees.
COVERAGE_POINTS = 100
#: The widest angle holding at most this share of a stretch's points counts as unseen: with 100 points
#: the two most isolated may stray across it (noise at the edge of a one-sided scan, a stray point).
COVERAGE_STRAY_SHARE = 0.02


def _around(points: np.ndarray, spine, t: np.ndarray, per_stretch: int):
    """Stretch index and angle around the spine of each point.

    The spine is cut into stretches of about ``per_stretch`` points each (equal counts, whatever the
    density); in each, angles are measured around the stretch's mid tangent -- one frame per stretch,
    so that they do not turn with the noise of each point's own tangent.

    Returns
    -------
    bins : ndarray of int, shape (N,)
    angle : ndarray, shape (N,)
        In (-pi, pi].
    n_bins : int
        Number of stretches (0 when there are fewer than ``per_stretch`` points).
    """
    n_bins = len(points) // per_stretch
    if n_bins == 0:
        return np.empty(0, int), np.empty(0), 0
    order = np.argsort(t, kind="stable")
    bins = np.empty(len(t), int)
    bins[order] = np.arange(len(t)) * n_bins // len(t)
    mid = _sorted_medians(t[order], np.bincount(bins, minlength=n_bins))
    tangent = spine.derivative()(mid)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    helper = np.where(np.abs(tangent[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = np.cross(tangent, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(tangent, e1)
    d = points - spine(t)
    angle = np.arctan2(np.einsum("ij,ij->i", d, e2[bins]), np.einsum("ij,ij->i", d, e1[bins]))
    return bins, angle, n_bins


def _sorted_medians(values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The median of each run of ``counts`` consecutive sorted ``values`` (each run at least one long), as
    ``np.median`` gives it: the middle value, or the mean of the two middle ones."""
    start = np.cumsum(counts) - counts
    low, high = values[start + (counts - 1) // 2], values[start + counts // 2]
    return np.where(counts % 2 == 1, low, (low + high) / 2)


def angular_coverage(points: np.ndarray, spine, t: np.ndarray) -> np.ndarray:
    """Degrees of the circumference covered by the points around each stretch of the spine.

    The spine is cut into stretches of about ``COVERAGE_POINTS`` points each; in each, the points'
    directions from their footpoints ``C(t_i)`` are taken as angles around the stretch's mid tangent,
    and the coverage is 360 degrees less the widest angle that holds at most ``COVERAGE_STRAY_SHARE``
    of them (a few scattered points do not make a one-sided scan look seen all round).

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    spine : callable
        C(t) on [0, 1] (a BSpline).
    t : ndarray, shape (N,)
        Footpoint parameter of each point.

    Returns
    -------
    ndarray
        Coverage in degrees per stretch, along the spine (empty when there are too few points).
    """
    bins, angle, n_bins = _around(points, spine, t, COVERAGE_POINTS)
    if n_bins == 0:
        return np.empty(0)
    cover = np.empty(n_bins)
    by_bin = angle[np.lexsort((angle, bins))]
    ends = np.cumsum(np.bincount(bins, minlength=n_bins))
    for b in range(n_bins):
        a = by_bin[ends[b - 1] if b else 0:ends[b]]
        m = int(COVERAGE_STRAY_SHARE * len(a))
        around = np.concatenate([a, a[: m + 1] + 2 * np.pi])
        widest = np.max(around[m + 1: m + 1 + len(a)] - around[: len(a)])
        cover[b] = 360.0 - np.degrees(widest)
    return cover


def closest_point_distance(a, b, n: int = N_DENSE) -> dict:
    """Closest-point distances between curves ``a`` and ``b`` (callables on [0, 1]).

    Returns
    -------
    dict
        ``mean``, ``max`` over both directions, and ``a_to_b_max``, ``b_to_a_max`` (the latter shows
        whether ``a`` is covered by ``b``: a reconstruction that stops short of an end has a large
        ``truth_to_model`` maximum).
    """
    _, pa = sample_arclength(a, n)
    _, pb = sample_arclength(b, n)
    dab = cKDTree(pb).query(pa)[0]
    dba = cKDTree(pa).query(pb)[0]
    return {"mean": float(max(dab.mean(), dba.mean())), "max": float(max(dab.max(), dba.max())),
            "a_to_b_max": float(dab.max()), "b_to_a_max": float(dba.max())}


def paper_distance(truth, model, n: int = 2000) -> dict:
    """The paper's spine distance ``|C(t) - C_a(t)|``, both curves by arc length on [0, 1].

    The reconstruction may run the other way; the direction giving the smaller mean is used.
    """
    _, pt = sample_arclength(truth, n)
    _, pm = sample_arclength(model, n)
    best = min((np.linalg.norm(pt - q, axis=1) for q in (pm, pm[::-1])), key=np.mean)
    return {"mean": float(best.mean()), "max": float(best.max())}


def radius_error(truth_spine, truth_radius, model_spine, model_radius, n: int = 2000) -> dict:
    """Radius error at corresponding spine points.

    For each of ``n`` true spine points (even in arc length) the nearest point of the reconstructed
    spine is found and the radii there compared.

    Returns
    -------
    dict
        ``mean`` and ``max`` absolute difference.
    """
    tt, pt = sample_arclength(truth_spine, n)
    tm, pm = sample_arclength(model_spine, 4 * n)
    _, j = cKDTree(pm).query(pt)
    diff = np.abs(truth_radius(tt) - model_radius(tm[j]))
    return {"mean": float(diff.mean()), "max": float(diff.max())}


def compare(model, truth) -> dict:
    """All accuracy figures of ``model`` against a :class:`~canalsurf.synth.SyntheticTube`.

    Figures are absolute; ``mean_radius`` (the truth's, along its spine) is returned for scaling.
    """
    cp = closest_point_distance(truth.spine, model.spine)
    _, r = sample_arclength(truth.spine, 2000)
    return {
        "mean_radius": float(np.mean(truth.radius(sample_arclength(truth.spine, 2000)[0]))),
        "spine_mean": cp["mean"], "spine_max": cp["max"], "coverage_gap": cp["a_to_b_max"],
        "paper": paper_distance(truth.spine, model.spine),
        "radius": radius_error(truth.spine, truth.radius, model.spine, model.radius),
    }


#: Branch parts within this many of the branch's radii of a junction are left out of the network
#: accuracy figures: there the surface belongs to several tubes at once.
JUNCTION_MARGIN_RADII = 2.5
#: A true spine point is covered when the model's spine passes within this share of the radius.
COVERED_RADII = 0.5
#: Samples per radius of spine length in :func:`compare_network` (distances to the nearest sample
#: are then at most 1/400 of the radius above those to the curve).
NETWORK_SAMPLES_PER_RADIUS = 200


def _dense_branch(spine, radius, junctions, ends):
    """Arc-length samples of a branch, its radius there, and which lie away from its junctions."""
    r_mean = float(np.mean(radius(np.linspace(0.0, 1.0, 64))))
    length = float(np.linalg.norm(np.diff(spine(np.linspace(0.0, 1.0, 2001)), axis=0), axis=1).sum())
    t, pts = sample_arclength(spine, max(200, int(NETWORK_SAMPLES_PER_RADIUS * length / r_mean)))
    away = np.ones(len(t), bool)
    for j in ends:
        if j is not None:
            away &= np.linalg.norm(pts - junctions[j], axis=1) > JUNCTION_MARGIN_RADII * r_mean
    return t, pts, radius(t), away, r_mean


def _nearest_on_average(pts: np.ndarray, trees: list, boxes: np.ndarray) -> int:
    """Index of the tree whose points lie nearest to ``pts`` on average (the first such on a tie).

    A point lies at least as far from a tree's points as from their bounding box, so trees are tried
    in order of that bound, and those whose bound exceeds the best mean so far are never queried.
    """
    gap = np.maximum(np.maximum(boxes[:, None, 0] - pts, pts - boxes[:, None, 1]), 0.0)
    bound = np.linalg.norm(gap, axis=2).mean(axis=1)
    mean_d = np.full(len(trees), np.inf)
    for k in np.argsort(bound, kind="stable"):
        if bound[k] > mean_d.min():
            break
        mean_d[k] = trees[k].query(pts)[0].mean()
    return int(np.argmin(mean_d))


def compare_network(network, truth) -> dict:
    """Accuracy of a reconstructed network against a :class:`~canalsurf.synth.SyntheticNetwork`.

    Each true branch is matched to the model branch its samples (away from junctions) lie nearest to
    on average.  Per true branch, away from its junctions (beyond ``JUNCTION_MARGIN_RADII`` of its
    radii): closest-point spine distance both ways (mean and max), radius error at corresponding
    points, and the share of its whole true spine within ``COVERED_RADII`` radii of the matched model
    spine.  Per true junction, the nearest model junction, its distance and whether the same branches
    meet there.  Finally the point labels of ``network.classify``.

    Returns
    -------
    dict
        ``branches`` (list of dicts, figures relative to the branch's mean radius), ``matched`` (model
        branch id of each true branch), ``one_to_one``, ``junctions`` (list of dicts), ``clutter_right``
        (share of clutter points labelled -1), ``tube_right`` (share of tube points on their branch).
    """
    tj = np.asarray(truth.junctions).reshape(-1, 3)
    mj = np.array([j.point for j in network.junctions]).reshape(-1, 3)
    model = []
    for b in network.branches:
        t, pts, r, away, r_mean = _dense_branch(b.spine, b.radius, mj, b.ends)
        model.append((pts, r, away))
    trees = [cKDTree(pts) for pts, _, _ in model]
    boxes = np.array([(pts.min(axis=0), pts.max(axis=0)) for pts, _, _ in model]).reshape(-1, 2, 3)
    branches, matched = [], []
    for tb in truth.branches:
        t, pts, r, away, r_mean = _dense_branch(tb.spine, tb.radius, tj, tb.ends)
        m = _nearest_on_average(pts[away], trees, boxes)
        matched.append(network.branches[m].id)
        d_all, near_all = trees[m].query(pts)
        d_tm, near = d_all[away], near_all[away]
        m_pts, m_r, m_away = model[m]
        # Model samples away from its junctions that lie opposite this branch's interior.
        d_mt, back = cKDTree(pts).query(m_pts[m_away])
        opposite = away[back]
        branches.append({
            "radius": r_mean,
            "spine_mean": max(d_tm.mean(), d_mt[opposite].mean() if opposite.any() else 0.0) / r_mean,
            "spine_max": max(d_tm.max(), d_mt[opposite].max() if opposite.any() else 0.0) / r_mean,
            "radius_mean": float(np.abs(m_r[near] - r[away]).mean()) / r_mean,
            "covered": float(np.mean(d_all <= COVERED_RADII * r_mean)),
        })
    junctions = []
    for j, point in enumerate(tj):
        meeting = sorted(matched[b] for b, tb in enumerate(truth.branches) for e in tb.ends if e == j)
        largest = max(float(np.max(tb.radius(np.linspace(0, 1, 64)))) for tb in truth.branches if j in tb.ends)
        if len(mj) == 0:
            junctions.append({"distance": np.inf, "largest_radius": largest, "same_branches": False})
            continue
        k = int(np.argmin(np.linalg.norm(mj - point, axis=1)))
        found = sorted(b for b, _ in network.junctions[k].ends)
        junctions.append({"distance": float(np.linalg.norm(mj[k] - point)), "largest_radius": largest,
                          "same_branches": found == meeting})
    label, _ = network.classify(truth.points)
    clutter = truth.label < 0
    expected = np.array(matched)[np.maximum(truth.label, 0)]
    return {
        "branches": branches, "matched": matched, "one_to_one": len(set(matched)) == len(matched),
        "junctions": junctions,
        "clutter_right": float(np.mean(label[clutter] < 0)) if clutter.any() else 1.0,
        "tube_right": float(np.mean(label[~clutter] == expected[~clutter])),
    }


#: Samples per model branch in :func:`model_error` (the truth is sampled with N_DENSE).
MODEL_ERROR_SAMPLES = 2000


def model_error(network, truth_branches, truth_junctions=()) -> list:
    """How far each branch of a model lies from the truth: the model's own claims checked.

    Each model branch is sampled densely; every sample is matched to the nearest point of any true
    spine, and its distance and radius error there are taken relative to the true radius.  Samples
    within ``JUNCTION_MARGIN_RADII`` radii of a model or true junction are left out.

    Parameters
    ----------
    network : Network
    truth_branches : list
        Objects with ``spine`` and ``radius`` (``SyntheticBranch``, ``SyntheticTube``).
    truth_junctions : array_like, shape (J, 3)

    Returns
    -------
    list of dict
        Per model branch: ``id``, ``quality``, ``spine_mean`` and ``spine_max`` (distances in true radii),
        ``radius_mean`` (mean relative radius error); NaN when all of a branch is near junctions; its
        ``kind``, and ``true_kind``: that of the true branch most of it lies along ("pipe" where its
        radius is constant, else "canal").
    """
    dense = []
    for tb in truth_branches:
        t, pts = sample_arclength(tb.spine, N_DENSE)
        dense.append((pts, tb.radius(t)))
    tree = cKDTree(np.concatenate([p for p, _ in dense]))
    true_r = np.concatenate([r for _, r in dense])
    owner = np.repeat(np.arange(len(dense)), [len(p) for p, _ in dense])
    true_kind = ["pipe" if np.ptp(tb.radius.c) == 0 else "canal" for tb in truth_branches]
    junctions = np.concatenate([np.asarray(truth_junctions, float).reshape(-1, 3),
                                np.array([j.point for j in network.junctions]).reshape(-1, 3)])
    out = []
    for b in network.branches:
        t, pts = sample_arclength(b.spine, MODEL_ERROR_SAMPLES)
        d, i = tree.query(pts)
        r_true = true_r[i]
        away = np.ones(len(t), bool)
        for j in junctions:
            away &= np.linalg.norm(pts - j, axis=1) > JUNCTION_MARGIN_RADII * r_true
        rel = d[away] / r_true[away]
        rad = np.abs(b.radius(t[away]) - r_true[away]) / r_true[away]
        nan = float("nan")
        out.append({"id": b.id, "quality": b.diagnostics.get("quality"),
                    "spine_mean": float(rel.mean()) if away.any() else nan,
                    "spine_max": float(rel.max()) if away.any() else nan,
                    "radius_mean": float(rad.mean()) if away.any() else nan,
                    "kind": b.kind, "true_kind": true_kind[np.bincount(owner[i]).argmax()]})
    return out


#: Angular sectors and points per stretch of :func:`roundness`.
ROUNDNESS_SECTORS = 8
ROUNDNESS_POINTS = 200
#: A cell needs this many points for its median residual to count.
ROUNDNESS_MIN_CELL = 5


def roundness(points: np.ndarray, spine, t: np.ndarray, residual: np.ndarray) -> float:
    """RMS of the median residual per cell of (stretch along the spine, sector around it), less noise.

    On a tube the residuals are noise and each cell's median is near 0; on a shape that is not round
    in cross-section (a box, a duct, a flattened or doubled cloud) whole sectors lie systematically
    outside or inside the fitted circle.  Stretches hold about ``ROUNDNESS_POINTS`` points each.

    Returns
    -------
    float
        In the units of ``residual`` (divide by the radius for a share); 0 with too few points.
    """
    bins, angle, n_bins = _around(points, spine, t, ROUNDNESS_POINTS)
    if n_bins == 0:
        return 0.0
    sector = np.minimum(((angle + np.pi) / (2 * np.pi) * ROUNDNESS_SECTORS).astype(int), ROUNDNESS_SECTORS - 1)
    cell = bins * ROUNDNESS_SECTORS + sector
    counts = np.unique(cell, return_counts=True)[1]
    medians = _sorted_medians(residual[np.lexsort((residual, cell))], counts)
    medians, counts = medians[counts >= ROUNDNESS_MIN_CELL], counts[counts >= ROUNDNESS_MIN_CELL]
    if not len(medians):
        return 0.0
    # Noise alone leaves each cell's median off by about sqrt(pi / 2) sigma / sqrt(n): what is left
    # after taking that out is the shape's own departure from round (a sparse, noisy scan's cells would
    # otherwise read as out of round).
    sigma = 1.4826 * np.median(np.abs(residual - np.median(residual)))
    excess = np.mean(np.square(medians)) - np.mean(np.pi / 2 * sigma**2 / counts)
    return float(np.sqrt(max(excess, 0.0)))
