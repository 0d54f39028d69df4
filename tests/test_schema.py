"""Tests of src/canalsurf/model.schema.json and docs/model-format.md.

Real reconstructions -- an open pipe, an open canal, a closed loop (networks of one branch) and a T
junction (three branches, one junction) -- validate against the schema and keep the promises it cannot
express; broken documents do not validate; and the doc's numpy + scipy snippet -- run verbatim, without
canalsurf -- reproduces every branch's samples stored in the file.
"""

from __future__ import annotations

import copy
import importlib.resources
import json
import re
from pathlib import Path

import numpy as np
import pytest

import canalsurf
from canalsurf.model import FORMAT, CanalModel
from canalsurf.network import NETWORK_VERSION, Network, n_branch_samples
from canalsurf.spine import constant_spline
from canalsurf.synth import SURFACES, make_network

jsonschema = pytest.importorskip("jsonschema")

DOC = Path(__file__).resolve().parents[1] / "docs" / "model-format.md"
#: The surfaces reconstructed: (kind, closed) of their single branch, or None for the network.
CASES = {"fig9-pipe": ("pipe", False), "fig16-canal": ("canal", False), "torus": (None, True),
         "t-junction": None}
SINGLE = [name for name, case in CASES.items() if case is not None]
#: The T junction's ground truth: a straight pipe with a side branch from its middle.
T_BRANCHES, T_JUNCTIONS = 3, 1


