"""Tests of :mod:`canalsurf.report` and ``canalsurf reconstruct --report``.

The page is checked as a file (one self-contained file, nothing fetched from the network, the
parameters and the stage PNGs in it) and in a real headless Chromium: it loads from a ``file://`` URL
with no console or page errors and no network request, and the plotly 3-D view draws something.
The browser test needs Debian's Chromium at ``/usr/bin/chromium`` (``.ci/run`` installs it) and fails,
not skips, without it.
"""

from __future__ import annotations

import base64
import io
import json
import re
import sys
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

from canalsurf import cli
from canalsurf.errors import InputError
from canalsurf.model import CanalModel
from canalsurf.report import render_report, write_report

#: The browser the report must work in, and how to get it.
CHROMIUM = Path("/usr/bin/chromium")
#: Headless, offline, no first-run or background activity (a fresh profile is added per run).
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]
#: Seconds to wait for the page and for plotly's WebGL scene.
PAGE_TIMEOUT = 30
#: The cloud the CLI reconstructs: the paper's Figure 9 pipe (2000 points).
CLOUD = ("fig9-pipe", 1)
#: Stage pictures of a model straight from the pipeline: S, Ŝ, S̃, spine, surface.
N_STAGE_PNGS = 5
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


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
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staging left over
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
        assert f"<th>{key}</th>" in page
        if isinstance(value, float):
            assert f"<td>{value:.6g}</td>" in page
    for key in ("iterations", "stop_rule", "rms_residual", "seconds.shrink", "seconds.thin"):
        assert f"<th>{key}</th>" in page
    r = data["radius"]["constant"]
    assert data["kind"] == "pipe" and f"A pipe surface of constant radius {r:.6g}" in page


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
    assert "<th>seconds.shrink</th><td>0.25</td>" in page
    imgs = [u for u in _parse(page).urls if u[0] == "img"]
    assert len(imgs) == 3  # S, spine, surface: no stages to show
    assert "<figcaption>shrunk" not in page and "<figcaption>thinned" not in page
    write_report(tmp_path / "r.html", model, points, source="cone <1>")
    assert (tmp_path / "r.html").read_text(encoding="utf-8") == page  # same input, same page


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


# --- the page in a browser -------------------------------------------------------------------------


def test_report_renders_in_headless_chromium(report_html, tmp_path):
    if not CHROMIUM.is_file():
        pytest.fail(f"this test needs Chromium at {CHROMIUM} to render report.html — install it with "
                    "'apt-get install chromium' (as root; .ci/run does this)")
    from PIL import Image
    from playwright.sync_api import sync_playwright

    console_errors, page_errors, requests = [], [], []
    with sync_playwright() as pw:
        browser = pw.chromium.launch_persistent_context(
            tmp_path / "profile", executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS,
            viewport={"width": 1280, "height": 900}, timeout=PAGE_TIMEOUT * 1000)
        try:
            # Anything but the file itself (a CDN script, a font) would be a network request: refuse it.
            browser.route(re.compile(r"^(?!file:|data:|blob:)"), lambda route: route.abort())
            page = browser.new_page()
            page.on("console", lambda m: console_errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda exc: page_errors.append(str(exc)))
            page.on("request", lambda r: requests.append(r.url))
            page.goto(report_html.as_uri(), wait_until="load", timeout=PAGE_TIMEOUT * 1000)
            # plotly has laid out the 3-D scene (three traces) and created its WebGL canvas.
            page.wait_for_function(
                "() => { const g = document.getElementById('viewer-3d');"
                " return !!(g && g._fullData && g._fullData.length === 3 && g._fullLayout.scene"
                " && g.querySelector('.gl-container canvas')); }",
                timeout=PAGE_TIMEOUT * 1000)
            viewer = page.locator("#viewer-3d")
            shot = tmp_path / "viewer-3d.png"
            for _ in range(20):  # the WebGL scene is drawn on an animation frame after the layout
                viewer.screenshot(path=shot)
                pixels = np.asarray(Image.open(shot).convert("RGB"))
                if _scene_drawn(pixels):
                    break
                page.wait_for_timeout(250)
        finally:
            browser.close()

    assert console_errors == [] and page_errors == []
    assert all(url.startswith(("file:", "data:", "blob:")) for url in requests), requests
    height, width, _ = pixels.shape
    assert height > 300 and width > 600
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 1
    assert _scene_drawn(pixels), f"the 3-D view looks blank (screenshot {shot})"


def _scene_drawn(pixels: np.ndarray) -> bool:
    """The middle of the 3-D view (where the tube is, away from legend and colour bar) holds a drawing:
    many colours, some of them red or blue points of the distance scale and the dark spine."""
    h, w, _ = pixels.shape
    middle = pixels[h // 4: 3 * h // 4, w // 4: 3 * w // 4].reshape(-1, 3).astype(int)
    colours = len(np.unique(middle, axis=0))
    dark = (middle.max(axis=1) < 80).mean()
    coloured = (np.abs(middle[:, 0] - middle[:, 2]) > 60).mean()
    return colours > 50 and dark > 1e-4 and coloured > 1e-4
