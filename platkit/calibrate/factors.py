"""R factors of tall matrices for identifiability: the same inner products between columns (so the
same spans, ranks and pivoting) at a fraction of the rows, summed in whatever order is fastest:
:func:`platkit.calibrate.identifiability.select_identifiable` decides ties by order, not rounding."""
from __future__ import annotations

import numpy as np

__all__ = ["MAX_PATTERNS", "SPARSE_FRACTION", "column_factor"]

#: a tall matrix with at most this fraction of nonzero entries is tried by its rows' column patterns
SPARSE_FRACTION = 0.75
#: ... with at most this many distinct patterns
MAX_PATTERNS = 64


def column_factor(A: np.ndarray) -> np.ndarray:
    """An R factor of A (m, n), m > n: (n, n) upper triangular with R^T R = A^T A, the same inner products between
    columns, so the same span, ranks and pivoting, at a fraction of the rows. Where A's rows fall
    in groups that each move a part of the columns (a tree's hands: each hand's markers move the
    trunk's columns and their own arm's), the rows are grouped by their nonzero columns (patterns
    whose union widens the wider by at most a tenth are one group), each group's R taken on its own
    columns, and R is the R of those stacked: where that costs at most half the flops of one QR of
    A (it sums in another order: identifiability's choice does not follow rounding); else one QR."""
    if np.count_nonzero(A) <= SPARSE_FRACTION * A.size:
        R = _factor_by_patterns(A)
        if R is not None:
            return R
    return np.linalg.qr(A, mode="r")


def _factor_by_patterns(A: np.ndarray) -> np.ndarray | None:
    """:func:`column_factor` by its rows' column patterns, or None where the groups would not save
    half the flops (or there are more than MAX_PATTERNS patterns)."""
    m, n = A.shape
    nz = A != 0
    packed = np.ascontiguousarray(np.packbits(nz, axis=1))
    keys = packed.view(np.dtype((np.void, packed.shape[1]))).ravel()
    uniq, first, inv = np.unique(keys, return_index=True, return_inverse=True)
    if len(uniq) > MAX_PATTERNS:
        return None
    groups: list[list] = []  # [columns (n,) bool, patterns]
    for p in sorted(range(len(uniq)), key=lambda p: -int(nz[first[p]].sum())):
        cols = nz[first[p]]
        for g in groups:
            union = g[0] | cols
            if union.sum() <= 1.1 * max(g[0].sum(), cols.sum()):
                g[0] = union
                g[1].append(p)
                break
        else:
            groups.append([cols.copy(), [p]])
    label = np.empty(len(uniq), int)
    for k, g in enumerate(groups):
        label[g[1]] = k
    rows_of = label[inv.ravel()]
    counts = np.bincount(rows_of, minlength=len(groups))
    widths = np.array([g[0].sum() for g in groups])
    if float(np.sum(counts * widths ** 2.0)) + float(widths.sum()) * n * n > 0.5 * m * n * n:
        return None
    parts = []
    for k, g in enumerate(groups):
        cols = np.flatnonzero(g[0])
        if cols.size == 0:
            continue
        B = A[np.ix_(np.flatnonzero(rows_of == k), cols)]
        part = np.zeros((min(B.shape), n))
        part[:, cols] = np.linalg.qr(B, mode="r") if B.shape[0] > B.shape[1] else B
        parts.append(part)
    stacked = np.vstack(parts + [np.zeros((max(0, n - sum(len(p) for p in parts)), n))])  # columns no row moves: 0
    return np.linalg.qr(stacked, mode="r")
