"""Speed and memory of the whole ``canalsurf reconstruct`` process against the machine's "floor".

For each size the paper's Figure 9 pipe is sampled (seeded, area-uniform), written as a binary PLY,
and reconstructed by the command line in a child process (file in, model.json + surface.ply out, no
parameters).  The floor -- one KD-tree build plus a 16-nearest-neighbour query over all the points on
all cores -- is measured in the same run, so machine noise cancels in the ratio.  Peak memory is the
child's maximum resident set size (``os.wait4``).  Accuracy is measured against the ground truth.
Each size is checked against its targets (``TARGETS``).

canalsurf's modules are first compiled to bytecode, as ``pip install`` leaves them: no run then pays for
compiling them (as every run would where ``PYTHONDONTWRITEBYTECODE`` is set, or the package directory
is read-only).

Sampling, the floor and scoring run in helper processes of their own: Linux counts the memory of the
process that starts a child into the child's peak, so the process that starts ``canalsurf`` must
stay small (it does not even import numpy).

Run from the repository root::

    python benchmarks/bench.py                 # 2k, 20k, 200k, 1M points
    python benchmarks/bench.py --full          # ... and 10M
    python benchmarks/bench.py --repeat 3      # fastest of 3 runs (on a busy machine)
    python benchmarks/bench.py --markdown docs/performance.md
    python benchmarks/bench.py --sizes 2000 --no-scene     # one size, no scene row
    python benchmarks/bench.py --sizes --no-scene --stream 10000000   # only the streaming row
    python benchmarks/bench.py --sizes --no-scene --stream 10000000 100000000 --bays 9   # two files
    python benchmarks/bench.py --sizes --no-scene --stream 10000000 --bays 9 --dask 1 2 4   # and on Dask

Besides the single tube, one row reconstructs a scene of many tubes (``SCENE``) of a million points.
With ``--stream N [N ...]`` another row per N streams a LAZ file of N points of that scene: generated once, in parts
of ``STREAM_PART`` points (each an independent seeded sample of the same plant) through laspy's chunked
writer, so no process holds the whole cloud; then laspy alone reads all its points (chunk by chunk, with
laspy's default, multi-threaded decoder) and ``canalsurf reconstruct`` runs on it, each in a process of
its own, timed in the same run; the row gives the ratio of the two and canalsurf's peak memory.
With ``--dask W [W ...]`` the first streamed file is reconstructed again with ``--dask ADDRESS`` on a local
Dask cluster of W worker processes (started in a process of its own), one row per W, and each model.json
is compared with the one of the run without Dask, byte for byte.
"""

from __future__ import annotations

import argparse
import compileall
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIZES = (2_000, 20_000, 200_000, 1_000_000)
FULL = (10_000_000,)
#: The stages ``reconstruct`` times (canalsurf.pipeline.STAGES; not imported, see above).
STAGES = ("normals", "shrink", "thin", "skeleton", "fit", "junctions", "residual")
#: The benchmark scene: the ``plant`` network (23 tubes per bay, a floor and boxes), its size and points.
SCENE, SCENE_SIZE, SCENE_POINTS = "plant", 1, 1_000_000
#: A true tube of the scene counts as found when its matched model branch covers this share of it.
FOUND_COVERED = 0.95
#: Points of each part of the streamed LAZ file (--stream): make_network takes about 12 s and 1 GB
#: for 2 million points of the plant.
STREAM_PART = 2_000_000
#: Grid of the streamed file's coordinates (LAS scale): a millimetre, on tubes of radius 0.9 (in the
#: same units) with 2 % noise.
STREAM_SCALE = 0.001
#: Points laspy hands out at a time when it reads the file alone: a million, laspy's own example size.
LASPY_CHUNK = 1_000_000
#: Targets of the streaming row, from the plant-scale issue: canalsurf's time at most this many times
#: laspy's alone, and peak memory in MB.
STREAM_TARGETS = (3.0, 4096)
#: ... and of the streamed plant of PLANT_POINTS (the issue's 10 million points of 200 tubes and more):
#: every tube found, within this many seconds, with each tube's spine mean within this share of its radius.
PLANT_TARGETS = (60.0, 0.02)
PLANT_POINTS = 10_000_000
#: Targets per size: (largest total wall / floor, largest total wall in seconds, largest peak MB).
#: Where a ratio is given it is the target and the seconds only say roughly what it means on a
#: typical machine; a paper-sized cloud has no meaningful floor, so there the seconds count
#: (Python start-up and imports included).
TARGETS = {
    2_000: (None, 1.0, 200),
    200_000: (1.3, 4.0, 600),
    1_000_000: (0.7, 12.0, 1500),
    10_000_000: (0.7, 150.0, 10_000),
}


