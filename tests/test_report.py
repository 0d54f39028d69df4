"""Tests of :mod:`canalsurf.report` and ``canalsurf reconstruct --report``.

The page is checked as a file (one self-contained file, nothing fetched from the network, the
parameters and the stage PNGs in it, the headline and branch table, and the plotly figures' data:
one legend entry and colour per branch, junction markers, the grey points on no tube, a camera that
shows every point drawn) and in a real headless Chromium: it loads from a ``file://`` URL with no
console or page errors and no network request, plotly builds the legend and the junction markers,
the colour buttons work, the 3-D view draws something, and plotly's own camera matrices put every
point of a long thin tube inside the first view.

The browser tests need Debian's Chromium at ``/usr/bin/chromium`` (``.ci/run`` installs it) and
playwright; without either they are skipped, with the reason.
"""

from __future__ import annotations

import base64
import io
import json
import math
import re
import sys
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

import canalsurf
from canalsurf import cli
from canalsurf._outputs import MANIFEST_NAME
from canalsurf.errors import InputError
from canalsurf.model import CanalModel
from canalsurf.spine import constant_spline, curve_length
from canalsurf.network import Network
from canalsurf.pipeline import STAGES
from canalsurf.report import (BRANCH_COLOURS, NO_TUBE_COLOUR, PLOTLY_AXIS_PAD, PLOTLY_FOVY, PLOTLY_JS_NAME,
                              VIEW_FIT_ASPECT, _label, render_report, write_plotly_js, write_report)

#: The browser the report must work in, and how to get it.
CHROMIUM = Path("/usr/bin/chromium")
#: Headless, offline, no first-run or background activity (a fresh profile is added per run).
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: The browser window: the page at its full width (1200 pixels of content).
VIEWPORT = {"width": 1280, "height": 900}
#: Seconds to wait for the page and for plotly's WebGL scene.
PAGE_TIMEOUT = 30
#: The cloud the CLI reconstructs: the paper's Figure 9 pipe (2000 points).
CLOUD = ("fig9-pipe", 1)
#: The networks and the long tube of the network tests: (generator, name, points, seed).
T_JUNCTION = ("network", "t-junction", 8000, 1)
FLOOR_CLUTTER = ("network", "floor-clutter", 8000, 1)
LONG_THIN = ("tube", "long-thin", 4000, 1)
#: Stage pictures of a model straight from the pipeline: S, Ŝ, S̃, spine, surface.
N_STAGE_PNGS = 5
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
#: plotly's default camera (eye at (1.25, 1.25, 1.25), looking at the origin, z up).
PLOTLY_DEFAULT_CAMERA = {"eye": {"x": 1.25, "y": 1.25, "z": 1.25}, "center": {"x": 0, "y": 0, "z": 0},
                         "up": {"x": 0, "y": 0, "z": 1}}


class _Links(HTMLParser):
    """Every script/link/img/iframe/source address of a page, its <title> and <h1>."""

    def __init__(self):
        super().__init__()
        self.urls: list[tuple[str, str, str]] = []
        self.text: dict[str, str] = {}
        self._in: str | None = None

    def handle_starttag(self, tag, attrs):
        for key, value in attrs:
            if key in ("src", "href", "data") and value is not None:
                self.urls.append((tag, key, value))
        self._in = tag if tag in ("title", "h1") else None

    def handle_data(self, data):
        if self._in:
            self.text[self._in] = self.text.get(self._in, "") + data

    def handle_endtag(self, tag):
        self._in = None


def _parse(page: str) -> _Links:
    parser = _Links()
    parser.feed(page)
    return parser


def _words(page: str) -> str:
    """The page's text as a reader sees it: no scripts, no tags, single spaces."""
    text = re.sub(r"<script.*?</script>|<style.*?</style>", " ", page, flags=re.S)
    text = re.sub(r"<[^>]+>", " ", text)
    return re.sub(r"\s+", " ", text.replace("&#x27;", "'").replace("&amp;", "&"))


def _figure(page: str, div_id: str) -> tuple[list, dict]:
    """The data and layout that the page hands to ``Plotly.newPlot`` for ``div_id``."""
    start = re.search(rf'Plotly\.newPlot\(\s*"{div_id}",\s*', page)
    assert start, f"no plotly figure {div_id!r} in the page"
    decoder = json.JSONDecoder()
    data, end = decoder.raw_decode(page, start.end())
    layout, _ = decoder.raw_decode(page, end + re.match(r"\s*,\s*", page[end:]).end())
    return data, layout


