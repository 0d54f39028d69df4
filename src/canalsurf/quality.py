"""Checks: how far a model can be trusted -- ``good``, ``check`` or ``poor``, with the reasons.

Every model canalsurf writes has passed the self-checks of :mod:`canalsurf.pipeline` (a branch that is
no tube is left out, a scan with no tube is refused).  What passes may still be uncertain: a tube seen
from one side, with gaps in its points, noisy or out of round.  Each branch gets a quality from what
its own points show, the scan the worst of its branches' and its own reasons; ``docs/quality.md``
says what each reason means and what to do about it.

* ``good`` -- no reason for doubt;
* ``check`` -- usable, but look at the reasons (a one-sided scan, a gap, noise above the scan's);
* ``poor`` -- the model is a rough guide only.
"""

from __future__ import annotations

import numpy as np

from .constants import ONE_SIDED_DEGREES

__all__ = ["LEVELS", "CLAIMS", "branch_quality", "scan_quality", "support_gap", "fold", "inside_others",
           "longest_inside"]

#: Qualities from best to worst.
LEVELS = ("good", "check", "poor")
#: What a quality level claims of a branch, against the truth (shares of the true radius): the mean
#: distance of the model's spine from the true spine, and the model's mean radius error -- both away
#: from junctions, where the surface belongs to several tubes.  ``benchmarks/trust.py`` checks every
#: written model against these over hundreds of random scans; tests/test_trust.py on a sample.
CLAIMS = {"good": {"spine": 0.05, "radius": 0.03},
          "check": {"spine": 0.10, "radius": 0.10},
          "poor": {"spine": 0.25, "radius": 0.25}}
#: Inlier RMS distance from the surface above this share of the radius: ``poor`` (noise of a tenth
#: of the radius leaves single cross-sections, and so a short tube's radius, that uncertain).
POOR_RMS_RADII = 0.10
#: Inlier RMS above this many times the scan's own noise (the points' scatter about their local
#: planes) and this share of the radius: ``check`` -- the model misses a systematic part of the shape
#: (ovality, a bend, a dent), where random noise alone would average out.
CHECK_NOISE_RATIO, CHECK_RMS_RADII = 2.0, 0.02
#: Out of roundness (:func:`canalsurf.metrics.roundness`) above this share of the radius: ``check``.
CHECK_ROUND_RADII = 0.04
#: Angular coverage below ONE_SIDED_DEGREES is ``check`` (the radius comes from a partial arc);
#: below this, ``poor``.
POOR_COVERAGE_DEGREES = 120.0
#: ... and ``poor`` too where this share of a branch's stretches is seen over less than
#: POOR_COVERAGE_DEGREES, whatever the median: there its spine and radius rest on narrow arcs, and a
#: tube fitted to the sides of different limbs (one stretch seen from below, the next from one flank)
#: reads as well covered on the median alone.
POOR_COVERAGE_SHARE = 0.25
#: A gap along the spine with no points, longer than this many radii: ``check``; longer than the
#: second, ``poor`` (the spine there is an interpolation).
CHECK_GAP_RADII, POOR_GAP_RADII = 1.0, 3.0
#: More than this share of the scan on no tube: ``check`` (tubes in it may have been missed).
CHECK_NO_TUBE_SHARE = 0.5


