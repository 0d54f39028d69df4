"""Bundles of touching pipes: tubes found, and no tube outside its claim.

Each scan is a ``bundle`` network of ``canalsurf.synth`` drawn from its seed: 2 to 5 straight pipes of
random radii 0.3 - 2, side by side and touching, 15,000 - 40,000 points, noise 0.5 - 3 % of the radius.
Where pipes touch, their surfaces meet in a crease and a thin pipe lies in the wider ones' shadow: the
hardest scene of parallel tubes.  Each is reconstructed in memory with no parameters.  A true tube is
*found* when the model branch matched to it covers 95 % of it (``canalsurf.metrics.compare_network``, as
``benchmarks/bench.py`` counts it); a bundle has no junctions, so every junction written is false; every
written branch is held to the claim of its quality level (``canalsurf.metrics.model_error`` against
``canalsurf.quality.CLAIMS``, as ``benchmarks/trust.py`` does); *refused* counts scans that ended in a
one-line ``ReconstructionError``.

Run from the repository root::

    python benchmarks/bundles.py                                  # seeds 0-199
    python benchmarks/bundles.py --markdown docs/bundles.md
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np

import canalsurf
from canalsurf.metrics import compare_network, model_error

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench import FOUND_COVERED  # noqa: E402
from trust import outside_claim  # noqa: E402

HEAD = ("| pipes | scans | refused | tubes | found | branches written | junctions written | outside its claim "
        "| spine mean % r (median, worst tube found) |")


def bundle(seed: int):
    """The random bundle of ``seed`` (see the module's docstring), with its truth."""
    rng = np.random.default_rng(seed)
    radii = tuple(rng.uniform(0.3, 2.0, int(rng.integers(2, 6))))
    return canalsurf.make_network("bundle", n=int(rng.integers(15_000, 40_001)), noise=rng.uniform(0.005, 0.03),
                                  rng=rng, radii=radii, gap=0.0)


def check(seed: int) -> dict:
    """Reconstruct one bundle: its tubes, those found, the branches and junctions written (a bundle has
    none: pipes that touch do not meet), those outside their claim, the tubes missing (seed, radius,
    share covered), the spine errors of those found, and seconds."""
    truth = bundle(seed)
    start = time.perf_counter()
    try:
        network = canalsurf.reconstruct(truth.points)
    except canalsurf.ReconstructionError:
        return {"tubes": len(truth.branches), "refused": 1, "found": 0, "written": 0, "junctions": 0,
                "outside": 0, "missing": [], "spine": [], "s": time.perf_counter() - start}
    seconds = time.perf_counter() - start
    compared = compare_network(network, truth)["branches"]
    found = [b for b in compared if b["covered"] >= FOUND_COVERED]
    errors = [e for e in model_error(network, truth.branches, truth.junctions) if np.isfinite(e["spine_mean"])]
    missing = [(seed, b["radius"], b["covered"]) for b in compared if b["covered"] < FOUND_COVERED]
    return {"tubes": len(truth.branches), "refused": 0, "found": len(found),
            "written": len(network.branches), "junctions": len(network.junctions),
            "outside": sum(outside_claim(e) for e in errors),
            "missing": missing, "spine": [b["spine_mean"] for b in found], "s": seconds}


def row(label, results: list) -> str:
    spine = 100 * np.array([s for r in results for s in r["spine"]] or [np.nan])
    counts = [sum(r[key] for r in results) for key in ("refused", "tubes", "found", "written", "junctions", "outside")]
    return (f"| {label} | {len(results)} | " + " | ".join(map(str, counts))
            + f" | {np.median(spine):.2f}, {spine.max():.2f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=200, help="bundles (default 200)")
    parser.add_argument("--first", type=int, default=0, help="seed of the first bundle (default 0)")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    args = parser.parse_args(argv)
    results = []
    for seed in range(args.first, args.first + args.cases):
        results.append(check(seed))
        r = results[-1]
        print(f"seed {seed}: {r['found']} of {r['tubes']} found, {r['junctions']} junctions, "
              f"{r['outside']} outside its claim, "
              f"{r['s']:.1f} s", file=sys.stderr, flush=True)
    lines = [HEAD, "|" + "---|" * (HEAD.count("|") - 1)]
    lines += [row(k, [r for r in results if r["tubes"] == k]) for k in sorted({r["tubes"] for r in results})]
    lines.append(row("all", results))
    missing = [f"- seed {s}: a pipe of radius {r:.2f}, {100 * c:.0f} % of it covered"
               for r_ in results for s, r, c in r_["missing"]]
    table = "\n".join(lines) + "\n" + ("\nTubes not found:\n\n" + "\n".join(missing) + "\n" if missing else "")
    print(table)
    if args.markdown:
        command = shlex.join(["python", "benchmarks/bundles.py", *(sys.argv[1:] if argv is None else argv)])
        args.markdown.write_text("# Bundles of touching pipes\n\nMade by `" + command + "` (seeds "
                                 f"{args.first} to {args.first + args.cases - 1}). "
                                 + " ".join(__doc__.split("\n\n")[1].split()) + "\n\n" + table)
    return 1 if sum(r["outside"] for r in results) else 0


if __name__ == "__main__":
    raise SystemExit(main())