def _array(value) -> np.ndarray:
    """A data array of a figure: a JSON list, or plotly's base64 typed array."""
    if isinstance(value, dict) and "bdata" in value:
        array = np.frombuffer(base64.b64decode(value["bdata"]), dtype=np.dtype(value["dtype"]))
        return array.reshape(value["shape"]) if "shape" in value else array
    return np.asarray(value)


def _in_legend(trace: dict) -> bool:
    return trace.get("showlegend", trace["type"] != "mesh3d")  # plotly's defaults


def _project(points: np.ndarray, drawn: np.ndarray, camera: dict, aspect: float) -> np.ndarray:
    """Where plotly draws ``points`` in a 3-D scene of aspect mode "data" that holds ``drawn``:
    normalised view coordinates (x, y in [-1, 1] are inside the view) and the depth before the eye.

    Written from plotly.js's gl3d scene: the axes span the data padded by 1/32 of its extent on each
    side, the "data" aspect ratio is each extent over the cube root of their product, the box of the
    axes is that aspect ratio in size and centred at the origin, and gl-plot3d looks from ``eye`` at
    ``center`` (``up`` upwards) through a perspective of 45 degrees vertically.
    """
    lo, hi = drawn.min(axis=0), drawn.max(axis=0)
    extent = hi - lo
    aspect_ratio = extent / np.cbrt(np.prod(extent))
    q = (points - (lo + hi) / 2) * aspect_ratio / (extent * (1 + 2 * PLOTLY_AXIS_PAD))
    eye, centre, up = (np.array([camera[k][c] for c in "xyz"], float) for k in ("eye", "center", "up"))
    forward = (centre - eye) / np.linalg.norm(centre - eye)
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    top = np.cross(right, forward)
    rel = q - eye
    depth = rel @ forward
    tan_half = math.tan(PLOTLY_FOVY / 2)
    return np.column_stack([rel @ right / (depth * tan_half * aspect), rel @ top / (depth * tan_half), depth])


def _drawn(data: list) -> np.ndarray:
    """Every point the 3-D figure draws."""
    return np.concatenate([np.column_stack([_array(t[c]) for c in "xyz"]) for t in data])


@dataclass
class Case:
    """A cloud, its reconstruction and the report of it, written to ``path``."""

    points: np.ndarray
    model: object
    page: str
    path: Path


def _case(tmp_path_factory, generator: str, name: str, n: int, seed: int) -> Case:
    make = canalsurf.make_network if generator == "network" else canalsurf.make_tube
    points = make(name, n=n, rng=seed).points
    model = canalsurf.reconstruct(points)
    page = render_report(model, points, source=name)
    path = tmp_path_factory.mktemp("report") / f"{name}.html"
    path.write_text(page, encoding="utf-8")
    return Case(points, model, page, path)


@pytest.fixture(scope="module")
def t_junction(tmp_path_factory) -> Case:
    return _case(tmp_path_factory, *T_JUNCTION)


@pytest.fixture(scope="module")
def floor_clutter(tmp_path_factory) -> Case:
    return _case(tmp_path_factory, *FLOOR_CLUTTER)


@pytest.fixture(scope="module")
def long_thin(tmp_path_factory) -> Case:
    return _case(tmp_path_factory, *LONG_THIN)


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """``canalsurf reconstruct cloud.ply -o out --report``: (input path, output folder, exit code)."""
    base = tmp_path_factory.mktemp("report")
    cloud = base / "pipe.ply"
    assert cli.main(["synth", CLOUD[0], "-o", str(cloud), "--seed", str(CLOUD[1]), "-q"]) == 0
    out = base / "out"
    code = cli.main(["reconstruct", str(cloud), "-o", str(out), "--report", "-q"])
    return cloud, out, code


@pytest.fixture(scope="module")
def report_html(cli_run) -> Path:
    _, out, code = cli_run
    assert code == 0
    return out / "report.html"


def _canal(n: int = 1500, seed: int = 3):
    """A hand-made canal model (straight spine of length 10, radius 1 -> 2) without stages, and points
    near its surface."""
    u = np.linspace(0.0, 1.0, 6)
    spine = make_interp_spline(u, np.column_stack([10 * u, 0 * u, 0 * u]), k=3)
    radius = make_interp_spline(u, 1.0 + u, k=3)
    rng = np.random.default_rng(seed)
    t, s = rng.uniform(0, 1, n), rng.uniform(0, 2 * np.pi, n)
    r = radius(t) + rng.uniform(-0.05, 0.05, n)
    points = np.column_stack([10 * t, r * np.cos(s), r * np.sin(s)])
    model = CanalModel("canal", spine, radius, False, {"R": 0.5, "H": 1.5},
                       {"n_points": n, "seconds": {"shrink": 0.25}})
    return model, points


