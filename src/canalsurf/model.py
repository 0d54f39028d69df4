"""The reconstructed model: spine B-spline, radius, and its ``model.json`` form.

``model.json`` (format ``canalsurf.model``, version 1) holds the spine as a plain B-spline (degree,
full knot vector, control points -- a closed spine is a periodic spline written out in full, so any
B-spline evaluator reproduces it), the radius (``{"constant": r}`` for a pipe, else a scalar B-spline on
the same parameter), samples evenly spaced in arc length, the parameters used and diagnostics.
"""

from __future__ import annotations

import json
import math
import numbers
import os
import stat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import BSpline

from ._validate import MAX_COORDINATE
from .errors import InputError
from .spine import constant_spline, sample_arclength

__all__ = ["CanalModel", "load_model", "model_from_dict", "FORMAT", "VERSION", "N_SAMPLES"]

FORMAT = "canalsurf.model"
VERSION = 1
#: Samples written to model.json (the format promises at least 200).
N_SAMPLES = 256


@dataclass
class CanalModel:
    """A pipe or canal surface: spine C(t) and radius r(t), t in [0, 1] by normalised arc length.

    Attributes
    ----------
    kind : {"pipe", "canal"}
    spine : scipy.interpolate.BSpline
        ``model.spine(t)`` gives points, shape ``t.shape + (3,)``.
    radius : scipy.interpolate.BSpline
        ``model.radius(t)``; constant for a pipe.
    closed : bool
        The spine is a loop (periodic spline, C(0) = C(1)).
    parameters : dict
        Paper parameters actually used (R, delta, mu, tau, H, k, ...), in the input's units.
    diagnostics : dict
        n_points, iterations, break_count, stop_rule, rms_residual, angular_coverage, seconds per
        stage, ...  (``model.json`` leaves out the seconds, so the same input gives the same file.)
    stages : dict, optional
        Intermediate clouds (``normals``, ``shrunk``, ``thin``) for figures; not saved.
    id : int
        The branch's id in its :class:`~canalsurf.network.Network` (0 for a single tube).
    ends : tuple of (int or None, int or None)
        Junction id at ``t = 0`` and at ``t = 1`` in the network; ``None`` for an open end.
    """

    kind: str
    spine: BSpline
    radius: BSpline
    closed: bool
    parameters: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    stages: dict | None = field(default=None, repr=False, compare=False)
    id: int = 0
    ends: tuple = (None, None)

    def sample(self, n: int = N_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
        """``n`` points evenly spaced in arc length along the spine, and the radius at each.

        Returns
        -------
        points : ndarray, shape (n, 3)
        radius : ndarray, shape (n,)
        """
        t, pts = sample_arclength(self.spine, int(n))
        return pts, self.radius(t)

    @property
    def mean_radius(self) -> float:
        """Radius averaged along the spine."""
        return float(np.mean(self.sample()[1]))

    def to_dict(self, n_samples: int = N_SAMPLES) -> dict:
        """The version 1 ``model.json`` content (plain JSON types) with ``n_samples`` samples; timings
        are left out, as they vary by run."""
        t, pts = sample_arclength(self.spine, n_samples)
        if self.kind == "pipe":
            radius = {"constant": float(self.radius.c[0])}
        else:
            radius = {"degree": int(self.radius.k), "knots": _floats(self.radius.t),
                      "coefficients": _floats(self.radius.c)}
        return {
            "format": FORMAT,
            "version": VERSION,
            "kind": self.kind,
            "spine": {"degree": int(self.spine.k), "knots": _floats(self.spine.t),
                      "control_points": _floats(self.spine.c), "closed": bool(self.closed)},
            "radius": radius,
            "samples": {"t": _floats(t), "points": _floats(pts), "radius": _floats(self.radius(t))},
            "parameters": _plain(self.parameters),
            "diagnostics": _plain({k: v for k, v in self.diagnostics.items() if k != "seconds"}),
        }

    def save(self, path) -> None:
        """Write ``model.json`` atomically (a failed write leaves no partial file)."""
        from .io import write_json

        write_json(path, self.to_dict())


def _floats(a) -> list:
    return np.asarray(a, dtype=float).tolist()


def _plain(obj):
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    return obj


#: Largest model file read: a spine of 100,000 control points with its samples takes about 10 MB, so
#: a larger file is not a model -- and is refused before it is read into memory.
MAX_MODEL_BYTES = 64 << 20
#: Deepest nesting of arrays and objects in a model file: canalsurf writes 4 levels (a network 5);
#: parameters and diagnostics may add a few.  The JSON parser recurses, so the depth must be bounded.
MAX_JSON_DEPTH = 32
#: Most digits of an integer in a model file: every integer canalsurf writes is a count or a degree,
#: and JSON readers in other languages hold integers as int64 (19 digits) or float64.
MAX_INT_DIGITS = 18
#: Degrees a spline in a model file may have: canalsurf writes cubics; beyond quintics a fit only
#: oscillates, and no canal surface needs one.
MIN_DEGREE, MAX_DEGREE = 1, 5
#: Longest repr of a bad value quoted in a message (a 400-digit number stays readable).
_SHOWN_CHARS = 40


class _BadNumber(Exception):
    """A JSON number no model can hold (NaN, Infinity, an overflowing float, a 400-digit integer)."""


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise _BadNumber(text)
    return int(text)


def _parse_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):  # 1e400 parses to inf
        raise _BadNumber(text)
    return value


