"""A self-contained HTML report of one reconstruction (the optional ``report`` extra).

:func:`render_report` builds, and :func:`write_report` writes, a single HTML file that works offline --
plotly.js is embedded in the page and the figures are PNG ``data:`` URIs -- with

* the headline: how many branches, junctions and separate networks, the share of the points on no
  tube, the RMS distance of the points on a tube from it (also relative to the mean radius) and how
  much of the circumference the scan saw; then a table of the branches;
* an interactive 3-D view (plotly): the points in the colour of the branch they lie on
  (:meth:`canalsurf.network.Network.classify`; light grey on no tube) -- or, by a button, coloured by
  their signed distance from the surface --, each branch's spine, the junctions and the united
  surface (:func:`canalsurf.network.network_mesh`), with a camera that shows the whole cloud;
* the radius along each branch, r over arc length, with each point's distance from the spine at its
  footpoint (the radius that point alone would give);
* the parameters used and the diagnostics under readable names (the ``model.json`` key on hover);
* PNG small multiples of the stages as in the paper's figures (matplotlib): the input S, the shrunk
  cloud S-hat, the thinned cloud S-tilde, the spines and the surfaces.

A branch has one colour throughout: its points and spine in the 3-D view, its curve in the radius
plot, its row in the table and the stage pictures.

plotly.js takes about 4.6 MB of each page.  Several reports side by side (one per scan of a batch)
can share one copy instead: :func:`write_plotly_js` writes it once, as ``plotly.min.js``, and each
page refers to it by a relative address (``plotly_js="../plotly.min.js"``); they still work offline,
as long as the folder is kept together.

plotly and matplotlib are imported only when a report is made; without them an
:class:`~canalsurf.errors.InputError` names the extra to install.

Examples
--------
>>> import canalsurf, canalsurf.report                              # doctest: +SKIP
>>> net = canalsurf.make_network("t-junction", n=8000, rng=1)       # doctest: +SKIP
>>> model = canalsurf.reconstruct(net.points)                       # doctest: +SKIP
>>> canalsurf.report.write_report("report.html", model, net.points, source="t-junction")  # doctest: +SKIP
"""

from __future__ import annotations

import base64
import html
import importlib
import io
import math
from dataclasses import dataclass
from numbers import Real
from typing import Any

import numpy as np

from ._validate import as_points
from .errors import InputError
from .io import atomic_write
from .network import Network, network_mesh
from .refine import footpoints
from .spine import curve_length
from .surface import surface_mesh

__all__ = ["render_report", "write_report", "write_plotly_js", "require_report_extra", "PLOTLY_JS_NAME",
           "MAX_VIEW_POINTS", "MAX_FIGURE_POINTS"]

#: File name of the plotly.js that reports share (:func:`write_plotly_js`), plotly's own name for it.
PLOTLY_JS_NAME = "plotly.min.js"
#: Most input points drawn in the 3-D view and the radius plot (a seeded random subset beyond this):
#: enough to show the noise everywhere on large scans, small enough for a browser to rotate smoothly.
MAX_VIEW_POINTS = 20_000
#: Most points drawn per stage in the PNG figures (matplotlib draws every marker; more only blurs).
MAX_FIGURE_POINTS = 4_000
#: Seed of the subsets above, so that the same model and points give the same page.
SUBSET_SEED = 0
#: Spine samples per branch for the 3-D view and the radius curves.
SPINE_SAMPLES = 400
#: Coarse mesh for the PNG surface panel (mplot3d sorts and draws every triangle in Python): rings
#: shared among the branches by length, at least ``FIGURE_MIN_RINGS`` each, and vertices per ring.
FIGURE_RINGS, FIGURE_MIN_RINGS, FIGURE_AROUND = 96, 12, 16
#: The distance colour scale spans +-(this quantile of |distance| over the points on a tube), so
#: clutter and one stray point do not wash out the colours of all the others.
DISTANCE_QUANTILE = 0.99
#: Size of each stage figure, inches at ``FIGURE_DPI``.
FIGURE_SIZE, FIGURE_DPI = (3.6, 3.4), 100
#: Zoom of the stage figures' 3-D boxes (mplot3d leaves a wide margin around a box at zoom 1).
FIGURE_ZOOM = 1.3
#: Opacity of the surface in the 3-D view (the points inside must stay visible).
SURFACE_OPACITY = 0.35
#: Significant digits of the numbers in the parameter and diagnostic tables.
DIGITS = 6
#: Significant digits in the headline and the branch table (read at a glance; the tables below and
#: model.json hold more).
SHORT_DIGITS = 4
#: Branch colours, a qualitative palette: d3's category10 without its grey, which marks the points on
#: no tube.  Branch i gets colour i mod 9, so colours repeat in larger networks; the legend and the
#: hover text name every branch.
BRANCH_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                  "#bcbd22", "#17becf")
#: Points on no tube (clutter, strays).
NO_TUBE_COLOUR = "#c4c8ce"
#: Spines and radius curves are drawn in their branch's colour darkened to this share of it, so a
#: spine stands out inside its own points.
SPINE_SHADE = 0.6
#: Opacity of the points in the radius plot (thousands overlap there).
RADIUS_POINTS_OPACITY = 0.3
#: Height of the 3-D view and of the radius plot, pixels.
VIEW_HEIGHT, RADIUS_HEIGHT = 640, 380
#: The 3-D view's camera looks from plotly's default direction, (1.25, 1.25, 1.25) with z up, ...
VIEW_DIRECTION = (1.0, 1.0, 1.0)
#: ... through plotly's perspective (gl-plot3d: a vertical field of view of 45 degrees) at a scene
#: of aspect mode "data", whose axes plotly pads by 1/32 of the data's extent on each side.
PLOTLY_FOVY, PLOTLY_AXIS_PAD = math.pi / 4, 1 / 32
#: The camera is placed so the whole drawing fits a 3-D view this many times as wide as it is tall:
#: 830 by 640 pixels, as in a browser window about 1000 pixels wide (the page is at most 1200 wide,
#: less the legend).  In a narrower window the sides may need a scroll to zoom out ...
VIEW_FIT_ASPECT = 1.3
#: ... leaving this share of the view free at its edges.
VIEW_MARGIN = 0.06
#: Rounds of centring the drawing in the view (each moves the centre to the middle of what is seen).
CAMERA_ROUNDS = 3

