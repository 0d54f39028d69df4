"""A self-contained HTML report of one reconstruction (the optional ``report`` extra).

:func:`render_report` builds, and :func:`write_report` writes, a single HTML file that works offline --
plotly.js is embedded in the page and the figures are PNG ``data:`` URIs -- with

* an interactive 3-D view (plotly): the input points coloured by their signed distance from the
  reconstructed surface (:func:`canalsurf.refine.footpoints`; positive outside), the spine and the
  semi-transparent surface mesh;
* the radius along the spine, r(t) over the normalised arc length t, with each point's distance from
  the spine at its footpoint (the radius that point alone would give);
* the parameters used and the diagnostics (iterations, stop rule, residuals, seconds per stage);
* PNG small multiples of the stages as in the paper's figures (matplotlib): the input S, the shrunk
  cloud S-hat, the thinned cloud S-tilde, the spine and the surface.

plotly and matplotlib are imported only when a report is made; without them an
:class:`~canalsurf.errors.InputError` names the extra to install.

Examples
--------
>>> import canalsurf, canalsurf.report                              # doctest: +SKIP
>>> tube = canalsurf.make_tube("fig9-pipe", rng=1)                  # doctest: +SKIP
>>> model = canalsurf.reconstruct(tube.points)                      # doctest: +SKIP
>>> canalsurf.report.write_report("report.html", model, tube.points, source="fig9-pipe")  # doctest: +SKIP
"""

from __future__ import annotations

import base64
import html
import importlib
import io
import math
from typing import Any

import numpy as np

from ._validate import as_points
from .errors import InputError
from .io import atomic_write
from .refine import footpoints
from .spine import curve_length
from .surface import surface_mesh

__all__ = ["render_report", "write_report", "require_report_extra", "MAX_VIEW_POINTS", "MAX_FIGURE_POINTS"]

#: Most input points drawn in the 3-D view and the radius plot (a seeded random subset beyond this):
#: enough to show the noise everywhere on large scans, small enough for a browser to rotate smoothly.
MAX_VIEW_POINTS = 20_000
#: Most points drawn per stage in the PNG figures (matplotlib draws every marker; more only blurs).
MAX_FIGURE_POINTS = 4_000
#: Seed of the subsets above, so that the same model and points give the same page.
SUBSET_SEED = 0
#: Spine samples for the 3-D view and the radius curve.
SPINE_SAMPLES = 400
#: Coarse mesh for the PNG surface panel (mplot3d sorts and draws every triangle in Python).
FIGURE_RINGS, FIGURE_AROUND = 96, 16
#: The distance colour scale spans +-(this quantile of |distance|), so one stray point does not wash
#: out the colours of all the others.
DISTANCE_QUANTILE = 0.99
#: Size of each stage figure, inches at ``FIGURE_DPI``.
FIGURE_SIZE, FIGURE_DPI = (3.6, 3.4), 100
#: Zoom of the stage figures' 3-D boxes (mplot3d leaves a wide margin around a box at zoom 1).
FIGURE_ZOOM = 1.3
#: Opacity of the surface in the 3-D view (the points inside must stay visible).
SURFACE_OPACITY = 0.35
#: Significant digits of the numbers in the tables and the text.
DIGITS = 6

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


def write_report(path, model, points, *, source: str | None = None) -> None:
    """Write the HTML report of ``model`` reconstructed from ``points`` to ``path`` (atomically).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.html`` file to write; its folder must exist.
    model : CanalModel
        The reconstruction.  Stage figures are drawn for the stages it holds (``model.stages``, set
        by :func:`canalsurf.reconstruct`, not by :func:`canalsurf.load_model`).
    points : array_like, shape (N, 3)
        The input points, in the model's units.
    source : str, optional
        Name of the input shown in the title (e.g. its file name).

    Raises
    ------
    InputError
        plotly or matplotlib is missing, the points are invalid, or the folder cannot be written.
    """
    text = render_report(model, points, source=source)
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def render_report(model, points, *, source: str | None = None) -> str:
    """The HTML report of ``model`` reconstructed from ``points``, as one string (see the module doc).

    Parameters are as for :func:`write_report`.  The page needs no network: every script and picture is
    inside it.  The same model and points give the same page (the point subsets are seeded).
    """
    require_report_extra()
    go = importlib.import_module("plotly.graph_objects")
    plotly_offline = importlib.import_module("plotly.offline")
    points = as_points(points, min_points=1)

    rng = np.random.default_rng(SUBSET_SEED)
    view = _subset(points, MAX_VIEW_POINTS, rng)
    t_view, dist_view = footpoints(view, model.spine, model.radius, closed=model.closed)
    ts = np.linspace(0.0, 1.0, SPINE_SAMPLES)
    spine_pts, spine_r = model.spine(ts), model.radius(ts)
    try:
        mesh = surface_mesh(model.spine, model.radius, closed=model.closed)
    except InputError:  # no envelope: the report still shows the points and the spine
        mesh = None
    length = curve_length(model.spine)
    name = source or f"{len(points)} points"

    viewer = _viewer_figure(go, view, dist_view, spine_pts, spine_r, mesh)
    radius_plot = _radius_figure(go, model, t_view, view, ts, spine_r, length)
    stages = _stage_pngs(model, points, rng)

    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>canalsurf report — {_e(name)}</title>",
        f"<style>{_CSS}</style>",
        f'<script type="text/javascript">{plotly_offline.get_plotlyjs()}</script>',
        "</head><body>",
        f"<h1>canalsurf report — {_e(name)}</h1>",
        f'<p class="summary">{_e(_describe(model, length, len(points)))}</p>',
        "<h2>Points, spine and surface</h2>",
        f"<p>{_e(_view_caption(view, points, dist_view, mesh))}</p>",
        '<div class="plot">',
        viewer.to_html(full_html=False, include_plotlyjs=False, div_id="viewer-3d",
                       config={"displaylogo": False, "responsive": True}),
        "</div>",
        "<h2>Radius along the spine</h2>",
        '<div class="plot small">',
        radius_plot.to_html(full_html=False, include_plotlyjs=False, div_id="radius-plot",
                            config={"displaylogo": False, "responsive": True}),
        "</div>",
        "<h2>Stages</h2>",
        _stages_html(stages),
        '<div class="tables">',
        _table("Parameters", model.parameters),
        _table("Diagnostics", model.diagnostics),
        "</div>",
        "</body></html>",
    ]
    return "\n".join(parts) + "\n"


