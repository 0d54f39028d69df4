"""Attacks on the ``canalsurf`` command: signals, a bug in one input of a batch, hostile input names,
an empty ``-o``, concurrent runs into one folder, stale files of an earlier run, caches in the home
folder, and numbers that pass a range check but not the arithmetic.

Where signals, separate processes or the environment matter the command runs in a subprocess
(``python -m canalsurf``, what the console script runs); elsewhere in-process through ``main(argv)``.
Every cloud is generated here from a seed.
"""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from canalsurf import _outputs, cli
from canalsurf._interrupt import INTERRUPTED
from canalsurf.io import write_points
from canalsurf.synth import make_tube

#: Seed of every cloud and every random choice below.
SEED = 20240611
#: The line an interrupted run prints.
INTERRUPTED_LINE = f"canalsurf: error: {INTERRUPTED}"
#: The command as the console script runs it.
COMMAND = [sys.executable, "-m", "canalsurf"]
#: Seconds any one subprocess may take before the test fails (instead of hanging).
SUBPROCESS_TIMEOUT = 120

posix_only = pytest.mark.skipif(os.name != "posix", reason="POSIX signals and file locks")


def _error_line(err: str) -> str:
    """The single stderr line of a failure (fails unless there is exactly one, and no traceback)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("canalsurf: error: "), err
    assert "Traceback" not in err
    return lines[0]


def _leftovers(folder: Path) -> list[str]:
    """canalsurf's temporary files in ``folder``: staging folders and the lock file."""
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir()
                  if p.name.startswith(".canalsurf") and p.name != _outputs.MANIFEST_NAME)


def _child_env(tmp_path: Path, **extra: str) -> dict[str, str]:
    """The environment of a subprocess: temporary files in a folder of the test's own."""
    env = dict(os.environ, **extra)
    tmp = tmp_path / "child-tmp"
    tmp.mkdir(exist_ok=True)
    env["TMPDIR"] = str(tmp)
    return env


def _write_cloud(path: Path, n: int, *, seed: int = SEED, scale: float = 1.0) -> Path:
    """The paper's Figure 9 pipe (true radius 1), ``n`` points, scaled by ``scale``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_points(path, scale * make_tube("fig9-pipe", n=n, rng=seed).points, None)
    return path


@pytest.fixture(scope="module")
def cloud(tmp_path_factory) -> Path:
    """2000 points, the size of the paper's examples."""
    return _write_cloud(tmp_path_factory.mktemp("cloud") / "pipe.ply", 2000)


@pytest.fixture
def never(monkeypatch):
    """Fail the test if a reconstruction starts."""

    def reconstruct(*args, **kwargs):
        raise AssertionError("reconstruction should not start")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)


# --- 1. Ctrl-C and SIGTERM -------------------------------------------------------------------------


def test_console_script_is_the_signal_safe_entry_point():
    """The console script must be canalsurf.__main__:main, which takes the signals over before SciPy
    loads; canalsurf.cli:main would leave the import time to Python's KeyboardInterrupt traceback."""
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    scripts = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["scripts"]
    assert scripts == {"canalsurf": "canalsurf.__main__:main"}
    code = "import sys, canalsurf.__main__; print(sorted({'numpy', 'scipy'} & set(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"  # nothing slow before the handlers are in place


def _startup_seconds() -> float:
    """Wall time of a process that only imports the entry point: before this the handlers cannot be
    in place, so signals are sent later than that."""
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import canalsurf.__main__"], check=True)
    return time.perf_counter() - start


