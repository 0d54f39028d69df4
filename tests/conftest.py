"""Shared, seeded ground truth for the stage tests.

Everything here is written independently of ``canalsurf`` (no stage code is reused to build the truth):

* :func:`random_cloud` -- seeded points with unit normals and no shape, for the file formats;
* :func:`cylinder` -- points on a straight circular cylinder (or an arc of it) with exact outward normals;
* :func:`envelope` -- points on the canal surface of a given spine and radius at *given* parameters, with
  their exact normals, so a test knows the generating ``t`` of every point;
* :func:`curve_distance` / :func:`envelope_distance` -- slow, obvious brute-force references: distance
  to a curve by a dense polyline, and ``min_t |P - C(t)| - r(t)`` (the signed distance to an envelope
  of spheres) by a dense parameter grid.

The helpers are served by fixtures of the same name so test modules need not import this file.
"""

from __future__ import annotations

import contextlib
import signal

import numpy as np
import pytest
from scipy.spatial import cKDTree

#: Seed of every generated cloud (the tests must not depend on the global RNG).
SEED = 20240611
#: Paper-sized clouds.
N_POINTS = 2000
#: Samples of the dense reference polylines (parameter step 5e-5).
N_DENSE = 20001


def cylinder(n: int = N_POINTS, *, radius: float = 1.0, length: float = 10.0, noise: float = 0.0,
             arc: float = 2 * np.pi, seed: int = SEED):
    """Points on the cylinder ``x^2 + y^2 = radius^2, 0 <= z <= length`` with exact outward normals.

    ``arc`` < 2 pi gives a one-sided scan (the angles ``[0, arc)`` only).  ``noise`` is the half-width of
    a uniform offset along the normal.

    Returns
    -------
    points, normals : ndarray, shape (n, 3)
    z, s : ndarray, shape (n,)
        Height and angle of each point.
    """
    rng = np.random.default_rng(seed)
    z = rng.uniform(0.0, length, n)
    s = rng.uniform(0.0, arc, n)
    normals = np.column_stack([np.cos(s), np.sin(s), np.zeros(n)])
    rho = radius + (rng.uniform(-noise, noise, n) if noise > 0 else 0.0)
    points = normals * np.reshape(rho, (-1, 1)) + np.column_stack([np.zeros(n), np.zeros(n), z])
    return points, normals, z, s


def envelope(spine, radius, t, s, offset=0.0):
    """Points of the canal surface (envelope of the spheres ``|X - C(t)| = r(t)``) at parameters ``(t, s)``.

    The characteristic circle of ``t`` has centre ``C - r r' C' / |C'|^2`` and its points have the unit
    normal ``-rho T + sqrt(1 - rho^2) (cos s e1 + sin s e2)`` with ``rho = r' / |C'|``; ``offset`` moves
    each point along that normal.

    Returns
    -------
    points, normals : ndarray, shape (len(t), 3)
    """
    t = np.asarray(t, float)
    s = np.asarray(s, float)
    velocity = spine.derivative()(t)
    speed = np.linalg.norm(velocity, axis=1)
    tangent = velocity / speed[:, None]
    rho = radius.derivative()(t) / speed
    assert np.all(np.abs(rho) < 1), "no envelope: the radius changes faster than the spine advances"
    axis = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])  # any direction off the tangents
    e1 = np.cross(tangent, axis)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(tangent, e1)
    normal = (-rho[:, None] * tangent
              + np.sqrt(1 - rho**2)[:, None] * (np.cos(s)[:, None] * e1 + np.sin(s)[:, None] * e2))
    return spine(t) + (radius(t) + offset)[:, None] * normal, normal


def dense_curve(curve, n: int = N_DENSE, a: float = 0.0, b: float = 1.0):
    """Parameters, points and cumulative chord length of ``n`` samples of ``curve`` on [a, b]."""
    t = np.linspace(a, b, n)
    pts = curve(t)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return t, pts, s