#: Readable names of the parameters and diagnostics (the key itself is shown on hover); any other key
#: is spelled out by :func:`_label`.
LABELS = {
    "R": "R: neighbour radius",
    "delta": "δ: shrink step",
    "mu": "μ: break portion",
    "tau": "τ: canal normal tolerance (cosine)",
    "H": "H: MLS weighting radius",
    "k": "k: neighbours of the normal estimation",
    "r0": "r₀: first radius estimate",
    "stop": "stopping rules",
    "neighbours": "neighbour search",
    "refine": "branches fitted to their points",
    "n_points": "input points",
    "n_shrink_points": "points in the shrinking subset",
    "n_fit_points": "points in the fitting subset",
    "n_residual_points": "points in the residual subset",
    "iterations": "shrinking moves",
    "break_count": "points that met an opposite normal",
    "stop_rule": "rule that stopped the shrinking",
    "points_reached_spine": "points that reached the spine",
    "eq6_radius": "radius by Eq. (6)",
    "n_branches": "branches",
    "n_junctions": "junctions",
    "n_components": "separate networks",
    "no_tube_share": "points on no tube",
    "rms_residual": "RMS distance from the surface, all points",
    "inlier_rms_residual": "RMS distance from the surface, points on a tube",
    "noise_sigma": "noise (robust deviation of the distances)",
    "stray_share": "stray points",
    "angular_coverage": "angular coverage (median over the branches)",
    "one_sided": "seen from one side only",
    "spine_segments": "spine knot intervals",
    "radius_segments": "radius knot intervals",
    "quality": "quality (good, check or poor)",
    "quality_reasons": "why the quality is not good",
    "scan_noise": "scan noise (from neighbour planes and coordinate steps)",
}
#: Prefix of the readable name of a stage's time, ``seconds.<stage>`` in the diagnostics.
TIME_LABEL = "time: "
#: How values of some keys read: shares as percentages, angles in degrees.
_SHARES = frozenset({"no_tube_share", "stray_share"})
_DEGREES = frozenset({"angular_coverage"})

_MISSING_EXTRA = "writing report.html needs the 'report' extra — pip install 'canalsurf[report]'"


