"""Block-tridiagonal solves and traces against dense linear algebra."""

import numpy as np
import pytest

from canalsurf._banded import BlockTridiagonal


def _banded(n, width, rng, *, border=(), cyclic=False):
    """A random symmetric positive definite (n, n) matrix whose unknowns couple within ``width`` of each
    other (round the ends too if ``cyclic``), plus ``border`` unknowns coupled to all, in a shuffled order."""
    near = np.abs(np.subtract.outer(np.arange(n), np.arange(n)))
    if cyclic:
        near = np.minimum(near, n - near)
    a = np.where(near <= width, rng.normal(size=(n, n)), 0.0)
    a = a + a.T + 4.0 * width * np.eye(n)
    for b in border:
        a[:, b] = a[b, :] = rng.normal(size=n)
        a[b, b] = 4.0 * n
    order = rng.permutation(n)
    return a[np.ix_(order, order)]


@pytest.mark.parametrize("n, border, cyclic", [(60, (), False), (61, (7,), False), (90, (3, 40), False),
                                               (64, (), True), (5, (), False)])
def test_solves_and_traces_match_dense_ones_for_a_batch_of_weights(n, border, cyclic):
    rng = np.random.default_rng(n)
    base = _banded(n, 4, rng, border=border, cyclic=cyclic)
    extra = _banded(n, 2, rng, cyclic=cyclic)
    extra = extra @ extra.T  # positive definite, as a penalty is semi-definite
    scales = np.array([0.0, 0.5, 20.0])
    solver = BlockTridiagonal((base != 0) | (extra != 0)).factor(base, extra, scales)
    rhs = rng.normal(size=(len(scales), n))
    dense = [base + s * extra for s in scales]
    assert np.allclose(solver.solve(rhs), [np.linalg.solve(a, r) for a, r in zip(dense, rhs)], atol=1e-12)
    assert np.allclose(solver.trace_product(base), [np.trace(np.linalg.solve(a, base)) for a in dense],
                       rtol=1e-12)
    assert len(solver.border) == len(border)


def test_a_band_is_cut_into_blocks_as_wide_as_its_bandwidth():
    rng = np.random.default_rng(0)
    a = _banded(300, 3, rng)
    solver = BlockTridiagonal(a != 0)
    assert solver.size <= 2 * 3 + 1 and solver.index.size >= 300
    x = solver.factor(a).solve(np.ones(300))
    assert np.allclose(a @ x, 1.0)
