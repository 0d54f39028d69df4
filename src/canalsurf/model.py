"""The reconstructed model: spine B-spline, radius, and its ``model.json`` form.

``model.json`` (format ``canalsurf.model``, version 1) holds the spine as a plain B-spline (degree,
full knot vector, control points -- a closed spine is a periodic spline written out in full, so any
B-spline evaluator reproduces it), the radius (``{"constant": r}`` for a pipe, else a scalar B-spline on
the same parameter), samples evenly spaced in arc length, the parameters used and diagnostics.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.interpolate import BSpline

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
    """

    kind: str
    spine: BSpline
    radius: BSpline
    closed: bool
    parameters: dict = field(default_factory=dict)
    diagnostics: dict = field(default_factory=dict)
    stages: dict | None = field(default=None, repr=False, compare=False)

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

    def to_dict(self) -> dict:
        """The ``model.json`` content (plain JSON types); timings are left out, as they vary by run."""
        t, pts = sample_arclength(self.spine, N_SAMPLES)
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


def model_from_dict(data: dict, source: str = "model") -> CanalModel:
    """Build a :class:`CanalModel` from ``model.json`` content, checking format and version."""
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InputError(f"{source}: not a canalsurf model (no \"format\": \"{FORMAT}\") — "
                         "give a model.json written by canalsurf")
    if data.get("version") != VERSION:
        raise InputError(f"{source}: model version {data.get('version')!r} is not supported "
                         f"(this canalsurf reads version {VERSION}) — re-run the reconstruction")
    try:
        sp = data["spine"]
        spine = BSpline(np.asarray(sp["knots"], float), np.asarray(sp["control_points"], float),
                        int(sp["degree"]))
        rad = data["radius"]
        if "constant" in rad:
            radius = constant_spline(float(rad["constant"]))
        else:
            radius = BSpline(np.asarray(rad["knots"], float), np.asarray(rad["coefficients"], float),
                             int(rad["degree"]))
        kind = data["kind"]
        closed = bool(sp["closed"])
        if kind not in ("pipe", "canal") or spine.c.ndim != 2 or spine.c.shape[1] != 3:
            raise ValueError("bad kind or spine shape")
        if not (np.isfinite(spine.c).all() and np.isfinite(radius.c).all()):
            raise ValueError("non-finite coefficients")
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{source}: corrupted model ({exc}) — re-run the reconstruction") from None
    return CanalModel(kind, spine, radius, closed, dict(data.get("parameters", {})),
                      dict(data.get("diagnostics", {})))


def load_model(path) -> CanalModel:
    """Read a ``model.json`` written by :meth:`CanalModel.save`.

    Raises
    ------
    InputError
        If the file is missing, not JSON, of another format or version, or corrupted.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such file — check the path") from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or exc.__class__.__name__
        raise InputError(f"{path}: cannot read the model ({reason}) — "
                         "give a model.json file") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}) — "
                         "the file is corrupted; re-run the reconstruction") from None
    return model_from_dict(data, str(path))
