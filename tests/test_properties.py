"""Properties of reconstruct over random tubes, not just the named test surfaces.

A random tube is an open cubic spine interpolating a random walk with bounded turns (r * curvature
< 0.5, and parts of the spine more than four radii apart along it at least three radii apart in space),
a constant radius or one that varies slowly by up to a factor of two, uniform noise along the normals
and 800 - 3000 points sampled by area.

* Every such tube is either reconstructed within the accuracy bar of test_pipeline.py (spine mean and
  max closest-point distance, radius mean error) or refused with a one-line ReconstructionError --
  never another exception, never a hang; and refusals are rare.
* Moving and scaling the input moves and scales the model with it; rotating it rotates the model.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings, strategies as st
from scipy.interpolate import BSpline, make_interp_spline
from scipy.spatial.transform import Rotation

import canalsurf
from canalsurf.metrics import closest_point_distance, compare, radius_error
from canalsurf.spine import constant_spline
from canalsurf.synth import SyntheticTube, sample_tube
from conftest import time_limit

# The bar of test_pipeline.py, in shares of the mean true radius.
SPINE_MEAN, SPINE_MAX, RADIUS_MEAN = 0.03, 0.15, 0.015

#: Largest turn between consecutive legs of the walk, and the leg length in largest radii: turns of
#: 60 degrees give r * curvature up to about the 0.5 allowed, so the bound is actually exercised.
MAX_TURN_DEG = 60.0
LEG_PER_RADIUS = 4.0
MAX_RADIUS_CURVATURE = 0.5
#: Parts of the spine more than LEG_PER_RADIUS radii apart along it must be this many radii apart in
#: space: the tube must not come close to itself.
MIN_GAP_PER_RADIUS = 3.0
#: Noise half-width in shares of the mean radius, from noise-free scans on.
NOISE = (0.0, 0.05)
N_POINTS = (800, 3000)
#: A reconstruction of at most 3000 points takes seconds; far longer means it hangs.
TIME_LIMIT_S = 120
#: Examples per property: the file must stay within about a minute on two cores.
EXAMPLES = 25
INVARIANCE_EXAMPLES = 6

#: No shrinking: every step of it is a whole reconstruction (minutes for a failure), and the first
#: failing generator parameters, which hypothesis prints, reproduce the failure already.
SETTINGS = dict(deadline=None, derandomize=True, phases=[Phase.explicit, Phase.generate],
                suppress_health_check=[HealthCheck.too_slow])


def _spine(rng: np.random.Generator, legs: int, r_max: float) -> BSpline:
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    vertices = [np.zeros(3), LEG_PER_RADIUS * r_max * direction]
    for _ in range(legs - 1):
        axis = np.cross(direction, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        turn = rng.uniform(0.0, np.radians(MAX_TURN_DEG))
        direction = direction * np.cos(turn) + np.cross(axis, direction) * np.sin(turn)
        vertices.append(vertices[-1] + LEG_PER_RADIUS * r_max * direction)
    u = np.linspace(0.0, 1.0, len(vertices))  # legs are equally long: this is chord length
    return make_interp_spline(u, np.array(vertices), k=3)


def _radius(rng: np.random.Generator, canal: bool, ratio: float) -> BSpline:
    if not canal:
        return constant_spline(1.0)
    m = int(rng.integers(4, 7))
    v = rng.uniform(0.0, 1.0, m)
    v = (v - v.min()) / np.ptp(v)
    knots = np.r_[np.zeros(3), np.linspace(0.0, 1.0, m - 2), np.ones(3)]
    return BSpline(knots, 1.0 + (ratio - 1.0) * v, 3)


def _regular(spine: BSpline, radius: BSpline) -> bool:
    t = np.linspace(0.0, 1.0, 4001)
    d1, d2 = spine.derivative(1)(t), spine.derivative(2)(t)
    speed = np.linalg.norm(d1, axis=1)
    kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / speed**3
    r = radius(t)
    if (r * kappa).max() >= MAX_RADIUS_CURVATURE:
        return False
    pts = spine(t)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])[::8]
    far = np.abs(s[:, None] - s[None]) >= LEG_PER_RADIUS * r.max()
    gap = np.linalg.norm(pts[::8, None] - pts[None, ::8], axis=2)
    return bool(np.all(gap[far] >= MIN_GAP_PER_RADIUS * r.max()))


def random_tube(seed: int, legs: int, canal: bool, ratio: float, noise: float, n: int) -> SyntheticTube:
    """A seeded random tube: minimum radius 1, ``noise`` a share of the mean radius."""
    rng = np.random.default_rng(seed)
    r_max = ratio if canal else 1.0
    for _ in range(100):  # about one walk in six bends too sharply and is drawn again
        spine, radius = _spine(rng, legs, r_max), _radius(rng, canal, ratio)
        if _regular(spine, radius):
            break
    else:
        raise AssertionError(f"no regular tube drawn for seed {seed}")
    half_width = noise * float(np.mean(radius(np.linspace(0.0, 1.0, 1001))))
    points, normals = sample_tube(spine, radius, n, half_width, rng)
    return SyntheticTube("random", points, normals, spine, radius, False, half_width)


def attempt(points):
    """The model, or None if the points were refused with a proper one-line ReconstructionError.

    Any other exception propagates and fails the test.
    """
    try:
        with time_limit(TIME_LIMIT_S):
            return canalsurf.reconstruct(points)
    except canalsurf.ReconstructionError as exc:
        message = str(exc)
        assert message.strip(), "a refusal must say why"
        assert "\n" not in message, message
        return None


def misses_bar(model, tube) -> str | None:
    """Why the model fails the accuracy bar, or None if it meets it."""
    c = compare(model, tube)
    r = c["mean_radius"]
    for what, value, bar in (("spine mean", c["spine_mean"], SPINE_MEAN),
                             ("spine max", c["spine_max"], SPINE_MAX),
                             ("radius mean", c["radius"]["mean"], RADIUS_MEAN)):
        if value > bar * r:
            return f"{what} {value / r:.4f} r > {bar} r"
    return None


TUBES = dict(seed=st.integers(0, 2**32 - 1), legs=st.integers(3, 6), canal=st.booleans(),
             ratio=st.floats(1.0, 2.0), noise=st.floats(*NOISE), n=st.integers(*N_POINTS))


@settings(max_examples=EXAMPLES, **SETTINGS)
@given(**TUBES)
def test_random_tube_meets_the_bar_or_is_refused(seed, legs, canal, ratio, noise, n):
    tube = random_tube(seed, legs, canal, ratio, noise, n)
    model = attempt(tube.points)
    if model is not None:
        assert not model.closed
        assert misses_bar(model, tube) is None, misses_bar(model, tube)


def test_refusals_are_rare():
    # A pipeline that refuses everything passes the property above; it must not pass this.
    rng = np.random.default_rng(20240611)
    outcomes = []
    for _ in range(12):
        params = dict(seed=int(rng.integers(2**32)), legs=int(rng.integers(3, 7)),
                      canal=bool(rng.integers(2)), ratio=float(rng.uniform(1.0, 2.0)),
                      noise=float(rng.uniform(*NOISE)), n=int(rng.integers(N_POINTS[0], N_POINTS[1] + 1)))
        tube = random_tube(**params)
        model = attempt(tube.points)
        outcomes.append((params, "refused" if model is None else misses_bar(model, tube) or "ok"))
    assert all(o in ("ok", "refused") for _, o in outcomes), outcomes
    assert sum(o == "ok" for _, o in outcomes) >= 10, outcomes


@settings(max_examples=INVARIANCE_EXAMPLES, **SETTINGS)
@given(seed=TUBES["seed"], canal=st.booleans(), scale_exponent=st.integers(-3, 3),
       offset=st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=3))
def test_units_and_placement_do_not_matter(seed, canal, scale_exponent, offset):
    # A tube well inside the generator's range (and a canal far from pipe-or-canal ties): this is
    # about the transform, not the tube.
    tube = random_tube(seed, 4, canal, 1.6, 0.02, 1200)
    scale, offset = 10.0**scale_exponent, np.array(offset)
    a = attempt(tube.points)
    b = attempt(tube.points * scale + offset)
    assert (a is None) == (b is None)
    if a is None:
        return
    assert (a.kind, a.closed) == (b.kind, b.closed)
    pa, ra = a.sample(300)
    pb, rb = b.sample(300)
    # The input is centred and scaled first, so only rounding differs: the moved coordinates carry
    # |offset| * 2^-53 of absolute error, ~1e-7 of the radius at offset 1e6 and scale 1e-3, and the
    # models then differ by a few times that -- well inside 1e-6 of the tube's size.
    size = np.ptp(pa, axis=0).max()
    assert np.abs((pb - offset) / scale - pa).max() <= 1e-6 * size
    assert np.abs(rb / scale - ra).max() <= 1e-6 * ra.max()


@settings(max_examples=INVARIANCE_EXAMPLES, **SETTINGS)
@given(seed=TUBES["seed"], canal=st.booleans(), rotation=st.integers(0, 2**32 - 1))
def test_rotation_rotates_the_model(seed, canal, rotation):
    tube = random_tube(seed, 4, canal, 1.6, 0.02, 1200)
    Q = Rotation.random(random_state=rotation).as_matrix()
    a = attempt(tube.points)
    b = attempt(tube.points @ Q.T)
    assert (a is None) == (b is None)
    if a is None:
        return
    assert (a.kind, a.closed) == (b.kind, b.closed)
    back = BSpline(b.spine.t, b.spine.c @ Q, b.spine.k)
    r = a.mean_radius
    # Not equal to rounding: the voxel grids of thinning and ordering are axis-aligned, so a rotated
    # cloud starts the refinement from a slightly different spine (and may walk it the other way), and
    # the refinement stops at a tolerance.  The interior then agrees to ~1e-3 r; an open end, placed
    # only to within the accuracy bar, can settle up to ~0.1 r away.  Measured geometrically (closest
    # points), so that a reversed or re-parameterised spine is the same spine.
    cp = closest_point_distance(a.spine, back)
    assert cp["mean"] <= 0.005 * r, cp
    assert cp["max"] <= SPINE_MAX * r, cp
    rad = radius_error(a.spine, a.radius, back, b.radius)
    assert rad["mean"] <= 0.005 * r, rad


# Found by the property above: with noise far below the fit's own misfit, an outlier cut of three
# robust deviations called real points near the ends stray, and the ends came out up to 0.7 r off (or
# the tube was refused).  The cut now never falls below 3 % of the radius.
@pytest.mark.parametrize("params", [
    dict(seed=1835295431, legs=3, canal=True, ratio=1.4593358828854037, noise=0.00024939831659950243, n=1963),
    dict(seed=85137139, legs=6, canal=False, ratio=1.4851909744316352, noise=0.003922948799204955, n=1417),
    dict(seed=3117609497, legs=3, canal=False, ratio=1.5160685855478788, noise=0.0004634624498830813, n=2934),
], ids=["canal", "pipe", "pipe-was-refused"])
def test_nearly_noise_free_tubes_meet_the_bar(params):
    tube = random_tube(**params)
    model = attempt(tube.points)
    assert model is not None
    assert misses_bar(model, tube) is None, misses_bar(model, tube)