# --- the CLI --------------------------------------------------------------------------------------


def test_cli_writes_report_beside_model(cli_run):
    cloud, out, code = cli_run
    assert code == 0
    assert (out / "model.json").is_file() and (out / "report.html").is_file()
    left = [p.name for p in out.iterdir() if p.name.startswith(".") and p.name != MANIFEST_NAME]
    assert left == []  # no staging folder or lock left over
    heading = _parse((out / "report.html").read_text(encoding="utf-8")).text
    assert str(cloud) in heading["title"] and str(cloud) in heading["h1"]


def test_cli_report_is_opt_in_for_demo_and_reconstruct():
    parser = cli.build_parser()
    assert parser.parse_args(["demo", "--report"]).report is True
    assert parser.parse_args(["demo"]).report is False
    assert parser.parse_args(["reconstruct", "a.ply", "-o", "out"]).report is False


def test_cli_without_extra_fails_before_work(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "plotly.graph_objects", None)  # import fails as if not installed
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(tmp_path / "missing.ply"), "-o", str(out), "--report"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("canalsurf: error: writing report.html needs the 'report' extra — "
                   "pip install 'canalsurf[report]'")
    assert not out.exists()


# --- the page as a file ----------------------------------------------------------------------------


def test_report_is_one_offline_file(report_html):
    page = report_html.read_text(encoding="utf-8")
    links = _parse(page)
    external = [u for u in links.urls if not u[2].startswith(("data:", "#"))]
    assert external == [], "the page refers to other files or the network"
    assert not re.search(r"""<(script|link|img|iframe)[^>]+(src|href)\s*=\s*["']?\s*(https?:)?//""", page)
    assert page.count("<script") >= 3  # plotly.js itself and the two figures, inline
    assert "Plotly.newPlot" in page and 'id="viewer-3d"' in page and 'id="radius-plot"' in page


def test_report_has_parameters_diagnostics_and_words(report_html, cli_run):
    page = report_html.read_text(encoding="utf-8")
    data = json.loads((cli_run[1] / "model.json").read_text(encoding="utf-8"))
    for key, value in data["parameters"].items():
        assert f'<th title="{key}">{_label(key)}</th>' in page  # a readable name, the key on hover
        if isinstance(value, float):
            assert f"<td>{value:.6g}</td>" in page
    for key, label in (("delta", "δ: shrink step"), ("n_shrink_points", "points in the shrinking subset"),
                       ("inlier_rms_residual", "RMS distance from the surface, points on a tube"),
                       ("stop_rule", "rule that stopped the shrinking"), ("seconds.normals", "time: normals (s)"),
                       ("seconds.shrink", "time: shrink (s)"), ("seconds.thin", "time: thin (s)"),
                       ("quality", "quality (good, check or poor)"),
                       ("scan_noise", "scan noise (from neighbour planes and coordinate steps)")):
        assert f'<th title="{key}">{label}</th>' in page
    r = data["branches"][0]["radius"]["constant"]
    assert f"A pipe surface of constant radius {r:.6g}" in page
    share = data["diagnostics"]["no_tube_share"]
    assert f'<th title="no_tube_share">points on no tube</th><td>{100 * share:.3g} %</td>' in page


def test_labels_spell_out_unknown_keys():
    assert _label("n_shrink_points") == "points in the shrinking subset"
    assert _label("seconds.normals") == "time: normals (s)"
    assert _label("seconds.mesh_union") == "time: mesh union (s)"
    assert _label("n_widgets") == "number of widgets"
    assert _label("largest_gap") == "largest gap"
    assert _label("fit.max_rounds") == "fit: max rounds"