def _tube(n: int):
    """The benchmark cloud of ``n`` points and its ground truth (the same every time)."""
    import canalsurf

    return canalsurf.make_tube("fig9-pipe", n=n, rng=0)


def prepare(n: int, cloud: Path, repeat: int) -> dict:
    """Write the cloud of ``n`` points to ``cloud``; the fastest of ``repeat`` floors in seconds."""
    from scipy.spatial import cKDTree

    from canalsurf.io import write_points

    points = _tube(n).points
    write_points(cloud, points, None)
    floors = []
    for _ in range(repeat):
        start = time.perf_counter()
        cKDTree(points).query(points, k=16, workers=-1)
        floors.append(time.perf_counter() - start)
    return {"floor": min(floors)}


def score(n: int, model_path: Path) -> dict:
    """Spine and radius errors of the model at ``model_path``, in shares of the true mean radius."""
    import canalsurf
    from canalsurf.metrics import compare

    c = compare(canalsurf.load_model(model_path), _tube(n))
    r = c["mean_radius"]
    return {"spine_mean": c["spine_mean"] / r, "spine_max": c["spine_max"] / r,
            "radius": c["radius"]["max"] / r}


def _scene(size: int = SCENE_SIZE, n: int = SCENE_POINTS):
    import canalsurf

    return canalsurf.make_network(SCENE, n=n, size=size, rng=0)


def prepare_scene(cloud: Path) -> dict:
    """Write the benchmark scene to ``cloud``; its number of tubes and junctions."""
    from canalsurf.io import write_points

    scene = _scene()
    write_points(cloud, scene.points, None)
    return {"tubes": len(scene.branches), "junctions": len(scene.junctions)}


def score_scene(model_path: Path, size: int = SCENE_SIZE) -> dict:
    """Branches found and the worst accuracy over the branches of the scene's model (a plant of ``size``
    bays; its truth sampled with as many points as the scene row, for the labels)."""
    import canalsurf
    import numpy as np
    from canalsurf.metrics import compare_network, model_error
    from trust import outside_claim

    network, truth = canalsurf.load_model(model_path), _scene(size)
    c = compare_network(network, truth)
    errors = [e for e in model_error(network, truth.branches, truth.junctions) if np.isfinite(e["spine_mean"])]
    # A true tube is found when the model branch matched to it follows it (covers 95 % of it); the
    # accuracy columns are over the tubes found (a missed tube's "match" is some other branch).
    found = [b for b in c["branches"] if b["covered"] >= FOUND_COVERED]
    return {"branches": len(network.branches), "found_junctions": len(network.junctions),
            "found": len(found), "tubes": len(truth.branches), "junctions": len(truth.junctions),
            "outside": sum(outside_claim(e) for e in errors),
            "spine_mean_mean": float(sum(b["spine_mean"] for b in found) / max(len(found), 1)),
            "spine_mean": max((b["spine_mean"] for b in found), default=float("nan")),
            "radius": max((b["radius_mean"] for b in found), default=float("nan")),
            "clutter_right": c["clutter_right"], "tube_right": c["tube_right"]}


def bench_scene(workdir: Path) -> dict:
    """The scene row: one reconstruction of the benchmark scene, timed, measured and scored."""
    cloud, out = workdir / "scene.ply", workdir / "out-scene"
    row = _helper("prepare_scene", cloud)
    wall, rss, summary, code = run_cli(cloud, out)
    row.update(points=SCENE_POINTS, wall=wall, rss=rss, exit=code)
    if code == 0:
        row.update(stages=summary["diagnostics"]["seconds"], **_helper("score_scene", out / "model.json"))
    else:
        row["error"] = summary.get("error", "")
    return row


