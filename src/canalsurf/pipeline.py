"""The whole reconstruction, as the paper's outline plus what a network of tubes needs:

prepare -> normals -> shrink -> thin -> skeleton -> fit each branch -> junctions -> checks -> network.

The input is first moved to its centroid and scaled to unit RMS size, so no stage sees georeferenced
coordinates or a particular unit; the result is mapped back at the end and every parameter is
reported in the input's units.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from functools import cached_property
from itertools import combinations

import numpy as np
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from . import constants as C
from ._rows import cores as _cores, one_thread
from ._validate import MIN_POINTS, as_normals, as_points, choice, in_range, positive
from .errors import InputError, ReconstructionError
from .metrics import ROUNDNESS_POINTS, angular_coverage, roundness
from .model import CanalModel
from .network import Junction, Network, classify_points
from .normals import estimate_normals, facing_inward, on_planes, point_inward, scatter_matrices, surface_noise
from .pointcloud import quantisation_noise
from .quality import POOR_GAP_RADII, branch_quality, fold, inside_others, longest_inside, scan_quality, support_gap
from .radius import curvature_radius, plausible_radius, prefer_canal, principal_curvature
from .refine import RefineResult, extended, footpoints, is_stray, outlier_cut, refine as refine_fit, robust_sigma
from .shrink import ShrinkResult, shrink, shrink_by_concentration, shrink_by_sections
from .skeleton import (MIN_BRANCH_POINTS, Skeleton, SkeletonBranch, skeletonize, with_ends_joined, with_ends_opened,
                       with_tees_mended, without_branches)
from .spine import (arclength_reparametrize, constant_spline, curvature, curve_length, polyline_arclength, pspline_fit,
                    reversed_spline, sample_arclength)

__all__ = ["reconstruct", "STAGES"]

#: Stage names, in the order ``progress`` reports them.
STAGES = ("normals", "shrink", "thin", "skeleton", "fit", "junctions", "residual")

log = logging.getLogger(__name__)

#: A branch whose inlier RMS distance from its fitted surface exceeds this share of its radius is not a
#: tube: uniform noise of +-10 % of the radius, the most the tests allow, gives 6 %; a fit through a
#: blob of points 20 - 25 %.
MAX_RELATIVE_RESIDUAL = 0.15
#: ... or that fewer points than this lie on (the checks below need a stretch of ROUNDNESS_POINTS
#: points to measure roundness; fewer cannot show a tube from a blob)
MIN_CHECKED_POINTS = ROUNDNESS_POINTS
#: ... or whose sectors around the spine lie systematically farther off it than this share of its
#: radius (:func:`canalsurf.metrics.roundness`): a scanned pipe is round to a few per cent, a box or a
#: square duct fitted by a tube is 10 - 30 % off at its corners and faces.
MAX_OUT_OF_ROUND = 0.08
#: ... or whose inlier RMS exceeds this many times the scan's own noise (:func:`_noise`) and
#: this share of its radius: a tube fitted to clutter (a box, a corner) misfits its points several
#: times the noise, a scanned tube about once (the share keeps a scan's largest tubes, whose absolute
#: noise may be above the scan's median, from being judged by its smallest).
SCAN_NOISE_RATIO = 3.0
TUBE_RELATIVE_RESIDUAL = 0.03
#: Points within this many radii (the largest meeting there) of a junction do not take part in the
#: fit of the branches that meet there: there the surface belongs to several tubes at once.
JUNCTION_EXCLUSION_RADII = 1.5
#: Before the fits, a point is given to the nearest branch only if it lies within this many of that
#: branch's radii of the first tube estimate (farther points: clutter, not fitted).
ASSIGN_RADII = 0.5
#: ... the first estimate continued this many radii past its open ends (the thin set may stop short).
ASSIGN_END_RADII = 1.0
#: A fitted open end that grew by more than this many radii past the estimate its points were taken
#: about (which reach ASSIGN_END_RADII past it) may go on: its points are taken again about the fit and
#: it is fitted again, at most MAX_GROW_ROUNDS times (a thin set that stops radii short of a tube's end
#: would otherwise cut the model short there, with nothing to show it).  An end still growing then grows
#: on once the network's branches are settled, at most GROW_ON_FITS more times (:func:`_grown_on`).
GROW_RADII = 0.5
MAX_GROW_ROUNDS = 6
GROW_ON_FITS = 3
#: Rounds of "fit, drop the branches that are no tube, join the branches they separated".
MAX_FIT_ROUNDS = 3


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
        self[stage] = round(self.get(stage, 0.0) + time.perf_counter() - start, 4)


@dataclass
class _Scan:
    """The input, normalised, with the seeded subsets the stages work on."""

    origin: np.ndarray
    scale: float
    all_pts: np.ndarray          # every point, normalised
    all_normals: np.ndarray | None
    draw: np.ndarray | None      # seeded permutation for large scans
    pts: np.ndarray              # the paper's stages' subset
    normals: np.ndarray | None


@dataclass
class _BranchFit:
    """One branch fitted in normalised coordinates: ``eq6`` is its Eq. (6) radius, the scale of its
    fit (how far its ends may grow per pass, the floor of its outlier cut)."""

    kind: str
    spine: BSpline
    radius: BSpline
    closed: bool
    ends: tuple
    eq6: float
    segments: tuple
    residual: np.ndarray
    t: np.ndarray
    points: np.ndarray
    kappa: np.ndarray | None = None
    growing: bool = False  # an open end still grew in the last of MAX_GROW_ROUNDS (see _grown_on)


def _segments(length: float, spacing: float, n_points: int) -> int:
    """Knot intervals: one per ``spacing`` of length, but enough points per interval."""
    return int(max(1, min(round(length / spacing), n_points // C.POINTS_PER_SEGMENT)))


def reconstruct(points, *, normals=None, kind: str = "auto", R: float | None = None,
                delta: float | None = None, mu: float | None = None, tau: float | None = None,
                H: float | None = None, k: int | None = None, stop: str = "auto",
                neighbours: str = "kdtree", refine: bool = True, progress=None, client=None) -> Network:
    """Reconstruct the pipe and canal surfaces of an unorganized point cloud: one tube or a network.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        The scan.  Any units and placement; one tube, a branching network, several tubes, and
        clutter (points on no tube are left out).
    normals : array_like, shape (N, 3), optional
        Outward unit normals.  Estimated (regression planes, oriented outward) when not given.
    kind : {"auto", "pipe", "canal"}
        ``"pipe"``: constant radius, Algorithm 1.  ``"canal"``: radius function, Algorithm 2.
        ``"auto"``: Algorithm 2, then per branch a pipe unless a radius function is clearly better.
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
        Fit spine and radius of each branch to its points after the paper's pipeline (default).
        ``False`` returns the paper's own result: spline through the thin set, Eq. (6) or the fitted
        ``r_i``.
    progress : callable, optional
        Called with the name of each stage (see ``STAGES``) as it starts.
    client : distributed.Client, optional
        Fit the branches as Dask tasks on this client's workers (:func:`canalsurf.cluster.connect`),
        one task per branch.  The result is the same as without.  Default: in this process, or over
        the cores in forked processes when a scene has many branches.

    Returns
    -------
    Network
        Branches (each a pipe or canal surface), junctions, parameters and diagnostics.  A single
        tube is a network of one branch, which also answers ``kind``, ``spine``, ``radius``, ...

    Raises
    ------
    InputError
        Invalid points or parameters.
    ReconstructionError
        The points are valid but no part of them forms a tube the method can follow.

    Examples
    --------
    >>> import canalsurf
    >>> tube = canalsurf.make_tube("fig9-pipe", rng=1)
    >>> model = canalsurf.reconstruct(tube.points)
    >>> len(model.branches), model.kind, round(model.mean_radius, 1)
    (1, 'pipe', 1.0)
    """
    timer = _Timer(progress)
    kind = choice(kind, "kind", ("auto", "pipe", "canal"))
    stop = choice(stop, "stop", ("auto", "paper"))
    neighbours = choice(neighbours, "neighbours", ("kdtree", "gauss"))
    R, delta, H = positive(R, "R"), positive(delta, "delta"), positive(H, "H")
    mu = in_range(mu, "mu", 0.0, 1.0)
    tau = in_range(tau, "tau", -1.0, 1.0)
    if not isinstance(refine, bool):
        raise InputError(f"refine must be True or False, got {refine!r}")
    scan = _prepare(points, normals, k)
    with timer("normals"):
        quantum = quantisation_noise(scan.all_pts)
    given = {"R": R, "delta": delta, "mu": mu, "tau": tau, "H": H}
    # Denser subsets and finer scales choose their own R, delta and H: not with the paper's rule, nor
    # with the scale given.
    automatic = stop == "auto" and R is None and delta is None and H is None
    first = _resolved(scan, k, given, kind=kind, stop=stop, neighbours=neighbours, quantum=quantum,
                      timer=timer, densify=automatic)
    passes = [first]
    if automatic:
        passes = _finer_scales(scan, first, k, given, kind=kind, neighbours=neighbours, quantum=quantum,
                               timer=timer)
    with timer("normals"):
        noise = _noise(scan, passes, quantum)
    built = _built(scan, passes, kind=kind, refine=refine, noise=noise, quantum=quantum, client=client, timer=timer)
    run = _beside_pass(scan, built.beside, k, given, kind=kind, neighbours=neighbours, quantum=quantum,
                       timer=timer) if automatic and refine else None
    if run is not None:
        try:
            built = _built(scan, passes + [run], kind=kind, refine=refine, noise=noise, quantum=quantum,
                           client=client, timer=timer)
            passes = passes + [run]
        except ReconstructionError as exc:
            log.info("with the points beside the tubes, no network is found (%s): the one without is kept", exc)
    branches, summary, fits, junction_points, fit_pts = (built.branches, built.summary, built.fits,
                                                          built.junction_points, built.fit_pts)
    network = _to_input_units(branches, junction_points, fits, scan)
    network.parameters = _reported_parameters(first.p, scan.scale, k=k, r0=first.r0, stop=stop,
                                              neighbours=neighbours, refine=refine)
    sr = first.sr
    network.diagnostics = {
        "n_points": len(scan.all_pts), "n_shrink_points": sum(len(s.scan.pts) for s in passes),
        "n_fit_points": len(fit_pts),
        "iterations": sr.iterations, "break_count": int(sr.break_counts[-1]), "stop_rule": sr.stop_rule,
        "points_reached_spine": sum(len(s.thin) for s in passes),
        "eq6_radius": float(first.r_i.mean()) * scan.scale,
        "scale_radii": [s.r0 * scan.scale for s in passes],
        "n_branches": len(network.branches),
        "n_junctions": len(network.junctions), "n_components": len(network.components),
        **{key: (val * scan.scale if key in ("rms_residual", "inlier_rms_residual", "noise_sigma", "scan_noise")
                 and val is not None else val)
           for key, val in summary.items()},
        "seconds": dict(timer),
    }
    network.stages = {"normals": first.nrm,
                      "shrunk": np.concatenate([s.sr.points[s.kept] for s in passes]) * scan.scale + scan.origin,
                      "thin": np.concatenate([s.thin for s in passes]) * scan.scale + scan.origin,
                      "break_counts": sr.break_counts}
    return network


# --------------------------------------------------------------------------------------------------
# the paper's stages, at one scale or several


@dataclass
class _Built:
    """A network built from the passes' thin sets: its fits and junctions (normalised), its branches
    described, the summary of the scan's checks, the points fitted, and the points beside its tubes."""

    fits: list
    junction_points: np.ndarray
    branches: list
    summary: dict
    fit_pts: np.ndarray
    beside: np.ndarray


def _built(scan: _Scan, passes: list, *, kind: str, refine: bool, noise: float, quantum: float, client,
           timer: _Timer) -> _Built:
    """Skeleton, fits, junctions and checks of the passes' thin sets (the stages after the paper's)."""
    with timer("skeleton"):
        skel = skeletonize(np.concatenate([s.thin for s in passes]), np.concatenate([s.r_i for s in passes]),
                           spacing=np.concatenate([np.full(len(s.thin), C.ORDER_VOXEL_PER_H * s.p["H"])
                                                   for s in passes]))
    fit_pts, support = _fit_points(scan, passes, len(skel.branches))
    with timer("fit"):
        skel, fits = _fit_network(fit_pts, skel, kind=kind, refine=refine, noise=noise, quantum=quantum,
                                  client=client, **support)
    with timer("junctions"):
        fits, junction_points = _join_at_junctions(fits, skel)
        fits, junction_points, left_out = _unfolded(fits, junction_points)
    with timer("residual"):
        branches, summary, on, beside = _check_and_describe(scan, fits, noise, junction_points, left_out)
        whys = _surface_goes_on(scan, passes[0], fits, branches, on, beside)
        if any(whys):
            fits, junction_points, more = _without(fits, junction_points, whys)
            left_out = [*left_out, *more]
            branches, summary, on, beside = _check_and_describe(scan, fits, noise, junction_points, left_out)
    return _Built(fits, junction_points, branches, summary, fit_pts, beside)


@dataclass
class _Pass:
    """The paper's stages (normals, shrinking, thinning) run on one subset of the scan at one scale.

    ``scan`` holds the points of the pass (``scan.pts`` its subset); ``curved`` indexes the subset's
    points that may shrink, ``kappa`` their larger principal curvature; ``neighbours`` holds each subset
    point's nearest points, itself first (``ORIENT_NEIGHBOURS + 1``); ``thin`` and ``r_i`` are the thin
    set and the distance of each of its points' input point (of ``scan.pts[curved[kept]]``).
    """

    scan: _Scan
    nrm: np.ndarray
    r0: float
    p: dict
    curved: np.ndarray
    kappa: np.ndarray
    neighbours: np.ndarray
    sr: ShrinkResult
    kept: np.ndarray
    thin: np.ndarray
    r_i: np.ndarray
    pool: np.ndarray | None = None  # indices of the scan's points the pass worked on (None: all)

    @cached_property
    def skeleton(self) -> Skeleton | None:
        """The skeleton of the thin set (None: it has none)."""
        try:
            return skeletonize(self.thin, self.r_i, spacing=C.ORDER_VOXEL_PER_H * self.p["H"])
        except ReconstructionError:
            return None

    @property
    def in_a_spot(self) -> bool:
        """Whether the thin set gathered in a spot narrower than the distances its points came from (a ball
        or a blob, shrunk to its middle): no denser subset or finer scale makes a curve of it."""
        return len(self.thin) > 0 and (float(np.linalg.norm(np.ptp(self.thin, axis=0)))
                                       < SPOT_RADII * float(np.median(self.r_i)))

    @cached_property
    def nodes(self) -> tuple | None:
        """A KD-tree of the nodes of the skeleton of the thin set, and their radii (None: it has none).
        Which points the pass explains is asked several times (:func:`_explained`)."""
        if self.skeleton is None:
            return None
        branches = self.skeleton.branches
        return cKDTree(np.concatenate([b.points for b in branches])), np.concatenate([b.radius for b in branches])

    @cached_property
    def past_ends(self) -> tuple | None:
        """:attr:`nodes` of the skeleton continued straight past its open ends (:func:`_past_end`); None
        where it has none."""
        if self.skeleton is None:
            return None
        nodes = [_past_end(b, end) for b in self.skeleton.branches if not b.closed
                 for end in (0, -1) if b.ends[end] is None]
        pts = np.concatenate([p for p, _ in nodes]) if nodes else np.empty((0, 3))
        return (cKDTree(pts), np.concatenate([r for _, r in nodes])) if len(pts) else None


#: A thin set stops short of a tube's open end, where the points meet no other side to shrink to, by about
#: a radius.  Whether a further pass runs is decided without the points on its skeleton continued straight
#: this many radii past each open end, in steps of a quarter radius; else a clean tube's end can call a
#: pass that finds no tube there and only costs time.
PAST_END_RADII = 2.0


def _past_end(branch: SkeletonBranch, end: int) -> tuple:
    """Nodes continuing a skeleton ``branch`` straight past its first (``end`` 0) or last (-1) vertex,
    along its chord over the last radius there, and their radii (the end vertex's)."""
    pts = branch.points if end == -1 else branch.points[::-1]
    r = float(branch.radius[end])
    inner = pts[::-1][min(int(np.searchsorted(polyline_arclength(pts[::-1]), r)), len(pts) - 1)]
    chord = pts[-1] - inner
    if not np.linalg.norm(chord) > 0:
        return np.empty((0, 3)), np.empty(0)
    steps = np.arange(1, int(4 * PAST_END_RADII) + 1) * r / 4
    return pts[-1] + steps[:, None] * chord / np.linalg.norm(chord), np.full(len(steps), r)


def _paper_stages(scan: _Scan, k, given: dict, *, kind: str, stop: str, neighbours: str, quantum: float,
                  timer: _Timer, fallback: bool, widest: float = 1.0) -> _Pass:
    """Normals, parameters, shrinking and thinning of ``scan``'s subset (r0 over the points that curve
    at least as tightly as a tube of radius ``widest``).

    With ``fallback``, normals that cannot be trusted (coordinates quantised to steps near the radius)
    give way to cross-sections of the points themselves.
    """
    algo = "pipe" if kind == "pipe" else "canal"
    with timer("normals"):
        scan, nrm, r0, area_per_point, curved, kappa, nbr = _normals(scan, k, flat_out=stop == "auto",
                                                                quantum=quantum, widest=widest)
    p = _parameters(r0, area_per_point, scan.scale, algo=algo, stop=stop, **given)
    with timer("shrink"):
        try:
            sr, kept = _shrink(scan.pts[curved], nrm[curved], p, r0, algo=algo, stop=stop, neighbours=neighbours)
        except ReconstructionError:
            if stop != "auto" or not fallback:
                raise
            # The normals could not be trusted (coordinates quantised to steps near the radius):
            # cross-sections of the points themselves find the axes.
            log.info("the points shifted along their normals do not gather: each point moves to the "
                     "centre of a circle fitted to its neighbourhood's cross-section")
            sr, tube = shrink_by_sections(scan.pts)
            r0 = float(np.median(sr.distance[tube])) if tube.any() else np.inf
            if not 0 < r0 < np.inf:
                raise
            curved = np.flatnonzero(tube & (sr.distance < C.MAX_SHRINK_PER_RADIUS * r0))
            p = _parameters(r0, area_per_point, scan.scale, algo=algo, stop=stop, **given)
            sr = replace(sr, points=sr.points[curved], distance=sr.distance[curved])
            kept = np.arange(len(curved))
    with timer("thin"):
        thin = _thin(sr.points[kept], p["H"])
        r_i = np.linalg.norm(scan.pts[curved[kept]] - thin, axis=1)
    return _Pass(scan, nrm, r0, p, curved, kappa, nbr, sr, kept, thin, r_i)


