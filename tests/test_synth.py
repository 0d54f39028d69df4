"""Tests of canalsurf.synth: the generated clouds lie on the surfaces the paper describes."""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from canalsurf import synth
from canalsurf.errors import InputError
from canalsurf.spine import constant_spline

NAMES = list(synth.SURFACES)
#: The Figure 15 pipe (r = 0.3) is very slightly singular at its tightest bend (r kappa = 1.05, NOTES):
#: there a few noise-free points lie up to ~4e-4 inside a neighbouring sphere.
SINGULAR_SLACK = {"fig15-pipe": 1e-3}


@pytest.mark.parametrize("name", NAMES)
def test_every_surface_samples(name):
    tube = synth.make_tube(name, n=500, rng=3)
    assert tube.name == name
    assert tube.points.shape == (500, 3) and tube.normals.shape == (500, 3)
    assert np.isfinite(tube.points).all()
    np.testing.assert_allclose(np.linalg.norm(tube.normals, axis=1), 1.0, atol=1e-12)
    assert tube.noise == synth.SURFACES[name][3]
    assert tube.closed == synth.SURFACES[name][2]
    assert tube.is_pipe == ("canal" not in name)
    assert not tube.outlier.any() and tube.arc == 360.0 and tube.noise_model == "uniform"


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_cloud(name):
    a = synth.make_tube(name, n=300, rng=42)
    b = synth.make_tube(name, n=300, rng=42)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    c = synth.make_tube(name, n=300, rng=np.random.default_rng(42))
    np.testing.assert_array_equal(a.points, c.points)
    assert not np.array_equal(a.points, synth.make_tube(name, n=300, rng=43).points)


def test_default_seed_is_fixed():
    np.testing.assert_array_equal(synth.make_tube("helix", n=100).points, synth.make_tube("helix", n=100).points)


@pytest.mark.parametrize("name", NAMES)
def test_points_lie_at_radius_plus_noise(name, envelope_distance):
    """Brute force over the spine: every point's distance from the canal surface is its uniform noise."""
    tube = synth.make_tube(name, n=1000, rng=5)
    dist, t = envelope_distance(tube.points, tube.spine, tube.radius, closed=tube.closed)
    slack = SINGULAR_SLACK.get(name, 1e-5)
    assert np.abs(dist).max() <= tube.noise + slack
    # Uniform in [-noise, noise]: both extremes are reached (1000 draws: within 1 % of the bound).
    assert dist.max() >= 0.98 * tube.noise and dist.min() <= -0.98 * tube.noise + slack
    assert abs(dist.mean()) <= 0.1 * tube.noise
    # The normal is the direction from the spine to the point (a sphere's normal), outward.
    radial = tube.points - tube.spine(t)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", radial, tube.normals)
    assert np.median(cos) >= 1 - 1e-6
    assert np.mean(cos >= 1 - 1e-4) >= 0.99


@pytest.mark.parametrize("name", NAMES)
def test_noise_free_points_are_on_the_surface(name, envelope_distance):
    tube = synth.make_tube(name, n=1000, noise=0.0, rng=5)
    dist, _ = envelope_distance(tube.points, tube.spine, tube.radius, closed=tube.closed)
    assert np.percentile(np.abs(dist), 99) <= 1e-5
    assert np.abs(dist).max() <= SINGULAR_SLACK.get(name, 1e-5)


def test_noise_can_be_set():
    assert synth.make_tube("fig9-pipe", noise=0.2).noise == 0.2
    quiet = synth.make_tube("torus", n=400, noise=0.0, rng=1)
    assert quiet.noise == 0.0


# --- real-scan conditions -------------------------------------------------------------------------------

def test_gaussian_noise_has_the_given_standard_deviation(envelope_distance):
    tube = synth.make_tube("torus", n=4000, noise=0.03, noise_model="gaussian", rng=2)
    dist, _ = envelope_distance(tube.points, tube.spine, tube.radius, closed=True)
    assert np.std(dist) == pytest.approx(0.03, rel=0.05)
    assert np.abs(dist).max() > 0.075  # beyond any uniform +-0.03: the tails are Gaussian


def test_outliers_are_marked_and_lie_in_the_bounding_box(envelope_distance):
    tube = synth.make_tube("elbow", n=2000, outliers=0.05, rng=2)
    assert tube.outlier.sum() == 100 and tube.points.shape == (2000, 3)
    surface = tube.points[~tube.outlier]
    assert (tube.points[tube.outlier] >= surface.min(axis=0)).all()
    assert (tube.points[tube.outlier] <= surface.max(axis=0)).all()
    dist, _ = envelope_distance(tube.points, tube.spine, tube.radius, closed=False)
    assert np.abs(dist[~tube.outlier]).max() <= tube.noise + 1e-5
    assert np.median(np.abs(dist[tube.outlier])) > 10 * tube.noise


@pytest.mark.parametrize("arc", [180.0, 270.0])
def test_one_sided_scan_sees_one_arc_of_each_cross_section(arc):
    """Every normal lies within arc / 2 of the viewing side of its own cross-section."""
    tube = synth.make_tube("fig9-pipe", n=3000, noise=0.0, arc=arc, rng=2)
    view = synth.view_direction(tube.spine)
    u = np.linspace(0, 1, 20001)
    t = u[np.argmin(np.linalg.norm(tube.points[:, None, :] - tube.spine(u[::20])[None], axis=2), axis=1) * 20]
    tangent = tube.spine.derivative()(t)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    towards = view - (tangent @ view)[:, None] * tangent
    towards /= np.linalg.norm(towards, axis=1, keepdims=True)
    across = tube.normals - np.einsum("ij,ij->i", tube.normals, tangent)[:, None] * tangent
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    angle = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", across, towards), -1, 1)))
    # The nearest of 1001 spine samples tilts the cross-section by a fraction of a degree.
    assert angle.max() <= arc / 2 + 2 and angle.max() >= arc / 2 - 2


def test_density_falls_along_the_spine_by_the_ratio():
    tube = synth.make_tube("canal-x3", n=6000, noise=0.0, density_ratio=10, rng=2)
    u = np.linspace(0, 1, 2001)
    t = u[np.argmin(np.linalg.norm(tube.points[:, None, :] - tube.spine(u)[None], axis=2), axis=1)]
    per_area = np.histogram(t, bins=[0, 0.1, 0.9, 1.0])[0]
    # Density at each end relative to the area there (the canal's radius grows 3x: area per unit t too).
    area = [np.mean(tube.radius(np.linspace(a, b, 50))) * (b - a) for a, b in ((0, 0.1), (0.9, 1.0))]
    ratio = (per_area[0] / area[0]) / (per_area[2] / area[1])
    assert 10 ** 0.9 / 1.4 <= ratio <= 10 ** 0.9 * 1.4  # exp(-t ln 10) between the bins' centres


@pytest.mark.parametrize("kwargs, match", [
    ({"arc": 0}, r"^arc must be in \(0, 360\] degrees, got 0"),
    ({"density_ratio": 0.5}, r"^density_ratio must be >= 1, got 0\.5$"),
    ({"outliers": 1.0}, r"^outliers must be a share in \[0, 1\), got 1\.0$"),
    ({"noise_model": "pink"}, r"^noise_model must be one of"),
])
def test_bad_condition_options(kwargs, match):
    with pytest.raises(InputError, match=match):
        synth.make_tube("torus", n=100, **kwargs)