def _import(module: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError:
        raise InputError(_MISSING_EXTRA) from None


def require_report_extra() -> None:
    """Raise :class:`~canalsurf.errors.InputError` naming the 'report' extra if plotly or matplotlib
    cannot be imported (lets a caller fail before any work is done)."""
    for module in ("plotly.graph_objects", "plotly.offline", "matplotlib"):
        _import(module)


def write_report(path, model, points, *, source: str | None = None, plotly_js: str | None = None) -> None:
    """Write the HTML report of ``model`` reconstructed from ``points`` to ``path`` (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.html`` file to write; its folder must exist.
    model : Network or CanalModel
        The reconstruction (:func:`canalsurf.reconstruct` returns a network; a single tube is a
        network of one branch).  Stage figures are drawn for the stages it holds (``model.stages``,
        set by :func:`canalsurf.reconstruct`, not by :func:`canalsurf.load_model`).
    points : array_like, shape (N, 3)
        The input points, in the model's units.
    source : str, optional
        Name of the input shown in the title (e.g. its file name).
    plotly_js : str, optional
        Address of a shared plotly.js, relative to the page (``"../plotly.min.js"``, written by
        :func:`write_plotly_js`), instead of a copy of it in the page.  Default: the page holds its
        own copy and stands alone.

    Raises
    ------
    InputError
        plotly or matplotlib is missing, the points are invalid, or the folder cannot be written.
    """
    text = render_report(model, points, source=source, plotly_js=plotly_js)
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_plotly_js(path) -> None:
    """Write the plotly.js of the installed plotly (minified, about 4.6 MB) to ``path``, atomically:
    the script that reports rendered with ``plotly_js`` refer to.

    Raises
    ------
    InputError
        plotly is missing, or the folder cannot be written.
    """
    script = _import("plotly.offline").get_plotlyjs()
    atomic_write(path, lambda tmp: tmp.write_text(script, encoding="utf-8"))


def render_report(model, points, *, source: str | None = None, plotly_js: str | None = None) -> str:
    """The HTML report of ``model`` reconstructed from ``points``, as one string (see the module doc).

    Parameters are as for :func:`write_report`.  The page needs no network: every script and picture is
    inside it (or, with ``plotly_js``, plotly.js beside it).  The same model and points give the same
    page (the point subsets are seeded).
    """
    require_report_extra()
    go = importlib.import_module("plotly.graph_objects")
    plotly_offline = importlib.import_module("plotly.offline")
    points = as_points(points, min_points=1)
    network = _as_network(model)

    rng = np.random.default_rng(SUBSET_SEED)
    view = _subset(points, MAX_VIEW_POINTS, rng)
    label, distance = network.classify(view)
    branches = _branches(network, label)
    try:
        mesh = network_mesh(network)
    except InputError:  # no envelope: the report still shows the points and the spines
        mesh = None
    name = source or f"{len(points)} points"

    viewer = _viewer_figure(go, network, branches, view, label, distance, mesh)
    radius_plot = _radius_figure(go, branches, view)
    stages = _stage_pngs(network, branches, points, rng)
    shown = len(view) < len(points)

    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>canalsurf report — {_e(name)}</title>",
        f"<style>{_CSS}</style>",
        (f'<script type="text/javascript">{plotly_offline.get_plotlyjs()}</script>' if plotly_js is None
         else f'<script type="text/javascript" src="{_e(plotly_js)}" charset="utf-8"></script>'),
        "</head><body>",
        f"<h1>canalsurf report — {_e(name)}</h1>",
        f'<p class="summary">{_e(_describe(network, branches, len(points)))}</p>',
        _headline(network, branches, label, distance),
        "<h2>Branches</h2>",
        _branch_table(branches, distance, len(view) if shown else None),
        "<h2>Points, spines and surface</h2>",
        f"<p>{_e(_view_caption(network, view, points, label, distance, mesh))}</p>",
        f'<div class="plot" style="height: {VIEW_HEIGHT}px">',
        viewer.to_html(full_html=False, include_plotlyjs=False, div_id="viewer-3d",
                       config={"displaylogo": False, "responsive": True}),
        "</div>",
        "<h2>Radius along each branch</h2>",
        f'<div class="plot" style="height: {RADIUS_HEIGHT}px">',
        radius_plot.to_html(full_html=False, include_plotlyjs=False, div_id="radius-plot",
                            config={"displaylogo": False, "responsive": True}),
        "</div>",
        "<h2>Stages</h2>",
        _stages_html(stages),
        '<div class="tables">',
        _table("Parameters", network.parameters),
        _table("Diagnostics", network.diagnostics),
        "</div>",
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


# --------------------------------------------------------------------------------------------------
# the network and its branches


def _as_network(model) -> Network:
    """A :class:`Network` as it is; a single :class:`CanalModel` as a network of one branch."""
    if isinstance(model, Network):
        return model
    return Network([model], [], dict(model.parameters), dict(model.diagnostics), stages=model.stages)


@dataclass
class _Branch:
    """What the report shows of one branch: its model, name, colour, spine samples and points."""

    model: Any
    name: str
    colour: str
    length: float
    t: np.ndarray        # SPINE_SAMPLES parameters, 0..1 (normalised arc length)
    spine: np.ndarray    # C(t)
    radius: np.ndarray   # r(t)
    on: np.ndarray       # indices of the shown points that lie on it

    @property
    def dark(self) -> str:
        return _shade(self.colour, SPINE_SHADE)


def _branches(network: Network, label: np.ndarray) -> list[_Branch]:
    ts = np.linspace(0.0, 1.0, SPINE_SAMPLES)
    return [_Branch(b, f"branch {b.id} ({b.kind})", BRANCH_COLOURS[i % len(BRANCH_COLOURS)],
                    curve_length(b.spine), ts, b.spine(ts), b.radius(ts), np.flatnonzero(label == b.id))
            for i, b in enumerate(network.branches)]


def _shade(colour: str, share: float) -> str:
    """``#rrggbb`` darkened to ``share`` of each channel."""
    rgb = [round(int(colour[i:i + 2], 16) * share) for i in (1, 3, 5)]
    return "#" + "".join(f"{c:02x}" for c in rgb)


def _mean_radius(branches: list[_Branch]) -> float:
    """Radius averaged along all spines (weighted by length)."""
    lengths = np.array([b.length for b in branches])
    means = np.array([float(np.mean(b.radius)) for b in branches])
    return float(np.sum(lengths * means) / np.sum(lengths)) if lengths.sum() > 0 else float(means.mean())


# --------------------------------------------------------------------------------------------------
# words and tables


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _num(value, digits: int = DIGITS) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.{digits}g}" if math.isfinite(value) else str(float(value))
    return str(value)


