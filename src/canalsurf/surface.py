"""Triangle meshes of pipe and canal surfaces.

A canal surface is the envelope of the spheres of radius r(t) centred on the spine C(t).  At each
parameter t the envelope touches its sphere along a *characteristic circle*: with unit tangent
T = C'/|C'| and rho = r'(t)/|C'(t)| (the rate dr/ds of the radius per unit spine arc length), the
surface point at angle s is

    A(s, t) = C(t) + r(t) n(s, t),   n = -rho T + sqrt(1 - rho**2) (cos(s) N1 + sin(s) N2),

where n is also the outward unit normal.  A pipe is the special case rho = 0.  The frame (N1, N2) is
rotation-minimizing (double reflection, Wang, Juettler, Zheng & Liu, "Computation of rotation
minimizing frames", ACM TOG 27(1), 2008), so the mesh does not twist around the spine.
"""

from __future__ import annotations

import operator

import numpy as np
from scipy.interpolate import BSpline, CubicHermiteSpline

from .errors import InputError

__all__ = ["surface_mesh"]

#: Default number of vertices on each ring; 32 keeps the polygon's area within 0.7 % of the circle's.
DEFAULT_N_AROUND = 32
#: Default ring spacing as a fraction of the smallest "outer-side radius" r / (1 + r kappa): half the
#: radius on a straight stretch, less on bends where the outer side of the tube is stretched by 1 + r kappa.
ALONG_SPACING_FRACTION = 0.5
#: Bounds on the default number of rings: at least enough to follow a short spine's shape, at most
#: enough to keep meshes of long thin tubes at a few hundred thousand triangles.
MIN_RINGS = 16
MAX_RINGS = 2000
#: Arc length is integrated on each knot span split into at least this many pieces (and on at least
#: ``ARC_PIECES_MIN`` pieces in all), with Gauss-Legendre nodes per piece: far below rounding for
#: the smooth pieces of a B-spline, so the rings sit evenly in arc length to ~1e-12 of the length.
ARC_PIECES_PER_SPAN = 8
ARC_PIECES_MIN = 1024
ARC_GAUSS_NODES = 4
#: Newton steps on the arc-length equation S(t) = s from a linear first guess; quadratic convergence
#: makes three ample.
ARC_NEWTON_STEPS = 3
#: A spine whose speed |C'| falls below this fraction of its length has a cusp or stationary point
#: and no tangent there.
MIN_RELATIVE_SPEED = 1e-9
#: A closed spine's ends (and radii) may differ by this fraction of the spine length (rounding in a fit).
CLOSED_GAP_TOL = 1e-6
#: Most vertices a mesh may have.  Building one takes about 200 bytes per vertex at its peak (float64
#: coordinates, frames and normals per ring and angle, two int64 triangles), so 50 million is ~10 GB,
#: the most a workstation can hold; the default rule gives at most MAX_RINGS x 32 = 64,000.
MAX_MESH_VERTICES = 50_000_000


