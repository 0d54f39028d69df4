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
from functools import cache

import numpy as np
from scipy.interpolate import BSpline
from scipy.linalg import eigh
from scipy.spatial import cKDTree
from threadpoolctl import ThreadpoolController

from ._banded import BlockTridiagonal
from ._rows import by_rows, workers
from .constants import MIN_SIGMA_PER_RADIUS, OUTLIER_SIGMAS, REFINE_ITERATIONS, SMOOTHING
from .errors import ReconstructionError
from .spine import (arclength_reparametrize, constant_spline, curve_length, local_basis, n_coefficients,
                    penalty)

__all__ = ["footpoints", "refine", "RefineResult", "robust_sigma", "outlier_cut", "is_stray", "extended"]

#: Most Newton steps of the footpoint search, and the parameter change that counts as converged:
#: Newton converges quadratically, so after a step this small the parameter is exact to ~1e-10 (the
#: distance, stationary there, to ~1e-15 of the spine's length).
FOOTPOINT_NEWTON_STEPS = 30
FOOTPOINT_TOL = 1e-5
#: Penalty weights tried by generalised cross-validation, relative to the fixed floor SMOOTHING * n / m.
GCV_GRID = 10.0 ** np.arange(0.0, 6.5, 0.5)
#: Each effective degree of freedom counts this many times in the GCV score.  Where the score is nearly
#: flat over the weights, as on a straight branch of a network (whose best spine is the line), plain
#: GCV (1) at times takes a far lighter weight and a wiggly spine; 1.4 is the inflation Kim and Gu
#: (2004) proposed against that (mgcv's ``gamma``).
GCV_GAMMA = 1.4
#: Gaps averaged for the local footpoint spacing at an end.
END_GAPS = 8
#: ... and a run of END_GAPS gaps more than this many times as long as the runs inside it is stray.
END_SPARSE = 3.0
#: ... or a single gap this many times the mean gap inside (a stray just past the end): one gap of an
#: even sampling exceeds it with probability exp(-8).
END_GAP_JUMP = 8.0
#: Only points within this many robust deviations of the surface place the ends: the scan's points
#: crowd there, while stray points spread evenly over the whole outlier shell.
END_SIGMAS = 2.0
#: The fit has converged when a pass's relative cost reduction changes by less than this from the
#: last pass and neither end moves by more than ``CONVERGED_END`` of the reach.  (At a tenth of this,
#: fits went on for passes whose gains differed by less than a thousandth: more passes, the same tubes.)
CONVERGED_GAIN = 1e-3
#: A pass whose step lowers the cost by less than this share leaves a spine that moves little more: the
#: footpoints are followed from there on, not searched along the whole spine again.
FOLLOW_GAIN = 0.01
CONVERGED_END = 0.01
#: A pass that repeats one of the last this many passes (within the tolerances above) ends the fit.
CYCLE_PASSES = 8
#: A cloud of more than SUBSET_FACTOR x SUBSET_POINTS points is first fitted through a seeded subset
#: of SUBSET_POINTS: as many as the paper's stages use (MAX_SHRINK_POINTS), plenty to place spine and
#: ends to within the noise, so that the passes on all points only polish.
SUBSET_POINTS = 5_000
SUBSET_FACTOR = 2
#: Ridge on every coefficient of a Gauss-Newton step, and stiffness against moving a control point
#: along the spine, relative to the mean diagonal of J^T J on the spine's coefficients.  A slide only
#: re-parameterises the spine, which each pass undoes; on a pipe, cheap slides let the spine's knots
#: crowd into a tight bend.  On a canal they also crowd the radius function's knots where the radius
#: changes -- a larger model than knots by arc length -- and cross-validation, finding the fit better
#: for it, smoothed a reducer's straight spine least (test_refine): there slides are stiffer.
RIDGE = 1e-8
TANGENT_STIFFNESS = 0.01
CANAL_TANGENT_STIFFNESS = 1.0
#: Systems of more unknowns than this are solved by blocks (:class:`~canalsurf._banded.BlockTridiagonal`):
#: below it a dense solve costs less (measured, one thread).
BANDED_UNKNOWNS = 200
#: Levenberg-Marquardt damping factors tried in turn until the cost falls.
LM_DAMPING = (1e-3, 1e-1, 1.0, 10.0, 100.0)
#: Samples of the spine the footpoint search starts from; on a canal a coarser set, searched
#: exhaustively for the least ``|P - C| - r`` (Newton refines the start either way).
FOOTPOINT_SAMPLES = 1024
FOOTPOINT_COARSE = 256
#: The canal search bounds runs of this many consecutive samples by a sphere, so that a point
#: computes exact distances only to the few runs that can hold its best sample.  Each run is one pass of
#: array operations over the points that need it: fewer, longer runs cost less than the extra distances.
FOOTPOINT_RUN = 16
#: Points per thread of the footpoint search at least (:func:`canalsurf._rows.by_rows`).
FOOTPOINT_ROWS = 10_000
#: Points per batch of the canal search: bounds its scratch memory (about 40 MB).
FOOTPOINT_BATCH = 1 << 16
#: An open spine whose tangent at an end is turned by more than this from its chord over the last
#: reach hooks there: a first estimate's end can curl within a fraction of a radius (at the dense end
#: of ``CONDITIONS["density-x10"]``, seeds 100 and 104, by 101 and 67 degrees; other ends of those
#: estimates, wiggling, by 13-36), and continued along that tangent, through the tube's wall, the fit
#: turned back alongside the tube.  It is continued along the chord instead.
HOOK_DEGREES = 45.0
#: A radius whose samples spread by less than this share of its size is a constant one that
#: rounding made uneven (a pipe, searched by its nearest centre).
PIPE_SPREAD = 1e-12