def _short(value) -> str:
    return _num(value, SHORT_DIGITS)


def _number(value) -> float | None:
    """``value`` as a finite float, or ``None`` (missing, not a number, NaN)."""
    if isinstance(value, Real) and not isinstance(value, (bool, np.bool_)) and math.isfinite(value):
        return float(value)
    return None


def _percent(share: float) -> str:
    return f"{100 * share:.3g} %"


def _plural(n: int, word: str) -> str:
    return f"{n} {word if n == 1 else word + 's'}"


def _describe(network: Network, branches: list[_Branch], n_points: int) -> str:
    """The result in one sentence: the tube itself when it is one, else the network's shape."""
    if len(branches) == 1:
        b = branches[0]
        spine = f"{'a closed' if b.model.closed else 'an open'} spine of length {_num(b.length)}"
        if b.model.kind == "pipe":
            shape = f"A pipe surface of constant radius {_num(float(b.radius[0]))}"
        else:
            shape = (f"A canal surface whose radius varies from {_num(float(b.radius.min()))} to "
                     f"{_num(float(b.radius.max()))} (mean {_num(float(b.radius.mean()))})")
        return f"{shape} around {spine}, reconstructed from {n_points} points."
    n_junctions, n_networks = len(network.junctions), len(network.components)
    meeting = (f"meeting at {_plural(n_junctions, 'junction')}, in {_plural(n_networks, 'separate network')}"
               if n_junctions else "meeting nowhere")
    return (f"A network of {len(branches)} branches ({_kinds(branches)}) {meeting}; spines "
            f"{_short(sum(b.length for b in branches))} long in all, reconstructed from {n_points} points.")


def _kinds(branches: list[_Branch]) -> str:
    """``3 pipes``, ``1 pipe, 2 canals``: the kinds there are."""
    kinds = [b.model.kind for b in branches]
    return ", ".join(_plural(kinds.count(k), k) for k in ("pipe", "canal") if k in kinds)


def _headline(network: Network, branches: list[_Branch], label: np.ndarray, distance: np.ndarray) -> str:
    """The numbers to read first: the network's shape, the clutter, the fit and the scan's coverage.

    The whole-scan diagnostics of :func:`canalsurf.reconstruct` are used where present; a model made
    otherwise is measured on the points shown.
    """
    d = network.diagnostics
    on = label >= 0
    share = _number(d.get("no_tube_share"))
    if share is None:
        share = float(np.mean(~on))
    rms = _number(d.get("inlier_rms_residual"))
    if rms is None and on.any():
        rms = float(np.sqrt(np.mean(distance[on] ** 2)))
    mean_r = _mean_radius(branches)
    coverage, one_sided = _number(d.get("angular_coverage")), d.get("one_sided")

    n_j, n_c = len(network.junctions), len(network.components)
    quality = d.get("quality")
    stats = [] if quality is None else [
        (str(quality), "quality", "; ".join(d.get("quality_reasons") or []) or "no reason for doubt "
         "(see docs/quality.md)")]
    stats += [
        (str(len(branches)), "branch" if len(branches) == 1 else "branches", _kinds(branches)),
        (str(n_j), "junction" if n_j == 1 else "junctions", "where branch ends meet"),
        (str(n_c), "separate network" if n_c == 1 else "separate networks", "not touching each other"),
        (_percent(share), "of the points on no tube", "clutter and strays (grey in the 3-D view)"),
    ]
    if rms is None:
        stats.append(("—", "inlier RMS", "no point lies on a tube"))
    else:
        stats.append((_short(rms), "inlier RMS",
                      f"{_percent(rms / mean_r)} of the mean radius {_short(mean_r)}; the RMS distance "
                      "of the points on a tube from it"))
    if coverage is None:
        stats.append(("—", "angular coverage", "not measured"))
    else:
        seen = ("one-sided: the scan saw the tubes from one side only" if one_sided
                else "seen all around")
        stats.append((f"{coverage:.0f}°", "angular coverage", f"median over the branches; {seen}"))
    cells = "".join(
        f'<div class="stat"><span class="value">{_e(value)}</span> <span class="what">{_e(what)}</span>'
        f' <span class="note">{_e(note)}</span></div>' for value, what, note in stats)
    return f'<div class="headline" id="headline">{cells}</div>'