def surface_mesh(spine: BSpline, radius: BSpline, *, closed: bool = False, caps: bool = True,
                 n_around: int | None = None, n_along: int | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the pipe or canal surface of a spine and a radius function.

    Parameters
    ----------
    spine : scipy.interpolate.BSpline
        The spine C(t), 3-D valued, evaluated on t in [0, 1].  Its speed |C'| must not vanish.
    radius : scipy.interpolate.BSpline
        The radius r(t) > 0 on [0, 1] (a pipe: :func:`canalsurf.synth.constant_spline`).  It must
        change more slowly than the spine advances, |dr/ds| < 1, or the spheres have no envelope.
    closed : bool
        The spine is a loop with C(0) = C(1) (C1 across the join); the last ring is joined to the
        first and the surface is a torus-like closed mesh without caps.
    caps : bool
        For an open spine, close each end with a fan of triangles to the centre of its end
        characteristic circle, so the mesh is watertight.  Ignored when ``closed``.
    n_around : int, optional
        Vertices per ring (>= 3).  Default ``DEFAULT_N_AROUND`` = 32.  The polygonal cross-section
        holds a fraction ``n sin(2 pi / n) / (2 pi)`` of the circle's area (99.4 % for 32, 99.8 %
        for 64); raise it for smoother renders or volume estimates.
    n_along : int, optional
        Number of rings (>= 2 open, >= 3 closed), placed evenly in arc length.  ``n_around * n_along``
        may not exceed ``MAX_MESH_VERTICES`` = 50 million.  Default: the spine
        length divided by ``ALONG_SPACING_FRACTION * min(r / (1 + r kappa))`` over the spine
        (kappa the curvature), rounded up, clipped to [``MIN_RINGS``, ``MAX_RINGS``] = [16, 2000]:
        rings about half a radius apart, closer on tight bends so that the outer side of the tube
        is sampled as finely as a straight stretch.

    Returns
    -------
    vertices : ndarray, shape (V, 3), float64
        Ring by ring in order of increasing t, ``n_around`` vertices per ring (ring ``i`` vertex ``j``
        at row ``i * n_around + j``, angle ``s = 2 pi j / n_around``); an open capped mesh then
        has the centre of the start cap and of the end cap as its last two rows.
    faces : ndarray, shape (F, 3), int64
        Triangles, counter-clockwise seen from outside (normals point outward).

    Raises
    ------
    InputError
        Bad sizes (or more than ``MAX_MESH_VERTICES`` vertices), a spine that is not 3-D or stops
        (C' = 0), a radius that is not positive, a closed spine whose ends do not meet, or
        |dr/ds| >= 1 (no envelope).

    Notes
    -----
    The mesh is the surface as given: where the radius exceeds the radius of curvature of the spine
    (r kappa >= 1) the tube folds through itself and the mesh self-intersects.

    Examples
    --------
    >>> from canalsurf.synth import make_tube
    >>> tube = make_tube("torus")
    >>> vertices, faces = surface_mesh(tube.spine, tube.radius, closed=True, n_around=16)
    >>> vertices.shape[1], faces.dtype
    (3, dtype('int64'))
    """
    n_around = _count(DEFAULT_N_AROUND if n_around is None else n_around, "n_around", 3)
    if n_along is not None:
        n_along = _count(n_along, "n_along", 3 if closed else 2)
    # Checked before anything is allocated, with the fewest rings the default rule can give.
    _check_size(n_around, MIN_RINGS if n_along is None else n_along)
    _check_spline(spine, "spine", ((3,),))
    _check_spline(radius, "radius", ((), (1,)))
    grid, arc, speed_grid = _arc_length_table(spine)
    length = float(arc[-1])
    _check_inputs(spine, radius, closed, grid, speed_grid, length)

    if n_along is None:
        n_along = _default_rings(spine, radius, grid, closed, length)
        _check_size(n_around, n_along)
    # A closed loop also gets the ring at s = L (= the first ring) to measure the frame's leftover twist.
    n_steps = n_along if closed else n_along - 1
    s_target = np.linspace(0.0, length, n_steps + 1)
    t = _invert_arc_length(spine, grid, arc, speed_grid, s_target)

    d1 = spine.derivative(1)(t)
    speed = np.linalg.norm(d1, axis=1)
    tangent = d1 / speed[:, None]
    r = _scalar(radius, t)
    rho = _derivative(radius, t) / speed
    if np.any(np.abs(rho) >= 1):
        _raise_no_envelope(rho, t)

    centre = spine(t)
    n1 = _rotation_minimizing_frame(centre, tangent)
    if closed:
        n1 = _close_frame(n1, tangent)
        t, centre, tangent, r, rho, n1 = t[:-1], centre[:-1], tangent[:-1], r[:-1], rho[:-1], n1[:-1]
    n2 = np.cross(tangent, n1)

    angle = 2 * np.pi * np.arange(n_around) / n_around
    around = (np.cos(angle)[None, :, None] * n1[:, None, :]
              + np.sin(angle)[None, :, None] * n2[:, None, :])
    normal = -rho[:, None, None] * tangent[:, None, :] + np.sqrt(1 - rho**2)[:, None, None] * around
    vertices = (centre[:, None, :] + r[:, None, None] * normal).reshape(-1, 3)

    faces = _tube_faces(len(t), n_around, closed)
    if caps and not closed:
        # Centres of the end characteristic circles: C - r rho T.
        ends = centre[[0, -1]] - (r * rho)[[0, -1], None] * tangent[[0, -1]]
        faces = np.concatenate([faces, _cap_faces(len(t), n_around, len(vertices))])
        vertices = np.concatenate([vertices, ends])
    return np.ascontiguousarray(vertices, dtype=np.float64), faces.astype(np.int64)


def _count(value, name: str, minimum: int) -> int:
    """``value`` as an int >= ``minimum``, or raise :class:`InputError`."""
    try:
        n = operator.index(value)
    except TypeError:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}") from None
    if n < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {n}")
    return n


def _check_size(n_around: int, n_along: int) -> None:
    """Raise :class:`InputError` if the mesh would have more than ``MAX_MESH_VERTICES`` vertices."""
    if n_around * n_along > MAX_MESH_VERTICES:
        raise InputError(f"a mesh of {n_along:,} rings of {n_around:,} vertices would have "
                         f"{n_around * n_along:.3g} vertices, more than the {MAX_MESH_VERTICES:,} that fit in "
                         "memory — give a smaller n_along or n_around")


def _scalar(spline: BSpline, t: np.ndarray) -> np.ndarray:
    """Values of a scalar spline as a 1-D array (a radius stored with shape (n, 1) also works)."""
    return np.asarray(spline(t), dtype=np.float64).reshape(len(t), -1)[:, 0]


def _derivative(spline: BSpline, t: np.ndarray) -> np.ndarray:
    """First derivative of a scalar spline; zero for a piecewise-constant one (degree 0 has none)."""
    if spline.k < 1:
        return np.zeros(len(t))
    return _scalar(spline.derivative(1), t)


def _arc_length_table(spine: BSpline) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid of t on [0, 1], cumulative arc length there, and the speed |C'| there."""
    knots = np.unique(np.clip(np.asarray(spine.t, dtype=np.float64), 0.0, 1.0))
    knots = np.union1d(knots, [0.0, 1.0])
    pieces = max(ARC_PIECES_PER_SPAN, -(-ARC_PIECES_MIN // (len(knots) - 1)))
    # Split each knot span evenly so no Gauss piece straddles a knot (where the spine is less smooth).
    frac = np.arange(pieces) / pieces
    grid = np.append((knots[:-1, None] + np.diff(knots)[:, None] * frac).ravel(), 1.0)
    nodes, weights = np.polynomial.legendre.leggauss(ARC_GAUSS_NODES)
    h = np.diff(grid)
    tq = grid[:-1, None] + h[:, None] * (nodes + 1) / 2
    d1 = spine.derivative(1)
    speed_q = np.linalg.norm(d1(tq.ravel()), axis=1).reshape(tq.shape)
    arc = np.concatenate([[0.0], np.cumsum(h / 2 * (speed_q @ weights))])
    return grid, arc, np.linalg.norm(d1(grid), axis=-1)


def _check_spline(spline, name: str, shapes: tuple[tuple[int, ...], ...]) -> None:
    """Raise :class:`InputError` unless ``spline`` is a BSpline whose values have one of ``shapes``."""
    if not isinstance(spline, BSpline):
        raise InputError(f"{name} must be a scipy.interpolate.BSpline, got {type(spline).__name__}")
    shape = np.asarray(spline(0.5)).shape
    if shape not in shapes:
        raise InputError(f"{name} must have values of shape {' or '.join(map(str, shapes))}, got {shape}")
    if name == "spine" and spline.k < 1:
        raise InputError("spine must be a BSpline of degree >= 1 (a continuous curve), got degree 0")


def _check_inputs(spine, radius, closed, grid, speed, length) -> None:
    """Raise :class:`InputError` for a spine or radius on which no tube can be built."""
    if not np.isfinite(length) or length <= 0 or speed.min() <= MIN_RELATIVE_SPEED * length:
        where = grid[int(np.argmin(speed))]
        raise InputError(f"spine stops (C'(t) = 0 near t = {where:.4g}): its tangent is undefined there")
    r = _scalar(radius, grid)
    if not np.all(np.isfinite(r)) or r.min() <= 0:
        raise InputError(f"radius must be positive on [0, 1], got a minimum of {r.min():.4g}")
    if closed:
        gap = np.linalg.norm(spine(1.0) - spine(0.0))
        if gap > CLOSED_GAP_TOL * length or abs(r[-1] - r[0]) > CLOSED_GAP_TOL * length:
            raise InputError(f"closed=True but the spine's ends are {gap:.4g} apart and the radii "
                             f"{r[0]:.6g} and {r[-1]:.6g}: C(0) must equal C(1) and r(0) equal r(1)")
    rho = _derivative(radius, grid) / speed
    if np.any(np.abs(rho) >= 1):
        _raise_no_envelope(rho, grid)


def _raise_no_envelope(rho: np.ndarray, t: np.ndarray) -> None:
    worst = int(np.argmax(np.abs(rho)))
    raise InputError(f"radius changes faster than the spine (|dr/ds| = {abs(rho[worst]):.4g} >= 1 "
                     f"at t = {t[worst]:.4g}): no envelope")


def _default_rings(spine, radius, grid, closed, length) -> int:
    """Ring count from the documented rule (see :func:`surface_mesh`, parameter ``n_along``)."""
    d1 = spine.derivative(1)(grid)
    d2 = spine.derivative(2)(grid) if spine.k >= 2 else np.zeros_like(d1)
    speed = np.linalg.norm(d1, axis=1)
    kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / speed**3
    r = _scalar(radius, grid)
    spacing = ALONG_SPACING_FRACTION * float(np.min(r / (1 + r * kappa)))
    intervals = int(np.ceil(length / spacing))
    rings = intervals if closed else intervals + 1
    return int(np.clip(rings, MIN_RINGS, MAX_RINGS))


def _invert_arc_length(spine, grid, arc, speed, s_target) -> np.ndarray:
    """Parameters t at which the arc length from t = 0 equals ``s_target``."""
    # Hermite interpolation of S(t) with its exact slope |C'| is 4th-order accurate between grid
    # points; Newton on it then places the rings at the requested arc lengths to rounding.
    arc_of_t = CubicHermiteSpline(grid, arc, speed)
    d1 = spine.derivative(1)
    t = np.interp(s_target, arc, grid)
    for _ in range(ARC_NEWTON_STEPS):
        t = np.clip(t - (arc_of_t(t) - s_target) / np.linalg.norm(d1(t), axis=1), 0.0, 1.0)
    # The ends are exact by construction; keep them so (a closed loop's last ring must be at t = 1).
    t[0], t[-1] = 0.0, 1.0
    return t


def _rotation_minimizing_frame(points: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """First normal N1 of the double-reflection rotation-minimizing frame at each point.

    The recurrence is sequential by nature; it is the one loop over the rings.
    """
    # Start from the coordinate axis least aligned with the tangent: any normal works, this one is
    # well conditioned and deterministic.
    helper = np.zeros(3)
    helper[np.argmin(np.abs(tangent[0]))] = 1.0
    r = helper - (helper @ tangent[0]) * tangent[0]
    frame = np.empty_like(points)
    frame[0] = r / np.linalg.norm(r)
    for i in range(len(points) - 1):
        # Reflect in the bisecting plane of the chord, then in the plane that takes the reflected
        # tangent onto the next tangent: the composition rotates the frame with no twist to O(h^4).
        v1 = points[i + 1] - points[i]
        c1 = v1 @ v1
        r_l = frame[i] - (2 / c1) * (v1 @ frame[i]) * v1
        t_l = tangent[i] - (2 / c1) * (v1 @ tangent[i]) * v1
        v2 = tangent[i + 1] - t_l
        c2 = v2 @ v2
        r_next = r_l - (2 / c2) * (v2 @ r_l) * v2 if c2 > 0 else r_l
        # Reflections preserve orthonormality; re-project only to stop rounding drift over many rings.
        r_next -= (r_next @ tangent[i + 1]) * tangent[i + 1]
        frame[i + 1] = r_next / np.linalg.norm(r_next)
    return frame


def _close_frame(n1: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """Spread a closed loop's leftover twist evenly so the frame at s = L equals the one at s = 0."""
    # The rotation-minimizing frame generally comes back rotated (holonomy); the angle that rotates it
    # onto the first frame about the (shared) tangent is added in equal steps along the rings, which
    # are evenly spaced in arc length.
    end, start, axis = n1[-1], n1[0], tangent[0]
    leftover = np.arctan2(np.cross(end, start) @ axis, end @ start)
    theta = leftover * np.arange(len(n1)) / (len(n1) - 1)
    rotated = np.cos(theta)[:, None] * n1 + np.sin(theta)[:, None] * np.cross(tangent, n1)
    rotated[-1] = rotated[0]
    return rotated


def _tube_faces(n_rings: int, n_around: int, closed: bool) -> np.ndarray:
    """Two triangles per quad between consecutive rings, outward for a right-handed (N1, N2, T)."""
    ring = np.arange(n_rings if closed else n_rings - 1)
    nxt_ring = (ring + 1) % n_rings
    j = np.arange(n_around)
    nxt_j = (j + 1) % n_around
    a = ring[:, None] * n_around + j            # (i, j)
    b = ring[:, None] * n_around + nxt_j        # (i, j+1)
    c = nxt_ring[:, None] * n_around + nxt_j    # (i+1, j+1)
    d = nxt_ring[:, None] * n_around + j        # (i+1, j)
    # (b - a) runs around the spine (T x n), (d - a) along it (T); their cross product is outward.
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                           np.stack([a, c, d], -1).reshape(-1, 3)])


def _cap_faces(n_rings: int, n_around: int, first_centre: int) -> np.ndarray:
    """Fans from the two end centres (rows ``first_centre`` and ``first_centre + 1``) to the end rings."""
    j = np.arange(n_around)
    nxt_j = (j + 1) % n_around
    last = (n_rings - 1) * n_around
    # The start cap faces -T, so its fan runs clockwise about T; the end cap faces +T.
    start = np.column_stack([np.full(n_around, first_centre), nxt_j, j])
    end = np.column_stack([np.full(n_around, first_centre + 1), last + j, last + nxt_j])
    return np.concatenate([start, end])