# --- the paper's data ---------------------------------------------------------------------------------

def test_fig15_radius_is_0_3_not_3():
    _, radius_f, _, _, description = synth.SURFACES["fig15-pipe"]
    np.testing.assert_allclose(radius_f()(np.linspace(0, 1, 11)), 0.3)
    assert "typo" in description
    tube = synth.make_tube("fig15-pipe", n=200)
    assert tube.is_pipe and tube.radius(0.5) == pytest.approx(0.3)


def test_paper_spines_start_and_end_at_their_control_polygons():
    """Clamped cubic B-splines interpolate the first and last control points of Tables 1 - 3."""
    table = {"fig9-pipe": ([-3.0, 6.66, 0.0], [6.76, -3.15, 0.0]),
             "fig15-pipe": ([0.0, 0.0, 0.0], [0.0, 0.0, 3.0]),
             "fig16-canal": ([-4.0, 4.0, 0.0], [-4.257, -4.7, 0.0])}
    for name, (first, last) in table.items():
        spine = synth.SURFACES[name][0]()
        np.testing.assert_allclose(spine(0.0), first, atol=1e-12)
        np.testing.assert_allclose(spine(1.0), last, atol=1e-12)
        assert spine.k == 3
    assert len(synth.SURFACES["fig15-pipe"][0]().c) == 10


def test_fig14_radius_is_the_quadratic_bspline_mapped_onto_the_spine():
    """Quadratic B-spline, knots (0,0,0,1,2,3,4,4,4), coefficients (2,1.5,1,1.5,2.5,2) on [0, 4] mapped to
    [0, 1]: at an interior knot it is the mean of the two coefficients there."""
    radius = synth.SURFACES["fig14-canal"][1]()
    np.testing.assert_allclose(radius([0.0, 0.25, 0.5, 0.75, 1.0]), [2.0, 1.25, 1.25, 2.0, 2.0], atol=1e-12)
    r = radius(np.linspace(0.0, 1.0, 4001))
    # Smallest in the middle of the (1.5, 1, 1.5) segment: 1.5 / 8 + 1 * 3 / 4 + 1.5 / 8.
    assert r.min() == pytest.approx(1.125, abs=1e-6) and r.max() <= 2.5


def test_stated_radius_ranges_are_true():
    """A description's "from A to B" is the least and the greatest radius, to 3 significant digits."""
    t = np.linspace(0.0, 1.0, 200001)
    stated = {name: re.search(r"from (\d+(?:\.\d+)?) to (\d+(?:\.\d+)?)", entry[4])
              for name, entry in synth.SURFACES.items()}
    stated = {name: match.groups() for name, match in stated.items() if match}
    assert {"fig14-canal", "canal-x3"} <= set(stated)
    for name, (low, high) in stated.items():
        r = synth.SURFACES[name][1]()(t)
        assert (f"{r.min():.3g}", f"{r.max():.3g}") == (f"{float(low):.3g}", f"{float(high):.3g}"), name


def test_fig16_radius_ends():
    radius = synth.SURFACES["fig16-canal"][1]()
    assert radius(0.0) == pytest.approx(1.9999) and radius(1.0) == pytest.approx(2.5)


def test_torus_spine_is_a_closed_circle():
    spine = synth.SURFACES["torus"][0]()
    np.testing.assert_allclose(spine(0.0), spine(1.0), atol=1e-12)
    np.testing.assert_allclose(spine.derivative()(0.0), spine.derivative()(1.0), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(spine(np.linspace(0, 1, 1001)), axis=1), 4.0, atol=1e-6)


def test_helix_spine():
    spine = synth.SURFACES["helix"][0]()
    t = np.linspace(0.0, 1.0, 1001)
    p = spine(t)
    # An interpolating spline through 200 samples: exact to about 1e-6.
    np.testing.assert_allclose(np.linalg.norm(p[:, :2], axis=1), 3.0, atol=1e-5)
    np.testing.assert_allclose(p[:, 2], 8.0 * t, atol=1e-5)


# --- bad requests ----------------------------------------------------------------------------------------

def test_unknown_name():
    with pytest.raises(InputError, match=r"^surface name must be one of 'fig9-pipe', 'fig15-pipe', "
                                         r"'fig14-canal', 'fig16-canal', 'helix', 'torus', 'trefoil', 'elbow', "
                                         r"'tight-helix', 'long-thin', 'canal-x3', got 'fig99'$"):
        synth.make_tube("fig99")


@pytest.mark.parametrize("n", [0, -5])
def test_bad_point_count(n):
    with pytest.raises(InputError, match=rf"^n must be a positive number of points, got {n}$"):
        synth.make_tube("helix", n=n)


def test_negative_noise():
    with pytest.raises(InputError, match=r"^noise must be >= 0, got -0\.1$"):
        synth.make_tube("helix", noise=-0.1)


def test_radius_too_steep_for_an_envelope(rng):
    spine = synth.SURFACES["helix"][0]()  # |C'| about 38.5
    steep = BSpline(np.array([0.0, 0.0, 1.0, 1.0]), np.array([1.0, 60.0]), 1)
    with pytest.raises(InputError, match=r"^the radius changes faster than the spine advances "
                                         r"\(\|dr/ds\| >= 1\): no envelope$"):
        synth.sample_tube(spine, steep, 100, 0.0, rng)
    points, normals = synth.sample_tube(spine, constant_spline(0.5), 100, 0.0, rng)
    assert points.shape == normals.shape == (100, 3)


# --- hardening of make_tube ------------------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, match", [
    ({"noise": float("nan")}, r"^noise must be a finite number, got nan$"),
    ({"noise": float("inf")}, r"^noise must be a finite number, got inf$"),
    ({"noise": "loud"}, r"^noise must be a number, got 'loud'$"),
    ({"noise": 1e308}, r"^noise 1e\+308 is larger than the surface itself \(the diagonal of its bounding box is "
                       r"[0-9.]+\); give a noise well below the radius$"),
    ({"rng": "x"}, r"^rng must be None, a seed \(an integer >= 0\) or a numpy\.random\.Generator, got 'x'$"),
    ({"rng": -1}, r"^rng must be None, a seed \(an integer >= 0\) or a numpy\.random\.Generator, got -1$"),
    ({"rng": 1.5}, r"^rng must be None, a seed .* got 1\.5$"),
    ({"n": 2.5}, r"^n must be a whole number of points, got 2\.5$"),
    ({"n": "100"}, r"^n must be a whole number of points, got '100'$"),
    ({"n": float("inf")}, r"^n must be a whole number of points, got inf$"),
    ({"n": 99999999999999999999}, r"^n = 99999999999999999999 points would not fit in memory; at most "
                                  r"20,000,000 can be generated at once$"),
    ({"n": 1e20}, r"^n = 1e\+20 points would not fit in memory"),
    ({"n": synth.MAX_SYNTH_POINTS + 1}, r"^n = 20000001 points would not fit in memory"),
])
def test_make_tube_refuses_bad_arguments_before_any_work(kwargs, match):
    with pytest.raises(InputError, match=match):
        synth.make_tube("fig9-pipe", **kwargs)