def curve_distance(points, curve, n: int = N_DENSE):
    """Distance of each point to ``curve`` (a callable on [0, 1]) and the arc length of its nearest sample."""
    _, pts, s = dense_curve(curve, n)
    dist, j = cKDTree(pts).query(np.asarray(points, float))
    return dist, s[j]


def envelope_distance(points, spine, radius, *, closed: bool = False, n: int = 1001, refine: int = 401,
                      chunk: int = 500):
    """Brute force ``min_t (|P - C(t)| - r(t))`` over t in [0, 1], and the minimising t.

    For a point near a regular canal surface this is its signed distance from the surface.  Every point
    is compared with ``n`` spine samples, then with ``refine`` samples across the two grid steps either
    side of the best one (a final step of 1e-5 in t, so the minimum is exact to about 1e-6 on the
    paper's surfaces).  ``closed`` wraps the parameter around (a periodic spine), else it is clamped.
    """
    points = np.asarray(points, float)
    grid = np.linspace(0.0, 1.0, n)
    centres, radii = spine(grid), radius(grid)
    best_t = np.empty(len(points))
    c2 = (centres**2).sum(axis=1)
    for lo in range(0, len(points), chunk):
        p = points[lo:lo + chunk]
        sq = (p**2).sum(axis=1)[:, None] + c2[None] - 2.0 * p @ centres.T
        f = np.sqrt(np.maximum(sq, 0.0)) - radii[None]
        best_t[lo:lo + chunk] = grid[np.argmin(f, axis=1)]
    h = 2.0 / (n - 1)
    t = best_t[:, None] + np.linspace(-h, h, refine)[None]  # (N, refine)
    t = np.mod(t, 1.0) if closed else np.clip(t, 0.0, 1.0)
    f = np.linalg.norm(points[:, None, :] - spine(t), axis=2) - radius(t)
    j = np.argmin(f, axis=1)
    rows = np.arange(len(points))
    return f[rows, j], t[rows, j]


def angle_deg(a, b):
    """Unsigned angle between the lines of corresponding unit rows of ``a`` and ``b``, in degrees."""
    dot = np.abs(np.einsum("ij,ij->i", a, b))
    return np.degrees(np.arccos(np.clip(dot, 0.0, 1.0)))


def random_cloud(n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` seeded points with unit normals, no shape, coordinates of order 10 (so float32 rounding
    shows): for the file readers and writers."""
    rng = np.random.default_rng(SEED)
    points = rng.normal(scale=10.0, size=(n, 3))
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return points, normals


@pytest.fixture(name="random_cloud")
def random_cloud_fixture():
    """:func:`random_cloud`."""
    return random_cloud


@pytest.fixture(name="cylinder")
def cylinder_fixture():
    """:func:`cylinder` (a factory: call it with the wanted size, noise and seed)."""
    return cylinder


@contextlib.contextmanager
def time_limit(seconds: float):
    """Turn a hang into a failure: ``TimeoutError`` once the block has run ``seconds`` (where the
    platform has interval timers)."""
    if not hasattr(signal, "setitimer"):
        yield
        return

    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@pytest.fixture(name="time_limit")
def time_limit_fixture():
    """:func:`time_limit`."""
    return time_limit


@pytest.fixture(name="envelope")
def envelope_fixture():
    """:func:`envelope`."""
    return envelope


@pytest.fixture(name="curve_distance")
def curve_distance_fixture():
    """:func:`curve_distance`."""
    return curve_distance


@pytest.fixture(name="envelope_distance")
def envelope_distance_fixture():
    """:func:`envelope_distance`."""
    return envelope_distance


@pytest.fixture(name="dense_curve")
def dense_curve_fixture():
    """:func:`dense_curve`."""
    return dense_curve


@pytest.fixture(name="angle_deg")
def angle_deg_fixture():
    """:func:`angle_deg`."""
    return angle_deg


@pytest.fixture
def rng():
    """A fresh seeded generator per test."""
    return np.random.default_rng(SEED)