def test_report_embeds_stage_pngs(report_html):
    from PIL import Image

    links = _parse(report_html.read_text(encoding="utf-8"))
    pngs = [u[2] for u in links.urls if u[0] == "img"]
    assert len(pngs) == N_STAGE_PNGS
    for uri in pngs:
        assert uri.startswith("data:image/png;base64,")
        raw = base64.b64decode(uri.split(",", 1)[1], validate=True)
        assert raw.startswith(PNG_MAGIC)
        pixels = np.asarray(Image.open(io.BytesIO(raw)).convert("RGB"))
        assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 10  # a drawing, not a blank
    for caption in ("input S", "shrunk Ŝ", "thinned S̃", "spine C(t)", "pipe surface"):
        assert f"<figcaption>{caption}" in report_html.read_text(encoding="utf-8")


def test_canal_without_stages_is_described_and_reproducible(tmp_path):
    model, points = _canal()
    page = render_report(model, points, source="cone <1>")
    assert "canalsurf report — cone &lt;1&gt;" in page  # the name is escaped
    assert "A canal surface whose radius varies from 1 to 2 (mean 1.5)" in page
    assert '<th title="seconds.shrink">time: shrink (s)</th><td>0.25</td>' in page
    assert "<td>canal</td><td>1.5 (1–2)</td><td>10</td><td>open, open</td>" in page  # the branch row
    imgs = [u for u in _parse(page).urls if u[0] == "img"]
    assert len(imgs) == 3  # S, spine, surface: no stages to show
    assert "<figcaption>shrunk" not in page and "<figcaption>thinned" not in page
    write_report(tmp_path / "r.html", model, points, source="cone <1>")
    assert (tmp_path / "r.html").read_text(encoding="utf-8") == page  # same input, same page


def _inline_plotly_js() -> str:
    from plotly.offline import get_plotlyjs

    return f'<script type="text/javascript">{get_plotlyjs()}</script>'


def test_shared_plotly_js_is_referred_to_instead_of_copied(tmp_path):
    model, points = _canal(n=300)
    alone = render_report(model, points, source="cone")
    shared = render_report(model, points, source="cone", plotly_js="../plotly.min.js")
    tag = '<script type="text/javascript" src="../plotly.min.js" charset="utf-8"></script>'
    # the same page, with the one script tag in place of plotly.js itself
    assert alone.count(_inline_plotly_js()) == 1 and shared == alone.replace(_inline_plotly_js(), tag)
    assert len(alone) - len(shared) > 3_000_000  # plotly.js: megabytes per page
    assert [u for u in _parse(shared).urls if u[0] == "script"] == [("script", "src", "../plotly.min.js")]
    write_plotly_js(tmp_path / PLOTLY_JS_NAME)
    script = (tmp_path / PLOTLY_JS_NAME).read_text("utf-8")
    assert _inline_plotly_js() == f'<script type="text/javascript">{script}</script>'
    assert [p.name for p in tmp_path.iterdir()] == [PLOTLY_JS_NAME]  # written atomically: no temporary left


def _instant_pipe(points, *, progress=None, **kwargs) -> Network:
    """Stands in for the pipeline: a straight pipe of radius 1 along x, at once."""
    for stage in STAGES:
        progress(stage)
    u = np.linspace(0.0, 1.0, 5)
    spine = make_interp_spline(u, np.column_stack([10 * u, 0 * u, 0 * u]), k=3)
    return Network([CanalModel("pipe", spine, constant_spline(1.0), False)], [], {"R": 0.5}, {"n_points": len(points)})


@pytest.fixture(scope="module")
def batch_reports(tmp_path_factory):
    """``canalsurf reconstruct a.xyz b.xyz -o out --report`` (the pipeline stood in for): the output folder."""
    base = tmp_path_factory.mktemp("batch")
    rng = np.random.default_rng(5)
    x, s = rng.uniform(0, 10, 400), rng.uniform(0, 2 * np.pi, 400)
    points = np.column_stack([x, np.cos(s), np.sin(s)])  # on the pipe _instant_pipe gives
    for name in ("a.xyz", "b.xyz"):
        np.savetxt(base / name, points)
    saved = canalsurf.pipeline.reconstruct
    canalsurf.pipeline.reconstruct = _instant_pipe  # (monkeypatch is function-scoped)
    try:
        code = cli.main(["reconstruct", str(base / "a.xyz"), str(base / "b.xyz"), "-o", str(base / "out"),
                         "--report", "-q"])
    finally:
        canalsurf.pipeline.reconstruct = saved
    assert code == 0
    return base / "out"


