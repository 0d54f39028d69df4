"""Trust: every model written is within what its own quality claims, or the scan is refused.

Random scans of every family of ``canalsurf.synth.CASE_FAMILIES`` (named surfaces seen all round or
from one side, short obliquely cut and flared segments, flared trunks on the ground, thin poles
scanned once from one side with 1 cm quantisation, networks with clutter, a bay of the plant) are
reconstructed with no parameters.  Each written branch is compared with the truth
(``canalsurf.metrics.model_error``) and held to the claim of its quality level
(``canalsurf.quality.CLAIMS``).  A branch outside its claim is a *silently wrong* model: the table
must show none.

Run from the repository root::

    python benchmarks/trust.py                       # 100 cases per family
    python benchmarks/trust.py --markdown docs/trust.md
    python benchmarks/trust.py --family pole --first 1000   # other seeds of one family
    python benchmarks/trust.py --family pole --turn 30      # registered into another frame

``--turn`` turns every scan and its truth about the vertical axis first: a scan registered or levelled
into another frame after its coordinates were rounded, whose grid then lies along no axis of the file.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.interpolate import BSpline
from scipy.spatial.transform import Rotation

import canalsurf
from canalsurf.metrics import model_error
from canalsurf.quality import CLAIMS
from canalsurf.synth import CASE_FAMILIES, SyntheticNetwork, random_case

#: Scans per family at most (a bay of the plant, 23 tubes, takes seconds; the other families a fraction).
MAX_CASES = {"plant": 25}
HEAD = ("| family | scans | refused | branches written | pipes fitted as canals | good / check / poor "
        "| outside its claim "
        "| spine mean % r (median, worst good) | radius error % (median, worst good) | s per scan |")


def outside_claim(error: dict) -> bool:
    """Whether one branch's error exceeds what its quality claims."""
    claim = CLAIMS[error["quality"]]
    return bool(error["spine_mean"] > claim["spine"] or error["radius_mean"] > claim["radius"])


def turned(case, degrees: float):
    """A random case, its points and its truth (spines, junctions), turned about the vertical axis."""
    if not degrees:
        return case
    turn = Rotation.from_euler("z", degrees, degrees=True).as_matrix().T

    def spine(s: BSpline) -> BSpline:  # a spline turns with its control points
        return BSpline(s.t, s.c @ turn, s.k)

    moved = {"points": case.points @ turn, "normals": case.normals @ turn}
    if isinstance(case, SyntheticNetwork):
        branches = tuple(replace(b, spine=spine(b.spine)) for b in case.branches)
        return replace(case, branches=branches, junctions=case.junctions @ turn, **moved)
    return replace(case, spine=spine(case.spine), **moved)


def check(family: str, seed: int, turn: float = 0.0) -> tuple[str | None, list, float]:
    """Reconstruct one random case, turned by ``turn`` degrees: (refusal message or None, per-branch
    errors, seconds)."""
    case = turned(random_case(family, seed), turn)
    start = time.perf_counter()
    try:
        network = canalsurf.reconstruct(case.points)
    except canalsurf.ReconstructionError as exc:
        return str(exc), [], time.perf_counter() - start
    seconds = time.perf_counter() - start
    if isinstance(case, SyntheticNetwork):
        errors = model_error(network, case.branches, case.junctions)
    else:
        errors = model_error(network, [case])
    return None, [e for e in errors if np.isfinite(e["spine_mean"])], seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", type=int, default=100, help="random scans per family (default 100)")
    parser.add_argument("--first", type=int, default=0, help="seed of the first scan (default 0)")
    parser.add_argument("--family", action="append", choices=CASE_FAMILIES,
                        help="only this family (repeatable; default every family)")
    parser.add_argument("--turn", type=float, default=0.0, metavar="DEG",
                        help="turn every scan and its truth by DEG degrees about the vertical first")
    parser.add_argument("--markdown", type=Path, help="also write the table into this Markdown file")
    args = parser.parse_args(argv)
    lines = [HEAD, "|" + "---|" * (HEAD.count("|") - 1)]
    print("\n".join(lines), flush=True)
    wrong_total, examples = 0, []
    for family in args.family or CASE_FAMILIES:
        refused, errors, seconds = 0, [], []
        cases = min(args.cases, MAX_CASES.get(family, args.cases))
        for seed in range(args.first, args.first + cases):
            why, found, s = check(family, seed, args.turn)
            refused += why is not None
            seconds.append(s)
            for e in found:
                errors.append(e)
                if outside_claim(e):
                    examples.append(f"{family} seed {seed}: branch {e['id']} {e['quality']}, spine "
                                    f"{100 * e['spine_mean']:.1f} % r, radius {100 * e['radius_mean']:.1f} %")
                    print("outside its claim:", examples[-1], file=sys.stderr, flush=True)
        wrong = sum(outside_claim(e) for e in errors)
        wrong_total += wrong
        levels = [sum(e["quality"] == q for e in errors) for q in CLAIMS]
        good = [e for e in errors if e["quality"] == "good"]
        spine = 100 * np.array([e["spine_mean"] for e in errors]) if errors else np.array([np.nan])
        radius = 100 * np.array([e["radius_mean"] for e in errors]) if errors else np.array([np.nan])
        worst_good = (max(100 * e["spine_mean"] for e in good), max(100 * e["radius_mean"] for e in good)) \
            if good else (np.nan, np.nan)
        as_canal = sum(e["kind"] == "canal" and e["true_kind"] == "pipe" for e in errors)
        lines.append(f"| {family} | {cases} | {refused} | {len(errors)} | {as_canal} | "
                     f"{' / '.join(map(str, levels))} | "
                     f"{wrong} | {np.median(spine):.2f}, {worst_good[0]:.2f} | {np.median(radius):.2f}, "
                     f"{worst_good[1]:.2f} | {np.mean(seconds):.2f} |")
        print(lines[-1], flush=True)
    claims = ", ".join(f"`{q}` spine ≤ {100 * c['spine']:.0f} % r and radius ≤ {100 * c['radius']:.0f} %"
                       for q, c in CLAIMS.items())
    if args.markdown:
        command = shlex.join(["python", "benchmarks/trust.py", *(sys.argv[1:] if argv is None else argv)])
        args.markdown.write_text(
            "# Trust: models within their stated quality\n\nMade by `" + command + f"`: {args.cases} random "
            f"scans of each family of `canalsurf.synth.random_case` (seeds {args.first} to "
            f"{args.first + args.cases - 1}; at most {MAX_CASES['plant']} of the plant, whose scans take seconds "
            "each), reconstructed with no parameters. Every written branch is compared with "
            "the truth away from junctions (`canalsurf.metrics.model_error`: the mean distance of its spine "
            "from the true spine in true radii, and its mean radius error) and held to what its quality "
            f"claims (`canalsurf.quality.CLAIMS`: {claims}). *Outside its claim* counts silently wrong "
            "models; *refused* counts scans that ended in a one-line `ReconstructionError`; *pipes fitted as "
            "canals* counts the written branches fitted with a radius function along a true tube of constant "
            "radius (a canal fitted as a pipe shows in the radius error).\n\n"
            + "\n".join(lines) + "\n" + ("\nOutside their claim:\n\n" + "\n".join(f"- {e}" for e in examples)
                                         + "\n" if examples else ""))
    return 1 if wrong_total else 0


if __name__ == "__main__":
    raise SystemExit(main())
