"""Tests of the ``canalsurf`` command, run in-process through ``main(argv)``."""

from __future__ import annotations

import json
import logging
import os
import re
import shlex
import socket
import struct
import sys
import threading
import time
import types
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import make_interp_spline

import canalsurf
from canalsurf import cli, load_model
from canalsurf.errors import ReconstructionError
from canalsurf.io import read_points, write_points
from canalsurf.model import CanalModel
from canalsurf.network import Network
from canalsurf.pipeline import STAGES
from canalsurf.spine import constant_spline
from canalsurf.synth import MAX_SYNTH_POINTS, NETWORKS, SURFACES, make_network, make_tube

#: The cloud most tests reconstruct: the paper's Figure 9 pipe (true radius 1), another seed than the demo.
CLOUD = ("fig9-pipe", 1)
#: Accepted relative radius error on that cloud (the reconstruction gets ~0.1 %; noise is 10 % of r).
RADIUS_TOL = 0.02


def _error_line(err: str) -> str:
    """The single stderr line of an expected failure (fails unless there is exactly one)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("canalsurf: error: "), err
    assert "Traceback" not in err
    return lines[0]


def _empty(folder: Path) -> bool:
    return not folder.exists() or not any(folder.iterdir())


def _never(*args, **kwargs):
    raise AssertionError("reconstruction should not start")


def _straight_pipe() -> Network:
    """A hand-made result (straight spine of length 10 along x, radius 1) for tests about the files."""
    u = np.linspace(0.0, 1.0, 5)
    spine = make_interp_spline(u, np.column_stack([10 * u, 0 * u, 0 * u]), k=3)
    return Network([CanalModel("pipe", spine, constant_spline(1.0), False)], [], {"R": 0.5}, {"n_points": 2000})


@pytest.fixture
def instant_pipeline(monkeypatch):
    """Replace the pipeline by one that reports every stage and returns :func:`_straight_pipe` at once."""

    def reconstruct(points, *, progress=None, **kwargs):
        for stage in STAGES:
            progress(stage)
        return _straight_pipe()

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)


def _on_a_terminal(argv: list[str]) -> tuple[int, str]:
    """Run ``main(argv)`` with stderr on a pseudo-terminal; return the exit code and what it showed."""
    termios = pytest.importorskip("termios")
    fcntl = pytest.importorskip("fcntl")
    master, slave = os.openpty()
    # 24 rows, 240 columns: tqdm sizes its bar to the terminal's width and cuts what does not fit, and
    # the line (a temporary path, a rate of thousands of stages per second, the stage) must fit whole
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 240, 0, 0))
    received = []

    def drain():  # read while main runs: a full terminal buffer would block the writer
        while True:
            try:
                data = os.read(master, 4096)
            except OSError:  # EIO: the terminal side is closed
                return
            if not data:
                return
            received.append(data)

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    terminal = os.fdopen(slave, "w", encoding="utf-8", buffering=1)
    saved, sys.stderr = sys.stderr, terminal
    try:
        code = cli.main(argv)
    finally:
        sys.stderr = saved
        terminal.close()
        reader.join(timeout=5)
        os.close(master)
    return code, b"".join(received).decode("utf-8")


@pytest.fixture(scope="module")
def cloud(tmp_path_factory) -> Path:
    """A 2000-point PLY of the Figure 9 pipe (with true normals), written by ``canalsurf synth``."""
    path = tmp_path_factory.mktemp("cloud") / "pipe.ply"
    assert cli.main(["synth", CLOUD[0], "-o", str(path), "--seed", str(CLOUD[1]), "--normals", "-q"]) == 0
    return path


# --- general ---------------------------------------------------------------------------------------


def test_version(capsys):
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"canalsurf {canalsurf.__version__}"


def test_synth_help_lists_the_surfaces_and_networks(capsys):
    """The list comes from canalsurf.synth, imported only when synth is used."""
    assert cli.main(["synth", "--help"]) == 0
    out = capsys.readouterr().out
    assert f"Surfaces: {', '.join(SURFACES)}." in out and f"Networks: {', '.join(NETWORKS)} (see --list)." in out
    noise = make_network.__kwdefaults__["noise"]
    assert f"; {make_network.__kwdefaults__['n']} for a network, clutter included)" in " ".join(out.split())
    assert f"(default {noise:g}: ±{100 * noise:g} % of the radius)" in " ".join(out.split())


@pytest.mark.parametrize("command", [[], ["demo"], ["reconstruct"], ["info"], ["synth"], ["paper"]])
def test_help_has_examples(command, capsys):
    assert cli.main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: canalsurf") and "examples:" in out
    examples = [shlex.split(line.split("#", 1)[0].split(">", 1)[0])  # comments, redirections cut off
                for line in re.findall(r"^  (canalsurf .*)$", out.split("examples:", 1)[1], re.M)]
    assert len(examples) >= 2 and all(words[1] == command[0] for words in examples[:2] if command)
    parser = cli.build_parser()
    for words in examples:  # every example is a command line that parses
        parser.parse_args(words[1:])


@pytest.mark.parametrize("argv, what", [
    ([], "required: COMMAND"),
    (["reconstruct", "x.ply"], "-o/--output"),
    (["reconstruct", "x.ply", "-o", "out", "--mu", "2"], "argument --mu"),
    (["reconstruct", "x.ply", "-o", "out", "--delta", "0"], "argument --delta"),
    (["reconstruct", "x.ply", "-o", "out", "--mesh-format", "fbx"], "invalid choice"),
    (["synth", "nope", "-o", "x.ply"], "invalid choice"),
    (["synth", "helix"], "NAME and -o FILE"),
    (["frobnicate"], "invalid choice"),
])
def test_usage_errors_are_one_line(argv, what, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    line = _error_line(captured.err)
    assert what in line and "--help" in line
    assert captured.out == ""
    assert not any(tmp_path.iterdir())


def test_global_options_before_or_after_the_command(capsys):
    assert cli.main(["--json", "synth", "--list"]) == 0
    first = json.loads(capsys.readouterr().out)
    assert cli.main(["synth", "--list", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == first == (
        {n: s[-1] for n, s in SURFACES.items()} | {n: f"network: {s[-1]}" for n, s in NETWORKS.items()})


def test_logging_is_restored_after_main(capsys):
    logger = logging.getLogger("canalsurf")
    handlers, level = list(logger.handlers), logger.level
    cli.main(["-v", "synth", "--list"])
    assert logger.handlers == handlers and logger.level == level


# --- synth -----------------------------------------------------------------------------------------


def test_synth_list(capsys):
    """Surfaces first, then the networks, each said to be one."""
    assert cli.main(["synth", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(SURFACES) + len(NETWORKS)
    for line, (name, spec) in zip(lines, [*SURFACES.items(), *NETWORKS.items()]):
        assert line.split()[0] == name and line.endswith(spec[-1])
        assert (line.split()[1] == "network:") == (name in NETWORKS)


def test_synth_network(tmp_path, capsys):
    path = tmp_path / "x.ply"
    assert cli.main(["synth", "t-junction", "-o", str(path), "--n", "3000", "--seed", "5", "--normals"]) == 0
    out = capsys.readouterr().out
    assert out == (f"{path}: 3000 points of t-junction (3 branches, 1 junction; uniform noise ±2 % of the "
                   "radius, seed 5, with true normals)\n")
    truth = make_network("t-junction", n=3000, rng=5)
    points, normals = read_points(path)
    np.testing.assert_array_equal(points, truth.points)
    np.testing.assert_array_equal(normals, truth.normals)


def test_synth_network_options(tmp_path, capsys):
    path = tmp_path / "scene.npy"
    argv = ["synth", "scene", "-o", str(path), "--n", "1000", "--noise", "0.05", "--clutter", "0.3", "--json"]
    assert cli.main(argv) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["network"] is True and record["n"] == 1000 and record["noise"] == 0.05
    assert record["clutter"] == 0.3 and (record["branches"], record["junctions"]) == (8, 1)
    np.testing.assert_array_equal(np.load(path), make_network("scene", n=1000, noise=0.05, clutter=0.3).points)
    path = tmp_path / "plant.npy"
    assert cli.main(["synth", "plant", "-o", str(path), "--n", "500", "--size", "2", "-q"]) == 0
    np.testing.assert_array_equal(np.load(path), make_network("plant", n=500, size=2).points)


def test_synth_summary_echoes_the_options(tmp_path, capsys):
    path = tmp_path / "x.xyz"
    argv = ["synth", "elbow", "-o", str(path), "--gaussian", "--noise", "0.03", "--arc", "200",
            "--outliers", "0.05", "--density-ratio", "4", "--sampling", "parameter"]
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert out == (f"{path}: 2000 points of elbow (Gaussian noise of standard deviation 0.03, one-sided scan "
                   "of 200°, 5 % stray points, density falling 4x along the spine, uniform in the surface "
                   "parameters, seed 0)\n")
    assert "±" not in out


@pytest.mark.parametrize("argv, line", [
    (["--seed", "-1"], "canalsurf: error: argument --seed: expected a non-negative integer, got '-1' — see "
                       "'canalsurf synth --help'"),
    (["--n", "99999999999999999999"], f"canalsurf: error: n = 99999999999999999999 points would not fit in "
                                      f"memory; at most {MAX_SYNTH_POINTS:,} can be generated at once"),
    (["--n", "1" + "0" * 5000], "canalsurf: error: argument --n: expected a positive integer, got "
                                "'10000000000000000000...0000000000' — see 'canalsurf synth --help'"),
    (["--noise", "1e308"], "canalsurf: error: noise 1e+308 is larger than the surface itself (the diagonal of "
                           "its bounding box is 21.1); give a noise well below the radius"),
    (["--clutter", "0.2"], "canalsurf: error: --clutter is an option of the networks, not of the surface "
                           "'fig9-pipe' — see 'canalsurf synth --help'"),
])
@pytest.mark.parametrize("name", ["fig9-pipe", "t-junction"])
def test_synth_bad_options_are_one_line(name, argv, line, tmp_path, capsys):
    if name in NETWORKS:
        line = {"--noise": "canalsurf: error: noise must be a share of the radius in [0, 0.5), got 1e+308",
                "--clutter": None}.get(argv[0], line)
        if line is None:
            argv, line = ["--arc", "200"], ("canalsurf: error: --arc is an option of the surfaces, not of the "
                                            "network 't-junction' — see 'canalsurf synth --help'")
    out = tmp_path / "out"
    assert cli.main(["synth", name, "-o", str(out / "x.ply"), *argv]) == 2
    captured = capsys.readouterr()
    assert _error_line(captured.err) == line
    assert captured.out == "" and not out.exists()


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".csv", ".npy", ".npz"])
@pytest.mark.parametrize("normals", [False, True])
def test_synth_round_trips_through_read_points(suffix, normals, tmp_path, capsys):
    path = tmp_path / "sub" / f"torus{suffix}"  # missing folders are created
    argv = ["synth", "torus", "-o", str(path), "--n", "300", "--seed", "4", "--noise", "0.01"]
    assert cli.main(argv + (["--normals"] if normals else [])) == 0
    assert str(path) in capsys.readouterr().out
    truth = make_tube("torus", n=300, noise=0.01, rng=4)
    points, read_normals = read_points(path)
    np.testing.assert_array_equal(points, truth.points)  # full float64 precision in every format
    if normals:
        np.testing.assert_array_equal(read_normals, truth.normals)
    else:
        assert read_normals is None
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary files left


def test_synth_same_seed_same_cloud(tmp_path):
    for name in ("a.npy", "b.npy"):
        assert cli.main(["synth", "helix", "-o", str(tmp_path / name), "--seed", "7", "-q"]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "a.npy"), np.load(tmp_path / "b.npy"))


def test_synth_unknown_suffix(tmp_path, capsys):
    assert cli.main(["synth", "helix", "-o", str(tmp_path / "out" / "x.vtk")]) == 2
    line = _error_line(capsys.readouterr().err)
    assert "'.vtk'" in line and ".ply" in line
    assert not (tmp_path / "out").exists()


# --- demo ------------------------------------------------------------------------------------------


def test_demo(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["demo"]) == 0
    folder = tmp_path / cli.DEMO_OUTDIR
    for name in ("input.ply", "model.json", "surface.ply", "spine.csv"):
        assert (folder / name).is_file(), name
    out = capsys.readouterr().out
    found = float(re.search(r"radius found\s+([0-9.]+)", out).group(1))
    assert abs(found - 1.0) < RADIUS_TOL
    assert "spine error" in out and "radius error" in out and "spine length" in out
    assert "model.json" in out
    # the written input is the demo cloud, and the model is what reconstruct gives for it
    points, _ = read_points(folder / "input.ply")
    np.testing.assert_array_equal(points, make_tube("fig9-pipe", n=2000, rng=0).points)
    assert load_model(folder / "model.json").kind == "pipe"


# --- reconstruct -----------------------------------------------------------------------------------


def test_reconstruct(cloud, tmp_path, capsys):
    trimesh = pytest.importorskip("trimesh")
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # not a terminal: no progress bar; no -v: no log
    assert "pipe" in captured.out and str(out) in captured.out

    model = load_model(out / "model.json")
    assert model.kind == "pipe" and not model.closed
    assert abs(model.mean_radius - 1.0) < RADIUS_TOL
    samples = json.loads((out / "model.json").read_text())["branches"][0]["samples"]
    assert len(samples["t"]) >= 50

    # spine.csv holds exactly model.json's samples
    table = np.loadtxt(out / "spine.csv", delimiter=",", skiprows=1)
    assert (out / "spine.csv").read_text().splitlines()[0] == "branch,t,x,y,z,radius"
    np.testing.assert_allclose(table, np.column_stack([np.zeros(len(samples["t"])), samples["t"],
                                                       samples["points"], samples["radius"]]),
                               rtol=1e-15, atol=0)

    # process=False: judge the mesh as written, not after trimesh has merged or dropped anything
    mesh = trimesh.load(out / "surface.ply", force="mesh", process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # consistently wound and enclosing a positive volume: facing outward
    assert mesh.nondegenerate_faces().all() and mesh.area_faces.min() > 1e-3 * mesh.area_faces.mean()
    # a capped tube of radius ~1 around the spine: volume close to pi r^2 L
    length = cli._spine_length(model)
    assert mesh.volume == pytest.approx(np.pi * length, rel=0.05)

    expected = {"model.json", "surface.ply", "spine.csv"}
    if cli._dxf_available():
        expected.add("spine.dxf")
        _check_spine_dxf(out / "spine.dxf", json.loads((out / "model.json").read_text()))
    # nothing else (no staging folder, no lock file) but the list of the files written
    assert {p.name for p in out.iterdir()} == expected | {".canalsurf-manifest.json"}


def _check_spine_dxf(path: Path, data: dict) -> None:
    """spine.dxf holds each branch's spine as one exact SPLINE and its sampled radii on a polyline."""
    import ezdxf

    msp = ezdxf.readfile(path).modelspace()
    splines, lines = msp.query("SPLINE"), msp.query("POLYLINE[layer=='RADIUS']")
    assert len(splines) == len(lines) == len(data["branches"])
    for spline, line, branch in zip(splines, lines, data["branches"]):
        assert spline.dxf.degree == branch["spine"]["degree"]
        np.testing.assert_array_equal(np.array(spline.control_points), branch["spine"]["control_points"])
        np.testing.assert_array_equal(np.array(spline.knots), branch["spine"]["knots"])
        vertices = list(line.vertices)
        np.testing.assert_array_equal([list(v.dxf.location) for v in vertices], branch["samples"]["points"])
        np.testing.assert_array_equal([v.get_xdata("CANALSURF")[0].value for v in vertices],
                                      branch["samples"]["radius"])