def _parse_constant(text: str):
    raise _BadNumber(text)  # NaN, Infinity, -Infinity: not JSON, though Python writes them


def _short(text: str) -> str:
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


def _shown(value) -> str:
    """A bad value for a message, spelled as in JSON where it differs from Python, shortened."""
    return _short(json.dumps(value) if value is None or isinstance(value, bool) else repr(value))


def _json_type(value) -> str:
    if value is None or isinstance(value, bool):
        return _shown(value)
    if isinstance(value, str):
        return "a string"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, (list, tuple)):
        return "a list"
    return "a number" if _is_number(value) else type(value).__name__


def _is_number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _corrupted(source: str, problem: str) -> InputError:
    return InputError(f"{source}: corrupted model ({problem}) — re-run the reconstruction")


def _depth(obj) -> int:
    """Nesting depth of arrays and objects (1 for a flat list, 0 for a number), without recursion.

    The walk stops once the depth passes ``MAX_JSON_DEPTH``.
    """
    if not isinstance(obj, (dict, list)):
        return 0
    deepest, stack = 0, [(obj, 1)]
    while stack and deepest <= MAX_JSON_DEPTH:
        item, level = stack.pop()
        deepest = max(deepest, level)
        children = item.values() if isinstance(item, dict) else item
        stack.extend((c, level + 1) for c in children if isinstance(c, (dict, list)))
    return deepest


