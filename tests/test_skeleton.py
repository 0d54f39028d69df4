"""Tests of canalsurf.skeleton: a thin cloud becomes branches between junctions that follow the true curves.

A single curve is one branch (ordered along the curve, open or closed); networks of lines (a T, a Y, a
four-way star) are branches meeting at one junction; separate lines are separate branches; short spurs
are pruned.  Every branch is checked against the true curve it came from with tolerances in voxels.
"""

from __future__ import annotations

import numpy as np
import pytest

from canalsurf.errors import ReconstructionError
from canalsurf.skeleton import (HAIRPIN_LEGS_RADII, MAX_JOIN_TURN, MIN_BRANCH_POINTS, SEPARATE_RADII, SPUR_RADII,
                                Skeleton, SkeletonBranch, skeletonize, with_ends_joined, with_ends_opened,
                                without_branches)

SEED = 3
N = 2000
#: Voxel size of every skeleton here.
SPACING = 0.05
#: Local tube radius of the thin points: 5 voxels, about what the pipeline has (voxel = 0.3 r).
RADIUS = 0.25
#: Thin points per unit length of the hand-made networks (about the density of the single curve).
DENSITY = 300
#: Noise of a thin set (as after MLS: well below the voxel size).
THIN_SIGMA = SPACING / 25


def _curve(t):
    """An open space curve of length about 6.8 with bends in two planes."""
    return np.column_stack([6 * t, 1.5 * np.sin(3 * t), 0.5 * np.cos(2 * t)])


def _radii(points, value=RADIUS):
    return np.full(len(points), value)


def _single(points, radius=RADIUS) -> SkeletonBranch:
    """The one branch of the skeleton of ``points`` (fails unless there is exactly one, with no junction)."""
    skel = skeletonize(points, _radii(points, radius), spacing=SPACING)
    assert len(skel.branches) == 1 and skel.junctions.shape == (0, 3)
    return skel.branches[0]


def _arc_positions(vertices, curve, curve_distance):
    """Arc length of the nearest true-curve point of each vertex (oriented to increase), and distances."""
    dist, s = curve_distance(vertices, curve)
    if s[-1] < s[0]:
        s = s[::-1]
    return s, dist


def _assert_follows(s, back=SPACING / 2, displacement=2):
    """Vertices advance along the curve: where a cross-section splits into two voxels side by side the
    path may visit them in either order, so allow back-steps of up to half a voxel and let no vertex sit
    more than ``displacement`` places from its rank along the curve."""
    assert np.diff(s).min() >= -back
    rank = np.argsort(np.argsort(s, kind="stable"), kind="stable")
    assert np.abs(rank - np.arange(len(s))).max() <= displacement


def _shuffled_curve(seed, sigma, n=N):
    rng = np.random.default_rng(seed)
    points = _curve(rng.uniform(0.0, 1.0, n)) + rng.normal(scale=sigma, size=(n, 3))
    return points[rng.permutation(n)], rng


def _segment(rng, a, b, sigma=THIN_SIGMA, density=DENSITY):
    """Thin points scattered uniformly along the segment from ``a`` to ``b``, with Gaussian noise."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = int(round(density * np.linalg.norm(b - a)))
    t = rng.uniform(0.0, 1.0, n)
    return a + t[:, None] * (b - a) + rng.normal(scale=sigma, size=(n, 3))


def _segment_distance(points, a, b):
    """Brute-force distance of each point to the segment from ``a`` to ``b``, and the position along it."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = b - a
    t = np.clip((points - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * d), axis=1), t * np.linalg.norm(d)


def _star(rng, centre, tips, sigma=THIN_SIGMA):
    """Thin points along segments from ``centre`` to each tip, shuffled."""
    points = np.vstack([_segment(rng, centre, tip, sigma) for tip in tips])
    return points[rng.permutation(len(points))]


def _assert_star(skel: Skeleton, centre, tips):
    """The skeleton is one junction at ``centre`` and one branch per arm to each tip.

    Each branch: every vertex within a voxel of its arm (the brute-force distance to the segment),
    advancing along it, its free end within two voxels of the tip and open (``None``), its other end
    listing junction 0 and lying within two voxels of the true meeting point; the arms are matched to
    the branches one to one.
    """
    centre = np.asarray(centre, float)
    assert len(skel.branches) == len(tips)
    assert skel.junctions.shape == (1, 3)
    assert np.linalg.norm(skel.junctions[0] - centre) <= 2 * SPACING
    matched = set()
    for branch in skel.branches:
        assert branch.closed is False
        assert sorted(branch.ends, key=lambda e: e is None) == [0, None]
        inner = 0 if branch.ends[0] == 0 else -1
        free = -1 - inner
        arm = int(np.argmin([np.linalg.norm(branch.points[free] - tip) for tip in tips]))
        matched.add(arm)
        dist, along = _segment_distance(branch.points, centre, tips[arm])
        assert dist.max() <= SPACING
        if inner == -1:
            along = along[::-1]
        _assert_follows(along)
        assert np.linalg.norm(branch.points[free] - tips[arm]) <= 2 * SPACING
        assert np.linalg.norm(branch.points[inner] - centre) <= 2 * SPACING
    assert matched == set(range(len(tips)))


# --------------------------------------------------------------------------------------------------
# a single curve: one branch


@pytest.mark.parametrize("seed", [SEED, SEED + 1, SEED + 2])
def test_thin_shuffled_curve_is_ordered_end_to_end(seed, curve_distance, dense_curve):
    """A thin set (noise well below the voxel spacing, as after MLS) is one open branch, ordered exactly."""
    points, _ = _shuffled_curve(seed, sigma=THIN_SIGMA)
    branch = _single(points)
    assert branch.closed is False and branch.ends == (None, None)
    s, dist = _arc_positions(branch.points, _curve, curve_distance)
    _assert_follows(s)
    assert np.mean(np.diff(s) > 0) >= 0.95  # nearly every step goes forward
    length = dense_curve(_curve)[2][-1]
    assert s[0] <= 2 * SPACING and s[-1] >= length - 2 * SPACING  # runs from end to end
    assert dist.max() <= SPACING
    # No thin point is lost: the vertex weights are the points they stand for.
    assert branch.weights.sum() == N
    assert branch.weights.min() >= 1
    steps = np.linalg.norm(np.diff(branch.points, axis=0), axis=1)
    assert steps.max() <= 3 * SPACING  # no jumps
    assert branch.length == pytest.approx(steps.sum())
    # The radius of a vertex is the mean radius of the points it stands for.
    np.testing.assert_allclose(branch.radius, RADIUS, rtol=1e-12)