def test_without_ezdxf_spine_dxf_is_skipped_and_said(cloud, tmp_path, capsys, monkeypatch, instant_pipeline):
    monkeypatch.setitem(sys.modules, "ezdxf", None)  # import fails as if not installed
    monkeypatch.setattr(cli, "_DXF_AVAILABLE", None)  # forget an earlier answer
    note = "spine.dxf not written: needs the 'dxf' extra (pip install 'canalsurf[dxf]')"
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "a")]) == 0
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == [".canalsurf-manifest.json", "model.json",
                                                                 "spine.csv", "surface.ply"]
    captured = capsys.readouterr()
    assert captured.err == ""  # a note of the summary, not an error or a warning
    assert f"\nnote: {note}\n" in captured.out
    assert "spine.dxf is unitless" not in captured.out  # nothing said of a file not written
    # the same in --json, as a field of the record
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "b"), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["not_written"] == {"spine.dxf": "needs the 'dxf' extra (pip install 'canalsurf[dxf]')"}
    assert record["notes"] == [note]
    # -q: no summary, so no note either
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "c"), "-q"]) == 0
    assert capsys.readouterr() == ("", "")


def test_progress_bar_on_a_terminal(cloud, tmp_path, capsys):
    code, shown = _on_a_terminal(["reconstruct", str(cloud), "-o", str(tmp_path / "out")])
    assert code == 0
    assert f"\r{cloud}:" in shown and f"0/{len(STAGES)}" in shown
    for stage in STAGES:  # the bar names each stage of the real pipeline as it starts
        assert f"stage/s, {stage}]" in shown, stage
    assert shown.endswith("\r") and not shown.rsplit("\r", 2)[-2].strip()  # wiped when done
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("quiet", [False, True], ids=["default", "quiet"])
def test_quiet_turns_the_progress_bar_off(quiet, cloud, tmp_path, instant_pipeline):
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path / "out")] + (["-q"] if quiet else [])
    code, shown = _on_a_terminal(argv)
    assert code == 0
    assert (shown == "") if quiet else (f"stage/s, {STAGES[-1]}]" in shown)