def _branch_table(branches: list[_Branch], distance: np.ndarray, n_shown: int | None) -> str:
    """One row per branch: colour, kind, radius, length, ends, points, inlier RMS, coverage."""
    points = "points" if n_shown is None else f"points (of the {n_shown} shown)"
    head = "".join(f"<th>{_e(h)}</th>" for h in (
        "branch", "kind", "radius", "length", "ends", points, "inlier RMS", "angular coverage"))
    rows = []
    for b in branches:
        m, diag = b.model, b.model.diagnostics
        if m.kind == "pipe":
            radius = _short(float(np.mean(b.radius)))
        else:
            radius = (f"{_short(float(np.mean(b.radius)))} ({_short(float(b.radius.min()))}–"
                      f"{_short(float(b.radius.max()))})")
        ends = "closed loop" if m.closed else ", ".join(
            "open" if e is None else f"junction {e}" for e in m.ends)
        rms = _number(diag.get("inlier_rms_residual"))
        if rms is None and len(b.on):
            rms = float(np.sqrt(np.mean(distance[b.on] ** 2)))
        coverage = _number(diag.get("angular_coverage"))
        seen = "—" if coverage is None else f"{coverage:.0f}°"
        if diag.get("one_sided"):
            seen += " (one-sided)"
        cells = [f'<span class="swatch" style="background:{b.colour}"></span>branch {m.id}', _e(m.kind),
                 _e(radius), _e(_short(b.length)), _e(ends), str(len(b.on)),
                 "—" if rms is None else _e(_short(rms)), _e(seen)]
        rows.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    return (f'<table id="branches" class="branches"><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(rows)}</tbody></table>')


def _view_caption(network, view, points, label, distance, mesh) -> str:
    shown = (f"all {len(points)} input points" if len(view) == len(points)
             else f"{len(view)} of the {len(points)} input points (a random subset)")
    on = label >= 0
    median = f"{_short(float(np.median(np.abs(distance[on]))))}" if on.any() else "—"
    junctions = ", the junctions (black diamonds)" if network.junctions else ""
    surface = "the surface (semi-transparent)" if mesh is not None else "no surface (it cannot be meshed)"
    return (f"Shown: {shown}, in the colour of the branch they lie on (light grey: on no tube), each "
            f"branch's spine (darker){junctions} and {surface}.  The buttons colour the points by their "
            f"signed distance from the surface instead (red outside, blue inside; median |distance| of "
            f"the points on a tube {median}); hovering over a point shows both.  Drag to rotate, scroll "
            "to zoom, click a legend entry to hide it.")


def _label(key: str) -> str:
    """A readable name for a parameter or diagnostic key: :data:`LABELS`, ``seconds.x`` as
    ``time: x (s)``, else the snake_case spelled out (``n_x`` as ``number of x``)."""
    if key in LABELS:
        return LABELS[key]
    if key.startswith("seconds."):
        return f"{TIME_LABEL}{key[len('seconds.'):].replace('_', ' ')} (s)"
    words = key.replace(".", ": ").split("_")
    if words[0] == "n" and len(words) > 1:
        words = ["number of", *words[1:]]
    return " ".join(words)


def _flatten(mapping: dict, prefix: str = "") -> list[tuple[str, Any]]:
    rows = []
    for key, value in mapping.items():
        if isinstance(value, dict):
            rows.extend(_flatten(value, f"{prefix}{key}."))
        else:
            rows.append((f"{prefix}{key}", value))
    return rows


def _table(title: str, mapping: dict) -> str:
    rows = "".join(f'<tr><th title="{_e(k)}">{_e(_label(k))}</th><td>{_e(_cell(k, v))}</td></tr>'
                   for k, v in _flatten(mapping or {}))
    body = rows or '<tr><td colspan="2">(none recorded)</td></tr>'
    return f'<table id="{_e(title.lower())}"><caption>{_e(title)}</caption>{body}</table>'


def _cell(key: str, value) -> str:
    if isinstance(value, (list, tuple, np.ndarray)):
        return ", ".join(_num(v) for v in np.ravel(value))
    if value is None:
        return "—"
    number = _number(value)
    if number is not None and key in _SHARES:
        return _percent(number)
    if number is not None and key in _DEGREES:
        return f"{_num(number)}°"
    return _num(value)


# --------------------------------------------------------------------------------------------------
# plotly figures


