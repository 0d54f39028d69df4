"""Tests of the ``canalsurf`` command, run in-process through ``main(argv)``."""

from __future__ import annotations

import json
import logging
import re
import sys
import types
import warnings
from pathlib import Path

import numpy as np
import pytest

import canalsurf
from canalsurf import cli, load_model
from canalsurf.errors import ReconstructionError
from canalsurf.io import read_points
from canalsurf.synth import SURFACES, make_tube

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


@pytest.mark.parametrize("command", [[], ["demo"], ["reconstruct"], ["synth"], ["paper"]])
def test_help_has_examples(command, capsys):
    assert cli.main([*command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: canalsurf") and "examples:" in out


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
    assert json.loads(capsys.readouterr().out) == first == {n: s[-1] for n, s in SURFACES.items()}


def test_logging_is_restored_after_main(capsys):
    logger = logging.getLogger("canalsurf")
    handlers, level = list(logger.handlers), logger.level
    cli.main(["-v", "synth", "--list"])
    assert logger.handlers == handlers and logger.level == level


# --- synth -----------------------------------------------------------------------------------------


def test_synth_list(capsys):
    assert cli.main(["synth", "--list"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == len(SURFACES)
    for line, (name, spec) in zip(lines, SURFACES.items()):
        assert line.split()[0] == name and line.endswith(spec[-1])


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
    samples = json.loads((out / "model.json").read_text())["samples"]
    assert len(samples["t"]) >= 200

    # spine.csv holds exactly model.json's samples
    table = np.loadtxt(out / "spine.csv", delimiter=",", skiprows=1)
    assert (out / "spine.csv").read_text().splitlines()[0] == "t,x,y,z,radius"
    np.testing.assert_allclose(table, np.column_stack([samples["t"], samples["points"], samples["radius"]]),
                               rtol=1e-15, atol=0)

    mesh = trimesh.load(out / "surface.ply", force="mesh")
    assert mesh.is_watertight and mesh.volume > 0
    # a capped tube of radius ~1 around the spine: volume close to pi r^2 L
    length = cli._spine_length(model)
    assert mesh.volume == pytest.approx(np.pi * length, rel=0.05)

    expected = {"model.json", "surface.ply", "spine.csv"}
    if cli._dxf_available():
        expected.add("spine.dxf")
    assert {p.name for p in out.iterdir()} == expected  # nothing else (no staging folder)


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
    assert len(captured.out.strip().splitlines()) == 2


def test_json(cloud, tmp_path, capsys):
    out = tmp_path / "out"
    missing = tmp_path / "missing.xyz"
    assert cli.main(["reconstruct", str(cloud), str(missing), "-o", str(out), "--json"]) == 2
    captured = capsys.readouterr()
    ok, bad = (json.loads(line) for line in captured.out.strip().splitlines())
    assert ok["input"] == str(cloud) and ok["outdir"] == str(out / "pipe")
    assert ok["kind"] == "pipe" and ok["closed"] is False and abs(ok["radius"] - 1) < RADIUS_TOL
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


BAD_INPUTS = {
    # name -> (write the file into the folder and return its path, exit code, words in the message)
    "missing": (lambda d: d / "nothere.ply", 2, "file not found"),
    "empty": (lambda d: (d / "empty.ply").touch() or d / "empty.ply", 2, "empty"),
    "nan": (lambda d: _write_xyz(d / "nan.xyz", np.vstack([_sphere(200), [[np.nan, 0, 0]]])), 2, "NaN"),
    "too few": (lambda d: _write_xyz(d / "few.xyz", _sphere(10)), 2, "10 points"),
    "plane": (lambda d: _write_xyz(d / "plane.xyz", np.c_[np.random.default_rng(1).uniform(size=(500, 2)),
                                                             np.zeros(500)]), 2, "coplanar"),
    "not a tube": (lambda d: _write_xyz(d / "sphere.xyz", _sphere()), 1, "not a tube"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input(case, tmp_path, capsys):
    make, code, words = BAD_INPUTS[case]
    path = make(tmp_path)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(path), "-o", str(out)]) == code
    captured = capsys.readouterr()
    line = _error_line(captured.err)
    assert str(path) in line and words in line and " — " in line
    assert captured.out == ""
    assert not out.exists()


def test_output_inside_a_file(cloud, tmp_path, capsys, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("reconstruction should not start")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", never)
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert cli.main(["reconstruct", str(cloud), "-o", str(blocker / "out")]) == 2
    line = _error_line(capsys.readouterr().err)
    assert "is a file" in line and "choose another output folder" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]
    assert cli.main(["demo", "-o", str(blocker)]) == 2
    _error_line(capsys.readouterr().err)


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
                     "stop": "paper", "neighbours": "gauss", "refine": False}
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


@pytest.mark.parametrize("suffix", [".ply", ".xyz", ".npy"])
def test_fifty_megabytes_of_random_bytes(suffix, tmp_path, capsys):
    path = tmp_path / f"noise{suffix}"
    path.write_bytes(np.random.default_rng(7).bytes(50 << 20))
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(path), "-o", str(out)]) == 2
    assert _error_line(capsys.readouterr().err).startswith(f"canalsurf: error: {path}: ")
    assert not out.exists()