def test_make_tube_accepts_whole_floats_and_numpy_seeds():
    a = synth.make_tube("helix", n=200.0, rng=np.int64(3))
    b = synth.make_tube("helix", n=np.int32(200), rng=3)
    assert a.points.shape == (200, 3)
    np.testing.assert_array_equal(a.points, b.points)


def test_make_tube_noise_up_to_the_size_of_the_surface_is_allowed():
    assert synth.make_tube("fig9-pipe", n=100, noise=5.0).noise == 5.0


#: First point of ``make_tube("fig9-pipe", n=5, rng=0)``: every seeded cloud made before the networks were
#: added (the paper's tables, the benchmarks) must stay as it was.
PINNED_FIG9_SEED0_FIRST = (0.04701795685566039, -0.8907894403761597, -7.3601232177568665)


def test_seeded_clouds_are_as_before():
    tube = synth.make_tube("fig9-pipe", n=5, rng=0)
    np.testing.assert_allclose(tube.points[0], PINNED_FIG9_SEED0_FIRST, rtol=0, atol=1e-9)


# --- networks ---------------------------------------------------------------------------------------------

#: name -> (branches, junctions, connected networks) of every network.
NETWORK_SHAPES = {"y-vessel": (3, 1, 1), "t-junction": (3, 1, 1), "tree": (7, 3, 1), "rack": (4, 0, 4),
                  "bundle": (2, 0, 2), "crossing": (2, 0, 2), "floor-clutter": (1, 0, 1), "scene": (8, 1, 6),
                  "plant": (23, 2, 19), "piping": (6, 1, 4)}
#: Default share of the points on clutter.
DEFAULT_CLUTTER = {"floor-clutter": 0.3, "scene": 0.2, "plant": 0.2}
#: Points of each test cloud (small enough for the brute-force checks).
N_NETWORK = 6000
#: Spine samples of the brute-force prefilter (the nearest is within half a step of any spine point).
N_SPINE = 4001
#: Refining samples of the brute-force envelope distance: a final step of 4e-5 in t, which finds the
#: minimum to about 1e-7 r on these spines (the error is quadratic in the step).
REFINE = 101


def test_every_network_is_listed_and_documented():
    assert list(synth.NETWORKS) == list(NETWORK_SHAPES)
    assert not set(synth.NETWORKS) & set(synth.SURFACES)
    assert all(callable(builder) and description for builder, description in synth.NETWORKS.values())


@pytest.mark.parametrize("name", list(NETWORK_SHAPES))
def test_network_layout(name):
    net = synth.make_network(name, n=500, rng=0)
    n_branches, n_junctions, n_components = NETWORK_SHAPES[name]
    assert len(net.branches) == n_branches and net.junctions.shape == (n_junctions, 3)
    assert len(net.components) == n_components
    assert sorted(b for c in net.components for b in c) == list(range(n_branches))
    assert net.components == sorted(sorted(c) for c in net.components)
    listed = [j for b in net.branches for j in b.ends if j is not None]
    assert sorted(set(listed)) == list(range(n_junctions))
    for branch in net.branches:
        assert isinstance(branch, synth.SyntheticBranch) and branch.spine.k == 3
        for end, j in zip((0.0, 1.0), branch.ends):
            if j is not None:
                np.testing.assert_allclose(branch.spine(end), net.junctions[j], rtol=0, atol=1e-9)
        # normalised arc length: constant speed, equal to the length
        t = np.linspace(0.0, 1.0, 2001)
        speed = np.linalg.norm(branch.spine.derivative()(t), axis=1)
        length = np.linalg.norm(np.diff(branch.spine(t), axis=0), axis=1).sum()
        np.testing.assert_allclose(speed, length, rtol=2e-3)
        assert branch.radius(t).min() > 0
    for j, junction in enumerate(net.junctions):
        # A daughter starts at the junction, which lies on its parent's axis (the parent ends there or runs on).
        assert sum(j in b.ends for b in net.branches) in (2, 3)
        starting = [b for b in net.branches if b.ends[0] == j]
        assert starting


def _unit(v):
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("name, side_angles", [("t-junction", [90.0]), ("tree", [55.0, 45.0, 50.0]),
                                               ("scene", [90.0]), ("plant", [90.0, 90.0])])
def test_split_pipes_run_on_through_their_junctions(name, side_angles):
    """Where a pipe is split, its halves meet end to end with one tangent; the side branch leaves at its angle."""
    net = synth.make_network(name, n=300, rng=0)
    for j, expected in zip(range(len(net.junctions)), side_angles):
        (before,) = [b for b in net.branches if b.ends[1] == j]
        after, side = [b for b in net.branches if b.ends[0] == j]
        axis = _unit(before.spine.derivative()(1.0))
        assert _unit(after.spine.derivative()(0.0)) @ axis == pytest.approx(1.0, abs=1e-9)
        angle = np.degrees(np.arccos(_unit(side.spine.derivative()(0.0)) @ axis))
        assert angle == pytest.approx(expected, abs=1e-6)
        assert before.radius(1.0) == pytest.approx(after.radius(0.0), abs=1e-12)
        assert side.radius(0.0) < after.radius(0.0)


def test_y_vessel_forks_at_two_different_angles():
    net = synth.make_network("y-vessel", n=300, rng=0)
    parent, first, second = net.branches
    assert parent.ends == (None, 0) and first.ends == second.ends == (0, None)
    axis = _unit(parent.spine.derivative()(1.0))
    angles = [np.degrees(np.arccos(_unit(b.spine.derivative()(0.0)) @ axis)) for b in (first, second)]
    np.testing.assert_allclose(angles, [25.0, 50.0], atol=1e-6)
    np.testing.assert_allclose([parent.radius(0.0), parent.radius(1.0), first.radius(0.0), first.radius(1.0),
                                second.radius(0.0), second.radius(1.0)], [1.0, 0.85, 0.75, 0.55, 0.65, 0.5])


def test_rack_and_crossing_gaps():
    """Neighbours in a rack are 1 - 2 smaller radii apart; the crossing pipes 0.75 r."""
    rack = synth.make_network("rack", n=300, rng=0)
    axes = [(b.spine(0.5), float(b.radius(0.5))) for b in rack.branches]
    for (c0, r0), (c1, r1) in zip(axes, axes[1:]):
        gap = np.linalg.norm(c1 - c0) - r0 - r1
        assert 1.0 * min(r0, r1) <= gap <= 2.0 * min(r0, r1)
    np.testing.assert_allclose([r for _, r in axes], [1.0, 1.5, 0.8, 2.0])
    a, b = synth.make_network("crossing", n=300, rng=0).branches
    da, db = _unit(a.spine(1.0) - a.spine(0.0)), _unit(b.spine(1.0) - b.spine(0.0))
    assert da @ db == pytest.approx(0.0, abs=1e-12)
    normal = _unit(np.cross(da, db))
    assert abs((b.spine(0.0) - a.spine(0.0)) @ normal) == pytest.approx(2.75, abs=1e-9)