#: A pass's thin set gathered in one spot (a ball shrunk to its middle) when it spans less than this many
#: times the median distance its points came from: half the shortest tree the skeleton keeps
#: (skeleton.MIN_TREE_RADII).  A ball's spanned 0.33 - 0.38 of it, a tube as long as its radius 0.94.
SPOT_RADII = 0.5


#: After the paper's stages, a point of the scan is explained when it lies within this many of the local
#: radius of the skeleton found (inside the tube, or on its surface with a quarter radius to spare).
EXPLAINED_RADII = 1.25
#: Further passes at finer scales, at most (a plant's pipes span radii of 1 - 30 cm: each pass takes the
#: median radius of what is left, about halving it).
MAX_SCALE_PASSES = 4
#: A further pass runs only on at least this many unexplained points, and this share of the scan.
MIN_PASS_POINTS = C.MAX_SHRINK_POINTS
MIN_PASS_SHARE = 0.02
#: What a pass leaves unexplained is first estimated on this many points of the draw: far below what
#: a further pass needs (most scans are one tube, explained whole), the other points are not queried.
EXPLAINED_SAMPLE = 50_000


#: A pass whose skeleton explains less than this share of the subset's curved points saw the scan too
#: sparsely (a scene of many tubes spreads a subset thinly over each): it runs again on a subset
#: DENSIFY times as large, up to MAX_STAGE_POINTS.  Each tube's points are explained once it is resolved.
MIN_EXPLAINED_SHARE = 0.5
DENSIFY = 4
MAX_STAGE_POINTS = 320_000


def _subset(scan: _Scan, n: int) -> _Scan:
    """``scan`` with its stages' subset the first ``n`` points of its draw (all, if it has no draw)."""
    if scan.draw is None:
        return replace(scan, pts=scan.all_pts, normals=scan.all_normals)
    pick = np.sort(scan.draw[:n])
    return replace(scan, pts=scan.all_pts[pick], normals=None if scan.all_normals is None else scan.all_normals[pick])


def _resolved(scan: _Scan, k, given: dict, *, densify: bool, **options) -> _Pass:
    """:func:`_paper_stages` on ``scan``'s subset, and with ``densify`` on denser subsets until its
    skeleton explains MIN_EXPLAINED_SHARE of the curved points (or no more points may be drawn).

    A subset too sparse for the tubes reads every neighbourhood as wider than they are: the curvature
    radius r0 follows the neighbourhoods' size, not the tubes', and the parameters derived from it
    shrink the points to nothing that explains them.
    """
    failed = None  # the sparsest subset whose normals did not gather
    while True:
        most = min(len(scan.all_pts), MAX_STAGE_POINTS)
        last = not densify or scan.draw is None or len(scan.pts) >= most
        try:
            # Normals that do not gather on a sparse subset of a scene may be its sparseness, which a
            # denser subset resolves: the fallback only once none does.
            run = _paper_stages(scan, k, given, fallback=last and failed is None, **options)
        except ReconstructionError:
            if not last:
                failed = scan if failed is None else failed
            elif failed is None:
                raise
            else:
                # They gather at no density (a one-sided scan of bark, coordinates quantised near the
                # radius): cross-sections, on the sparsest subset, whose neighbourhoods span most of a tube.
                return _paper_stages(failed, k, given, fallback=True, **options)
        else:
            if last:
                return run
            if run.in_a_spot:
                # Each denser subset of a ball costs more than the last (its points meet all at once, every
                # one within reach of every other) and gathers in the same spot.
                raise ReconstructionError("the shrunk cloud gathered in one spot, not along a curve (a ball or a "
                                          "blob) — the input is not a tube")
            share = _explained_share(run)
            if share >= MIN_EXPLAINED_SHARE:
                return run
            log.info("the skeleton explains %.0f%% of the %d curved points of the subset: drawing it denser",
                     100 * share, len(run.curved))
            scan = run.scan  # with the subset _normals may have grown
        scan = _subset(scan, min(DENSIFY * len(scan.pts), most))


def _explained_share(run: _Pass) -> float:
    """The share of the pass's curved subset points its skeleton explains (:func:`_explained`)."""
    return float(_explained(run.scan.pts[run.curved], run).mean()) if len(run.curved) else 0.0


def _explained(points: np.ndarray, run: _Pass, *, on_surface: bool = False) -> np.ndarray:
    """Which ``points`` lie in or on a tube of the pass's skeleton (within EXPLAINED_RADII of its radius);
    with ``on_surface``, only those on its surface (as far from its spine as EXPLAINED_RADII - 1 of its
    radius).

    What a pass hands on to a finer one is what is not on a surface it found: at a coarse scale a rack of
    thin pipes can shrink to one fat branch across them, which is no tube but holds their points inside.
    """
    return _near(points, run.nodes, on_surface)


def _near(points: np.ndarray, nodes: tuple | None, on_surface: bool) -> np.ndarray:
    """:func:`_explained` by the ``nodes`` (a KD-tree and the nodes' radii; None: none)."""
    if nodes is None:
        return np.zeros(len(points), bool)
    tree, node_r = nodes
    d, i = tree.query(points, workers=-1)
    if on_surface:
        return np.abs(d - node_r[i]) < (EXPLAINED_RADII - 1) * node_r[i]
    return d < EXPLAINED_RADII * node_r[i]


def _finer_scales(scan: _Scan, first: _Pass, k, given: dict, *, kind: str, neighbours: str, quantum: float,
                  timer: _Timer) -> list:
    """The first pass, and further passes of the paper's stages on the points that lie on no surface an
    earlier pass found.

    One scale cannot serve a scene of tubes of very different radii: the subset and the parameters
    (R, delta, H) follow the first radius estimate r0, the median over the scene, and a tube a few
    times thinner is too sparse there for its normals to curve (it reads as flat) or shrinks with a
    step that overshoots its spine.  What the first pass left unexplained is drawn again, DENSIFY times
    as densely, and run again at its own scale, until too little is left or a pass explains too little
    of what it saw.  A pass may find tubes wider than the first's median scale: the first pass stops
    shrinking once its many thinner tubes have met, before a wider tube's sides do.  The work grows
    with the tubes found, not with the points.
    """
    runs = [first]
    left = np.ones(len(scan.all_pts), bool)
    run, coarser = first, first.r0
    for _ in range(MAX_SCALE_PASSES - 1):
        # A further pass that would not run (too few points left, or a scan no larger than one subset,
        # with no denser one to draw) runs all the same if the last left a tube its normals faced into:
        # of several touching in a row, each pass may face into another.
        inward = functools.cache(functools.partial(_left_facing_inward, run, tuple(runs)))
        least = max(MIN_PASS_POINTS, MIN_PASS_SHARE * len(left))
        with timer("normals"):
            few = scan.draw is None
            if not few:
                sample = scan.draw[:EXPLAINED_SAMPLE]
                sample = sample[left[sample]]
                unexplained = int((~_explained(scan.all_pts[sample], run, on_surface=True)
                                   & ~_near(scan.all_pts[sample], run.past_ends, on_surface=True)).sum())
                few = unexplained * len(left) / min(EXPLAINED_SAMPLE, len(left)) < least / 2
            if few and not inward():
                break
            left[left] = ~_explained(scan.all_pts[left], run, on_surface=True)
        forced = few or left.sum() < least
        if forced and not inward():
            break  # too little left
        pool = np.flatnonzero(left)
        local = np.cumsum(left) - 1  # index in the pool of each point of it
        draw = None if scan.draw is None else local[scan.draw[left[scan.draw]]]
        # DENSIFY times as densely as the last pass drew from its points: what it left is what it saw
        # too sparsely, tubes about half as thin (or clutter).
        n = DENSIFY * len(run.scan.pts) / len(run.scan.all_pts) * len(pool)
        sub = _subset(_Scan(scan.origin, scan.scale, scan.all_pts[pool],
                            None if scan.all_normals is None else scan.all_normals[pool], draw, None, None),
                      int(min(max(n, C.MAX_SHRINK_POINTS), MAX_STAGE_POINTS)))
        try:
            # Its r0 over the points that curve at least as tightly as the last scale: a scene's floor
            # and boxes, most of what is left, would otherwise set it.  A tube the last pass's normals
            # faced into may be wider than the last scale.
            run = _paper_stages(sub, k, given, kind=kind, stop="auto", neighbours=neighbours, quantum=quantum,
                                timer=timer, fallback=False, widest=1.0 if forced else coarser)
        except ReconstructionError as exc:
            log.info("no further tubes among the %d points left unexplained: %s", len(pool), exc)
            break
        log.info("a further pass on %d points left unexplained: r0 = %.4g, %d thin points",
                 len(pool), run.r0 * scan.scale, len(run.thin))
        run.pool = pool
        share = _explained_share(run)
        last = share < MIN_EXPLAINED_SHARE
        if last:
            # Most of what it saw is clutter, or tubes too sparse for it: the tubes it resolved stay, its
            # other thin points go, and what it leaves is drawn no further.
            log.info("the skeleton of the further pass explains %.0f%% of its %d curved points: the last pass",
                     100 * share, len(run.curved))
            run = _trimmed(run)
            if len(run.thin) < MIN_BRANCH_POINTS:
                break  # it resolved no tube: the last pass keeps all it found
        # What the last pass could not explain is this one's now: its thin points from those points (a
        # tube too thin for that scale, shrunk past its spine) would only link tubes that are apart.
        runs[-1] = _trimmed(runs[-1])
        runs.append(run)
        coarser = run.r0
        if last:
            break
    return runs


#: A further pass runs on fewer points than MIN_PASS_POINTS, or on a scan no larger than one subset, when
#: points the last pass's normals faced into that lie on the surface of no tube found so far are this
#: share of its subset.  Tubes left so, of two to five touching pipes, were 6 - 39 %; the remnants of a
#: found tube past its skeleton's end, which a further pass made a false tube of, 0.7 - 3.4 %.
INWARD_LEFT_SHARE = 0.05


def _left_facing_inward(run: _Pass, runs: tuple) -> bool:
    """Whether ``run`` left unexplained by ``runs`` (the passes so far) a tube of its subset that its
    normals faced into (:func:`canalsurf.normals.facing_inward`): shrunk outward, its points gathered
    nowhere.  A further pass estimates their normals apart from the tube they touch."""
    pts = run.scan.pts
    facing = facing_inward(pts, run.nrm, run.neighbours)
    if not facing.any():
        return False
    on = pts[facing]
    left = np.logical_and.reduce([~_explained(on, r, on_surface=True) & ~_near(on, r.past_ends, on_surface=True)
                                  for r in runs]).sum()
    log.info("%d points of the subset lie on a tube their normals face into; %d of them on no tube's surface",
             facing.sum(), left)
    return left >= INWARD_LEFT_SHARE * len(pts)


def _trimmed(run: _Pass) -> _Pass:
    """The pass with only the thin points whose own input points its skeleton explains."""
    ok = _explained(run.scan.pts[run.curved[run.kept]], run)
    return replace(run, kept=run.kept[ok], thin=run.thin[ok], r_i=run.r_i[ok])


# --------------------------------------------------------------------------------------------------
# prepare, normals, parameters, shrink, thin


def _prepare(points, normals, k) -> _Scan:
    """Validate, normalise, and draw the seeded subsets of a large scan."""
    raw = as_points(points)
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
    # paper's stages see MAX_SHRINK_POINTS (more for long, thin tubes and scenes) -- k-nearest-neighbour
    # normals and curvature get noisier, not better, as the density grows -- and the final fit at most
    # MAX_FIT_POINTS, a superset from the same draw.
    draw = np.random.default_rng(0).permutation(len(pts)) if len(pts) > C.MAX_SHRINK_POINTS else None
    if draw is None:
        return _Scan(origin, scale, pts, given, None, pts, given)
    pick = np.sort(draw[: C.MAX_SHRINK_POINTS])
    return _Scan(origin, scale, pts, given, draw, pts[pick], None if given is None else given[pick])


def _normals(scan: _Scan, k, *, flat_out: bool, quantum: float = 0.0, widest: float = 1.0):
    """Normals, the first radius estimate r0, the area per point, the points that may shrink, their
    curvature and each point's nearest points (ORIENT_NEIGHBOURS + 1, itself first).

    r0 is taken over the points that curve at least as tightly as a tube of radius ``widest`` (in the
    normalised units: the cloud's RMS size is 1; a finer pass gives the last pass's r0).

    A long, thin tube (or a scene of many) spreads a fixed-size subset too thinly around each
    circumference: the subset then grows (once) to be as dense, relative to the radius, as a usual one.
    With ``flat_out``, points whose surface is flatter than a tube of radius ``MAX_SHRINK_PER_RADIUS
    r0`` (a floor, a wall, a box's face) do not shrink: they can reach no spine within the shrink
    bound, and a floor's orientation is arbitrary -- shrinking it would drive it into the tubes above.
    """
    for attempt in range(2):
        # One search serves the normals, the curvature, the spacing and the noise (16 neighbours each).
        tree = cKDTree(scan.pts)
        dist, nbr = tree.query(scan.pts, k=min(C.NORMAL_NEIGHBOURS, len(scan.pts)), workers=-1)
        if scan.normals is None:
            own = nbr if k is None or min(int(k), len(scan.pts)) == nbr.shape[1] else \
                tree.query(scan.pts, k=min(int(k), len(scan.pts)), workers=-1)[1]
            nrm = estimate_normals(scan.pts, neighbours=own)
        else:
            nrm = scan.normals
            if point_inward(scan.pts, nrm, nbr[:, :C.ORIENT_NEIGHBOURS]):
                log.warning("the given normals point into the tube; they are used flipped")
                nrm = -nrm
        kappa = principal_curvature(scan.pts, nrm, neighbours=nbr)
        r0 = curvature_radius(scan.pts, nrm, kappa=kappa)
        if flat_out:
            # Flat clutter (a floor, walls) pulls the median towards large radii: take it again over
            # the points that curve at all -- no tube is wider than the cloud, whose RMS distance from
            # its centre is 1 here -- and then over those curved enough to lie on a tube.
            r0 = curvature_radius(scan.pts, nrm, kappa=kappa[kappa * widest >= 1.0])
            if np.isfinite(r0):
                r0 = curvature_radius(scan.pts, nrm, kappa=kappa[kappa * C.MAX_SHRINK_PER_RADIUS * r0 >= 1.0])
        # Mean area per point is pi d_k^2 / k for the k-th neighbour distance d_k.
        area_per_point = np.pi * np.mean(dist[:, -1] ** 2) / C.NORMAL_NEIGHBOURS
        if scan.draw is None or attempt or not np.isfinite(r0):
            break
        wanted = area_per_point / (C.MAX_SPACING_PER_RADIUS * r0) ** 2 * len(scan.pts)
        grown = int(min(wanted, C.MAX_FIT_POINTS, len(scan.all_pts)))
        if grown <= len(scan.pts):
            break
        pick = np.sort(scan.draw[:grown])
        scan = _Scan(scan.origin, scan.scale, scan.all_pts, scan.all_normals, scan.draw, scan.all_pts[pick],
                     None if scan.all_normals is None else scan.all_normals[pick])
    if not np.isfinite(r0) or r0 > 10:
        raise ReconstructionError("the surface is flat (no curvature around a spine) — "
                                  "the input is not a tube")
    if not flat_out:
        curved = np.arange(len(scan.pts))
    else:
        curved = np.flatnonzero(kappa * C.MAX_SHRINK_PER_RADIUS * r0 >= 1.0)
        if len(curved) < MIN_POINTS:
            raise ReconstructionError("the surface is flat (no curvature around a spine) — "
                                      "the input is not a tube")
    if flat_out:
        # Points on a large plane (ground, a wall, a sign) are clutter even where their neighbourhood
        # reaches a tube and reads as curved.  The tubes' noise, not the floor's: a quantised floor is
        # exactly flat and would read as no noise.
        noise = max(_scan_noise(scan.pts, nbr[curved]), quantum)
        flat = np.ones(len(scan.pts), bool)
        flat[curved] = False
        flat[on_planes(scan.pts, nrm, np.flatnonzero(flat), C.PLANE_TOLERANCE_NOISES * noise)] = True
        curved = curved[~flat[curved]]
    return scan, nrm, r0, area_per_point, curved, kappa, np.ascontiguousarray(nbr[:, :C.ORIENT_NEIGHBOURS + 1])


def _scan_noise(points: np.ndarray, nbr: np.ndarray) -> float:
    """The median RMS offset of each point's neighbours from their regression plane: how far off a
    plane its points may lie (:func:`canalsurf.normals.on_planes`).  On a pass's subset it also takes in
    the tubes' curvature, so it is not the noise a fit is judged against (:func:`_noise`)."""
    if not len(nbr):
        return 0.0
    cov = scatter_matrices(points, nbr) / nbr.shape[1]
    return float(np.sqrt(max(np.median(np.linalg.eigvalsh(cov)[:, 0]), 0.0)))


#: The scan's noise is measured about this many points (a seeded sample) of the passes' curved points ...
NOISE_SEEDS = 2_000
#: ... in neighbourhoods among at most this many of the scan's points (a seeded subset of a larger one):
#: neighbourhoods from the whole scan reach a fraction of the radius even beside a scene's thinnest tubes.
NOISE_POINTS = 2_000_000


def _noise(scan: _Scan, passes: list, quantum: float) -> float:
    """The scan's own noise (:func:`canalsurf.normals.surface_noise`), at least its grid's
    (``quantum``): what a good fit's residual must come close to, independent of any tube fitted."""
    seeds = np.concatenate([s.scan.pts[s.curved] for s in passes])
    seeds = seeds[np.random.default_rng(0).permutation(len(seeds))[:NOISE_SEEDS]]
    points = scan.all_pts
    if scan.draw is not None and len(points) > NOISE_POINTS:
        points = points[np.sort(scan.draw[:NOISE_POINTS])]
    return max(surface_noise(points, seeds), quantum)


