"""The whole reconstruction: normals -> shrinking -> MLS thinning -> ordering/spine -> radius -> refinement.

The input is first moved to its centroid and scaled to unit RMS size, so no stage sees georeferenced
coordinates or a particular unit; the model is mapped back at the end and every parameter is reported in
the input's units.
"""

from __future__ import annotations

import logging
import time
from contextlib import contextmanager

import numpy as np
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from . import constants as C
from ._validate import as_normals, as_points, choice, in_range, positive
from .errors import InputError, ReconstructionError
from .metrics import angular_coverage
from .model import CanalModel
from .normals import estimate_normals
from .order import order_curve
from .radius import curvature_radius, pipe_radius, prefer_canal
from .refine import footpoints, is_stray, outlier_cut, refine as refine_fit, robust_sigma
from .shrink import shrink, shrink_by_concentration
from .spine import constant_spline, pspline_fit
from .thin import mls_thin

__all__ = ["reconstruct", "STAGES"]

#: Stage names, in the order ``progress`` reports them.
STAGES = ("normals", "shrink", "thin", "order", "radius", "refine", "residual")

log = logging.getLogger(__name__)

#: A cloud whose RMS distance from the fitted surface exceeds this share of the radius is not a tube.
MAX_RELATIVE_RESIDUAL = 0.25


class _Timer(dict):
    """Seconds per stage; tells ``progress`` (if any) when a stage starts."""

    def __init__(self, progress=None):
        super().__init__()
        self.progress = progress

    @contextmanager
    def __call__(self, stage):
        if self.progress is not None:
            self.progress(stage)
        start = time.perf_counter()
        yield
        self[stage] = round(time.perf_counter() - start, 4)