def robust_sigma(residual: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (1.4826 MAD)."""
    return float(1.4826 * np.median(np.abs(residual - np.median(residual))))


def _envelope_start(points: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Index of the sample minimising ``|P - C_j| - r_j`` for each point, exactly over all samples.

    Branch and bound: the nearest centre gives an upper bound ``u`` on each point's minimum, and a
    run of samples inside a sphere (mid, rho) with largest radius ``r_max`` cannot go below
    ``|P - mid| - rho - r_max``; only runs whose bound does not exceed ``u`` are evaluated.  On a
    tube a point needs a handful of the runs, where a k-nearest search would need every sample
    within its distance plus the radius spread.
    """
    # Distances are taken as |P|^2 - 2 P.C + |C|^2 (matrix products), about the spine's centre so
    # that far-off coordinates lose no digits.
    origin = centres.mean(axis=0)
    points, centres = points - origin, centres - origin
    n_runs = -(-len(centres) // FOOTPOINT_RUN)
    run = np.minimum(np.arange(n_runs * FOOTPOINT_RUN), len(centres) - 1).reshape(n_runs, -1)
    mid = centres[run].mean(axis=1)
    reach = np.linalg.norm(centres[run] - mid[:, None], axis=2).max(axis=1) + radii[run].max(axis=1)
    near_d, near = cKDTree(centres).query(points, workers=workers(len(points)))
    best = near.copy()
    for lo in range(0, len(points), FOOTPOINT_BATCH):
        p, j = points[lo:lo + FOOTPOINT_BATCH], near[lo:lo + FOOTPOINT_BATCH]
        p2 = np.einsum("ij,ij->i", p, p)
        best_f = near_d[lo:lo + FOOTPOINT_BATCH] - radii[j]
        limit = best_f[:, None] + reach
        d2 = p2[:, None] - 2 * p @ mid.T + np.einsum("ij,ij->i", mid, mid)
        needed = (limit >= 0) & (d2 <= limit**2)
        for r in range(n_runs):
            idx = np.flatnonzero(needed[:, r])
            if not len(idx):
                continue
            c = centres[run[r]]
            f = np.sqrt(np.maximum(p2[idx, None] - 2 * p[idx] @ c.T + np.einsum("ij,ij->i", c, c), 0.0))
            f -= radii[run[r]]
            k = f.argmin(axis=1)
            f_min = f[np.arange(len(idx)), k]
            better = f_min < best_f[idx]
            best_f[idx[better]] = f_min[better]
            best[lo + idx[better]] = run[r, k[better]]
    return best


def _polyline_start(points: np.ndarray, ts: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Parameter of each point's closest point on the polyline through ``centres`` (at ``ts``).

    The nearest centre is found by a KD-tree, then the point is projected onto the two segments at
    it: the start is then off by the square of the sample spacing, not by the spacing, which saves
    the footpoint search a Newton step.
    """
    near = cKDTree(centres).query(points, workers=workers(len(points)))[1]
    best_t, best_d = ts[near], np.full(len(points), np.inf)
    for a in (np.maximum(near - 1, 0), np.minimum(near, len(ts) - 2)):
        chord = centres[a + 1] - centres[a]
        along = np.einsum("ij,ij->i", points - centres[a], chord)
        s = np.clip(along / np.maximum(np.einsum("ij,ij->i", chord, chord), 1e-300), 0.0, 1.0)
        d = np.linalg.norm(points - centres[a] - s[:, None] * chord, axis=1)
        better = d < best_d
        best_t[better] = (ts[a] + s * (ts[a + 1] - ts[a]))[better]
        best_d[better] = d[better]
    return best_t


def outlier_cut(residual: np.ndarray, radius: float) -> float:
    """Residuals farther than this from their median are stray points.

    ``OUTLIER_SIGMAS`` robust standard deviations, the deviation taken as at least
    ``MIN_SIGMA_PER_RADIUS`` of the tube's ``radius``.
    """
    return OUTLIER_SIGMAS * max(robust_sigma(residual), MIN_SIGMA_PER_RADIUS * radius)


def is_stray(residual: np.ndarray, radius: float) -> np.ndarray:
    """Points whose residual lies beyond :func:`outlier_cut` from the median residual."""
    return np.abs(residual - np.median(residual)) > outlier_cut(residual, radius)


def footpoints(points: np.ndarray, spine: BSpline, radius: BSpline, *, closed: bool,
               start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parameter of the characteristic circle nearest to each point, and the signed distance.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    spine, radius : BSpline
    closed : bool
        Parameters wrap around [0, 1); else they are clamped to [0, 1].
    start : ndarray, shape (N,), optional
        Parameters to start from, e.g. the footpoints on a slightly different spine: the nearest
        footpoint is then followed from there.  By default every point starts from the best of a
        set of samples along the spine.

    Returns
    -------
    t : ndarray, shape (N,)
    distance : ndarray, shape (N,)
        ``|P - C(t)| - r(t)``: positive outside the surface.
    """
    ts = np.linspace(0.0, 1.0, FOOTPOINT_SAMPLES)
    radii = radius(ts)
    # A constant radius evaluates to values that differ in the last bits; that is still a pipe.
    pipe = np.ptp(radii) <= PIPE_SPREAD * np.abs(radii).max()

    def search(rows):
        return _footpoints(points[rows], spine, radius, closed=closed, pipe=pipe, ts=ts,
                           start=None if start is None else start[rows])

    if workers(len(points), FOOTPOINT_ROWS) == 1:
        return search(slice(None))
    # Each point's footpoint depends on that point alone: slices of the points are searched in threads.
    found = by_rows(lambda rows: np.column_stack(search(rows)), len(points), FOOTPOINT_ROWS)
    return found[:, 0].copy(), found[:, 1].copy()


def _footpoints(points, spine, radius, *, closed, pipe, ts, start):
    """:func:`footpoints`, with ``ts`` the samples a pipe's points start from."""
    if start is not None:
        t = np.array(start, dtype=float)
    elif pipe:
        t = _polyline_start(points, ts, spine(ts))
    else:
        # On a canal the start is the sample minimising |P - C| - r, not the nearest centre.
        ts = np.linspace(0.0, 1.0, FOOTPOINT_COARSE)
        t = ts[_envelope_start(points, spine(ts), radius(ts))]
    active = np.ones(len(points), bool)
    for _ in range(FOOTPOINT_NEWTON_STEPS):
        ta = t[active]
        pa = points[active]
        diff = pa - spine(ta)
        dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
        u = diff / dist[:, None]
        # Derivatives evaluated in place (``nu``): a derivative spline costs more to build than to use.
        c1, c2 = spine(ta, 1), spine(ta, 2)
        uc1 = np.einsum("ij,ij->i", u, c1)
        c1c1 = np.einsum("ij,ij->i", c1, c1)
        grad = -uc1
        curv = (c1c1 - uc1**2) / dist - np.einsum("ij,ij->i", u, c2)
        if not pipe:
            grad -= radius(ta, 1)
            curv -= radius(ta, 2)
        # Where the second derivative is not positive Newton would climb: take a gradient step
        # scaled like |C'|^2 / d instead.
        curv = np.where(curv > 0, curv, c1c1 / dist)
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


def extended(f: BSpline, span: float = 0.0, turn: float = HOOK_DEGREES):
    """``f`` continued beyond [0, 1] by its tangent line at each end -- or, for a curve whose tangent
    there is turned more than ``turn`` degrees from its chord over the last ``span`` of its parameter
    (at most half of it), along that chord.

    A cubic's own end polynomial curls away when extrapolated; a tube that goes on past the current
    end of the spine goes on (locally) straight, and a canal's radius goes on changing at its rate
    there (held constant, the continuation misfits a clean scan's points past the end by r' times
    the distance, and they are cut as stray: the spine stops short).
    """
    rate = f.derivative()(np.array([0.0, 1.0]))
    if span > 0:
        span = min(span, 0.5)
        chord = (f(np.array([span, 1.0])) - f(np.array([0.0, 1.0 - span]))) / span
        cos = np.einsum("ij,ij->i", rate, chord) / np.maximum(
            np.linalg.norm(rate, axis=1) * np.linalg.norm(chord, axis=1), 1e-300)
        hooked = cos < np.cos(np.radians(turn))
        rate[hooked] = chord[hooked]

    def g(t):
        t = np.asarray(t, float)
        out = f(np.clip(t, 0.0, 1.0))
        shape = t.shape + (1,) * (out.ndim - t.ndim)
        return out + np.minimum(t, 0.0).reshape(shape) * rate[0] + np.maximum(t - 1.0, 0.0).reshape(shape) * rate[1]

    return g


def _end(s: np.ndarray) -> float:
    """Where a tube ends, from the ascending arc-length positions ``s`` of its footpoints.

    For footpoints spread evenly with gap ``g`` from an end ``e``, the first lies near ``e + g``.  The
    gap is measured on the next few points, as the density near an end may differ from the middle.
    Stray points that happen to lie near the surface's continuation past an end are far sparser than
    the scan: the end is taken at the first point whose run of ``END_GAPS`` gaps is no wider than
    ``END_SPARSE`` times the runs just inside it and whose next gap is no wider than ``END_GAP_JUMP``
    mean gaps there, so they cannot drag the spine out.
    """
    m = END_GAPS
    if len(s) <= 4 * m:
        j = min(m, len(s) - 1)
        return float(s[0] - (s[j] - s[0]) / max(j, 1))
    runs = s[m:] - s[:-m]
    # Each run against the runs just inside it: the density may vary along the tube, strays are
    # isolated where they are.
    inside = np.median(np.stack([runs[m: len(runs) - 2 * m], runs[2 * m: len(runs) - m], runs[3 * m:]]), axis=0)
    gaps = np.diff(s)[: len(inside)]
    sparse = (runs[: len(inside)] > END_SPARSE * inside) | (gaps > END_GAP_JUMP * inside / m)
    first = int(np.argmin(sparse)) if not sparse.all() else 0
    return float(s[first] - runs[first] / m)


@cache
def _blas() -> ThreadpoolController:
    """The BLAS libraries loaded (numpy's and scipy's, both loaded by this module's imports): looking them
    up costs about a millisecond, which ``threadpool_limits`` pays on every call -- a scene's fits make
    thousands."""
    return ThreadpoolController()


def refine(points: np.ndarray, spine: BSpline, radius: BSpline, **kwargs) -> RefineResult:
    """Fit spine and radius to the points by robust Gauss-Newton (see :func:`_refine`).

    The dense systems have only a few hundred unknowns; BLAS threads cost far more than they save on
    them (and thrash on a busy machine), so the fit runs with one BLAS thread.
    """
    with _blas().limit(limits=1, user_api="blas"):
        return _refine(points, spine, radius, **kwargs)


def _refine(points: np.ndarray, spine: BSpline, radius: BSpline, *, closed: bool, spine_segments: int,
           radius_segments: int | None, iterations: int = REFINE_ITERATIONS,
           reach: float = 0.0) -> RefineResult:
    """Fit spine and radius to the points by robust Gauss-Newton.

    A large cloud is first fitted through a seeded subset of ``SUBSET_POINTS``: the passes that
    still move the spine and its ends run on few points, and those on all points start converged.

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
        Most Gauss-Newton passes (on the subset, and again on all points).
    reach : float
        How far (in length units) an open spine may grow past each end per pass; it is then trimmed
        to where the footpoints actually lie, so that it ends where the tube ends.

    Returns
    -------
    RefineResult
    """
    options = {"closed": closed, "spine_segments": spine_segments, "radius_segments": radius_segments,
               "iterations": iterations, "reach": reach}
    subset = len(points) > SUBSET_FACTOR * SUBSET_POINTS
    if subset:
        pick = np.random.default_rng(0).choice(len(points), SUBSET_POINTS, replace=False)
        spine, radius, _, _ = _passes(points[np.sort(pick)], spine, radius, follow=False, **options)
    spine, radius, inlier, t = _passes(points, spine, radius, follow=subset, **options)
    # The last pass's footpoints, carried through its trim, are each point's on this spine.
    t, res = footpoints(points, spine, radius, closed=closed, start=t)
    return RefineResult(spine, radius, t, res, inlier, iterations)


def _passes(points, spine, radius, *, closed, spine_segments, radius_segments, iterations, reach,
            follow):
    """Gauss-Newton passes until converged (see :func:`_refine`); the spine, radius, inliers and
    footpoint parameters (searched on the last pass's spine, mapped onto the returned one).

    Each pass searches every footpoint along the whole spine until one pass's step gains less than
    ``FOLLOW_GAIN`` (the spine has settled: it moves little more), or with ``follow`` (a start that has
    converged on a subset) after the first; later passes follow each footpoint from the last pass's
    (carried through the re-parameterisations), as each step's cost does.
    """
    inlier = np.ones(len(points), bool)
    history = []
    t = None
    settled = follow
    for it in range(iterations + 1):
        segs, rsegs = spine_segments, radius_segments
        if closed:
            spine, extra, to_new = arclength_reparametrize(
                spine, n_segments=segs, closed=True,
                extra=[] if rsegs is None else [(radius, rsegs)])
        else:
            # Fit on the spine continued straight for ``reach`` past each end (along its chord where
            # its end hooks, HOOK_DEGREES): points beyond the current end then meet the tube's
            # continuation, not the end sphere.  The margins without points stay straight under the
            # penalty and are trimmed off after the step.  (Never more than the spine's own length:
            # a spine shorter than the reach is no tube's.)
            ext = min(reach / max(curve_length(spine), 1e-300), 1.0)
            segs = int(np.ceil(spine_segments * (1 + 2 * ext)))
            rsegs = None if rsegs is None else int(np.ceil(radius_segments * (1 + 2 * ext)))
            spine, extra, to_new = arclength_reparametrize(
                extended(spine, ext), n_segments=segs, closed=False, a=-ext, b=1 + ext,
                extra=[] if rsegs is None else [(extended(radius), rsegs)])
        if rsegs is not None:
            radius = extra[0]
        start = to_new(t) if settled and t is not None else None
        t, res = footpoints(points, spine, radius, closed=closed, start=start)
        cut = outlier_cut(res, max(reach, 1e-12 * curve_length(spine)))
        inlier = np.abs(res - np.median(res)) <= cut
        if it < iterations:
            # Levenberg-Marquardt: accept a step only if the truncated cost (outliers count as
            # ``cut``) falls with re-computed footpoints; otherwise damp harder.  A step moves the
            # spine little, so the footpoints are followed from where they were.
            # The truncation bound reaches past the residuals' own offset: a start radius a few
            # per cent off puts every residual near the cut, and a wild step that makes them all
            # outliers would cost little more than a good one.
            bound = cut + abs(float(np.median(res)))
            cost = np.minimum(res**2, bound**2).sum()
            gain = 0.0
            system = _linearise(points, t, inlier, spine, radius, segs, rsegs, closed)
            stiff = _stiffness(system[0], spine, segs, closed, rsegs is not None)
            solver = _solver(system[0], system[2], stiff)
            lam = _gcv_smoothing(*system, stiff=stiff, solver=solver,
                                 floor=SMOOTHING * inlier.sum() / n_coefficients(segs, closed))
            for damping in LM_DAMPING:
                new_spine, new_radius = _step(system, stiff, spine, radius, segs, rsegs, closed, lam, damping,
                                              solver)
                new_t, new_res = footpoints(points, new_spine, new_radius, closed=closed, start=t)
                new_cost = np.minimum(new_res**2, bound**2).sum()
                if new_cost < cost:
                    spine, radius, t, res = new_spine, new_radius, new_t, new_res
                    gain = 1.0 - new_cost / cost
                    break
            settled |= gain < FOLLOW_GAIN
        if not closed:
            length = curve_length(spine)
            near = np.abs(res - np.median(res)) <= END_SIGMAS / OUTLIER_SIGMAS * cut
            ti = np.sort(t[near]) * length
            lo = max(_end(ti), 0.0) / length
            hi = min(length - _end(length - ti[::-1]), length) / length
            if not hi - lo > END_GAPS / max(len(ti), 1):
                raise ReconstructionError("the fitted spine shrank to a point: the points do not follow "
                                          "a curve — the input is not a tube")
            ends = np.array([lo * length, (1 - hi) * length])
            spine, extra, to_new = arclength_reparametrize(
                spine, n_segments=spine_segments, closed=False, a=lo, b=hi,
                extra=[] if rsegs is None else [(radius, radius_segments)])
            if rsegs is not None:
                radius = extra[0]
            t = to_new(t)
        else:
            ends = np.zeros(2)  # nothing to trim on a loop
        if it < iterations:
            # Growing and trimming the ends perturbs the fit a little each pass, so "converged" means
            # the ends and the pass's gain have stopped changing, not that the gain is zero -- or
            # that they repeat those of a recent pass: the fit then cycles (e.g. GCV alternating
            # between two penalty weights) and further passes only go round.
            if any(abs(gain - g) < CONVERGED_GAIN
                   and np.abs(ends - e).max() < CONVERGED_END * max(reach, 1e-300)
                   for g, e in history[-CYCLE_PASSES:]):
                break
            history.append((gain, ends))
    return spine, radius, inlier, t


def _linearise(points, t, inlier, spine, radius, segs, rsegs, closed):
    """Normal equations of ``e_i = |P_i - C(t_i)| - r(t_i)`` in the coefficients, ``t_i`` fixed.

    Outliers have weight zero, inliers weight one.

    Returns
    -------
    JtWJ, g, Pen : dense arrays -- ``J^T W J``, ``J^T W e`` and the block second-difference penalty
    x : ndarray -- current coefficients (spine x, y, z blocks, then radius)
    rss : float -- ``sum w e^2``
    nw : float -- total weight
    """
    # Only the inliers count; in the order of t, the points of one knot interval are contiguous.
    keep = np.flatnonzero(inlier)
    keep = keep[np.argsort(t[keep], kind="stable")]
    points, t = points[keep], t[keep]
    n = len(points)
    m = n_coefficients(segs, closed)
    diff = points - spine(t)
    dist = np.maximum(np.linalg.norm(diff, axis=1), 1e-300)
    u = diff / dist[:, None]
    e = dist - radius(t)
    # Row i of the Jacobian J has non-zeros only at the basis functions of t_i: -u_i B(t_i) in each
    # spine block and -B_r(t_i) in the radius block.
    values, columns = local_basis(t, segs, closed)
    if rsegs is None:
        mr, r_values, r_columns = 1, np.ones((n, 1)), np.zeros((n, 1), np.intp)
        r_coef, r_pen = radius.c[:1], np.zeros((1, 1))
    else:
        mr = n_coefficients(rsegs, closed)
        r_values, r_columns = local_basis(t, rsegs, closed)
        r_coef, r_pen = radius.c[:mr], penalty(rsegs, closed)
    size = 3 * m + mr
    rows = -np.concatenate([u[:, [0]] * values, u[:, [1]] * values, u[:, [2]] * values, r_values], axis=1)
    cols = np.concatenate([columns, columns + m, columns + 2 * m, r_columns + 3 * m], axis=1)
    # A row's columns follow from its first spine and first radius column.
    JtWJ = _gram(rows, cols, columns[:, 0] * mr + r_columns[:, 0], size)
    JtWe = np.bincount(cols.ravel(), weights=(rows * e[:, None]).ravel(), minlength=size)
    x = np.concatenate([spine.c[:m].T.ravel(), r_coef])
    spine_pen = np.zeros((size, size))
    pen = penalty(segs, closed)
    for a in range(3):
        spine_pen[a * m:(a + 1) * m, a * m:(a + 1) * m] = pen
    # The radius function keeps a light fixed penalty (like the initial fits); only the spine's
    # smoothing is chosen from the data.
    fixed = np.zeros((size, size))
    fixed[3 * m:, 3 * m:] = SMOOTHING * n / m * r_pen
    return JtWJ + fixed, JtWe + fixed @ x, spine_pen, x, float(e @ e), float(n)


def _gram(rows, cols, key, size):
    """``J^T J`` of a sparse ``J`` given by the non-zeros ``rows`` of each row and their ``cols``.

    Consecutive rows with the same ``key`` have the same columns; each such run is one small dense
    product, added into the (size, size) result.
    """
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    stop = np.r_[start[1:], len(key)]
    blocks = np.empty((len(start), rows.shape[1], rows.shape[1]))
    for g, (lo, hi) in enumerate(zip(start, stop)):
        blocks[g] = rows[lo:hi].T @ rows[lo:hi]
    out = np.zeros((size, size))
    c = cols[start]
    np.add.at(out, (c[:, :, None], c[:, None, :]), blocks)
    return out


def _gcv_smoothing(JtWJ, g, Pen, x, rss, nw, *, stiff, floor: float, solver: BlockTridiagonal | None = None) -> float:
    """Penalty weight minimising generalised cross-validation, ``nw RSS / (nw - GCV_GAMMA tr H)^2``.

    The noise of a scan, not a fixed rule, then decides how much the spine is smoothed: straight,
    well-sampled stretches are averaged over many points while sharp bends keep their shape.  The
    search starts at ``floor``: the straight margins past the ends carry no data, and only the penalty
    holds them.  Each weight is scored on the system the step solves, ``stiff`` included (without it a
    heavy weight straightens a bend by sliding control points along the spine, which the linear model
    charges as misfit and the re-computed footpoints do not).  ``solver`` is the system's
    :func:`_solver` (made here if not given).
    """
    solver = solver or _solver(JtWJ, Pen, stiff)
    lams = floor * GCV_GRID
    rhs = g + lams[:, None] * (Pen @ x)
    if solver is None:
        # One generalised eigendecomposition (Demmler-Reinsch) makes every trial weight cheap.
        M = JtWJ + floor * Pen + stiff
        s, V = eigh(Pen, M)  # V^T M V = I, V^T Pen V = diag(s)
        shrink = 1.0 / (1.0 + (lams[:, None] - floor) * np.maximum(s, 0.0))  # of (M + (lam - floor) Pen)^-1 in V
        steps = -(shrink * (rhs @ V)) @ V.T
        dof = shrink @ np.einsum("ij,ij->j", V, JtWJ @ V)
    else:
        solver.factor(JtWJ + stiff, Pen, lams)
        steps = -solver.solve(rhs)
        dof = solver.trace_product(JtWJ)
    # dof = tr(A^-1 JtWJ).  A weight that leaves no degrees of freedom to the noise (or so few that their
    # square underflows) is not scored: computing its score anyway divided 0 by 0 where the fit was exact,
    # and warned on the console of a good run.
    fit_rss = rss + 2 * steps @ g + np.einsum("ij,ij->i", steps @ JtWJ, steps)
    room = nw - GCV_GAMMA * dof
    scored = room > 1e-150
    gcv = np.full(len(lams), np.inf)
    gcv[scored] = nw * np.maximum(fit_rss[scored], 0.0) / room[scored] ** 2
    return float(lams[int(np.argmin(gcv))]) if np.isfinite(gcv).any() else float(floor)


def _solver(JtWJ, Pen, stiff) -> BlockTridiagonal | None:
    """The block-tridiagonal solver of a pass's systems, when they are large enough to gain from it
    (BANDED_UNKNOWNS): their unknowns couple only locally, and the cost then grows with the spine's
    length, not its cube."""
    if len(JtWJ) <= BANDED_UNKNOWNS:
        return None
    return BlockTridiagonal((JtWJ != 0) | (Pen != 0) | (stiff != 0))


def _tangential(spine: BSpline, m: int, closed: bool, size: int) -> np.ndarray:
    """``t t^T`` on the (x, y, z) coefficients of each control point, ``t`` the spine's unit tangent at
    the control point's Greville abscissa; zero elsewhere (the radius block)."""
    k = spine.k
    greville = np.array([spine.t[j + 1:j + k + 1].mean() for j in range(m)])
    greville = np.mod(greville, 1.0) if closed else np.clip(greville, 0.0, 1.0)
    tangent = spine.derivative()(greville)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    K = np.zeros((size, size))
    j = np.arange(m)
    for a in range(3):
        for b in range(3):
            K[a * m + j, b * m + j] = tangent[:, a] * tangent[:, b]
    return K


def _stiffness(JtWJ, spine, segs, closed, canal):
    """What every step adds to ``JtWJ`` besides the penalty: a stiffness against sliding control
    points along the spine (more on a ``canal``) and a small ridge.

    Sliding control points along the spine changes (almost) no distance -- it only re-parameterises
    the curve, which each pass does anyway -- and the second-difference penalty does not hold a
    straight stretch's shift or stretch along itself: such steps are stiffened, or rounding moves
    the spine along itself by radii and the step fails.
    """
    m = n_coefficients(segs, closed)
    scale = max(float(JtWJ.diagonal()[: 3 * m].mean()), 1e-300)
    slide = CANAL_TANGENT_STIFFNESS if canal else TANGENT_STIFFNESS
    return scale * (slide * _tangential(spine, m, closed, len(JtWJ)) + RIDGE * np.eye(len(JtWJ)))


def _step(system, stiff, spine, radius, segs, rsegs, closed, lam, damping, solver: BlockTridiagonal | None):
    """One damped Gauss-Newton step with penalty weight ``lam`` and :func:`_stiffness` ``stiff``; returns
    the new spine and radius."""
    JtWJ, g, Pen, x, _, _ = system
    m = n_coefficients(segs, closed)
    A = JtWJ + damping * np.diag(JtWJ.diagonal()) + stiff
    if solver is None:
        x_new = x + np.linalg.solve(A + lam * Pen, -g - lam * (Pen @ x))
    else:
        x_new = x + solver.factor(A, Pen, [lam]).solve(-g - lam * (Pen @ x))[0]
    ctrl = x_new[: 3 * m].reshape(3, m).T
    if closed:
        ctrl = np.vstack([ctrl, ctrl[:3]])
    new_spine = BSpline(spine.t, ctrl, 3)
    rad = x_new[3 * m:]
    if rsegs is None:
        return new_spine, constant_spline(float(rad[0]))
    return new_spine, BSpline(radius.t, np.concatenate([rad, rad[:3]]) if closed else rad, 3)