def _parameters(r0, area_per_point, scale, *, R, delta, mu, tau, H, algo, stop) -> dict:
    """The paper's parameters in normalised units: the given ones, or the automatic defaults."""
    # Spacing of the collapsed cloud: all points on a spine of length area / (2 pi r0).
    collapsed = area_per_point / (2 * np.pi * r0)
    p = {
        "R": R / scale if R else max(C.R_PER_RADIUS * r0, C.R_PER_COLLAPSED_SPACING * collapsed),
        "delta": delta / scale if delta else C.DELTA_PER_RADIUS * r0,
        "mu": mu if mu is not None else (C.MU if algo == "pipe" or stop == "paper" else C.MU_CANAL_AUTO),
        "tau": tau if tau is not None else C.TAU,
        "H": H / scale if H else C.H_PER_RADIUS * r0,
    }
    log.info("first radius estimate r0 = %.4g; R = %.4g, delta = %.4g, mu = %.3g, tau = %.3g, H = %.4g",
             r0 * scale, p["R"] * scale, p["delta"] * scale, p["mu"], p["tau"], p["H"] * scale)
    return p


def _reported_parameters(p, scale, *, k, r0, stop, neighbours, refine) -> dict:
    parameters = {key: (val * scale if key in ("R", "delta", "H") else val) for key, val in p.items()}
    parameters.update(k=int(k or C.NORMAL_NEIGHBOURS), r0=r0 * scale, stop=stop, neighbours=neighbours,
                      refine=bool(refine))
    return parameters


def _shrink(pts, nrm, p, r0, *, algo, stop, neighbours):
    """Shrinking (Algorithm 1 or 2), with the one-sided fallback; the result and the kept indices."""
    sr = shrink(pts, nrm, R=p["R"], delta=p["delta"], mu=p["mu"], tau=p["tau"], kind=algo, stop=stop,
                neighbours=neighbours, max_distance=C.MAX_SHRINK_PER_RADIUS * r0)
    log.info("shrinking: %d moves, break count %d, stopped by %s", sr.iterations, sr.break_counts[-1],
             sr.stop_rule)
    if stop == "auto" and (not sr.converged or sr.keep.sum() < C.MIN_KEPT_SHARE * len(pts)):
        # Too few points met an opposite normal: the scan saw the tube from one side.
        log.info("too few points met the other side of the tube (a one-sided scan?): each point "
                 "moves by the distance at which the shifted points concentrate most")
        nbr = cKDTree(pts).query(pts, k=min(C.NORMAL_NEIGHBOURS, len(pts)), workers=-1)[1]
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
    return sr, kept


def _thin(shrunk, H):
    from .thin import mls_thin

    return mls_thin(shrunk, H=H)


# --------------------------------------------------------------------------------------------------
# fit each branch


#: Of the R_I_WINDOW skeleton vertices at an end, one whose r_i exceeds their median by more than
#: R_I_OUTLIER times takes that median in the first estimate's radius function: a stray thin point at
#: an open end (r_i 3.5 on a pipe of radius 1), or one at a junction that took in the other tubes' points
#: (r_i 1.7 on a tee's side of radius 0.5), swings the radius spline there to several times the tube's.
#: Past an open end the continuation then grows faster than its length; at a junction the widened end
#: takes in the points beside it as inside it.  Either way the scan's points there are nearest to no
#: estimate and the fit stops short.  The vertices lie about half a radius apart; no tube's radius
#: doubles within two radii.
R_I_OUTLIER = 2.0
R_I_WINDOW = 5


def _steady(r: np.ndarray) -> np.ndarray:
    """The radii ``r`` of an open branch's vertices with the outliers at its ends (R_I_OUTLIER) replaced.

    A small r_i at an end (a cap, or where a thinner tube joins) swings the estimate's radius no wider:
    those are kept.
    """
    r = r.copy()
    if len(r) >= R_I_WINDOW:
        for window in (slice(0, R_I_WINDOW), slice(-R_I_WINDOW, None)):
            median = np.median(r[window])
            r[window] = np.where(r[window] > R_I_OUTLIER * median, median, r[window])
    return r


def _first_guess(branch: SkeletonBranch) -> dict:
    """Spline through a skeleton branch by arc length, its radius function and Eq. (6) radius."""
    steps = np.linalg.norm(np.diff(branch.points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(steps)])
    length = s[-1] + (np.linalg.norm(branch.points[-1] - branch.points[0]) if branch.closed else 0.0)
    # A link the skeleton split off at a tee can hold no thin points; its vertices stand in for them.
    w = branch.weights if branch.weights.sum() > 0 else np.ones(len(branch.points))
    n_thin = int(w.sum())
    r_b = float(np.average(branch.radius, weights=w))  # Eq. (6) over the branch's points
    # Where only one vertex holds thin points, the vertices stand in for the splines too: the penalty
    # leaves lines free, so a spline through one weighted point is any line through it (solved, one ran
    # off across a plant, and its assign band took in the tubes along that line).
    fit_w = w if np.count_nonzero(w) >= 2 else np.ones(len(branch.points))
    r_v = branch.radius if branch.closed else _steady(branch.radius)
    # A loop's periodic splines need more segments than their degree.
    least = 4 if branch.closed else 1
    nseg = max(least, _segments(length, C.SPINE_KNOTS_PER_RADIUS * r_b, n_thin))
    rseg = max(least, _segments(length, C.RADIUS_KNOTS_PER_RADIUS * r_b, n_thin))
    u = s / length
    spine = pspline_fit(u, branch.points, n_segments=nseg, closed=branch.closed, weights=fit_w)
    radius = pspline_fit(u, r_v, n_segments=rseg, closed=branch.closed, weights=fit_w)
    return {"spine": spine, "radius": radius, "eq6": r_b, "segments": (nseg, rseg), "closed": branch.closed,
            "u": u, "r_v": r_v, "w": w}


#: The final fit takes at least MAX_FIT_POINTS of the scan's points, and this many per branch of the
#: skeleton: a scene of hundreds of tubes needs more than a single tube, and no fewer per tube.
FIT_POINTS_PER_BRANCH = 4_000


def _fit_points(scan: _Scan, passes: list, n_branches: int) -> tuple[np.ndarray, dict]:
    """The points of the final fit (a seeded subset of a large scan: more for more branches) and, for each,
    whether the surface is curved like a tube there and its larger principal curvature -- those of its
    nearest point in the subset of the finest pass that worked on it."""
    if scan.draw is None:
        index = np.arange(len(scan.all_pts))
    else:
        index = np.sort(scan.draw[: max(C.MAX_FIT_POINTS, FIT_POINTS_PER_BRANCH * n_branches)])
    points = scan.all_pts[index]
    level = np.zeros(len(index), int)
    for j, run in enumerate(passes[1:], 1):
        level[np.isin(index, run.pool)] = j
    curved, kappa, sections = np.zeros(len(index), bool), np.zeros(len(index)), np.zeros(len(index), bool)
    for j, run in enumerate(passes):
        mine = level == j
        sections[mine] = run.sr.stop_rule == "sections"
        mask = np.zeros(len(run.scan.pts), bool)
        mask[run.curved] = True
        if run.scan.pts is scan.all_pts and mine.all():
            curved, kappa = mask[index], run.kappa[index]
            break
        nearest = cKDTree(run.scan.pts).query(points[mine], workers=-1)[1]
        curved[mine], kappa[mine] = mask[nearest], run.kappa[nearest]
    return points, {"curved": curved, "kappa": kappa, "loose": sections & ~curved}


def _stand_in(g: dict, branch: SkeletonBranch, i: int) -> CanalModel:
    """A first tube estimate as a model, continued ``ASSIGN_END_RADII`` radii past its open ends: the
    spine straight on, the radius held at its end value (its slope there is the thin set's end, where
    the r_i scatter most: continued, it can reach several radii)."""
    spine, radius = g["spine"], g["radius"]
    if not g["closed"]:
        ext = ASSIGN_END_RADII * g["eq6"] / curve_length(spine)
        a, b = (0.0 if branch.ends[0] is not None else -ext), (1.0 if branch.ends[1] is not None else 1 + ext)
        nseg, rseg = g["segments"]
        spine, (radius,), _ = arclength_reparametrize(extended(spine), n_segments=nseg + 2, closed=False, a=a, b=b,
                                                      extra=[(lambda t, f=radius: f(np.clip(t, 0.0, 1.0)), rseg + 2)])
    return CanalModel("canal", spine, radius, g["closed"], id=i)


class _Estimates:
    """The branches' first tube estimates (``guesses``), each as a :func:`_stand_in` with the box its
    assign band reaches, made once per estimate; and how far round each junction points go to no branch.

    ``made`` (shared by the estimates of one network's fit) keeps each branch's estimate by its arrays
    and which of its ends are open, all an estimate depends on: a skeleton with pieces joined or
    branches dropped keeps the other branches' arrays, and their estimates are not made again.
    """

    def __init__(self, skel: Skeleton, made: dict):
        self.guesses, self.skel, self._made = [], skel, {}
        for i, b in enumerate(skel.branches):
            key = (id(b.points), id(b.weights), id(b.radius), b.closed, b.ends[0] is None, b.ends[1] is None)
            if key in made:
                _, guess, (model, *rest) = made[key]
                self.guesses.append(guess)
                self._made[i] = (replace(model, id=i), *rest)
            else:
                # Made here, before the fits are spread over processes: each would otherwise make them all
                # again.  The branch is kept with them, so that its arrays' ids are not taken by others.
                self.guesses.append(_first_guess(b))
                made[key] = (b, self.guesses[i], self.model(i))
        largest = np.zeros(len(skel.junctions))
        for g, b in zip(self.guesses, skel.branches):
            for j in b.ends:
                if j is not None:
                    largest[j] = max(largest[j], g["eq6"])
        self.junction_reach = JUNCTION_EXCLUSION_RADII * largest

    def replaced(self, i: int, guess: dict) -> _Estimates:
        """These estimates with branch ``i``'s replaced (the others' models are kept)."""
        out = _Estimates.__new__(_Estimates)
        out.guesses, out.skel, out.junction_reach = list(self.guesses), self.skel, self.junction_reach
        out.guesses[i] = guess
        out._made = {j: made for j, made in self._made.items() if j != i}
        return out

    def model(self, i: int) -> tuple[CanalModel, np.ndarray, np.ndarray, float]:
        """Branch ``i``'s stand-in, the corners (2, 3) of a box holding it and its assign band, samples
        along its spine, and the distance from them within which the band lies."""
        if i not in self._made:
            g = self.guesses[i]
            model = _stand_in(g, self.skel.branches[i], i)
            t = np.linspace(0.0, 1.0, 64 * (len(model.spine.t) - 2 * model.spine.k))
            pts = model.spine(t)
            reach = float(model.radius(np.linspace(0.0, 1.0, 64)).max()) + ASSIGN_RADII * g["eq6"]
            # The spine is within a sample step of a sample, the band within the largest radius and the
            # assign cut of the spine.
            band = (float(model.radius(t).max()) + ASSIGN_RADII * g["eq6"]
                    + float(np.linalg.norm(np.diff(pts, axis=0), axis=1).max()))
            self._made[i] = (model, np.array([pts.min(axis=0) - reach, pts.max(axis=0) + reach]), pts, band)
        return self._made[i]


class _Fittable:
    """The points a fit may take (``curved``), in order along each axis: those in a box are then found by
    binary searches and a test of the box's thinnest slab, not of every point of a scene (a rack's pipe
    spans the plant along its run, but not across it)."""

    def __init__(self, points: np.ndarray, curved: np.ndarray):
        index = np.flatnonzero(curved)
        self.order = [index[np.argsort(points[index, axis], kind="stable")] for axis in range(3)]
        self.key = [points[order, axis] for axis, order in enumerate(self.order)]

    def in_box(self, points: np.ndarray, box: np.ndarray) -> np.ndarray:
        """Ascending indices of the fittable ``points`` inside ``box`` (corners, shape (2, 3))."""
        spans = [(np.searchsorted(key, box[0, axis], side="left"), np.searchsorted(key, box[1, axis], side="right"))
                 for axis, key in enumerate(self.key)]
        axis = int(np.argmin([b - a for a, b in spans]))
        slab = self.order[axis][slice(*spans[axis])]
        return np.sort(slab[np.all((points[slab] >= box[0]) & (points[slab] <= box[1]), axis=1)])


def _assign(points: np.ndarray, estimates: _Estimates, fittable: _Fittable, i: int) -> np.ndarray:
    """Indices of the points branch ``i`` is fitted to.

    A point goes to the branch whose first tube estimate -- continued straight for
    ``ASSIGN_END_RADII`` radii past its open ends, which the thin set may fall short of -- it lies
    nearest, if within ``ASSIGN_RADII`` of that branch's radii; points near one of its junctions go to
    none (there its surface belongs to several tubes), but a junction of other tubes takes none of its
    points (a rack pipe keeps its end beside its neighbour's junction).  Clutter (a floor under a pipe,
    a box beside it) is then no part of any fit, however much of the scan it is; nor is a point where
    the surface is flat (not ``fittable``): ground beside a pipe that lies near it would otherwise pull a
    one-sided fit towards a larger radius.  Only the points in the box of the branch's band, and the
    branches whose bands reach into it, are looked at, so that the cost does not grow with the size of
    the scene.
    """
    guesses = estimates.guesses
    _, mine, samples, band = estimates.model(i)
    boxes = np.array([estimates.model(j)[1] for j in range(len(guesses))])
    index = np.flatnonzero(np.all((boxes[:, 0] <= mine[1]) & (boxes[:, 1] >= mine[0]), axis=1))
    near = fittable.in_box(points, mine)
    # Only points within the band can be the branch's: the rest of its box (a rack's other pipes) need
    # not be classified.
    near = near[cKDTree(samples).query(points[near], distance_upper_bound=band)[0] <= band]
    label, _ = classify_points(points[near], [estimates.model(j)[0] for j in index],
                               cut=[ASSIGN_RADII * guesses[j]["eq6"] for j in index], far=False)
    keep = label == i
    keep[keep] = _off_junctions(points[near[keep]], estimates, i)
    return near[keep]


def _off_junctions(points: np.ndarray, estimates: _Estimates, i: int) -> np.ndarray:
    """Which ``points`` lie beyond the reach of branch ``i``'s junctions (there its surface belongs to
    several tubes)."""
    keep = np.ones(len(points), bool)
    own = [j for j in estimates.skel.branches[i].ends if j is not None]
    if own and len(points):
        for hits in cKDTree(points).query_ball_point(estimates.skel.junctions[own], estimates.junction_reach[own]):
            keep[hits] = False
    return keep


def _fit_branch(points: np.ndarray, guess: dict, *, kind: str, refine: bool, was: str | None = None) -> _BranchFit:
    """Spine and radius of one branch: the refined fit to its points, or the paper's own result.

    ``was`` is the kind of the fit ``guess`` holds, when the branch is fitted again once grown
    (:func:`_grow`): a pipe is then fitted again as a pipe alone, unless its radius no longer stays
    steady along it (:func:`_steady_radius`).
    """
    spine, radius_fn, eq6 = guess["spine"], guess["radius"], guess["eq6"]
    closed, (nseg, rseg) = guess["closed"], guess["segments"]
    if refine:
        fits = {}
        if kind == "auto" and was == "pipe":
            # Started from its own converged fit, a pipe fit takes few passes; the canal fit, and the pipe
            # fit started from it, are made only where the grown points leave the radius changing.
            pipe = refine_fit(points, spine, radius_fn, closed=closed, spine_segments=nseg, radius_segments=None,
                              reach=eq6)
            if _steady_radius(pipe, rseg, closed):
                fits["pipe"], kind = pipe, "pipe"
        # Left to choose, a branch one of whose fits fails is the other kind, not no tube: a canal's
        # free radius can let the fit's ends close in until it shrinks to a point where a pipe's
        # cannot (a tree's limb, seen from one side).
        if kind in ("auto", "canal"):
            try:
                fits["canal"] = refine_fit(points, spine, radius_fn, closed=closed, spine_segments=nseg,
                                           radius_segments=rseg, reach=eq6)
            except ReconstructionError:
                if kind == "canal":
                    raise
                kind = "pipe"
        if kind in ("auto", "pipe") and "pipe" not in fits:
            # The canal fit's spine is the better start, unless that fit ran off (its free radius
            # function lets a bad step grow) or folded (its end slid back along the tube, dragged by a
            # hook of the first estimate): then the pipe fit would go with it.
            canal = fits.get("canal")
            sound = (canal is not None and _near_radius(canal.radius, eq6)
                     and not fold(canal.spine, canal.radius, closed))
            start = canal.spine if sound else spine
            try:
                fits["pipe"] = refine_fit(points, start, constant_spline(eq6), closed=closed,
                                          spine_segments=nseg, radius_segments=None, reach=eq6)
            except ReconstructionError:
                if kind == "pipe":
                    raise
                kind = "canal"
        if kind == "auto":
            # Both fits scored with the same outlier cut, so that a canal fit that went wrong does not
            # look good by calling most points outliers; and without the clutter beside a pipe or past
            # its ends (:func:`_unscored`), which a canal would otherwise win by taking in.
            cut = outlier_cut(fits["canal"].residual, eq6)
            mine = ~_unscored(points, fits["pipe"], closed, eq6)
            rss = {name: float(np.minimum(f.residual[mine]**2, cut**2).sum()) for name, f in fits.items()}
            # A pipe beside whose points the spine shifts as the radius would change explains a one-sided
            # scan about as well (:func:`_shifted_pipe_rss`); the canal must beat that pipe too.
            rss_pipe = min(rss["pipe"], _shifted_pipe_rss(points, fits["canal"], mine, cut, eq6))
            samples = fits["canal"].radius(np.linspace(0, 1, 200))
            kind = "canal" if prefer_canal(rss_pipe, rss["canal"], int(mine.sum()), rseg + 2, samples) else "pipe"
            if kind == "canal" and _gapped(fits["canal"], float(np.mean(samples)), closed):
                kind = "pipe"
        spine, radius, t = fits[kind].spine, fits[kind].radius, fits[kind].t
        if not closed and _runs_back(spine, guess["spine"], eq6):
            spine, radius, t = reversed_spline(spine), reversed_spline(radius), 1.0 - t
        return _BranchFit(kind, spine, radius, closed, (None, None), eq6, (nseg, rseg), fits[kind].residual, t, points)
    if kind == "auto":
        w, r_v, u = guess["w"], guess["r_v"], guess["u"]
        rss_pipe = float((w * (r_v - eq6) ** 2).sum())
        rss_canal = float((w * (r_v - radius_fn(u)) ** 2).sum())
        kind = "canal" if prefer_canal(rss_pipe, rss_canal, int(w.sum()), rseg + 2,
                                       radius_fn(np.linspace(0, 1, 200))) else "pipe"
    if kind == "pipe":
        radius_fn = constant_spline(eq6)
    t, residual = footpoints(points, spine, radius_fn, closed=closed)
    return _BranchFit(kind, spine, radius_fn, closed, (None, None), eq6, (nseg, rseg), residual, t, points)