def _subset(points: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    if len(points) <= limit:
        return points
    return points[np.sort(rng.choice(len(points), limit, replace=False))]


def _rounded(values: np.ndarray) -> list:
    """Plain floats of 4 significant digits, ``None`` for no number (for the colour buttons, which are
    written out as JSON text)."""
    return [float(f"{v:.4g}") if math.isfinite(v) else None for v in values]


def _viewer_figure(go, network, branches, view, label, distance, mesh):
    """Points by branch (grey: on no tube), spines, junctions, surface; buttons switch the points to
    their signed distance from the surface."""
    on = label >= 0
    scale = float(np.quantile(np.abs(distance[on]), DISTANCE_QUANTILE)) if on.any() else 1.0
    scale = scale if math.isfinite(scale) and scale > 0 else 1.0
    where = "(%{x:.4g}, %{y:.4g}, %{z:.4g})"

    traces, groups = [], []  # groups: (trace index, colour, distances) of each point trace
    for b in branches:
        groups.append((len(traces), b.colour, distance[b.on]))
        traces.append(go.Scatter3d(
            x=view[b.on, 0], y=view[b.on, 1], z=view[b.on, 2], mode="markers", name=b.name,
            legendgroup=b.name, marker={"size": 2, "color": b.colour}, customdata=distance[b.on],
            hovertemplate=f"{b.name}<br>{where}<br>distance from the surface %{{customdata:.3g}}"
                          "<extra></extra>"))
    for b in branches:
        traces.append(go.Scatter3d(
            x=b.spine[:, 0], y=b.spine[:, 1], z=b.spine[:, 2], mode="lines", name=f"{b.name} spine",
            legendgroup=b.name, showlegend=False, line={"color": b.dark, "width": 6},
            customdata=np.column_stack([b.t * b.length, b.radius]),
            hovertemplate=f"{b.name} spine<br>{where}<br>arc length %{{customdata[0]:.4g}}, "
                          "radius %{customdata[1]:.4g}<extra></extra>"))
    off = np.flatnonzero(~on)
    if len(off):
        groups.append((len(traces), NO_TUBE_COLOUR, distance[off]))
        traces.append(go.Scatter3d(
            x=view[off, 0], y=view[off, 1], z=view[off, 2], mode="markers", name="no tube",
            marker={"size": 2, "color": NO_TUBE_COLOUR}, customdata=distance[off],
            hovertemplate=f"on no tube<br>{where}<br>distance from the nearest surface "
                          "%{customdata:.3g}<extra></extra>"))
    if network.junctions:
        pts = np.array([j.point for j in network.junctions], dtype=float)
        text = [f"junction {j.id}: branches {', '.join(str(b) for b in sorted({b for b, _ in j.ends}))}"
                for j in network.junctions]
        traces.append(go.Scatter3d(
            x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], mode="markers", name="junctions", text=text,
            marker={"size": 8, "color": "black", "symbol": "diamond"},
            hovertemplate="%{text}<br>" + where + "<extra></extra>"))
    if mesh is not None:
        vertices, faces = mesh
        traces.append(go.Mesh3d(
            x=vertices[:, 0], y=vertices[:, 1], z=vertices[:, 2], i=faces[:, 0], j=faces[:, 1],
            k=faces[:, 2], name="surface", showlegend=True, color="#8fa8c8", opacity=SURFACE_OPACITY,
            flatshading=False, hoverinfo="skip"))

    indices = [i for i, _, _ in groups]
    by_branch = [{"marker.color": [c for _, c, _ in groups], "marker.coloraxis": [None] * len(groups)},
                 {}, indices]
    by_distance = [{"marker.color": [_rounded(d) for _, _, d in groups],
                    "marker.coloraxis": ["coloraxis"] * len(groups)}, {}, indices]
    fig = go.Figure(traces)
    fig.update_layout(
        template="plotly_white", height=VIEW_HEIGHT, margin={"l": 0, "r": 0, "t": 10, "b": 0},
        scene={"aspectmode": "data", "camera": _camera(_drawn(view, branches, network, mesh))},
        legend={"itemsizing": "constant"},
        coloraxis={"colorscale": "RdBu", "reversescale": True, "cmin": -scale, "cmax": scale,
                   "colorbar": {"title": {"text": "signed distance<br>(+ outside)"}, "thickness": 14,
                                "len": 0.5, "x": 0.0, "xanchor": "left"}},
        updatemenus=[{"type": "buttons", "direction": "right", "x": 0.0, "xanchor": "left", "y": 1.0,
                      "yanchor": "top", "showactive": True, "active": 0, "pad": {"l": 4, "t": 4},
                      "buttons": [{"label": "colour by branch", "method": "update", "args": by_branch},
                                  {"label": "colour by distance from the surface", "method": "update",
                                   "args": by_distance}]}])
    return fig


def _drawn(view, branches, network, mesh) -> np.ndarray:
    """Every point the 3-D view draws: the points, spines, junctions and mesh vertices."""
    parts = [view, *(b.spine for b in branches)]
    parts.append(np.array([j.point for j in network.junctions], dtype=float).reshape(-1, 3))
    if mesh is not None:
        parts.append(mesh[0])
    return np.concatenate(parts)