def test_reconstruct_without_caps_is_open(cloud, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--no-caps", "-q"]) == 0
    mesh = trimesh.load(tmp_path / "surface.ply", force="mesh")
    assert not mesh.is_watertight
    assert len(trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)) == 2 * 32  # two open rings


@pytest.mark.parametrize("fmt", ["obj", "stl", "glb", "off"])
def test_mesh_formats(fmt, cloud, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path), "--mesh-format", fmt, "-q"]) == 0
    assert not (tmp_path / "surface.ply").exists()
    mesh = trimesh.load(tmp_path / f"surface.{fmt}", force="mesh")
    assert mesh.is_watertight and mesh.volume > 0


def test_several_inputs_one_bad(cloud, tmp_path, capsys):
    other = tmp_path / "elsewhere" / cloud.name  # same stem as `cloud`
    other.parent.mkdir()
    other.write_bytes(cloud.read_bytes())
    empty = tmp_path / "empty.ply"
    empty.touch()
    out = tmp_path / "out"
    code = cli.main(["reconstruct", str(cloud), str(empty), str(other), "-o", str(out)])
    assert code == 2
    captured = capsys.readouterr()
    line = _error_line(captured.err)
    assert str(empty) in line and "empty" in line
    assert sorted(p.name for p in out.iterdir()) == ["pipe", "pipe-2"]
    for folder in ("pipe", "pipe-2"):
        assert load_model(out / folder / "model.json").kind == "pipe"
    summary, notes = captured.out.strip().split("\nnote: ")  # the notes of the run follow once, at the end
    assert len(summary.splitlines()) == 2 and notes.startswith("no --units given: spine.dxf is unitless")