def _unscored(points: np.ndarray, pipe: RefineResult, closed: bool, eq6: float) -> np.ndarray:
    """Which ``points`` a ``pipe`` fit and a canal fit are not compared on: the pipe's strays that lie
    beside its inliers -- at stations along it (a radius, ``eq6``, long) where most points are
    inliers -- and the points past an open end within a radius of it.

    A canal whose radius swells to take in clutter beside a pipe (the ground a radius under a one-sided
    pole), or closes in on a capped end, makes points its inliers that the pipe leaves out while its own
    stay on the tube: a gain that is no sign of a radius changing along it.  Where the radius changes
    (a reducer), the points a pipe cannot reach make up their stations, and run on past its end.
    """
    stray = is_stray(pipe.residual, eq6)
    station = (pipe.t * curve_length(pipe.spine) / eq6).astype(int)
    share = np.bincount(station, weights=stray) / np.maximum(np.bincount(station), 1)
    out = stray & (share[station] < 0.5)
    if not closed:
        for end, sign in ((0.0, -1.0), (1.0, 1.0)):
            at = np.flatnonzero(pipe.t == end)
            tangent = pipe.spine.derivative()(end)
            past = (points[at] - pipe.spine(end)) @ (sign * tangent / np.linalg.norm(tangent))
            out[at[past <= eq6]] = True
    return out


def _shifted_pipe_rss(points: np.ndarray, canal: RefineResult, mine: np.ndarray, cut: float,
                      eq6: float) -> float:
    """Truncated residual sum of squares, on the ``points`` selected by ``mine``, of the pipe that
    imitates a ``canal`` fit by moving its spine instead of changing its radius.

    Seen from one side, a tube whose radius grows by ``dr`` and one whose axis moves ``dr`` away from
    the scanner put their points (almost) in the same place: only the points seen at a slant tell them
    apart, by ``dr (1 - cos phi)``.  The imitation is the canal's spine moved, at each station (``eq6``
    long), along the mean direction ``m`` of its points from it by ``k r(t) + c``, with a constant
    radius ``rho``; to first order a point's residual is then ``e + r(t) - rho - (k r(t) + c) cos phi``
    with ``cos phi = u . m``, and ``rho, k, c`` are fitted by least squares to the inliers.  On a scan
    all round, ``cos phi`` averages to zero at every station and the imitation gains nothing.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
    canal : RefineResult
        The canal fit to ``points``.
    mine : ndarray of bool, shape (N,)
        The points the fits are compared on.
    cut : float
        Residuals count as at most ``cut`` (the comparison's outlier cut).
    eq6 : float
        The branch's first radius estimate: the stations' length.

    Returns
    -------
    float
    """
    t, e = canal.t[mine], canal.residual[mine]
    off = points[mine] - canal.spine(t)
    u = off / np.maximum(np.linalg.norm(off, axis=1), 1e-300)[:, None]
    station = (t * curve_length(canal.spine) / eq6).astype(int)
    mean = np.stack([np.bincount(station, weights=u[:, i]) for i in range(3)], axis=1)[station]
    cos = np.einsum("ij,ij->i", u, mean) / np.maximum(np.linalg.norm(mean, axis=1), 1e-300)
    r = canal.radius(t)
    design = np.column_stack([np.ones(len(t)), r * cos, cos])
    inlier = np.abs(e) <= cut
    if inlier.sum() <= design.shape[1]:
        return np.inf
    coef = np.linalg.lstsq(design[inlier], (e + r)[inlier], rcond=None)[0]
    return float(np.minimum((e + r - design @ coef) ** 2, cut**2).sum())


#: A pipe fit's radius is steady where a radius function fitted to its points' distances from its spine
#: varies by less than this share of CANAL_MIN_VARIATION (:func:`_steady_radius`).
STEADY_SHARE = 0.5


def _steady_radius(fit: RefineResult, segments: int, closed: bool) -> bool:
    """Whether the points of a pipe ``fit`` keep their distance from its spine along it: a radius
    function of ``segments`` intervals fitted to those distances (the spine held) varies by less than
    STEADY_SHARE of ``CANAL_MIN_VARIATION``, so that no canal fit, which may move the spine too, would
    be kept.

    Every point counts, the fit's outliers too: on a reducer a pipe fit takes the wide half and leaves
    the narrow one out, and its distances are what show the change; strays only make a canal fit likelier.
    """
    if len(fit.t) < C.POINTS_PER_SEGMENT * (segments + 3):
        return False
    samples = pspline_fit(fit.t, fit.residual + float(fit.radius.c[0]), n_segments=segments,
                          closed=closed)(np.linspace(0.0, 1.0, 200))
    return bool(np.ptp(samples) < STEADY_SHARE * C.CANAL_MIN_VARIATION * np.mean(samples))


#: A canal fit whose radius leaves [r_b / RUNAWAY_RADIUS, RUNAWAY_RADIUS r_b] anywhere has run off: the
#: first estimate's Eq. (6) radius is within tens of per cent of a tube's, and a canal's taper about it.
RUNAWAY_RADIUS = 3.0


def _near_radius(radius: BSpline, eq6: float) -> bool:
    """Whether a fitted radius function stays within RUNAWAY_RADIUS of the first estimate's ``eq6``."""
    r = radius(np.linspace(0.0, 1.0, 200))
    return bool(r.min() >= eq6 / RUNAWAY_RADIUS and r.max() <= RUNAWAY_RADIUS * eq6)


def _runs_back(spine: BSpline, guess: BSpline, radius: float) -> bool:
    """Whether an open fitted spine runs from its first estimate's last end to its first.

    A short fit that started far off can swing round; the branch's ends (at a junction, or open) are
    where its first estimate has them, so it is turned back.  Only where both run more than
    TURN_CHORD_RADII radii from end to end: a stub's direction is noise."""
    ends, start = spine(np.array([0.0, 1.0])), guess(np.array([0.0, 1.0]))
    chords = (ends[1] - ends[0], start[1] - start[0])
    return bool(min(map(np.linalg.norm, chords)) > TURN_CHORD_RADII * radius and chords[0] @ chords[1] < 0
                and np.linalg.norm(ends - start[::-1], axis=1).sum() < np.linalg.norm(ends - start, axis=1).sum())


#: A fit is turned back to its estimate's direction only if both run more than this many radii end to end.
TURN_CHORD_RADII = 2.0


def _gapped(fit: RefineResult, radius: float, closed: bool) -> bool:
    """Whether a refined fit's points leave a gap of more than POOR_GAP_RADII radii along its spine.

    A radius function is fitted to nothing across such a gap: a canal there joins two tubes' radii (the
    ends of two pipes of a sparse plant, bridged by a canal 0.8 radii off either), and is no evidence
    that the radius changes.
    """
    near = ~is_stray(fit.residual, radius)
    return support_gap(fit.t[near], curve_length(fit.spine), closed) > POOR_GAP_RADII * radius


def _quality(fit: _BranchFit) -> dict:
    """Inlier RMS distance, mean radius and out-of-roundness of a fitted branch (normalised units)."""
    stray = is_stray(fit.residual, fit.eq6)
    radii = fit.radius(np.linspace(0, 1, 200))
    mean_r = float(np.mean(radii))
    inlier_rms = float(np.sqrt(np.mean(fit.residual[~stray] ** 2))) if (~stray).any() else np.inf
    out_of_round = roundness(fit.points[~stray], fit.spine, fit.t[~stray], fit.residual[~stray])
    kappa = fit.kappa[~stray] if fit.kappa is not None and (~stray).any() else np.empty(0)
    curving = 1.0 / np.median(kappa) if len(kappa) and np.median(kappa) > 0 else np.inf
    # Only a tube far wider than its Eq. (6) radius is judged by its coverage (MAX_RADIUS_PER_EQ6).
    wide = mean_r > MAX_RADIUS_PER_EQ6 * fit.eq6
    coverage = angular_coverage(fit.points[~stray], fit.spine, fit.t[~stray]) if wide else np.empty(0)
    return {"rms": inlier_rms, "radius": mean_r, "round": out_of_round, "n": int((~stray).sum()),
            "curving": float(curving), "eq6": fit.eq6, "fold": fold(fit.spine, fit.radius, fit.closed),
            "coverage": float(np.median(coverage)) if len(coverage) else 0.0,
            "radius_range": (float(radii.min()), float(radii.max()))}


#: A branch whose radius exceeds this many times the median curvature radius of its own points
#: (1 / kappa_max, about the radius on a tube: 0.9 - 1.2 of it on the paper's surfaces, up to 3 times
#: it on sparse, quantised one-sided scans, where curvature is underestimated) is several thinner
#: tubes, or a coil, read as one wide tube.
MAX_RADIUS_PER_CURVING = 2.5
#: A branch whose points' median curvature radius exceeds this many times its radius lies on a nearly
#: flat surface: a strip of ground that a tube touches from below fits it within a coarse grid's
#: rounding.  Set far above the 3 of one-sided scans: curvature reads lowest on thin, sparse branches.
MAX_CURVING_PER_RADIUS = 20.0
#: A branch seen from one side (ONE_SIDED_DEGREES) whose radius exceeds this many times its Eq. (6)
#: radius -- the mean distance its points moved to their thin images -- is a fit that left its points'
#: own scale: a circle through a narrow arc, as through the tops of several thinner pipes side by side.
#: Seen all round, the points pin the circle, and shrinking may have stopped short of the spine.
MAX_RADIUS_PER_EQ6 = 2.5


def _is_tube(q: dict, noise: float, quantum: float = 0.0) -> tuple[bool, str]:
    """Whether a fitted branch is a tube: its points near the surface lie close to it, all round,
    and no farther than the scan's own ``noise`` explains.

    A tube whose points scatter more than ``MAX_RELATIVE_RESIDUAL`` of its radius, or lie off round by
    more than ``MAX_OUT_OF_ROUND``, passes when the grid of the coordinates (``quantum``,
    :func:`canalsurf.pointcloud.quantisation_noise`) explains it: a thin pole stored in steps of a third
    of its radius can be no closer to its surface than that, and along a pole parallel to an axis of the
    grid the rounding is the same in every cross-section, so it stays by sector.
    """
    if q["n"] < MIN_CHECKED_POINTS:
        return False, f"only {q['n']} points lie on the best tube, too few to tell it is one"
    if not q["radius"] > 0 or q["rms"] > max(MAX_RELATIVE_RESIDUAL * q["radius"], SCAN_NOISE_RATIO * quantum):
        return False, (f"the points do not lie on a tube: RMS distance from the best tube is "
                       f"{q['rms'] / max(q['radius'], 1e-300):.0%} of its radius")
    if q["round"] > max(MAX_OUT_OF_ROUND * q["radius"], SCAN_NOISE_RATIO * quantum):
        return False, (f"the points are not round about the spine: whole sectors lie "
                       f"{q['round'] / q['radius']:.0%} of the radius off the best tube")
    if q["fold"]:
        return False, q["fold"]
    if not plausible_radius(np.array(q["radius_range"])):
        low, high = q["radius_range"]
        return False, (f"the radius goes from {low:.2g} to {high:.2g} along the tube, more than "
                       f"{C.MAX_RADIUS_RATIO:g} times: not one tube")
    if q["radius"] > MAX_RADIUS_PER_CURVING * q["curving"]:
        return False, (f"the points curve far more tightly (radius {q['curving']:.2g}) than the one tube through "
                       f"them (radius {q['radius']:.2g}): thinner tubes side by side or a coil, not one tube")
    if q["curving"] > MAX_CURVING_PER_RADIUS * q["radius"]:
        return False, (f"the points lie on a nearly flat surface (curvature radius {q['curving']:.2g}, "
                       f"{q['curving'] / q['radius']:.0f} times the best tube's radius): not a tube")
    if q["coverage"] < C.ONE_SIDED_DEGREES and q["radius"] > MAX_RADIUS_PER_EQ6 * q["eq6"]:
        return False, (f"the best tube (radius {q['radius']:.2g}) is far wider than the distance the points "
                       f"moved to its spine (radius {q['eq6']:.2g}): not the tube the points came from")
    if q["rms"] > SCAN_NOISE_RATIO * noise and q["rms"] > TUBE_RELATIVE_RESIDUAL * q["radius"]:
        return False, (f"the points misfit the best tube by {q['rms'] / q['radius']:.0%} of its radius, "
                       + (f"{q['rms'] / noise:.0f} times the scan's own noise" if noise > 0
                          else "and the scan has no noise"))
    return True, ""


def _grow(points: np.ndarray, fit: _BranchFit, idx: np.ndarray, i: int, estimates: _Estimates,
          fittable: _Fittable, kind: str) -> tuple[_BranchFit, np.ndarray]:
    """Branch ``i``'s fit and the indices of its points (``idx``), grown where an open end grew towards
    the edge of its points: the points are assigned again about the fit (continued ASSIGN_END_RADII past
    its ends, like the first estimate) and the branch fitted again, until no end grows by more than
    ``GROW_RADII`` or ``MAX_GROW_ROUNDS``.  The refinement's own end placement stops it at a gap in the
    points, as before.  A round whose fit fails keeps the fit before it: an end grown into clutter (a
    tree's stem into the flare under its limbs) loses what it grew, not the tube it grew from."""
    free = [e for e in (0, 1) if estimates.skel.branches[i].ends[e] is None and not estimates.guesses[i]["closed"]]
    for round_ in range(MAX_GROW_ROUNDS + 1):
        g = estimates.guesses[i]
        # Outward along the fit, not the estimate: an estimate whose thin set strays sideways at its end
        # hooks there, and the fit's end, on past it, would not count as grown along the hook.
        tangent = fit.spine.derivative()(np.array([0.0, 1.0]))
        outward = tangent / np.linalg.norm(tangent, axis=1, keepdims=True) * np.array([[-1.0], [1.0]])
        if not any((fit.spine(float(e)) - g["spine"](float(e))) @ outward[e] > GROW_RADII * g["eq6"] for e in free):
            break
        if round_ == MAX_GROW_ROUNDS:
            fit.growing = True
            break
        length, grown = curve_length(g["spine"]), curve_length(fit.spine)
        nseg, rseg = (max(n, int(round(n * grown / length))) for n in g["segments"])
        estimates = estimates.replaced(i, {**g, "spine": fit.spine, "radius": fit.radius, "segments": (nseg, rseg)})
        grown_idx = _assign(points, estimates, fittable, i)
        try:
            fit = _fit_branch(points[grown_idx], estimates.guesses[i], kind=kind, refine=True, was=fit.kind)
        except ReconstructionError:
            break
        idx = grown_idx
    return fit, idx


#: A branch takes back the ``loose`` points on its surface in at most this many rounds (:func:`_regathered`).
REGATHER_ROUNDS = 3


def _regathered(points: np.ndarray, fit: _BranchFit, idx: np.ndarray, i: int, estimates: _Estimates,
                loose: _Fittable, kind: str) -> tuple[_BranchFit, np.ndarray]:
    """Branch ``i``'s fit and the indices of its points (``idx``), with the ``loose`` points on its
    surface taken back and the branch fitted again.

    Cross-sections find a tube only where a point's neighbourhood is elongated like a piece of it
    (:func:`~canalsurf.shrink.shrink_by_sections`): on a one-sided scan on a coarse grid that can be a
    quarter of its points, and a fit to those alone is off by a third of its radius.  Each round takes
    the loose points whose footpoints lie inside the branch, away from its junctions, and whose
    residuals lie within the outlier cut of the fit's own points -- not of all, which the ground under
    the tube would widen until it took the ground in -- and fits the branch again, until the points
    taken are the same.  Clutter beside the tube stays out, as it stayed out of the first fit.
    """
    taken = np.zeros(0, int)
    for _ in range(REGATHER_ROUNDS):
        r = fit.radius(np.linspace(0.0, 1.0, 64))
        cut = outlier_cut(fit.residual, float(np.mean(r)))
        pts = fit.spine(np.linspace(0.0, 1.0, 64 * (len(fit.spine.t) - 2 * fit.spine.k)))
        reach = float(r.max()) + cut + float(np.linalg.norm(np.diff(pts, axis=0), axis=1).max())
        near = loose.in_box(points, np.array([pts.min(axis=0) - reach, pts.max(axis=0) + reach]))
        t, res = footpoints(points[near], fit.spine, fit.radius, closed=fit.closed)
        on = np.abs(res - np.median(fit.residual)) <= cut
        if not fit.closed:
            on &= (t > 0.0) & (t < 1.0)
        on[on] = _off_junctions(points[near[on]], estimates, i)
        if np.array_equal(near[on], taken):
            break
        taken = near[on]
        guess = {**estimates.guesses[i], "spine": fit.spine, "radius": fit.radius}
        fit = _fit_branch(points[np.union1d(idx, taken)], guess, kind=kind, refine=True, was=fit.kind)
    return fit, np.union1d(idx, taken)


#: Spine samples (by arc length) of the tests on a fit's ends below.
END_SAMPLES = 600
#: Past a gap in its points longer than POOR_GAP_RADII radii, the part of a branch towards an open end
#: that holds less than this share of its points is not the same tube: strays (clutter, another tube's
#: end) its end grew to across the gap.  The branch is fitted again without them.
MAX_TAIL_SHARE = 0.1
#: ... nor is a larger part whose own pipe fit differs in radius by more than this share from the
#: rest's: a tube goes on across a gap (an occlusion) with its radius, and a pipe's end that grew across
#: one into thinner tubes beside it fits some of their points, one sector of each, at its own radius.
MAX_GAP_RADIUS_CHANGE = 0.15


