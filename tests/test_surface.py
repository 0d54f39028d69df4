"""Tests of canalsurf.surface: meshes of pipe and canal surfaces against their analytic geometry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline, make_interp_spline
from scipy.optimize import brentq

from canalsurf.errors import InputError
from canalsurf.surface import MAX_RINGS, MIN_RINGS, surface_mesh
from canalsurf.synth import SURFACES, constant_spline

trimesh = pytest.importorskip("trimesh")

#: Positions that should agree to rounding (the mesh vertices are closed-form expressions).
EXACT = 1e-9


def _line(length: float, coefs=None) -> BSpline:
    """The segment from the origin to (0, 0, length); ``coefs`` reparametrizes it (quadratic)."""
    if coefs is None:
        return BSpline(np.array([0.0, 0, 1, 1]), np.array([[0, 0, 0], [0, 0, length]], float), 1)
    c = np.zeros((3, 3))
    c[:, 2] = np.asarray(coefs) * length
    return BSpline(np.array([0.0, 0, 0, 1, 1, 1]), c, 2)


def _trefoil(n: int = 201) -> BSpline:
    """A periodic spline through a trefoil knot: non-planar, so its rotation-minimizing frame does not close
    (it comes back turned by about 127 degrees)."""
    a = np.linspace(0, 2 * np.pi, n)
    xyz = np.column_stack([np.sin(a) + 2 * np.sin(2 * a), np.cos(a) - 2 * np.cos(2 * a), -np.sin(3 * a)])
    xyz[-1] = xyz[0]
    return make_interp_spline(a / (2 * np.pi), xyz, k=3, bc_type="periodic")


def _surface(name: str):
    spine_f, radius_f, closed, _, _ = SURFACES[name]
    return spine_f(), radius_f(), closed


def _mesh(vertices, faces):
    return trimesh.Trimesh(vertices, faces, process=False)


def _ring_parameters(spine, radius, rings: np.ndarray) -> np.ndarray:
    """The t of each ring, found independently of the mesher from the envelope condition.

    A point X lies on the characteristic circle of t iff |X - C(t)| = r(t) and
    g(X, t) = (X - C(t)) . C'(t) + r(t) r'(t) = 0 (the t-derivative of the sphere equation).  g is
    linear in X, so the ring's mean (the circle's centre) gives the same t; solve g = 0 near the
    sample whose circle centre C - r r' C' / |C'|^2 is closest.
    """
    d1, dr = spine.derivative(), radius.derivative()
    dense = np.linspace(0, 1, 2001)
    step = 3 * (dense[1] - dense[0])
    velocity = d1(dense)
    circle_centre = spine(dense) - (radius(dense) * dr(dense) / (velocity**2).sum(axis=1))[:, None] * velocity
    out = []
    for m in rings.mean(axis=1):
        near = dense[np.argmin(np.linalg.norm(circle_centre - m, axis=1))]

        def g(t, m=m):
            return (m - spine(t)) @ d1(t) + radius(t) * dr(t)

        # Open splines extrapolate smoothly past [0, 1], so the bracket may overhang the end rings.
        out.append(brentq(g, near - step, near + step, xtol=1e-15))
    return np.array(out)


def _boundary_loops(faces: np.ndarray) -> list[int]:
    """Edge counts of the loops formed by the edges that belong to only one face."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    boundary = unique[count == 1]
    nxt = {}
    for a, b in boundary:
        nxt.setdefault(a, []).append(b)
        nxt.setdefault(b, []).append(a)
    seen, loops = set(), []
    for start in nxt:
        if start in seen:
            continue
        size, stack = 0, [start]
        while stack:
            v = stack.pop()
            if v in seen:
                continue
            seen.add(v)
            size += 1
            stack.extend(nxt[v])
        loops.append(size)
    return loops


# --- a straight cylinder: the mesh is an exact polygonal prism -------------------------------------------

def test_cylinder_is_exact_prism():
    length, r, n_around = 10.0, 0.7, 24
    vertices, faces = surface_mesh(_line(length), constant_spline(r), n_around=n_around)
    mesh = _mesh(vertices, faces)
    assert mesh.is_watertight and mesh.is_winding_consistent
    prism = n_around / 2 * r**2 * np.sin(2 * np.pi / n_around) * length
    assert mesh.volume == pytest.approx(prism, rel=EXACT)  # positive: the normals point outward
    ring_vertices, centres = vertices[:-2], vertices[-2:]
    np.testing.assert_allclose(np.hypot(ring_vertices[:, 0], ring_vertices[:, 1]), r, atol=EXACT)
    np.testing.assert_allclose(centres, [[0, 0, 0], [0, 0, length]], atol=EXACT)
    # Default rule: spacing r / 2 = 0.35 -> ceil(10 / 0.35) = 29 intervals, 30 rings.
    assert len(ring_vertices) == 30 * n_around