def test_json(cloud, tmp_path, capsys):
    out = tmp_path / "out"
    missing = tmp_path / "missing.xyz"
    assert cli.main(["reconstruct", str(cloud), str(missing), "-o", str(out), "--json"]) == 2
    captured = capsys.readouterr()
    ok, bad = (json.loads(line) for line in captured.out.strip().splitlines())
    assert ok["input"] == str(cloud) and ok["outdir"] == str(out / "pipe")
    (branch,) = ok["branches"]
    assert branch["kind"] == "pipe" and branch["closed"] is False and abs(branch["radius"] - 1) < RADIUS_TOL
    assert branch["ends"] == [None, None] and ok["junctions"] == 0 and ok["components"] == [[0]]
    assert {"R", "delta", "mu", "tau", "H"} <= set(ok["parameters"])
    assert ok["diagnostics"]["n_points"] == 2000
    assert all(Path(f).is_file() for f in ok["files"]) and str(out / "pipe" / "model.json") in ok["files"]
    assert bad["input"] == str(missing) and bad["exit_code"] == 2 and "not found" in bad["error"]
    assert _error_line(captured.err).endswith(bad["error"])


def test_verbose_logs_parameters(cloud, tmp_path, capsys):
    assert cli.main(["-v", "reconstruct", str(cloud), "-o", str(tmp_path), "--normals", "estimate"]) == 0
    err = capsys.readouterr().err
    for what in ("normals estimated", "R = ", "delta = ", "mu = ", "H = ", "stopped by", "timings"):
        assert what in err, what
    assert "canalsurf: error" not in err