def _stray_tail(fit: _BranchFit, guess: dict, ends: tuple) -> np.ndarray:
    """Which of the fit's points lie past its widest gap, towards an open end, and are not the same
    tube (MAX_TAIL_SHARE, MAX_GAP_RADIUS_CHANGE); ``guess`` is the branch's first estimate.  Past a gap
    the estimate never crossed, the fit grew into another tube however many points that holds: a link
    between two tubes' ends that grew across the gap to a third."""
    tail = np.zeros(len(fit.t), bool)
    if fit.closed or len(fit.t) < 2:
        return tail
    length = curve_length(fit.spine)
    inlier = np.sort(fit.t[~is_stray(fit.residual, fit.eq6)])
    if len(inlier) < 2:
        return tail
    widest = int(np.argmax(np.diff(inlier)))
    if (inlier[widest + 1] - inlier[widest]) * length <= POOR_GAP_RADII * fit.eq6:
        return tail
    before = (widest + 1) / len(inlier)  # share of the inliers before the gap
    sides = ((fit.t <= inlier[widest], (0.0, inlier[widest]), before),
             (fit.t >= inlier[widest + 1], (inlier[widest + 1], 1.0), 1 - before))
    t, pts = sample_arclength(fit.spine, END_SAMPLES)
    reach = t[np.argmin(np.linalg.norm(pts[:, None] - guess["spine"](np.array([0.0, 1.0])), axis=2), axis=0)]
    grown = (reach[0] > inlier[widest], reach[1] < inlier[widest + 1])  # the estimate never crossed the gap
    for end in (0, 1):
        side, span, share = sides[end]
        # Of two sides that differ, the branch's tube is the one its estimate reached; where it reached
        # both, the larger.
        theirs = grown[end] or share < 0.5 and not grown[1 - end]
        if ends[end] is None and (share < MAX_TAIL_SHARE or theirs and _other_tube(fit, guess, sides[end],
                                                                                     sides[1 - end])):
            tail |= side
    return tail


#: Within this many radii of an open end, a spine bending more tightly than its radius (curvature times
#: radius above 1: the surface would pass through itself) has turned to another tube's points -- a pipe's
#: end among its neighbours' ends in a rack -- where no elbow bends so tightly.
HOOK_RADII = 4.0
#: A hook farther than this many radii from its end cuts a stretch of the tube with it: the points of that
#: stretch that lie on the tube going on straight are kept (:func:`_straight_on`).  Nearer, the points cut
#: are the end's own few, which a one-sided scan's coarse grid curls (a pole's ends, ``trust.py``): the
#: branch is fitted again without them, from its first estimate.
STRAIGHT_ON_RADII = 1.0


def _hooks(fit: _BranchFit, ends: tuple) -> dict:
    """``{end: t}``: the spine's parameter ``t`` past which each hooked open end turns tighter than the
    radius within HOOK_RADII of that end."""
    hooks = {}
    if fit.closed:
        return hooks
    t, pts = sample_arclength(fit.spine, END_SAMPLES)
    r = fit.radius(t)
    s = polyline_arclength(pts)
    tight = curvature(fit.spine, t) * r > 1.0
    for end, near in ((0, s <= HOOK_RADII * r), (1, s >= s[-1] - HOOK_RADII * r)):
        hook = t[tight & near]
        if ends[end] is None and len(hook):
            hooks[end] = hook.max() if end == 0 else hook.min()
    return hooks


def _hooked_end(fit: _BranchFit, hooks: dict) -> np.ndarray:
    """Which of the fit's points lie past its ``hooks`` (:func:`_hooks`; they are fitted again without
    them, but for those on the tube going on straight: :func:`_straight_on`)."""
    tail = np.zeros(len(fit.t), bool)
    for end, t in hooks.items():
        tail |= fit.t <= t if end == 0 else fit.t >= t
    return tail


def _straight_on(fit: _BranchFit, hooks: dict, guess: dict) -> tuple[dict, np.ndarray]:
    """The estimate to fit a branch with ``hooks`` again from, and which of its points lie on it past them.

    A hook is an end that turned to another tube's points (a rack's pipes end side by side), but the
    points there are not all that tube's: the branch's own tube went on straight to its end, and where
    the hook lies more than STRAIGHT_ON_RADII from the end, its points past the hook, cut with it, would
    leave the model radii short (refitted from the first estimate, which stopped short of them as well:
    a rack pipe of the 10⁸-point plant, ``bench.py --stream``).  The estimate is the fit
    :func:`_straightened` at the hooks; the points kept lie within the outlier cut of its surface,
    towards a hooked end.  With no hook that far from its end, ``guess`` and none.
    """
    length = curve_length(fit.spine)
    hooks = {end: t for end, t in hooks.items() if (t if end == 0 else 1.0 - t) * length > STRAIGHT_ON_RADII * fit.eq6}
    straight = _straightened(fit, hooks)
    if straight is None:
        return guess, np.zeros(len(fit.t), bool)
    spine, radius = straight
    t, res = footpoints(fit.points, spine, radius, closed=False)
    # Towards a hooked end only: past a gap at the other end, points on the fit's surface are another
    # tube in line (:func:`_stray_tail`).
    hooked_side = np.zeros(len(fit.t), bool)
    for end in hooks:
        hooked_side |= fit.t < 0.5 if end == 0 else fit.t >= 0.5
    on = ((np.abs(res - np.median(fit.residual)) <= outlier_cut(fit.residual, fit.eq6))
          & (t > 0.0) & (t < 1.0) & hooked_side)
    return {**guess, "spine": spine, "radius": radius, "segments": fit.segments}, on


def _straightened(fit: _BranchFit, hooks: dict) -> tuple[BSpline, BSpline] | None:
    """The fit's spine and radius cut HOOK_RADII / 2 radii inside its ``hooks`` (``{end: t}``), where the
    spine has stopped turning, and continued straight as far as it ran past the cut and ASSIGN_END_RADII
    on (like a first estimate), the radius held; ``None`` with no hooks, or hooked along most of it."""
    length = curve_length(fit.spine)
    inside = HOOK_RADII / 2 * fit.eq6 / length
    a, b = (hooks[0] + inside if 0 in hooks else 0.0), (hooks[1] - inside if 1 in hooks else 1.0)
    if not hooks or b - a < 0.5:
        return None
    nseg, rseg = fit.segments
    cut, (radius,), _ = arclength_reparametrize(fit.spine, n_segments=nseg, closed=False, a=a, b=b,
                                                extra=[(lambda t: fit.radius(np.clip(t, a, b)), rseg)])
    per_radius = fit.eq6 / curve_length(cut)  # a radius in the cut spine's parameter
    scale, past = length / curve_length(cut), ASSIGN_END_RADII * per_radius
    # On along the chord of the next HOOK_RADII radii, not the tangent: a fit's spine is never quite straight.
    spine, (radius,), _ = arclength_reparametrize(
        extended(cut, HOOK_RADII * per_radius, turn=0.0), n_segments=nseg, closed=False,
        a=-(a * scale + past) if 0 in hooks else 0.0, b=1 + (1 - b) * scale + past if 1 in hooks else 1.0,
        extra=[(lambda t, f=radius: f(np.clip(t, 0.0, 1.0)), rseg)])
    return spine, radius


#: A stretch at an open end whose spine holds, per radius of its length, fewer of the fit's inliers than
#: this share of the branch's median, and more strays than inliers, is no part of the tube if it runs
#: more than POOR_GAP_RADII radii: an end that grew across the ends of a rack's pipes, fitting a few of
#: each one's points, and found no gap among its inliers.  A tube sampled ever more thinly towards its
#: end (a pipe running away from the scanner) keeps its points: they lie on it, not astray.
SPARSE_END_SHARE = 0.25


def _sparse_end(fit: _BranchFit, ends: tuple) -> np.ndarray:
    """Which of the fit's points lie in a sparse stretch of strays at an open end (SPARSE_END_SHARE;
    they are fitted again without them)."""
    tail = np.zeros(len(fit.t), bool)
    if fit.closed or len(fit.t) < 2:
        return tail
    span = curve_length(fit.spine) / fit.eq6
    stray = is_stray(fit.residual, fit.eq6)
    along = np.minimum(fit.t * span, np.nextafter(span, 0))
    for end in (0, 1):
        if ends[end] is not None:
            continue
        radii = (along if end == 0 else span - along).astype(int)  # whole radii from this end
        inliers = np.bincount(radii[~stray], minlength=int(np.ceil(span)))
        dense = np.flatnonzero(inliers >= SPARSE_END_SHARE * np.median(inliers))
        run = dense[0] if len(dense) else len(inliers)
        sparse = radii < run
        if run > POOR_GAP_RADII and stray[sparse].mean() > 0.5:
            tail |= sparse
    return tail


def _other_tube(fit: _BranchFit, guess: dict, side: tuple, rest: tuple) -> bool:
    """Whether one ``side`` of a fit's points is another tube than the ``rest``, each ``(mask, (a, b),
    share)`` over the spine's parameters [a, b]: their own pipe fits differ in radius
    (MAX_GAP_RADIUS_CHANGE), or one fits no pipe."""
    radii = []
    for mine, (a, b), _ in (side, rest):
        if not b > a:  # points that all lie past the spine's end: no stretch of it to fit a pipe along
            return True
        nseg, rseg = (max(1, int(round(n * (b - a)))) for n in guess["segments"])
        spine, _, _ = arclength_reparametrize(fit.spine, n_segments=nseg, closed=False, a=a, b=b)
        radius = constant_spline(float(np.mean(fit.radius(np.linspace(a, b, 50)))))
        try:
            part = _fit_branch(fit.points[mine], {**guess, "spine": spine, "radius": radius, "segments": (nseg, rseg)},
                               kind="pipe", refine=True)
        except ReconstructionError:
            return True
        radii.append(float(part.radius(0.5)))
    return abs(radii[0] - radii[1]) > MAX_GAP_RADIUS_CHANGE * radii[1]


def _fit_one(i: int, job: dict) -> _BranchFit | _Folded | str:
    """Branch ``i`` fitted to its points (:func:`_assign`, grown at its open ends) and checked; or why it
    is no tube, with the legs to fit instead where it folds.

    ``job`` holds what every branch's fit shares (see :func:`_fit_network`).
    """
    points, estimates = job["points"], job["estimates"]
    idx = _assign(points, estimates, job["fittable"], i)
    if len(idx) < C.POINTS_PER_SEGMENT:
        return f"only {len(idx)} points lie near the first estimate of a tube"
    try:
        fit = _fit_branch(points[idx], estimates.guesses[i], kind=job["kind"], refine=job["refine"])
        if job["refine"]:
            fit, idx = _grow(points, fit, idx, i, estimates, job["fittable"], job["kind"])
            ends = estimates.skel.branches[i].ends
            hooks = _hooks(fit, ends)
            tail = _stray_tail(fit, estimates.guesses[i], ends) | _hooked_end(fit, hooks) | _sparse_end(fit, ends)
            if tail.any():
                guess = estimates.guesses[i]
                if hooks:
                    guess, on = _straight_on(fit, hooks, guess)
                    tail &= ~on
                idx = idx[~tail]
                if len(idx) < C.POINTS_PER_SEGMENT:
                    return f"only {len(idx)} points are left once the strays at its ends are cut"
                fit = _fit_branch(points[idx], guess, kind=job["kind"], refine=True)
            if job["loose"] is not None and _judged(fit, idx, job)[0][0]:
                # Judged on the points whose cross-section was found before it takes back the others: a
                # strip of ground, no tube, would take in more of the ground and could pass for one.
                fit, idx = _regathered(points, fit, idx, i, estimates, job["loose"], job["kind"])
    except ReconstructionError as exc:
        if len(estimates.guesses) == 1:
            raise
        return str(exc).split(" — ")[0]
    (ok, why), q = _judged(fit, idx, job)
    # Only where the fold is the first test it fails (its points lie on it): clutter's fits fold too,
    # and a leg of one may pass.
    if not ok and job["refine"] and why == q["fold"]:
        legs = _legs(fit, estimates.skel.branches[i])
        if legs:
            return _Folded(why, legs)
    return fit if ok else why


@dataclass
class _Folded:
    """A branch whose fit folds (``why``), and the skeleton branches of its legs (:func:`_legs`): it is
    fitted again as those."""

    why: str
    legs: list


#: A fit that is no tube only as it folds (:func:`canalsurf.quality.fold`; its points lie on it) is cut
#: where its spine has turned round, each leg HOOK_RADII / 2 radii past the turn, and the legs at least
#: LEG_RADII radii long whose part cut off ends at no junction are fitted again as branches of their own:
#: a hairpin of two pipes side by side -- the thin set of the two joined round their ends, or the fit of
#: one grown round the other's end and back along it -- is the tubes of its legs.  Left out whole, a tube
#: is missing, and a neighbour's end can veer into its points.
LEG_RADII = 2.0


def _legs(fit: _BranchFit, branch: SkeletonBranch) -> list:
    """Skeleton branches along the legs of a folded fit of ``branch``: each from ``HOOK_RADII / 2`` radii
    past the point where its tangent has turned by a right angle from that leg's end, to that end (which
    keeps ``branch``'s junction there; the cut is an open end).  Only legs LEG_RADII long whose part cut
    off ends at no junction (there the tubes unite), the longer first; none if the spine turns round
    nowhere."""
    if fit.closed:
        return []
    t, pts = sample_arclength(fit.spine, END_SAMPLES)
    s = polyline_arclength(pts)
    tangent = fit.spine.derivative()(t)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    margin, legs = HOOK_RADII / 2 * fit.eq6, []
    for end, turned in ((0, tangent @ tangent[0] < 0), (1, tangent @ tangent[-1] < 0)):
        k = np.flatnonzero(turned)
        if not len(k) or branch.ends[1 - end] is not None:
            continue
        a, b = (s[k.max()] + margin, s[-1]) if end == 1 else (0.0, s[k.min()] - margin)
        if b - a >= LEG_RADII * fit.eq6:
            legs.append((b - a, end, *np.interp([a, b], s, t)))
    out = []
    for length, end, a, b in sorted(legs, reverse=True):
        share = length / s[-1]
        spine, (radius,), _ = arclength_reparametrize(fit.spine, n_segments=fit.segments[0], closed=False, a=a,
                                                      b=b, extra=[(fit.radius, fit.segments[1])])
        u, on = sample_arclength(spine, max(MIN_BRANCH_POINTS, int(round(share * len(branch.points)))))
        ends = (branch.ends[0], None) if end == 0 else (None, branch.ends[1])
        out.append(SkeletonBranch(on, np.full(len(u), share * branch.weights.sum() / len(u)), radius(u), ends))
    return out


def _judged(fit: _BranchFit, idx: np.ndarray, job: dict) -> tuple[tuple[bool, str], dict]:
    """Whether a fit to the points ``idx`` is a tube, and if not why (:func:`_is_tube`); and its
    :func:`_quality`."""
    fit.kappa = job["kappa"][idx]
    q = _quality(fit)
    return _is_tube(q, job["noise"], job["quantum"]), q


#: Branches fitted at once before the fits are spread over the machine's cores, and the scan's points
#: from which two are enough (their fits take seconds each: the few a scene refits after joining pieces
#: or dropping branches); fewer, one process, which costs less than forking.
PARALLEL_BRANCHES = 8
PARALLEL_POINTS = 200_000
_JOB: dict = {}


def _fit_in_worker(i: int) -> _BranchFit | str:
    return _fit_one(i, _JOB)


def _quiet_worker() -> None:
    import signal

    # Ctrl-C is the parent's to handle (it cleans up and exits; the workers then find their queue closed).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_thread()  # the workers fill the cores


def _fit_all(tasks: list, job: dict, client=None) -> list:
    """:func:`_fit_one` of every branch in ``tasks``: as Dask tasks on ``client``'s workers if given,
    else over the cores in forked processes (Linux) when there are many or the scan is large (see
    PARALLEL_BRANCHES), so that a scene's hundreds of branches take a share of the time.  Each fit
    depends on its task alone, so the results are the same every way."""
    import multiprocessing  # only for a scene: a single tube's run does not pay for the import
    from concurrent.futures import ProcessPoolExecutor

    if client is not None:
        from .cluster import map_in_order

        return list(map_in_order(client, _fit_one, tasks, job))
    cores = _cores()
    few = len(tasks) < 2 or (len(tasks) < PARALLEL_BRANCHES and len(job["points"]) < PARALLEL_POINTS)
    if few or cores < 2 or "fork" not in multiprocessing.get_all_start_methods():
        return [_fit_one(i, job) for i in tasks]
    global _JOB
    _JOB = job
    try:
        with ProcessPoolExecutor(max_workers=cores, mp_context=multiprocessing.get_context("fork"),
                                 initializer=_quiet_worker) as pool:
            return list(pool.map(_fit_in_worker, tasks))
    finally:
        _JOB = {}


#: A branch whose spine lies inside other tubes along more than this share of it (away from its own
#: junctions) is no tube of its own: it bridges the ends of neighbours (a rack's pipes end side by side,
#: and their end caps can thin to a short link across them) -- a real tube's spine is inside no other.
MAX_INSIDE_OTHERS = 0.5
#: Spine samples per branch of that test.
INSIDE_SAMPLES = 100


#: A branch that runs inside other tubes keeps its longest stretch outside them, if that stretch is at least
#: OWN_PART_RADII of its radius long: a stub whose thin set ran on into the tube it leaves (an L, with no
#: junction where they meet) is a tube there, and so is a piece of a tube found twice over part of its
#: length, while a copy of a tube or a link across the ends of two leaves nothing that long outside.
OWN_PART_RADII = 4.0


def _own_part(fits: list, branch: SkeletonBranch, radius: float) -> SkeletonBranch | None:
    """The part of an open skeleton branch outside the tubes of ``fits`` (falsy entries skipped) as a
    branch of its own (see OWN_PART_RADII), or ``None``.  An end the part stops short of is open: the
    caller repairs the junction it left."""
    others = [f for f in fits if f]
    if branch.closed or not others:
        return None
    t = np.linspace(0.0, 1.0, INSIDE_SAMPLES)
    pts = np.concatenate([f.spine(t) for f in others])
    r = np.concatenate([f.radius(t) for f in others])
    inside = np.array([bool(np.any(np.linalg.norm(pts[near] - p, axis=1) < r[near])) for p, near in
                       zip(branch.points, cKDTree(pts).query_ball_point(branch.points, float(r.max())))])
    edges = np.flatnonzero(np.diff(np.concatenate([[True], inside, [True]]).astype(int)))
    runs = edges.reshape(-1, 2)  # [start, stop) of each stretch outside
    if not len(runs):
        return None
    s = polyline_arclength(branch.points)
    a, b = max(runs, key=lambda run: s[run[1] - 1] - s[run[0]])
    if b - a < 4 or s[b - 1] - s[a] < OWN_PART_RADII * radius:
        return None
    ends = (branch.ends[0] if a == 0 else None, branch.ends[1] if b == len(inside) else None)
    return SkeletonBranch(branch.points[a:b], branch.weights[a:b], branch.radius[a:b], ends, False)