def test_rings_are_even_in_arc_length_not_in_t():
    # z(t) = L (0.4 t + 0.6 t^2): speed grows 4-fold along the spine.
    length, n_along = 3.0, 40
    vertices, _ = surface_mesh(_line(length, [0, 0.2, 1]), constant_spline(0.1), n_around=8,
                               n_along=n_along, caps=False)
    z = vertices.reshape(n_along, 8, 3)[:, :, 2]
    np.testing.assert_allclose(z, np.linspace(0, length, n_along)[:, None] * np.ones(8), atol=EXACT * length)


@pytest.mark.parametrize(("length", "r", "rings"), [
    (10.0, 1.0, 21),          # ceil(10 / 0.5) + 1
    (1.0, 1.0, MIN_RINGS),    # 3 by the rule, raised to the minimum
    (100.0, 0.01, MAX_RINGS),  # 20001 by the rule, capped
])
def test_default_ring_count_follows_the_documented_rule(length, r, rings):
    vertices, _ = surface_mesh(_line(length), constant_spline(r), caps=False, n_around=4)
    assert len(vertices) == rings * 4


def test_default_ring_count_tightens_on_bends():
    # Torus spine: circle of radius 4, r = 1: spacing 0.5 * 1 / (1 + 1/4) = 0.4 over 8 pi -> 63 rings.
    spine, radius, closed = _surface("torus")
    vertices, _ = surface_mesh(spine, radius, closed=closed, n_around=4)
    assert len(vertices) == 63 * 4


# --- closed spines -----------------------------------------------------------------------------------------

def test_torus_volume_and_topology():
    spine, radius, closed = _surface("torus")
    vertices, faces = surface_mesh(spine, radius, closed=closed, n_around=64)
    mesh = _mesh(vertices, faces)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.euler_number == 0  # a torus, with no duplicate seam ring
    assert mesh.volume == pytest.approx(2 * np.pi**2 * 4.0 * 1.0**2, rel=0.01)
    assert len(np.unique(vertices.round(9), axis=0)) == len(vertices)