def scene_table(row: dict) -> str:
    head = ("| scene | tubes | points | " + " | ".join(STAGES) + " | total wall s | peak MB | tubes found "
            "| branches, junctions in the model | outside its claim | spine mean % r (worst tube found) "
            "| radius err % r (worst) | clutter / tube points right |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    if row["exit"] != 0:
        lines.append(f"| {SCENE} | {row['tubes']} | {row['points']:,} | failed (exit {row['exit']}): "
                     f"{row['error'].strip()} |")
        return "\n".join(lines)
    st = " | ".join(f"{row['stages'].get(s, 0.0):.2f}" for s in STAGES)
    lines.append(f"| {SCENE} (size {SCENE_SIZE}) | {row['tubes']} | {row['points']:,} | {st} | {row['wall']:.1f} | "
                 f"{row['rss'] / 2**20:.0f} | {row['found']} of {row['tubes']} | {row['branches']} "
                 f"(true {row['tubes']}), {row['found_junctions']} (true {row['junctions']}) | {row['outside']} | "
                 f"{100 * row['spine_mean']:.2f} | {100 * row['radius']:.2f} | {row['clutter_right']:.3f} / "
                 f"{row['tube_right']:.3f} |")
    return "\n".join(lines)


def prepare_stream(n: int, cloud: Path, size: int = SCENE_SIZE) -> dict:
    """Write ``n`` points of the benchmark plant of ``size`` bays as a LAZ file, a part at a time; seconds
    and bytes."""
    import laspy
    import numpy as np

    import canalsurf

    start = time.perf_counter()
    header = laspy.LasHeader(point_format=3, version="1.4")
    header.scales = np.full(3, STREAM_SCALE)
    header.offsets = np.zeros(3)
    with laspy.open(cloud, mode="w", header=header) as writer:
        for seed, first in enumerate(range(0, n, STREAM_PART)):
            part = canalsurf.make_network(SCENE, n=min(STREAM_PART, n - first), size=size, rng=seed).points
            record = laspy.ScaleAwarePointRecord.zeros(len(part), header=header)
            record.x, record.y, record.z = part.T
            writer.write_points(record)
    return {"generate": time.perf_counter() - start, "bytes": cloud.stat().st_size}


def laspy_read(cloud: Path) -> dict:
    """Seconds laspy alone takes to read every point of ``cloud`` (opening included), and the count."""
    import laspy

    start = time.perf_counter()
    count = 0
    with laspy.open(cloud) as reader:
        for points in reader.chunk_iterator(LASPY_CHUNK):
            count += len(points)
    return {"laspy": time.perf_counter() - start, "read": count}


def bench_stream(n: int, workdir: Path, size: int = SCENE_SIZE, dask: tuple = ()) -> dict:
    """The streaming row: a LAZ file of ``n`` points of a plant of ``size`` bays, read by laspy alone and
    reconstructed; then on a local Dask cluster of each number of workers in ``dask``."""
    cloud, out = workdir / f"{SCENE}-{n}.laz", workdir / "out-stream"
    row = {"points": n, "size": size, **_helper("prepare_stream", n, cloud, size), **_helper("laspy_read", cloud)}
    wall, rss, summary, code = run_cli(cloud, out)
    row.update(wall=wall, rss=rss, ratio=wall / row["laspy"], exit=code)
    model = (out / "model.json").read_bytes() if code == 0 else None
    row["dask"] = [bench_dask(w, cloud, workdir / f"out-dask-{w}", model) for w in dask]
    cloud.unlink()
    if code == 0:
        row.update(sampled=summary.get("points_sampled", summary.get("points_read")), read=summary["read_seconds"],
                   stages=summary["diagnostics"]["seconds"], **_helper("score_scene", out / "model.json", size))
    else:
        row["error"] = summary.get("error", "")
    return row


def dask_cluster(workers: int) -> None:
    """Run a local Dask cluster of ``workers`` processes until stdin closes; its address, as JSON, first."""
    import distributed

    with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster:
        print(json.dumps({"address": cluster.scheduler_address}), flush=True)
        sys.stdin.read()


def bench_dask(workers: int, cloud: Path, out: Path, model: bytes | None) -> dict:
    """Wall seconds and fit seconds of ``canalsurf reconstruct --dask`` on a cluster of ``workers``, and
    whether its model.json is ``model``, byte for byte."""
    cluster = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--helper", "dask_cluster",
                                str(workers)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        address = json.loads(cluster.stdout.readline())["address"]
        wall, rss, summary, code = run_cli(cloud, out, "--dask", address)
    finally:
        cluster.stdin.close()
        cluster.wait()
    if code != 0:
        return {"workers": workers, "wall": wall, "exit": code, "error": summary.get("error", "")}
    return {"workers": workers, "wall": wall, "rss": rss, "exit": code, "fit": summary["diagnostics"]["seconds"]["fit"],
            "same": (out / "model.json").read_bytes() == model}


def dask_table(row: dict) -> str:
    """The Dask rows of a streamed file: seconds, speed-up over one worker, and the model against the run
    without Dask."""
    lines = ["| Dask workers | canalsurf wall s | fit s | speed-up over 1 worker (wall, fit) | client peak MB "
             "| model.json the same as without Dask |", "|---|---|---|---|---|---|"]
    one = next((r for r in row["dask"] if r["workers"] == 1 and r["exit"] == 0), None)
    for r in row["dask"]:
        if r["exit"] != 0:
            lines.append(f"| {r['workers']} | {r['wall']:.2f} | failed (exit {r['exit']}): {r['error'].strip()} | | | |")
            continue
        speed = "" if one is None else f"{one['wall'] / r['wall']:.2f}, {one['fit'] / r['fit']:.2f}"
        lines.append(f"| {r['workers']} | {r['wall']:.2f} | {r['fit']:.2f} | {speed} | {r['rss'] / 2**20:.0f} | "
                     f"{'yes' if r['same'] else 'no'} |")
    lines.append(f"| none (forked processes, {os.cpu_count()} cores) | {row['wall']:.2f} | "
                 f"{row['stages']['fit']:.2f} | | {row['rss'] / 2**20:.0f} | |")
    return "\n".join(lines)


def stream_table(rows: list) -> str:
    head = ("| points in the LAZ file | bays | file MB | generated in s | laspy alone s | canalsurf wall s | ratio "
            "| peak MB | of which reading s | stages s | points reconstructed | tubes found | junctions found "
            "| branches outside their claim | spine mean % r (mean, worst over the tubes found) "
            "| radius err % r (worst) | targets met |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for row in rows:
        start = (f"| {row['points']:,} | {row['size']} | {row['bytes'] / 2**20:.0f} | {row['generate']:.0f} | "
                 f"{row['laspy']:.2f} | {row['wall']:.2f} | {row['ratio']:.2f} | {row['rss'] / 2**20:.0f} |")
        if row["exit"] != 0:
            lines.append(f"{start} failed (exit {row['exit']}): {row['error'].strip()} |")
            continue
        ratio, megabytes = STREAM_TARGETS
        seconds, spine = PLANT_TARGETS
        plant = row["points"] == PLANT_POINTS
        missed = [text for text, miss in (("a branch outside its claim", row["outside"] > 0),
                                          (f"ratio > {ratio:g}", row["ratio"] > ratio),
                                          (f"peak > {megabytes:,} MB", row["rss"] / 2**20 > megabytes),
                                          ("a tube missed", plant and row["found"] < row["tubes"]),
                                          (f"spine mean > {100 * spine:g} % r", plant and row["spine_mean"] > spine),
                                          (f"wall > {seconds:g} s", plant and row["wall"] > seconds)) if miss]
        lines.append(f"{start} {row['read']:.2f} | {sum(row['stages'].values()):.2f} | {row['sampled']:,} | "
                     f"{row['found']} of {row['tubes']} | {row['found_junctions']} (true {row['junctions']}) | "
                     f"{row['outside']} | {100 * row['spine_mean_mean']:.2f}, {100 * row['spine_mean']:.2f} | "
                     f"{100 * row['radius']:.2f} | {'no: ' + ', '.join(missed) if missed else 'yes'} |")
    return "\n".join(lines)


def _helper(task: str, *args) -> dict:
    """Run ``task`` (prepare or score) of this script in a fresh process; its JSON answer."""
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--helper", task, *map(str, args)],
                         check=True, stdout=subprocess.PIPE, text=True)
    return json.loads(out.stdout.splitlines()[-1])


def run_cli(cloud: Path, out: Path, *options: str) -> tuple[float, int, dict, int]:
    """Wall seconds, peak RSS in bytes, the --json summary and the exit code of one reconstruction."""
    exe = Path(sys.executable).with_name("canalsurf")
    start = time.perf_counter()
    proc = subprocess.Popen([str(exe), "--json", "-q", "reconstruct", str(cloud), "-o", str(out), *options],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout = proc.stdout.read()
    stderr = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    summary = json.loads(stdout.decode().splitlines()[-1]) if stdout.strip() else {"error": stderr.decode()}
    return wall, usage.ru_maxrss * 1024, summary, proc.returncode


#: Runs of each process in the start-up comparison (interleaved; the median is kept).
STARTUP_RUNS = 7
#: Target: a 2,000-point reconstruction within this many times a process that only imports numpy and
#: scipy.spatial.
STARTUP_TARGET = 1.5
#: The reference process of that target, and one importing every compiled library a reconstruction
#: needs (scipy.interpolate, for the splines, imports scipy.optimize): what no change to canalsurf can undercut.
STARTUP_BARE = "import numpy, scipy.spatial"
STARTUP_LIBRARIES = "import numpy, scipy.spatial, scipy.interpolate, scipy.sparse.csgraph"


def bench_startup(workdir: Path) -> str:
    """A table row: median wall seconds of the ``STARTUP_BARE`` and ``STARTUP_LIBRARIES`` processes and
    of a 2,000-point ``canalsurf reconstruct``, run one after the other ``STARTUP_RUNS`` times, and
    their ratios to the first."""
    cloud = workdir / "startup.ply"
    _helper("prepare", 2000, cloud, 1)
    bare, libraries, full = [], [], []
    for i in range(STARTUP_RUNS):
        for code, times in ((STARTUP_BARE, bare), (STARTUP_LIBRARIES, libraries)):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], check=True)
            times.append(time.perf_counter() - start)
        full.append(run_cli(cloud, workdir / f"startup-{i}")[0])
    a, b, c = (statistics.median(times) for times in (bare, libraries, full))
    return (f"| `{STARTUP_BARE}` s | `{STARTUP_LIBRARIES}` s; ratio | reconstruct 2,000 points s | ratio | target |\n"
            f"|---|---|---|---|---|\n| {a:.2f} | {b:.2f}; {b / a:.2f} | {c:.2f} | {c / a:.2f} | ≤ {STARTUP_TARGET:g} |")