@pytest.mark.parametrize("radii, gap", [((1.0, 1.0), 0.0), ((1.0, 0.5, 0.8), 0.2)])
def test_bundle_pipes_touch_or_keep_their_gap(radii, gap):
    axes = [(b.spine(0.5), float(b.radius(0.5))) for b in
            synth.make_network("bundle", n=300, rng=0, radii=radii, gap=gap).branches]
    np.testing.assert_allclose([r for _, r in axes], radii)
    for (c0, r0), (c1, r1) in zip(axes, axes[1:]):
        assert np.linalg.norm(c1 - c0) - r0 - r1 == pytest.approx(gap * min(r0, r1), abs=1e-9)


@pytest.mark.parametrize("options, match", [
    ({"radii": ()}, r"^a bundle takes 1 to 8 positive radii, got \(\)$"),
    ({"radii": (1.0, -1.0)}, r"^a bundle takes 1 to 8 positive radii, got \(1\.0, -1\.0\)$"),
    ({"gap": -0.5}, r"^a bundle's gap is a share of the smaller radius in \[0, 10\], got -0\.5$"),
])
def test_bundle_options_are_checked(options, match):
    with pytest.raises(InputError, match=match):
        synth.make_network("bundle", n=300, **options)


def _other_tube_depth(points, branch, envelope_distance):
    """Brute force ``min_t |P - C(t)| - r(t)`` of the points near ``branch`` (+inf for the others)."""
    t = np.linspace(0.0, 1.0, N_SPINE)
    samples, radii = branch.spine(t), branch.radius(t)
    step = np.linalg.norm(np.diff(samples, axis=0), axis=1).max()
    dist, _ = cKDTree(samples).query(points, distance_upper_bound=radii.max() + step)
    near = np.isfinite(dist)
    depth = np.full(len(points), np.inf)
    if near.any():
        depth[near] = envelope_distance(points[near], branch.spine, branch.radius, refine=REFINE)[0]
    return depth


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("name", list(NETWORK_SHAPES))
def test_network_points_lie_on_the_union_of_the_tubes(name, seed, envelope_distance):
    """Noise-free: every tube point is on its branch's surface and outside every other tube; with noise,
    the same points moved along their normals by at most noise x the local radius."""
    quiet = synth.make_network(name, n=N_NETWORK, noise=0.0, rng=seed)
    noisy = synth.make_network(name, n=N_NETWORK, rng=seed)
    assert noisy.noise == 0.02 and quiet.noise == 0.0
    for net in (quiet, noisy):
        assert net.points.shape == net.normals.shape == (N_NETWORK, 3) and net.label.shape == (N_NETWORK,)
        assert np.isfinite(net.points).all() and net.label.dtype.kind == "i"
        np.testing.assert_allclose(np.linalg.norm(net.normals, axis=1), 1.0, atol=1e-12)
        assert net.label.min() >= -1 and net.label.max() < len(net.branches)
        assert net.clutter.sum() == round(DEFAULT_CLUTTER.get(name, 0.0) * N_NETWORK)
        np.testing.assert_array_equal(net.clutter, net.label == -1)
    np.testing.assert_array_equal(quiet.label, noisy.label)
    np.testing.assert_array_equal(quiet.normals, noisy.normals)
    offset = np.einsum("ij,ij->i", noisy.points - quiet.points, quiet.normals)
    np.testing.assert_allclose(noisy.points, quiet.points + offset[:, None] * quiet.normals, rtol=0, atol=1e-12)

    scale = np.empty(N_NETWORK)
    for b, branch in enumerate(quiet.branches):
        mine = quiet.label == b
        assert mine.sum() >= 10, f"branch {b} got {mine.sum()} points"
        dist, t = envelope_distance(quiet.points[mine], branch.spine, branch.radius, refine=REFINE)
        assert np.abs(dist).max() <= 1e-6 * branch.radius(0.5)
        scale[mine] = branch.radius(t)
        depth = _other_tube_depth(quiet.points[~mine], branch, envelope_distance)
        assert depth.min() >= -1e-6 * branch.radius(np.linspace(0, 1, 64)).max()
        noisy_dist, _ = envelope_distance(noisy.points[mine], branch.spine, branch.radius, refine=REFINE)
        assert np.abs(noisy_dist).max() <= noisy.noise * scale[mine].max() + 1e-6
        np.testing.assert_array_less(np.abs(noisy_dist), noisy.noise * scale[mine] + 1e-6)
    clutter = quiet.clutter
    if clutter.any():
        scale[clutter] = np.median([np.mean(b.radius(np.linspace(0, 1, 64))) for b in quiet.branches])
        # faces of a floor or of axis-aligned boxes
        assert np.all(np.isin(np.round(np.abs(quiet.normals[clutter]).max(axis=1), 12), [1.0]))
        assert np.all(quiet.normals[clutter][:, 2] >= 0)
        # the tubes stand clear of the floor and the boxes (by a radius or more)
        assert cKDTree(quiet.points[clutter]).query(quiet.points[~clutter])[0].min() >= 0.9
    assert np.all(np.abs(offset) <= noisy.noise * scale * (1 + 1e-9))
    assert np.abs(offset).max() >= 0.9 * noisy.noise * scale[np.argmax(np.abs(offset))]


@pytest.mark.parametrize("name", ["t-junction", "tree"])
def test_no_gap_where_the_halves_of_a_split_pipe_meet(name):
    """The circle where two halves meet is on both surfaces: the points next to it are kept (a band of
    +-0.02 around it, away from the side branch, holds about 14 - 20 points at this density)."""
    net = synth.make_network(name, n=20000, noise=0.0, rng=4)
    for j, junction in enumerate(net.junctions):
        (a,) = [b for b, branch in enumerate(net.branches) if branch.ends[1] == j]
        after, side = [b for b, branch in enumerate(net.branches) if branch.ends[0] == j]
        axis = _unit(net.branches[a].spine.derivative()(1.0))
        away = net.branches[side].spine(0.2) - junction
        rel = net.points - junction
        band = (np.isin(net.label, [a, after]) & (np.abs(rel @ axis) < 0.02) & (rel @ away < 0))
        assert band.sum() >= 5, (j, band.sum())


def test_network_density_is_uniform_by_area():
    """On the rack nothing is removed: each pipe gets its share of the points by area (4 sigma)."""
    net = synth.make_network("rack", n=N_NETWORK, rng=3)
    area = np.array([2 * np.pi * float(b.radius(0.5)) * 20.0 for b in net.branches])
    expected = N_NETWORK * area / area.sum()
    np.testing.assert_array_less(np.abs(np.bincount(net.label) - expected), 4 * np.sqrt(expected))