# --------------------------------------------------------------------------------------------------
# words and tables


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _num(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.{DIGITS}g}" if math.isfinite(value) else str(float(value))
    return str(value)


def _describe(model, length: float, n_points: int) -> str:
    """The model in one sentence: kind, radius, spine."""
    spine = f"{'a closed' if model.closed else 'an open'} spine of length {_num(length)}"
    r = model.radius(np.linspace(0.0, 1.0, SPINE_SAMPLES))
    if model.kind == "pipe":
        shape = f"A pipe surface of constant radius {_num(float(r[0]))}"
    else:
        shape = (f"A canal surface whose radius varies from {_num(float(r.min()))} to "
                 f"{_num(float(r.max()))} (mean {_num(float(r.mean()))})")
    rms = model.diagnostics.get("rms_residual")
    fit = (f"; RMS distance of the points from it {_num(rms)}" if isinstance(rms, (int, float))
           and not isinstance(rms, bool) else "")
    return f"{shape} around {spine}, reconstructed from {n_points} points{fit}."


def _view_caption(view, points, dist, mesh) -> str:
    shown = (f"all {len(points)} input points" if len(view) == len(points)
             else f"{len(view)} of the {len(points)} input points (a random subset)")
    surface = "the surface (semi-transparent)" if mesh is not None else "no surface (it cannot be meshed)"
    return (f"Shown: {shown}, coloured by their signed distance from the surface (red outside, blue "
            f"inside; median |distance| {_num(float(np.median(np.abs(dist))))}), the spine (black) "
            f"and {surface}.  Drag to rotate, scroll to zoom, click a legend entry to hide it.")


def _flatten(mapping: dict, prefix: str = "") -> list[tuple[str, Any]]:
    rows = []
    for key, value in mapping.items():
        if isinstance(value, dict):
            rows.extend(_flatten(value, f"{prefix}{key}."))
        else:
            rows.append((f"{prefix}{key}", value))
    return rows


def _table(title: str, mapping: dict) -> str:
    rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(_cell(v))}</td></tr>" for k, v in _flatten(mapping or {}))
    body = rows or '<tr><td colspan="2">(none recorded)</td></tr>'
    return f'<table id="{_e(title.lower())}"><caption>{_e(title)}</caption>{body}</table>'


def _cell(value) -> str:
    if isinstance(value, (list, tuple, np.ndarray)):
        return ", ".join(_num(v) for v in np.ravel(value))
    if value is None:
        return "—"
    return _num(value)


# --------------------------------------------------------------------------------------------------
# plotly figures