def _signals_as_in_a_terminal() -> None:
    """The child's SIGINT and SIGTERM as in a command run from a terminal: a test suite started as a
    background job passes on SIGINT ignored, and an ignored signal stays ignored (see ``install``)."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)


@posix_only
def test_signals_end_in_one_line_and_leave_nothing(tmp_path):
    """SIGINT and SIGTERM at seeded moments of a 200k-point run with --report: exit 130 / 143 (never
    killed by the signal, never a segmentation fault), one line, no traceback, and either nothing
    written or the complete set of files (a signal during the final moves waits for them)."""
    pytest.importorskip("plotly")
    pytest.importorskip("matplotlib")
    big = _write_cloud(tmp_path / "big.ply", 200_000)
    complete = {"model.json", "surface.ply", "spine.csv", "report.html", _outputs.MANIFEST_NAME}
    if importlib.util.find_spec("ezdxf") is not None:
        complete.add("spine.dxf")
    rng = np.random.default_rng(SEED)
    # imports (the first ~0.6 s), then normals, shrinking, thinning, the fit and the report
    delays = np.concatenate([rng.uniform(0.05, 0.6, 3), rng.uniform(0.6, 3.0, 7)])
    floor = 1.5 * _startup_seconds()
    env = _child_env(tmp_path)
    interrupted = 0
    for i, delay in enumerate(np.maximum(delays, floor)):
        sig = (signal.SIGINT, signal.SIGTERM)[i % 2]
        out = tmp_path / f"out-{i}"
        child = subprocess.Popen([*COMMAND, "reconstruct", str(big), "-o", str(out), "--report"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                 preexec_fn=_signals_as_in_a_terminal)
        try:
            time.sleep(delay)
            child.send_signal(sig)
            _, err = child.communicate(timeout=SUBPROCESS_TIMEOUT)
        finally:
            child.kill()
            child.wait()
        what = f"{sig.name} after {delay:.2f} s: exit {child.returncode}, stderr {err!r}"
        assert child.returncode in (0, 128 + sig), what  # a negative code: killed (e.g. SIGSEGV)
        assert "Traceback" not in err and "Fatal Python error" not in err, what
        if child.returncode:
            interrupted += 1
            assert err.strip() == INTERRUPTED_LINE, what
        if delay < 1.0:  # imports and a 200k-point reconstruction take longer: surely interrupted
            assert child.returncode == 128 + sig, what
        # nothing (not even the folder), or everything: never a part, a staging folder or a lock
        assert not out.exists() or {p.name for p in out.iterdir()} == complete, what
        assert not any(Path(env["TMPDIR"]).iterdir()), what  # the private cache folder is gone too
    assert interrupted >= 3


@posix_only
def test_keyboard_interrupt_raised_during_imports(tmp_path):
    """A KeyboardInterrupt that some code raises while the command loads still ends in one line."""
    code = ("import sys, canalsurf.cli\n"
            "def loading(argv=None):\n"
            "    raise KeyboardInterrupt\n"
            "canalsurf.cli.main = loading\n"
            "from canalsurf.__main__ import main\n"
            "sys.exit(main())\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=_child_env(tmp_path), timeout=SUBPROCESS_TIMEOUT)
    assert done.returncode == 130 and done.stderr.strip() == INTERRUPTED_LINE


def test_interrupt_while_writing_in_process(cloud, tmp_path, capsys, monkeypatch):
    """main() called from Python: Ctrl-C in the middle of the writes removes the staging folder, the
    lock file and the folders made for the run, and leaves an earlier result as it was."""
    def interrupted(path, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("canalsurf.io.write_spine_csv", interrupted)
    out = tmp_path / "new" / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out)]) == cli.EXIT_INTERRUPTED
    assert _error_line(capsys.readouterr().err) == INTERRUPTED_LINE
    assert not (tmp_path / "new").exists()
    old = tmp_path / "old"
    old.mkdir()
    (old / "model.json").write_text("earlier")
    assert cli.main(["reconstruct", str(cloud), "-o", str(old)]) == cli.EXIT_INTERRUPTED
    _error_line(capsys.readouterr().err)
    assert [p.name for p in old.iterdir()] == ["model.json"] and (old / "model.json").read_text() == "earlier"


# --- 2. a bug in one input of a batch --------------------------------------------------------------


@pytest.mark.parametrize("error", [ValueError("boom"), RuntimeError("boom"), MemoryError()],
                         ids=["ValueError", "RuntimeError", "MemoryError"])
def test_unexpected_error_fails_only_its_input(error, cloud, tmp_path, capsys, monkeypatch):
    from canalsurf import pipeline

    real = pipeline.reconstruct
    bad = _write_cloud(tmp_path / "in" / "bad.ply", 2000, seed=SEED + 1)
    calls = []

    def reconstruct(points, **kwargs):
        calls.append(len(points))
        if len(calls) == 2:  # the second input: bad.ply
            raise error
        return real(points, **kwargs)

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)
    other = _write_cloud(tmp_path / "in" / "other.ply", 2000, seed=SEED + 2)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), str(bad), str(other), "-o", str(out), "--json"]) == 1
    captured = capsys.readouterr()
    what = f"{type(error).__name__}: boom" if str(error) else type(error).__name__
    assert _error_line(captured.err) == \
        f"canalsurf: error: {bad}: internal error ({what}) — please report it"
    records = [json.loads(line) for line in captured.out.splitlines()]
    assert [r["input"] for r in records] == [str(cloud), str(bad), str(other)]  # the batch went on
    assert records[1]["exit_code"] == 1 and "internal error" in records[1]["error"]
    assert "error" not in records[0] and "error" not in records[2]
    assert sorted(p.name for p in out.iterdir()) == ["other", "pipe"]
    for name in ("other", "pipe"):
        assert (out / name / "model.json").is_file()


def test_unexpected_error_traceback_with_verbose(cloud, tmp_path, capsys, monkeypatch):
    def reconstruct(points, **kwargs):
        raise RuntimeError("boom")

    monkeypatch.setattr("canalsurf.pipeline.reconstruct", reconstruct)
    missing = tmp_path / "missing.ply"
    argv = ["reconstruct", str(missing), str(cloud), "-o", str(tmp_path / "out")]
    assert cli.main(argv) == 2  # the highest failure: a missing file (2) over the bug (1)
    assert len(capsys.readouterr().err.strip().splitlines()) == 2
    assert cli.main(["-v", *argv]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and 'raise RuntimeError("boom")' in err  # the debug aid
    assert f"canalsurf: error: {cloud}: internal error (RuntimeError: boom) — please report it" in err


def test_unexpected_error_outside_reconstruct_is_one_line(tmp_path, capsys, monkeypatch):
    def broken(args, console):
        raise RuntimeError("boom")

    monkeypatch.setattr(cli, "_cmd_demo", broken)
    assert cli.main(["demo", "-o", str(tmp_path / "demo")]) == 1
    assert _error_line(capsys.readouterr().err) == \
        "canalsurf: error: internal error (RuntimeError: boom) — please report it"


# --- 3. folder names made from input names ---------------------------------------------------------

#: Characters the generated names are drawn from: separators, dots, dashes, spaces, control
#: characters, Windows' forbidden ones, letters and non-ASCII.
NAME_ALPHABET = list("/\\.- :*?\"<>|\t\n\x00\x7fabcXYZ019_é€𝄞") + ["\udcff"]  # an undecodable byte
RESERVED = ["CON", "prn", "Aux", "NUL", "com1", "LPT9", "COM¹", "con.tar", "NUL "]


def _random_stems(n: int) -> list[str]:
    rng = np.random.default_rng(SEED)
    stems = ["..", ".", "...", "", "-", "--rf", "-o", "../../etc", "a/../../b", "..\\..\\x", " . ",
             *RESERVED, "é" * 300]
    for _ in range(n):
        length = int(rng.integers(1, 12))
        stems.append("".join(rng.choice(NAME_ALPHABET, length)))
    return stems


def test_safe_folder_names(tmp_path):
    base = tmp_path.resolve()
    names = cli._folder_names([Path(f"{stem}.ply") for stem in _random_stems(500)])
    assert len({n.casefold() for n in names}) == len(names)  # unique, even where case is ignored
    for name in names:
        assert name and name not in (".", "..") and name == name.strip()
        assert not name.startswith(("-", ".")) and not name.endswith(".")
        assert not set(name) & set("/\\:*?\"<>|") and name.isprintable()
        assert name.split(".")[0].rstrip(" ").upper() not in cli._WINDOWS_RESERVED
        assert len(name.encode("utf-8")) <= cli.FOLDER_NAME_BYTES + 8
        assert (base / name).resolve().parent == base  # one plain folder inside the output folder


def test_dot_dot_input_writes_inside_the_output_folder(cloud, tmp_path, capsys):
    inputs = tmp_path / "in"
    inputs.mkdir()
    dots, con = inputs / "...ply", inputs / "CON.ply"
    for path in (dots, con):
        path.write_bytes(cloud.read_bytes())
    out = tmp_path / "work" / "out"
    assert cli.main(["reconstruct", str(dots), str(con), "-o", str(out), "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["_CON", "input"]
    assert sorted(p.name for p in (tmp_path / "work").iterdir()) == ["out"]  # nothing beside -o
    assert (out / "input" / "model.json").is_file() and (out / "_CON" / "model.json").is_file()


@posix_only
def test_a_link_out_of_the_output_folder_is_refused(cloud, tmp_path, capsys):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "pipe").symlink_to(elsewhere, target_is_directory=True)
    other = tmp_path / "in" / "other.ply"
    other.parent.mkdir()
    other.write_bytes(cloud.read_bytes())
    assert cli.main(["reconstruct", str(cloud), str(other), "-o", str(out), "-q"]) == 2
    line = _error_line(capsys.readouterr().err)
    assert f"{out / 'pipe'}: leads outside {out}" in line
    assert not any(elsewhere.iterdir())  # nothing written through the link
    assert (out / "other" / "model.json").is_file()  # the other input went on


# --- 4. an empty output path -----------------------------------------------------------------------


@pytest.mark.parametrize("argv", [["reconstruct", "CLOUD", "-o", ""], ["reconstruct", "CLOUD", "-o", "  "],
                                  ["demo", "-o", ""], ["paper", "-o", ""]])
def test_empty_output_path_is_refused(argv, cloud, tmp_path, capsys, monkeypatch, never):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "model.json").write_text("mine")
    argv = [str(cloud) if a == "CLOUD" else a for a in argv]
    assert cli.main(argv) == 2
    line = _error_line(capsys.readouterr().err)
    assert "argument -o/--output: expected a folder" in line and "'-o .'" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]
    assert (tmp_path / "model.json").read_text() == "mine"


# --- 5. concurrent runs into one folder ------------------------------------------------------------

#: A child that moves files slowly (a seeded pause before each os.replace), so that without the lock
#: the moves of two runs into one folder would interleave.
SLOW_MOVES = """
import os, random, sys, time
real, rng = os.replace, random.Random(int(sys.argv[1]))
def replace(src, dst, **kwargs):
    time.sleep(rng.uniform(0.0, 0.1))
    return real(src, dst, **kwargs)