def _camera(drawn: np.ndarray) -> dict:
    """A plotly scene camera (aspect mode "data") whose first view holds every point of ``drawn``.

    Plotly scales the data by one factor, ``1 / cbrt(product of the extents)`` shrunk by the padding
    of ``PLOTLY_AXIS_PAD`` of the extent on each side, about the middle of its box, and looks at
    ``center`` from ``eye`` through a perspective of ``PLOTLY_FOVY``.  Its default, the eye at
    (1.25, 1.25, 1.25) and the center at the origin, suits a cube; a long tube (a 7 m stem of 5 cm
    radius) or a wide elbow runs off that view.  Here the eye keeps the default direction, the center
    moves to the middle of the drawing as seen from there, and the eye comes as near as the points
    allow: each must lie inside a view of aspect ``VIEW_FIT_ASPECT`` less ``VIEW_MARGIN`` at its edges.
    """
    lo, hi = drawn.min(axis=0), drawn.max(axis=0)
    extent = hi - lo
    extent = np.maximum(extent, 1e-9 * extent.max()) if extent.max() > 0 else np.ones(3)
    q = (drawn - (lo + hi) / 2) / (np.cbrt(np.prod(extent)) * (1 + 2 * PLOTLY_AXIS_PAD))
    back = np.asarray(VIEW_DIRECTION, float) / np.linalg.norm(VIEW_DIRECTION)  # centre -> eye
    right = np.cross(-back, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, -back)
    frame = np.stack([right, up, back])
    coords = q @ frame.T
    centre = frame.T @ ((coords.min(axis=0) + coords.max(axis=0)) / 2)
    # A point at depth D - z in front of an eye at distance D from the centre is inside the view
    # when its offsets across it are within tan_half (times the aspect, sideways) of that depth.
    wide, tall = math.tan(PLOTLY_FOVY / 2) * (1 - VIEW_MARGIN) * np.array([VIEW_FIT_ASPECT, 1.0])
    for _ in range(CAMERA_ROUNDS):
        x, y, z = ((q - centre) @ frame.T).T
        distance = float(np.max(z + np.maximum(np.abs(x) / wide, np.abs(y) / tall)))
        # Perspective shows the near side larger: move the centre across the view to the middle of
        # what the eye sees, at the depth of the centre.
        seen_x, seen_y = x / (wide * (distance - z)), y / (tall * (distance - z))
        centre = centre + distance * (right * wide * (seen_x.min() + seen_x.max()) / 2
                                      + up * tall * (seen_y.min() + seen_y.max()) / 2)
    x, y, z = ((q - centre) @ frame.T).T
    distance = float(np.max(z + np.maximum(np.abs(x) / wide, np.abs(y) / tall)))
    eye = centre + back * distance
    return {"eye": dict(zip("xyz", map(float, eye))), "center": dict(zip("xyz", map(float, centre))),
            "up": {"x": 0.0, "y": 0.0, "z": 1.0}, "projection": {"type": "perspective"}}


def _radius_figure(go, branches, view):
    """r over arc length per branch, with each of its points' distance from the spine at its footpoint
    (= r + the point's signed distance from the surface)."""
    traces = []
    for b in branches:
        if len(b.on):
            m = b.model
            t, signed = footpoints(view[b.on], m.spine, m.radius, closed=m.closed)
            traces.append(go.Scattergl(
                x=t * b.length, y=m.radius(t) + signed, mode="markers", name=f"{b.name}: points",
                legendgroup=b.name, showlegend=False,
                marker={"size": 3, "color": b.colour, "opacity": RADIUS_POINTS_OPACITY},
                hovertemplate=f"{b.name} point<br>arc length %{{x:.4g}}<br>distance from the spine "
                              "%{y:.4g}<extra></extra>"))
    for b in branches:
        traces.append(go.Scatter(
            x=b.t * b.length, y=b.radius, mode="lines", name=b.name, legendgroup=b.name,
            line={"color": b.dark, "width": 3},
            hovertemplate=f"{b.name}<br>arc length %{{x:.4g}}<br>r %{{y:.4g}}<extra></extra>"))
    fig = go.Figure(traces)
    fig.update_layout(template="plotly_white", height=RADIUS_HEIGHT,
                      margin={"l": 60, "r": 10, "t": 10, "b": 50},
                      xaxis={"title": {"text": "arc length along the branch, from its t = 0 end"},
                             "rangemode": "tozero"},
                      yaxis={"title": {"text": "radius; dots: the points' distance from the spine"},
                             "rangemode": "tozero"},
                      legend={"itemsizing": "constant"})
    return fig


# --------------------------------------------------------------------------------------------------
# matplotlib stage figures


