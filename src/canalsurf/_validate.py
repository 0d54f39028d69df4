"""Checks done once, at the public boundary; the stages trust their arrays after this."""

from __future__ import annotations

import numpy as np

from .errors import InputError

#: Fewest points the pipeline accepts: a tube needs several cross-sections of several points each,
#: and the normal estimation needs a neighbourhood of ``MIN_NEIGHBOURS`` around every point.
MIN_POINTS = 50


def as_points(points, name: str = "points", min_points: int = MIN_POINTS) -> np.ndarray:
    """Return ``points`` as a finite ``(N, 3)`` float64 array, or raise :class:`InputError`."""
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric, got {type(points).__name__}: {exc}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3), got {arr.shape}")
    if len(arr) < min_points:
        raise InputError(
            f"{name} holds {len(arr)} points; at least {min_points} are needed — give a denser scan"
        )
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{name} has {int(bad.sum())} rows with NaN or inf (first at row {first}) — remove them"
        )
    return arr


def as_normals(normals, n: int) -> np.ndarray:
    """Return ``normals`` as a finite ``(n, 3)`` array of unit vectors, or raise :class:`InputError`."""
    try:
        arr = np.asarray(normals, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"normals must be a numeric (N, 3) array, got {type(normals).__name__}") from None
    if arr.shape != (n, 3):
        raise InputError(f"normals must have shape ({n}, 3) like the points, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError("normals contain NaN or inf — drop them and let canalsurf estimate normals")
    length = np.linalg.norm(arr, axis=1)
    if (length < 1e-12).any():
        raise InputError("normals contain zero vectors — drop them and let canalsurf estimate normals")
    return arr / length[:, None]


def _number(value, name: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None


def positive(value, name: str) -> float | None:
    """``None`` or a finite float > 0."""
    if value is None:
        return None
    v = _number(value, name)
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive number, got {value!r}")
    return v


def in_range(value, name: str, lo: float, hi: float) -> float | None:
    """``None`` or a float in the closed interval ``[lo, hi]``."""
    if value is None:
        return None
    v = _number(value, name)
    if not (lo <= v <= hi):
        raise InputError(f"{name} must lie in [{lo}, {hi}], got {value!r}")
    return v


def choice(value, name: str, options) -> str:
    """``value`` if it is one of ``options``."""
    if value not in options:
        raise InputError(f"{name} must be one of {', '.join(map(repr, options))}, got {value!r}")
    return value
