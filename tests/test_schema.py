"""Tests of src/canalsurf/model.schema.json and docs/model-format.md.

Real reconstructions (an open pipe, an open canal, a closed loop) validate against the schema, broken
documents do not, and the doc's numpy + scipy snippet -- run verbatim, without canalsurf -- reproduces
the samples stored in the file.
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
from canalsurf.model import FORMAT, N_SAMPLES, VERSION

jsonschema = pytest.importorskip("jsonschema")

DOC = Path(__file__).resolve().parents[1] / "docs" / "model-format.md"
#: The surfaces reconstructed, and the kind and closedness their models must have.
CASES = {"fig9-pipe": ("pipe", False), "fig16-canal": ("canal", False), "torus": (None, True)}


def _schema() -> dict:
    text = importlib.resources.files("canalsurf").joinpath("model.schema.json").read_text(encoding="utf-8")
    return json.loads(text)


def _snippet() -> str:
    """The Python block of the doc's section on evaluating a model.json without canalsurf."""
    section = DOC.read_text(encoding="utf-8").split("## Evaluating a model.json without canalsurf", 1)[1]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


@pytest.fixture(scope="module")
def validator():
    return jsonschema.Draft202012Validator(_schema())


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict:
    """name -> path of the model.json written by ``model.save`` for one seeded reconstruction."""
    paths = {}
    for name in CASES:
        model = canalsurf.reconstruct(canalsurf.make_tube(name, rng=1).points)
        path = tmp_path_factory.mktemp(name) / "model.json"
        model.save(path)
        paths[name] = path
    return paths


def _load(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def test_schema_is_valid_draft_2020_12_and_shipped_as_package_data():
    schema = _schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$id"] and schema["title"]
    assert schema["properties"]["format"]["const"] == FORMAT
    assert schema["properties"]["version"]["const"] == VERSION
    assert schema["additionalProperties"] is False


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


@pytest.mark.parametrize("name", list(CASES))
def test_reconstructed_models_validate(name, saved, validator):
    data = _load(saved[name])
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in validator.iter_errors(data)]
    assert not errors, errors
    kind, closed = CASES[name]
    assert data["spine"]["closed"] is closed
    if kind is not None:
        assert data["kind"] == kind
    # What the schema cannot express but the doc promises.
    for spline, coef in ((data["spine"], "control_points"), (data["radius"], "coefficients")):
        if coef not in spline:
            continue
        knots, k = np.array(spline["knots"]), spline["degree"]
        assert len(knots) == len(spline[coef]) + k + 1
        assert np.all(np.diff(knots) >= 0)
        assert (knots[k], knots[-k - 1]) == (0.0, 1.0)
        if closed:  # periodic, written out in full: the last k coefficients repeat the first k
            np.testing.assert_array_equal(np.array(spline[coef])[-k:], np.array(spline[coef])[:k])
    samples = data["samples"]
    assert len(samples["t"]) == len(samples["points"]) == len(samples["radius"]) == N_SAMPLES
    assert samples["t"][0] == 0.0 and samples["t"][-1] == 1.0 and np.all(np.diff(samples["t"]) > 0)


def _drop_spine(d):
    del d["spine"]


def _version_2(d):
    d["version"] = 2


def _kind_tube(d):
    d["kind"] = "tube"


def _ten_samples(d):
    d["samples"] = {key: val[:10] for key, val in d["samples"].items()}


def _null_radius(d):
    """What a NaN radius becomes in JSON (a non-finite value written as null)."""
    if "constant" in d["radius"]:
        d["radius"]["constant"] = None
    else:
        d["radius"]["coefficients"][0] = None


def _null_sample_radius(d):
    d["samples"]["radius"][7] = None


def _extra_top_level_key(d):
    d["comment"] = "not part of version 1"


def _two_d_control_point(d):
    d["spine"]["control_points"][0] = d["spine"]["control_points"][0][:2]


def _wrong_radius_form(d):
    d["radius"] = ({"degree": 3, "knots": [0, 0, 0, 0, 1, 1, 1, 1], "coefficients": [1, 1, 1, 1]}
                   if d["kind"] == "pipe" else {"constant": 1.0})


def _zero_constant_radius(d):
    d["kind"], d["radius"] = "pipe", {"constant": 0.0}


def _string_degree(d):
    d["spine"]["degree"] = "3"


MUTATIONS = [_drop_spine, _version_2, _kind_tube, _ten_samples, _null_radius, _null_sample_radius,
             _extra_top_level_key, _two_d_control_point, _wrong_radius_form, _zero_constant_radius,
             _string_degree]


@pytest.mark.parametrize("name", ["fig9-pipe", "fig16-canal"])
@pytest.mark.parametrize("mutate", MUTATIONS, ids=lambda f: f.__name__.lstrip("_"))
def test_broken_documents_are_rejected(mutate, name, saved, validator):
    data = _load(saved[name])
    assert validator.is_valid(data)
    broken = copy.deepcopy(data)
    mutate(broken)
    assert not validator.is_valid(broken)


def test_parameters_and_diagnostics_allow_other_keys_and_nulls(saved, validator):
    data = _load(saved["fig9-pipe"])
    data["parameters"]["future_option"] = None
    data["diagnostics"]["not_a_number"] = None
    data["diagnostics"]["angular_coverage"] = None
    assert validator.is_valid(data)
    data["diagnostics"]["angular_coverage"] = "all around"
    assert not validator.is_valid(data)


@pytest.mark.parametrize("name", list(CASES))
def test_doc_snippet_reproduces_the_samples_without_canalsurf(name, saved, monkeypatch, capsys):
    """The doc's snippet, run as written in the model.json's folder, evaluates spine and radius."""
    monkeypatch.chdir(saved[name].parent)
    namespace: dict = {"__name__": "model_format_snippet"}
    exec(compile(_snippet(), str(DOC), "exec"), namespace)  # noqa: S102 -- our own documentation
    capsys.readouterr()
    spine, radius, model = namespace["spine"], namespace["radius"], namespace["model"]
    assert not any(mod.startswith("canalsurf") for mod in _snippet_imports())
    samples = model["samples"]
    t = np.array(samples["t"])
    np.testing.assert_allclose(spine(t), np.array(samples["points"]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(radius(t), np.array(samples["radius"]), rtol=0, atol=1e-9)
    assert np.shape(radius(t)) == t.shape and spine(t).shape == t.shape + (3,)
    if model["spine"]["closed"]:
        np.testing.assert_allclose(spine(1.0), spine(0.0), rtol=0, atol=1e-9)
        np.testing.assert_allclose(radius(1.0), radius(0.0), rtol=0, atol=1e-9)


def _snippet_imports() -> list[str]:
    return re.findall(r"^\s*(?:import|from)\s+([\w.]+)", _snippet(), re.M)