def _largest_at_junctions(fits: list, skel: Skeleton) -> np.ndarray:
    """The largest Eq. (6) radius of the fitted branches (falsy entries skipped) ending at each junction."""
    largest = np.zeros(len(skel.junctions))
    for fit, branch in zip(fits, skel.branches):
        for j in branch.ends:
            if fit and j is not None:
                largest[j] = max(largest[j], fit.eq6)
    return largest


def _inside_others(fits: list, skel: Skeleton) -> list:
    """Indices of the fitted branches whose spine runs inside other fitted tubes (see MAX_INSIDE_OTHERS).

    They are taken out one at a time, of those inside others the one with the fewest points (and of
    those the most inside) first, each against the branches still in: of a tube found twice (two passes,
    two pieces that overlap) the copy that holds more of its points stays.  The other may have wandered
    off where few points pin it, and so lie less inside than the copy that did not.
    """
    live = [i for i, f in enumerate(fits) if f]
    if len(live) < 2:
        return []
    t = np.linspace(0.0, 1.0, INSIDE_SAMPLES)
    pts = np.concatenate([fits[i].spine(t) for i in live])
    r = np.concatenate([fits[i].radius(t) for i in live])
    owner = np.repeat(np.arange(len(live)), INSIDE_SAMPLES)
    reach = JUNCTION_EXCLUSION_RADII * _largest_at_junctions(fits, skel)
    away = np.ones(len(pts), bool)
    for n, i in enumerate(live):
        for j in skel.branches[i].ends:
            if j is not None:
                mine = owner == n
                away[mine] &= np.linalg.norm(pts[mine] - skel.junctions[j], axis=1) > reach[j]
    # (sample, other branch) pairs where the sample lies inside that branch's tube
    pairs = []
    for a, near in enumerate(cKDTree(pts).query_ball_point(pts, float(r.max()), workers=-1)):
        near = np.asarray(near, int)
        near = near[(owner[near] != owner[a]) & (np.linalg.norm(pts[near] - pts[a], axis=1) < r[near])]
        pairs += [(a, o) for o in np.unique(owner[near])]
    if not pairs:
        return []
    sample, other = np.array(pairs).T
    keep = away[sample]
    sample, other = sample[keep], other[keep]
    alive = np.ones(len(live), bool)
    size = np.array([len(fits[i].points) for i in live])
    out = []
    while True:
        covered = np.zeros(len(pts), bool)
        covered[sample[alive[other]]] = True
        share = np.bincount(owner, covered, len(live)) / np.maximum(np.bincount(owner, away, len(live)), 1)
        share[~alive] = 0.0
        inside = np.flatnonzero(share > MAX_INSIDE_OTHERS)
        if not len(inside):
            return out
        worst = min(inside, key=lambda n: (size[n], -share[n]))
        alive[worst] = False
        out.append(live[worst])


def _grown_into(fits: list, skel: Skeleton, dropped: list) -> list:
    """Indices of the fitted branches with an open end inside the tube of one of the ``dropped`` fits,
    in line with it and of its radius (MAX_PIECE_TURN, MAX_GAP_RADIUS_CHANGE), that runs on past that
    end by more than PIECE_GAP_RADII radii: a piece of their own tube, found twice, whose skeleton branch
    ran to a junction (so the pieces were not joined) and whose part outside them was too short to keep
    on its own.  Left as they are, they stop where that piece began, radii short of the tube's end."""
    out = []
    for piece in dropped:
        t, pts = sample_arclength(piece.spine, max(INSIDE_SAMPLES, int(curve_length(piece.spine) / piece.eq6)))
        tangent = piece.spine.derivative()(t)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        r = piece.radius(t)
        for k, fit in enumerate(fits):
            if not fit or fit.closed or k in out:
                continue
            for e in (0, 1):
                if skel.branches[k].ends[e] is not None:
                    continue
                p, d = _end_frame(fit.spine, e)
                n = int(np.argmin(np.linalg.norm(pts - p, axis=1)))
                if (np.linalg.norm(pts[n] - p) < r[n] and abs(tangent[n] @ d) >= np.cos(np.radians(MAX_PIECE_TURN))
                        and abs(r[n] - fit.eq6) <= MAX_GAP_RADIUS_CHANGE * max(r[n], fit.eq6)
                        and ((pts - p) @ d).max() > PIECE_GAP_RADII * fit.eq6):
                    out.append(k)
                    break
    return out


#: A branch left out is a fragment of a fitted tube's own thin set when its thin points lie within this many
#: radii past one of the tube's open ends, inside the tube continued straight (with the assign band's
#: margin), and its radius is less than FRAGMENT_RADIUS_SHARE of the tube's.  (In a random bundle, a
#: 2-point stub a ninth of its tube's radius, where the tube's end stopped a radius short; on a tree, the
#: limbs left out beside an end were wider than the branch, no part of it.)
DROPPED_AHEAD_RADII = 2.0
FRAGMENT_RADIUS_SHARE = 0.5


def _fragments_ahead(fits: list, skel: Skeleton, drop: list) -> list:
    """Indices of the fitted branches with an open end that a ``drop``ped branch lies ahead of, a fragment
    of their own tube (DROPPED_AHEAD_RADII, FRAGMENT_RADIUS_SHARE): while that branch was there its
    stand-in took the tube's points about it, and the end stopped where they began."""
    out = []
    for k, fit in enumerate(fits):
        if not fit or fit.closed:
            continue
        thin = [skel.branches[i].points for i in drop
                if np.median(skel.branches[i].radius) < FRAGMENT_RADIUS_SHARE * fit.eq6]
        if not thin:
            continue
        ahead = np.concatenate(thin)
        for e in (0, 1):
            if skel.branches[k].ends[e] is not None:
                continue
            p, d = _end_frame(fit.spine, e)
            along = (ahead - p) @ d
            off = np.linalg.norm(ahead - p - along[:, None] * d, axis=1)
            if np.any((along > 0) & (along < DROPPED_AHEAD_RADII * fit.eq6) & (off < (1 + ASSIGN_RADII) * fit.eq6)):
                out.append(k)
                break
    return out


def _as_branch(spine: BSpline, radius: BSpline, branch: SkeletonBranch) -> SkeletonBranch:
    """A skeleton branch along ``spine`` in place of ``branch`` (its ends, its thin points spread evenly
    along it): the estimate the branch is fitted again from."""
    t, pts = sample_arclength(spine, len(branch.points))
    weights = np.full(len(t), branch.weights.sum() / len(t))
    return SkeletonBranch(pts, weights, radius(t), branch.ends, branch.closed)


def _veered_ends(fits: list, skel: Skeleton, done: set) -> dict:
    """``{i: (spine, radius)}``: the fitted branches (but those ``done``) with an open end that runs into
    another tube, away from junctions, where the branch going on straight would not, each cut inside that
    end and continued straight (:func:`_straightened`) -- the estimate to fit it again from.

    A thin pipe's end beside a wider one it touches can follow the wider one's points into its tube: the
    two fit a sector of them about as well.  Going on straight, it stays on its own; a stub whose end
    meets a tube head-on (a tee whose junction was not found) would not, and keeps its fit.
    """
    live = [i for i, f in enumerate(fits) if f]
    if len(live) < 2:
        return {}
    largest = _largest_at_junctions(fits, skel)
    met = [[(skel.junctions[j], JUNCTION_EXCLUSION_RADII * largest[j]) for j in skel.branches[i].ends if j is not None]
           for i in live]
    inside = inside_others([(fits[i].spine, fits[i].radius) for i in live], met)
    out = {}
    for n, i in enumerate(live):
        fit, (t, _, other) = fits[i], inside[n]
        if i in done or fit.closed or (other >= 0).all():
            continue
        hooks, into = {}, set()
        for end, run in ((0, other), (1, other[::-1])):
            held = int(np.argmin(run >= 0))  # samples inside another tube, from this end
            if held and skel.branches[i].ends[end] is None:
                hooks[end] = t[held - 1] if end == 0 else t[len(t) - held]
                into |= set(run[:held].tolist())
        straight = _straightened(fit, hooks) if hooks else None
        if straight is not None and not (inside_others([straight] + [(fits[live[o]].spine, fits[live[o]].radius)
                                                                     for o in into])[0][2] >= 0).any():
            out[i] = straight
    return out


#: Two fitted branches are pieces of one tube -- the thin set broke along it, or two passes each found
#: a part -- when their open ends point against each other (within MAX_PIECE_TURN degrees), their radii
#: differ by no more than MAX_GAP_RADIUS_CHANGE, and either the end of each lies inside the other's
#: tube (continued straight PIECE_GAP_RADII radii past its end) or each end lies ahead of the other on
#: the line continuing it, no farther aside than the radius, at most MAX_PIECE_GAP_RADII radii away.
#: Left apart, the one more inside the other is dropped (the tube is cut short), both stay (written
#: twice), or the stretch between is missing: a coarse pass's branch across the tube there, to its
#: neighbours, kept that stretch from the finer pass's thin set, and was dropped as no tube.
PIECE_GAP_RADII = 1.0
MAX_PIECE_GAP_RADII = 20.0
MAX_PIECE_TURN = 30.0
#: Spine samples per radius of that test.
PIECE_SAMPLES_PER_RADIUS = 2
#: The joined fit must fit its points within this many times the inlier RMS of the worse-fitting piece.
JOINED_RMS_RATIO = 1.25


def _pieces_of_one_tube(fits: list, skel: Skeleton, refused: tuple = ()) -> list:
    """Pairs ``((a, ea), (b, eb))`` of open ends of fitted branches that may be one tube's two pieces
    (see PIECE_GAP_RADII), each branch in one pair at most: those inside each other first, then those
    in line, the pairs whose ends are closest first in each.  A pair of ``refused`` (its two fits, by
    identity, and their ends: see :func:`_joined_pieces`) is none."""
    pts, radius, ends = [], {}, {}
    for i, f in enumerate(fits):
        if not f or f.closed:
            continue
        radius[i] = r = float(np.mean(f.radius(np.linspace(0.0, 1.0, 64))))
        n = max(INSIDE_SAMPLES, int(PIECE_SAMPLES_PER_RADIUS * curve_length(f.spine) / r))
        tube = [sample_arclength(f.spine, n)[1]]
        for e in (0, 1):
            if skel.branches[i].ends[e] is None:
                ends[i, e] = p, d = _end_frame(f.spine, e)
                tube.append(p + np.outer(np.linspace(0.0, PIECE_GAP_RADII * r, PIECE_SAMPLES_PER_RADIUS + 1), d))
        pts.append((i, np.vstack(tube)))
    if len(ends) < 2:
        return []
    owner = np.concatenate([np.full(len(x), i) for i, x in pts])
    pts = np.vstack([x for _, x in pts])
    keys = list(ends)
    own = np.array([a for a, _ in keys])
    # [m, n]: the tube of end n's branch (continued past its open ends) holds end m
    inside = np.zeros((len(keys), len(keys)), bool)
    for m, near in enumerate(cKDTree(pts).query_ball_point([ends[k][0] for k in keys], max(radius.values()))):
        near = np.asarray(near, int)
        close = np.linalg.norm(pts[near] - ends[keys[m]][0], axis=1) < np.array([radius[o] for o in owner[near]])
        inside[m] = np.isin(own, owner[near[close]])
    p, d = (np.array([ends[k][n] for k in keys]) for n in (0, 1))
    r = np.array([radius[a] for a in own])
    v = p[None] - p[:, None]  # [m, n]: from end m to end n
    ahead = np.einsum("mnk,mk->mn", v, d)
    aside = np.linalg.norm(v - ahead[..., None] * d[:, None], axis=2)
    wider = np.maximum(r[:, None], r[None])
    in_line = (ahead > 0) & (aside <= wider) & (np.linalg.norm(v, axis=2) <= MAX_PIECE_GAP_RADII * wider)
    pair = ((own[:, None] < own[None]) & (d @ d.T <= -np.cos(np.radians(MAX_PIECE_TURN)))
            & (np.abs(r[:, None] - r[None]) <= MAX_GAP_RADIUS_CHANGE * wider)
            & ((in_line & in_line.T) | (inside & inside.T)))
    # Pieces that overlap or nearly meet before pieces a gap apart: those are surer.
    candidates = [(not (inside[m, n] and inside[n, m]), float(np.linalg.norm(v[m, n])), keys[m], keys[n])
                  for m, n in np.argwhere(pair) if not _refused(fits, keys[m], keys[n], refused)]
    pairs, taken = [], set()
    for *_, (a, ea), (b, eb) in sorted(candidates):
        if not {a, b} & taken:
            taken |= {a, b}
            pairs.append(((a, ea), (b, eb)))
    return pairs


def _refused(fits: list, end_a: tuple, end_b: tuple, refused) -> bool:
    """Whether the pair of ends ``end_a``, ``end_b`` (``(branch, end)`` each) is one of ``refused``."""
    (a, ea), (b, eb) = end_a, end_b
    return any(fa is fits[a] and fb is fits[b] and (xa, xb) == (ea, eb) for fa, xa, fb, xb in refused)


def _unmet_ends(fits: list, skel: Skeleton) -> list:
    """``(branch, end)`` of the fitted branches whose end does not meet its junction: the junction lies
    behind the end by more than END_TRIM_RADII of the branch's radius (the fit runs on past it), or
    aside of the line continuing the end by more than the branch's radius and the largest there.

    Two tubes that run side by side, close together, can share a thin set for a stretch, which the
    skeleton reads as a junction between them: each tube's fit, to its own points, runs past it.
    (Joined there, such a fit folds and is left out.)
    """
    largest = _largest_at_junctions(fits, skel)
    unmet = []
    for i, (fit, branch) in enumerate(zip(fits, skel.branches)):
        for e, j in enumerate(branch.ends):
            if not fit or j is None:
                continue
            p, d = _end_frame(fit.spine, e)
            v = skel.junctions[j] - p
            ahead = float(v @ d)
            if ahead < -END_TRIM_RADII * fit.eq6 or np.linalg.norm(v - ahead * d) > fit.eq6 + largest[j]:
                unmet.append((i, e))
    return unmet


#: Two tubes that touch can share their thin set where they touch, which the skeleton reads as a junction
#: between them; seen from far enough (``skeleton.BRIDGE_WINDOW_RADII``) the skeleton parts them, but a
#: tube only a few radii long gives no such view.  Their fits do: two fitted ends at one junction that
#: run parallel (within SIDE_BY_SIDE_TURN degrees, either way) and whose lines each pass the other's end
#: farther off than the wider radius are tubes side by side, not branches that meet.
SIDE_BY_SIDE_TURN = 15.0


def _off_line(p: np.ndarray, origin: np.ndarray, direction: np.ndarray) -> float:
    v = p - origin
    return float(np.linalg.norm(v - (v @ direction) * direction))


def _side_by_side(fits: list, skel: Skeleton) -> tuple[list, list]:
    """Branch ends (``(branch, end)``) at a false junction between fitted tubes side by side (see
    SIDE_BY_SIDE_TURN): the ends whose line misses the junction by more than their radius (they were
    linked to it), and, where two ends are left there in line (a tube the false junction cut in two), those
    two, for :func:`_joined_pieces` to join.  Returns the ends linked and the ends left in line."""
    parallel = np.cos(np.radians(SIDE_BY_SIDE_TURN))
    linked, pieces = [], []
    for j, ends in _ends_at_junctions([b.ends for b in skel.branches]).items():
        ends = [(i, e) for i, e in ends if fits[i] and not fits[i].closed]
        frames = {m: (*_end_frame(fits[m[0]].spine, m[1]), fits[m[0]].eq6) for m in ends}
        here = set()
        for a, b in combinations(ends, 2):
            (pa, da, ra), (pb, db, rb) = frames[a], frames[b]
            wider = max(ra, rb)
            if (a[0] != b[0] and abs(da @ db) >= parallel
                    and min(_off_line(pb, pa, da), _off_line(pa, pb, db)) > wider):
                here |= {m for m in (a, b) if _off_line(skel.junctions[j], *frames[m][:2]) > frames[m][2]}
        linked += sorted(here)
        left = [m for m in ends if m not in here]
        if here and len(left) == 2:
            (pa, da, ra), (pb, db, rb) = frames[left[0]], frames[left[1]]
            if da @ db <= -parallel and _off_line(pb, pa, da) <= max(ra, rb):
                pieces += left
    return linked, pieces


def _spans(fit: _BranchFit, first: np.ndarray, last: np.ndarray) -> bool:
    """Whether a fit of two joined pieces reaches the far ends ``first`` and ``last`` of both (passes
    within END_TRIM_RADII radii of them): where the points between the pieces are missing (taken by a
    branch across the tube there), the fit stops at that gap, and would put one piece in place of both."""
    spine = sample_arclength(fit.spine, max(INSIDE_SAMPLES, int(curve_length(fit.spine) / fit.eq6)))[1]
    return bool(cKDTree(spine).query(np.array([first, last]))[0].max() <= END_TRIM_RADII * fit.eq6)


def _leaves(fit: _BranchFit, piece: _BranchFit) -> bool:
    """Whether the spine of a fit of joined pieces leaves the tube of one of them beside it (passes
    farther from that piece's spine than its radius, abreast of it, not past its ends): a pipe's joined
    fit took to the points of a neighbour as wide as it that it touches, across the pieces' gap or
    where they overlap."""
    n = max(INSIDE_SAMPLES, int(PIECE_SAMPLES_PER_RADIUS * curve_length(piece.spine) / piece.eq6))
    t, pts = sample_arclength(piece.spine, n)
    mine = sample_arclength(fit.spine, max(INSIDE_SAMPLES, int(PIECE_SAMPLES_PER_RADIUS * curve_length(fit.spine)
                                                                / fit.eq6)))[1]
    distance, nearest = cKDTree(pts).query(mine)
    abreast = (nearest > 0) & (nearest < n - 1)
    return bool((distance[abreast] > piece.radius(t[nearest[abreast]])).any())


