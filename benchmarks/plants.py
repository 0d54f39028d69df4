"""Plants of several bays, sampled sparsely or densely: tubes found, and no tube outside its claim.

Each scan is ``canalsurf.make_network("plant", n=POINTS, size=BAYS, rng=SEED)`` (23 tubes per bay),
reconstructed in memory with no parameters.  A true tube is *found* when the model branch matched to it
covers 95 % of it (``canalsurf.metrics.compare_network``, as ``benchmarks/bench.py`` counts it); every
written branch is held to the claim of its quality level (``canalsurf.metrics.model_error`` against
``canalsurf.quality.CLAIMS``, as ``benchmarks/trust.py`` does).

Run from the repository root::

    python benchmarks/plants.py                                   # 2 bays, 400,000 points, seeds 0-11
    python benchmarks/plants.py --bays 9 --points 2000000 --seeds 0  # the streamed 10^7 file's density

With ``--markdown FILE`` the table is appended to FILE (made with a heading if missing): docs/plants.md
holds both runs above.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import canalsurf
from canalsurf.metrics import compare_network, model_error

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench import FOUND_COVERED  # noqa: E402
from trust import outside_claim  # noqa: E402


HEAD = "| bays | points | seed | tubes | found | branches written | outside its claim | spine mean % r, worst tube found | s |"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bays", type=int, default=2)
    parser.add_argument("--points", type=int, default=400_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(12)))
    parser.add_argument("--markdown", type=Path, help="also append the table to this Markdown file")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    lines = [HEAD, "|" + "---|" * (HEAD.count("|") - 1)]
    print("\n".join(lines), flush=True)
    totals = np.zeros(4, int)
    for seed in args.seeds:
        truth = canalsurf.make_network("plant", n=args.points, size=args.bays, rng=seed)
        start = time.perf_counter()
        network = canalsurf.reconstruct(truth.points)
        seconds = time.perf_counter() - start
        found = [b for b in compare_network(network, truth)["branches"] if b["covered"] >= FOUND_COVERED]
        errors = [e for e in model_error(network, truth.branches, truth.junctions) if np.isfinite(e["spine_mean"])]
        outside = sum(outside_claim(e) for e in errors)
        worst = max((b["spine_mean"] for b in found), default=float("nan"))
        row = (len(truth.branches), len(found), len(network.branches), outside)
        totals += row
        lines.append(f"| {args.bays} | {args.points:,} | {seed} | " + " | ".join(map(str, row))
                     + f" | {100 * worst:.2f} | {seconds:.1f} |")
        print(lines[-1], flush=True)
    lines.append(f"| {args.bays} | {args.points:,} | all | " + " | ".join(map(str, totals)) + " | | |")
    print(lines[-1])
    if args.markdown:
        command = " ".join(["python", "benchmarks/plants.py", *argv])
        if not args.markdown.exists():
            args.markdown.write_text(
                "# Plants of several bays\n\nEach table is made by the command above it, which appends it here "
                "(remove this file to make it afresh). "
                + __doc__.split("\n\n")[1].replace("\n", " ") + "\n")
        with args.markdown.open("a") as out:
            out.write(f"\n`{command}`\n\n" + "\n".join(lines) + "\n")
    return 0

if __name__ == "__main__":
    sys.exit(main())