def _schema() -> dict:
    text = importlib.resources.files("canalsurf").joinpath("model.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


def _snippet() -> str:
    """The Python block of the doc's section on evaluating a model.json without canalsurf."""
    section = DOC.read_text(encoding="utf-8").split("## Evaluating a model.json without canalsurf", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def _cloud(name: str) -> np.ndarray:
    if name == "t-junction":
        return make_network("t-junction", n=12000, rng=1).points
    return canalsurf.make_tube(name, rng=1).points


@pytest.fixture(scope="module")
def validator():
    return jsonschema.Draft202012Validator(_schema())


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict:
    """name -> path of the model.json written by ``Network.save`` for one seeded reconstruction."""
    paths = {}
    for name in CASES:
        network = canalsurf.reconstruct(_cloud(name))
        path = tmp_path_factory.mktemp(name) / "model.json"
        network.save(path)
        paths[name] = path
    return paths


def _load(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def _errors(validator, data) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(data)]


def test_schema_is_valid_draft_2020_12_and_shipped_as_package_data():
    schema = _schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] == "urn:canalsurf:model:2" and schema["title"]
    assert schema["properties"]["format"]["const"] == FORMAT
    assert schema["properties"]["version"]["const"] == NETWORK_VERSION
    assert schema["additionalProperties"] is False
    for name in ("spine", "radius", "samples", "branch", "junction"):
        assert name in schema["$defs"], name
    for name in ("spine", "samples", "branch", "junction"):
        assert schema["$defs"][name]["additionalProperties"] is False, name


def test_every_property_is_described():
    def walk(node, where):
        if isinstance(node, dict):
            for name, sub in node.get("properties", {}).items():
                assert sub.get("description"), f"{where}.{name} has no description"
            for key, sub in node.items():
                if key not in ("if", "then", "else"):  # conditions restate declared properties
                    walk(sub, f"{where}.{key}")
        elif isinstance(node, list):
            for i, sub in enumerate(node):
                walk(sub, f"{where}[{i}]")

    walk(_schema(), "schema")


def _check_what_the_schema_cannot(data: dict) -> None:
    """The promises the schema states in words: knot counts, ids, cross-references, components."""
    branches, junctions = data["branches"], data["junctions"]
    assert [b["id"] for b in branches] == list(range(len(branches)))
    assert [j["id"] for j in junctions] == list(range(len(junctions)))
    for b in branches:
        closed = b["closed"]
        for spline, coef in ((b["spine"], "control_points"), (b["radius"], "coefficients")):
            if coef not in spline:
                continue
            knots, k = np.array(spline["knots"]), spline["degree"]
            assert len(knots) == len(spline[coef]) + k + 1
            assert np.all(np.diff(knots) >= 0)
            assert (knots[k], knots[-k - 1]) == (0.0, 1.0)
            if closed:  # periodic, written out in full: the last k coefficients repeat the first k
                np.testing.assert_array_equal(np.array(spline[coef])[-k:], np.array(spline[coef])[:k])
        samples = b["samples"]
        assert len(samples["t"]) == len(samples["points"]) == len(samples["radius"]) >= 50
        assert samples["t"][0] == 0.0 and samples["t"][-1] == 1.0 and np.all(np.diff(samples["t"]) > 0)
        # No coarser than half the branch's mean radius (measured along the sampled polyline).
        step = np.linalg.norm(np.diff(np.array(samples["points"]), axis=0), axis=1)
        assert step.max() <= 0.5 * np.mean(samples["radius"]) * 1.01
    # Junction ends and branch ends name each other.
    listed = {(e["branch"], e["end"]): j["id"] for j in junctions for e in j["ends"]}
    named = {(b["id"], e): jid for b in branches for e, jid in enumerate(b["ends"]) if jid is not None}
    assert listed == named
    assert sum(len(j["ends"]) for j in junctions) == len(listed)  # no end listed twice
    # Components partition the branch ids into the networks joined through junctions.
    components = data["components"]
    assert sorted(i for c in components for i in c) == list(range(len(branches)))
    assert all(c == sorted(c) for c in components) and components == sorted(components)
    component_of = {i: n for n, c in enumerate(components) for i in c}
    for j in junctions:
        assert len({component_of[e["branch"]] for e in j["ends"]}) == 1
    assert data["diagnostics"]["n_branches"] == len(branches)
    assert data["diagnostics"]["n_junctions"] == len(junctions)
    assert data["diagnostics"]["n_components"] == len(components)


@pytest.mark.parametrize("name", list(CASES))
def test_reconstructed_models_validate(name, saved, validator):
    data = _load(saved[name])
    errors = _errors(validator, data)
    assert not errors, errors
    _check_what_the_schema_cannot(data)
    if name in SINGLE:
        kind, closed = CASES[name]
        (branch,) = data["branches"]
        assert (data["junctions"], data["components"], branch["ends"]) == ([], [[0]], [None, None])
        assert branch["closed"] is closed and branch["spine"]["closed"] is closed
        if kind is not None:
            assert branch["kind"] == kind
    else:
        assert (len(data["branches"]), len(data["junctions"])) == (T_BRANCHES, T_JUNCTIONS)
        assert data["components"] == [[0, 1, 2]]
        assert len(data["junctions"][0]["ends"]) == 3
        assert all(b["closed"] is False and b["ends"].count(0) == 1 for b in data["branches"])


def test_sample_count_follows_the_branch_size():
    """At least 50 samples, more when the branch is long for its radius (a thin helix)."""
    spine, _, closed, _, _ = SURFACES["helix"]
    thin = CanalModel("pipe", spine(), constant_spline(0.2), closed)
    data = Network([thin]).to_dict()
    n = len(data["branches"][0]["samples"]["t"])
    assert n == n_branch_samples(thin) > 50
    assert jsonschema.Draft202012Validator(_schema()).is_valid(data)


# --- broken documents ---------------------------------------------------------------------------------
# Each mutation breaks branch 0 (or the document) in one way the schema must catch.

def _drop_spine(d):
    del d["branches"][0]["spine"]


def _version_3(d):
    d["version"] = 3


def _version_1(d):
    """A version 2 body labelled version 1."""
    d["version"] = 1


def _kind_tube(d):
    d["branches"][0]["kind"] = "tube"


def _too_few_samples(d):
    d["branches"][0]["samples"] = {key: val[:49] for key, val in d["branches"][0]["samples"].items()}


def _null_radius(d):
    """What a NaN radius becomes in JSON (a non-finite value written as null)."""
    radius = d["branches"][0]["radius"]
    if "constant" in radius:
        radius["constant"] = None
    else:
        radius["coefficients"][0] = None


def _null_sample_radius(d):
    d["branches"][0]["samples"]["radius"][7] = None


def _extra_top_level_key(d):
    d["comment"] = "not part of version 2"


def _extra_branch_key(d):
    d["branches"][0]["colour"] = "red"


def _no_branches(d):
    d["branches"] = []


def _no_components(d):
    del d["components"]


def _two_d_control_point(d):
    d["branches"][0]["spine"]["control_points"][0] = d["branches"][0]["spine"]["control_points"][0][:2]


def _wrong_radius_form(d):
    branch = d["branches"][0]
    branch["radius"] = ({"degree": 3, "knots": [0, 0, 0, 0, 1, 1, 1, 1], "coefficients": [1, 1, 1, 1]}
                        if branch["kind"] == "pipe" else {"constant": 1.0})


def _zero_constant_radius(d):
    d["branches"][0]["kind"], d["branches"][0]["radius"] = "pipe", {"constant": 0.0}


def _string_degree(d):
    d["branches"][0]["spine"]["degree"] = "3"


def _closed_disagrees_with_spine(d):
    d["branches"][0]["closed"] = not d["branches"][0]["spine"]["closed"]


def _three_ends(d):
    d["branches"][0]["ends"] = [None, None, None]


def _string_end(d):
    d["branches"][0]["ends"][0] = "0"


BRANCH_MUTATIONS = [_drop_spine, _version_3, _version_1, _kind_tube, _too_few_samples, _null_radius,
                    _null_sample_radius, _extra_top_level_key, _extra_branch_key, _no_branches,
                    _no_components, _two_d_control_point, _wrong_radius_form, _zero_constant_radius,
                    _string_degree, _closed_disagrees_with_spine, _three_ends, _string_end]


def _two_coordinate_junction(d):
    d["junctions"][0]["point"] = d["junctions"][0]["point"][:2]


def _end_2(d):
    d["junctions"][0]["ends"][0]["end"] = 2


def _boolean_end(d):
    d["junctions"][0]["ends"][0]["end"] = True


def _one_end_at_a_junction(d):
    d["junctions"][0]["ends"] = d["junctions"][0]["ends"][:1]


def _junction_without_point(d):
    del d["junctions"][0]["point"]


def _loop_with_a_junction(d):
    branch = d["branches"][0]
    branch["closed"] = branch["spine"]["closed"] = True


JUNCTION_MUTATIONS = [_two_coordinate_junction, _end_2, _boolean_end, _one_end_at_a_junction,
                      _junction_without_point, _loop_with_a_junction]


def _rejected(mutate, data, validator):
    assert validator.is_valid(data)
    broken = copy.deepcopy(data)
    mutate(broken)
    assert json.dumps(broken) != json.dumps(data)  # (True == 1 in Python, not in JSON)
    assert not validator.is_valid(broken)


@pytest.mark.parametrize("name", ["fig9-pipe", "fig16-canal", "t-junction"])
@pytest.mark.parametrize("mutate", BRANCH_MUTATIONS, ids=lambda f: f.__name__.lstrip("_"))
def test_broken_documents_are_rejected(mutate, name, saved, validator):
    _rejected(mutate, _load(saved[name]), validator)


@pytest.mark.parametrize("mutate", JUNCTION_MUTATIONS, ids=lambda f: f.__name__.lstrip("_"))
def test_broken_junctions_are_rejected(mutate, saved, validator):
    _rejected(mutate, _load(saved["t-junction"]), validator)


def test_parameters_and_diagnostics_allow_other_keys_and_nulls(saved, validator):
    data = _load(saved["t-junction"])
    data["parameters"]["future_option"] = None
    data["diagnostics"]["not_a_number"] = None
    data["diagnostics"]["angular_coverage"] = None
    data["branches"][1]["diagnostics"]["not_a_number"] = None
    data["branches"][1]["diagnostics"]["inlier_rms_residual"] = None
    assert validator.is_valid(data)
    for where in (lambda d: d["diagnostics"], lambda d: d["branches"][1]["diagnostics"]):
        broken = copy.deepcopy(data)
        where(broken)["angular_coverage"] = "all around"
        assert not validator.is_valid(broken)


# --- the doc's snippet --------------------------------------------------------------------------------

def _run_snippet(folder: Path, monkeypatch, capsys) -> dict:
    """The doc's snippet, run as written in ``folder`` (which holds a model.json); its namespace."""
    monkeypatch.chdir(folder)
    namespace: dict = {"__name__": "model_format_snippet"}
    exec(compile(_snippet(), str(DOC), "exec"), namespace)  # noqa: S102 -- our own documentation
    capsys.readouterr()
    return namespace


def _snippet_imports() -> list[str]:
    return re.findall(r"^\s*(?:import|from)\s+([\w.]+)", _snippet(), re.M)


@pytest.mark.parametrize("name", list(CASES))
def test_doc_snippet_reproduces_the_samples_without_canalsurf(name, saved, monkeypatch, capsys):
    """The doc's snippet, run as written in the model.json's folder, evaluates every branch."""
    namespace = _run_snippet(saved[name].parent, monkeypatch, capsys)
    tubes, model = namespace["tubes"], namespace["model"]
    assert not any(mod.startswith("canalsurf") for mod in _snippet_imports())
    assert len(tubes) == len(model["branches"])
    for (spine, radius), branch in zip(tubes, model["branches"]):
        samples = branch["samples"]
        t = np.array(samples["t"])
        np.testing.assert_allclose(spine(t), np.array(samples["points"]), rtol=0, atol=1e-9)
        np.testing.assert_allclose(radius(t), np.array(samples["radius"]), rtol=0, atol=1e-9)
        assert np.shape(radius(t)) == t.shape and spine(t).shape == t.shape + (3,)
        if branch["closed"]:
            np.testing.assert_allclose(spine(1.0), spine(0.0), rtol=0, atol=1e-9)
            np.testing.assert_allclose(radius(1.0), radius(0.0), rtol=0, atol=1e-9)


def test_doc_snippet_reads_a_version_1_file(tmp_path, monkeypatch, capsys):
    """A version 1 file (one tube, written before networks) is read by the snippet as one branch."""
    spine, radius, closed, _, _ = SURFACES["fig16-canal"]
    model = CanalModel("canal", spine(), radius(), closed)
    v1 = model.to_dict()
    assert v1["version"] == 1
    (tmp_path / "model.json").write_text(json.dumps(v1), encoding="utf-8")
    namespace = _run_snippet(tmp_path, monkeypatch, capsys)
    (tube,) = namespace["tubes"]
    t = np.array(v1["samples"]["t"])
    np.testing.assert_allclose(tube[0](t), np.array(v1["samples"]["points"]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(tube[1](t), np.array(v1["samples"]["radius"]), rtol=0, atol=1e-9)