def test_floor_clutter_geometry():
    net = synth.make_network("floor-clutter", n=N_NETWORK, noise=0.0, rng=1)
    (pipe,) = net.branches
    clutter = net.points[net.clutter]
    up = net.normals[net.clutter][:, 2] == 1.0
    floor = clutter[up & (clutter[:, 2] < 1.0)]
    np.testing.assert_allclose(floor[:, 2], 0.0, atol=1e-12)
    t = np.linspace(0.0, 1.0, N_SPINE)
    spine = pipe.spine(t)
    assert spine[:, 2].min() - 1.0 == pytest.approx(1.0)  # the pipe's bottom one radius above the floor
    box = clutter[~up | (clutter[:, 2] > 1.0)]
    np.testing.assert_allclose(np.ptp(box, axis=0), 3.0, atol=0.05)
    assert cKDTree(spine).query(box)[0].min() - 1.0 >= 1.5  # 1.5 radii between box and pipe
    # the floor reaches a few radii beyond the pipe and the box
    assert (floor.min(axis=0)[:2] <= np.minimum(spine.min(axis=0), box.min(axis=0))[:2] - 2).all()
    assert (floor.max(axis=0)[:2] >= np.maximum(spine.max(axis=0), box.max(axis=0))[:2] + 2).all()


@pytest.mark.parametrize("clutter", [0.0, 0.25, 0.9])
def test_clutter_share_can_be_set(clutter):
    net = synth.make_network("t-junction", n=1001, clutter=clutter, rng=2)
    assert abs(net.clutter.sum() - clutter * 1001) <= 1
    if clutter:  # a floor is added below the network, flat and facing up
        below = net.points[net.clutter]
        assert np.ptp(below[:, 2]) <= 2 * net.noise * 1.0 + 1e-12
        assert below[:, 2].max() < net.points[~net.clutter][:, 2].min()
    assert synth.make_network("scene", n=1000, clutter=0.0, rng=2).clutter.sum() == 0


def test_plant_size_multiplies_the_tubes():
    small = synth.make_network("plant", n=2000, rng=0)
    large = synth.make_network("plant", n=2000, rng=0, size=10)
    assert len(small.branches) >= 20 and len(large.branches) >= 200
    assert len(large.branches) == 10 * len(small.branches)
    assert len(large.junctions) == 10 * len(small.junctions)
    elbows = [b for b in small.branches if b.ends == (None, None)
              and not np.allclose(b.spine(0.5), (b.spine(0.0) + b.spine(1.0)) / 2)]
    assert len(elbows) == 2  # the bent runs (every other branch is straight)
    radii = sorted({round(float(b.radius(0.5)), 6) for b in small.branches})
    assert radii[0] <= 0.5 and radii[-1] >= 2.0


