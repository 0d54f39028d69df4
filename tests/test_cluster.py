"""Dask: the same models and files on a cluster of worker processes as in one process."""

import json
import sys
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed", reason="the 'dask' extra is part of the test extra")

from canalsurf import cli, io, make_network, reconstruct  # noqa: E402
from canalsurf.cluster import connect, map_in_order  # noqa: E402
from canalsurf.cluster import labelled_chunks as cluster_labelled_chunks  # noqa: E402
from canalsurf.errors import InputError  # noqa: E402

SEED = 0


@pytest.fixture(scope="module")
def cluster():
    """A scheduler and two worker processes, as a user's cluster would be: reached by its address."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as c:
        yield c


def _slow_square(x, pause):
    time.sleep(pause * (x % 3))
    return x * x


def test_results_come_in_order_and_a_generator_is_read_only_a_few_ahead(cluster):
    taken = []

    def items():
        for x in range(12):
            taken.append(x)
            yield x

    with distributed.Client(cluster) as client:
        out = map_in_order(client, _slow_square, items(), 0.05)
        assert next(out) == 0
        assert len(taken) < 12  # two workers, a few chunks each ahead: not the whole generator
        assert list(out) == [x * x for x in range(1, 12)]
        assert list(map_in_order(client, _slow_square, list(range(7)), 0.01)) == [x * x for x in range(7)]


def test_a_network_fitted_on_dask_is_the_network_fitted_here(cluster):
    scene = make_network("tree", rng=SEED)
    here = reconstruct(scene.points)
    with connect(cluster.scheduler_address) as client:
        there = reconstruct(scene.points, client=client)
    assert len(here.branches) >= 5
    assert json.dumps(there.to_dict()) == json.dumps(here.to_dict())


def test_the_command_line_writes_the_same_files_on_dask(cluster, tmp_path, capsys, monkeypatch):
    path = tmp_path / "rack.npy"
    np.save(path, make_network("rack", rng=SEED).points)
    # a "large" file: sampled when read, its points labelled again a chunk at a time (on the workers)
    monkeypatch.setattr(cli, "STREAM_POINTS", 20_000)
    monkeypatch.setattr(io, "_STREAM_CHUNK_POINTS", 4000)
    chunks = []

    def spy(client, model, points):
        for chunk in cluster_labelled_chunks(client, model, points):
            chunks.append(len(chunk[0]))
            yield chunk

    monkeypatch.setattr("canalsurf.cluster.labelled_chunks", spy)
    runs = {}
    for name, extra in (("here", []), ("there", ["--dask", cluster.scheduler_address])):
        assert cli.main(["reconstruct", str(path), "-o", str(tmp_path / name), "--labels", "-q", *extra]) == 0
        runs[name] = {f: (tmp_path / name / f).read_bytes() for f in ("model.json", "points.ply", "spine.csv")}
    assert capsys.readouterr().err == ""
    assert runs["there"] == runs["here"]
    assert b"element vertex 30000" in runs["here"]["points.ply"][:200]
    assert chunks == [4000] * 7 + [2000]  # labelled on the workers


def test_without_an_address_a_local_cluster_is_started(tmp_path):
    path = tmp_path / "rack.npy"
    np.save(path, make_network("rack", n=6000, rng=SEED).points)
    for name, extra in (("here", []), ("there", ["--dask"])):
        assert cli.main(["reconstruct", str(path), "-o", str(tmp_path / name), "-q", *extra]) == 0
    assert (tmp_path / "there" / "model.json").read_bytes() == (tmp_path / "here" / "model.json").read_bytes()


def test_a_scheduler_that_cannot_be_reached_fails_with_one_line(tmp_path, capsys, monkeypatch):
    path = tmp_path / "rack.npy"
    np.save(path, make_network("rack", n=3000, rng=SEED).points)
    monkeypatch.setattr("canalsurf.cluster.CONNECT_SECONDS", 1)
    out = tmp_path / "out"
    assert cli.main(["reconstruct", str(path), "-o", str(out), "--dask", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("canalsurf: error: could not reach the Dask scheduler at tcp://127.0.0.1:9 (")
    assert err.endswith("— check that it runs and the address, or leave out the address for a local cluster\n")
    assert err.count("\n") == 1
    assert not out.exists()


def test_without_the_extra_dask_is_refused_with_the_fix(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)
    path = tmp_path / "rack.npy"
    np.save(path, make_network("rack", n=3000, rng=SEED).points)
    assert cli.main(["reconstruct", str(path), "-o", str(tmp_path / "out"), "--dask"]) == 2
    assert capsys.readouterr().err == ("canalsurf: error: Dask needs the 'dask' extra — pip install "
                                       "'canalsurf[dask]'\n")


@pytest.mark.parametrize("workers, address, message", [
    (0, None, r"workers must be a whole number >= 1, got 0"),
    (2.5, None, r"workers must be a whole number >= 1, got 2.5"),
    (2, "tcp://127.0.0.1:9", r"workers is for a local cluster"),
])
def test_bad_connect_arguments_are_refused(workers, address, message):
    with pytest.raises(InputError, match=message):
        with connect(address, workers=workers):
            pass
