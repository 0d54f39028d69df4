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

__all__ = ["closest_point_distance", "paper_distance", "radius_error", "compare", "angular_coverage"]

#: Samples per curve for the distance measures (dense enough that sampling error is < 1e-4 length).
N_DENSE = 20000
#: Points per stretch of spine for the angular coverage: with 100 points spread all around, the largest
#: angular gap is about 2 pi ln(100) / 100, i.e. a full scan reads about 340 degrees.
COVERAGE_POINTS = 100


def angular_coverage(points: np.ndarray, spine, t: np.ndarray) -> np.ndarray:
    """Degrees of the circumference covered by the points around each stretch of the spine.

    The spine is cut into stretches of about ``COVERAGE_POINTS`` points each; in each, the points'
    directions from their footpoints ``C(t_i)`` are taken as angles around the stretch's mid tangent,
    and the coverage is 360 degrees less the widest empty angle.

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
    n_bins = len(points) // COVERAGE_POINTS
    if n_bins == 0:
        return np.empty(0)
    # Stretches of equal point count, so each has enough points whatever the density.
    order = np.argsort(t, kind="stable")
    bins = np.empty(len(t), int)
    bins[order] = np.arange(len(t)) * n_bins // len(t)
    mid = np.array([np.median(t[bins == b]) for b in range(n_bins)])
    tangent = spine.derivative()(mid)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    helper = np.where(np.abs(tangent[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = np.cross(tangent, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(tangent, e1)
    d = points - spine(t)
    angle = np.arctan2(np.einsum("ij,ij->i", d, e2[bins]), np.einsum("ij,ij->i", d, e1[bins]))
    cover = np.empty(n_bins)
    for b in range(n_bins):
        a = np.sort(angle[bins == b])
        widest = np.max(np.diff(np.concatenate([a, [a[0] + 2 * np.pi]])))
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
