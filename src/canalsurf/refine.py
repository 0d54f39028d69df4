"""Stage 5b: geometric refinement of spine and radius with all points.

The shrinking/MLS spine and the paper's radii are a first estimate.  This stage fits them to the
input points directly: it minimises the sum of squared distances of the points from the canal surface,

    e_i = min_t ( |P_i - C(t)| - r(t) ),

(the distance from a point outside to the envelope of the spheres), over the spine's control points
and the radius coefficients, by Gauss-Newton with the footpoints t_i held fixed in each linearisation
(at the minimiser the derivative with respect to t vanishes).  Residuals far beyond the noise are
given zero weight (stray points).  For an open spine the curve is trimmed or extended to the range of
the footpoints, so that it ends where the tube ends, and re-parameterised by arc length each pass.
"""

from __future__ import annotations


from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.interpolate import BSpline
from scipy.linalg import eigh
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from .constants import OUTLIER_SIGMAS, REFINE_ITERATIONS, SMOOTHING
from .spine import arclength_reparametrize, constant_spline, curve_length, design_matrix, n_coefficients, penalty

__all__ = ["footpoints", "refine", "RefineResult", "robust_sigma"]

#: Most Newton steps of the footpoint search, and the parameter change that counts as converged.
FOOTPOINT_NEWTON_STEPS = 30
FOOTPOINT_TOL = 1e-10
#: Penalty weights tried by generalised cross-validation, relative to the fixed floor SMOOTHING * n / m.
GCV_GRID = 10.0 ** np.arange(0.0, 6.5, 0.5)
#: Gaps averaged for the local footpoint spacing at an end.
END_GAPS = 8
#: The fit has converged when a pass's relative cost reduction changes by less than this from the
#: last pass and neither end moves by more than ``CONVERGED_END`` of the reach.
CONVERGED_GAIN = 1e-4
CONVERGED_END = 0.01
#: Levenberg-Marquardt damping factors tried in turn until the cost falls.
LM_DAMPING = (1e-3, 1e-1, 1.0, 10.0, 100.0)
#: Clouds at least this large query their KD-trees on all cores.
PARALLEL_MIN_POINTS = 50_000
#: Samples of the spine the footpoint search starts from; on a canal a coarser set, of which the
#: nearest ``FOOTPOINT_CANDIDATES`` are tried (Newton refines the start either way).
FOOTPOINT_SAMPLES = 1024
FOOTPOINT_COARSE = 256
FOOTPOINT_CANDIDATES = 64


def _workers(points: np.ndarray) -> int:
    """Threads for a KD-tree query: starting them costs more than it saves on small clouds."""
    return -1 if len(points) >= PARALLEL_MIN_POINTS else 1