def _write_xyz(path: Path, points) -> Path:
    np.savetxt(path, np.asarray(points), fmt="%.17g")
    return path


def _sphere(n=1000):
    v = np.random.default_rng(0).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _ply(path: Path, *, claim: int | None = None, keep_rows: int | None = None) -> Path:
    """A binary PLY of 200 float64 points whose header claims ``claim`` vertices and which is cut
    after ``keep_rows`` rows and a piece of the next."""
    write_points(path, _sphere(200), None)
    raw = path.read_bytes()
    if claim is not None:
        raw = raw.replace(b"element vertex 200\n", f"element vertex {claim}\n".encode())
    if keep_rows is not None:
        raw = raw[: raw.index(b"end_header\n") + len(b"end_header\n") + keep_rows * 24 + 7]
    path.write_bytes(raw)
    return path


def _special(path: Path, make) -> Path:
    """``make(path)`` creates a socket, pipe or link; skip where the system cannot."""
    try:
        make(path)
    except (AttributeError, NotImplementedError, OSError) as exc:
        pytest.skip(f"cannot create {path.name} here: {exc}")
    return path


def _socket(path: Path) -> None:
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(path))  # the socket file stays after the socket is closed


def _link_to_unreadable(path: Path) -> None:
    """A link to Linux's /proc/self/mem: a regular file whose first byte nobody can read, not even root
    (address 0 is never mapped, so reading it fails with EIO)."""
    target = Path("/proc/self/mem")
    if not target.is_file():
        raise NotImplementedError("no /proc/self/mem on this system")
    path.symlink_to(target)


def _text(path: Path, content: str) -> Path:
    path.write_text(content)
    return path