def test_cli_batch_reports_share_one_plotly_js(batch_reports):
    out = batch_reports
    assert sorted(p.name for p in out.iterdir()) == ["a", "b", PLOTLY_JS_NAME]
    script = (out / PLOTLY_JS_NAME).read_text("utf-8")
    assert _inline_plotly_js() == f'<script type="text/javascript">{script}</script>'
    for name in ("a", "b"):
        page = (out / name / "report.html").read_text(encoding="utf-8")
        scripts = [u for u in _parse(page).urls if u[0] == "script"]
        assert scripts == [("script", "src", f"../{PLOTLY_JS_NAME}")]  # relative: the folder can move
        assert (out / name / scripts[0][2]).resolve() == (out / PLOTLY_JS_NAME).resolve()
        assert len(page.encode("utf-8")) < 1_000_000 and "Plotly.newPlot" in page


def test_cli_single_report_stands_alone(report_html):
    page = report_html.read_text(encoding="utf-8")
    assert page.count(_inline_plotly_js()) == 1
    assert not (report_html.parent / PLOTLY_JS_NAME).exists()
    assert [u for u in _parse(page).urls if u[0] == "script"] == []


def test_missing_extra_names_it(monkeypatch):
    model, points = _canal(n=100)
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(InputError, match=r"^writing report\.html needs the 'report' extra — "
                                         r"pip install 'canalsurf\[report\]'$"):
        render_report(model, points)


def test_bad_points_raise():
    model, _ = _canal(n=100)
    with pytest.raises(InputError, match=r"points must have shape \(N, 3\), got \(4, 2\)"):
        render_report(model, np.zeros((4, 2)))


# --- networks: the figures' data ------------------------------------------------------------------


def test_network_has_a_legend_entry_and_colour_per_branch(t_junction):
    net, page = t_junction.model, t_junction.page
    assert [len(net.branches), len(net.junctions)] == [3, 1]
    names = [f"branch {b.id} ({b.kind})" for b in net.branches]
    colours = list(BRANCH_COLOURS[:3])
    data, layout = _figure(page, "viewer-3d")
    assert [t["name"] for t in data if _in_legend(t)] == [*names, "junctions", "surface"]
    points = {t["name"]: t for t in data if t["type"] == "scatter3d" and t["mode"] == "markers"}
    assert [points[n]["marker"]["color"] for n in names] == colours
    # Each branch's points are the input points classified onto it; its spine shares its legend entry.
    label, _ = net.classify(t_junction.points)
    for b, name in zip(net.branches, names):
        assert len(_array(points[name]["x"])) == np.sum(label == b.id)
        spine = next(t for t in data if t["name"] == f"{name} spine")
        assert spine["legendgroup"] == name and spine["showlegend"] is False
    assert "no tube" not in points  # no clutter, nothing in grey
    junctions = points["junctions"]
    assert junctions["text"] == ["junction 0: branches 0, 1, 2"]
    assert np.allclose(np.column_stack([_array(junctions[c]) for c in "xyz"]), net.junctions[0].point)
    # The radius plot: one curve per branch, in the branch's colour family, over its arc length.
    data, _ = _figure(page, "radius-plot")
    curves = [t for t in data if _in_legend(t)]
    assert [t["name"] for t in curves] == names
    for b, curve in zip(net.branches, curves):
        s = _array(curve["x"])
        assert s[0] == 0 and s[-1] == pytest.approx(curve_length(b.spine))
        assert np.allclose(_array(curve["y"]), b.radius(s / s[-1]))
    dots = [t for t in data if not _in_legend(t)]
    assert [t["marker"]["color"] for t in dots] == colours
    # The table shows each branch in the same colour.
    for i, colour in enumerate(colours):
        assert f'<span class="swatch" style="background:{colour}"></span>branch {i}</td>' in page


def test_network_colour_buttons_switch_to_distance(t_junction):
    data, layout = _figure(t_junction.page, "viewer-3d")
    (menu,) = layout["updatemenus"]
    by_branch, by_distance = menu["buttons"]
    assert [by_branch["label"], by_distance["label"]] == ["colour by branch",
                                                          "colour by distance from the surface"]
    points = [i for i, t in enumerate(data) if t["type"] == "scatter3d" and t["mode"] == "markers"
              and t["name"] != "junctions"]
    assert by_branch["args"][2] == by_distance["args"][2] == points
    assert by_branch["args"][0]["marker.color"] == [data[i]["marker"]["color"] for i in points]
    distances = by_distance["args"][0]["marker.color"]
    for i, d in zip(points, distances):
        assert np.allclose(d, _array(data[i]["customdata"]), rtol=1e-3, atol=1e-12)
    assert by_distance["args"][0]["marker.coloraxis"] == ["coloraxis"] * len(points)
    assert layout["coloraxis"]["cmax"] == -layout["coloraxis"]["cmin"] > 0