def test_vertex_radius_is_the_weighted_mean_of_its_points():
    """``radius`` is the mean of the thin points' radii each vertex stands for: on a curve whose radius
    grows linearly along x, each vertex's radius is the radius at its own position to within a voxel's
    worth of the slope, and the weighted mean over the branch is the mean over all points."""
    points, _ = _shuffled_curve(SEED, sigma=THIN_SIGMA)
    r = 0.2 + 0.01 * points[:, 0]  # 0.2 ... 0.26 along the curve
    skel = skeletonize(points, r, spacing=SPACING)
    (branch,) = skel.branches
    np.testing.assert_allclose(branch.radius, 0.2 + 0.01 * branch.points[:, 0], atol=0.01 * 2 * SPACING)
    assert np.average(branch.radius, weights=branch.weights) == pytest.approx(r.mean(), rel=1e-12)


@pytest.mark.parametrize("strays", [False, True])
def test_link_is_the_sampling_step(strays):
    """``Skeleton.link`` is documented as the median link of the spanning forest, its sampling step.  On
    a thin curve the forest's links are the steps between neighbouring voxels, so it must equal the
    median polyline step.  Strays (5 % of the points, but a third of the voxels) add long links to the
    tree and may raise the median somewhat, not double it."""
    points, rng = _shuffled_curve(SEED, sigma=THIN_SIGMA)
    if strays:
        points = np.vstack([points, rng.uniform(-5.0, 10.0, size=(N // 20, 3))])
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    steps = np.linalg.norm(np.diff(skel.branches[0].points, axis=0), axis=1)
    assert skel.link == pytest.approx(np.median(steps), rel=0.5 if strays else 0.1)


def test_thicker_cloud_is_ordered_up_to_a_voxel(curve_distance):
    """Noise of a fifth of the spacing: voxels lie side by side across the curve and the path may step
    back, but never by more than one voxel; the side steps are not taken for branches."""
    points, _ = _shuffled_curve(SEED, sigma=SPACING / 5)
    branch = _single(points)
    assert branch.closed is False
    s, dist = _arc_positions(branch.points, _curve, curve_distance)
    _assert_follows(s, back=SPACING, displacement=4)
    assert s[-1] - s[0] >= 6.0
    assert dist.max() <= 2 * SPACING
    assert branch.weights.sum() == N


def test_noisy_circle_is_closed():
    rng = np.random.default_rng(SEED)
    a = rng.uniform(0.0, 2 * np.pi, N)
    points = np.column_stack([3 * np.cos(a), 3 * np.sin(a), np.zeros(N)]) + rng.normal(scale=0.002,
                                                                                      size=(N, 3))
    branch = _single(points)
    assert branch.closed is True
    assert branch.ends == (None, None)
    angle = np.unwrap(np.arctan2(branch.points[:, 1], branch.points[:, 0]))
    step = np.diff(angle)
    assert np.all(step > 0) or np.all(step < 0)
    assert np.ptp(angle) >= 2 * np.pi - 4 * SPACING / 3  # all the way round but the closing link
    assert np.abs(np.linalg.norm(branch.points[:, :2], axis=1) - 3).max() <= SPACING
    assert branch.weights.sum() == N


def test_open_arc_is_not_closed():
    """300 degrees of a circle: the ends are 3 apart, far more than a link."""
    rng = np.random.default_rng(SEED)
    a = rng.uniform(0.0, np.radians(300), N)
    points = np.column_stack([3 * np.cos(a), 3 * np.sin(a), np.zeros(N)])
    branch = _single(points)
    assert branch.closed is False
    angle = np.unwrap(np.arctan2(branch.points[:, 1], branch.points[:, 0]))
    assert np.ptp(angle) >= np.radians(300) - 4 * SPACING / 3


def test_stray_points_are_excluded(curve_distance):
    """5 % of the points scattered far off the curve: the branch follows the curve, and the strays are
    left out -- of the vertices and of the weights, which count the curve's points only."""
    points, rng = _shuffled_curve(SEED, sigma=THIN_SIGMA)
    m = N // 20
    strays = rng.uniform(-5.0, 10.0, size=(m, 3)) + [0.0, 0.0, 5.0]
    mixed = np.vstack([points, strays])[rng.permutation(N + m)]
    branch = _single(mixed)
    assert branch.closed is False
    s, dist = _arc_positions(branch.points, _curve, curve_distance)
    _assert_follows(s)
    assert dist.max() <= SPACING  # no vertex on a stray
    assert s[-1] - s[0] >= 6.5
    # Only strays that happen to fall within a voxel or so of the curve can join it.
    near = curve_distance(strays, _curve)[0] <= 2 * SPACING
    assert N <= branch.weights.sum() <= N + near.sum()


def test_same_input_same_output():
    points, _ = _shuffled_curve(SEED, sigma=0.005)
    a = skeletonize(points, _radii(points), spacing=SPACING)
    b = skeletonize(points.copy(), _radii(points), spacing=SPACING)
    assert len(a.branches) == len(b.branches) == 1
    np.testing.assert_array_equal(a.branches[0].points, b.branches[0].points)
    np.testing.assert_array_equal(a.branches[0].weights, b.branches[0].weights)
    np.testing.assert_array_equal(a.branches[0].radius, b.branches[0].radius)
    assert a.link == b.link


def test_input_is_not_changed():
    points, _ = _shuffled_curve(SEED, sigma=THIN_SIGMA)
    radius = _radii(points)
    before = points.copy(), radius.copy()
    skeletonize(points, radius, spacing=SPACING)
    np.testing.assert_array_equal(points, before[0])
    np.testing.assert_array_equal(radius, before[1])


def test_a_blob_is_not_a_curve():
    rng = np.random.default_rng(SEED)
    blob = rng.normal(scale=0.01, size=(200, 3))
    with pytest.raises(ReconstructionError, match=r"^the shrunk cloud collapsed to a point, not a curve — "
                                                  r"the input is not a tube$"):
        skeletonize(blob, _radii(blob), spacing=1.0)


def test_only_strays_is_not_a_curve():
    """Points scattered so thinly that no voxel has a neighbour within the cut: no tree is a tube."""
    rng = np.random.default_rng(SEED)
    scattered = rng.uniform(0.0, 100.0, size=(15, 3))
    with pytest.raises(ReconstructionError, match=r"^the thin point set has no long curve in it — "
                                                  r"the input is not a tube$"):
        skeletonize(scattered, _radii(scattered), spacing=SPACING)


# --------------------------------------------------------------------------------------------------
# networks: junctions, separate tubes, spurs


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_t_is_three_branches_at_one_junction(seed):
    """A line and a perpendicular line from its middle: three branches, each from the junction (within
    two voxels of the meeting point) to its own end, and every thin point weighs on some branch."""
    rng = np.random.default_rng(seed)
    tips = [np.array([-3.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0]), np.array([0.0, 3.0, 0.0])]
    points = np.vstack([_segment(rng, tips[0], tips[1]), _segment(rng, [0.0, 0.0, 0.0], tips[2])])
    points = points[rng.permutation(len(points))]
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    _assert_star(skel, [0.0, 0.0, 0.0], tips)
    assert sum(b.weights.sum() for b in skel.branches) == len(points)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_y_is_three_branches_at_one_junction(seed):
    """Three arms 120 degrees apart, tilted out of the coordinate planes and moved off the origin."""
    rng = np.random.default_rng(seed)
    centre = np.array([1.0, -2.0, 0.5])
    u, v = np.array([1.0, 2.0, 2.0]) / 3, np.array([2.0, 1.0, -2.0]) / 3  # orthonormal
    tips = [centre + 2.5 * (np.cos(a) * u + np.sin(a) * v) for a in np.radians([90.0, 210.0, 330.0])]
    points = _star(rng, centre, tips)
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    _assert_star(skel, centre, tips)
    assert sum(b.weights.sum() for b in skel.branches) == len(points)


def test_four_way_star_is_four_branches_at_one_junction():
    rng = np.random.default_rng(SEED)
    tips = [2.5 * np.array([np.cos(a), np.sin(a), 0.3 * np.sin(2 * a)]) for a in np.radians([0, 90, 180, 270])]
    points = _star(rng, np.zeros(3), tips)
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    _assert_star(skel, np.zeros(3), tips)


def test_separate_parallel_lines_are_separate_branches():
    """Two parallel lines 0.2 apart with radius 0.08: farther than ``SEPARATE_RADII`` times the sum of
    the radii (0.144), yet within the cut for stray links (6 voxels = 0.3), so only the radius rule
    separates them: two open branches, no junction, each along its own line."""
    rng = np.random.default_rng(SEED)
    radius, gap = 0.08, 0.2
    assert SEPARATE_RADII * 2 * radius < gap < 6 * SPACING
    lines = [([0.0, 0.0, 0.0], [3.0, 0.0, 0.0]), ([0.0, gap, 0.0], [3.0, gap, 0.0])]
    points = np.vstack([_segment(rng, a, b) for a, b in lines])
    skel = skeletonize(points[rng.permutation(len(points))], _radii(points, radius), spacing=SPACING)
    assert len(skel.branches) == 2
    assert skel.junctions.shape == (0, 3)
    on = []
    for branch in skel.branches:
        assert branch.ends == (None, None) and branch.closed is False
        dist = np.array([_segment_distance(branch.points, a, b)[0].max() for a, b in lines])
        assert dist.min() <= SPACING
        on.append(int(np.argmin(dist)))
        a, b = lines[on[-1]]
        ends = sorted([branch.points[0], branch.points[-1]], key=lambda p: p[0])
        assert np.linalg.norm(ends[0] - a) <= 2 * SPACING and np.linalg.norm(ends[1] - b) <= 2 * SPACING
    assert sorted(on) == [0, 1]


def test_touching_parallel_lines_are_one_network():
    """The same two lines with radius 0.25: tubes whose spines are closer than the sum of their radii
    overlap, so the lines are not separated: they form one connected network, with junctions."""
    rng = np.random.default_rng(SEED)
    gap = 0.2
    assert gap < SEPARATE_RADII * 2 * RADIUS
    points = np.vstack([_segment(rng, [0.0, 0.0, 0.0], [3.0, 0.0, 0.0]),
                        _segment(rng, [0.0, gap, 0.0], [3.0, gap, 0.0])])
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    assert len(skel.junctions) >= 1
    # every branch is joined to the rest through junctions
    assert all(any(e is not None for e in b.ends) for b in skel.branches)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_two_lines_ending_side_by_side_and_linked_by_strays_are_two_branches(seed):
    """Two parallel lines of radius 0.1, 2.5 radii apart, whose ends a trail of thin points links (as
    the shrunk ends of two rack pipes can): not one branch turning back through the trail, but two
    open branches, each within a voxel of its own line for its whole length but the trail's end."""
    rng = np.random.default_rng(seed)
    radius, gap = 0.1, 0.25
    assert gap < HAIRPIN_LEGS_RADII * radius
    lines = [([0.0, 0.0, 0.0], [3.0, 0.0, 0.0]), ([0.0, gap, 0.0], [3.0, gap, 0.0])]
    points = np.vstack([_segment(rng, a, b) for a, b in lines] + [_segment(rng, lines[0][1], lines[1][1])])
    skel = skeletonize(points[rng.permutation(len(points))], _radii(points, radius), spacing=SPACING)
    assert len(skel.branches) == 2 and skel.junctions.shape == (0, 3)
    on = []
    for branch in skel.branches:
        assert branch.ends == (None, None)
        dist = np.array([_segment_distance(branch.points, a, b)[0].max() for a, b in lines])
        assert dist.min() <= SPACING
        on.append(int(np.argmin(dist)))
        assert np.ptp(branch.points[:, 0]) >= 3.0 - 3 * radius
    assert sorted(on) == [0, 1]


def test_a_return_bend_is_one_branch(curve_distance):
    """A 180-degree return bend of bend radius 2 r (legs 4 r apart: a short-radius fitting) turns back
    by more than MAX_JOIN_TURN between its legs, but they lie farther apart than two tubes that end
    side by side: it stays one branch, end to end."""
    rng = np.random.default_rng(SEED)
    radius = 0.1
    bend = 2 * radius

    def u_bend(t):  # legs of 2 along x joined by a half circle, by arc length
        total = 4.0 + np.pi * bend
        s = np.asarray(t) * total
        leg, arc = np.minimum(s, 2.0), np.clip(s - 2.0, 0.0, np.pi * bend) / bend
        back = np.clip(s - 2.0 - np.pi * bend, 0.0, 2.0)
        return np.column_stack([leg + bend * np.sin(arc) - back, bend - bend * np.cos(arc), np.zeros_like(s)])

    points = u_bend(rng.uniform(0.0, 1.0, 2000)) + rng.normal(scale=THIN_SIGMA, size=(2000, 3))
    branch = _single(points, radius)
    s, dist = _arc_positions(branch.points, u_bend, curve_distance)
    assert dist.max() <= SPACING
    assert s[0] <= 2 * SPACING and s[-1] >= 4.0 + np.pi * bend - 2 * SPACING
    assert MAX_JOIN_TURN < 180.0 and 2 * bend > HAIRPIN_LEGS_RADII * radius


@pytest.mark.parametrize(("radius", "pieces"), [(RADIUS, 1), (0.08, 2)])
def test_a_gap_of_a_radius_is_no_break(radius, pieces):
    """A line with a gap of 0.2: about one radius of a 0.25 tube (a sparse stretch of one tube) keeps
    one branch across it; 2.5 radii of a 0.08 tube (two tubes end to end) cuts it in two.  Both gaps are
    within the cut for stray links, so the radius decides."""
    rng = np.random.default_rng(SEED)
    gap = 0.2
    points = np.vstack([_segment(rng, [0.0, 0.0, 0.0], [2.0, 0.0, 0.0]),
                        _segment(rng, [2.0 + gap, 0.0, 0.0], [4.0 + gap, 0.0, 0.0])])
    skel = skeletonize(points, _radii(points, radius), spacing=SPACING)
    assert len(skel.branches) == pieces
    assert skel.junctions.shape == (0, 3)
    steps = [np.linalg.norm(np.diff(b.points, axis=0), axis=1) for b in skel.branches]
    if pieces == 1:
        assert max(s.max() for s in steps) >= gap  # the gap is bridged by one link
    else:
        assert max(s.max() for s in steps) <= 3 * SPACING
    assert sum(b.weights.sum() for b in skel.branches) == len(points)


def test_each_scale_is_averaged_and_cut_on_its_own_grid():
    """A thin set gathered at two scales (a scene's wide and thin tubes): the wide tube's gap of 0.8, within
    the stray-link cut of its own voxels (0.2) and less than a radius, does not break it, though the
    thin tube's voxels (0.02) would cut any link of more than 0.12."""
    rng = np.random.default_rng(SEED)
    wide = np.vstack([_segment(rng, [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], density=50),
                      _segment(rng, [5.8, 0.0, 0.0], [10.0, 0.0, 0.0], density=50)])
    thin = _segment(rng, [0.0, 5.0, 0.0], [3.0, 5.0, 0.0], density=1000)
    points = np.vstack([wide, thin])
    radius = np.r_[np.full(len(wide), 1.0), np.full(len(thin), 0.1)]
    spacing = np.r_[np.full(len(wide), 0.2), np.full(len(thin), 0.02)]
    skel = skeletonize(points, radius, spacing=spacing)
    assert len(skel.branches) == 2
    lengths = sorted(b.length for b in skel.branches)
    assert lengths[0] == pytest.approx(3.0, abs=0.1) and lengths[1] == pytest.approx(10.0, abs=0.3)
    # One grid for all, the thin tube's: the wide one falls apart at its gap.
    assert len(skeletonize(points, radius, spacing=0.02).branches) > 2


@pytest.mark.parametrize(("length", "n_points"), [
    (0.8 * SPUR_RADII * RADIUS, None),           # short: pruned however many points it has
    (1.2 * SPUR_RADII * RADIUS, MIN_BRANCH_POINTS // 2),  # long enough, but too few points
])
def test_spurs_are_pruned(length, n_points, curve_distance):
    """A stub sticking out sideways from the middle of a line, shorter than ``SPUR_RADII`` radii (with
    more than ``MIN_BRANCH_POINTS`` points), or longer but standing for too few points: one branch along
    the line, no junction, and the stub's points weigh on it."""
    rng = np.random.default_rng(SEED)
    line = _segment(rng, [-3.0, 0.0, 0.0], [3.0, 0.0, 0.0])
    stub = _segment(rng, [0.0, 0.0, 0.0], [0.0, length, 0.0])
    if n_points is not None:
        stub = stub[:n_points]
    assert n_points is not None or len(stub) > MIN_BRANCH_POINTS
    points = np.vstack([line, stub])
    branch = _single(points[rng.permutation(len(points))])
    assert branch.ends == (None, None) and branch.closed is False
    dist, along = _segment_distance(branch.points, [-3.0, 0.0, 0.0], [3.0, 0.0, 0.0])
    assert dist.max() <= SPACING
    if along[-1] < along[0]:
        along = along[::-1]
    _assert_follows(along)
    assert along[0] <= 2 * SPACING and along[-1] >= 6.0 - 2 * SPACING
    assert branch.weights.sum() == len(points)


def test_a_side_line_longer_than_a_spur_is_kept():
    """The same stub twice ``SPUR_RADII`` radii long: a branch of its own at a junction on the line."""
    rng = np.random.default_rng(SEED)
    length = 2 * SPUR_RADII * RADIUS
    tips = [np.array([-3.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0]), np.array([0.0, length, 0.0])]
    points = np.vstack([_segment(rng, tips[0], tips[1]), _segment(rng, [0.0, 0.0, 0.0], tips[2])])
    skel = skeletonize(points[rng.permutation(len(points))], _radii(points), spacing=SPACING)
    _assert_star(skel, [0.0, 0.0, 0.0], tips)
    side = min(skel.branches, key=lambda b: b.length)
    assert side.length == pytest.approx(length, abs=2 * SPACING)


# --------------------------------------------------------------------------------------------------
# without_branches


def _t_skeleton(seed=SEED):
    rng = np.random.default_rng(seed)
    tips = [np.array([-3.0, 0.0, 0.0]), np.array([3.0, 0.0, 0.0]), np.array([0.0, 3.0, 0.0])]
    points = np.vstack([_segment(rng, tips[0], tips[1]), _segment(rng, [0.0, 0.0, 0.0], tips[2])])
    points = points[rng.permutation(len(points))]
    return skeletonize(points, _radii(points), spacing=SPACING), len(points)


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_dropping_the_side_of_a_t_joins_the_halves(seed):
    """Without the side branch the junction has two ends left: the halves become one open branch from
    end to end along the line, no junction remains, no thin point of the halves is lost, and the new
    branch is no unchanged old one (origin ``None``)."""
    skel, _ = _t_skeleton(seed)
    side = [i for i, b in enumerate(skel.branches) if b.points[:, 1].max() > 1.0]
    assert len(side) == 1
    halves = [b for i, b in enumerate(skel.branches) if i != side[0]]
    out, origin = without_branches(skel, side)
    assert origin == [None]
    assert out.junctions.shape == (0, 3)
    assert out.link == skel.link
    (joined,) = out.branches
    assert joined.ends == (None, None) and joined.closed is False
    assert len(joined.points) == len(joined.weights) == len(joined.radius)
    dist, along = _segment_distance(joined.points, [-3.0, 0.0, 0.0], [3.0, 0.0, 0.0])
    assert dist.max() <= SPACING
    if along[-1] < along[0]:
        along = along[::-1]
    _assert_follows(along)
    assert along[0] <= 2 * SPACING and along[-1] >= 6.0 - 2 * SPACING
    assert joined.weights.sum() == sum(b.weights.sum() for b in halves)
    np.testing.assert_allclose(joined.radius, RADIUS, rtol=1e-12)
    assert np.linalg.norm(np.diff(joined.points, axis=0), axis=1).max() <= 3 * SPACING


def _arms(skel: Skeleton, tips) -> list:
    """Index of the tip each branch reaches (one to one), by its end nearest to a tip."""
    arm = [int(np.argmin([min(np.linalg.norm(b.points[[0, -1]] - t, axis=1)) for t in tips]))
           for b in skel.branches]
    assert sorted(arm) == list(range(len(tips)))
    return arm


def test_dropping_one_arm_of_a_star_keeps_the_junction():
    """A four-way star less one arm: the junction keeps the three other ends, and the three branches
    are the old ones unchanged, which ``origin`` names."""
    rng = np.random.default_rng(SEED)
    tips = [2.5 * np.array([np.cos(a), np.sin(a), 0.3 * np.sin(2 * a)]) for a in np.radians([0, 90, 180, 270])]
    points = _star(rng, np.zeros(3), tips)
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    arm = _arms(skel, tips)
    for drop in range(4):
        out, origin = without_branches(skel, [drop])
        assert origin == [i for i in range(4) if i != drop]
        np.testing.assert_array_equal(out.junctions, skel.junctions)
        _assert_star(out, np.zeros(3), [t for i, t in enumerate(tips) if i != arm[drop]])
        for new, old in zip(out.branches, origin):
            b = skel.branches[old]
            np.testing.assert_array_equal(new.points, b.points)
            np.testing.assert_array_equal(new.weights, b.weights)
            assert new.ends == b.ends


def test_dropping_two_arms_of_a_star_joins_the_rest():
    rng = np.random.default_rng(SEED)
    tips = [2.5 * np.array([np.cos(a), np.sin(a), 0.0]) for a in np.radians([0, 90, 180, 270])]
    points = _star(rng, np.zeros(3), tips)
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    branch_of = {a: i for i, a in enumerate(_arms(skel, tips))}
    out, origin = without_branches(skel, [branch_of[1], branch_of[3]])  # the y arms: the x line is left
    assert origin == [None] and out.junctions.shape == (0, 3)
    (line,) = out.branches
    assert line.ends == (None, None)
    assert _segment_distance(line.points, tips[2], tips[0])[0].max() <= SPACING
    ends = sorted(line.points[[0, -1]], key=lambda p: p[0])
    assert np.linalg.norm(ends[0] - tips[2]) <= 2 * SPACING and np.linalg.norm(ends[1] - tips[0]) <= 2 * SPACING
    assert line.weights.sum() == skel.branches[branch_of[0]].weights.sum() + skel.branches[branch_of[2]].weights.sum()


def test_dropping_every_branch_at_a_junction_but_one_opens_it():
    """A junction left with one end becomes an open end of that branch; one with none disappears."""
    rng = np.random.default_rng(SEED)
    tips = [2.5 * np.array([np.cos(a), np.sin(a), 0.0]) for a in np.radians([90, 210, 330])]
    points = _star(rng, np.zeros(3), tips)
    skel = skeletonize(points, _radii(points), spacing=SPACING)
    out, origin = without_branches(skel, [0, 1])
    assert origin == [None]
    assert out.branches[0].ends == (None, None) and out.junctions.shape == (0, 3)
    np.testing.assert_array_equal(out.branches[0].points, skel.branches[2].points)
    out, origin = without_branches(skel, [0, 1, 2])
    assert out.branches == [] and origin == [] and out.junctions.shape == (0, 3)


def test_without_no_branches_is_the_same_skeleton():
    skel, _ = _t_skeleton()
    out, origin = without_branches(skel, [])
    assert origin == [0, 1, 2]
    np.testing.assert_array_equal(out.junctions, skel.junctions)
    for new, old in zip(out.branches, skel.branches):
        np.testing.assert_array_equal(new.points, old.points)
        assert new.ends == old.ends


# --------------------------------------------------------------------------------------------------
# with_ends_joined


def _line_branch(x0: float, x1: float, ends=(None, None)) -> SkeletonBranch:
    x = np.arange(x0, x1 + 1e-9, 0.25) if x1 > x0 else np.arange(x0, x1 - 1e-9, -0.25)
    return SkeletonBranch(np.c_[x, 0 * x, 0 * x], np.ones(len(x)), np.full(len(x), RADIUS), ends)


@pytest.mark.parametrize(("b", "eb"), [((8.0, 20.0), 0), ((20.0, 8.0), 1), ((12.0, 20.0), 0)])
def test_two_pieces_of_one_line_are_joined_without_doubling_back(b, eb):
    """Two pieces of a line that overlap (8 to 10) or leave a gap (10 to 12), either way round, become
    one branch in the first's place: it runs from 0 to 20 straight on (its vertices behind the first's
    end left out), keeps the second's far junction, and the other branch stays unchanged."""
    other = _line_branch(0.0, 5.0, (None, 0))
    skel = Skeleton([other, _line_branch(0.0, 10.0), _line_branch(*b, (None, 0) if eb == 0 else (0, None))],
                    np.array([[20.0, 0.0, 0.0]]), 0.25)
    out, origin = with_ends_joined(skel, [((1, 1), (2, eb))])
    assert origin == [0, None]
    np.testing.assert_array_equal(out.branches[0].points, other.points)
    joined = out.branches[1]
    x = joined.points[:, 0]
    assert np.all(np.diff(x) > 0) and x[0] == 0.0 and x[-1] == 20.0
    assert joined.ends == (None, 0)
    assert len(joined.weights) == len(joined.radius) == len(x)
    np.testing.assert_array_equal(out.junctions, skel.junctions)


def test_a_piece_whose_thin_set_hooks_at_its_end_is_joined_with_the_end_given():
    """The first piece's last thin points hook down by 6 radii (as a scene's thin set can at an end
    next to a bridge): from its own end direction, the second piece 8 radii on lies behind it and is
    lost; along the direction given (a fitted spine's: along x) it is kept whole."""
    hook = _line_branch(0.0, 10.0)
    points = np.vstack([hook.points, [[10.1, 0.0, -0.5], [10.1, 0.0, -1.0], [10.1, 0.0, -1.5], [10.4, 0.0, -1.2]]])
    first = SkeletonBranch(points, np.ones(len(points)), np.full(len(points), RADIUS), (None, None))
    second = _line_branch(12.0, 20.0)
    skel = Skeleton([first, second], np.empty((0, 3)), 0.25)
    lost, _ = with_ends_joined(skel, [((0, 1), (1, 0))])
    assert lost.branches[0].points[:, 0].max() < 11.0
    given = {(0, 1): np.array([1.0, 0.0, 0.0])}
    kept, origin = with_ends_joined(skel, [((0, 1), (1, 0))], given)
    assert origin == [None]
    np.testing.assert_array_equal(kept.branches[0].points[-len(second.points):], second.points)


def test_only_open_ends_are_joined_and_each_branch_once():
    skel = Skeleton([_line_branch(0.0, 10.0, (None, 0)), _line_branch(10.0, 20.0), _line_branch(20.0, 30.0)],
                    np.array([[10.0, 0.0, 0.0]]), 0.25)
    with pytest.raises(ValueError, match="open ends"):
        with_ends_joined(skel, [((0, 1), (1, 0))])
    with pytest.raises(ValueError, match="only once"):
        with_ends_joined(skel, [((1, 1), (2, 0)), ((2, 1), (0, 0))])


# --------------------------------------------------------------------------------------------------
# broken tees


def _polyline(*corners, radius: float, ends=(None, None), step: float = 0.1) -> SkeletonBranch:
    pts = [np.asarray(corners[0], float)]
    for a, b in zip(corners[:-1], corners[1:]):
        a, b = np.asarray(a, float), np.asarray(b, float)
        n = max(1, int(round(np.linalg.norm(b - a) / step)))
        pts += [a + (b - a) * k / n for k in range(1, n + 1)]
    pts = np.array(pts)
    return SkeletonBranch(pts, np.ones(len(pts)), np.full(len(pts), radius), ends)


@pytest.mark.parametrize(("run_end", "mended"), [
    ((1.2, 0.0, 0.0), True),    # the run's far half stops 1.5 radii short of the corner, in line
    ((2.5, 0.0, 0.0), False),   # 3 radii short: not at the corner
    ((0.0, 0.0, 1.2), False),   # beside the corner, but not in line with either leg
])
def test_a_tee_whose_run_broke_off_at_the_junction_is_mended(run_end, mended):
    """The thin set of a tee broke between the junction and the run's far half: the side branch and the
    near half are one branch round a corner, the far half ends short of it.  Mended, the three meet at a
    junction at the corner; an end farther off, or out of line, leaves the skeleton as it was."""
    from canalsurf.skeleton import _broken_tees_mended

    corner = _polyline((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), (-8.0, 0.0, 0.0), radius=0.5)
    direction = np.asarray(run_end) / np.linalg.norm(run_end)
    run = _polyline(run_end, np.asarray(run_end) + 8.0 * direction, radius=0.8)
    out = _broken_tees_mended(Skeleton([corner, run], np.empty((0, 3)), 0.1))
    _assert_mended_at_origin(out, mended, corner, run)
    if mended:
        side = next(b for b in out.branches if b.points[:, 1].max() > 1.0)
        assert side.points[:, 0].min() > -0.05 and side.points[:, 1].min() == pytest.approx(0.0)


def test_a_tube_beside_a_corner_is_no_broken_tee():
    """An open end 1.3 beside the corner's leg, parallel to it -- the sum of the radii: a tube touching it
    side by side, as a hairpin's leg cut from the fit of two pipes -- is no broken-off half of a run."""
    from canalsurf.skeleton import _broken_tees_mended

    corner = _polyline((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), (-8.0, 0.0, 0.0), radius=0.5)
    beside = _polyline((0.6, 0.0, 1.3), (8.6, 0.0, 1.3), radius=0.8)
    _assert_mended_at_origin(_broken_tees_mended(Skeleton([corner, beside], np.empty((0, 3)), 0.1)), False,
                             corner, beside)


def _assert_mended_at_origin(out: Skeleton, mended: bool, *before: SkeletonBranch) -> None:
    """Three branches meet at a junction at the origin, no thin point lost; or the two are as they were."""
    if not mended:
        assert len(out.branches) == 2 and out.junctions.shape == (0, 3)
        return
    np.testing.assert_allclose(out.junctions, [[0.0, 0.0, 0.0]], atol=1e-9)
    assert sorted(map(str, (b.ends for b in out.branches))) == ["(0, None)", "(0, None)", "(None, 0)"]
    assert sum(b.weights.sum() for b in out.branches) == sum(b.weights.sum() for b in before)


def test_an_elbow_alone_is_no_broken_tee():
    from canalsurf.skeleton import _broken_tees_mended

    elbow = _polyline((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), (-8.0, 0.0, 0.0), radius=0.5)
    assert len(_broken_tees_mended(Skeleton([elbow], np.empty((0, 3)), 0.1)).branches) == 1


@pytest.mark.parametrize(("start", "direction", "mended"), [
    ((0.0, 1.2, 0.0), (0.0, 1.0, 0.0), True),    # stops 0.4 off the run's surface, square to it
    ((0.0, 3.0, 0.0), (0.0, 1.0, 0.0), False),   # 2.2 off: farther than SIDE_GAP_RADII of its radius
    ((0.0, 1.2, 0.0), (0.0, 1.0, 2.0), False),   # points past the run's axis
    ((0.0, 0.6, 0.0), (-2.0, 1.0, 0.0), False),   # aims at the axis, but leaves the run at 27 degrees
])
def test_a_side_branch_that_stops_short_of_the_run_meets_it(start, direction, mended):
    """A tee's side branch whose thin set broke short of the junction: its open end lies a little off the
    run's tube and points into the run's axis. Mended, the run is split at the vertex it points to and
    the three meet there; an end farther off, or aimed past the axis or along the run, is left open."""
    from canalsurf.skeleton import _broken_tees_mended

    run = _polyline((-8.0, 0.0, 0.0), (8.0, 0.0, 0.0), radius=0.8)
    direction = np.asarray(direction) / np.linalg.norm(direction)
    side = _polyline(start, np.asarray(start) + 5.0 * direction, radius=0.5)
    _assert_mended_at_origin(_broken_tees_mended(Skeleton([run, side], np.empty((0, 3)), 0.1)), mended, run, side)


def test_tees_mended_after_a_drop_name_the_branches_left_unchanged():
    """The thin set split a tee's junction in two: the run's halves meet at the origin, the side branch
    1.2 above it, and a piece that is no tube links the two (with a spur at the upper one).  Dropped,
    the run's halves join and the side is left open inside the run; mended, the three meet at the
    origin again.  ``origin`` names the one branch left unchanged, a pipe apart from the tee."""
    from canalsurf.skeleton import with_tees_mended

    apart = _polyline((-8.0, 0.0, 6.0), (8.0, 0.0, 6.0), radius=0.5)
    left = _polyline((-8.0, 0.0, 0.0), (0.0, 0.0, 0.0), radius=0.8, ends=(None, 0))
    right = _polyline((0.0, 0.0, 0.0), (8.0, 0.0, 0.0), radius=0.8, ends=(0, None))
    link = _polyline((0.0, 0.0, 0.0), (0.0, 1.2, 0.0), radius=0.8, ends=(0, 1))
    spur = _polyline((0.0, 1.2, 0.0), (0.6, 1.4, 0.0), radius=0.5, ends=(1, None))
    side = _polyline((0.0, 1.2, 0.0), (0.0, 6.2, 0.0), radius=0.5, ends=(1, None))
    skel = Skeleton([apart, left, right, link, spur, side], np.array([[0.0, 0.0, 0.0], [0.0, 1.2, 0.0]]), 0.1)
    dropped, origin = without_branches(skel, [3, 4])
    assert sorted(origin, key=str) == [0, None, None] and dropped.junctions.shape == (0, 3)  # run joined, side open
    out, unchanged = with_tees_mended(dropped)
    kept = [n for n, u in enumerate(unchanged) if u is not None]
    assert len(out.branches) == 4 and [origin[unchanged[n]] for n in kept] == [0]
    assert out.branches[kept[0]] is dropped.branches[unchanged[kept[0]]]
    tee = [b for n, b in enumerate(out.branches) if n not in kept]
    _assert_mended_at_origin(Skeleton(tee, out.junctions, 0.1), True, left, right, side)
    _, unchanged = with_tees_mended(out)
    assert unchanged == [0, 1, 2, 3]


# --------------------------------------------------------------------------------------------------
# false junctions between tubes side by side


def _rack_junction(side_corners, side_radius=0.5):
    """A run of radius 0.8 along x through a junction at the origin, and a third branch from the
    junction along ``side_corners``."""
    left = _polyline((-10.0, 0.0, 0.0), (0.0, 0.0, 0.0), radius=0.8, ends=(None, 0))
    right = _polyline((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), radius=0.8, ends=(0, None))
    side = _polyline((0.0, 0.0, 0.0), *side_corners, radius=side_radius, ends=(0, None))
    return Skeleton([left, right, side], np.zeros((1, 3)), 0.1)


@pytest.mark.parametrize(("side", "parted"), [
    # a rack neighbour 2 away, linked to the run by a short bridge: the junction is false
    (((0.5, 2.0, 0.0), (10.0, 2.0, 0.0)), True),
    # a tee's side branch, square to the run
    (((0.0, 10.0, 0.0),), False),
    # a lateral leaving the run at 10 degrees, overlapping it near the junction
    (((10.0, 10.0 * np.tan(np.radians(10.0)), 0.0),), False),
    # a neighbour that touches the run (1.1 apart, the radii sum to 1.3): one tube's surface meets the other's
    (((0.5, 1.1, 0.0), (10.0, 1.1, 0.0)), False)])
def test_a_neighbour_linked_beside_a_run_is_no_branch_of_it(side, parted):
    """Parted, the run is one open branch through the false junction and the neighbour an open branch of
    its own; every thin point is kept.  A branch that leaves the run at an angle, or that touches it,
    keeps the junction."""
    from canalsurf.skeleton import _bridges_parted

    skel = _rack_junction(side)
    out = _bridges_parted(skel)
    if not parted:
        assert out is skel
        return
    assert out.junctions.shape == (0, 3) and len(out.branches) == 2
    assert all(b.ends == (None, None) for b in out.branches)
    run = next(b for b in out.branches if np.abs(b.points[:, 1]).max() < 0.1)
    assert np.ptp(run.points[:, 0]) == pytest.approx(20.0)
    # the link to the junction is cut off the neighbour: it keeps within its radius of its line
    neighbour = next(b for b in out.branches if b is not run)
    assert np.abs(neighbour.points[:, 1] - 2.0).max() <= 0.5
    assert sum(b.weights.sum() for b in out.branches) == pytest.approx(sum(b.weights.sum() for b in skel.branches))


def test_two_runs_side_by_side_at_one_false_junction_are_two_branches():
    """Two rack neighbours 2 apart whose four halves meet at one junction: two open branches, one along each."""
    from canalsurf.skeleton import _bridges_parted

    halves = [_polyline((-10.0, 0.0, 0.0), (0.0, 0.0, 0.0), radius=0.8, ends=(None, 0)),
              _polyline((0.0, 0.0, 0.0), (10.0, 0.0, 0.0), radius=0.8, ends=(0, None)),
              _polyline((-10.0, 2.0, 0.0), (-0.5, 2.0, 0.0), (0.0, 0.0, 0.0), radius=0.5, ends=(None, 0)),
              _polyline((0.0, 0.0, 0.0), (0.5, 2.0, 0.0), (10.0, 2.0, 0.0), radius=0.5, ends=(0, None))]
    out = _bridges_parted(Skeleton(halves, np.zeros((1, 3)), 0.1))
    assert out.junctions.shape == (0, 3) and len(out.branches) == 2
    assert sorted(round(float(np.median(b.points[:, 1])), 6) for b in out.branches) == [0.0, 2.0]
    assert all(np.ptp(b.points[:, 1]) <= np.median(b.radius) for b in out.branches)
    assert all(np.ptp(b.points[:, 0]) == pytest.approx(20.0) for b in out.branches)


def test_a_junction_is_moved_to_where_its_branches_lines_meet():
    """A tee whose thin sets merged off its axes: the graph put the junction 0.3 from where the three
    lines meet, and each branch bends to it over its last 0.3, where its r_i took in the other tubes'
    points (1.5 against 0.5).  The junction moves to the lines' meeting point, each branch runs straight
    from it with the radius of its first vertex past the merging, and no vertex or thin point is lost."""
    from canalsurf.skeleton import _junctions_placed

    graph = (0.2, 0.25, 0.0)
    branches = [_polyline((-6.0, 0.0, 0.0), (-0.3, 0.0, 0.0), graph, radius=0.5, ends=(None, 0)),
                _polyline(graph, (0.3, 0.0, 0.0), (6.0, 0.0, 0.0), radius=0.5, ends=(0, None)),
                _polyline(graph, (0.0, 0.3, 0.0), (0.0, 6.0, 0.0), radius=0.5, ends=(0, None))]
    for b in branches:
        b.radius[np.linalg.norm(b.points - graph, axis=1) < 0.5] = 1.5
    out = _junctions_placed(Skeleton(branches, np.array([graph]), 0.1))
    point = out.junctions[0]
    assert np.linalg.norm(point) <= 0.01
    for old, new, axis in zip(branches, out.branches, (0, 0, 1)):
        assert new.ends == old.ends and len(new.points) == len(old.points)
        np.testing.assert_array_equal(new.weights, old.weights)
        np.testing.assert_array_equal(new.radius, 0.5)
        end = new.points[-1] if old.ends[1] == 0 else new.points[0]
        np.testing.assert_array_equal(end, point)
        off_axis = np.delete(new.points, axis, axis=1)
        assert np.abs(off_axis).max() <= 0.01
        assert np.linalg.norm(np.diff(new.points, axis=0), axis=1).max() <= 0.2


def test_a_link_between_two_pipes_side_by_side_moves_no_junction_along_them():
    """A pipe (radius 0.5) whose thin set linked, bending, to a pipe beside it: the link, 1.7 long, is
    shorter than the lines' stretch (up to 3 of its radii, 0.6), so it gives no line.  The junction
    stays at its place along the pipe (only moved onto the pipe's axis), and the link is left as it
    was; its line, where it runs past 1.5 radii, meets the pipe's axis 1.0 along it."""
    from canalsurf.skeleton import _junctions_placed

    graph = (0.0, 0.1, 0.0)
    branches = [_polyline((-6.0, 0.0, 0.0), (-0.3, 0.0, 0.0), graph, radius=0.5, ends=(None, 0)),
                _polyline(graph, (0.3, 0.0, 0.0), (6.0, 0.0, 0.0), radius=0.5, ends=(0, None)),
                _polyline(graph, (0.2, 0.6, 0.0), (1.2, 1.1, 0.0), radius=0.6, ends=(0, None))]
    out = _junctions_placed(Skeleton(branches, np.array([graph]), 0.1))
    np.testing.assert_allclose(out.junctions[0], (0.0, 0.0, 0.0), atol=0.01)
    np.testing.assert_array_equal(out.branches[2].points, branches[2].points)
    np.testing.assert_array_equal(out.branches[2].radius, branches[2].radius)


@pytest.mark.parametrize(("meets", "placed"), [
    (0.8, (0.8, 0.0, 0.0)),   # within the run's radius (1) of the graph's junction along the run
    (1.5, (0.0, 0.0, 0.0)),   # farther: the side line alone cannot move it along the run
])
def test_a_side_line_alone_moves_a_junction_along_its_run_only_within_the_largest_radius(meets, placed):
    """A tee whose side branch (radius 0.4) leaves its run (radius 1) at 50 degrees, the graph's junction
    0.2 off the run's axis: the run's two lines are parallel, so the side line alone fixes where along the
    run the lines meet.  Where it meets the run's axis farther along than the run's radius, that line is
    left out (a thin branch's thin set lies off its axis near a thick one), and the junction is only
    moved onto the run's axis."""
    from canalsurf.skeleton import _junctions_placed

    graph = np.array((0.0, 0.2, 0.0))
    d = np.array((np.cos(np.radians(50.0)), np.sin(np.radians(50.0)), 0.0))
    on = np.array((meets, 0.0, 0.0))
    foot = on + ((graph - on) @ d) * d
    branches = [_polyline((-6.0, 0.0, 0.0), (-0.3, 0.0, 0.0), graph, radius=1.0, ends=(None, 0)),
                _polyline(graph, (0.3, 0.0, 0.0), (6.0, 0.0, 0.0), radius=1.0, ends=(0, None)),
                _polyline(graph, foot, foot + 7.0 * d, radius=0.4, ends=(0, None))]
    out = _junctions_placed(Skeleton(branches, np.array([graph]), 0.1))
    # within the light pull to the graph's junction
    np.testing.assert_allclose(out.junctions[0], placed, atol=0.005)
    assert all(np.array_equal(b.points[-1 if b.ends[1] == 0 else 0], out.junctions[0]) for b in out.branches)


def test_with_ends_opened_opens_a_junction_left_with_one_end_and_drops_one_left_with_none():
    """Of a star of three branches at junction 0 and a pair at junction 1, two ends of the star are opened:
    its third end opens too and junction 0 goes; junction 1 is renumbered 0, and no branch moves.  With one
    end of the pair opened too, no junction is left."""
    def branch(a, b, ends):
        pts = np.linspace(a, b, 5)
        return SkeletonBranch(pts, np.ones(5), np.full(5, 0.1), ends)

    branches = [branch([0, 0, 0], [1, 0, 0], (0, None)), branch([0, 0, 0], [0, 1, 0], (0, None)),
                branch([0, 0, 0], [0, 0, 1], (0, 1)), branch([0, 0, 2], [0, 0, 1], (None, 1))]
    skel = Skeleton(branches, np.array([[0.0, 0, 0], [0, 0, 1]]), 0.25)
    out = with_ends_opened(skel, [(0, 0), (1, 0)])
    assert [b.ends for b in out.branches] == [(None, None), (None, None), (None, 0), (None, 0)]
    np.testing.assert_array_equal(out.junctions, [[0.0, 0.0, 1.0]])
    assert all(b.points is a.points for a, b in zip(branches, out.branches))
    out = with_ends_opened(skel, [(0, 0), (1, 0), (2, 1)])
    assert all(b.ends == (None, None) for b in out.branches) and out.junctions.shape == (0, 3)
