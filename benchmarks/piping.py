"""Piping: how close the pieces of a reconstructed plant-like network come to the true pieces.

The ``piping`` network of ``canalsurf.synth`` (millimetres: NPS 4 and NPS 2 runs, a long-radius
90-degree, a 3R 45-degree and an NPS 2 long-radius elbow, a reducing tee, a 4 x 2 reducer; true pieces
by ``canalsurf.synth.piping_truth``) is scanned with 40,000 points at two noise levels, reconstructed
with no parameters and decomposed by ``canalsurf.piping.decompose`` with the scan's points (as
``canalsurf reconstruct --piping`` does).  Every true piece is matched with the found piece of its type
nearest to it; the table gives, per noise level over the seeds, the worst error of each measure in per
cent of the piece's radius (angles in degrees) and how many runs found every piece with its type and
catalogue size.

Run from the repository root::

    python benchmarks/piping.py                          # seeds 1 - 10
    python benchmarks/piping.py --markdown docs/piping.md
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import canalsurf
from canalsurf import synth
from canalsurf.piping import decompose

COMMAND = "python benchmarks/piping.py --markdown docs/piping.md"
POINTS = 40_000
NOISES = (0.005, 0.01)
MEASURES = ("fitting ends", "straight lengths", "elbow bend radii", "elbow arc lengths", "elbow angles (deg)",
            "reducer ends", "reducer lengths")


def _middle(piece) -> np.ndarray:
    return (np.asarray(piece.start) + np.asarray(piece.end)) / 2


def _ends(t, p) -> tuple:
    """The found piece's ends in the order of the true piece's (a run may come out reversed)."""
    same = np.linalg.norm(p.start - t.start) + np.linalg.norm(p.end - t.end)
    swapped = np.linalg.norm(p.start - t.end) + np.linalg.norm(p.end - t.start)
    return (p.start, p.end) if same <= swapped else (p.end, p.start)


def errors(pieces, truth, free: np.ndarray) -> tuple[dict, bool]:
    """Worst error per measure (per cent of the radius, degrees for angles) of one decomposition, and
    whether every true piece was found once with its type and size."""
    out = {m: 0.0 for m in MEASURES}
    found = len(pieces) == len(truth)
    used = set()
    for t in truth:
        candidates = [p for p in pieces if p.type == t.type and p.id not in used]
        if not candidates:
            found = False
            continue
        p = min(candidates, key=lambda p: np.linalg.norm(_middle(p) - _middle(t)))
        used.add(p.id)
        r = t.outside_diameter / 2
        # the catalogue sizes at the true piece's start and end (a run may come out reversed)
        sizes = (p.catalogue_diameter, p.end_catalogue_diameter or p.catalogue_diameter)
        if _ends(t, p)[0] is p.end:
            sizes = sizes[::-1]
        found &= bool(np.allclose(sizes, (t.outside_diameter, t.end_diameter)))

        def worst(measure, value):
            out[measure] = max(out[measure], abs(float(value)))

        if t.type == "tee":
            worst("fitting ends", 100 * np.linalg.norm(p.start - t.start) / r)
            continue
        ends = _ends(t, p)
        if t.type == "reducer":
            for a, b in zip(ends, (t.start, t.end)):
                worst("reducer ends", 100 * np.linalg.norm(a - b) / r)
            worst("reducer lengths", 100 * (p.length - t.length) / r)
            continue
        cut = [np.linalg.norm(free - e, axis=1).min() < 1e-6 for e in (t.start, t.end)]
        for a, b, at_free in zip(ends, (t.start, t.end), cut):
            if not at_free:
                worst("fitting ends", 100 * np.linalg.norm(a - b) / r)
        if t.type == "elbow":
            worst("elbow bend radii", 100 * (p.bend_radius - t.bend_radius) / r)
            worst("elbow arc lengths", 100 * (p.length - t.length) / r)
            worst("elbow angles (deg)", p.angle - t.angle)
        elif not any(cut):
            worst("straight lengths", 100 * (p.length - t.length) / r)
    return out, found


def run(seeds, noise: float) -> dict:
    truth = synth.piping_truth()
    layout = synth.NETWORKS["piping"][0]()
    free = np.array([b.spine(float(e)) for b in layout.branches for e in (0, 1) if b.ends[e] is None])
    worst = {m: 0.0 for m in MEASURES}
    complete, seconds = 0, 0.0
    for seed in seeds:
        cloud = synth.make_network("piping", n=POINTS, noise=noise, rng=seed)
        start = time.perf_counter()
        network = canalsurf.reconstruct(cloud.points)
        pieces = decompose(network, cloud.points, units="mm")
        seconds += time.perf_counter() - start
        errs, found = errors(pieces, truth, free)
        complete += found
        for m in MEASURES:
            worst[m] = max(worst[m], errs[m])
        print(f"  noise {noise:g} seed {seed}: " + ", ".join(f"{m} {v:.2f}" for m, v in errs.items())
              + ("" if found else "  (pieces missing or wrong)"), file=sys.stderr)
    return {"worst": worst, "complete": complete, "runs": len(seeds), "seconds": seconds / len(seeds)}


def table(results: dict) -> str:
    head = "| noise % r | runs | every piece found, right size | " + " | ".join(MEASURES) + " | s per run |"
    rows = [head, "|" + "---|" * (len(MEASURES) + 4)]
    for noise, res in results.items():
        rows.append(f"| {100 * noise:g} | {res['runs']} | {res['complete']} | "
                    + " | ".join(f"{res['worst'][m]:.2f}" for m in MEASURES) + f" | {res['seconds']:.1f} |")
    return "\n".join(rows)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=10, help="seeds 1 .. N per noise level (default 10)")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    args = parser.parse_args()
    results = {noise: run(range(1, args.seeds + 1), noise) for noise in NOISES}
    text = table(results)
    print(text)
    if args.markdown:
        args.markdown.write_text(
            "# Piping pieces against the truth\n\n"
            f"Made by `{COMMAND}`.\n\n"
            f"The `piping` network of `canalsurf synth`, {POINTS:,} points, noise as a share of each tube's "
            "radius, seeds 1 to "
            f"{args.seeds}; reconstructed with no parameters and decomposed with the scan's points "
            "(`canalsurf reconstruct --piping`). Worst error over the seeds, in % of the piece's radius "
            "(angles in degrees): the ends of pieces at fittings (elbow tangent points, the tee's junction), "
            "straights between two fittings, elbows, the reducer (where its cone meets each size).\n\n"
            + text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