@pytest.mark.parametrize("name", ["tree", "scene"])
def test_network_same_seed_same_cloud(name):
    a = synth.make_network(name, n=2000, rng=7)
    b = synth.make_network(name, n=2000, rng=np.random.default_rng(7))
    for field in ("points", "normals", "label"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not np.array_equal(a.points, synth.make_network(name, n=2000, rng=8).points)
    np.testing.assert_array_equal(synth.make_network(name, n=500).points,
                                  synth.make_network(name, n=500, rng=0).points)


@pytest.mark.parametrize("kwargs, match", [
    ({"name": "knot"}, r"^network name must be one of 'y-vessel', 't-junction', 'tree', 'rack', 'bundle', "
                       r"'crossing', 'floor-clutter', 'scene', 'plant', 'piping', got 'knot'$"),
    ({"n": 0}, r"^n must be a positive number of points, got 0$"),
    ({"n": 10.5}, r"^n must be a whole number of points, got 10\.5$"),
    ({"n": 99999999999999999999}, r"^n = 99999999999999999999 points would not fit in memory; at most "
                                  r"20,000,000 can be generated at once$"),
    ({"noise": float("nan")}, r"^noise must be a finite number, got nan$"),
    ({"noise": 0.5}, r"^noise must be a share of the radius in \[0, 0\.5\), got 0\.5$"),
    ({"noise": -0.01}, r"^noise must be a share of the radius in \[0, 0\.5\), got -0\.01$"),
    ({"noise": 1e308}, r"^noise must be a share of the radius in \[0, 0\.5\), got 1e\+308$"),
    ({"clutter": 0.95}, r"^clutter must be a share of the points in \[0, 0\.9\], got 0\.95$"),
    ({"clutter": -0.1}, r"^clutter must be a share of the points in \[0, 0\.9\], got -0\.1$"),
    ({"clutter": float("nan")}, r"^clutter must be a finite number, got nan$"),
    ({"rng": "x"}, r"^rng must be None, a seed \(an integer >= 0\) or a numpy\.random\.Generator, got 'x'$"),
    ({"rng": -1}, r"^rng must be None, a seed \(an integer >= 0\) or a numpy\.random\.Generator, got -1$"),
    ({"size": 2}, r"^the 't-junction' network has no option 'size'; it takes none$"),
    ({"name": "plant", "size": 0}, r"^size must be a whole number of bays in \[1, 100\], got 0$"),
    ({"name": "plant", "size": 1.5}, r"^size must be a whole number of bays in \[1, 100\], got 1\.5$"),
    ({"name": "plant", "bays": 2}, r"^the 'plant' network has no option 'bays'; it takes size$"),
])
def test_make_network_refuses_bad_arguments(kwargs, match):
    kwargs = {"name": "t-junction", "n": 100} | kwargs
    with pytest.raises(InputError, match=match):
        synth.make_network(kwargs.pop("name"), **kwargs)


# --- simulated scans ----------------------------------------------------------------------------------

def _straight_branch(a, b, r=1.0, ends=(None, None)):
    """A straight tube from ``a`` to ``b`` (cubic spine on normalised arc length)."""
    from scipy.interpolate import make_interp_spline

    xyz = np.linspace(np.asarray(a, float), np.asarray(b, float), 4)
    return synth.SyntheticBranch(make_interp_spline(np.linspace(0, 1, 4), xyz, k=3), constant_spline(r), ends)


def _pipe(a=(-5.0, 0.0, 0.0), b=(5.0, 0.0, 0.0), r=1.0):
    """A straight open pipe as a SyntheticTube (its truth only)."""
    branch = _straight_branch(a, b, r)
    return synth.SyntheticTube("pipe", np.empty((0, 3)), np.empty((0, 3)), branch.spine, branch.radius, False, 0.0)


def _network(*branches, name="pair"):
    """Branches as a SyntheticNetwork without junctions or clutter (its truth only)."""
    return synth.SyntheticNetwork(name, np.empty((0, 3)), np.empty((0, 3)), np.empty(0, np.int64), branches,
                                  np.empty((0, 3)), 0.0)


def _coverage(points):
    """Degrees of the circle around the x axis that the points cover (360 less the widest empty angle)."""
    a = np.sort(np.arctan2(points[:, 2], points[:, 1]))
    return 360.0 - np.degrees(np.max(np.diff(np.concatenate([a, [a[0] + 2 * np.pi]]))))


def test_scan_of_a_pipe_is_one_sided_and_two_opposite_scanners_see_more():
    """From one side a pipe shows less than half its circumference (a scanner 20 r away sees the arc
    of 2 acos(1/20) = 174 degrees), and nothing of its far side; two facing scanners see nearly all of it."""
    pipe = _pipe()
    one = synth.scan(pipe, positions=[[0.0, -20.0, 0.0]], step=0.2, noise=0.0, ground=False)
    assert len(one.points) > 1000 and not one.outlier.any()
    # Visible points satisfy (P - C) . (O - C) >= r^2: here y <= -r^2 / 20.
    assert one.points[:, 1].max() <= -1 / 20 + 1e-9
    assert 150.0 < _coverage(one.points) < 2 * np.degrees(np.arccos(1 / 20)) + 1e-6
    facing = np.einsum("ij,ij->i", one.normals, one.scan.positions[0] - one.points)
    assert facing.min() > 0
    two = synth.scan(pipe, positions=[[0.0, -20.0, 0.0], [0.0, 20.0, 0.0]], step=0.2, noise=0.0, ground=False)
    assert _coverage(two.points) > 330.0
    assert sorted(set(two.scan.scanner.tolist())) == [0, 1]
    assert np.all(two.points[two.scan.scanner == 1, 1] >= 1 / 20 - 1e-9)


def _segment_clearance(origin, points, a, b, samples=400):
    """Smallest distance from the axis ``a b`` of the samples of the segments ``origin -> points`` that lie
    between the planes through ``a`` and ``b`` across it (the open pipe's slab), inf where none does."""
    s = np.linspace(0.0, 1.0, samples)[None, :, None]
    along = origin + s * (points[:, None, :] - origin)                 # (N, samples, 3)
    axis = (b - a) / np.linalg.norm(b - a)
    u = (along - a) @ axis
    distance = np.linalg.norm(along - (a + u[..., None] * axis), axis=2)
    return np.where((u >= 0) & (u <= np.linalg.norm(b - a)), distance, np.inf).min(axis=1)


def test_a_tube_hides_what_stands_behind_it():
    """A short pipe in front of a long one casts a shadow on it: no ray to a point of the long pipe
    passes through the short one, and the long pipe's middle is missing."""
    front = _straight_branch([-2.0, 0.0, 0.0], [2.0, 0.0, 0.0])
    back = _straight_branch([-10.0, 5.0, 0.0], [10.0, 5.0, 0.0])
    origin = np.array([0.0, -20.0, 0.0])
    both = synth.scan(_network(front, back), positions=origin, step=0.25, noise=0.0, ground=False)
    alone = synth.scan(_network(back), positions=origin, step=0.25, noise=0.0, ground=False)
    seen = both.points[both.label == 1]
    assert len(seen) > 100 and len(both.points[both.label == 0]) > 100
    # The segment from the scanner to each seen point stays outside the front pipe (radius 1; the sampling
    # of the segment every 0.06 can miss at most 5e-4 of a radius).
    assert _segment_clearance(origin, seen, np.array([-2.0, 0, 0]), np.array([2.0, 0, 0])).min() >= 1 - 1e-3
    # The shadow: the middle of the back pipe (|x| < 2.5 is behind the front pipe) is missing.
    assert not np.any(np.abs(seen[:, 0]) < 2.4)
    assert np.sum(np.abs(alone.points[:, 0]) < 2.4) > 100
    assert len(seen) < len(alone.points)


def test_scan_spacing_grows_with_range():
    """An angular grid: the median neighbour distance of far points exceeds that of near ones."""
    pipe = _pipe([0.0, 0.0, 0.0], [0.0, 40.0, 0.0])
    cloud = synth.scan(pipe, positions=[[-8.0, 5.0, 0.0]], step=0.2, noise=0.0, ground=False)
    distance = cloud.scan.range
    np.testing.assert_allclose(distance, np.linalg.norm(cloud.points - cloud.scan.positions[0], axis=1))
    near, far = cloud.points[distance < 14], cloud.points[distance > 28]
    assert len(near) > 100 and len(far) > 100
    spacing = [np.median(cKDTree(p).query(p, k=2)[0][:, 1]) for p in (near, far)]
    assert spacing[1] > 1.5 * spacing[0]


def test_scan_quantises_coordinates_like_a_las_file():
    raw = synth.scan("t-junction", step=0.3, rng=2)
    grid = synth.scan("t-junction", step=0.3, rng=2, quantum=0.01)
    assert grid.scan.quantum == 0.01 and raw.scan.quantum is None
    units = grid.points / 0.01
    np.testing.assert_allclose(units, np.round(units), rtol=0, atol=1e-6)
    assert np.abs(grid.points - raw.points).max() <= 0.005 + 1e-12
    assert np.abs(raw.points / 0.01 - np.round(raw.points / 0.01)).max() > 0.1


@pytest.mark.parametrize("name", ["fig14-canal", "torus"])
def test_scan_points_lie_on_the_surface_within_their_noise(name, envelope_distance):
    """Brute force: a noise-free scan lies on the true surface; a noisy one is off it by no more than its
    offset along the ray, and those offsets are N(0, sigma^2) with sigma = noise + range_noise * range."""
    quiet = synth.scan(name, step=0.35, noise=0.0, ground=False)
    noisy = synth.scan(name, step=0.35, noise=0.02, range_noise=1e-3, ground=False, rng=3)
    np.testing.assert_array_equal(quiet.scan.range, noisy.scan.range)
    assert quiet.closed == (name == "torus") and quiet.noise_model == "scan" and np.isnan(quiet.arc)
    dist, t = envelope_distance(quiet.points, quiet.spine, quiet.radius, closed=quiet.closed)
    assert np.abs(dist).max() <= 1e-6 * quiet.radius(t).max()
    # True normals: from the spine towards the point (the envelope's normal), turned to the scanner.
    toward = quiet.scan.positions[0] - quiet.points
    assert np.all(np.einsum("ij,ij->i", quiet.normals, toward) > 0)
    radial = quiet.points - quiet.spine(t)
    radial /= np.linalg.norm(radial, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", radial, quiet.normals)), 1.0, atol=1e-6)

    offset = np.linalg.norm(noisy.points - noisy.scan.positions[0], axis=1) - noisy.scan.range
    sigma = noisy.scan.sigma
    np.testing.assert_allclose(sigma, 0.02 + 1e-3 * noisy.scan.range)
    z = offset / sigma
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1 and np.abs(z).max() < 6
    noisy_dist, _ = envelope_distance(noisy.points, noisy.spine, noisy.radius, closed=noisy.closed)
    assert np.all(np.abs(noisy_dist) <= np.abs(offset) + 1e-6)


def _on_clutter(points, net, ground):
    """True for points on the floor or ground plane or on a face of a box."""
    on = np.abs(points[:, 2] - ground) < 1e-9
    if net.floor is not None:
        on |= np.abs(points[:, 2] - net.floor[4]) < 1e-9
    for lo, hi in net.boxes:
        inside = np.all((points >= lo - 1e-9) & (points <= hi + 1e-9), axis=1)
        on_face = np.any((np.abs(points - lo) < 1e-9) | (np.abs(points - hi) < 1e-9), axis=1)
        on |= inside & on_face
    return on


@pytest.mark.parametrize("name", ["t-junction", "floor-clutter"])
def test_scan_labels_are_right(name, envelope_distance):
    """Each tube point lies on its branch's surface and inside no other tube; every other point lies on
    the floor, a box or the ground."""
    net = synth.scan(name, positions=2, step=0.25, noise=0.0)
    assert isinstance(net, synth.SyntheticNetwork) and net.points.shape == net.normals.shape
    assert net.label.dtype.kind == "i" and set(net.label.tolist()) == {-1, *range(len(net.branches))}
    for b, branch in enumerate(net.branches):
        mine = net.label == b
        dist, _ = envelope_distance(net.points[mine], branch.spine, branch.radius)
        assert np.abs(dist).max() <= 1e-6 * branch.radius(0.5)
        others = net.points[~mine & ~net.clutter]
        if len(others):
            depth, _ = envelope_distance(others, branch.spine, branch.radius)
            assert depth.min() >= -1e-6
    assert np.all(_on_clutter(net.points[net.clutter], net, net.scan.ground))
    assert not np.any(_on_clutter(net.points[~net.clutter], net, net.scan.ground))
    clutter_normals = net.normals[net.clutter]
    assert np.all(np.isin(np.abs(clutter_normals).max(axis=1), [1.0]))


def test_scan_of_a_generated_network_sees_its_floor_and_boxes():
    cloud = synth.make_network("floor-clutter", n=200, rng=0)
    assert cloud.floor is not None and len(cloud.boxes) == 1
    assert synth.make_network("floor-clutter", n=200, rng=0, clutter=0.0).floor is None
    np.testing.assert_array_equal(synth.scan(cloud, step=0.4).points, synth.scan("floor-clutter", step=0.4).points)


def test_scanner_inside_a_pipe_sees_its_inner_wall_all_around():
    cloud = synth.scan(_pipe(r=1.0), positions=[[0.0, 0.2, 0.1]], step=3.0, noise=0.0, ground=False)
    assert len(cloud.points) > 1000 and not cloud.outlier.any()
    inner = np.abs(cloud.points[:, 0]) < 4.9
    np.testing.assert_allclose(np.linalg.norm(cloud.points[inner][:, 1:], axis=1), 1.0, atol=1e-9)
    assert _coverage(cloud.points[inner]) > 355.0
    assert len(np.unique(cloud.points, axis=0)) == len(cloud.points)  # straight up and down: one ray each
    # the normals face the scanner, so inwards here
    assert np.all(np.einsum("ij,ij->i", cloud.normals, cloud.points * [0, 1, 1]) < 0)


def test_default_scanners_follow_the_documented_rule():
    one = synth.scan("rack", step=0.5)
    three = synth.scan("rack", positions=3, step=0.5)
    lo, hi = synth._scene_box(synth._scene("rack", {}))
    centre, size = (lo + hi) / 2, np.linalg.norm(hi - lo)
    ground = one.scan.ground
    assert ground == pytest.approx(lo[2] - 2.0)  # one largest radius (2) below the lowest pipe
    for cloud in (one, three):
        xy = cloud.scan.positions[:, :2] - centre[:2]
        np.testing.assert_allclose(np.linalg.norm(xy, axis=1), synth.SCANNER_DISTANCE * size)
        np.testing.assert_allclose(cloud.scan.positions[:, 2], (ground + hi[2]) / 2)
    # the rack is longer in x: the first scanner stands on the -y side, turned by 30 degrees
    first = one.scan.positions[0, :2] - centre[:2]
    assert np.degrees(np.arctan2(first[1], first[0])) == pytest.approx(-90.0 + synth.SCANNER_TURN)
    np.testing.assert_allclose(three.scan.positions[0], one.scan.positions[0])
    angles = np.degrees(np.arctan2(*(three.scan.positions[:, :2] - centre[:2]).T[::-1]))
    np.testing.assert_allclose(np.diff(np.unwrap(np.radians(angles))), np.radians(120.0))


def test_scan_defaults_follow_the_scene():
    cloud = synth.scan("fig9-pipe")
    distance = np.linalg.norm(cloud.scan.positions[0] - np.mean(synth._scene_box(synth._scene("fig9-pipe", {})),
                                                                axis=0))
    assert cloud.scan.step == pytest.approx(np.degrees(synth.SCAN_SPACING_PER_RADIUS / distance))
    assert cloud.noise == cloud.scan.noise == pytest.approx(synth.SCAN_NOISE_PER_RADIUS)
    assert cloud.scan.range_noise == pytest.approx(cloud.scan.noise / distance)
    assert cloud.scan.rays >= len(cloud.points)
    assert cloud.outlier.any() and np.all(np.abs(cloud.points[cloud.outlier][:, 2] - cloud.scan.ground)
                                          <= 6 * cloud.scan.sigma[cloud.outlier])


def test_scan_same_seed_same_scan():
    a = synth.scan("y-vessel", step=0.3, rng=7)
    b = synth.scan("y-vessel", step=0.3, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.normals, b.normals)
    np.testing.assert_array_equal(a.label, b.label)
    c = synth.scan("y-vessel", step=0.3, rng=8)
    np.testing.assert_array_equal(a.label, c.label)  # the seed moves the points, not what is seen
    assert not np.array_equal(a.points, c.points)
    np.testing.assert_array_equal(synth.scan("torus", step=1.0).points, synth.scan("torus", step=1.0).points)


def test_scan_refuses_a_grid_larger_than_max_points():
    with pytest.raises(InputError, match=r"^a scan from 1 scanner with a step of 0\.001 degrees would cast "
                                         r"[\d,]+ rays, more than max_points = 2,000,000; give a larger step "
                                         r"\(about [\d.]+ degrees or more: the rays fall with its square\) or "
                                         r"raise max_points$"):
        synth.scan("fig9-pipe", step=0.001)
    with pytest.raises(InputError, match=r"more than max_points = 100; give a larger step"):
        synth.scan("fig9-pipe", max_points=100)
    assert len(synth.scan("fig9-pipe", step=2.0, max_points=1000).points) <= 1000


@pytest.mark.parametrize("kwargs, match", [
    ({"truth": "knot"}, r"^surface or network name must be one of 'fig9-pipe', .*, 'plant', 'piping', got 'knot'$"),
    ({"truth": 3}, r"^scan needs a name of SURFACES or NETWORKS, a SyntheticTube or a SyntheticNetwork, got int$"),
    ({"size": 2}, r"^option 'size' is an option of a network's builder; 'fig9-pipe' takes none$"),
    ({"truth": "t-junction", "size": 2}, r"^the 't-junction' network has no option 'size'; it takes none$"),
    ({"positions": 0}, r"^positions must be a number of scanners >= 1 or an array of shape \(S, 3\), got 0$"),
    ({"positions": [[0.0, 1.0]]}, r"^positions must be a number of scanners or a finite array of shape \(S, 3\), "
                                  r"got an array of shape \(1, 2\)$"),
    ({"positions": [[0.0, 1.0, np.nan]]}, r"finite array of shape \(S, 3\)"),
    ({"step": 0}, r"^step must be an angle in \(0, 90\] degrees, got 0\.0$"),
    ({"step": 91}, r"^step must be an angle in \(0, 90\] degrees, got 91\.0$"),
    ({"step": "x"}, r"^step must be a number, got 'x'$"),
    ({"noise": -1}, r"^noise must be >= 0, got -1\.0$"),
    ({"range_noise": -1e-3}, r"^range_noise must be >= 0, got -0\.001$"),
    ({"quantum": 0}, r"^quantum must be > 0, got 0\.0$"),
    ({"ground": "yes"}, r"^ground must be True or False, got 'yes'$"),
    ({"max_points": 0}, r"^max_points must be a whole number in \[1, 20,000,000\], got 0$"),
    ({"rng": -1}, r"^rng must be None, a seed"),
    ({"positions": [[1e3, 1.0, 0.5]], "step": 1.0}, r"^no ray of the scan met the scene \(step 1 degrees from 1 "
                                                    r"scanner\(s\)\): give a smaller step or place the scanners "
                                                    r"nearer$"),
])
def test_scan_refuses_bad_arguments(kwargs, match):
    kwargs = {"truth": "fig9-pipe"} | kwargs
    if "no ray" in match:  # a scene smaller than one step seen from afar, between the grid's directions
        kwargs["truth"] = _pipe(r=1e-4, a=(0, 0, 0), b=(1e-3, 0, 0))
        kwargs["ground"] = False
    with pytest.raises(InputError, match=match):
        synth.scan(kwargs.pop("truth"), **kwargs)


@pytest.mark.parametrize("missing", ["trimesh", "embreex"])
def test_scan_without_its_extra_names_it(missing, monkeypatch):
    import sys

    import trimesh.ray.ray_pyembree  # noqa: F401 -- loaded, so that the test leaves it as it was

    monkeypatch.setitem(sys.modules, missing, None)  # as if not installed
    monkeypatch.delitem(sys.modules, "trimesh.ray.ray_pyembree")  # imported again, so it needs embreex again
    with pytest.raises(InputError, match=r"^simulating a scan needs the 'scan' extra \(trimesh with Embree\) — "
                                         r"pip install 'canalsurf\[scan\]'$"):
        synth.scan("fig9-pipe", step=2.0)


def _brute_force_hits(triangles, fan):
    """The first triangle each ray of ``fan`` meets (-1: none) and the distance to it (inf: none), by
    testing every ray against every triangle (Moeller-Trumbore): the slow, obvious reference."""
    directions = fan.directions()
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    p = np.cross(directions[:, None], e2[None])  # (rays, triangles, 3)
    s = fan.origin - v0
    q = np.cross(s, e1)
    with np.errstate(divide="ignore", invalid="ignore"):  # a ray in a triangle's plane (det 0) misses it
        det = np.einsum("rfj,fj->rf", p, e1)
        u = np.einsum("rfj,fj->rf", p, s) / det
        v = directions @ q.T / det
        distance = np.einsum("fj,fj->f", e2, q) / det
    hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (distance > 0)
    distance = np.where(hit, distance, np.inf)
    triangle = np.argmin(distance, axis=1)
    nearest = distance[np.arange(len(triangle)), triangle]
    return np.where(np.isfinite(nearest), triangle, -1), nearest


def test_ray_caster_matches_brute_force():
    """Embree's first hits against every ray tested on every triangle, from outside a torus and from
    inside it (a fan that turns all the way round)."""
    from canalsurf.surface import surface_mesh

    tube = synth.make_tube("torus", n=10)
    vertices, faces = surface_mesh(tube.spine, tube.radius, closed=True, n_around=8, n_along=24)
    triangles = vertices[faces]
    caster = synth._ray_caster(triangles)
    h = np.radians(1.5)
    fans = [synth._Fan(np.array([1.0, -15.0, 3.0]), np.radians(70), h, 30, np.radians(-20), h, 17),
            synth._Fan(np.array([4.0, 0.1, 0.05]), 0.0, 2 * np.pi / 60, 60, -np.pi / 2, 4 * h, 31, wraps=True)]
    for fan in fans:
        triangle, distance = synth._first_hits(caster, triangles, fan)
        reference, reference_distance = _brute_force_hits(triangles, fan)
        assert (triangle >= 0).sum() > 100
        np.testing.assert_array_equal(triangle, reference)
        np.testing.assert_allclose(distance, reference_distance, rtol=1e-12)


def test_cli_writes_a_scan(tmp_path, capsys):
    from canalsurf import cli
    from canalsurf.io import read_points

    path = tmp_path / "scan.ply"
    argv = ["synth", "t-junction", "-o", str(path), "--scanner", "2", "--step", "0.3", "--quantum", "0.01",
            "--seed", "4", "--normals"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    truth = synth.scan("t-junction", positions=2, step=0.3, quantum=0.01, rng=4)
    assert out.startswith(f"{path}: {len(truth.points)} points of t-junction (simulated scan from 2 scanners, "
                          "step 0.3°, Gaussian noise along the ray σ = 0.006 + ")
    assert "coordinates on a 0.01 grid, ground at z = -2;" in out and out.endswith(", seed 4, with true normals)\n")
    points, normals = read_points(path)
    np.testing.assert_allclose(points, truth.points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(normals, truth.normals, rtol=0, atol=1e-6)
    assert cli.main(["synth", "fig9-pipe", "-o", str(tmp_path / "x.xyz"), "--step", "0.3"]) == 2
    assert "--step is an option of a simulated scan: add --scanner" in capsys.readouterr().err
    assert cli.main(["synth", "fig9-pipe", "-o", str(tmp_path / "x.xyz"), "--scanner", "--arc", "180"]) == 2
    assert "--arc does not apply to a simulated scan (--scanner)" in capsys.readouterr().err


def test_segments_trunks_and_poles_are_seeded_and_lie_on_their_truth():
    from canalsurf.refine import footpoints
    from canalsurf.synth import CASE_FAMILIES, make_pole_scan, make_segment, make_trunk, random_case

    seg = make_segment(length=4.0, cut=(45.0, 0.0), flare=(0.3, 0.0), noise=0.0, rng=5)
    assert np.array_equal(seg.points, make_segment(length=4.0, cut=(45.0, 0.0), flare=(0.3, 0.0), noise=0.0,
                                                   rng=5).points)
    t, d = footpoints(seg.points, seg.spine, seg.radius, closed=False)
    assert np.abs(d).max() < 1e-6
    # The points stop at the cuts: within the middle length + 2 radii of spine (a 45-degree cut reaches
    # one radius past its centre), and none near the overrun ends of the truth.
    length = np.linalg.norm(np.diff(seg.spine(np.linspace(0, 1, 2001)), axis=0), axis=1).sum()
    assert np.ptp(t) * length <= 4.0 + 2.0 + 1e-6 and t.min() > 0 and t.max() < 1
    trunk = make_trunk(n=3000, ground=0.5, rng=2)
    assert trunk.outlier.sum() > 1000 and np.abs(trunk.points[trunk.outlier, 2]).max() < 0.01
    assert trunk.radius(0.0) > 1.3 * trunk.radius(1.0)
    pole = make_pole_scan(points=1500, rng=3)
    assert np.allclose(pole.points / 0.01, np.round(pole.points / 0.01), atol=1e-6)
    assert 750 < (~pole.outlier).sum() < 3000
    for family in CASE_FAMILIES:
        assert np.array_equal(random_case(family, 7).points, random_case(family, 7).points)
    with pytest.raises(InputError, match="make_segment needs"):
        make_segment(cut=(70.0, 0.0))