def test_network_headline_and_branch_table(t_junction):
    net, words = t_junction.model, _words(t_junction.page)
    d = net.diagnostics
    assert "A network of 3 branches (3 pipes) meeting at 1 junction, in 1 separate network" in words
    headline = words[words.index("3 branches"):words.index("Branches ")]
    for stat in ("3 branches 3 pipes", "1 junction ", "1 separate network "):
        assert stat in headline
    assert "0 % of the points on no tube" in headline
    lengths = np.array([curve_length(b.spine) for b in net.branches])
    means = [np.mean(b.radius(np.linspace(0, 1, 400))) for b in net.branches]
    mean_r = np.sum(lengths * means) / lengths.sum()
    rms = d["inlier_rms_residual"]
    assert f"{rms:.4g} inlier RMS {100 * rms / mean_r:.3g} % of the mean radius {mean_r:.4g}" in headline
    assert f"{d['angular_coverage']:.0f}° angular coverage" in headline and "seen all around" in headline
    label, _ = net.classify(t_junction.points)
    for b, length in zip(net.branches, lengths):
        ends = ", ".join("open" if e is None else f"junction {e}" for e in b.ends)
        row = (f"branch {b.id} pipe {b.mean_radius:.4g} {length:.4g} {ends} {np.sum(label == b.id)} "
               f"{b.diagnostics['inlier_rms_residual']:.4g} {b.diagnostics['angular_coverage']:.0f}°")
        assert row in words


def test_clutter_shows_the_points_on_no_tube_in_grey(floor_clutter):
    net, page = floor_clutter.model, floor_clutter.page
    label, _ = net.classify(floor_clutter.points)
    assert 0.2 < np.mean(label < 0) < 0.4  # the floor and the box
    data, _ = _figure(page, "viewer-3d")
    (grey,) = [t for t in data if t["name"] == "no tube"]
    assert grey["marker"]["color"] == NO_TUBE_COLOUR and _in_legend(grey)
    assert len(_array(grey["x"])) == np.sum(label < 0)
    assert grey["hovertemplate"].startswith("on no tube")
    share = net.diagnostics["no_tube_share"]
    assert f"{100 * share:.3g} % of the points on no tube" in _words(page)


@pytest.mark.parametrize("case", ["t_junction", "floor_clutter", "long_thin"])
def test_first_view_shows_every_point(case, request):
    """The camera holds every point drawn, in plotly's projection of the page's figure, while plotly's
    default camera loses the long tube and the wide floor."""
    data, layout = _figure(request.getfixturevalue(case).page, "viewer-3d")
    scene = layout["scene"]
    assert scene["aspectmode"] == "data"
    drawn = _drawn(data)
    seen = _project(drawn, drawn, scene["camera"], VIEW_FIT_ASPECT)
    assert (seen[:, 2] > 0).all() and np.abs(seen[:, :2]).max() <= 1
    assert np.abs(seen[:, :2]).max() > 0.8  # and fills it
    if case != "t_junction":
        default = _project(drawn, drawn, PLOTLY_DEFAULT_CAMERA, VIEW_FIT_ASPECT)
        assert np.abs(default[:, :2]).max() > 1


# --- the page in a browser -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """A headless Chromium (a persistent context that refuses every request off this machine)."""
    if not CHROMIUM.is_file():
        pytest.skip(f"no Chromium at {CHROMIUM} to render report.html in: install Debian's 'chromium' "
                    "package (as root; .ci/run does this) to run the browser tests")
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="playwright is not installed (pip install -e '.[test]')")
    with sync_api.sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            tmp_path_factory.mktemp("profile"), executable_path=str(CHROMIUM), headless=True,
            args=CHROMIUM_FLAGS, viewport=VIEWPORT, timeout=PAGE_TIMEOUT * 1000)
        try:
            # Anything but the file itself (a CDN script, a font) would be a network request: refuse it.
            context.route(re.compile(r"^(?!file:|data:|blob:)"), lambda route: route.abort())
            yield context
        finally:
            context.close()


@dataclass
class Loaded:
    """A report open in the browser, and what it logged."""

    page: object
    console_errors: list
    page_errors: list
    requests: list

    def check_clean(self):
        assert self.console_errors == [] and self.page_errors == []
        assert all(url.startswith(("file:", "data:", "blob:")) for url in self.requests), self.requests


