"""Operations on a point cloud before it is reconstructed: crop to a box, thin out on a voxel grid,
measure the typical spacing.

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

__all__ = ["crop", "voxel_downsample", "point_spacing", "SPACING_SAMPLE", "SPACING_SEED"]

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
