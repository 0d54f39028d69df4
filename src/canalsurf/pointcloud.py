"""Operations on a point cloud before it is reconstructed: crop to a box, thin out on a voxel grid,
measure the typical spacing and the grid its coordinates were rounded to.

Each is a plain function on ``(N, 3)`` arrays that carries the optional normals along, so a cloud
read with :func:`canalsurf.read_points` can go through them and on to :func:`canalsurf.reconstruct`
unchanged in form.  None of them changes the caller's arrays.

Examples
--------
>>> import numpy as np
>>> from canalsurf.pointcloud import crop, point_spacing, voxel_downsample
>>> points = np.random.default_rng(0).uniform(0, 10, size=(1000, 3))
>>> inside, _ = crop(points, (0, 0, 0, 5, 10, 10))           # x <= 5: about half the points
>>> bool(400 < len(inside) < 600)
True
>>> coarse, _ = voxel_downsample(points, 2.5)                 # at most one point per 2.5-unit cube
>>> len(coarse) <= 4 ** 3
True
>>> bool(point_spacing(coarse) > point_spacing(points))
True
"""

from __future__ import annotations

import math

import numpy as np

from ._validate import as_table, positive
from .errors import InputError

__all__ = ["crop", "voxel_downsample", "point_spacing", "quantisation_noise", "SPACING_SAMPLE", "SPACING_SEED"]

#: Points whose nearest neighbour :func:`point_spacing` looks up by default: the median of 20,000
#: distances is within about 1 % of the median of all of them, and takes a fraction of a second.
SPACING_SAMPLE = 20_000
#: Seed of that sample, so the same file always gives the same spacing.
SPACING_SEED = 0
#: Neighbours looked at for the nearest point at a positive distance: duplicated points (a LAS file
#: rounds coordinates to its grid) would otherwise give a spacing of 0.
SPACING_NEIGHBOURS = 8
#: Largest voxel index :func:`voxel_downsample` handles (|coordinate| / size): beyond 2**52 a float64
#: coordinate no longer resolves one voxel from the next.
MAX_VOXEL_INDEX = 2.0**52

#: Coordinates of this many points (a seeded sample) are searched for a common grid step.
QUANTUM_SAMPLE = 5000
#: Steps between sorted distinct coordinates below this share of their range are rounding of
#: arithmetic (the normalisation), not a grid.
QUANTUM_RESOLUTION = 1e-9
#: Every coordinate must lie within this share of a step of the grid for the axis to count as gridded.
QUANTUM_TOLERANCE = 1e-3
#: A grid turned off the coordinate axes is searched for among this many points (the sample's
#: seeded superset): its neighbours must be close enough to share the grid's layers ...
TURNED_POINTS = 50_000
#: ... about this many of them, each with this many nearest neighbours.
TURNED_SEEDS = 2_000
TURNED_NEIGHBOURS = 8
#: Two neighbour differences in one layer of a grid span a plane whose normal is the grid's axis;
#: pairs closer to parallel than this sine of their angle give no normal worth counting.
TURNED_MIN_SINE = 0.3
#: Normals within this angle (radians) of one another count as one direction, among this many of
#: them (a seeded sample) ...
TURNED_CONE = 0.05
TURNED_NORMALS = 20_000
#: ... of which at most this many of the most frequent, each at least this far (radians) from
#: perpendicular to every axis found, are tried as an axis.
TURNED_TRIES = 6
TURNED_OFF_AXIS = math.radians(10.0)
#: A grid's points agree in phase along its axis: |mean exp(2 pi i p.u / q)| is 1 on an exact grid,
#: 0.82 for noise of a tenth of the step and near 0 for points off any grid; a scanner's rows of
#: points are as regular as a grid between neighbours, but drift in phase across the scan.
GRID_COHERENCE = 0.7
#: A step must be a share at least this large of the neighbour differences along the axis (the rest
#: lie in one layer), or every spread of values would be one step of a coarse enough grid.
GRID_MIN_SHARE = 0.1


def _as_cloud(points, normals) -> tuple[np.ndarray, np.ndarray | None]:
    """``points`` as a finite ``(N, 3)`` float64 array and ``normals`` (if any) of the same shape."""
    pts = as_table(points, "points")
    if not np.isfinite(pts).all():
        raise InputError("points contain NaN or inf — remove those rows first")
    if normals is None:
        return pts, None
    nrm = np.asarray(normals, dtype=np.float64)
    if nrm.shape != pts.shape:
        raise InputError(f"normals must have the shape of the points {pts.shape}, got {nrm.shape}")
    return pts, nrm


