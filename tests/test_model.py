"""Tests of canalsurf.model: model.json round trips exactly, and every bad file fails with one clean line."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
from scipy.interpolate import BSpline, make_interp_spline

from canalsurf import synth
from canalsurf.errors import InputError
from canalsurf.model import FORMAT, N_SAMPLES, VERSION, CanalModel, load_model, model_from_dict
from canalsurf.network import NETWORK_VERSION, Junction, Network
from canalsurf.spine import constant_spline, curve_length

FINE = np.linspace(0.0, 1.0, 1001)


def _pipe() -> CanalModel:
    spine_f, radius_f, closed, _, _ = synth.SURFACES["fig9-pipe"]
    return CanalModel("pipe", spine_f(), radius_f(), closed,
                      parameters={"R": 0.2, "delta": np.float64(0.05), "mu": 0.7, "k": np.int64(16)},
                      diagnostics={"iterations": np.int64(5), "stop_rule": "mu", "seconds": {"shrink": 0.1},
                                   "not_a_number": float("nan"), "history": np.array([0, 63, 672])})


def _canal_closed() -> CanalModel:
    spine_f, _, closed, _, _ = synth.SURFACES["torus"]
    u = np.linspace(0.0, 1.0, 41)
    r = 1.0 + 0.3 * np.sin(2 * np.pi * u)
    r[-1] = r[0]
    return CanalModel("canal", spine_f(), make_interp_spline(u, r, k=3, bc_type="periodic"), closed)


def _y_vessel() -> Network:
    """The y-vessel's true branches (tapering canals) and junction as a network."""
    truth = synth.make_network("y-vessel", n=1000, rng=1)
    branches = [CanalModel("canal", b.spine, b.radius, False, diagnostics={"n_points": 7}, id=i, ends=b.ends)
                for i, b in enumerate(truth.branches)]
    ends = [(i, e) for i, b in enumerate(truth.branches) for e in (0, 1) if b.ends[e] == 0]
    return Network(branches, [Junction(0, truth.junctions[0], ends)], parameters={"R": 0.2},
                   diagnostics={"n_branches": 3, "no_tube_share": np.float64(0.0)})


def _as_network(make) -> Network:
    """A network of one branch holding ``make()``, with its parameters and diagnostics; or a network."""
    made = make()
    if isinstance(made, Network):
        return made
    return Network([made], [], dict(made.parameters), dict(made.diagnostics))


def _assert_same_spline(a: BSpline, b: BSpline):
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.c, b.c)
    assert a.k == b.k
    np.testing.assert_array_equal(a(FINE), b(FINE))