def test_closed_loop_spreads_the_leftover_twist_evenly():
    spine, n_around, n_along = _trefoil(), 16, 300
    vertices, faces = surface_mesh(spine, constant_spline(0.2), closed=True, n_around=n_around,
                                   n_along=n_along)
    mesh = _mesh(vertices, faces)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    rings = vertices.reshape(n_along, n_around, 3)
    # Per-ring frame read back from the mesh: N1 towards vertex 0, N2 towards vertex n_around/4.
    centre = rings.mean(axis=1)
    n1 = rings[:, 0] - centre
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    n2 = rings[:, n_around // 4] - centre
    n2 /= np.linalg.norm(n2, axis=1, keepdims=True)
    tangent = np.cross(n1, n2)
    # Twist of each step (the seam step last -> first included) relative to the minimal rotation taking
    # one tangent onto the next: the rotation-minimizing frame gives 0, the closing correction adds the
    # same small angle at every step, so the seam is no different from the rest.
    nxt = np.roll(np.arange(n_along), -1)
    axis = np.cross(tangent, tangent[nxt])
    sin, cos = np.linalg.norm(axis, axis=1), np.einsum("ij,ij->i", tangent, tangent[nxt])
    axis /= sin[:, None]
    moved = (n1 * cos[:, None] + np.cross(axis, n1) * sin[:, None]
             + axis * np.einsum("ij,ij->i", axis, n1)[:, None] * (1 - cos[:, None]))
    twist = np.arctan2(np.einsum("ij,ij->i", np.cross(moved, n1[nxt]), tangent[nxt]),
                       np.einsum("ij,ij->i", moved, n1[nxt]))
    assert abs(twist.mean()) > 1e-3  # the trefoil's frame really does need closing
    np.testing.assert_allclose(twist, twist.mean(), atol=1e-4)
    # And the edges joining the last ring to the first are as long as those one ring earlier.
    seam = np.linalg.norm(rings[0] - rings[-1], axis=1)
    before = np.linalg.norm(rings[-1] - rings[-2], axis=1)
    np.testing.assert_allclose(seam, before, rtol=0.05)


def test_rotation_minimizing_frame_does_not_twist_on_a_helix():
    spine, radius, _ = _surface("helix")
    n_around = 16
    vertices, _ = surface_mesh(spine, radius, caps=False, n_around=n_around)
    rings = vertices.reshape(-1, n_around, 3)
    centre = rings.mean(axis=1)
    n1 = rings[:, 0] - centre
    n1 /= np.linalg.norm(n1, axis=1, keepdims=True)
    tangent = spine.derivative()(_ring_parameters(spine, radius, rings))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    # The component of dN1 along N2 = T x N1 integrates to the frame's twist about the spine; the Frenet
    # frame of this helix would turn by its total torsion, about 2.6 rad.
    mid_n2 = np.cross(tangent[:-1] + tangent[1:], n1[:-1] + n1[1:]) / 4
    twist = np.einsum("ij,ij->i", n1[1:] - n1[:-1], mid_n2)
    assert abs(twist.sum()) < 0.01


# --- canal surfaces: the envelope, not circles of radius r -------------------------------------------------

@pytest.mark.parametrize("name", ["fig14-canal", "fig16-canal"])
def test_canal_vertices_lie_on_the_characteristic_circles(name):
    spine, radius, _ = _surface(name)
    n_around = 64
    vertices, faces = surface_mesh(spine, radius, caps=False, n_around=n_around)
    rings = vertices.reshape(-1, n_around, 3)
    t = _ring_parameters(spine, radius, rings)
    offset = rings - spine(t)[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(offset, axis=2), radius(t)[:, None] * np.ones(n_around),
                               rtol=EXACT)
    envelope = (np.einsum("ijk,ik->ij", offset, spine.derivative()(t))
                + (radius(t) * radius.derivative()(t))[:, None])
    np.testing.assert_allclose(envelope, 0, atol=EXACT * np.abs(radius(t)).max() ** 2)

    # The analytic envelope normal (X - C) / r is the mesh's normal (boundary rings left out: one-sided).
    analytic = offset / radius(t)[:, None, None]
    mesh_normal = _mesh(vertices, faces).vertex_normals.reshape(rings.shape)
    cos = np.einsum("ijk,ijk->ij", analytic, mesh_normal)[1:-1]
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 3.0


def test_canal_is_watertight_with_caps():
    spine, radius, _ = _surface("fig16-canal")
    mesh = _mesh(*surface_mesh(spine, radius))
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0


# --- orientation and mesh hygiene, on every synthetic surface ----------------------------------------------

@pytest.mark.parametrize("name", list(SURFACES))
def test_faces_point_away_from_the_spine(name):
    spine, radius, closed = _surface(name)
    n_around = 16
    vertices, faces = surface_mesh(spine, radius, closed=closed, n_around=n_around)
    n_ring_vertices = len(vertices) - (0 if closed else 2)
    rings = vertices[:n_ring_vertices].reshape(-1, n_around, 3)
    t = _ring_parameters(spine, radius, rings)
    centres = np.concatenate([spine(t).repeat(n_around, axis=0), vertices[n_ring_vertices:]])
    mesh = _mesh(vertices, faces)
    tube = (faces < n_ring_vertices).all(axis=1)
    # Each face's spine point: the mean of its vertices' ring centres.
    away = mesh.triangles_center[tube] - centres[faces[tube]].mean(axis=1)
    outward = np.einsum("ij,ij->i", mesh.face_normals[tube], away) > 0
    # Where the radius exceeds the spine's radius of curvature (fig15-pipe: r kappa up to 1.05, see
    # synth) the surface itself folds through the spine; only there may a face point inward.
    d1, d2 = spine.derivative()(t), spine.derivative(2)(t)
    r_kappa = radius(t) * np.linalg.norm(np.cross(d1, d2), axis=1) / np.linalg.norm(d1, axis=1) ** 3
    folded = (r_kappa >= 1)[faces[tube] // n_around].any(axis=1)
    assert outward[~folded].all()
    assert outward.mean() > 0.999
    if not closed:
        # Caps face backwards at t = 0 and forwards at t = 1.
        ends = spine.derivative()(np.array([0.0, 1.0]))
        cap_normals = mesh.face_normals[~tube]
        first = faces[~tube, 0] == n_ring_vertices
        assert (cap_normals[first] @ ends[0] < 0).all() and (cap_normals[~first] @ ends[1] > 0).all()


@pytest.mark.parametrize("name", list(SURFACES))
def test_no_degenerate_faces_or_duplicate_vertices(name):
    spine, radius, closed = _surface(name)
    vertices, faces = surface_mesh(spine, radius, closed=closed)
    assert vertices.dtype == np.float64 and faces.dtype == np.int64
    assert vertices.shape[1] == 3 and faces.shape[1] == 3
    mesh = _mesh(vertices, faces)
    assert mesh.area_faces.min() > 1e-6 * mesh.area_faces.mean()
    assert len(np.unique(vertices.round(9), axis=0)) == len(vertices)
    assert set(np.unique(faces)) == set(range(len(vertices)))  # every vertex used
    assert mesh.is_watertight and mesh.is_winding_consistent


def test_without_caps_the_mesh_is_open_with_two_boundary_loops():
    spine, radius, _ = _surface("fig9-pipe")
    vertices, faces = surface_mesh(spine, radius, caps=False, n_around=20)
    assert not _mesh(vertices, faces).is_watertight
    assert _boundary_loops(faces) == [20, 20]


def test_caps_are_ignored_for_a_closed_spine():
    spine, radius, _ = _surface("torus")
    with_caps = surface_mesh(spine, radius, closed=True, caps=True, n_around=8)
    without = surface_mesh(spine, radius, closed=True, caps=False, n_around=8)
    np.testing.assert_array_equal(with_caps[0], without[0])
    np.testing.assert_array_equal(with_caps[1], without[1])


@pytest.mark.parametrize(("shift", "scale"), [((1.5, -2.0, 7.0), 1.0), ((0.0, 0.0, 0.0), 3.5),
                                              ((-4.0, 0.5, 0.25), 0.2)])
def test_mesh_moves_and_scales_with_its_surface(shift, scale):
    spine, radius, _ = _surface("fig14-canal")
    vertices, faces = surface_mesh(spine, radius, n_around=12)
    moved_spine = BSpline(spine.t, spine.c * scale + np.asarray(shift), spine.k)
    scaled_radius = BSpline(radius.t, radius.c * scale, radius.k)
    moved, moved_faces = surface_mesh(moved_spine, scaled_radius, n_around=12)
    np.testing.assert_array_equal(moved_faces, faces)
    np.testing.assert_allclose(moved, vertices * scale + np.asarray(shift), atol=EXACT * 10 * scale)


# --- bad input ---------------------------------------------------------------------------------------------

def test_radius_faster_than_spine_has_no_envelope():
    # r grows by 2 over a spine of length 1: |dr/ds| = 2.
    radius = BSpline(np.array([0.0, 0, 1, 1]), np.array([1.0, 3.0]), 1)
    with pytest.raises(InputError, match=r"radius changes faster than the spine .* no envelope"):
        surface_mesh(_line(1.0), radius)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"n_around": 2}, r"n_around must be an integer >= 3, got 2"),
    ({"n_around": 8.5}, r"n_around must be an integer >= 3, got 8.5"),
    ({"n_along": 1}, r"n_along must be an integer >= 2, got 1"),
    ({"closed": True}, r"closed=True but the spine's ends are 2 apart"),
])
def test_bad_parameters_raise(kwargs, message):
    with pytest.raises(InputError, match=message):
        surface_mesh(_line(2.0), constant_spline(0.5), **kwargs)


def test_bad_splines_raise():
    with pytest.raises(InputError, match=r"radius must be positive on \[0, 1\], got a minimum of -0.5"):
        surface_mesh(_line(2.0), constant_spline(-0.5))
    with pytest.raises(InputError, match=r"spine must have values of shape \(3,\), got \(2,\)"):
        surface_mesh(BSpline(np.array([0.0, 0, 1, 1]), np.eye(2), 1), constant_spline(1.0))
    with pytest.raises(InputError, match=r"spine stops"):
        surface_mesh(BSpline(np.array([0.0, 0, 1, 1]), np.ones((2, 3)), 1), constant_spline(1.0))
    with pytest.raises(InputError, match=r"radius must be a scipy.interpolate.BSpline, got float"):
        surface_mesh(_line(2.0), 1.0)