def _open(browser, path: Path) -> Loaded:
    """Load the report and wait until plotly has laid out both figures and drawn the 3-D scene's camera."""
    page = browser.new_page()
    loaded = Loaded(page, [], [], [])
    page.on("console", lambda m: loaded.console_errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda exc: loaded.page_errors.append(str(exc)))
    page.on("request", lambda r: loaded.requests.append(r.url))
    page.goto(path.as_uri(), wait_until="load", timeout=PAGE_TIMEOUT * 1000)
    page.wait_for_function(
        "() => { const g = document.getElementById('viewer-3d'), r = document.getElementById('radius-plot');"
        " const s = g && g._fullLayout && g._fullLayout.scene && g._fullLayout.scene._scene;"
        " return !!(s && s.glplot && s.glplot.cameraParams.view && g.querySelector('.gl-container canvas')"
        " && r && r._fullData && r._fullData.length); }",
        timeout=PAGE_TIMEOUT * 1000)
    return loaded


def _screenshot(loaded: Loaded, path: Path, drawn) -> np.ndarray:
    """The 3-D view's pixels, once ``drawn(pixels)`` (the WebGL scene is drawn on an animation frame
    after the layout)."""
    from PIL import Image

    viewer = loaded.page.locator("#viewer-3d")
    for _ in range(20):
        viewer.screenshot(path=path)
        pixels = np.asarray(Image.open(path).convert("RGB"))
        if drawn(pixels):
            break
        loaded.page.wait_for_timeout(250)
    return pixels