def _as_box(box) -> np.ndarray:
    """``box`` as a ``(2, 3)`` array of its lower and upper corner, checked."""
    try:
        values = np.asarray(box, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"box must be 6 numbers (xmin, ymin, zmin, xmax, ymax, zmax), got {box!r}") from None
    if values.shape != (6,) or not np.isfinite(values).all():
        raise InputError(f"box must be 6 finite numbers (xmin, ymin, zmin, xmax, ymax, zmax), got {box!r}")
    corners = values.reshape(2, 3)
    for axis, lo, hi in zip("xyz", *corners):
        if lo > hi:
            raise InputError(f"box {axis}min = {lo:g} is larger than {axis}max = {hi:g} — give the lower "
                             "corner first (xmin,ymin,zmin,xmax,ymax,zmax)")
    return corners


def crop(points, box, *, normals=None) -> tuple[np.ndarray, np.ndarray | None]:
    """The points inside an axis-aligned box (and their normals).

    Parameters
    ----------
    points : (N, 3) array_like of float
    box : sequence of 6 floats
        ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the points' units; the faces belong to the box.
        A lower bound above its upper bound is an error, equal bounds keep a plane.  To choose one,
        look at the bounding box ``canalsurf info`` prints.
    normals : (N, 3) array_like of float, optional
        Kept for the same points.

    Returns
    -------
    points : (M, 3) float64 ndarray
        The points inside, in their original order (``M`` may be 0).
    normals : (M, 3) float64 ndarray or None

    Raises
    ------
    InputError
        The box is not 6 finite numbers with each minimum at most its maximum, or the arrays are
        not ``(N, 3)``, finite, and of one shape.

    Examples
    --------
    >>> crop([[0, 0, 0], [2, 0, 0], [1, 1, 1]], (0, 0, 0, 1, 1, 1))[0]
    array([[0., 0., 0.],
           [1., 1., 1.]])
    """
    pts, nrm = _as_cloud(points, normals)
    lower, upper = _as_box(box)
    keep = np.all((pts >= lower) & (pts <= upper), axis=1)
    return pts[keep], None if nrm is None else nrm[keep]


def voxel_downsample(points, size: float, *, normals=None) -> tuple[np.ndarray, np.ndarray | None]:
    """At most one point per cube of edge ``size``: the input point nearest the centroid of its cube.

    Parameters
    ----------
    points : (N, 3) array_like of float
    size : float
        Edge of the voxels, in the points' units.  A dense scan (spacing far below the radius) can be
        thinned to about a tenth of the smallest radius without changing the result; the spacing of
        the result is about ``size``.  The grid is anchored at the origin, so a point falls into the
        same voxel whatever else is cropped away.
    normals : (N, 3) array_like of float, optional
        The normals of the kept points are kept with them.

    Returns
    -------
    points : (M, 3) float64 ndarray
        One point per occupied voxel, in the input's order.
    normals : (M, 3) float64 ndarray or None

    Notes
    -----
    A measured point is kept rather than the centroid itself: on a curved surface the centroid of a
    patch lies inside the surface, by about ``size**2 / (8 r)`` on a tube of radius ``r``, which
    would shrink every radius; averaging the normals would likewise give vectors that are neither
    unit length nor any point's normal.  The point kept is a real measurement and its normal is its
    own.  Ties go to the point that comes first.

    Raises
    ------
    InputError
        ``size`` is not a positive number, is too small for the coordinates (more than 2**52 voxels
        from the origin), or the arrays are invalid.

    Examples
    --------
    >>> points = [[0.1, 0.1, 0.1], [0.4, 0.4, 0.4], [0.3, 0.2, 0.3], [1.5, 0.0, 0.0]]
    >>> voxel_downsample(points, 1.0)[0]
    array([[0.3, 0.2, 0.3],
           [1.5, 0. , 0. ]])
    """
    pts, nrm = _as_cloud(points, normals)
    size = positive(size, "voxel size")
    if size is None:
        raise InputError("voxel size must be a positive number, got None")
    if len(pts) == 0:
        return pts.copy(), None if nrm is None else nrm.copy()
    extent = float(np.abs(pts).max()) / size
    if not extent < MAX_VOXEL_INDEX:
        raise InputError(f"voxel size {size:g} is too small for coordinates as large as {np.abs(pts).max():.3g} "
                         "— give a larger size")
    cells = np.floor(pts / size).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    if math.prod(int(d) for d in dims) < 2**62:  # one integer key per voxel: a 1-D sort
        key = np.ravel_multi_index(cells.T, dims)
        _, voxel = np.unique(key, return_inverse=True)
    else:
        _, voxel = np.unique(cells, axis=0, return_inverse=True)
    voxel = voxel.reshape(-1)
    count = np.bincount(voxel)
    centroid = np.column_stack([np.bincount(voxel, weights=pts[:, i]) for i in range(3)]) / count[:, None]
    gap = np.sum((pts - centroid[voxel]) ** 2, axis=1)
    order = np.lexsort((np.arange(len(pts)), gap, voxel))  # by voxel, nearest first, then first in file
    first = np.ones(len(order), dtype=bool)
    first[1:] = voxel[order[1:]] != voxel[order[:-1]]
    keep = np.sort(order[first])
    return pts[keep], None if nrm is None else nrm[keep]


