"""Work split over the cores in threads: numpy's loops and scipy's KD-trees release the GIL."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: Rows per thread at least: on fewer, starting the threads costs more than they save.
MIN_ROWS = 50_000
#: Points per slab at least (:func:`slabs`): a KD-tree's build and search gain from threads sooner.
MIN_SLAB_POINTS = 10_000
#: Threads at most (0: one per core; see :func:`one_thread`).
_most_threads = 0


def cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1


def one_thread() -> None:
    """Do this process's work on one thread: it is one of several processes that fill the cores."""
    global _most_threads
    _most_threads = 1


def workers(n: int, least: int | None = None) -> int:
    """Threads for work on ``n`` rows, ``least`` (default MIN_ROWS) each at least, and no more than the
    process may use (see :func:`one_thread`): also scipy's ``workers`` for a KD-tree query of ``n`` points."""
    return max(1, min(_most_threads or cores(), n // (least or MIN_ROWS)))


def in_threads(func, parts: list) -> list:
    """``[func(part) for part in parts]``, one thread per part."""
    if len(parts) < 2:
        return [func(part) for part in parts]
    with ThreadPoolExecutor(len(parts)) as pool:
        return list(pool.map(func, parts))


def by_rows(func, n: int, least: int | None = None) -> np.ndarray:
    """``func(rows)`` over consecutive slices ``rows`` of ``range(n)``, at least ``least`` rows each
    (default MIN_ROWS), in threads, joined in order.

    ``func`` must give each row a result that depends on that row alone (its first axis): the result
    is then the same, bit for bit, however the rows are split.
    """
    cuts = np.linspace(0, n, workers(n, least) + 1).astype(int)
    return np.concatenate(in_threads(func, [slice(a, b) for a, b in zip(cuts[:-1], cuts[1:])]))


def slabs(points: np.ndarray, reach: float) -> list:
    """Indices of the points in overlapping slabs across their widest axis, one per core (of at least
    MIN_SLAB_POINTS points): any two points at most ``reach`` apart both lie in one slab.

    A slab runs from its cut to the next cut plus ``reach``: the nearer point of two in different
    slabs, taken along the axis, lies in the other's.
    """
    parts = workers(len(points), MIN_SLAB_POINTS)
    if parts == 1:
        return [np.arange(len(points))]
    x = points[:, int(np.argmax(np.ptp(points, axis=0)))]
    cuts = np.r_[-np.inf, np.quantile(x, np.arange(1, parts) / parts), np.inf]
    return [np.flatnonzero((x >= lo) & (x < hi + reach)) for lo, hi in zip(cuts[:-1], cuts[1:])]
