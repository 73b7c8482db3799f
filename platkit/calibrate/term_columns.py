"""A model term's columns of the calibration problem's Jacobian, from the observation function's
Jacobian and the term's offset derivatives, written without the products by zeros (a screened
control offset moves one control; the marker probe's columns each move one marker coordinate):
what :meth:`platkit.calibrate.problem.CalibrationProblem._rows` assembles the Jacobian with."""
from __future__ import annotations

import numpy as np

__all__ = ["by_rows", "contiguous", "offset_column", "one_row_columns", "support"]


def support(d: np.ndarray) -> np.ndarray:
    """The columns of a term's offset derivative d (N, k) nonzero (or not finite) at some pose."""
    return np.flatnonzero(d.any(axis=0))  # NaN counts as nonzero


def offset_column(parts, supports) -> np.ndarray:
    """One term parameter's Jacobian column (n, rows): the sum over ``parts`` ((Y (n, rows, k), d (n, k))) of
    ``np.einsum("nak,nk->na", Y, d)`` in the parts' order. With ``supports`` (each d's columns nonzero
    at some pose, :func:`support`; given only where every Y is finite) a part whose d is zero is left
    out (its sum is +0 everywhere; x + 0 is x), one with a single such column is that column's product
    plus +0 (the one product the sum adds to zeros, a zero of either sign +0): the same bits, without
    the products by zeros (a screened control offset moves one control)."""
    total = None
    for (Y, d), s in zip(parts, supports if supports is not None else (None,) * len(parts)):
        if s is not None and s.size == 0:
            continue
        if s is not None and s.size == 1:
            c = int(s[0])
            term = Y[:, :, c] * d[:, c, None] + 0.0
        else:
            term = np.einsum("nak,nk->na", Y, d)
        total = term if total is None else total + term
    return np.zeros(parts[0][0].shape[:2]) if total is None else total


def one_row_columns(d: np.ndarray) -> list[tuple[int, np.ndarray]] | None:
    """Where every column of the term's marker offsets d (N, rows, K) is nonzero in at most one
    row (the same for every pose): each such row's index with its columns, else None (and for
    fewer than 8 columns, where a matrix product costs no more)."""
    if d.shape[2] < 8:
        return None
    used = (d != 0).any(axis=0)  # (rows, K)
    if used.sum(axis=0).max(initial=0) > 1:
        return None
    return [(int(b), contiguous(np.flatnonzero(used[b]))) for b in np.flatnonzero(used.any(axis=1))]


def contiguous(idx: np.ndarray):
    """``idx`` (sorted indices) as a slice where they are a contiguous run (a view, not a copy)."""
    if len(idx) and idx[-1] - idx[0] == len(idx) - 1:
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def by_rows(Y: np.ndarray, d: np.ndarray, pattern: list, out: np.ndarray, first: bool) -> np.ndarray | None:
    """out = Y @ d (``first``) or out += Y @ d, (n, a, b) @ (n, b, K), where each column of d is
    nonzero in one row b at most (``pattern``, :func:`one_row_columns`): each column the product
    of its one entry with Y's column b, written only into the rows where that column of Y is
    nonzero. The same numbers as the matrix product (a sum of one product and exact zeros) but
    the sign of some zeros. Returns which rows each column was written in, (a, K) bool (the
    product is zero in the others at every pose); None (nothing written) where Y is not finite
    (0 * inf is NaN there)."""
    if not np.isfinite(Y).all():
        return None
    Ynz = (Y != 0).any(axis=0)  # (a, b): the rows each column of Y reaches
    written = np.zeros(out.shape[1:], bool)
    if first:
        out[...] = 0.0
    for b, cols in pattern:
        written[:, cols] = Ynz[:, b, None]
        rows = contiguous(np.flatnonzero(Ynz[:, b]))
        if not isinstance(rows, slice) and len(rows) == 0:
            continue
        block = Y[:, rows, b][:, :, None] * d[:, b, cols][:, None, :]
        ix = (slice(None), rows, cols) if isinstance(rows, slice) and isinstance(cols, slice) else \
            np.ix_(np.arange(out.shape[0]), _indices(rows, out.shape[1]), _indices(cols, out.shape[2]))
        if first:
            out[ix] = block
        else:
            out[ix] += block
    return written


def _indices(idx, n: int) -> np.ndarray:
    """A slice or index array of :func:`contiguous` as an index array (for ``np.ix_``)."""
    return np.arange(n)[idx] if isinstance(idx, slice) else idx
