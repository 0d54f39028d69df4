"""Tests of canalsurf._validate: every boundary check and its exact message."""

from __future__ import annotations

import math

import numpy as np
import pytest

from canalsurf._validate import MIN_POINTS, as_normals, as_points, choice, in_range, positive
from canalsurf.errors import CanalsurfError, InputError


@pytest.fixture
def cloud(rng):
    return rng.normal(size=(MIN_POINTS + 10, 3))


def test_good_points_come_back_as_float64(cloud):
    ints = np.round(cloud * 100).astype(np.int32)
    out = as_points(ints)
    assert out.dtype == np.float64 and out.shape == ints.shape
    np.testing.assert_array_equal(out, ints)
    assert as_points(cloud.tolist()).shape == cloud.shape


def test_input_error_is_a_value_error():
    assert issubclass(InputError, ValueError) and issubclass(InputError, CanalsurfError)


@pytest.mark.parametrize("bad, got", [(np.zeros((60, 2)), r"\(60, 2\)"), (np.zeros(180), r"\(180,\)"),
                                      (np.zeros((60, 3, 1)), r"\(60, 3, 1\)"), (np.zeros((60, 4)), r"\(60, 4\)")])
def test_wrong_shape(bad, got):
    with pytest.raises(InputError, match=rf"^points must have shape \(N, 3\), got {got}$"):
        as_points(bad)


def test_wrong_shape_names_the_parameter():
    with pytest.raises(InputError, match=r"^scan must have shape \(N, 3\), got \(60, 2\)$"):
        as_points(np.zeros((60, 2)), name="scan")


def test_too_few_points():
    with pytest.raises(InputError, match=rf"^points holds 49 points; at least {MIN_POINTS} are needed — "
                                         r"give a denser scan$"):
        as_points(np.zeros((MIN_POINTS - 1, 3)))
    assert as_points(np.zeros((5, 3)), min_points=5).shape == (5, 3)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_nan_and_inf(cloud, value):
    cloud[7, 1] = value
    cloud[20, 0] = value
    with pytest.raises(InputError, match=r"^points has 2 rows with NaN or inf \(first at row 7\) — "
                                         r"remove them$"):
        as_points(cloud)


@pytest.mark.parametrize("bad", [[["a", "b", "c"]] * 60, {"x": 1}, object()])
def test_non_numeric(bad):
    with pytest.raises(InputError, match=r"^points must be numeric, got \w+: "):
        as_points(bad)


def test_ragged_rows_are_non_numeric():
    with pytest.raises(InputError, match=r"^points must be numeric, got list: "):
        as_points([[0.0, 1.0, 2.0], [1.0, 2.0]] * 30)


def test_normals_are_normalised(rng):
    raw = rng.normal(size=(100, 3)) * rng.uniform(0.1, 10.0, size=(100, 1))
    before = raw.copy()
    out = as_normals(raw, 100)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(out * np.linalg.norm(raw, axis=1, keepdims=True), raw, rtol=1e-12)
    np.testing.assert_array_equal(raw, before)


def test_bad_normals(rng):
    with pytest.raises(InputError, match=r"^normals must have shape \(100, 3\) like the points, got \(99, 3\)$"):
        as_normals(np.ones((99, 3)), 100)
    bad = rng.normal(size=(100, 3))
    bad[3] = np.nan
    with pytest.raises(InputError, match=r"^normals contain NaN or inf — drop them and let canalsurf estimate "
                                         r"normals$"):
        as_normals(bad, 100)
    bad[3] = 0.0
    with pytest.raises(InputError, match=r"^normals contain zero vectors — drop them and let canalsurf "
                                         r"estimate normals$"):
        as_normals(bad, 100)


def test_positive():
    assert positive(None, "R") is None
    assert positive(np.float32(0.5), "R") == 0.5
    for bad in (0, -1.0, math.nan, math.inf):
        with pytest.raises(InputError, match=rf"^R must be a positive number, got {bad!r}$".replace("(", r"\(")
                           .replace(")", r"\)")):
            positive(bad, "R")


def test_in_range():
    assert in_range(None, "mu", 0.0, 1.0) is None
    assert in_range(1, "mu", 0.0, 1.0) == 1.0
    assert in_range(0.0, "mu", 0.0, 1.0) == 0.0
    with pytest.raises(InputError, match=r"^mu must lie in \[0\.0, 1\.0\], got 1\.5$"):
        in_range(1.5, "mu", 0.0, 1.0)
    with pytest.raises(InputError, match=r"^tau must lie in \[-1\.0, 1\.0\], got nan$"):
        in_range(math.nan, "tau", -1.0, 1.0)


def test_choice():
    assert choice("pipe", "kind", ("auto", "pipe", "canal")) == "pipe"
    with pytest.raises(InputError, match=r"^kind must be one of 'auto', 'pipe', 'canal', got 'cone'$"):
        choice("cone", "kind", ("auto", "pipe", "canal"))


@pytest.mark.parametrize("check", [lambda v: positive(v, "R"), lambda v: in_range(v, "mu", 0.0, 1.0)])
@pytest.mark.parametrize("value", ["abc", [0.1, 0.2]])
def test_non_numeric_parameters_raise_input_error_naming_them(check, value):
    """Habit 4: invalid input raises InputError naming the parameter -- not a bare float() error."""
    with pytest.raises(InputError, match=r"^(R|mu) must "):
        check(value)


@pytest.mark.parametrize("value", [[["a", "b", "c"]] * 100, object()])
def test_non_numeric_normals(value):
    with pytest.raises(InputError, match=r"^normals "):
        as_normals(value, 100)