BAD_INPUTS = {
    # name -> (write the file into the folder and return its path, exit code, words in the message)
    "missing": (lambda d: d / "nothere.ply", 2, "file not found"),
    "empty": (lambda d: (d / "empty.ply").touch() or d / "empty.ply", 2, "empty"),
    "folder": (lambda d: (d / "scans.ply").mkdir() or d / "scans.ply", 2, "is a folder, not a point file"),
    "wrong extension": (lambda d: _write_xyz(d / "scan.vtk", _sphere(200)), 2, "unknown point format '.vtk'"),
    "truncated ply": (lambda d: _ply(d / "cut.ply", keep_rows=120), 2,
                      "PLY file is truncated (header says 200 vertices, data holds 120)"),
    "ply claims more": (lambda d: _ply(d / "more.ply", claim=300), 2,
                        "PLY file is truncated (header says 300 vertices, data holds 200)"),
    "ply claims fewer": (lambda d: _ply(d / "fewer.ply", claim=100), 2,
                         "PLY header says 100 vertices but more data follows"),
    "non-numeric row": (lambda d: _text(d / "row.csv", "x,y,z\n1,2,3\n4,5,6\n7,oops,9\n"), 2,
                        "line 4 is not numeric ('7,oops,9')"),
    "nan": (lambda d: _write_xyz(d / "nan.xyz", np.vstack([_sphere(200), [[np.nan, 0, 0]]])), 2, "NaN"),
    "inf": (lambda d: _write_xyz(d / "inf.xyz", np.vstack([_sphere(200), [[0, -np.inf, 0]]])), 2, "NaN or inf"),
    "too few": (lambda d: _write_xyz(d / "few.xyz", _sphere(10)), 2, "10 points"),
    "identical": (lambda d: _write_xyz(d / "same.xyz", np.ones((200, 3))), 2, "all points are identical"),
    "line": (lambda d: _write_xyz(d / "line.xyz", np.outer(np.arange(200.0), [1, 2, -3])), 2,
             "coplanar or collinear"),
    "plane": (lambda d: _write_xyz(d / "plane.xyz", np.c_[np.random.default_rng(1).uniform(size=(500, 2)),
                                                             np.zeros(500)]), 2, "coplanar"),
    # cannot-be-read cases that hold even for root, who may read any file whatever its permissions
    "socket": (lambda d: _special(d / "sock.ply", _socket), 2, "is a socket, not a regular file"),
    "named pipe": (lambda d: _special(d / "pipe.xyz", lambda p: os.mkfifo(p)), 2,
                   "is a named pipe, not a regular file"),
    "broken link": (lambda d: _special(d / "link.ply", lambda p: p.symlink_to(d / "gone.ply")), 2,
                    "gone.ply', which does not exist"),
    "read error": (lambda d: _special(d / "mem.npy", _link_to_unreadable), 2,
                   "cannot be read (Input/output error) — check the disk"),
    "not a tube": (lambda d: _write_xyz(d / "sphere.xyz", _sphere()), 1, "not a tube"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input(case, tmp_path, capsys, time_limit):
    make, code, words = BAD_INPUTS[case]
    path = make(tmp_path)
    out = tmp_path / "out"
    with time_limit(30):  # a reader waiting on the named pipe would otherwise hang the suite
        assert cli.main(["reconstruct", str(path), "-o", str(out)]) == code
    captured = capsys.readouterr()
    line = _error_line(captured.err)
    assert str(path) in line and words in line and " — " in line
    assert captured.out == ""
    assert not out.exists()


def test_output_inside_a_file(cloud, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("canalsurf.pipeline.reconstruct", _never)
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert cli.main(["reconstruct", str(cloud), "-o", str(blocker / "out")]) == 2
    line = _error_line(capsys.readouterr().err)
    assert "is a file" in line and "choose another output folder" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]
    assert cli.main(["demo", "-o", str(blocker)]) == 2
    _error_line(capsys.readouterr().err)


def test_output_that_cannot_be_written(cloud, tmp_path, capsys, instant_pipeline):
    """A real write failure that holds even for root: nothing can be created in Linux's /proc."""
    proc = Path("/proc")
    if not (proc / "self").is_dir():
        pytest.skip("needs Linux's /proc")
    out = proc / "canalsurf-test" / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out)]) == 2
    captured = capsys.readouterr()
    line = _error_line(captured.err)
    assert f"{cloud}: {out.parent}: cannot write (" in line
    assert line.endswith("— choose another output folder or free space")
    assert captured.out == "" and not out.parent.exists()
    target = proc / "canalsurf-test.ply"
    assert cli.main(["synth", "helix", "-o", str(target)]) == 2
    line = _error_line(capsys.readouterr().err)
    assert f"{target}: cannot write (" in line and line.endswith("— choose another output path")
    assert not target.exists()