def _segments(length: float, spacing: float, n_points: int) -> int:
    """Knot intervals: one per ``spacing`` of length, but enough points per interval."""
    return int(max(1, min(round(length / spacing), n_points // C.POINTS_PER_SEGMENT)))


def reconstruct(points, *, normals=None, kind: str = "auto", R: float | None = None,
                delta: float | None = None, mu: float | None = None, tau: float | None = None,
                H: float | None = None, k: int | None = None, stop: str = "auto",
                neighbours: str = "kdtree", refine: bool = True, progress=None) -> CanalModel:
    """Reconstruct a pipe or canal surface from an unorganized point cloud.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The scan.  Any units and placement.
    normals : array_like, shape (N, 3), optional
        Outward unit normals.  Estimated (regression planes, oriented outward) when not given.
    kind : {"auto", "pipe", "canal"}
        ``"pipe"``: constant radius, Algorithm 1.  ``"canal"``: radius function, Algorithm 2.
        ``"auto"``: Algorithm 2, then a pipe unless a radius function is clearly better.
    R, delta, mu, tau, H : float, optional
        The paper's parameters: neighbour radius, shrink step, break portion, canal normal tolerance,
        MLS weighting radius.  Defaults derive from a first radius estimate ``r0`` (median inverse
        principal curvature): ``R = max(0.2 r0, 3 x collapsed spacing)``, ``delta = r0 / 20``,
        ``mu = 0.7`` (pipe) or ``0.98`` (canal, auto stop), ``tau = cos 80 deg``, ``H = 0.6 r0``.
    k : int, optional
        Neighbours of the normal estimation (default 16).
    stop : {"auto", "paper"}
        ``"paper"`` uses only the printed ``mu`` rule (which can fail to stop); ``"auto"`` adds the
        peak / patience rules, and falls back on :func:`~canalsurf.shrink.shrink_by_concentration`
        when too few points meet the other side of the tube (a scan from one side).
    neighbours : {"kdtree", "gauss"}
        Neighbour search of the shrinking: KD-tree pairs, or the paper's Gauss-map grouping.
    refine : bool
        Fit spine and radius to all points after the paper's pipeline (default).  ``False`` returns the
        paper's own result: spline through the thin set, Eq. (6) or the fitted ``r_i``.
    progress : callable, optional
        Called with the name of each stage (``"normals"``, ``"shrink"``, ``"thin"``, ``"order"``,
        ``"radius"``, ``"refine"``) as it starts.

    Returns
    -------
    CanalModel

    Raises
    ------
    InputError
        Invalid points or parameters.
    ReconstructionError
        The points are valid but do not form a tube the method can follow.

    Examples
    --------
    >>> import canalsurf
    >>> tube = canalsurf.make_tube("fig9-pipe", rng=1)
    >>> model = canalsurf.reconstruct(tube.points)
    >>> model.kind, round(model.mean_radius, 1)
    ('pipe', 1.0)
    """
    timer = _Timer(progress)
    raw = as_points(points)
    kind = choice(kind, "kind", ("auto", "pipe", "canal"))
    stop = choice(stop, "stop", ("auto", "paper"))
    neighbours = choice(neighbours, "neighbours", ("kdtree", "gauss"))
    R, delta, H = positive(R, "R"), positive(delta, "delta"), positive(H, "H")
    mu = in_range(mu, "mu", 0.0, 1.0)
    tau = in_range(tau, "tau", -1.0, 1.0)
    if k is not None and not (3 <= int(k) <= len(raw)):
        raise InputError(f"k must be between 3 and the number of points ({len(raw)}), got {k!r}")

    origin = raw.mean(axis=0)
    scale = float(np.sqrt(((raw - origin) ** 2).sum(axis=1).mean()))
    if not scale > 0:
        raise InputError("all points are identical — give a scan of a tube")
    pts = (raw - origin) / scale
    if np.linalg.svd(pts[:: max(1, len(pts) // 5000)], compute_uv=False)[-1] < 1e-9 * np.sqrt(len(pts)):
        raise InputError("the points are coplanar or collinear — a tube needs a 3D scan")

    given = None if normals is None else as_normals(normals, len(pts))
    # A large scan is worked on through seeded random subsets (they keep its density pattern): the
    # paper's stages see MAX_SHRINK_POINTS (more for a long, thin tube) -- k-nearest-neighbour normals
    # and curvature get noisier, not better, as the density grows -- and the final fit at most
    # MAX_FIT_POINTS, a superset from the same draw.  At most MAX_RESIDUAL_POINTS of them are measured against the result.
    all_pts, all_given = pts, given
    draw = np.random.default_rng(0).permutation(len(pts)) if len(pts) > C.MAX_SHRINK_POINTS else None
    fit_pts = all_pts if draw is None else all_pts[np.sort(draw[: C.MAX_FIT_POINTS])]
    if draw is not None:
        pick = np.sort(draw[: C.MAX_SHRINK_POINTS])
        pts = pts[pick]
        given = None if given is None else given[pick]

    with timer("normals"):
        for attempt in range(2):
            tree = cKDTree(pts)
            nrm = estimate_normals(pts, k=k, tree=tree) if given is None else given
            r0 = curvature_radius(pts, nrm, tree=tree)
            dist, nbr = tree.query(pts, k=min(C.NORMAL_NEIGHBOURS, len(pts)), workers=-1)
            dk = dist[:, -1]
            # Mean area per point is pi d_k^2 / k for the k-th neighbour distance d_k.
            area_per_point = np.pi * np.mean(dk**2) / C.NORMAL_NEIGHBOURS
            if draw is None or attempt or not np.isfinite(r0):
                break
            # A long, thin tube spreads a fixed-size subset too thinly around its circumference: take
            # more of the draw (once) so the subset is as dense, relative to the radius, as a usual one.
            wanted = area_per_point / (C.MAX_SPACING_PER_RADIUS * r0) ** 2 * len(pts)
            grown = int(min(wanted, C.MAX_FIT_POINTS, len(all_pts)))
            if grown <= len(pts):
                break
            pick = np.sort(draw[:grown])
            pts = all_pts[pick]
            given = None if all_given is None else all_given[pick]
    if not np.isfinite(r0) or r0 > 10:
        raise ReconstructionError("the surface is flat (no curvature around a spine) — "
                                  "the input is not a tube")
    # Spacing of the collapsed cloud: all points on a spine of length area / (2 pi r0).
    collapsed = area_per_point / (2 * np.pi * r0)
    algo = "pipe" if kind == "pipe" else "canal"
    p = {
        "R": R / scale if R else max(C.R_PER_RADIUS * r0, C.R_PER_COLLAPSED_SPACING * collapsed),
        "delta": delta / scale if delta else C.DELTA_PER_RADIUS * r0,
        "mu": mu if mu is not None else (C.MU if algo == "pipe" or stop == "paper" else C.MU_CANAL_AUTO),
        "tau": tau if tau is not None else C.TAU,
        "H": H / scale if H else C.H_PER_RADIUS * r0,
    }
    log.info("first radius estimate r0 = %.4g; R = %.4g, delta = %.4g, mu = %.3g, tau = %.3g, H = %.4g",
             r0 * scale, p["R"] * scale, p["delta"] * scale, p["mu"], p["tau"], p["H"] * scale)

    with timer("shrink"):
        sr = shrink(pts, nrm, R=p["R"], delta=p["delta"], mu=p["mu"], tau=p["tau"], kind=algo, stop=stop,
                    neighbours=neighbours, max_distance=C.MAX_SHRINK_PER_RADIUS * r0)
        log.info("shrinking: %d moves, break count %d, stopped by %s", sr.iterations, sr.break_counts[-1],
                 sr.stop_rule)
        if stop == "auto" and (not sr.converged or sr.keep.sum() < C.MIN_KEPT_SHARE * len(pts)):
            # Too few points met an opposite normal: the scan saw the tube from one side.
            log.info("too few points met the other side of the tube (a one-sided scan?): each point "
                     "moves by the distance at which the shifted points concentrate most")
            sr = shrink_by_concentration(pts, nrm, R=p["R"], delta=p["delta"],
                                         max_distance=C.MAX_SHRINK_PER_RADIUS * r0, neighbours=nbr)
            if sr.break_counts.max() < C.MIN_CONCENTRATION * max(sr.break_counts[0], 1):
                raise ReconstructionError("no spine: the points shifted along their normals do not "
                                          "gather anywhere — the input is not a tube")
    if not sr.converged and stop == "auto":
        raise ReconstructionError(
            f"shrinking did not stop after {sr.iterations} moves (no opposite normals met) — "
            "the input is not a closed-around tube; try a larger R")
    kept = np.flatnonzero(sr.keep)
    if len(kept) < C.MIN_KEPT_SHARE * len(pts):
        raise ReconstructionError(f"only {len(kept)} of {len(pts)} points reached a spine — "
                                  "the input is not a tube")

    with timer("thin"):
        thin = mls_thin(sr.points[kept], H=p["H"])
    with timer("order"):
        curve = order_curve(thin, spacing=C.ORDER_VOXEL_PER_H * p["H"])
        step = np.linalg.norm(np.diff(curve.points, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(step)])
        length = s[-1] + (np.linalg.norm(curve.points[-1] - curve.points[0]) if curve.closed else 0.0)
        nseg = _segments(length, C.SPINE_KNOTS_PER_RADIUS * r0, len(pts))
        spine = pspline_fit(s / length, curve.points, n_segments=nseg, closed=curve.closed,
                            weights=curve.weights)
    with timer("radius"):
        r_i = np.linalg.norm(pts[kept] - thin, axis=1)
        eq6 = pipe_radius(pts[kept], thin)
        rseg = _segments(length, C.RADIUS_KNOTS_PER_RADIUS * r0, len(kept))
        t_i, _ = footpoints(thin, spine, constant_spline(0.0), closed=curve.closed)
        radius_fn = pspline_fit(t_i, r_i, n_segments=rseg, closed=curve.closed)

    with timer("refine"):
        if refine:
            fits = {}
            if kind in ("auto", "canal"):
                fits["canal"] = refine_fit(fit_pts, spine, radius_fn, closed=curve.closed, spine_segments=nseg,
                                           radius_segments=rseg, reach=r0)
            if kind in ("auto", "pipe"):
                start = fits["canal"].spine if "canal" in fits else spine
                fits["pipe"] = refine_fit(fit_pts, start, constant_spline(eq6), closed=curve.closed,
                                          spine_segments=nseg, radius_segments=None, reach=r0)
            if kind == "auto":
                # Both fits scored on all points with the same outlier cut: a fit that went wrong
                # must not look good by calling most points outliers.
                cut = outlier_cut(fits["canal"].residual, r0)
                rss = {name: float(np.minimum(f.residual**2, cut**2).sum()) for name, f in fits.items()}
                samples = fits["canal"].radius(np.linspace(0, 1, 200))
                kind = "canal" if prefer_canal(rss["pipe"], rss["canal"], len(fit_pts), rseg + 2,
                                               samples) else "pipe"
            fit = fits[kind]
            spine, radius_fn, fit_t, residual = fit.spine, fit.radius, fit.t, fit.residual
        else:
            if kind == "auto":
                rss_pipe = float(((r_i - eq6) ** 2).sum())
                rss_canal = float(((r_i - radius_fn(t_i)) ** 2).sum())
                kind = "canal" if prefer_canal(rss_pipe, rss_canal, len(r_i), rseg + 2,
                                               radius_fn(np.linspace(0, 1, 200))) else "pipe"
            if kind == "pipe":
                radius_fn = constant_spline(eq6)
            fit_t, residual = footpoints(fit_pts, spine, radius_fn, closed=curve.closed)

    # How much of the circumference the scan saw (full scans read about 340 degrees or more).
    near = ~is_stray(residual, r0)
    coverage = angular_coverage(fit_pts[near], spine, fit_t[near])
    coverage = float(np.median(coverage)) if len(coverage) else float("nan")

    with timer("residual"):
        if len(all_pts) > len(fit_pts):
            # The RMS residual is a diagnostic, not a fit: a seeded sample estimates it far below its
            # own spread, so a huge scan is not walked point by point for it.
            measured = all_pts if draw is None else all_pts[np.sort(draw[: C.MAX_RESIDUAL_POINTS])]
            residual = footpoints(measured, spine, radius_fn, closed=curve.closed)[1]
    rms = float(np.sqrt(np.mean(residual**2)))
    # Whether the points form a tube is judged on the points near the surface: stray points (a few
    # percent in real scans) are far off by nature and must not make a good tube look like none.
    sigma = robust_sigma(residual)
    stray = is_stray(residual, r0)
    inlier_rms = float(np.sqrt(np.mean(residual[~stray] ** 2))) if (~stray).any() else np.inf
    mean_r = float(np.mean(radius_fn(np.linspace(0, 1, 200))))
    if not mean_r > 0 or inlier_rms > MAX_RELATIVE_RESIDUAL * mean_r:
        raise ReconstructionError(
            f"the points do not lie on a tube: RMS distance from the best tube is "
            f"{inlier_rms / max(mean_r, 1e-300):.0%} of its radius — check the input is a single pipe or canal")
    if stray.mean() > C.MAX_STRAY_SHARE:
        raise ReconstructionError(
            f"{stray.mean():.0%} of the points lie far off the best tube — the input is not a single "
            "pipe or canal; crop it to one tube")

    # Back to the input's units and placement.
    spine = BSpline(spine.t, spine.c * scale + origin, spine.k)
    radius_fn = BSpline(radius_fn.t, radius_fn.c * scale, radius_fn.k)
    parameters = {key: (val * scale if key in ("R", "delta", "H") else val) for key, val in p.items()}
    parameters.update(k=int(k or C.NORMAL_NEIGHBOURS), r0=r0 * scale, stop=stop, neighbours=neighbours,
                      refine=bool(refine), spine_segments=nseg, radius_segments=rseg)
    diagnostics = {
        "n_points": len(all_pts), "n_shrink_points": len(pts), "n_fit_points": len(fit_pts),
        "n_residual_points": len(residual),
        "iterations": sr.iterations, "break_count": int(sr.break_counts[-1]),
        "stop_rule": sr.stop_rule, "points_reached_spine": int(len(kept)), "closed": bool(curve.closed),
        "eq6_radius": eq6 * scale, "rms_residual": rms * scale, "inlier_rms_residual": inlier_rms * scale,
        "stray_share": float(stray.mean()), "noise_sigma": sigma * scale, "angular_coverage": coverage,
        "one_sided": bool(coverage < C.ONE_SIDED_DEGREES), "seconds": dict(timer),
    }
    stages = {"normals": nrm, "shrunk": sr.points[kept] * scale + origin, "thin": thin * scale + origin,
              "break_counts": sr.break_counts}
    return CanalModel(kind, spine, radius_fn, bool(curve.closed), parameters, diagnostics, stages)