def _subset(points: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    if len(points) <= limit:
        return points
    return points[np.sort(rng.choice(len(points), limit, replace=False))]


def _viewer_figure(go, view, dist, spine_pts, spine_r, mesh):
    scale = float(np.quantile(np.abs(dist), DISTANCE_QUANTILE)) or 1.0
    traces = [go.Scatter3d(
        x=view[:, 0], y=view[:, 1], z=view[:, 2], mode="markers", name="input points",
        marker={"size": 2, "color": dist, "colorscale": "RdBu", "reversescale": True,
                "cmin": -scale, "cmax": scale,
                "colorbar": {"title": {"text": "signed distance<br>(+ outside)"}, "thickness": 14}},
        hovertemplate="(%{x:.4g}, %{y:.4g}, %{z:.4g})<br>distance %{marker.color:.3g}<extra></extra>")]
    if mesh is not None:
        vertices, faces = mesh
        traces.append(go.Mesh3d(
            x=vertices[:, 0], y=vertices[:, 1], z=vertices[:, 2], i=faces[:, 0], j=faces[:, 1],
            k=faces[:, 2], name="surface", showlegend=True, color="#8fa8c8", opacity=SURFACE_OPACITY,
            flatshading=False, hoverinfo="skip"))
    traces.append(go.Scatter3d(
        x=spine_pts[:, 0], y=spine_pts[:, 1], z=spine_pts[:, 2], mode="lines", name="spine",
        line={"color": "black", "width": 6}, customdata=spine_r,
        hovertemplate="spine (%{x:.4g}, %{y:.4g}, %{z:.4g})<br>radius %{customdata:.4g}<extra></extra>"))
    fig = go.Figure(traces)
    fig.update_layout(template="plotly_white", height=640, margin={"l": 0, "r": 0, "t": 10, "b": 0},
                      scene={"aspectmode": "data"}, legend={"x": 0.01, "y": 0.99, "itemsizing": "constant"})
    return fig


def _radius_figure(go, model, t_view, view, ts, spine_r, length):
    # A point's own radius: its distance from the spine at its footpoint, = r(t) + signed distance.
    own = np.linalg.norm(view - model.spine(t_view), axis=1)
    fig = go.Figure([
        go.Scattergl(x=t_view, y=own, mode="markers", name="points: distance from the spine",
                     marker={"size": 3, "color": "rgba(90, 110, 140, 0.35)"},
                     hovertemplate="t %{x:.4f}<br>%{y:.4g}<extra></extra>"),
        go.Scatter(x=ts, y=spine_r, mode="lines", name=f"r(t), {model.kind}",
                   line={"color": "#c0392b", "width": 3},
                   hovertemplate="t %{x:.4f}<br>r %{y:.4g}<extra></extra>"),
    ])
    fig.update_layout(template="plotly_white", height=360, margin={"l": 60, "r": 10, "t": 10, "b": 50},
                      xaxis={"title": {"text": f"t (normalised arc length; spine length {_num(length)})"},
                             "range": [0, 1]},
                      yaxis={"title": {"text": "radius"}, "rangemode": "tozero"},
                      legend={"orientation": "h", "y": 1.08})
    return fig


# --------------------------------------------------------------------------------------------------
# matplotlib stage figures


def _stage_pngs(model, points, rng) -> list[tuple[str, str, str]]:
    """(title, caption, base64 PNG) per stage, all drawn in the same frame like the paper's figures."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    stages = model.stages or {}
    spine_pts = model.spine(np.linspace(0.0, 1.0, SPINE_SAMPLES))
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    half = np.maximum(half, 1e-3 * max(float(half.max()), 1e-300))

    def scatter(ax, pts, colour, size):
        pts = _subset(np.asarray(pts, float), MAX_FIGURE_POINTS, rng)
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=size, c=colour, depthshade=False, linewidths=0)

    def faint_input(ax):
        scatter(ax, points, "#c8ccd4", 1.0)

    def spine_line(ax):
        ax.plot(spine_pts[:, 0], spine_pts[:, 1], spine_pts[:, 2], color="black", lw=1.8)

    panels = [("S", f"input S, {len(points)} points", lambda ax: scatter(ax, points, "#34495e", 1.5))]
    if "shrunk" in stages:
        shrunk = stages["shrunk"]
        panels.append(("Ŝ", f"shrunk Ŝ, {len(shrunk)} points",
                       lambda ax: (faint_input(ax), scatter(ax, shrunk, "#2471a3", 2.0))))
    if "thin" in stages:
        thin = stages["thin"]
        panels.append(("S̃", f"thinned S̃, {len(thin)} points",
                       lambda ax: (faint_input(ax), scatter(ax, thin, "#1e8449", 3.0))))
    panels.append(("spine", f"spine C(t), {'closed' if model.closed else 'open'}",
                   lambda ax: (faint_input(ax), spine_line(ax))))
    try:
        vertices, faces = surface_mesh(model.spine, model.radius, closed=model.closed,
                                       n_along=FIGURE_RINGS, n_around=FIGURE_AROUND)
    except InputError:
        vertices = None
    if vertices is not None:
        tris = vertices[faces]
        panels.append(("surface", f"{model.kind} surface",
                       lambda ax: ax.add_collection3d(Poly3DCollection(
                           tris, facecolors="#8fa8c8", edgecolors="#5d7391", linewidths=0.15,
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
.plot { height: 640px; border: 1px solid #eee; }
.plot.small { height: 360px; }
.stages { display: flex; flex-wrap: wrap; gap: 0.5rem; }
.stages figure { margin: 0; border: 1px solid #eee; text-align: center; flex: 1 1 200px; max-width: 360px; }
.stages img { width: 100%; height: auto; display: block; }
.stages figcaption { font-size: 0.85rem; padding: 0.2rem; }
.tables { display: flex; flex-wrap: wrap; gap: 2rem; margin-top: 1.8rem; }
table { border-collapse: collapse; font-size: 0.9rem; }
caption { text-align: left; font-weight: bold; padding-bottom: 0.3rem; }
th, td { border-bottom: 1px solid #eee; padding: 0.15rem 0.8rem 0.15rem 0; text-align: left; }
td { font-variant-numeric: tabular-nums; }
"""