#: A spine whose tangent turns by more than a right angle within this many radii of its length turns
#: back on itself: a hook, or a hairpin's tip.  Any real bend is gentler -- a pipe's tightest elbow
#: (bend radius 1 D = 2 r) turns 90 degrees over 3.1 radii -- and the wiggles of an unrefined spline,
#: however sharp, are too small to turn it round.
FOLD_TURN_RADII = 1.0
#: A pipe or canal surface is regular only where its spine bends less tightly than its radius (curvature
#: times radius below 1): beyond, the inner side of the bend passes through itself.  A spine that does so
#: along more than this share of its length is no tube's: a fit wiggling with the bumps of a one-sided
#: scan of bark.  Refined fits of the generated surfaces and networks stay below 1 throughout;
#: unrefined splines (``refine=False``) wiggle past it along short stretches only.
FOLD_BEND_SHARE = 0.2
#: Spine samples of :func:`fold`: bends and near passes are found to well within a radius.
FOLD_SAMPLES = 600
#: Two parts of a spine this many radii apart along it (half a turn round a circle of the radius
#: is pi) that come closer in space than the sum of their radii times the second constant
#: pass through each other.
FOLD_ALONG_RADII, FOLD_CLEARANCE = np.pi, 0.9
#: A spine that turns by more than a right angle within the first many radii and runs back within
#: the second times the sum of the radii of itself is a hairpin whose legs touch -- two tubes side by
#: side -- even where it passes the clearance.  A pipe fit whose end crept on and turned back along
#: the tube did so (legs 1.96-2.0 radii apart, turning 116-126 degrees within 2 radii).  Neither
#: alone is a fold: a coil's turns touch, and an unrefined spline's wiggle can turn a right angle
#: within 2 radii.
FOLD_HAIRPIN_RADII, FOLD_TOUCH = 2.0, 1.25


def fold(spine, radius, closed: bool, *, junctions=()) -> str:
    """Why a tube's spine folds -- it turns back on itself, or passes through itself -- or ``""`` if it
    does not.

    A tube whose spine turns round within a radius of its length folds onto itself; one whose spine
    comes back within a radius of itself (a hairpin: the spine of a short tube run to the far end and
    back) is two tubes in one place.  Neither is a pipe or canal surface.  Within ``junctions``
    (pairs of a point and a reach) the tubes meeting there are united and the spine is not checked.
    """
    from .spine import curvature, polyline_arclength, sample_arclength

    t, pts = sample_arclength(spine, FOLD_SAMPLES)
    r = radius(t)
    s = polyline_arclength(pts)
    length = s[-1]
    if closed and length < 2 * np.pi * r.max():
        # A ring's tube is round about a spine that is itself a circle of at least its radius.
        return (f"the spine is a loop {length / r.max():.1f} radii long, too short to go round a tube of "
                "its radius (it passes through itself)")
    checked = np.ones(len(t), bool)
    for point, reach in junctions:
        checked &= np.linalg.norm(pts - point, axis=1) > reach
    t, pts, r, s = t[checked], pts[checked], r[checked], s[checked]
    if not len(t):
        return ""
    tangent = spine.derivative()(t)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-300)
    if _turns_back(s, tangent, FOLD_TURN_RADII * r):
        return "the spine turns back on itself within a radius (a hook or a hairpin)"
    tight = float(np.mean(curvature(spine, t) * r > 1.0))
    if tight > FOLD_BEND_SHARE:
        return (f"the spine bends more tightly than the tube's radius along {tight:.0%} of it (the surface "
                "passes through itself)")
    # Only pairs of samples near each other in space can be close: a KD-tree finds them, where
    # the dense matrix of all pairs cost tens of milliseconds on every fit.
    from scipy.spatial import cKDTree

    i, j = cKDTree(pts).query_pairs(2 * FOLD_TOUCH * r.max(), output_type="ndarray").T
    along = np.abs(s[i] - s[j])
    if closed:
        along = np.minimum(along, length - along)
    apart = np.linalg.norm(pts[i] - pts[j], axis=1)
    wider = np.maximum(r[i], r[j])
    far_along = along > FOLD_ALONG_RADII * wider
    close = np.flatnonzero(far_along & (apart < FOLD_CLEARANCE * (r[i] + r[j])))
    if len(close):
        k = close[np.lexsort((j[close], i[close]))[0]]  # the first pair in order along the spine
        return (f"the spine passes within {apart[k] / wider[k]:.1f} radii of itself "
                f"{along[k] / wider[k]:.0f} radii further along it (a fold)")
    touch = np.flatnonzero(far_along & (apart < FOLD_TOUCH * (r[i] + r[j])))
    if len(touch) and _turns_back(s, tangent, FOLD_HAIRPIN_RADII * r):
        k = touch[np.argmin(apart[touch] / wider[touch])]
        return (f"the spine turns back on itself within {FOLD_HAIRPIN_RADII:g} radii and runs back "
                f"{apart[k] / wider[k]:.1f} radii from itself (a hairpin whose legs touch)")
    return ""