def point_spacing(points, *, sample: int = SPACING_SAMPLE, rng=SPACING_SEED) -> float:
    """The typical distance between neighbouring points: the median distance from a point to the
    nearest other point (at a positive distance), over a random sample of the points.

    Parameters
    ----------
    points : (N, 3) array_like of float
    sample : int, optional
        Points whose nearest neighbour is looked up (all of them if there are fewer).  Their
        neighbours are searched among all the points, so the sample does not make the cloud look
        sparser than it is.
    rng : int or numpy.random.Generator, optional
        Seed or generator of the sample; the default makes the answer repeatable.

    Returns
    -------
    float
        The median distance; NaN for fewer than two distinct points.

    Examples
    --------
    >>> grid = np.stack(np.meshgrid(*[np.arange(10.0)] * 3), axis=-1).reshape(-1, 3) * 0.5
    >>> point_spacing(grid)
    0.5
    """
    from scipy.spatial import cKDTree

    pts, _ = _as_cloud(points, None)
    if len(pts) < 2:
        return math.nan
    generator = np.random.default_rng(rng)
    chosen = pts if len(pts) <= sample else pts[generator.choice(len(pts), size=sample, replace=False)]
    k = min(SPACING_NEIGHBOURS, len(pts))
    # An unbalanced tree builds about five times faster and answers the same: it is queried only once.
    tree = cKDTree(pts, balanced_tree=False, compact_nodes=False)
    distance, _ = tree.query(chosen, k=k)
    distance = np.where(distance > 0, distance, np.inf).min(axis=1)  # nearest at a positive distance
    distance = distance[np.isfinite(distance)]
    return float(np.median(distance)) if len(distance) else math.nan


def quantisation_noise(points, *, sample: int = QUANTUM_SAMPLE, rng=0) -> float:
    """The noise that rounding coordinates to a grid adds along a surface normal (0 if not rounded).

    LAS and many scanners' files store coordinates as whole multiples of a step q per axis (1 mm,
    1 cm, ...).  The rounding error is uniform on [-q/2, q/2] along each axis, variance q^2 / 12;
    along a normal of random direction that averages to sum(q_a^2) / 36.  A quantised floor or wall
    has no scatter at all about its plane, so this is the least noise a fit can be held to.

    The grid is looked for along the coordinate axes, where a file stores it (exactly, however fine),
    and along any other three perpendicular axes, where a scan turned after it was rounded has it
    (registered, levelled or georeferenced, and written with more digits): there it is found where
    neighbouring points share its layers, with noise up to about a tenth of its step
    (``GRID_COHERENCE``).  Of the two, the larger.

    Parameters
    ----------
    points : (N, 3) array_like of float
    sample : int, optional
        Points whose coordinates are searched for a grid along the axes; a turned grid is searched
        for among ``TURNED_POINTS`` of them.
    rng : int or numpy.random.Generator, optional
        Seed or generator of the sample; the default makes the answer repeatable.

    Returns
    -------
    float
        In the points' units.

    Examples
    --------
    A cloud stored in centimetres, then turned:

    >>> from scipy.spatial.transform import Rotation
    >>> stored = np.round(np.random.default_rng(0).uniform(0, 0.5, (3000, 3)), 2)
    >>> round(quantisation_noise(stored), 5)
    0.00289
    >>> round(quantisation_noise(stored @ Rotation.from_euler("zx", [30, 10], degrees=True).as_matrix()), 5)
    0.00289
    """
    pts, _ = _as_cloud(points, None)
    pts = pts[np.random.default_rng(rng).permutation(len(pts))[:max(sample, TURNED_POINTS)]]
    along = sum(q * q / 36.0 for q in _axis_steps(pts[:sample]))
    turned = sum(q * q / 36.0 for q in _turned_steps(pts))
    # A grid along the axes is found both ways; its exact steps then stand.
    return float(np.sqrt(along if turned < along * (1 + 1e-6) else turned))


