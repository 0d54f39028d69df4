"""Accuracy on networks of tubes: every network of ``canalsurf.synth.NETWORKS`` over several seeds.

Each cloud (30,000 points, 2 % noise) is reconstructed with no parameters and estimated normals, and
compared with its ground truth by :func:`canalsurf.metrics.compare_network`.  Per network the table
gives how many runs found the true branches and junctions, and the worst figure over its runs and
branches: spine and radius errors away from junctions (in percent of each branch's radius), the
share of each true spine covered, the junction distance (in shares of half the largest radius there)
and the share of clutter and tube points labelled right.

Run from the repository root::

    python benchmarks/networks.py                  # 5 seeds
    python benchmarks/networks.py --markdown docs/networks.md
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import canalsurf
from canalsurf.metrics import compare_network
from canalsurf.synth import NETWORKS, make_network

#: The networks of the table (``plant`` is the benchmark scene of docs/performance.md).
NAMES = tuple(name for name in NETWORKS if name != "plant")
HEAD = ("| network | runs | refused | right branches, junctions | spine mean % r (worst) "
        "| radius mean err % r (worst) | covered (least) | junction distance / half radius (worst) "
        "| clutter right (least) | tube points right (least) | s per run |")


def run(name: str, seeds: range, n: int, noise: float) -> str:
    """One table row: ``name`` reconstructed once per seed."""
    refused, right, spine, radius, covered, junction, clutter, tube, seconds = 0, 0, [], [], [], [], [], [], []
    for seed in seeds:
        truth = make_network(name, n=n, noise=noise, rng=seed)
        start = time.perf_counter()
        try:
            network = canalsurf.reconstruct(truth.points)
        except canalsurf.ReconstructionError:
            refused += 1
            continue
        seconds.append(time.perf_counter() - start)
        c = compare_network(network, truth)
        right += (len(network.branches) == len(truth.branches) and len(network.junctions) == len(truth.junctions)
                  and c["one_to_one"] and all(j["same_branches"] for j in c["junctions"]))
        spine.append(max(b["spine_mean"] for b in c["branches"]))
        radius.append(max(b["radius_mean"] for b in c["branches"]))
        covered.append(min(b["covered"] for b in c["branches"]))
        junction.extend(j["distance"] / (0.5 * j["largest_radius"]) for j in c["junctions"])
        clutter.append(c["clutter_right"])
        tube.append(c["tube_right"])
    if not seconds:
        return f"| {name} | {len(seeds)} | {refused} | – | – | – | – | – | – | – | – |"
    worst_junction = f"{max(junction):.2f}" if junction else "–"
    return (f"| {name} | {len(seeds)} | {refused} | {right}/{len(seconds)} | {100 * max(spine):.2f} | "
            f"{100 * max(radius):.2f} | {min(covered):.3f} | {worst_junction} | {min(clutter):.3f} | "
            f"{min(tube):.3f} | {np.mean(seconds):.1f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds per network (default 5)")
    parser.add_argument("--n", type=int, default=30_000, help="points per cloud (default 30000)")
    parser.add_argument("--noise", type=float, default=0.02, help="relative noise (default 0.02)")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    lines = [HEAD, "|" + "---|" * (HEAD.count("|") - 1)]
    print("\n".join(lines), flush=True)
    for name in NAMES:
        lines.append(run(name, range(200, 200 + args.seeds), args.n, args.noise))
        print(lines[-1], flush=True)
    if args.markdown:
        command = " ".join(["python", "benchmarks/networks.py", *argv])
        args.markdown.write_text(
            "# Accuracy on networks of tubes\n\nMade by `" + command + "`: every network of "
            "`canalsurf.synth.NETWORKS` but the benchmark plant (see docs/performance.md), "
            f"{args.n:,} points with {100 * args.noise:g} % noise, reconstructed with no parameters and "
            f"estimated normals, seeds 200 to {199 + args.seeds}. Each true branch is matched to the "
            "model branch nearest to it; figures are the worst over runs and branches. Spine: mean "
            "closest-point distance between true and reconstructed spine away from junctions (beyond 2.5 "
            "of the branch's radii), in percent of the branch's mean radius; radius: mean absolute "
            "radius error there; covered: share of the whole true spine within half a radius of the "
            "model; junction distance in shares of half the largest radius meeting there (the bar is "
            "1); labels from `Network.classify` on the input points. The test suite "
            "(`tests/test_pipeline_networks.py`) holds every network to the bar on its own seeds.\n\n"
            + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