def _middle(pixels: np.ndarray) -> np.ndarray:
    """The middle of the 3-D view (where the tubes are, away from legend, buttons and colour bar)."""
    h, w, _ = pixels.shape
    return pixels[h // 4: 3 * h // 4, w // 4: 3 * w // 4].reshape(-1, 3).astype(int)


def _scene_drawn(pixels: np.ndarray) -> bool:
    """The middle of the 3-D view holds a drawing: many colours, some of them strongly coloured points."""
    middle = _middle(pixels)
    colours = len(np.unique(middle, axis=0))
    coloured = (middle.max(axis=1) - middle.min(axis=1) > 80).mean()
    return colours > 50 and coloured > 1e-3


def _branch_colours_seen(pixels: np.ndarray) -> int:
    """How many of the branch colours show in the middle of the view (points not behind the surface
    keep their colour)."""
    middle = _middle(pixels)
    rgb = [np.array([int(c[i:i + 2], 16) for i in (1, 3, 5)]) for c in BRANCH_COLOURS]
    return sum(int((np.abs(middle - c).max(axis=1) < 40).sum() >= 10) for c in rgb)


#: Legend entries of a figure as plotly built them, and how many the legend shows.
LEGEND_JS = """(id) => { const g = document.getElementById(id);
    return {names: g._fullData.filter(t => t.visible === true && t.showlegend).map(t => t.name),
            items: g.querySelectorAll('.legend .traces').length}; }"""


def test_report_renders_in_headless_chromium(browser, report_html, tmp_path):
    data, _ = _figure(report_html.read_text(encoding="utf-8"), "viewer-3d")
    names = [t["name"] for t in data if _in_legend(t)]
    assert names[0] == "branch 0 (pipe)" and names[-1] == "surface"
    loaded = _open(browser, report_html)
    pixels = _screenshot(loaded, tmp_path / "viewer-3d.png", _scene_drawn)
    legend = loaded.page.evaluate(LEGEND_JS, "viewer-3d")
    loaded.page.close()
    loaded.check_clean()
    assert legend == {"names": names, "items": len(names)}
    height, width, _ = pixels.shape
    assert height > 300 and width > 600
    assert _scene_drawn(pixels), f"the 3-D view looks blank (screenshot {tmp_path / 'viewer-3d.png'})"


def test_batch_report_loads_its_shared_plotly_js_in_headless_chromium(browser, batch_reports, tmp_path):
    loaded = _open(browser, batch_reports / "b" / "report.html")  # waits until plotly has drawn both figures
    pixels = _screenshot(loaded, tmp_path / "batch.png", _scene_drawn)
    loaded.page.close()
    loaded.check_clean()
    assert (batch_reports / PLOTLY_JS_NAME).as_uri() in loaded.requests
    assert _scene_drawn(pixels)


def test_network_in_headless_chromium(browser, t_junction, tmp_path):
    loaded = _open(browser, t_junction.path)
    page = loaded.page
    shot = tmp_path / "network.png"
    pixels = _screenshot(loaded, shot, lambda p: _scene_drawn(p) and _branch_colours_seen(p) >= 2)
    names = [f"branch {b.id} (pipe)" for b in t_junction.model.branches]
    assert page.evaluate(LEGEND_JS, "viewer-3d") == {"names": [*names, "junctions", "surface"], "items": 5}
    assert page.evaluate(LEGEND_JS, "radius-plot") == {"names": names, "items": 3}
    junctions = page.evaluate("() => { const t = document.getElementById('viewer-3d')._fullData"
                              ".find(t => t.name === 'junctions'); return Array.from(t.text); }")
    assert junctions == ["junction 0: branches 0, 1, 2"]
    headline = " ".join(page.locator("#headline").inner_text().split())
    for stat in ("3 branches", "1 junction", "1 separate network", "0 % of the points on no tube",
                 "inlier RMS", "angular coverage"):
        assert stat in headline
    assert page.locator("#branches tbody tr").count() == 3
    # The buttons: colour by the distance from the surface (a colour bar appears), and back.
    buttons = page.locator("#viewer-3d g.updatemenu-button")
    assert buttons.count() == 2
    buttons.nth(1).dispatch_event("click")
    page.wait_for_function("() => { const g = document.getElementById('viewer-3d');"
                           " const c = g._fullData[0].marker.color;"
                           " return !!g._fullLayout.coloraxis"
                           " && (Array.isArray(c) || ArrayBuffer.isView(c)); }",
                           timeout=PAGE_TIMEOUT * 1000)
    buttons.nth(0).dispatch_event("click")
    page.wait_for_function("() => typeof document.getElementById('viewer-3d')._fullData[0].marker.color"
                           " === 'string'", timeout=PAGE_TIMEOUT * 1000)
    page.close()
    loaded.check_clean()
    assert _scene_drawn(pixels), f"the 3-D view looks blank (screenshot {shot})"
    assert _branch_colours_seen(pixels) >= 2, f"the branches' colours do not show (screenshot {shot})"


def test_clutter_in_headless_chromium(browser, floor_clutter):
    loaded = _open(browser, floor_clutter.path)
    grey = loaded.page.evaluate("() => { const t = document.getElementById('viewer-3d')._fullData"
                                ".find(t => t.name === 'no tube'); return t && [t.marker.color, t.x.length,"
                                " t.showlegend]; }")
    legend = loaded.page.evaluate(LEGEND_JS, "viewer-3d")
    loaded.page.close()
    loaded.check_clean()
    label, _ = floor_clutter.model.classify(floor_clutter.points)
    assert grey == [NO_TUBE_COLOUR, int(np.sum(label < 0)), True]
    assert legend["names"] == ["branch 0 (pipe)", "no tube", "surface"] and legend["items"] == 3


#: Every point given, projected by the 3-D scene's own camera: plotly.js draws a point p of the data at
#: projection * view * model * (p * dataScale, 1), the matrices column-major (as for its 3-D annotations).
PROJECT_JS = """(points) => { const s = document.getElementById('viewer-3d')._fullLayout.scene._scene;
    const c = s.glplot.cameraParams, d = s.dataScale;
    const mul = (m, v) => [0, 1, 2, 3].map(
        r => m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r] * v[3]);
    return points.map(p => { const v = mul(c.projection, mul(c.view, mul(c.model,
        [p[0] * d[0], p[1] * d[1], p[2] * d[2], 1])));
        return [v[0] / v[3], v[1] / v[3], v[3]]; }); }"""


def test_long_tube_is_in_the_first_view_in_headless_chromium(browser, long_thin):
    net = long_thin.model
    spines = np.concatenate([b.spine(np.linspace(0.0, 1.0, 200)) for b in net.branches])
    loaded = _open(browser, long_thin.path)
    seen = np.array(loaded.page.evaluate(PROJECT_JS, np.concatenate([spines, long_thin.points]).tolist()))
    loaded.page.close()
    loaded.check_clean()
    assert (seen[:, 2] > 0).all()  # in front of the eye
    outside = np.abs(seen[:, :2]).max(axis=1) > 1
    assert not outside.any(), (f"{outside.sum()} points off the first view, "
                               f"{outside[:len(spines)].sum()} of them on the spines")