def test_more_neighbours_than_points(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("canalsurf.pipeline.reconstruct", _never)
    path = _write_xyz(tmp_path / "sparse.xyz", _sphere(60))
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(path), "-o", str(out), "-k", "61"]) == 2
    assert _error_line(capsys.readouterr().err) == (
        f"canalsurf: error: {path}: 60 points are fewer than the 61 neighbours -k asks for — give a smaller "
        "-k or a denser scan")
    assert not out.exists()


def test_mesh_format_without_the_extra_fails_before_work(cloud, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "trimesh", None)  # import fails as if not installed
    monkeypatch.setattr("canalsurf.pipeline.reconstruct", _never)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--mesh-format", "obj"]) == 2
    assert _error_line(capsys.readouterr().err) == (
        "canalsurf: error: writing .obj meshes needs the 'mesh' extra — pip install 'canalsurf[mesh]', "
        "or use --mesh-format ply")
    assert not out.exists()


def test_failed_write_leaves_nothing(cloud, tmp_path, capsys, monkeypatch):
    def disk_full(path, *args):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr("canalsurf.io.write_spine_csv", disk_full)
    # a new folder: removed again
    out = tmp_path / "new" / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out)]) == 2
    line = _error_line(capsys.readouterr().err)
    assert "No space left on device" in line
    assert not (tmp_path / "new").exists()
    # an existing folder with an earlier result: left exactly as it was
    old = tmp_path / "old"
    old.mkdir()
    (old / "model.json").write_text("earlier")
    assert cli.main(["reconstruct", str(cloud), "-o", str(old)]) == 2
    _error_line(capsys.readouterr().err)
    assert [p.name for p in old.iterdir()] == ["model.json"]
    assert (old / "model.json").read_text() == "earlier"


def test_options_reach_reconstruct(cloud, tmp_path, capsys, monkeypatch):
    calls = []

    def fake(points, **kwargs):
        calls.append(kwargs)
        raise ReconstructionError("shrinking did not stop — try a larger R")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", fake)
    argv = ["reconstruct", str(cloud), "-o", str(tmp_path / "out"), "--kind", "canal", "-R", "0.3",
            "--delta", "0.04", "--mu", "0.8", "--tau", "0.2", "-H", "0.5", "-k", "12", "--stop", "paper",
            "--neighbours", "gauss", "--no-refine"]
    assert cli.main(argv) == 1
    assert cli.main(argv[:4] + ["--normals", "estimate"]) == 1
    line = _error_line(capsys.readouterr().err.splitlines()[0])
    assert line == f"canalsurf: error: {cloud}: shrinking did not stop — try a larger R"
    first, second = calls
    assert callable(first.pop("progress")) and callable(second.pop("progress"))
    assert first.pop("normals").shape == (2000, 3)  # the file's normals are used
    assert first == {"kind": "canal", "R": 0.3, "delta": 0.04, "mu": 0.8, "tau": 0.2, "H": 0.5, "k": 12,
                     "stop": "paper", "neighbours": "gauss", "refine": False, "client": None}
    assert second["normals"] is None
    assert second["kind"] == "auto" and second["R"] is None and second["refine"] is True


def test_library_warnings_become_log_lines(cloud, tmp_path, capsys, monkeypatch):
    def fake(points, **kwargs):
        warnings.warn("few points near the ends", UserWarning, stacklevel=1)
        raise ReconstructionError("not a tube — check the input")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", fake)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert cli.main(["reconstruct", str(cloud), "-o", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["canalsurf.cli: warning: few points near the ends",
                   f"canalsurf: error: {cloud}: not a tube — check the input"]


def test_folder_names_are_unique():
    paths = [Path("a/scan.ply"), Path("b/scan.ply"), Path("Scan.xyz"), Path("scan-2.ply")]
    assert cli._folder_names(paths) == ["scan", "scan-2", "Scan-3", "scan-2-2"]


# --- paper -----------------------------------------------------------------------------------------


@pytest.fixture
def experiments(monkeypatch):
    """A stand-in for ``canalsurf.experiments`` recording how run_paper is called."""
    module = types.ModuleType("canalsurf.experiments")
    module.calls = []

    def run_paper(outdir, *, seeds, progress=None):
        module.calls.append((Path(outdir), seeds))
        for i in range(3):
            progress(f"fig9-pipe seed {i}")
        return {"tables": 3}

    module.run_paper = run_paper
    monkeypatch.setitem(sys.modules, "canalsurf.experiments", module)
    return module