def verdict(row: dict) -> str:
    """Whether ``row`` meets the targets of its size: "yes", or what missed; "" without targets."""
    if row["points"] not in TARGETS:
        return ""
    ratio, seconds, megabytes = TARGETS[row["points"]]
    missed = []
    if ratio is not None and row["ratio"] > ratio:
        missed.append(f"ratio > {ratio:g}")
    if ratio is None and row["wall"] > seconds:
        missed.append(f"wall > {seconds:g} s")
    if row["rss"] / 2**20 > megabytes:
        missed.append(f"peak > {megabytes:,} MB")
    return "no: " + ", ".join(missed) if missed else "yes"


def bench(n: int, workdir: Path, repeat: int = 1) -> dict:
    """One table row: the fastest of ``repeat`` floors and of ``repeat`` reconstructions.

    Peak memory is the largest of the runs.
    """
    cloud, out = workdir / f"fig9-{n}.ply", workdir / f"out-{n}"
    floor = _helper("prepare", n, cloud, repeat)["floor"]
    runs = [run_cli(cloud, out) for _ in range(repeat)]
    wall, _, summary, code = min(runs, key=lambda r: (r[3] != 0, r[0]))
    rss = max(r[1] for r in runs)
    row = {"points": n, "wall": wall, "floor": floor, "ratio": wall / floor, "rss": rss, "exit": code}
    if code == 0:
        row.update(stages=summary["diagnostics"]["seconds"], **_helper("score", n, out / "model.json"))
    else:
        row["error"] = summary.get("error", "")
    return row