def _stage_pngs(network, branches, points, rng) -> list[tuple[str, str, str]]:
    """(title, caption, base64 PNG) per stage, all drawn in the same frame like the paper's figures."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    stages = network.stages or {}
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    half = np.maximum(half, 1e-3 * max(float(half.max()), 1e-300))
    single = len(branches) == 1

    def scatter(ax, pts, colour, size):
        pts = _subset(np.asarray(pts, float), MAX_FIGURE_POINTS, rng)
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=size, c=colour, depthshade=False, linewidths=0)

    def faint_input(ax):
        scatter(ax, points, "#c8ccd4", 1.0)

    def spine_lines(ax):
        for b in branches:
            ax.plot(b.spine[:, 0], b.spine[:, 1], b.spine[:, 2], color="black" if single else b.dark, lw=1.8)
        if network.junctions:
            j = np.array([x.point for x in network.junctions], dtype=float)
            ax.scatter(j[:, 0], j[:, 1], j[:, 2], s=16, c="black", marker="D", depthshade=False)

    panels = [("S", f"input S, {len(points)} points", lambda ax: scatter(ax, points, "#34495e", 1.5))]
    if "shrunk" in stages:
        shrunk = stages["shrunk"]
        panels.append(("Ŝ", f"shrunk Ŝ, {len(shrunk)} points",
                       lambda ax: (faint_input(ax), scatter(ax, shrunk, "#2471a3", 2.0))))
    if "thin" in stages:
        thin = stages["thin"]
        panels.append(("S̃", f"thinned S̃, {len(thin)} points",
                       lambda ax: (faint_input(ax), scatter(ax, thin, "#1e8449", 3.0))))
    if single:
        spines = f"spine C(t), {'closed' if branches[0].model.closed else 'open'}"
    else:
        spines = (f"spines C(t) of {len(branches)} branches, "
                  f"{_plural(len(network.junctions), 'junction')}")
    panels.append(("spine", spines, lambda ax: (faint_input(ax), spine_lines(ax))))
    tris, colours = _figure_mesh(branches)
    if len(tris):
        surfaces = (f"{branches[0].model.kind} surface" if single
                    else f"surfaces of the {len(branches)} branches")
        panels.append(("surface", surfaces,
                       lambda ax: ax.add_collection3d(Poly3DCollection(
                           tris, facecolors=colours, edgecolors="#5d7391", linewidths=0.15,
                           alpha=0.9, shade=True))))

    out = []
    for key, caption, draw in panels:
        fig = Figure(figsize=FIGURE_SIZE, dpi=FIGURE_DPI)
        FigureCanvasAgg(fig)
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0), projection="3d")
        draw(ax)
        ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
        ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
        ax.set_zlim(centre[2] - half[2], centre[2] + half[2])
        ax.set_box_aspect(tuple(half / half.max()), zoom=FIGURE_ZOOM)
        ax.set_axis_off()
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=FIGURE_DPI)
        out.append((key, caption, base64.b64encode(buffer.getvalue()).decode("ascii")))
    return out


def _figure_mesh(branches: list[_Branch]) -> tuple[np.ndarray, list]:
    """Triangles of coarse tubes around every branch (one collection, so mplot3d sorts them all
    together) and each triangle's colour: a single tube in the report's surface colour, a network's
    branches in theirs."""
    total = sum(b.length for b in branches) or 1.0
    tris, colours = [], []
    for b in branches:
        rings = max(FIGURE_MIN_RINGS, math.ceil(FIGURE_RINGS * b.length / total))
        try:
            vertices, faces = surface_mesh(b.model.spine, b.model.radius, closed=b.model.closed,
                                           n_along=rings, n_around=FIGURE_AROUND)
        except InputError:  # no envelope: that branch is left out of the picture
            continue
        tris.append(vertices[faces])
        colours += ["#8fa8c8" if len(branches) == 1 else b.colour] * len(faces)
    return (np.concatenate(tris) if tris else np.empty((0, 3, 3))), colours


def _stages_html(stages) -> str:
    cells = "".join(
        f'<figure><img alt="{_e(caption)}" src="data:image/png;base64,{png}">'
        f"<figcaption>{_e(caption)}</figcaption></figure>" for _, caption, png in stages)
    return f'<div class="stages">{cells}</div>'


_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5rem auto;
       max-width: 1200px; padding: 0 1rem; color: #222; }
h1 { font-size: 1.5rem; margin-bottom: 0.3rem; }
h2 { font-size: 1.15rem; margin-top: 1.8rem; border-bottom: 1px solid #ddd; }
.summary { font-size: 1.05rem; }
.headline { display: flex; flex-wrap: wrap; gap: 0.6rem; }
.stat { border: 1px solid #e3e3e3; border-radius: 6px; padding: 0.45rem 0.7rem; flex: 1 1 150px;
        max-width: 260px; }
.stat .value { font-size: 1.45rem; font-weight: 600; font-variant-numeric: tabular-nums; }
.stat .what { font-weight: 600; }
.stat .note { display: block; font-size: 0.8rem; color: #666; margin-top: 0.15rem; }
.plot { border: 1px solid #eee; }
.stages { display: flex; flex-wrap: wrap; gap: 0.5rem; }
.stages figure { margin: 0; border: 1px solid #eee; text-align: center; flex: 1 1 200px; max-width: 360px; }
.stages img { width: 100%; height: auto; display: block; }
.stages figcaption { font-size: 0.85rem; padding: 0.2rem; }
.tables { display: flex; flex-wrap: wrap; gap: 2rem; margin-top: 1.8rem; }
table { border-collapse: collapse; font-size: 0.9rem; }
caption { text-align: left; font-weight: bold; padding-bottom: 0.3rem; }
th, td { border-bottom: 1px solid #eee; padding: 0.15rem 0.8rem 0.15rem 0; text-align: left; }
th { font-weight: 600; }
th[title] { cursor: help; }
td { font-variant-numeric: tabular-nums; }
table.branches th { border-bottom: 1px solid #ccc; }
.swatch { display: inline-block; width: 0.8em; height: 0.8em; border-radius: 2px; margin-right: 0.4em;
          vertical-align: -0.05em; }
"""
