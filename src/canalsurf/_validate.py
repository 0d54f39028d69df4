"""Checks done once, at the public boundary; the stages trust their arrays after this."""

from __future__ import annotations

import numbers

import numpy as np

from .errors import InputError

#: Fewest points the pipeline accepts: a tube needs several cross-sections of several points each,
#: and the normal estimation needs a neighbourhood of ``MIN_NEIGHBOURS`` around every point.
MIN_POINTS = 50
#: Largest coordinate accepted (any unit).  float64 keeps about 16 significant digits, so at 1e15 its
#: numbers are 0.125 apart: a scan in any unit never needs larger coordinates (the Earth's
#: circumference is 4e10 mm), and larger ones leave too few digits for the shape -- near 1e308 the
#: sums and squares of the stages overflow outright.
MAX_COORDINATE = 1e15
#: Smallest spread of the points (the largest of their x, y, z ranges) relative to their largest
#: coordinate: below this, fewer than 7 of float64's 16 digits describe the shape, so the normals
#: and the curvature are made of rounding.  Move such points near the origin first.
MIN_RELATIVE_SPREAD = 1e-9
#: Smallest spread in absolute terms: the first stage squares distances, and below about 1e-154
#: (the square root of the smallest normal float64) the squares underflow to nothing.
MIN_SPREAD = 1e-150
#: Longest repr of a rejected value quoted in a message (a 400-digit integer stays readable).
_SHOWN_CHARS = 40


def _show(value) -> str:
    """``repr(value)``, shortened so that a message stays one readable line."""
    text = repr(value)
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


def as_points(points, name: str = "points", min_points: int = MIN_POINTS) -> np.ndarray:
    """Return ``points`` as a finite ``(N, 3)`` float64 array, or raise :class:`InputError`.

    Coordinates beyond ``MAX_COORDINATE`` are refused, and points that differ must spread far enough
    to be resolved (:func:`check_scale`).
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except OverflowError:
        raise InputError(f"{name} hold numbers too large for float64 — give coordinates in a larger "
                         "unit") from None
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
    check_scale(arr, name)
    return arr


def as_table(values, name: str) -> np.ndarray:
    """``values`` as an ``(N, 3)`` float64 array (any values), or :class:`InputError` naming ``name``."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{name} must be a numeric (N, 3) array, got {type(values).__name__}") from None
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr


def check_scale(arr: np.ndarray, name: str = "points") -> None:
    """Raise :class:`InputError` unless finite ``(N, 3)`` points suit float64 arithmetic.

    No coordinate may exceed ``MAX_COORDINATE`` in size, and points that differ must spread (the
    largest of their x, y and z ranges) at least ``MIN_SPREAD`` and at least ``MIN_RELATIVE_SPREAD``
    times their largest coordinate; see those constants for why.  Points that are all identical
    (spread 0) pass: whether one point is enough is the caller's question.
    """
    if len(arr) == 0:
        return
    lo, hi = arr.min(axis=0), arr.max(axis=0)  # no temporary copy of a large cloud
    magnitude = float(max(hi.max(), -lo.min()))
    if magnitude > MAX_COORDINATE:
        raise InputError(
            f"{name} coordinates are too large (max |x| = {magnitude:.3g}, more than {MAX_COORDINATE:.0e}: "
            "float64 keeps only 16 digits) — subtract an offset (e.g. the mean) or use a larger unit"
        )
    spread = float((hi - lo).max())  # after the bound: hi - lo cannot overflow now
    if spread == 0:
        return
    if spread < MIN_SPREAD:
        raise InputError(
            f"{name} span only {spread:.3g}, too little for float64 arithmetic (at least {MIN_SPREAD:.0e}) "
            "— use a smaller unit (scale the points up)"
        )
    if spread < MIN_RELATIVE_SPREAD * magnitude:
        raise InputError(
            f"{name} span only {spread:.3g} at coordinates as large as {magnitude:.3g}, too little to "
            "resolve in float64 — subtract an offset (e.g. the mean) first"
        )


def as_normals(normals, n: int) -> np.ndarray:
    """Return ``normals`` as a finite ``(n, 3)`` array of unit vectors, or raise :class:`InputError`."""
    try:
        arr = np.asarray(normals, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"normals must be a numeric (N, 3) array, got {type(normals).__name__}") from None
    if arr.shape != (n, 3):
        raise InputError(f"normals must have shape ({n}, 3) like the points, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise InputError("normals contain NaN or inf — drop them and let canalsurf estimate normals")
    # Divided by its largest component first, so that a vector of 1e200s does not overflow when squared.
    big = np.abs(arr).max(axis=1, initial=0.0)
    scaled = arr / np.where(big > 0, big, 1.0)[:, None]
    length = np.linalg.norm(scaled, axis=1)
    if (big * length < 1e-12).any():
        raise InputError("normals contain zero vectors — drop them and let canalsurf estimate normals")
    return scaled / length[:, None]


def _number(value, name: str) -> float:
    """``value`` as a float; a bool, complex, string or other non-number raises :class:`InputError`."""
    # bool is an int to Python but never a meaningful length or share; numbers.Real admits Python and
    # numpy ints and floats (and Fraction), not complex numbers or strings.
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be a real number, got {type(value).__name__} {_show(value)}")
    try:
        return float(value)
    except OverflowError:
        raise InputError(f"{name} is too large for a float64 number, got {_show(value)}") from None
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {_show(value)}") from None


def positive(value, name: str) -> float | None:
    """``None`` or a finite float > 0 of normal size (not subnormal)."""
    if value is None:
        return None
    v = _number(value, name)
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive number, got {_show(value)}")
    if v < np.finfo(np.float64).tiny:
        # subnormal: divided by the scan's size it becomes 0, and its own precision is a few bits
        raise InputError(f"{name} = {v:.3g} is too small for float64 arithmetic (at least "
                         f"{np.finfo(np.float64).tiny:.3g}) — give a larger {name} or use a smaller unit")
    return v


def in_range(value, name: str, lo: float, hi: float) -> float | None:
    """``None`` or a float in the closed interval ``[lo, hi]``."""
    if value is None:
        return None
    v = _number(value, name)
    if not (lo <= v <= hi):
        raise InputError(f"{name} must lie in [{lo}, {hi}], got {_show(value)}")
    return v


def choice(value, name: str, options) -> str:
    """``value`` if it is one of ``options``."""
    try:
        known = value in options
    except TypeError:  # an unhashable value against a set or dict
        known = False
    if not known:
        raise InputError(f"{name} must be one of {', '.join(map(repr, options))}, got {_show(value)}")
    return value