def table(rows: list[dict]) -> str:
    stages = STAGES
    head = ("| points | " + " | ".join(stages) + " | total wall s | floor s | ratio | peak MB "
            "| spine mean / max (% r) | radius err (% r) | targets met |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for row in rows:
        if row["exit"] != 0:
            lines.append(f"| {row['points']:,} | failed (exit {row['exit']}): {row['error'].strip()} |")
            continue
        st = " | ".join(f"{row['stages'].get(s, 0.0):.2f}" for s in stages)
        lines.append(f"| {row['points']:,} | {st} | {row['wall']:.2f} | {row['floor']:.2f} | "
                     f"{row['ratio']:.2f} | {row['rss'] / 2**20:.0f} | {100 * row['spine_mean']:.2f} / "
                     f"{100 * row['spine_max']:.1f} | {100 * row['radius']:.2f} | {verdict(row)} |")
    return "\n".join(lines)


def targets_table() -> str:
    lines = ["| points | total wall / floor | total wall, roughly | peak MB |", "|---|---|---|---|"]
    for n, (ratio, seconds, megabytes) in TARGETS.items():
        wall = f"≤ {seconds:g} s" + (" (start-up and imports included)" if ratio is None else "")
        per_floor = "—" if ratio is None else f"≤ {ratio:g}"
        lines.append(f"| {n:,} | {per_floor} | {wall} | ≤ {megabytes:,} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="also 10 million points")
    parser.add_argument("--sizes", type=int, nargs="*",
                        help="point counts to run instead (none given: no tube rows)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run floor and reconstruction this many times and keep the fastest")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    parser.add_argument("--no-scene", action="store_true", help="leave out the benchmark scene")
    parser.add_argument("--stream", type=int, nargs="+", metavar="N",
                        help="also stream a LAZ file of N points of the scene, one row per N (e.g. 10000000)")
    parser.add_argument("--bays", type=int, default=SCENE_SIZE,
                        help="bays of the streamed plant (23 tubes each; 9 for the plant-scale bar of 207 tubes)")
    parser.add_argument("--dask", type=int, nargs="+", metavar="W", default=(),
                        help="also reconstruct the first streamed file on local Dask clusters of W workers")
    parser.add_argument("--startup", action="store_true",
                        help="also compare a 2,000-point run with a process that only imports numpy and scipy")
    parser.add_argument("--helper", nargs="+", help=argparse.SUPPRESS)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    if args.helper:
        task, *rest = args.helper
        if task == "prepare_scene":
            print(json.dumps(prepare_scene(Path(rest[0]))))
        elif task == "score_scene":
            print(json.dumps(score_scene(Path(rest[0]), *map(int, rest[1:]))))
        elif task == "prepare_stream":
            print(json.dumps(prepare_stream(int(rest[0]), Path(rest[1]), *map(int, rest[2:]))))
        elif task == "dask_cluster":
            dask_cluster(int(rest[0]))
        elif task == "laspy_read":
            print(json.dumps(laspy_read(Path(rest[0]))))
        elif task == "prepare":
            n, path, *more = rest
            print(json.dumps(prepare(int(n), Path(path), *map(int, more))))
        else:
            n, path = rest
            print(json.dumps(score(int(n), Path(path))))
        return 0
    sizes = SIZES + (FULL if args.full else ()) if args.sizes is None else args.sizes
    compileall.compile_dir(importlib.util.find_spec("canalsurf").submodule_search_locations[0], quiet=1)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            rows.append(bench(n, Path(tmp), repeat=max(1, args.repeat)))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
        scene = None if args.no_scene else scene_table(bench_scene(Path(tmp)))
        streamed = [bench_stream(n, Path(tmp), args.bays, args.dask if i == 0 else ())
                    for i, n in enumerate(args.stream or ())]
        stream = stream_table(streamed) if streamed else None
        dask = dask_table(streamed[0]) if args.dask and streamed else None
        startup = bench_startup(Path(tmp)) if args.startup else None
    text = table(rows) if rows else ""
    print(text)
    if scene:
        print(scene)
    if stream:
        print(stream)
    if dask:
        print(dask)
    if startup:
        print(startup)
    if args.markdown:
        args.markdown.write_text(
            "# Performance\n\nMade by `" + " ".join(["python", "benchmarks/bench.py", *argv]) + "` on the development machine "
            f"({os.cpu_count()} cores). Stage columns are the seconds `reconstruct` reports for each "
            "stage; "
            "*total wall* is the whole `canalsurf reconstruct` process (start-up, reading, meshing, "
            "writing); the *floor* is one KD-tree build plus a 16-nearest-neighbour query over all points "
            "on all cores, measured in the same run; *ratio* = total / floor; *peak MB* is the child "
            "process's maximum resident set; canalsurf's modules are compiled to bytecode before the runs, "
            "as `pip install` leaves them. Accuracy is against the ground truth of the sampled Figure 9 "
            "pipe (radius 1).\n\n" + text + "\n\nTargets (*targets met* above): where a ratio is given it "
            "is the target, and the seconds only say roughly what it means; a paper-sized cloud has no "
            "meaningful floor, so there the seconds count.\n\n" + targets_table() + "\n"
            + ("" if scene is None else
               f"\n## A scene of many tubes\n\nThe `{SCENE}` network of `canalsurf.synth` (size "
               f"{SCENE_SIZE}: racks of parallel pipes, runs with elbows, tees, boxes on a floor; 2 % noise, "
               f"20 % of the points on clutter), {SCENE_POINTS:,} points, reconstructed by the same command "
               "with no parameters; accuracy by `canalsurf.metrics.compare_network` against the scene's "
               "ground truth: a tube is *found* when the model branch nearest to it covers 95 % of its "
               "spine within half a radius; spine and radius errors away from junctions, in % of each "
               "branch's radius, worst over the tubes found). *Outside its claim*: written branches whose error "
               "against the truth exceeds what their quality claims (`canalsurf.quality.CLAIMS`, held as in "
               "`benchmarks/trust.py`); there must be none.\n\n" + scene + "\n")
            + ("" if stream is None else
               f"\n## A plant streamed from a file\n\nThe `{SCENE}` network of {args.bays} bays "
               f"({23 * args.bays} tubes) as LAZ files of {' and '.join(f'{n:,}' for n in args.stream)} points "
               f"(LAS 1.4, a {STREAM_SCALE * 1000:g} mm grid; parts of {STREAM_PART:,} points, each a seeded sample of "
               "the plant, written through laspy's chunked writer). *laspy alone* is the time laspy takes to hand "
               f"out every point ({LASPY_CHUNK:,} at a time, its default decoder), measured in the same run; "
               "*canalsurf wall* the whole `canalsurf reconstruct` process, which reads the file in chunks and "
               "reconstructs a seeded sample of `STREAM_POINTS` of its points (*of which reading*: the time it "
               "takes to read the file and keep the sample; *stages*: the pipeline's stages, as in the tables "
               "above); *ratio* = canalsurf / laspy; tubes and junctions found, branches outside their claim and "
               f"the accuracy as in the scene row. Targets: no branch outside its claim, ratio ≤ "
               f"{STREAM_TARGETS[0]:g} and peak ≤ {STREAM_TARGETS[1]:,} MB; for "
               f"{PLANT_POINTS:,} points also every tube found, each tube's spine mean ≤ {100 * PLANT_TARGETS[1]:g} % r "
               f"and wall ≤ {PLANT_TARGETS[0]:g} s (the plant-scale bar: 10⁷ points of 200 tubes and more, "
               "`--stream 10000000 --bays 9`).\n\n" + stream + "\n")
            + ("" if dask is None else
               f"\n## The same file on Dask\n\nThe file of {args.stream[0]:,} points again, with `--dask ADDRESS`: "
               "its branches fitted as Dask tasks on a local cluster (`distributed.LocalCluster`, one thread per "
               "worker process, started before the run and not timed); *fit s* the fit stage; *client peak MB* "
               "the `canalsurf` process alone; the last column compares each `model.json` with the one of the "
               "run without Dask (the row above), byte for byte. The last row is that run.\n\n" + dask + "\n")
            + ("" if startup is None else
               "\n## Start-up\n\nMedian wall seconds of a process that only imports numpy and scipy.spatial, of "
               "one that imports the compiled libraries a reconstruction needs, and of a whole 2,000-point "
               f"`canalsurf reconstruct` (all files written), run in turn {STARTUP_RUNS} times.\n\n"
               + startup + "\n"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