def _joined_pieces(fits: list, skel: Skeleton, job: dict, client, made: dict,
                   refused: tuple = ()) -> tuple[Skeleton, list, list]:
    """The skeleton and fits with each two pieces of one tube (:func:`_pieces_of_one_tube`, but for the
    pairs ``refused``) joined and fitted as one branch -- where that fit is a tube; else both pieces stay
    as they were.  Also the pairs refused now, as ``(fit, end, fit, end)``.  ``made``: see
    :class:`_Estimates`."""
    pairs = _pieces_of_one_tube(fits, skel, refused)
    if not pairs:
        return skel, fits, []
    ends = {(a, ea): _end_frame(fits[a].spine, ea) for (a, ea), _ in pairs}
    outward = {key: d for key, (_, d) in ends.items()}
    joined, origin = with_ends_joined(skel, pairs, outward)
    todo = [k for k, o in enumerate(origin) if o is None]
    job = {**job, "estimates": _Estimates(joined, made)}
    # A joined branch takes the place of the first of its pair, so they come in that order.
    by_first = dict(zip(sorted(a for (a, _), _ in pairs), _fit_all(todo, job, client)))
    # Kept where the one fit is a tube, reaches the far ends of both, and fits its points about as closely
    # as the pieces did: a piece of a canal whose radius changes fast (a trunk's flare) may not go on into
    # the other as one spline.  Pieces a gap apart, more than the inside test allows, need points all
    # along it: two tubes in line, a stretch apart, are not one.
    def kept(a, ea, b, eb):
        fit = by_first[a]
        if not isinstance(fit, _BranchFit) or not _spans(fit, fits[a].spine(1.0 - ea), fits[b].spine(1.0 - eb)):
            return False
        if _quality(fit)["rms"] > JOINED_RMS_RATIO * max(_quality(fits[a])["rms"], _quality(fits[b])["rms"]):
            return False
        if _leaves(fit, fits[a]) or _leaves(fit, fits[b]):
            return False
        p, d = ends[a, ea]
        gap = float((fits[b].spine(float(eb)) - p) @ d)
        return gap <= (PIECE_GAP_RADII + 1) * fit.eq6 or not _gapped(fit, fit.eq6, False)

    good = [((a, ea), (b, eb)) for (a, ea), (b, eb) in pairs if kept(a, ea, b, eb)]
    log.info("%d of %d pairs of branches are pieces of one tube: joined", len(good), len(pairs))
    bad = [(fits[a], ea, fits[b], eb) for (a, ea), (b, eb) in pairs if ((a, ea), (b, eb)) not in good]
    if not good:
        return skel, fits, bad
    joined, origin = with_ends_joined(skel, good, outward) if len(good) < len(pairs) else (joined, origin)
    firsts = iter(sorted(a for (a, _), _ in good))
    return joined, [by_first[next(firsts)] if o is None else fits[o] for o in origin], bad


def _fit_network(points: np.ndarray, skel: Skeleton, *, kind: str, refine: bool, noise: float,
                 quantum: float, curved: np.ndarray, kappa: np.ndarray, loose: np.ndarray | None = None,
                 client=None):
    """Fit every branch; drop those that are no tube and join the branches they separated.

    ``noise`` is the scan's own noise (:func:`_noise`), against which a branch's misfit is judged,
    ``quantum`` the part of it its coordinates' grid alone adds (:func:`canalsurf.pointcloud.quantisation_noise`);
    ``curved`` marks the points that may be fitted (:func:`_assign`), ``kappa`` is each point's larger
    principal curvature (a tube's points curve with its radius); ``loose`` marks the points of a pass
    that fell back to cross-sections whose own was not found, which a branch takes back where they lie
    on its surface (:func:`_regathered`); ``client``, Dask's, fits there.
    """
    fits = [None] * len(skel.branches)
    fittable = _Fittable(points, curved)
    loose = _Fittable(points, loose) if loose is not None and loose.any() else None
    cut = set()  # branches cut to their part outside other tubes
    straightened = set()  # branches fitted again from an end continued straight (_veered_ends)
    made = {}  # the branches' first estimates (see _Estimates)
    for round_ in range(MAX_FIT_ROUNDS):
        estimates = _Estimates(skel, made)
        job = {"points": points, "estimates": estimates, "fittable": fittable, "kappa": kappa, "kind": kind,
               "refine": refine, "noise": noise, "quantum": quantum, "loose": loose}
        todo = [i for i, f in enumerate(fits) if f is None]
        reason = ""
        last = round_ == MAX_FIT_ROUNDS - 1  # a branch cut (a part, legs) in the last round could not be fitted
        for i, fit in zip(todo, _fit_all(todo, job, client)):
            if isinstance(fit, _Folded):
                if not last:
                    log.info("branch %d folds (%s): fitted again as %d leg(s)", i, fit.why, len(fit.legs))
                    skel = replace(skel, branches=[fit.legs[0] if n == i else b for n, b in enumerate(skel.branches)]
                                   + fit.legs[1:])
                    fits += [None] * (len(fit.legs) - 1)
                    continue
                fit = fit.why
            if isinstance(fit, str):
                reason, fit = fit, False
            fits[i] = fit
        if refine:
            unmet = _unmet_ends(fits, skel)
            if unmet:
                log.info("%d branch ends do not meet their junction: opened", len(unmet))
                skel = with_ends_opened(skel, unmet)
            linked, pieces = _side_by_side(fits, skel)
            if linked:
                log.info("%d branch ends at a junction between tubes side by side: opened", len(linked))
                skel = with_ends_opened(skel, linked + pieces)
                if not last:
                    # Each fit stopped where the junction's reach began: fitted again from it, its open end
                    # grows into its own tube's points there.
                    redo = {i for i, _ in linked}
                    skel = replace(skel, branches=[_as_branch(fits[n].spine, fits[n].radius, b) if n in redo else b
                                                   for n, b in enumerate(skel.branches)])
                    fits = [None if n in redo else f for n, f in enumerate(fits)]
            # A tube in three pieces or more is joined a pair at a time.  A pair refused is not tried
            # again in this round: its pieces' fits are unchanged, and so would its joined fit be, unless
            # a neighbour joined since took some of its points.  (After branches are dropped, the next
            # round tries it again: a dropped branch may have held points it lacked.)
            refused = []
            while True:
                before = len(fits)
                skel, fits, bad = _joined_pieces(fits, skel, job, client, made, tuple(refused))
                refused += bad
                if len(fits) == before:
                    break
        inside = _inside_others(fits, skel)
        were = {i: fits[i] for i in inside}
        rest = [False if k in inside else f for k, f in enumerate(fits)]
        opened = False  # a part left a junction
        for i in inside:
            part = None if i in cut or last else _own_part(rest, skel.branches[i], fits[i].eq6)
            if part is None:
                reason, fits[i] = "its spine runs inside other tubes (it joins their ends, it is none itself)", False
            else:
                opened |= part.ends != skel.branches[i].ends
                skel = replace(skel, branches=[part if k == i else b for k, b in enumerate(skel.branches)])
                fits[i] = None
                cut.add(i)
        if not last:
            # The points of a piece dropped are the tube's it was a piece of: that tube is fitted again,
            # from its fit, to grow into them.
            for k in _grown_into(fits, skel, [were[i] for i in inside if fits[i] is False]):
                skel = replace(skel, branches=[_as_branch(fits[k].spine, fits[k].radius, b) if n == k else b
                                               for n, b in enumerate(skel.branches)])
                fits[k] = None
            for k, (spine, radius) in _veered_ends(fits, skel, straightened).items():
                log.info("branch %d runs into another tube at an open end: fitted again from its straight "
                         "continuation", k)
                skel = replace(skel, branches=[_as_branch(spine, radius, b) if n == k else b
                                               for n, b in enumerate(skel.branches)])
                fits[k] = None
                straightened.add(k)
        drop = [i for i, f in enumerate(fits) if f is False]
        if not drop and not opened:
            if all(fits):
                break
            continue
        if len(drop) == len(fits):
            raise ReconstructionError(f"no part of the cloud is a tube ({reason or 'no branch could be fitted'})"
                                      " — check the input is a scan of pipes or canals")
        if drop:
            log.info("%d of %d branches are no tube (left out): %s", len(drop), len(fits), reason)
            if not last:
                # A fragment of a tube's thin set left out held points the tube's open end would have
                # grown into: the tube is fitted again, from its fit, without it.
                for k in _fragments_ahead(fits, skel, drop):
                    skel = replace(skel, branches=[_as_branch(fits[k].spine, fits[k].radius, b) if n == k else b
                                                   for n, b in enumerate(skel.branches)])
                    fits[k] = None
        skel, origin = without_branches(skel, drop)
        skel, unchanged = with_tees_mended(skel)
        origin = [None if u is None else origin[u] for u in unchanged]
        fits = [None if o is None else fits[o] for o in origin]
        cut = {n for n, o in enumerate(origin) if o in cut}
        straightened = {n for n, o in enumerate(origin) if o in straightened}
    else:
        if any(f is None or f is False for f in fits):
            raise ReconstructionError("the branches of the network could not be fitted — the input is not a tube")
    if refine:
        skel, fits = _grown_on(fits, skel, job, client, made)
        skel, fits = _fitted_about_placed_junctions(fits, skel, job, client, made)
        fits = _clear_of_contacts(fits, skel)
    for fit, branch in zip(fits, skel.branches):
        fit.ends = branch.ends
    return skel, fits


#: Samples of each spine per (smallest) radius where :func:`_near_pairs` looks for tubes that touch.
CONTACT_SAMPLES_PER_RADIUS = 2
#: A branch is fitted again without its points on the line of contact only if at least this share of
#: them is left: a branch whose points mostly lie on others' surfaces (a crease between two pipes) is
#: :func:`_crease`'s to judge on all of them.
CONTACT_KEEP_SHARE = 0.5


def _clear_of_contacts(fits: list, skel: Skeleton) -> list:
    """The fits, with each branch that touches another it does not meet at a junction fitted again
    without the points on the line where they touch.

    There (a bundle's pipes, a pipe laid on another) each tube's points lie within the outlier cut of
    the other's surface too, and a branch's fit took in some of its neighbour's: they lie outside its
    surface, and drew its spine towards the neighbour and its radius up (on ``synth``'s bundle by up to
    0.2 % of the radius, 4 - 5 times the best fit of the tube's own points, ``docs/oracle.md``).
    Left out are the points whose place on the branch's surface (the footpoint's circle, along the
    point's direction from the spine) lies within the two branches' outlier cuts of the other's
    surface: chosen by where they lie round the spine, not by their own residual, the points left are
    no biased sample of the tube.  They are left out of the fit only: the branch keeps them, and its
    checks (where its surface was seen, how well it fits) take them in.  A branch that cannot be
    fitted again keeps its fit.
    """
    met = [{j for j in b.ends if j is not None} for b in skel.branches]
    out = list(fits)
    cuts = [outlier_cut(f.residual, f.eq6) for f in fits]
    for i, near in _near_pairs(fits, cuts).items():
        others = [j for j in near if not met[i] & met[j]]
        if not others:
            continue
        fit = fits[i]
        centre = fit.spine(fit.t)
        off = fit.points - centre
        place = centre + fit.radius(fit.t)[:, None] * off / np.maximum(np.linalg.norm(off, axis=1), 1e-300)[:, None]
        shared = np.zeros(len(place), bool)
        for j in others:
            _, distance = footpoints(place, fits[j].spine, fits[j].radius, closed=fits[j].closed)
            shared |= np.abs(distance) <= cuts[i] + cuts[j]
        keep = ~shared
        if not shared.any() or keep.sum() < CONTACT_KEEP_SHARE * len(keep):
            continue
        nseg, rseg = fit.segments
        try:
            new = refine_fit(fit.points[keep], fit.spine, fit.radius, closed=fit.closed, spine_segments=nseg,
                             radius_segments=None if fit.kind == "pipe" else rseg, reach=fit.eq6)
        except ReconstructionError:
            continue
        # The branch keeps its points: where its surface was seen, and how well it fits them, take in the
        # line of contact too.
        t, residual = np.empty(len(keep)), np.empty(len(keep))
        t[keep], residual[keep] = new.t, new.residual
        t[shared], residual[shared] = footpoints(fit.points[shared], new.spine, new.radius, closed=fit.closed)
        out[i] = replace(fit, spine=new.spine, radius=new.radius, residual=residual, t=t)
    refitted = sum(a is not b for a, b in zip(out, fits))
    if refitted:
        log.info("%d branches touch another they do not meet at a junction: fitted again without the points "
                 "where they touch", refitted)
    return out


def _near_pairs(fits: list, cuts: list) -> dict:
    """``{branch: [other branches]}``: the pairs of branches whose surfaces may come within their outlier
    ``cuts`` of each other (their spines' samples within both radii, cuts and half sample steps)."""
    samples, reach = [], []
    for fit, cut in zip(fits, cuts):
        r = fit.radius(np.linspace(0.0, 1.0, 64))
        length = curve_length(fit.spine)
        n = max(2, math.ceil(CONTACT_SAMPLES_PER_RADIUS * length / float(r.min())) + 1)
        samples.append(sample_arclength(fit.spine, n)[1])
        reach.append(float(r.max()) + cut + length / (n - 1) / 2)
    reach = np.array(reach)
    lo = np.array([s.min(axis=0) for s in samples]) - reach[:, None]
    hi = np.array([s.max(axis=0) for s in samples]) + reach[:, None]
    overlap = np.all((lo[:, None] <= hi[None]) & (hi[:, None] >= lo[None]), axis=2)
    pairs = {}
    for i, j in zip(*np.nonzero(np.triu(overlap, 1))):
        d, _ = cKDTree(samples[j]).query(samples[i], distance_upper_bound=reach[i] + reach[j])
        if np.isfinite(d).any():
            pairs.setdefault(int(i), []).append(int(j))
            pairs.setdefault(int(j), []).append(int(i))
    return pairs


#: A junction placed from its branches' fits (:func:`_junction_point`) more than this share of the largest
#: radius there from where the skeleton put it moves the points its branches leave out with it: they are
#: fitted again.
REFIT_JUNCTION_RADII = 0.25


def _grown_on(fits: list, skel: Skeleton, job: dict, client, made: dict):
    """The skeleton and fits with each branch whose open end still grew after MAX_GROW_ROUNDS (its thin set
    stopped many radii short of its tube's end: a thin pipe's, tangled where it touches wider ones) fitted
    again from its fit, to grow on, at most GROW_ON_FITS times.  Done once the network's branches are
    settled: which branches are kept and joined must not hang on how far an end has grown yet.  A fit that
    fails keeps the fit before it."""
    for _ in range(GROW_ON_FITS):
        todo = [i for i, f in enumerate(fits) if f.growing]
        if not todo:
            break
        log.info("%d branches still grow at an open end: fitted again from their fits", len(todo))
        skel = replace(skel, branches=[_as_branch(fits[i].spine, fits[i].radius, b) if i in todo else b
                                       for i, b in enumerate(skel.branches)])
        job = {**job, "estimates": _Estimates(skel, made)}
        for i, fit in zip(todo, _fit_all(todo, job, client)):
            fits[i] = fit if isinstance(fit, _BranchFit) else replace(fits[i], growing=False)
    for fit in fits:
        fit.growing = False
    return skel, fits


def _fitted_about_placed_junctions(fits: list, skel: Skeleton, job: dict, client, made: dict):
    """The skeleton with its junctions placed from the fits, and the branches meeting at one that moved
    (REFIT_JUNCTION_RADII) fitted again about it.

    The thin set's junction can lie radii into one of its branches (the fork of an acute Y thins to a
    point up the fork): each branch then left out the points round that point, one of them radii too
    many, another the points where the tubes' surfaces merge.  Its branches' fitted ends place it where
    their lines meet; points are left out round that place instead, and the branches' points are
    assigned by their fits continued to it (their first estimates ran to the skeleton's junction, one
    of them inside another tube).  A branch that cannot be fitted again keeps its fit.
    """
    largest = _largest_at_junctions(fits, skel)
    junctions, moved = skel.junctions.copy(), set()
    for j, ends in _ends_at_junctions([b.ends for b in skel.branches]).items():
        placed = _junction_point(fits, ends, skel.junctions[j])
        if np.linalg.norm(placed - skel.junctions[j]) > REFIT_JUNCTION_RADII * largest[j]:
            junctions[j] = placed
            moved.add(j)
    if not moved:
        return skel, fits
    log.info("%d junctions placed from the fits moved: their branches are fitted again", len(moved))
    skel = replace(skel, junctions=junctions)
    todo = [i for i, b in enumerate(skel.branches) if moved & set(b.ends)]
    estimates = _Estimates(skel, made)
    for i in todo:
        fit = replace(fits[i])
        for e, j in enumerate(skel.branches[i].ends):
            if j is not None:
                _continue_to(fit, e, junctions[j])
        estimates = estimates.replaced(i, {**estimates.guesses[i], "spine": fit.spine, "radius": fit.radius,
                                           "segments": fit.segments})
    job = {**job, "estimates": estimates}
    for i, fit in zip(todo, _fit_all(todo, job, client)):
        if isinstance(fit, _BranchFit):
            fits[i] = fit
    return skel, fits


def _ends_at_junctions(ends: list) -> dict:
    """``{junction: [(branch, end), ...]}`` from each branch's ``ends`` (a junction or ``None`` each)."""
    meeting = {}
    for i, pair in enumerate(ends):
        for e, j in enumerate(pair):
            if j is not None:
                meeting.setdefault(j, []).append((i, e))
    return meeting


# --------------------------------------------------------------------------------------------------
# junctions


def _end_frame(spine: BSpline, end: int) -> tuple[np.ndarray, np.ndarray]:
    """Point and unit tangent pointing out of the branch at ``end`` (0: t = 0, 1: t = 1)."""
    d = spine.derivative()(float(end))
    d = d / np.linalg.norm(d)
    return spine(float(end)), (d if end == 1 else -d)