os.replace = replace
sys.argv = ["canalsurf", *sys.argv[2:]]
from canalsurf.__main__ import main
sys.exit(main())
"""
#: Concurrent runs.
N_RUNS = 8


def _scales(folder: Path, diagonal: float) -> dict[str, int]:
    """Which of the two inputs (scale 1 or 2) each file of a result folder was made from."""
    from plyfile import PlyData

    def scale(value: float, unit: float) -> int:
        return 2 if value > 1.5 * unit else 1

    data = json.loads((folder / "model.json").read_text())
    table = np.genfromtxt(folder / "spine.csv", delimiter=",", names=True)
    vertex = PlyData.read(str(folder / "surface.ply"))["vertex"]
    mesh = np.column_stack([vertex["x"], vertex["y"], vertex["z"]])
    found = {"model.json": scale(data["parameters"]["r0"], 1.0),  # the first radius estimate
             "spine.csv": scale(float(np.median(table["radius"])), 1.0),
             "surface.ply": scale(float(np.ptp(mesh, axis=0) @ np.ptp(mesh, axis=0)) ** 0.5, diagonal)}
    if (folder / "spine.dxf").exists():
        import ezdxf

        points = np.vstack([np.array(s.control_points)
                            for s in ezdxf.readfile(folder / "spine.dxf").modelspace().query("SPLINE")])
        found["spine.dxf"] = scale(float(np.ptp(points, axis=0) @ np.ptp(points, axis=0)) ** 0.5, diagonal)
    return found


@posix_only
def test_concurrent_runs_do_not_mix_their_files(tmp_path):
    """N_RUNS runs at once into one -o, half with one pair of inputs and half with the same pair
    scaled by 2: every result folder must hold the files of one run (all of one scale)."""
    pairs = []
    for scale in (1.0, 2.0):
        folder = tmp_path / f"x{scale:g}"
        pairs.append([str(_write_cloud(folder / f"{name}.ply", 2000, seed=SEED + i, scale=scale))
                      for i, name in enumerate(("p", "q"))])
    diagonal = float(np.ptp(make_tube("fig9-pipe", n=2000, rng=SEED).points, axis=0) @
                     np.ptp(make_tube("fig9-pipe", n=2000, rng=SEED).points, axis=0)) ** 0.5
    out = tmp_path / "out"
    env = _child_env(tmp_path)
    children = [subprocess.Popen([sys.executable, "-c", SLOW_MOVES, str(SEED + i), "reconstruct",
                                  *pairs[i % 2], "-o", str(out), "-q"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
                for i in range(N_RUNS)]
    try:
        results = [child.communicate(timeout=SUBPROCESS_TIMEOUT) for child in children]
    finally:
        for child in children:
            child.kill()
            child.wait()
    for child, (_, err) in zip(children, results):
        assert child.returncode == 0 and err == "", err
    assert sorted(p.name for p in out.iterdir()) == ["p", "q"]
    for name in ("p", "q"):
        folder = out / name
        scales = _scales(folder, diagonal)
        assert len(set(scales.values())) == 1, f"{folder}: files of different runs: {scales}"
        manifest = json.loads((folder / _outputs.MANIFEST_NAME).read_text())
        assert set(manifest["files"]) == {p.name for p in folder.iterdir() if not p.name.startswith(".")}
        assert _leftovers(folder) == []


@pytest.mark.skipif(_outputs.fcntl is None and _outputs.msvcrt is None, reason="no file locking")
def test_a_folder_locked_too_long_is_refused(cloud, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(_outputs, "LOCK_TIMEOUT", 0.3)
    out = tmp_path / "out"
    with _outputs.output_lock(out):  # another run writing (flock: a second open file conflicts)
        assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 2
    line = _error_line(capsys.readouterr().err)
    assert f"{out}: another canalsurf run has been writing into this folder for 0.3 s" in line
    assert not any(out.iterdir())  # no staging folder; the lock file went with the holder
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0  # free again


# --- 6. files of an earlier run --------------------------------------------------------------------


def test_rerun_removes_only_the_files_it_wrote_before(cloud, tmp_path, capsys):
    pytest.importorskip("plotly")
    pytest.importorskip("matplotlib")
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--report", "-q"]) == 0
    assert (out / "report.html").is_file()
    (out / "notes.txt").write_text("mine")
    (out / "spine.csv").write_text("edited by hand")  # will be replaced: canalsurf writes it again
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0
    assert not (out / "report.html").exists()  # stale: written before, not now
    assert (out / "notes.txt").read_text() == "mine"  # never written by canalsurf
    assert (out / "spine.csv").read_text() != "edited by hand"
    # a report changed since canalsurf wrote it is kept
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "--report", "-q"]) == 0
    with open(out / "report.html", "a", encoding="utf-8") as page:
        page.write("<!-- my notes -->")
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0
    assert (out / "report.html").read_text(encoding="utf-8").endswith("<!-- my notes -->")
    assert _leftovers(out) == []


def test_a_forged_manifest_removes_nothing_outside(cloud, tmp_path, capsys):
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (out / "sub").mkdir()
    (out / "sub" / "x.txt").write_text("keep")
    stamp = {"size": victim.stat().st_size, "mtime_ns": victim.stat().st_mtime_ns}
    inner = {"size": (out / "sub" / "x.txt").stat().st_size,
             "mtime_ns": (out / "sub" / "x.txt").stat().st_mtime_ns}
    forged = {"files": {"../victim.txt": stamp, "sub/x.txt": inner, str(victim): stamp, ".": stamp}}
    (out / _outputs.MANIFEST_NAME).write_text(json.dumps(forged))
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0
    assert victim.read_text() == "keep" and (out / "sub" / "x.txt").read_text() == "keep"
    (out / _outputs.MANIFEST_NAME).write_text("{not json")  # unreadable: removes nothing, is rewritten
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), "-q"]) == 0
    assert "model.json" in json.loads((out / _outputs.MANIFEST_NAME).read_text())["files"]


# --- 7. nothing written into the home folder -------------------------------------------------------


def test_no_caches_in_the_home_folder(cloud, tmp_path):
    pytest.importorskip("plotly")
    pytest.importorskip("matplotlib")
    pytest.importorskip("ezdxf")
    home = tmp_path / "home"
    home.mkdir()
    env = _child_env(tmp_path, HOME=str(home), USERPROFILE=str(home))
    for name in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "MPLCONFIGDIR"):
        env.pop(name, None)
    out = tmp_path / "out"
    done = subprocess.run([*COMMAND, "reconstruct", str(cloud), "-o", str(out), "--report", "-q"],
                          capture_output=True, text=True, env=env, timeout=SUBPROCESS_TIMEOUT)
    assert done.returncode == 0, done.stderr
    assert (out / "report.html").is_file() and (out / "spine.dxf").is_file()
    assert [str(p.relative_to(home)) for p in home.rglob("*")] == []
    assert not any(Path(env["TMPDIR"]).iterdir())  # and the temporary cache folder is gone


def test_ezdxf_reads_no_font_files_in_the_private_cache(tmp_path):
    # ezdxf scans the system's fonts when its font list is absent or of a version it does not read,
    # and then rewrites the list; the empty list written for it must be read as it is.
    pytest.importorskip("ezdxf")
    env = _child_env(tmp_path)
    env.pop("XDG_CACHE_HOME", None)
    code = ("import os\n"
            "from canalsurf import _interrupt\n"
            "with _interrupt.private_caches():\n"
            "    import ezdxf\n"
            "    path = os.path.join(os.environ['XDG_CACHE_HOME'], _interrupt.EZDXF_FONT_CACHE[0])\n"
            "    print(open(path).read() == _interrupt.EZDXF_FONT_CACHE[1])\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=SUBPROCESS_TIMEOUT)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"


# --- 8. numbers that pass a range check but not the arithmetic --------------------------------------

#: Option values that are refused before any work: each names its option in the one error line.
REFUSED = {
    "delta overflows": (["--delta", "1e308"], "argument --delta"),
    "delta tiny": (["--delta", "1e-308"], "argument --delta"),
    "delta subnormal": (["--delta", "5e-324"], "argument --delta"),
    "H singular": (["-H", "1e-308"], "argument -H/--H"),
    "R huge": (["-R", "1e308"], "argument -R/--R"),
    "k dashes": (["-k=--"], "argument -k"),
    "k empty": (["-k="], "argument -k"),
    "k overflows": (["-k", "1e400"], "argument -k"),
    "kind dashes": (["--kind=--"], "argument --kind"),
    "mu dashes": (["--mu=--"], "argument --mu"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_absurd_numbers_are_usage_errors(case, cloud, tmp_path, capsys, never):
    option, what = REFUSED[case]
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(cloud), "-o", str(out), *option]) == 2
    line = _error_line(capsys.readouterr().err)
    assert what in line and "--help" in line
    assert not out.exists()


@pytest.mark.parametrize("option", [["-H", "1e-300"], ["-R", "1e14"]], ids=["H tiny", "R huge"])
def test_numbers_the_parser_lets_through_never_give_a_traceback(option, cloud, tmp_path, capsys):
    """Values within the parser's bounds that the method cannot use end as a result or one line."""
    code = cli.main(["reconstruct", str(cloud), "-o", str(tmp_path / "out"), *option])
    err = capsys.readouterr().err
    assert code in (0, 1, 2) and "Traceback" not in err
    assert len(err.strip().splitlines()) == (0 if code == 0 else 1), err