def _axis_steps(points: np.ndarray) -> list[float]:
    """The steps of the grids the points' x, y and z lie on, exactly (none for an axis off a grid)."""
    found = []
    for values in points.T:
        levels = np.unique(values)
        steps = np.diff(levels)
        steps = steps[steps > QUANTUM_RESOLUTION * np.ptp(values)]
        if not len(steps):
            continue
        q = steps.min()
        offsets = (levels - levels[0]) / q
        if np.all(np.abs(offsets - np.round(offsets)) < QUANTUM_TOLERANCE):
            found.append(float(q))
    return found


def _turned_steps(points: np.ndarray) -> list[float]:
    """The steps of a grid the points lie on along three perpendicular axes of any direction.

    Neighbours in one layer of the grid differ by vectors perpendicular to its axis, so the normals of
    pairs of neighbour differences crowd about the axes.  The most crowded directions are tried in
    turn: along each, the differences' largest common step, refined by least squares on differences
    ever farther apart, and kept if the points all agree in phase along it.
    """
    from scipy.spatial import cKDTree

    k = TURNED_NEIGHBOURS
    if len(points) <= 4 * k:
        return []
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)  # quicker to build, for few queries
    seeds = points[:TURNED_SEEDS]
    diff = points[tree.query(seeds, k=k + 1)[1][:, 1:]] - seeds[:, None]
    first, second = np.triu_indices(k, 1)
    normals = np.cross(diff[:, first], diff[:, second]).reshape(-1, 3)
    size = (np.linalg.norm(diff[:, first], axis=2) * np.linalg.norm(diff[:, second], axis=2)).ravel()
    length = np.linalg.norm(normals, axis=1)
    keep = length > TURNED_MIN_SINE * size
    if not keep.any():
        return []
    normals = normals[keep][np.random.default_rng(0).permutation(keep.sum())[:TURNED_NORMALS]]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    probes = normals[:TURNED_SEEDS]
    crowd = cKDTree(np.vstack([normals, -normals])).query_ball_point(probes, TURNED_CONE, return_length=True)
    near = diff.reshape(-1, 3)
    near = near[np.any(near != 0, axis=1)]
    # Farther differences pin the axis and step more finely, once the nearer ones leave no doubt
    # which multiple of the step each one is.
    scales = [near, seeds - points[tree.query(seeds, k=[4 * k])[1][:, 0]], seeds - seeds[0]]
    axes, tried = [], 0
    taken = np.zeros(len(probes), bool)
    for index in np.argsort(-crowd, kind="stable"):
        if len(axes) == 2 or tried == TURNED_TRIES:
            break
        if taken[index]:
            continue
        cone = np.abs(probes @ probes[index]) > np.cos(TURNED_CONE)
        taken |= cone
        tried += 1
        axis = (probes[cone] * np.sign(probes[cone] @ probes[index])[:, None]).mean(axis=0)
        grid = _grid_along(axis / np.linalg.norm(axis), scales)
        if grid is not None:
            axes.append(grid)
            taken |= np.abs(probes @ grid) > np.sin(TURNED_OFF_AXIS) * np.linalg.norm(grid)
    if len(axes) == 2:
        third = np.cross(*axes)
        grid = _grid_along(third / np.linalg.norm(third), scales)
        axes += [] if grid is None else [grid]
    return [1.0 / float(np.linalg.norm(grid)) for grid in axes]


def _grid_along(axis: np.ndarray, scales: list) -> np.ndarray | None:
    """The grid along ``axis`` as its axis over its step (None if there is none): its step from the
    nearest differences of ``scales``, the pair refined by least squares on each in turn, and kept if
    the last (every seed from the first) agrees in phase along it."""
    step = _common_step(scales[0] @ axis)
    if not step:
        return None
    grid = axis / step
    for diff in scales:
        for _ in range(2):
            multiple = np.round(diff @ grid)
            if not multiple.any():
                break
            grid = np.linalg.lstsq(diff, multiple, rcond=None)[0]
    return grid if abs(np.exp(2j * np.pi * (scales[-1] @ grid)).mean()) >= GRID_COHERENCE else None


def _common_step(values: np.ndarray) -> float:
    """The largest step of which the (first 400) ``values`` are whole multiples, give or take a tenth
    of it, with at least ``GRID_MIN_SHARE`` of them off 0; 0 if there is none."""
    values = values[:400]
    size = np.abs(values)
    top = np.quantile(size, 1.0 - GRID_MIN_SHARE)
    if not top > 0:
        return 0.0
    steps = np.geomspace(top, top / 100.0, 200)
    off = size >= steps[:, None] / 2
    agree = np.abs((np.exp(2j * np.pi * values / steps[:, None]) * off).sum(axis=1)) / np.maximum(off.sum(axis=1), 1)
    found = np.flatnonzero((off.mean(axis=1) >= GRID_MIN_SHARE) & (agree >= GRID_COHERENCE))
    return float(steps[found[0]]) if len(found) else 0.0