def test_paper(experiments, tmp_path, capsys):
    assert cli.main(["paper", "-o", str(tmp_path / "paper"), "--seeds", "3"]) == 0
    assert experiments.calls == [(tmp_path / "paper", 3)]
    assert str(tmp_path / "paper") in capsys.readouterr().out
    assert cli.main(["paper", "-o", str(tmp_path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"outdir": str(tmp_path), "seeds": 10,
                                                   "result": {"tables": 3}}


def test_paper_failure_is_one_line(experiments, tmp_path, capsys):
    def broken(outdir, *, seeds, progress=None):
        raise ReconstructionError("fig15-pipe: shrinking did not stop — see NOTES")

    experiments.run_paper = broken
    assert cli.main(["paper", "-o", str(tmp_path)]) == 1
    assert _error_line(capsys.readouterr().err) == \
        "canalsurf: error: fig15-pipe: shrinking did not stop — see NOTES"


def test_paper_without_experiments_module(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "canalsurf.experiments", None)  # import fails
    assert cli.main(["paper", "-o", str(tmp_path)]) == 2
    assert "paper experiments cannot be loaded" in _error_line(capsys.readouterr().err)


#: Seconds a 50 MB file of random bytes may take to be refused (it takes milliseconds: only its first
#: bytes are looked at), generous for slow machines.
REFUSE_SECONDS = 5.0


#: What a file of random bytes is told, per built-in suffix (.txt and .asc read like .xyz).
RANDOM_BYTES = {
    ".ply": "not a PLY file (it does not start with 'ply' and a format line) — re-export the file",
    ".xyz": "not a text file (it holds non-UTF-8 bytes) — export the points as text",
    ".csv": "not a text file (it holds non-UTF-8 bytes) — export the points as text",
    ".npy": "not a NumPy .npy file (it lacks the format's leading bytes) — save an (N, 3)",
    ".npz": "not a NumPy .npz file (it lacks the format's leading bytes) — save with numpy.savez",
}


@pytest.mark.parametrize("suffix", list(RANDOM_BYTES))
def test_fifty_megabytes_of_random_bytes(suffix, tmp_path, capsys):
    what = RANDOM_BYTES[suffix]
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(np.random.default_rng(7).bytes(50 << 20))
    out = tmp_path / "out"
    start = time.perf_counter()
    assert cli.main(["reconstruct", str(path), "-o", str(out)]) == 2
    assert time.perf_counter() - start < REFUSE_SECONDS
    assert _error_line(capsys.readouterr().err).startswith(f"canalsurf: error: {path}: {what}")
    assert not out.exists()


def test_quiet_paper_prints_nothing_even_when_its_runner_reads_info_records(experiments, tmp_path, capsys):
    """The paper runner lowers the pipeline logger's level to read its records; -q must still hold."""
    import logging

    def chatty(outdir, *, seeds, progress=None):
        logger = logging.getLogger("canalsurf.pipeline")
        level = logger.level
        logger.setLevel(logging.INFO)
        try:
            logger.info("shrinking: %d moves, break count %d, stopped by %s", 5, 10, "mu")
        finally:
            logger.setLevel(level)
        return {}

    experiments.run_paper = chatty
    assert cli.main(["-q", "paper", "-o", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_reconstruct_a_network_with_labels(tmp_path, capsys):
    """A T junction end to end: model.json version 2, one united mesh, branch columns and point labels."""
    trimesh = pytest.importorskip("trimesh")
    plyfile = pytest.importorskip("plyfile")
    truth = canalsurf.make_network("t-junction", n=12_000, rng=4)
    cloud = tmp_path / "tee.ply"
    write_points(cloud, truth.points, None)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--labels"]) == 0
    assert "3 branches (3 pipes, 0 canals), 1 junction, 1 separate network" in capsys.readouterr().out

    data = json.loads((out / "model.json").read_text())
    assert data["version"] == 2 and len(data["branches"]) == 3 and len(data["junctions"]) == 1
    assert data["components"] == [[0, 1, 2]]
    mesh = trimesh.load(out / "surface.ply", force="mesh", process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert len(mesh.split(only_watertight=False)) == 1  # the tubes are united at the junction
    table = np.loadtxt(out / "spine.csv", delimiter=",", skiprows=1)
    assert sorted(set(table[:, 0].astype(int))) == [0, 1, 2]

    vertex = plyfile.PlyData.read(str(out / "points.ply"))["vertex"]
    np.testing.assert_array_equal(np.column_stack([vertex["x"], vertex["y"], vertex["z"]]), truth.points)
    label = np.asarray(vertex["branch"])
    assert set(np.unique(label)) <= {-1, 0, 1, 2}
    assert np.mean(label >= 0) >= 0.95
    on = label >= 0
    assert np.abs(np.asarray(vertex["distance"])[on]).max() < 0.1  # radius 0.6 - 1, noise 2 %