#: Spine samples per radius of :func:`inside_others` (at least INSIDE_MIN_SAMPLES a tube).
INSIDE_SAMPLES_PER_RADIUS, INSIDE_MIN_SAMPLES = 4, 50


def inside_others(tubes: list, junctions: list = ()) -> list:
    """Where each tube's spine runs inside another tube: two tubes of a scan never pass through each
    other but where they meet.

    Parameters
    ----------
    tubes : list of (BSpline, BSpline)
        Each tube's spine and radius function.
    junctions : list of list of (ndarray, float)
        For each tube, the junctions it meets as a point and a reach: within the reach the tubes meeting
        there are united and its spine is not checked.

    Returns
    -------
    list of (t, s, other)
        For each tube, samples of its spine by arc length: their parameters ``t``, their arc lengths ``s``,
        and ``other``, the index of a tube whose inside holds the sample (-1 where none does).
    """
    from scipy.spatial import cKDTree

    from .spine import curve_length, polyline_arclength, sample_arclength

    samples = []
    for spine, radius in tubes:
        mean_r = float(np.mean(radius(np.linspace(0.0, 1.0, 64))))
        n = max(INSIDE_MIN_SAMPLES, int(INSIDE_SAMPLES_PER_RADIUS * curve_length(spine) / mean_r))
        t, pts = sample_arclength(spine, n)
        samples.append((t, pts, radius(t)))
    pts = np.concatenate([p for _, p, _ in samples])
    r = np.concatenate([r for *_, r in samples])
    owner = np.repeat(np.arange(len(tubes)), [len(t) for t, *_ in samples])
    other = np.full(len(pts), -1)
    # Each sample's ball of its tube's radius holds the other tubes' samples inside that tube: balls of
    # their own radius, not of the widest, stay small in a scene of thin tubes beside wide ones.
    for b, near in enumerate(cKDTree(pts).query_ball_point(pts, r)):
        near = np.asarray(near, int)
        other[near[owner[near] != owner[b]]] = owner[b]
    out = []
    for k, (t, p, _) in enumerate(samples):
        mine = other[owner == k]
        for point, reach in junctions[k] if len(junctions) else ():
            mine[np.linalg.norm(p - point, axis=1) <= reach] = -1
        out.append((t, polyline_arclength(p), mine))
    return out


def longest_inside(s: np.ndarray, other: np.ndarray) -> tuple[float, int]:
    """The longest run of samples of one tube's spine inside another tube (:func:`inside_others`): its
    length along the spine (a sample's share of it each) and the other tube's index; ``(0.0, -1)`` where
    no sample is inside another."""
    edges = np.diff(np.concatenate([[0], other >= 0, [0]]).astype(int))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if not len(starts):
        return 0.0, -1
    k = int(np.argmax(stops - starts))
    run = other[starts[k]:stops[k]]
    return float(len(run) * s[-1] / max(len(s) - 1, 1)), int(np.bincount(run).argmax())


def _turns_back(s: np.ndarray, tangent: np.ndarray, reach: np.ndarray) -> bool:
    """Whether the unit ``tangent`` at arc lengths ``s`` turns by more than a right angle over ``reach``."""
    ahead = np.searchsorted(s, s + reach)
    inside = ahead < len(s)
    return bool((np.einsum("ij,ij->i", tangent[inside], tangent[ahead[inside]]) < 0).any())


def support_gap(t: np.ndarray, length: float, closed: bool) -> float:
    """The longest stretch of spine (in length units) between consecutive footpoints ``t``.

    The ends of an open spine are where its points end, so only gaps between points count.
    """
    s = np.sort(np.asarray(t, float)) * length
    if len(s) < 2:
        return float(length)
    gaps = np.diff(s)
    if closed:
        gaps = np.append(gaps, s[0] + length - s[-1])
    return float(gaps.max())


