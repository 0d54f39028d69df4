"""Dask: a reconstruction's independent pieces of work as tasks on a cluster's workers.

:func:`connect` opens a client -- of a local cluster of worker processes, or of a running
``distributed`` scheduler -- and :func:`canalsurf.reconstruct` given that client (``client=``) fits
its branches there, one task per branch; :func:`labelled_chunks` labels a file's points there a
chunk at a time.  Each task depends on its own inputs alone, so the results are those of the single-process run,
bit for bit.

Needs the ``dask`` extra (``pip install 'canalsurf[dask]'``), and on a remote cluster canalsurf
installed on every worker.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager

from .errors import InputError

__all__ = ["connect", "labelled_chunks", "map_in_order"]

#: Seconds to wait for a scheduler given by its address before giving up.
CONNECT_SECONDS = 20
#: Chunks :func:`map_in_order` sends ahead of the one it waits for, per worker: enough to keep every
#: worker busy, few enough that the chunks held (each a few MB) stay a bounded memory.
AHEAD_PER_WORKER = 2


def _distributed():
    try:
        import distributed
    except ImportError:
        raise InputError("Dask needs the 'dask' extra — pip install 'canalsurf[dask]'") from None
    return distributed


@contextmanager
def connect(address: str | None = None, *, workers: int | None = None) -> Iterator:
    """A ``distributed.Client`` for the duration of the ``with`` block.

    Parameters
    ----------
    address : str, optional
        A running scheduler's address (``tcp://host:8786``).  Default: a local cluster of worker
        processes, one thread each, started here and shut down at the end of the block.
    workers : int, optional
        Worker processes of the local cluster (default: one per core this process may use).  Not
        with ``address``: a remote cluster has the workers it was started with.

    Raises
    ------
    InputError
        The ``dask`` extra is missing, ``workers`` is not a whole number >= 1 or is given with an
        address, or the scheduler cannot be reached.

    Examples
    --------
    >>> import canalsurf
    >>> from canalsurf.cluster import connect
    >>> tube = canalsurf.make_tube("fig9-pipe", rng=1)
    >>> with connect(workers=2) as client:  # doctest: +SKIP
    ...     model = canalsurf.reconstruct(tube.points, client=client)
    """
    distributed = _distributed()
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError(f"workers must be a whole number >= 1, got {workers!r}")
    if address is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
        # Any free port: a second cluster would find the usual one taken.
        with distributed.LocalCluster(n_workers=workers or cores, threads_per_worker=1, processes=True,
                                      dashboard_address=":0") as cluster, distributed.Client(cluster) as client:
            yield client
        return
    if workers is not None:
        raise InputError("workers is for a local cluster: a scheduler at an address has the workers it was "
                         "started with")
    try:
        client = distributed.Client(address, timeout=CONNECT_SECONDS)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"could not reach the Dask scheduler at {address} ({exc}) — check that it runs "
                         "and the address, or leave out the address for a local cluster") from None
    with client:
        yield client


def map_in_order(client, func: Callable, items: Iterable, shared=None) -> Iterator:
    """``func(item, shared)`` of every item, as tasks on ``client``'s workers, yielded in item order.

    ``shared`` is sent to every worker once, not with every task.  The items of a list are sent all at
    once (no worker waits while a long task holds up the order); those of any other iterable only as
    tasks finish, a few per worker ahead, so a generator of chunks is never held whole.
    """
    distributed = _distributed()
    if shared is not None:
        [shared] = client.scatter([shared], broadcast=True, hash=False)
    ahead = (len(items) if isinstance(items, list) else
             AHEAD_PER_WORKER * max(1, len(client.scheduler_info().get("workers", {}))))
    pending: deque = deque()
    try:
        for item in items:
            pending.append(client.submit(func, item, shared, pure=False))
            if len(pending) > ahead:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for future in pending:  # an error, or the caller stopped early: drop the rest
            future.cancel()
        if isinstance(shared, distributed.Future):
            shared.release()


def _classify(points, model):
    return model.classify(points)


def labelled_chunks(client, model, chunks: Iterable) -> Iterator:
    """``(points, label, distance)`` of every chunk of points, labelled by ``model.classify`` as tasks
    on ``client``'s workers, in chunk order; a few chunks per worker are held at a time."""
    held: deque = deque()

    def feed():
        for points in chunks:
            held.append(points)
            yield points

    for label, distance in map_in_order(client, _classify, feed(), model):
        yield held.popleft(), label, distance