def robust_sigma(residual: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (1.4826 MAD)."""
    return float(1.4826 * np.median(np.abs(residual - np.median(residual))))


def footpoints(points: np.ndarray, spine: BSpline, radius: BSpline, *,
               closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Parameter of the characteristic circle nearest to each point, and the signed distance.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    spine, radius : BSpline
    closed : bool
        Parameters wrap around [0, 1); else they are clamped to [0, 1].

    Returns
    -------
    t : ndarray, shape (N,)
    distance : ndarray, shape (N,)
        ``|P - C(t)| - r(t)``: positive outside the surface.
    """
    ts = np.linspace(0.0, 1.0, FOOTPOINT_SAMPLES)
    radii = radius(ts)
    spread = float(np.ptp(radii))
    if spread == 0:
        t = ts[cKDTree(spine(ts)).query(points, workers=_workers(points))[1]]
    else:
        # Start at the sample minimising |P - C| - r (on a canal not the nearest centre), searched
        # among the nearest samples; only samples within (nearest distance + spread of r) can win,
        # so points whose candidate list may be too short get an exact ball search.
        ts = np.linspace(0.0, 1.0, FOOTPOINT_COARSE)
        centres, radii = spine(ts), radius(ts)
        k = min(FOOTPOINT_CANDIDATES, len(ts))
        dist, idx = cKDTree(centres).query(points, k=k, workers=_workers(points))
        f = dist - radii[idx]
        t = ts[idx[np.arange(len(points)), np.argmin(f, axis=1)]]
        short = np.flatnonzero(dist[:, -1] < dist[:, 0] + spread)
        if len(short):
            tree = cKDTree(centres)
            for i, c in zip(short, tree.query_ball_point(points[short], dist[short, 0] + spread)):
                c = np.asarray(c, dtype=np.intp)
                t[i] = ts[c[np.argmin(np.linalg.norm(points[i] - centres[c], axis=1) - radii[c])]]
    d1, d2 = spine.derivative(1), spine.derivative(2)
    r1, r2 = radius.derivative(1), radius.derivative(2)
    active = np.ones(len(points), bool)
    for _ in range(FOOTPOINT_NEWTON_STEPS):
        ta = t[active]
        pa = points[active]
        diff = pa - spine(ta)
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
        u = diff / dist[:, None]
        c1, c2 = d1(ta), d2(ta)
        uc1 = np.einsum("ij,ij->i", u, c1)
        grad = -uc1 - r1(ta)
        curv = (np.einsum("ij,ij->i", c1, c1) - uc1**2) / dist - np.einsum("ij,ij->i", u, c2) - r2(ta)
        # Where the second derivative is not positive Newton would climb: take a gradient step
        # scaled like |C'|^2 / d instead.
        curv = np.where(curv > 0, curv, np.einsum("ij,ij->i", c1, c1) / dist)
        new = ta - grad / curv
        new = np.mod(new, 1.0) if closed else np.clip(new, 0.0, 1.0)
        moved = np.abs(new - ta) > FOOTPOINT_TOL
        t[active] = new
        active[np.flatnonzero(active)[~moved]] = False
        if not active.any():
            break
    return t, np.linalg.norm(points - spine(t), axis=1) - radius(t)


@dataclass
class RefineResult:
    """Refined spine and radius.

    Attributes
    ----------
    spine, radius : BSpline
    t : ndarray
        Footpoint parameter of each point.
    residual : ndarray
        Signed distance of each point from the surface.
    inlier : ndarray of bool
        Points used in the fit (not stray).
    iterations : int
    """

    spine: BSpline
    radius: BSpline
    t: np.ndarray
    residual: np.ndarray
    inlier: np.ndarray
    iterations: int


def _extended(f: BSpline, straight: bool):
    """``f`` continued beyond [0, 1] by its tangent line (``straight``) or its end value.

    A cubic's own end polynomial curls away when extrapolated; a tube that goes on past the current
    end of the spine goes on (locally) straight.
    """
    d = f.derivative()

    def g(t):
        t = np.asarray(t, float)
        inside = np.clip(t, 0.0, 1.0)
        out = f(inside)
        if straight:
            over = (t - inside).reshape(t.shape + (1,) * (out.ndim - t.ndim))
            out = out + over * d(inside)
        return out

    return g


def _end(s: np.ndarray) -> float:
    """Where a tube ends, from the ascending arc-length positions ``s`` of its footpoints.

    For footpoints spread evenly with gap ``g`` from an end ``e``, the first lies near ``e + g``.  The
    gap is measured on the next few points, as the density near an end may differ from the middle.
    (A stray point beyond an end is already an outlier by its residual.)
    """
    m = END_GAPS
    if len(s) <= m:
        return float(s[0])
    return float(s[0] - (s[m] - s[0]) / m)


def refine(points: np.ndarray, spine: BSpline, radius: BSpline, **kwargs) -> RefineResult:
    """Fit spine and radius to the points by robust Gauss-Newton (see :func:`_refine`).

    The dense systems have only a few hundred unknowns; BLAS threads cost far more than they save on
    them (and thrash on a busy machine), so the fit runs with one BLAS thread.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        return _refine(points, spine, radius, **kwargs)


def _refine(points: np.ndarray, spine: BSpline, radius: BSpline, *, closed: bool, spine_segments: int,
           radius_segments: int | None, iterations: int = REFINE_ITERATIONS,
           reach: float = 0.0) -> RefineResult:
    """Fit spine and radius to the points by robust Gauss-Newton.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    spine, radius : BSpline
        Start values, parameter t in [0, 1].
    closed : bool
    spine_segments : int
        Knot intervals of the spine.
    radius_segments : int or None
        Knot intervals of the radius function; ``None`` for a constant radius (a pipe).
    iterations : int
    reach : float
        How far (in length units) an open spine may grow past each end per pass; it is then trimmed
        to where the footpoints actually lie, so that it ends where the tube ends.

    Returns
    -------
    RefineResult
    """
    n = len(points)
    inlier = np.ones(n, bool)
    last_gain, last_ends = np.inf, np.full(2, np.inf)
    for it in range(iterations + 1):
        segs, rsegs = spine_segments, radius_segments
        if closed:
            spine, extra, _ = arclength_reparametrize(
                spine, n_segments=segs, closed=True,
                extra=[] if rsegs is None else [(radius, rsegs)])
        else:
            # Fit on the spine continued straight for ``reach`` past each end: points beyond the
            # current end then meet the tube's continuation, not the end sphere.  The margins without
            # points stay straight under the penalty and are trimmed off after the step.
            ext = reach / max(curve_length(spine), 1e-300)
            segs = int(np.ceil(spine_segments * (1 + 2 * ext)))
            rsegs = None if rsegs is None else int(np.ceil(radius_segments * (1 + 2 * ext)))
            spine, extra, _ = arclength_reparametrize(
                _extended(spine, True), n_segments=segs, closed=False, a=-ext, b=1 + ext,
                extra=[] if rsegs is None else [(_extended(radius, False), rsegs)])
        if rsegs is not None:
            radius = extra[0]
        t, res = footpoints(points, spine, radius, closed=closed)
        cut = OUTLIER_SIGMAS * max(robust_sigma(res), 1e-12 * curve_length(spine))
        inlier = np.abs(res - np.median(res)) <= cut
        if it < iterations:
            # Levenberg-Marquardt: accept a step only if the truncated cost (outliers count as
            # ``cut``) falls with re-computed footpoints; otherwise damp harder.
            cost = np.minimum(res**2, cut**2).sum()
            gain = 0.0
            system = _linearise(points, t, inlier, spine, radius, segs, rsegs, closed)
            lam = _gcv_smoothing(*system, floor=SMOOTHING * inlier.sum() / n_coefficients(segs, closed))
            for damping in LM_DAMPING:
                new_spine, new_radius = _step(system, spine, radius, segs, rsegs, closed, lam, damping)
                new_t, new_res = footpoints(points, new_spine, new_radius, closed=closed)
                new_cost = np.minimum(new_res**2, cut**2).sum()
                if new_cost < cost:
                    spine, radius, t, res = new_spine, new_radius, new_t, new_res
                    gain = 1.0 - new_cost / cost
                    break
        if not closed:
            length = curve_length(spine)
            ti = np.sort(t[inlier]) * length
            lo = max(_end(ti), 0.0) / length
            hi = min(length - _end(length - ti[::-1]), length) / length
            ends = np.array([lo * length, (1 - hi) * length])
            spine, extra, _ = arclength_reparametrize(
                spine, n_segments=spine_segments, closed=False, a=lo, b=hi,
                extra=[] if rsegs is None else [(radius, radius_segments)])
            if rsegs is not None:
                radius = extra[0]
        else:
            ends = np.zeros(2)  # nothing to trim on a loop
        if it < iterations:
            # Growing and trimming the ends perturbs the fit a little each pass, so "converged" means
            # the ends and the pass's gain have stopped changing, not that the gain is zero.
            if (abs(gain - last_gain) < CONVERGED_GAIN
                    and np.abs(ends - last_ends).max() < CONVERGED_END * max(reach, 1e-300)):
                break
            last_gain, last_ends = gain, ends

    t, res = footpoints(points, spine, radius, closed=closed)
    return RefineResult(spine, radius, t, res, inlier, iterations)


def _linearise(points, t, inlier, spine, radius, segs, rsegs, closed):
    """Normal equations of ``e_i = |P_i - C(t_i)| - r(t_i)`` in the coefficients, ``t_i`` fixed.

    Returns
    -------
    JtWJ, g, Pen : dense arrays -- ``J^T W J``, ``J^T W e`` and the block second-difference penalty
    x : ndarray -- current coefficients (spine x, y, z blocks, then radius)
    rss : float -- ``sum w e^2``
    nw : float -- total weight
    """
    n = len(points)
    m = n_coefficients(segs, closed)
    diff = points - spine(t)
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
    u = diff / dist[:, None]
    e = dist - radius(t)
    w = inlier.astype(float)
    B = design_matrix(t, segs, closed)
    blocks = [B.multiply(-u[:, [a]]) for a in range(3)]
    coef = [spine.c[:m, a] for a in range(3)]
    pens = [penalty(segs, closed)] * 3
    if rsegs is None:
        blocks.append(sparse.csr_matrix(-np.ones((n, 1))))
        coef.append(np.array([radius.c[0]]))
        pens.append(sparse.csr_matrix((1, 1)))
    else:
        mr = n_coefficients(rsegs, closed)
        blocks.append(-design_matrix(t, rsegs, closed))
        coef.append(radius.c[:mr])
        pens.append(penalty(rsegs, closed))
    J = sparse.hstack(blocks).tocsr()
    JtW = J.T.multiply(w).tocsr()
    spine_pen = sparse.block_diag(pens[:3] + [0 * pens[3]]).toarray()
    radius_pen = sparse.block_diag([0 * pens[0]] * 3 + [pens[3]]).toarray()
    JtWJ = (JtW @ J).toarray()
    # The radius function keeps a light fixed penalty (like the initial fits); only the spine's
    # smoothing is chosen from the data.
    fixed = SMOOTHING * w.sum() / m * radius_pen
    return (JtWJ + fixed, JtW @ e + fixed @ np.concatenate(coef), spine_pen, np.concatenate(coef),
            float((w * e**2).sum()), float(w.sum()))


def _gcv_smoothing(JtWJ, g, Pen, x, rss, nw, floor: float) -> float:
    """Penalty weight minimising generalised cross-validation, ``nw RSS / (nw - tr H)^2``.

    The noise of a scan, not a fixed rule, then decides how much the spine is smoothed: straight,
    well-sampled stretches are averaged over many points while sharp bends keep their shape.  The
    search starts at ``floor``: the straight margins past the ends carry no data, and only the penalty
    holds them.  One generalised eigendecomposition (Demmler-Reinsch) makes every trial weight cheap.
    """
    M = JtWJ + floor * Pen
    M += 1e-12 * np.trace(M) / len(M) * np.eye(len(M))
    s, V = eigh(Pen, M)  # V^T M V = I, V^T Pen V = diag(s)
    s = np.maximum(s, 0.0)
    best, best_lam = np.inf, floor
    for lam in floor * GCV_GRID:
        shrink = 1.0 / (1.0 + (lam - floor) * s)  # eigenvalues of (M + (lam - floor) Pen)^-1 in V
        step = -V @ (shrink * (V.T @ (g + lam * (Pen @ x))))
        fit_rss = rss + 2 * step @ g + step @ JtWJ @ step
        dof = float(np.sum(shrink * (1.0 - floor * s)))  # tr(A^-1 JtWJ), JtWJ = M - floor Pen
        if dof >= nw:
            continue
        gcv = nw * max(fit_rss, 0.0) / (nw - dof) ** 2
        if gcv < best:
            best, best_lam = gcv, lam
    return float(best_lam)


def _step(system, spine, radius, segs, rsegs, closed, lam, damping):
    """One damped Gauss-Newton step with penalty weight ``lam``; returns the new spine and radius."""
    JtWJ, g, Pen, x, _, _ = system
    m = n_coefficients(segs, closed)
    A = JtWJ + lam * Pen + damping * np.diag(JtWJ.diagonal() + 1e-12)
    x_new = x + np.linalg.solve(A, -g - lam * (Pen @ x))
    ctrl = x_new[: 3 * m].reshape(3, m).T
    if closed:
        ctrl = np.vstack([ctrl, ctrl[:3]])
    new_spine = BSpline(spine.t, ctrl, 3)
    rad = x_new[3 * m:]
    if rsegs is None:
        return new_spine, constant_spline(float(rad[0]))
    return new_spine, BSpline(radius.t, np.concatenate([rad, rad[:3]]) if closed else rad, 3)
