"""Which columns of a Jacobian each point (marker) moves on, and the runs of consecutive points that
move on nearly the same columns: what the normal equations are summed by (a tree's hand: its markers
move on its arm's and the trunk's columns, not the other arm's; platkit.calibrate.solve)."""
from __future__ import annotations

import numpy as np

__all__ = ["RUN_WIDENS", "columns_by_structure", "point_columns", "runs_of_points", "take"]

#: a run of points grows while the union of their columns widens the wider by at most this fraction
RUN_WIDENS = 0.1


def point_columns(J: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(P, len(cols)) bool: whether point p's rows of J (N, P, 3, n_z) have a nonzero (or NaN)
    entry in column cols[j] at some pose."""
    return (J != 0).any(axis=0).any(axis=1)[:, cols]


def runs_of_points(moves: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """The runs of consecutive points the normal equations are summed by, from each point's columns
    ``moves`` (P, n) bool: (first point, end, the indices of their columns' union); a run takes the
    next point while their union is at most RUN_WIDENS wider than the wider of the two."""
    runs: list[tuple[int, int, np.ndarray]] = []
    union = np.zeros(moves.shape[1:], bool)  # the last run's columns, as a mask
    for p in range(len(moves)):
        widest = max(int(np.count_nonzero(union)), int(np.count_nonzero(moves[p])))
        joined = union | moves[p]
        if runs and np.count_nonzero(joined) <= (1 + RUN_WIDENS) * widest:
            runs[-1], union = (runs[-1][0], p + 1, np.flatnonzero(joined)), joined
        else:
            runs.append((p, p + 1, np.flatnonzero(moves[p])))
            union = moves[p].copy()
    return runs


def columns_by_structure(J: np.ndarray | tuple[np.ndarray, ...], cols: np.ndarray,
                         structure: np.ndarray | None) -> np.ndarray | None:
    """:func:`point_columns` without a pass over every entry of J (or of its parts side by side,
    FitState.parts), where ``structure`` (P, k) decides it: False where J[:, p, :, j] is zero at
    every pose, for J's first k columns. A point's columns there lie between those nonzero at the
    first pose and the structure's; where the two agree they are the structure's. The columns
    beyond k are read off J. None (read J whole) without a structure, where the first pose leaves
    a structural column zero (a product with a parameter that is 0, a pose where a column
    vanishes), or where more than a quarter of ``cols`` (ascending) lie beyond k (reading those
    costs about as much as reading every column)."""
    parts = J if isinstance(J, tuple) else (J,)
    if structure is None or structure.shape[0] != parts[0].shape[1] or \
            structure.shape[1] > sum(p.shape[3] for p in parts) or not len(parts[0]):
        return None
    k = structure.shape[1]
    known = cols < k
    if 4 * np.count_nonzero(~known) > cols.size:
        return None
    moves = np.empty((parts[0].shape[1], cols.size), bool)
    moves[:, known] = structure[:, cols[known]]
    if not np.array_equal((take(parts, cols[known], poses=slice(0, 1))[0] != 0).any(axis=1), moves[:, known]):
        return None
    if not known.all():
        moves[:, ~known] = (take(parts, cols[~known]) != 0).any(axis=0).any(axis=1)
    return moves


def take(parts: tuple[np.ndarray, ...], cols: np.ndarray, poses: slice = slice(None),
         points: slice = slice(None)) -> np.ndarray:
    """J[poses, points][..., cols] of a Jacobian held as ``parts`` (arrays (N, P, 3, k_i) side by
    side along the last axis, FitState.parts), ``cols`` ascending: a new array, numpy's gather
    where the columns lie in one part, else each part's gathered into one array laid out as that
    gather lays out its result (the gathered axis outermost): the same array, in the same memory
    order, as the gather from J whole."""
    edges = np.cumsum([0] + [p.shape[-1] for p in parts])
    at = np.searchsorted(cols, edges)  # cols[at[i]:at[i + 1]] lie in part i
    out = None
    for part, lo, a, b in zip(parts, edges, at[:-1], at[1:]):
        if b > a or (out is None and part is parts[-1]):
            block = part[poses, points][..., cols[a:b] - lo]
            if b - a == cols.size:
                return block
            if out is None:  # laid out as numpy's gather lays it out (the products after it follow the layout)
                out = np.empty_like(block, shape=block.shape[:-1] + (cols.size,))
            out[..., a:b] = block
    return out