def branch_quality(*, rms: float, radius: float, noise: float, coverage: float, gap: float,
                   out_of_round: float, stretches: np.ndarray = np.empty(0),
                   inside: tuple = (0.0, -1)) -> tuple[str, list]:
    """Quality of one branch and its reasons.

    Parameters
    ----------
    rms : float
        Inlier RMS distance of its points from its surface.
    radius : float
        Its mean radius.
    noise : float
        The scan's own noise (same units).
    coverage : float
        Median degrees of the circumference its points cover (NaN when too few points tell).
    stretches : ndarray
        The degrees covered around each stretch of its spine (:func:`canalsurf.metrics.angular_coverage`).
    gap : float
        :func:`support_gap` of its points.
    out_of_round : float
        :func:`canalsurf.metrics.roundness` of its points.
    inside : (float, int)
        The length of its spine's longest stretch inside another branch's tube and that branch's id
        (:func:`longest_inside`).

    Returns
    -------
    quality : {"good", "check", "poor"}
    reasons : list of str
        One short phrase per reason, worst first.
    """
    found = []
    if rms > POOR_RMS_RADII * radius:
        found.append(("poor", f"points scatter {rms / radius:.0%} of the radius about the surface"))
    if noise > 0 and rms > CHECK_NOISE_RATIO * noise and rms > CHECK_RMS_RADII * radius:
        found.append(("check", f"misfit {rms / noise:.1f} times the scan's noise"))
    if out_of_round > CHECK_ROUND_RADII * radius:
        found.append(("check", f"out of round by {out_of_round / radius:.0%} of the radius"))
    if not np.isfinite(coverage):
        found.append(("check", "too few points to tell how much of the circumference was seen"))
    elif coverage < POOR_COVERAGE_DEGREES:
        found.append(("poor", f"seen from one side only ({coverage:.0f} degrees of the circumference)"))
    elif coverage < ONE_SIDED_DEGREES:
        found.append(("check", f"seen from one side ({coverage:.0f} degrees of the circumference)"))
    narrow = np.mean(stretches < POOR_COVERAGE_DEGREES) if len(stretches) else 0.0
    if coverage >= POOR_COVERAGE_DEGREES and narrow >= POOR_COVERAGE_SHARE:
        found.append(("poor", f"seen over less than {POOR_COVERAGE_DEGREES:.0f} degrees along {narrow:.0%} of it"))
    if gap > POOR_GAP_RADII * radius:
        found.append(("poor", f"a gap of {gap / radius:.1f} radii with no points along the spine"))
    elif gap > CHECK_GAP_RADII * radius:
        found.append(("check", f"a gap of {gap / radius:.1f} radii with no points along the spine"))
    length, other = inside
    if length > 0:
        found.append(("poor", f"its spine runs inside the tube of branch {other} along {length / radius:.1f} radii "
                              "(one of the two is misplaced there)"))
    return _summed(found)


def scan_quality(branches: list, no_tube_share: float, left_out=()) -> tuple[str, list]:
    """Quality of a whole reconstruction: the worst of its branches', and the scan's own reasons.

    Parameters
    ----------
    branches : list of (int, str, list)
        ``(branch id, quality, reasons)`` of each branch.
    no_tube_share : float
        Share of the scan's points on no tube.
    left_out : list of str
        Why each tube that was found but could not be modelled was left out: at least ``check``, the
        model is missing a tube.
    """
    found = [(q, f"branch {bid}: {why}") for bid, q, reasons in branches for why in reasons]
    found += [("check", f"a tube was left out: {why}") for why in left_out]
    if no_tube_share > CHECK_NO_TUBE_SHARE:
        found.append(("check", f"{no_tube_share:.0%} of the points lie on no tube"))
    return _summed(found)


def _summed(found: list) -> tuple[str, list]:
    found = sorted(found, key=lambda item: -LEVELS.index(item[0]))
    quality = found[0][0] if found else "good"
    return quality, [why for _, why in found]