@pytest.mark.parametrize("make", [_pipe, _canal_closed, _y_vessel])
def test_save_load_round_trip_is_exact(make, tmp_path):
    network = _as_network(make)
    path = tmp_path / "model.json"
    network.save(path)
    assert json.loads(path.read_text(encoding="utf-8"))["version"] == NETWORK_VERSION
    back = load_model(path)
    assert isinstance(back, Network)
    assert len(back.branches) == len(network.branches)
    for b, original in zip(back.branches, network.branches):
        assert (b.id, b.kind, b.closed, b.ends) == (original.id, original.kind, original.closed,
                                                    tuple(original.ends))
        _assert_same_spline(b.spine, original.spine)
        if b.kind == "pipe":  # written as {"constant": r}
            assert b.radius.c[0] == original.radius.c[0]
            np.testing.assert_array_equal(b.radius(FINE), original.radius(FINE))
        else:
            _assert_same_spline(b.radius, original.radius)
    assert len(back.junctions) == len(network.junctions)
    for j, original in zip(back.junctions, network.junctions):
        assert j.id == original.id and j.ends == [tuple(e) for e in original.ends]
        np.testing.assert_array_equal(j.point, original.point)
    assert back.components == network.components
    if len(network.branches) == 1:  # a network of one branch answers as its branch does
        model = network.branches[0]
        assert (back.kind, back.closed) == (model.kind, model.closed)
        np.testing.assert_array_equal(back.sample()[0], model.sample()[0])
        assert back.mean_radius == model.mean_radius
    # Saving the loaded network gives the same file.
    back.save(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_text(encoding="utf-8") == path.read_text(encoding="utf-8")


def test_closed_spine_is_written_as_a_plain_periodic_bspline(tmp_path):
    """Any B-spline evaluator must reproduce the loop from the file alone: C(0) = C(1)."""
    model = _canal_closed()
    model.save(tmp_path / "model.json")
    data = json.loads((tmp_path / "model.json").read_text(encoding="utf-8"))
    sp = data["spine"]
    spline = BSpline(np.array(sp["knots"]), np.array(sp["control_points"]), sp["degree"])
    np.testing.assert_allclose(spline(0.0), spline(1.0), atol=1e-12)
    assert sp["closed"] is True
    assert data["radius"]["degree"] == 3


def test_parameters_and_diagnostics_become_plain_json(tmp_path):
    model = _pipe()
    model.save(tmp_path / "model.json")
    text = (tmp_path / "model.json").read_text(encoding="utf-8")
    assert "NaN" not in text
    data = json.loads(text)
    assert data["format"] == FORMAT and data["version"] == VERSION
    assert data["radius"] == {"constant": 1.0}
    assert data["parameters"] == {"R": 0.2, "delta": 0.05, "mu": 0.7, "k": 16}
    assert data["diagnostics"]["not_a_number"] is None
    assert data["diagnostics"]["history"] == [0, 63, 672]
    assert load_model(tmp_path / "model.json").parameters["k"] == 16


@pytest.mark.parametrize("make", [_pipe, _canal_closed])
def test_samples_are_many_and_even_in_arc_length(make):
    model = make()
    samples = model.to_dict()["samples"]
    t = np.array(samples["t"])
    points = np.array(samples["points"])
    assert len(t) == N_SAMPLES >= 200
    assert t[0] == 0.0 and t[-1] == 1.0 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(points, model.spine(t), atol=1e-12)
    np.testing.assert_allclose(samples["radius"], model.radius(t), atol=1e-12)
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    expected = curve_length(model.spine) / (len(t) - 1)
    assert np.abs(step / expected - 1.0).max() <= 5e-3


def test_sample_and_mean_radius():
    model = _canal_closed()
    pts, r = model.sample(500)
    assert pts.shape == (500, 3) and r.shape == (500,)
    np.testing.assert_allclose(np.linalg.norm(pts[:, :2], axis=1), 4.0, atol=1e-3)  # the torus' spine circle
    assert model.mean_radius == pytest.approx(1.0, abs=1e-3)  # mean of 1 + 0.3 sin over a period


# --- bad files ---------------------------------------------------------------------------------------

def _write(tmp_path, content) -> str:
    path = tmp_path / "model.json"
    path.write_text(content if isinstance(content, str) else json.dumps(content), encoding="utf-8")
    return str(path)


def _raises_one_line(path, pattern):
    with pytest.raises(InputError, match=pattern) as info:
        load_model(path)
    assert "\n" not in str(info.value)


def test_other_version_is_refused(tmp_path):
    data = _as_network(_pipe).to_dict()
    data["version"] = 3
    path = _write(tmp_path, data)
    # The versions named in the parenthesis are left open: the message should name both 1 and 2.
    _raises_one_line(path, r"^.*model\.json: model version 3 is not supported \(this canalsurf reads "
                           r"versions? [^)]*\) — re-run the reconstruction$")


@pytest.mark.parametrize("make", [_pipe, _canal_closed])
def test_version_1_file_loads_as_one_branch(make, tmp_path):
    model = make()
    data = model.to_dict()
    assert data["version"] == VERSION == 1
    back = load_model(_write(tmp_path, data))
    assert isinstance(back, Network)
    (branch,) = back.branches
    assert (branch.id, branch.ends, back.junctions, back.components) == (0, (None, None), [], [[0]])
    assert (back.kind, back.closed) == (model.kind, model.closed)
    _assert_same_spline(back.spine, model.spine)
    np.testing.assert_array_equal(back.radius(FINE), model.radius(FINE))
    assert back.parameters == data["parameters"]


def test_corrupted_json_is_refused(tmp_path):
    text = json.dumps(_pipe().to_dict(), indent=1)
    path = _write(tmp_path, text[: len(text) // 2])
    _raises_one_line(path, r"^.*model\.json: not valid JSON \(.* at line \d+\) — the file is corrupted; "
                           r"re-run the reconstruction$")


@pytest.mark.parametrize("content", [{"format": "something.else", "version": 1}, [1, 2, 3], {"version": 1}])
def test_wrong_format_is_refused(tmp_path, content):
    path = _write(tmp_path, content)
    _raises_one_line(path, r'^.*model\.json: not a canalsurf model \(no "format": "canalsurf\.model"\) — '
                           r"give a model\.json written by canalsurf$")


@pytest.mark.parametrize("damage", ["no-spine", "bad-kind", "short-knots", "2d-spine", "nan-radius"])
def test_corrupted_content_is_refused(tmp_path, damage):
    data = _pipe().to_dict()
    if damage == "no-spine":
        del data["spine"]
    elif damage == "bad-kind":
        data["kind"] = "cone"
    elif damage == "short-knots":
        data["spine"]["knots"] = data["spine"]["knots"][:3]
    elif damage == "2d-spine":
        data["spine"]["control_points"] = [p[:2] for p in data["spine"]["control_points"]]
    else:
        data["radius"] = {"degree": 3, "knots": [0, 0, 0, 0, 1, 1, 1, 1], "coefficients": [1, 1, None, 1]}
    path = _write(tmp_path, data)
    _raises_one_line(path, r"^.*model\.json: corrupted model \(.+\) — re-run the reconstruction$")


def test_missing_file_is_refused(tmp_path):
    _raises_one_line(tmp_path / "nope.json", r"^.*nope\.json: no such file — check the path$")


@pytest.mark.parametrize("case", ["folder", "random bytes", "socket"])
def test_unreadable_file_is_refused(tmp_path, monkeypatch, case):
    monkeypatch.chdir(tmp_path)  # a short relative name: socket paths are limited to about 100 bytes
    path = tmp_path / "model.json"
    if case == "folder":
        path.mkdir()
        reason = "Is a directory"
    elif case == "random bytes":
        path.write_bytes(np.random.default_rng(0).bytes(4096))
        reason = "UnicodeDecodeError"
    else:
        if not hasattr(socket, "AF_UNIX"):
            pytest.skip("no Unix sockets here")
        with socket.socket(socket.AF_UNIX) as sock:
            sock.bind("model.json")
        reason = ".+"  # the system's word for it: ENXIO on Linux
    _raises_one_line(path, rf"^.*model\.json: cannot read the model \({reason}\) — give a model\.json file$")


def test_model_from_dict_names_its_source():
    with pytest.raises(InputError, match=r"^scan-17: not a canalsurf model"):
        model_from_dict({"format": "x"}, "scan-17")


def test_constant_radius_is_a_pipe_radius():
    model = CanalModel("pipe", synth.SURFACES["helix"][0](), constant_spline(0.5), False)
    data = model.to_dict()
    assert data["radius"] == {"constant": 0.5}
    assert model_from_dict(data).radius(0.3) == pytest.approx(0.5)
