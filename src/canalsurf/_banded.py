"""Symmetric positive definite systems whose unknowns couple only locally: a spline fit's.

A spline's coefficients couple only with the few whose basis functions overlap theirs, so its normal
equations, put in a bandwidth-reducing order (reverse Cuthill-McKee), are block tridiagonal -- but for
a few unknowns coupled to all (a pipe's one radius), which border the system.  Solving them, and the
entries of the inverse within the band (selected inversion), then costs time linear in the number of
unknowns instead of cubic, for a whole batch of matrices of the one pattern at once.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

#: An unknown coupled to more than this share of the others borders the system (it is no part of a band).
BORDER_SHARE = 0.5


class BlockTridiagonal:
    """A batch of symmetric positive definite matrices of one sparsity pattern, factored block-wise.

    Parameters
    ----------
    pattern : ndarray of bool, shape (n, n)
        Where any of the matrices can be non-zero (symmetric).

    Attributes
    ----------
    index : ndarray of int, shape (blocks, size)
        The unknowns of each block, in band order; the last block padded with ``n``.
    size : int
        Unknowns per block: the band's bandwidth.
    border : ndarray of int
        The unknowns coupled to more than BORDER_SHARE of the others, set apart from the band.
    """

    def __init__(self, pattern: np.ndarray):
        n = len(pattern)
        dense = pattern.sum(axis=1) > BORDER_SHARE * n
        dense &= not dense.all()  # all coupled to all: one block
        inner = np.flatnonzero(~dense)
        sub = pattern[np.ix_(inner, inner)]
        order = inner[reverse_cuthill_mckee(csr_matrix(sub), symmetric_mode=True)]
        rows, cols = np.nonzero(pattern[np.ix_(order, order)])
        # Block size the bandwidth: an unknown then couples only with its own block and the two beside it.
        self.size = max(int(np.abs(rows - cols).max()) if len(rows) else 0, 1)
        blocks = -(-len(order) // self.size)
        self.index = np.full(blocks * self.size, n)  # padded with a dummy unknown, index n
        self.index[: len(order)] = order
        self.index = self.index.reshape(blocks, self.size)
        self.border = np.flatnonzero(dense)
        self.n = n

    def _blocks(self, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The diagonal blocks of ``matrix`` (blocks, size, size) and those below them (blocks - 1, size,
        size), in this order; the padding's entries 0."""
        i = np.minimum(self.index, self.n - 1)
        real = self.index < self.n
        diag = matrix[i[:, :, None], i[:, None, :]] * (real[:, :, None] & real[:, None, :])
        lower = matrix[i[1:, :, None], i[:-1, None, :]] * (real[1:, :, None] & real[:-1, None, :])
        return diag, lower

    def factor(self, base: np.ndarray, extra: np.ndarray | None = None,
               scales: np.ndarray | None = None) -> BlockTridiagonal:
        """Factor ``base + s * extra`` for each ``s`` of ``scales`` (or ``base`` alone, ``extra`` None),
        each (n, n) with the pattern's sparsity; returns ``self``."""
        self._single = extra is None
        s = np.zeros(1) if extra is None else np.asarray(scales, float)
        extra = np.zeros_like(base) if extra is None else extra
        (bd, bl), (ed, el) = self._blocks(base), self._blocks(extra)
        diag = bd + s[:, None, None, None] * ed  # (batch, blocks, size, size)
        self._lower = bl + s[:, None, None, None] * el
        pad = np.flatnonzero(self.index[-1] == self.n)
        diag[:, -1, pad, pad] = 1.0  # the padding's unknowns solve to themselves
        inverse = np.empty_like(diag)
        inverse[:, 0] = np.linalg.inv(diag[:, 0])
        for k in range(1, len(self.index)):
            c = self._lower[:, k - 1]
            inverse[:, k] = np.linalg.inv(diag[:, k] - c @ inverse[:, k - 1] @ c.transpose(0, 2, 1))
        self._inverse = inverse
        if len(self.border):
            b = self.border
            edge = base[None, :, b] + s[:, None, None] * extra[None, :, b]  # (batch, n, nb)
            self._w = self._inner_solve(edge)  # B^-1 c
            corner = base[b[:, None], b[None, :]] + s[:, None, None] * extra[b[:, None], b[None, :]]
            self._schur_inverse = np.linalg.inv(corner - edge.transpose(0, 2, 1) @ self._w)
        return self

    def _inner_solve(self, rhs: np.ndarray) -> np.ndarray:
        """The band's system solved for ``rhs`` (batch, n, r): entries of the border are ignored and 0 out."""
        i = self.index
        padded = np.zeros((rhs.shape[0], self.n + 1, rhs.shape[2]))
        padded[:, : self.n] = rhs
        z = padded[:, i]  # (batch, blocks, size, r)
        for k in range(1, len(i)):
            z[:, k] -= self._lower[:, k - 1] @ (self._inverse[:, k - 1] @ z[:, k - 1])
        y = np.empty_like(z)
        y[:, -1] = self._inverse[:, -1] @ z[:, -1]
        for k in range(len(i) - 2, -1, -1):
            y[:, k] = self._inverse[:, k] @ (z[:, k] - self._lower[:, k].transpose(0, 2, 1) @ y[:, k + 1])
        out = np.zeros_like(padded)
        out[:, i.ravel()] = y.reshape(y.shape[0], -1, y.shape[3])
        return out[:, : self.n]

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A x = rhs`` for each factored matrix: ``rhs`` of shape (n,) or (batch, n); ``x`` alike."""
        r = np.asarray(rhs, float)
        batch = len(self._inverse[:, 0])
        r = np.broadcast_to(r, (batch, self.n)) if r.ndim == 1 else r
        x = self._inner_solve(r[:, :, None])
        if len(self.border):
            b = self.border
            # [[B, c], [c^T, d]]: the border's unknowns z = S^-1 (q - w^T r), S = d - c^T w, w = B^-1 c.
            z = self._schur_inverse @ (r[:, b, None] - self._w.transpose(0, 2, 1) @ r[:, :, None])
            x = x - self._w @ z
            x[:, b] = z
        x = x[:, :, 0]
        return x[0] if self._single else x

    def trace_product(self, other: np.ndarray) -> np.ndarray:
        """``tr(A^-1 other)`` for each factored matrix ``A``, ``other`` (n, n) symmetric with the pattern's
        sparsity: only the inverse's entries within the pattern are made (selected inversion)."""
        i = self.index
        diag, lower = self._blocks(other)
        inv, c = self._inverse, self._lower
        g = inv[:, -1]
        total = np.einsum("bij,ij->b", g, diag[-1])
        for k in range(len(i) - 2, -1, -1):
            right = c[:, k] @ inv[:, k]  # C_k S_k^-1
            below = -g @ right  # G_{k+1,k}
            g = inv[:, k] + right.transpose(0, 2, 1) @ g @ right
            total += np.einsum("bij,ij->b", g, diag[k]) + 2.0 * np.einsum("bij,ij->b", below, lower[k])
        if len(self.border):
            b = self.border
            w, s = self._w, self._schur_inverse
            # A^-1 = [[B^-1 + w S^-1 w^T, -w S^-1], [-S^-1 w^T, S^-1]]
            inner = other.copy()
            inner[:, b] = 0.0
            inner[b, :] = 0.0
            total += np.einsum("bij,bji->b", s, w.transpose(0, 2, 1) @ (inner @ w))
            total -= 2.0 * np.einsum("bij,bji->b", s, w.transpose(0, 2, 1) @ other[:, b])
            total += np.einsum("bij,ji->b", s, other[b[:, None], b[None, :]])
        return total[0] if self._single else total
