"""How steady a reconstruction of a real scan is: the same scan, its points shuffled and moved by a
millimetre, reconstructed again and again.

A scan has no truth to score against, but a model a user can trust does not come and go with the
order of the points, with noise far below the scan's own or with the frame it is given in: each run
turns the scan by ``--turn`` degrees about the vertical (z) axis through its centre, shuffles the
points and adds seeded Gaussian noise of ``--jitter`` (in the file's units; default 1 mm for a scan in
metres) to every coordinate, then runs :func:`canalsurf.reconstruct` with no parameters.  A run that is refused
(:class:`canalsurf.errors.CanalsurfError`) counts as such; any other exception is a bug and is listed
with its type.  Per run: the share of the points on no tube, the branches (pipes, canals) and the
longest branch.

Run from the repository root on a file of your own, e.g.::

    python benchmarks/steadiness.py scan.xyz                 # 6 runs
    python benchmarks/steadiness.py scan.xyz --runs 10 --jitter 0.002
    python benchmarks/steadiness.py scan.xyz --runs 1 --jitter 0 --turn 10   # the frame alone
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import canalsurf
from canalsurf.errors import CanalsurfError
from canalsurf.spine import curve_length


def run(points: np.ndarray, seed: int, jitter: float) -> str:
    """One run's table row: ``points`` shuffled and moved by ``jitter`` (seeded), reconstructed."""
    rng = np.random.default_rng(seed)
    moved = points[rng.permutation(len(points))] + rng.normal(0.0, jitter, points.shape)
    start = time.perf_counter()
    try:
        net = canalsurf.reconstruct(moved)
    except CanalsurfError as exc:
        return f"| {seed} | refused: {exc} | | | | {time.perf_counter() - start:.1f} |"
    except Exception as exc:  # noqa: BLE001 -- a bug, listed as one
        return f"| {seed} | **{type(exc).__name__}**: {exc} | | | | {time.perf_counter() - start:.1f} |"
    seconds = time.perf_counter() - start
    on_none = float(np.mean(net.classify(moved)[0] < 0))
    kinds = [b.kind for b in net.branches]
    longest = max(net.branches, key=lambda b: curve_length(b.spine))
    return (f"| {seed} | {100 * on_none:.1f} | {len(kinds)} ({kinds.count('pipe')} pipes, {kinds.count('canal')} "
            f"canals) | {curve_length(longest.spine):.3g} | {longest.kind}, {longest.diagnostics['n_points']} points, "
            f"r {longest.mean_radius:.3g} | {seconds:.1f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("file", help="a point cloud canalsurf reads")
    parser.add_argument("--runs", type=int, default=6, help="runs, seeds 0 to RUNS - 1 (default 6)")
    parser.add_argument("--jitter", type=float, default=0.001,
                        help="standard deviation of the noise added to each coordinate (default 0.001)")
    parser.add_argument("--turn", type=float, default=0.0,
                        help="degrees the scan is turned about the vertical axis first (default 0)")
    args = parser.parse_args()
    points, _ = canalsurf.read_points(args.file)
    if args.turn:  # else the points as read, to the bit
        a = np.radians(args.turn)
        turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        centre = points.mean(axis=0)
        points = (points - centre) @ turn.T + centre
    print(f"{args.file}: {len(points):,} points, turned by {args.turn:g} degrees about z; each run shuffled and "
          f"moved by N(0, {args.jitter:g}) per coordinate\n")
    print("| seed | % of the points on no tube | branches | longest spine | longest branch | s |")
    print("|---|---|---|---|---|---|")
    for seed in range(args.runs):
        print(run(points, seed, args.jitter), flush=True)


if __name__ == "__main__":
    main()