def _junction_point(fits: list, ends: list, guess: np.ndarray) -> np.ndarray:
    """The point nearest to the lines continuing the branch ends (least squares), near ``guess``.

    A T's two halves of the main pipe fix the point on their common axis, the side branch fixes it
    along that axis; a light pull towards the skeleton's junction keeps it determined when lines are
    parallel.  Too far from the skeleton's junction (a bad tangent), the skeleton's is kept.
    """
    A = np.zeros((3, 3))
    b = np.zeros(3)
    largest = max(fits[i].eq6 for i, _ in ends)
    for i, e in ends:
        p, d = _end_frame(fits[i].spine, e)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ p
    pull = 1e-3 * len(ends)
    point = np.linalg.solve(A + pull * np.eye(3), b + pull * guess)
    return point if np.linalg.norm(point - guess) <= 2 * largest else guess


#: A spine end is cut back to its point nearest its junction when that point lies within this many
#: of the branch's radii of the end.
END_TRIM_RADII = 2.0


def _continue_to(fit: _BranchFit, end: int, target: np.ndarray) -> None:
    """Continue the branch's spine from ``end`` smoothly to ``target`` (a Hermite arc), in place."""
    spine, radius = fit.spine, fit.radius
    length = curve_length(spine)
    nseg = len(spine.t) - 2 * spine.k - 1
    n = max(40 * nseg, 2001)
    t = np.linspace(0.0, 1.0, n)
    pts, r = spine(t), radius(t)
    # A spine that runs on past the junction (or turns away before it) is cut back at its point
    # nearest the junction, within a radius or two of the end: an arc from its end would turn round
    # to reach a point behind it, a hook that folds the tube.
    near_end = np.flatnonzero(np.abs(t - end) * length <= END_TRIM_RADII * fit.eq6)
    nearest = near_end[np.argmin(np.linalg.norm(pts[near_end] - target, axis=1))]
    keep = slice(0, nearest + 1) if end == 1 else slice(nearest, n)
    pts, r, t_end = pts[keep], r[keep], float(t[nearest])
    p = pts[-1] if end == 1 else pts[0]
    d = spine.derivative()(t_end)
    d = d / np.linalg.norm(d) * (1.0 if end == 1 else -1.0)
    gap = float(np.linalg.norm(target - p))
    if gap <= 1e-9 * length:
        return
    u = np.linspace(0.0, 1.0, max(20, int(n * gap / length)))[1:, None]
    h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
    arc = h00 * p + h10 * gap * d + h01 * target + h11 * gap * d
    # A canal's radius goes on changing at its rate at the end (per unit of length along the arc).
    along = polyline_arclength(np.vstack([p, arc]))[1:]
    rate = float(radius.derivative()(t_end)) / length * (1.0 if end == 1 else -1.0)
    r_arc = float(radius(t_end)) + rate * along
    if end == 1:
        pts, r = np.vstack([pts, arc]), np.r_[r, r_arc]
    else:
        pts, r = np.vstack([arc[::-1], pts]), np.r_[r_arc[::-1], r]
    s = polyline_arclength(pts)
    s /= s[-1]
    grow = 1.0 + gap / length
    fit.spine = pspline_fit(s, pts, n_segments=math.ceil(nseg * grow), smoothing=1e-9)
    if fit.kind == "canal":
        rseg = len(radius.t) - 2 * radius.k - 1
        fit.radius = pspline_fit(s, r, n_segments=math.ceil(rseg * grow), smoothing=1e-9)


def _join_at_junctions(fits: list, skel: Skeleton):
    """Place each junction and continue the spines of the branches that meet there to it."""
    meeting = _ends_at_junctions([f.ends for f in fits])
    points = np.empty((len(skel.junctions), 3))
    for j, ends in sorted(meeting.items()):
        points[j] = _junction_point(fits, ends, skel.junctions[j])
    for j, ends in sorted(meeting.items()):
        for i, e in ends:
            _continue_to(fits[i], e, points[j])
    # The refits leave each end within a small fraction of a radius of its junction; a clamped
    # spline ends at its end control point, so that point is the junction.
    for j, ends in meeting.items():
        for i, e in ends:
            fits[i].spine.c[-1 if e == 1 else 0] = points[j]
    return fits, points


# --------------------------------------------------------------------------------------------------
# checks and the result


def _unfolded(fits: list, junction_points: np.ndarray) -> tuple[list, np.ndarray, list]:
    """The branches less those whose spine folds once continued into its junctions and those that are
    a crease between others (:func:`_crease`), and why each of those was left out; a junction left with
    one branch end becomes an open end, with none it goes.

    Every branch was checked for folds before the junctions were placed (:func:`_quality`); a spine
    continued into a junction that lies behind its end can fold.  A scene keeps its other tubes; a
    scan whose every branch is left out is refused.
    """
    near = _near_pairs(fits, [outlier_cut(f.residual, f.eq6) if len(f.residual) else 0.0 for f in fits])
    whys = [fold(fit.spine, fit.radius, fit.closed, junctions=junctions)
            or _crease(fit, [fits[j] for j in near.get(i, ())])
            for i, (fit, junctions) in enumerate(zip(fits, _junctions_met(fits, junction_points)))]
    return _without(fits, junction_points, whys)


def _without(fits: list, junction_points: np.ndarray, whys: list) -> tuple[list, np.ndarray, list]:
    """The fits less those with a reason (``whys``, ``""`` for none) to be left out, the junctions
    renumbered (one left with one branch end becomes an open end, with none it goes), and the reasons;
    a scan whose every branch is left out is refused."""
    kept = [fit for fit, why in zip(fits, whys) if not why]
    left_out = [why for why in whys if why]
    if not kept:
        raise ReconstructionError(f"{left_out[0]} — the model cannot be trusted; crop the scan to fewer tubes, "
                                  "or report it with the input")
    if left_out:
        log.info("%d of %d branches are left out once fitted: %s", len(left_out), len(fits), left_out[0])
        meeting = np.bincount([j for f in kept for j in f.ends if j is not None], minlength=len(junction_points))
        used = np.flatnonzero(meeting >= 2)
        renumber = {int(j): n for n, j in enumerate(used)}
        for fit in kept:
            fit.ends = tuple(None if j is None else renumber.get(j) for j in fit.ends)
        junction_points = junction_points[used]
    return kept, junction_points, left_out


#: A branch whose inliers lie on the surfaces of other branches (within their outlier cut) for more than
#: CREASE_SHARE of them is no tube: the crease where two wide pipes touch, seen from its open side, fits
#: a narrow tube whose points are theirs (a bundle of the trust checks, 100 % of its points on theirs),
#: and so does the gap between two pipes' facing surfaces, whose points surround it (273 degrees on a
#: random bundle).  A real tube that touches others shares only the points near the lines where they
#: touch: 15 - 29 % of them, within 5 % of the radius.
CREASE_SHARE = 0.8
#: Points of a branch (spread over its own, which lie in no order along it) the test looks at: enough
#: for a share, few enough not to cost a scene of hundreds of branches a second.
CREASE_POINTS = 100


def _crease(fit: _BranchFit, others: list) -> str:
    """Why ``fit`` is a crease between the ``others`` (CREASE_SHARE), the fits whose surfaces come near
    its own (:func:`_near_pairs`), or ``""``."""
    if not len(fit.points) or not others:
        return ""
    points = fit.points[np.linspace(0, len(fit.points) - 1, min(len(fit.points), CREASE_POINTS)).astype(int)]
    _, residual = footpoints(points, fit.spine, fit.radius, closed=fit.closed)
    pts = points[~is_stray(residual, fit.eq6)]
    on = np.zeros(len(pts), bool)
    for other in others:
        _, res = footpoints(pts, other.spine, other.radius, closed=other.closed)
        on |= np.abs(res - np.median(other.residual)) <= outlier_cut(other.residual, other.eq6)
    share = float(on.mean()) if len(on) else 0.0
    if share <= CREASE_SHARE:
        return ""
    return f"{share:.0%} of its points lie on other tubes (a crease or a gap between them)"


def _junctions_met(fits: list, junction_points: np.ndarray) -> list:
    """For each fit, the junctions it meets as ``(point, reach)``: the tubes meeting there are one within
    JUNCTION_EXCLUSION_RADII of the largest radius there."""
    reach = {j: JUNCTION_EXCLUSION_RADII * max(f.eq6 for f in fits if j in f.ends)
             for f in fits for j in f.ends if j is not None}
    return [[(junction_points[j], reach[j]) for j in f.ends if j is not None] for f in fits]


def _check_and_describe(scan: _Scan, fits: list, noise: float, junction_points: np.ndarray,
                        left_out: list = ()):
    """Per-branch diagnostics and the scan's: which points lie on a tube, how well, how seen, and the
    quality each can be trusted with (:mod:`canalsurf.quality`); ``left_out`` says why tubes found were
    left out of the model.  Also, of the sample of the scan's points measured, how many lie on each
    branch, and which (indices into the scan) lie beside a branch's surface (:func:`_beside`)."""
    branches = []
    inside = inside_others([(f.spine, f.radius) for f in fits], _junctions_met(fits, junction_points))
    for i, fit in enumerate(fits):
        t, residual = footpoints(fit.points, fit.spine, fit.radius, closed=fit.closed)
        stray = is_stray(residual, fit.eq6)
        near = ~stray
        stretches = angular_coverage(fit.points[near], fit.spine, t[near])
        coverage = float(np.median(stretches)) if len(stretches) else float("nan")
        rms = float(np.sqrt(np.mean(residual[near] ** 2))) if near.any() else float("inf")
        mean_r = float(np.mean(fit.radius(np.linspace(0, 1, 200))))
        level, reasons = branch_quality(
            rms=rms, radius=mean_r, noise=noise, coverage=coverage,
            gap=support_gap(t[near], curve_length(fit.spine), fit.closed),
            out_of_round=roundness(fit.points[near], fit.spine, t[near], residual[near]), stretches=stretches,
            inside=longest_inside(*inside[i][1:]))
        branches.append(CanalModel(fit.kind, fit.spine, fit.radius, fit.closed, diagnostics={
            "quality": level, "quality_reasons": reasons,
            "n_points": int(len(fit.points)), "eq6_radius": fit.eq6, "inlier_rms_residual": rms,
            "noise_sigma": robust_sigma(residual), "stray_share": float(stray.mean()),
            "angular_coverage": coverage, "one_sided": bool(coverage < C.ONE_SIDED_DEGREES),
            "spine_segments": fit.segments[0], "radius_segments": fit.segments[1]}, id=i, ends=fit.ends))
    # The scan as a whole, on a seeded sample of at most MAX_RESIDUAL_POINTS points.
    index = np.arange(len(scan.all_pts)) if scan.draw is None else np.sort(scan.draw[: C.MAX_RESIDUAL_POINTS])
    measured = scan.all_pts[index]
    label, distance = classify_points(measured, branches)
    on = label >= 0
    coverage = [b.diagnostics["angular_coverage"] for b in branches]
    no_tube = float(1.0 - on.mean())
    level, reasons = scan_quality([(b.id, b.diagnostics["quality"], b.diagnostics["quality_reasons"])
                                   for b in branches], no_tube, left_out)
    summary = {
        "quality": level, "quality_reasons": reasons,
        "n_residual_points": int(len(measured)),
        "no_tube_share": no_tube,
        "rms_residual": float(np.sqrt(np.mean(np.minimum(distance, 1e300) ** 2))),
        "inlier_rms_residual": float(np.sqrt(np.mean(distance[on] ** 2))) if on.any() else None,
        "noise_sigma": robust_sigma(distance[on]) if on.any() else None,
        "scan_noise": noise,
        "angular_coverage": float(np.nanmedian(coverage)) if np.isfinite(coverage).any() else float("nan"),
    }
    summary["one_sided"] = bool(summary["angular_coverage"] < C.ONE_SIDED_DEGREES)
    return branches, summary, np.bincount(label[on], minlength=len(branches)), \
        index[_beside(measured, label, distance, branches)]


def _beside(points: np.ndarray, label: np.ndarray, distance: np.ndarray, branches: list) -> np.ndarray:
    """Which ``points``, on no tube (``label`` -1 at signed ``distance`` from the nearest surface,
    :func:`canalsurf.network.classify_points`), lie beside a branch's surface: within EXPLAINED_RADII - 1
    of its mean radius, where the paper's stages counted them as on it."""
    band = EXPLAINED_RADII - 1
    mean_r = np.array([float(np.mean(b.radius(np.linspace(0, 1, 200)))) for b in branches])
    near = np.flatnonzero((label < 0) & (np.abs(distance) < band * mean_r.max(initial=0.0)))
    if len(near):
        # Which surface is nearest, without the cuts (the few points near some surface only).
        nearest, d = classify_points(points[near], branches, cut=[np.inf] * len(branches))
        near = near[np.abs(d) < band * mean_r[nearest]]
    return near


#: A branch seen from one side (``C.ONE_SIDED_DEGREES``) whose surface goes on past the arc its points
#: cover, off the tube, is no tube: an oval duct or a flattened hose, fitted as the round tube of its
#: tighter curved side.  Its points on no tube that lie beside it (:func:`_beside`) and curve (no floor or
#: wall it lies against: those are flat) are then at least CONTINUED_SHARE of those on it, and widen the
#: arc by CONTINUED_DEGREES or more; a one-sided scan's surface stops at the arc's edges (the points beside
#: a thin pole on a coarse grid lie within them), and a floor under a pipe goes on past them flat
#: (``tests/test_trust.py``: ovals of semi-axes 1 and 0.8, 1 and 0.7; a pipe against a floor, a wall).
CONTINUED_SHARE = 0.1
CONTINUED_DEGREES = 15.0


def _surface_goes_on(scan: _Scan, first: _Pass, fits: list, branches: list, on: np.ndarray,
                     beside: np.ndarray) -> list:
    """Why each branch is no tube as its surface goes on past its arc (CONTINUED_SHARE), or ``""``.
    ``on`` counts the points on each branch and ``beside`` indexes the scan's points beside them, of the
    same sample (:func:`_check_and_describe`); whether each curves is read at its nearest point of the
    ``first`` pass."""
    whys = [""] * len(fits)
    if not len(beside):
        return whys
    pts = scan.all_pts[beside]
    nearest, _ = classify_points(pts, branches, cut=[np.inf] * len(branches))
    counts = np.bincount(nearest, minlength=len(fits))
    todo = [i for i, b in enumerate(branches)
            if b.diagnostics["one_sided"] and counts[i] >= max(CONTINUED_SHARE * on[i], MIN_BRANCH_POINTS)]
    if not todo:
        return whys
    curved = np.zeros(len(first.scan.pts), bool)
    curved[first.curved] = True
    curved = curved[cKDTree(first.scan.pts).query(pts, workers=-1)[1]]
    for i in todo:
        fit = fits[i]
        mine = pts[(nearest == i) & curved]
        t, _ = footpoints(mine, fit.spine, fit.radius, closed=fit.closed)
        if not fit.closed:
            mine, t = mine[(t > 0.0) & (t < 1.0)], t[(t > 0.0) & (t < 1.0)]
        if len(mine) < max(CONTINUED_SHARE * on[i], MIN_BRANCH_POINTS):
            continue
        own_t, residual = footpoints(fit.points, fit.spine, fit.radius, closed=fit.closed)
        own = ~is_stray(residual, fit.eq6)
        before = np.median(angular_coverage(fit.points[own], fit.spine, own_t[own]))
        after = np.median(angular_coverage(np.vstack([fit.points[own], mine]), fit.spine, np.r_[own_t[own], t]))
        if after - before >= CONTINUED_DEGREES:
            whys[i] = (f"its surface goes on past the {before:.0f} degrees its points cover, off the tube "
                       f"({len(mine) / on[i]:.0%} as many points lie beside it as on it): an oval or flattened "
                       "section, not a round tube")
    return whys


#: After the fits, the points on no tube that lie beside a tube's surface, where the paper's stages took
#: them for its points (:func:`_explained`), are run through them again on their own when they are this
#: share of the scan: a thin pipe squeezed between two wider ones it touches (3.8 - 5.9 % of the points of
#: six such scans); beside the tubes of every network family, the plant and the real scans, at most 0.1 %.
BESIDE_SHARE = 0.01


def _beside_pass(scan: _Scan, beside: np.ndarray, k, given: dict, *, kind: str, neighbours: str,
                 quantum: float, timer: _Timer) -> _Pass | None:
    """A further pass of the paper's stages on the points ``beside`` the fitted tubes
    (:func:`_beside`), or None where they are too few or no tube is among them.

    The paper's stages count a point within a quarter radius of a skeleton's tube as explained by it:
    a thin pipe squeezed between two wider ones that it touches lies within that of their surfaces all
    round, and no finer pass sees it.  The fits know the surfaces to the noise; what they leave beside
    them is drawn again, once, on its own.
    """
    measured = min(len(scan.all_pts), C.MAX_RESIDUAL_POINTS)
    if len(beside) < max(BESIDE_SHARE * measured, MIN_BRANCH_POINTS):
        return None
    pts, nrm = scan.all_pts[beside], None if scan.all_normals is None else scan.all_normals[beside]
    try:
        run = _paper_stages(_Scan(scan.origin, scan.scale, pts, nrm, None, pts, nrm), k, given, kind=kind,
                            stop="auto", neighbours=neighbours, quantum=quantum, timer=timer, fallback=False)
    except ReconstructionError as exc:
        log.info("no tube among the %d points beside the tubes fitted: %s", len(beside), exc)
        return None
    run = replace(_trimmed(run), pool=beside)
    if len(run.thin) < MIN_BRANCH_POINTS:
        return None
    log.info("a further pass on the %d points beside the tubes fitted: r0 = %.4g, %d thin points",
             len(beside), run.r0 * scan.scale, len(run.thin))
    return run


def _to_input_units(branches: list, junction_points: np.ndarray, fits: list, scan: _Scan) -> Network:
    """Map the branches and junctions back to the input's units and placement."""
    s, o = scan.scale, scan.origin
    out = []
    for b in branches:
        d = dict(b.diagnostics)
        for key in ("eq6_radius", "inlier_rms_residual", "noise_sigma"):
            if d.get(key) is not None:
                d[key] = d[key] * s
        out.append(CanalModel(b.kind, BSpline(b.spine.t, b.spine.c * s + o, b.spine.k),
                              BSpline(b.radius.t, b.radius.c * s, b.radius.k), b.closed, diagnostics=d,
                              id=b.id, ends=b.ends))
    junctions = []
    for j, point in enumerate(junction_points):
        ends = [(b.id, e) for b in out for e, jj in enumerate(b.ends) if jj == j]
        junctions.append(Junction(j, point * s + o, ends))
    return Network(out, junctions)