def read_model_json(path) -> object:
    """The parsed JSON of a model file, with the checks every model file (any version) gets.

    The size is checked before reading (``MAX_MODEL_BYTES``), the nesting depth while and after
    parsing (``MAX_JSON_DEPTH``), and every number as it is parsed: NaN, Infinity, floats beyond
    float64 and integers of more than ``MAX_INT_DIGITS`` digits are refused.

    Raises
    ------
    InputError
        The file is missing, unreadable, too large, not JSON, or holds such numbers or nesting.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"model path must be a file path (str or os.PathLike), got {type(path).__name__}")
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file — check the path") from None
    except (OSError, ValueError) as exc:
        reason = getattr(exc, "strerror", None) or exc.__class__.__name__
        raise InputError(f"{path}: cannot read the model ({reason}) — give a model.json file") from None
    if not (stat.S_ISREG(info.st_mode) or stat.S_ISDIR(info.st_mode)):
        # a named pipe would block the read, a device never end
        raise InputError(f"{path}: cannot read the model (not a regular file) — give a model.json file")
    if info.st_size > MAX_MODEL_BYTES:
        raise InputError(f"{path}: is {info.st_size / 2**20:.0f} MiB, more than the {MAX_MODEL_BYTES >> 20} MiB "
                         "a model file can take — give a model.json written by canalsurf")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file — check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc.__class__.__name__
        raise InputError(f"{path}: cannot read the model ({reason}) — "
                         "give a model.json file") from None
    nested = InputError(f"{path}: not a model (its JSON nests deeper than {MAX_JSON_DEPTH} levels) — the file "
                        "is corrupted; re-run the reconstruction")
    try:
        data = json.loads(text, parse_int=_parse_int, parse_float=_parse_float, parse_constant=_parse_constant)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}) — "
                         "the file is corrupted; re-run the reconstruction") from None
    except RecursionError:
        raise nested from None
    except _BadNumber as exc:
        raise _corrupted(str(path), f"the number {_short(str(exc))} is out of range: models hold finite "
                                    f"float64 numbers and integers of at most {MAX_INT_DIGITS} digits") from None
    if _depth(data) > MAX_JSON_DEPTH:
        raise nested
    return data


def _array(value, what: str, source: str, width: int | None = None) -> np.ndarray:
    """A list of finite numbers (``width`` None) or of ``width``-number lists, as a float64 array."""
    if width is None:
        expected, fits = "a list of numbers", _is_number
    else:
        expected = "a list of [x, y, z] points" if width == 3 else f"a list of {width}-number lists"

        def fits(row) -> bool:
            return isinstance(row, list) and len(row) == width and all(_is_number(v) for v in row)

    if not isinstance(value, list):
        raise _corrupted(source, f"{what} must be {expected}, got {_json_type(value)}")
    bad = next((i for i, item in enumerate(value) if not fits(item)), None)
    if bad is not None:
        item = value[bad]
        shown = f"a list of {len(item)}" if isinstance(item, list) else _json_type(item)
        raise _corrupted(source, f"{what} must be {expected}; item {bad} is {shown}")
    try:
        arr = np.array(value, dtype=np.float64).reshape(len(value), *(() if width is None else (width,)))
    except OverflowError:
        arr = np.full(1, np.inf)
    if not np.isfinite(arr).all() or (arr.size and np.abs(arr).max() > MAX_COORDINATE):
        raise _corrupted(source, f"{what} must be finite numbers of at most {MAX_COORDINATE:.0e} in size")
    return arr


def spline_from_dict(data, what: str, source: str) -> BSpline:
    """A B-spline from its model-file form, with every invariant of the format checked.

    Parameters
    ----------
    data : dict
        ``{"degree", "knots", "control_points"}`` (a curve in 3-D, e.g. a spine) or
        ``{"degree", "knots", "coefficients"}`` (a scalar function, e.g. a radius); other keys
        (``closed``) are left to the caller.
    what : str
        What the spline is, for messages (``"spine"``, ``"branch 3 radius"``).
    source : str
        Where it comes from (the file), for messages.

    Returns
    -------
    scipy.interpolate.BSpline

    Raises
    ------
    InputError
        ``"<source>: corrupted model (<what> ...) — re-run the reconstruction"`` unless: ``data`` is an
        object with exactly one of ``control_points`` / ``coefficients``; ``degree`` is an integer
        (not a bool or a float) from ``MIN_DEGREE`` to ``MAX_DEGREE``; knots and coefficients are
        finite numbers of at most ``MAX_COORDINATE`` (control points ``[x, y, z]`` lists of them);
        there are at least ``degree + 1`` coefficients and exactly ``coefficients + degree + 1``
        knots; the knots never decrease; and the spline's domain ``knots[degree] .. knots[-degree-1]``
        is exactly [0, 1] -- clamped there for an open spline, periodically extended past it (the
        full knot vector of a closed one) otherwise.
    """
    if not isinstance(data, dict):
        raise _corrupted(source, f"{what} must be an object, got {_json_type(data)}")
    if ("control_points" in data) == ("coefficients" in data):
        raise _corrupted(source, f"{what} needs either control_points or coefficients")
    key = "control_points" if "control_points" in data else "coefficients"
    degree = data.get("degree")
    if type(degree) is not int or not MIN_DEGREE <= degree <= MAX_DEGREE:
        raise _corrupted(source, f"{what} degree must be an integer from {MIN_DEGREE} to {MAX_DEGREE}, "
                                 f"got {_shown(degree)}")
    knots = _array(data.get("knots"), f"{what} knots", source)
    coefficients = _array(data[key], f"{what} {key}", source, 3 if key == "control_points" else None)
    n = len(coefficients)
    if n < degree + 1:
        raise _corrupted(source, f"{what} has {n} {key}; degree {degree} needs at least {degree + 1}")
    if len(knots) != n + degree + 1:
        raise _corrupted(source, f"{what} has {len(knots)} knots; {n} {key} of degree {degree} need "
                                 f"{n + degree + 1}")
    if np.any(np.diff(knots) < 0):
        raise _corrupted(source, f"{what} knots decrease at index {int(np.argmax(np.diff(knots) < 0)) + 1}")
    if knots[degree] != 0.0 or knots[-degree - 1] != 1.0:
        raise _corrupted(source, f"{what} is defined on [{knots[degree]:.6g}, {knots[-degree - 1]:.6g}], "
                                 "not on [0, 1]")
    return BSpline(knots, coefficients, degree)


def radius_from_dict(data, what: str, source: str) -> BSpline:
    """The radius r(t) from its model-file form, checked to be positive on [0, 1].

    ``{"constant": r}`` (a pipe) gives a constant spline; anything else must be a scalar B-spline
    (:func:`spline_from_dict`, ``coefficients``) whose values at ``N_SAMPLES`` even parameters and at
    its knots in [0, 1] are positive.  Raises :class:`InputError` as :func:`spline_from_dict`.
    """
    if isinstance(data, dict) and "constant" in data:
        value = data["constant"]
        try:
            ok = _is_number(value) and math.isfinite(float(value)) and 0 < float(value) <= MAX_COORDINATE
        except OverflowError:
            ok = False
        if not ok:
            raise _corrupted(source, f"{what} constant must be a positive number, got {_shown(value)}")
        return constant_spline(float(value))
    spline = spline_from_dict(data, what, source)
    if spline.c.ndim != 1:
        raise _corrupted(source, f"{what} must be a scalar spline (coefficients, not control points)")
    t = np.union1d(np.linspace(0.0, 1.0, N_SAMPLES), spline.t[(spline.t >= 0) & (spline.t <= 1)])
    r = spline(t)
    if not (np.isfinite(r).all() and r.min() > 0):
        raise _corrupted(source, f"{what} must be positive on [0, 1], its least value there is {r.min():.4g}")
    return spline


def model_from_dict(data: dict, source: str = "model") -> CanalModel:
    """Build a :class:`CanalModel` from ``model.json`` content (version 1), checking every field.

    Format and version come first (a file of another kind or version is named as such), then the
    kind, the spine and radius (:func:`spline_from_dict`, :func:`radius_from_dict`), ``closed``, the
    samples when present (three lists of equal length), and that parameters and diagnostics, when
    present, are objects.

    Raises
    ------
    InputError
        Any of these does not hold (one line naming the problem).
    """
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{source}: not a canalsurf model (no \"format\": \"{FORMAT}\") — "
                         "give a model.json written by canalsurf")
    version = data.get("version")
    if type(version) is not int or version != VERSION:  # neither true nor 1.0
        raise InputError(f"{source}: model version {_shown(version)} is not supported "
                         f"(this canalsurf reads version {VERSION}) — re-run the reconstruction")
    kind = data.get("kind")
    if not (isinstance(kind, str) and kind in ("pipe", "canal")):
        raise _corrupted(source, f"kind must be \"pipe\" or \"canal\", got {_shown(kind)}")
    sp = data.get("spine")
    spine = spline_from_dict(sp, "spine", source)
    if spine.c.ndim != 2:
        raise _corrupted(source, "spine must have control_points [x, y, z]")
    closed = sp.get("closed")
    if not isinstance(closed, bool):
        raise _corrupted(source, f"spine closed must be true or false, got {_shown(closed)}")
    rad = data.get("radius")
    radius = radius_from_dict(rad, "radius", source)
    if (kind == "pipe") != ("constant" in rad):
        raise _corrupted(source, f"a {kind} has {'a constant radius' if kind == 'pipe' else 'a radius B-spline'}")
    if "samples" in data:
        samples = data["samples"]
        if not isinstance(samples, dict):
            raise _corrupted(source, f"samples must be an object, got {_json_type(samples)}")
        lengths = {len(_array(samples.get("t"), "samples t", source)),
                   len(_array(samples.get("points"), "samples points", source, 3)),
                   len(_array(samples.get("radius"), "samples radius", source))}
        if len(lengths) != 1:
            raise _corrupted(source, "samples t, points and radius differ in length")
    extras = {}
    for key in ("parameters", "diagnostics"):
        extras[key] = data.get(key, {})
        if not isinstance(extras[key], dict):
            raise _corrupted(source, f"{key} must be an object, got {_json_type(extras[key])}")
    return CanalModel(kind, spine, radius, closed, dict(extras["parameters"]), dict(extras["diagnostics"]))


def load_model(path):
    """Read a ``model.json`` written by canalsurf: a :class:`~canalsurf.network.Network`.

    Version 2 files hold a network; a version 1 file (one tube) is read as a network of one branch.

    Raises
    ------
    InputError
        If the file is missing, not JSON, of another format or version, or corrupted.
    """
    data = read_model_json(path)
    from .network import network_from_dict

    return network_from_dict(data, str(Path(path)))
