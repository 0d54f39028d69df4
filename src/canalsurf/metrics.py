"""Accuracy measures against ground truth, and the surface residual.

* :func:`closest_point_distance` -- the geometric (parameter-free) distance between two curves: from
  each point of one to the nearest point of the other, both directions.  This is the honest spine error.
* :func:`paper_distance` -- the paper's ``|C(t) - C_a(t)|`` at equal parameters, both curves
  parameterised by normalised arc length on [0, 1] (and the reconstruction's direction matched to the
  truth).  It mixes position error with parameterisation drift, so it is much larger.
* :func:`radius_error` -- radius difference at corresponding spine points (nearest reconstructed spine
  point to each true spine point).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .spine import sample_arclength

__all__ = ["closest_point_distance", "paper_distance", "radius_error", "compare"]

#: Samples per curve for the distance measures (dense enough that sampling error is < 1e-4 length).
N_DENSE = 20000


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
