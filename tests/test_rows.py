"""Tests of canalsurf._rows: work split over threads gives what one thread gives, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from canalsurf import _rows, synth
from canalsurf.normals import estimate_normals
from canalsurf.radius import principal_curvature

SEED = 5


@pytest.fixture
def threads(monkeypatch):
    """Split work that small into ``parts`` threads: ``threads(parts)``."""
    def split(parts: int) -> None:
        monkeypatch.setattr(_rows, "cores", lambda: parts)
        monkeypatch.setattr(_rows, "MIN_ROWS", 100)
        monkeypatch.setattr(_rows, "MIN_SLAB_POINTS", 100)
    return split


@pytest.mark.parametrize("parts", [2, 3, 7])
def test_every_pair_within_reach_lies_in_one_slab(threads, parts):
    """Clustered points (some on the cuts' coordinates exactly): each pair at most ``reach`` apart shares
    a slab, and every point is in one."""
    threads(parts)
    rng = np.random.default_rng(SEED)
    points = np.vstack([rng.normal(size=(1500, 3)), rng.normal(scale=0.05, size=(500, 3)) + [2.0, 0, 0]])
    points[::50, 0] = np.round(points[::50, 0], 1)
    reach = 0.1
    found = _rows.slabs(points, reach)
    assert len(found) == parts
    member = np.zeros((len(points), parts), bool)
    for s, rows in enumerate(found):
        member[rows, s] = True
    assert member.any(axis=1).all()
    pairs = cKDTree(points).query_pairs(reach, output_type="ndarray")
    assert len(pairs) > 1000  # the case is not trivial
    assert (member[pairs[:, 0]] & member[pairs[:, 1]]).any(axis=1).all()


def test_a_process_among_processes_works_on_one_thread(threads, monkeypatch):
    threads(4)
    monkeypatch.setattr(_rows, "_most_threads", 0)  # restored after the test
    seen = []

    def rows(r):
        seen.append((r.start, r.stop))
        return np.arange(r.start, r.stop)

    np.testing.assert_array_equal(_rows.by_rows(rows, 1000), np.arange(1000))
    assert sorted(seen) == [(0, 250), (250, 500), (500, 750), (750, 1000)]
    assert (_rows.workers(1000), _rows.workers(250), _rows.workers(199)) == (4, 2, 1)
    _rows.one_thread()
    seen.clear()
    np.testing.assert_array_equal(_rows.by_rows(rows, 1000), np.arange(1000))
    assert seen == [(0, 1000)]
    assert len(_rows.slabs(np.random.default_rng(SEED).normal(size=(1000, 3)), 0.1)) == 1
    assert _rows.workers(10**9) == 1


def test_one_slab_below_its_least_size():
    points = np.random.default_rng(SEED).normal(size=(_rows.MIN_SLAB_POINTS * 2 - 1, 3))
    assert [len(rows) for rows in _rows.slabs(points, 0.1)] == [len(points)]


def test_normals_and_curvature_are_the_same_in_threads(threads):
    """Each point's normal and curvature depend on its neighbourhood alone: split over threads, they are
    the same to the last bit."""
    tube = synth.make_tube("elbow", n=3000, rng=SEED)
    normals = estimate_normals(tube.points)
    kappa = principal_curvature(tube.points, normals)
    threads(3)
    np.testing.assert_array_equal(estimate_normals(tube.points), normals)
    np.testing.assert_array_equal(principal_curvature(tube.points, normals), kappa)


@pytest.mark.parametrize("name", ["fig9-pipe", "fig14-canal"])
def test_footpoints_are_the_same_in_threads(threads, monkeypatch, name):
    """Each point's footpoint search depends on that point alone: split over threads, the parameters and
    distances are the same to the last bit, searched afresh or followed from a start."""
    from canalsurf import refine

    tube = synth.make_tube(name, n=3000, rng=SEED)
    t, d = refine.footpoints(tube.points, tube.spine, tube.radius, closed=False)
    again = refine.footpoints(tube.points, tube.spine, tube.radius, closed=False, start=np.clip(t + 1e-3, 0, 1))
    threads(3)
    monkeypatch.setattr(refine, "FOOTPOINT_ROWS", 100)
    for want, got in zip((t, d, *again), (*refine.footpoints(tube.points, tube.spine, tube.radius, closed=False),
                                          *refine.footpoints(tube.points, tube.spine, tube.radius, closed=False,
                                                             start=np.clip(t + 1e-3, 0, 1)))):
        np.testing.assert_array_equal(got, want)
