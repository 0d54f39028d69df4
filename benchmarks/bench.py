"""Speed and memory of the whole ``canalsurf reconstruct`` process against the machine's "floor".

For each size the paper's Figure 9 pipe is sampled (seeded, area-uniform), written as a binary PLY,
and reconstructed by the command line in a child process (file in, model.json + surface.ply out, no
parameters).  The floor -- one KD-tree build plus a 16-nearest-neighbour query over all the points on
all cores -- is measured in the same run, so machine noise cancels in the ratio.  Peak memory is the
child's maximum resident set size (``os.wait4``).  Accuracy is measured against the ground truth.
Each size is checked against its targets (``TARGETS``).

Sampling, the floor and scoring run in helper processes of their own: Linux counts the memory of the
process that starts a child into the child's peak, so the process that starts ``canalsurf`` must
stay small (it does not even import numpy).

Run from the repository root::

    python benchmarks/bench.py                 # 2k, 20k, 200k, 1M points
    python benchmarks/bench.py --full          # ... and 10M
    python benchmarks/bench.py --repeat 3      # fastest of 3 runs (on a busy machine)
    python benchmarks/bench.py --markdown docs/performance.md
    python benchmarks/bench.py --sizes 2000 --no-scene     # one size, no scene row

Besides the single tube, one row reconstructs a scene of many tubes (``SCENE``) of a million points.
"""

from __future__ import annotations

import argparse
import json
import os
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


def _scene():
    import canalsurf

    return canalsurf.make_network(SCENE, n=SCENE_POINTS, size=SCENE_SIZE, rng=0)


def prepare_scene(cloud: Path) -> dict:
    """Write the benchmark scene to ``cloud``; its number of tubes and junctions."""
    from canalsurf.io import write_points

    scene = _scene()
    write_points(cloud, scene.points, None)
    return {"tubes": len(scene.branches), "junctions": len(scene.junctions)}


def score_scene(model_path: Path) -> dict:
    """Branches found and the worst accuracy over the branches of the scene's model."""
    import canalsurf
    from canalsurf.metrics import compare_network

    network, truth = canalsurf.load_model(model_path), _scene()
    c = compare_network(network, truth)
    # A true tube is found when the model branch matched to it follows it (covers 95 % of it); the
    # accuracy columns are over the tubes found (a missed tube's "match" is some other branch).
    found = [b for b in c["branches"] if b["covered"] >= FOUND_COVERED]
    return {"branches": len(network.branches), "found_junctions": len(network.junctions),
            "found": len(found),
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
            "| branches, junctions in the model | spine mean % r (worst tube found) | radius err % r (worst) "
            "| clutter / tube points right |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    if row["exit"] != 0:
        lines.append(f"| {SCENE} | {row['tubes']} | {row['points']:,} | failed (exit {row['exit']}): "
                     f"{row['error'].strip()} |")
        return "\n".join(lines)
    st = " | ".join(f"{row['stages'].get(s, 0.0):.2f}" for s in STAGES)
    lines.append(f"| {SCENE} (size {SCENE_SIZE}) | {row['tubes']} | {row['points']:,} | {st} | {row['wall']:.1f} | "
                 f"{row['rss'] / 2**20:.0f} | {row['found']} of {row['tubes']} | {row['branches']} "
                 f"(true {row['tubes']}), {row['found_junctions']} (true {row['junctions']}) | "
                 f"{100 * row['spine_mean']:.2f} | {100 * row['radius']:.2f} | {row['clutter_right']:.3f} / "
                 f"{row['tube_right']:.3f} |")
    return "\n".join(lines)


def _helper(task: str, *args) -> dict:
    """Run ``task`` (prepare or score) of this script in a fresh process; its JSON answer."""
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--helper", task, *map(str, args)],
                         check=True, stdout=subprocess.PIPE, text=True)
    return json.loads(out.stdout.splitlines()[-1])


def run_cli(cloud: Path, out: Path) -> tuple[float, int, dict, int]:
    """Wall seconds, peak RSS in bytes, the --json summary and the exit code of one reconstruction."""
    exe = Path(sys.executable).with_name("canalsurf")
    start = time.perf_counter()
    proc = subprocess.Popen([str(exe), "--json", "-q", "reconstruct", str(cloud), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    stdout = proc.stdout.read()
    stderr = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    summary = json.loads(stdout.decode().splitlines()[-1]) if stdout.strip() else {"error": stderr.decode()}
    return wall, usage.ru_maxrss * 1024, summary, proc.returncode


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
    parser.add_argument("--sizes", type=int, nargs="*", help="point counts to run instead")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run floor and reconstruction this many times and keep the fastest")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    parser.add_argument("--no-scene", action="store_true", help="leave out the benchmark scene")
    parser.add_argument("--helper", nargs="+", help=argparse.SUPPRESS)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    if args.helper:
        task, *rest = args.helper
        if task == "prepare_scene":
            print(json.dumps(prepare_scene(Path(rest[0]))))
        elif task == "score_scene":
            print(json.dumps(score_scene(Path(rest[0]))))
        elif task == "prepare":
            n, path, *more = rest
            print(json.dumps(prepare(int(n), Path(path), *map(int, more))))
        else:
            n, path = rest
            print(json.dumps(score(int(n), Path(path))))
        return 0
    sizes = args.sizes or (SIZES + (FULL if args.full else ()))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            rows.append(bench(n, Path(tmp), repeat=max(1, args.repeat)))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
        scene = None if args.no_scene else scene_table(bench_scene(Path(tmp)))
    text = table(rows)
    print(text)
    if scene:
        print(scene)
    if args.markdown:
        args.markdown.write_text(
            "# Performance\n\nMade by `" + " ".join(["python", "benchmarks/bench.py", *argv]) + "` on the development machine "
            f"({os.cpu_count()} cores). Stage columns are the seconds `reconstruct` reports for each "
            "stage; "
            "*total wall* is the whole `canalsurf reconstruct` process (start-up, reading, meshing, "
            "writing); the *floor* is one KD-tree build plus a 16-nearest-neighbour query over all points "
            "on all cores, measured in the same run; *ratio* = total / floor; *peak MB* is the child "
            "process's maximum resident set. Accuracy is against the ground truth of the sampled Figure 9 "
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
               "branch's radius, worst over the tubes found).\n\n" + scene + "\n"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
