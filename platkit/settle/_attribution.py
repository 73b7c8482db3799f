"""Which actuator is still moving when holds never settle: from the direction of its motion.

Late in a hold that never settled, the markers still move towards where they are heading. A
slow actuator j still making up its step moves them along its own column of the stand's
Jacobian in marker space, the way its step went: ``d_i = -sum_j c_ij J_j(u) du_ij`` with c_ij
> 0 for an actuator still short of its command (d_i: what the markers moved late in hold i,
reversed; or the fitted tail at its end). The Jacobian is read from the session itself: the
held marker positions of every command regressed on the controls, locally (Gaussian weights in
the controls, normalised by their span in the session, around the middle of the step), so no
model of the stand is needed. Per hold, c_ij is a least-squares fit of d_i on the columns of
the actuators that moved (each scaled to unit length: c_ij in m). An actuator that lags is
behind in nearly every hold it moved in, the others are behind or ahead by chance: it is named
when its c is positive in significantly more than half of them (one-sided sign test, p below
1e-3 over the actuators) and its median c is at least twice any other's; none when no one is.

    named, table = attribute_actuators(U, held, tails)
"""
from __future__ import annotations

import numpy as np
from scipy.stats import binomtest

#: an actuator takes part in a hold's step when it moved by more than this share of its span
MOVED_SHARE = 0.05


def local_jacobian(Un: np.ndarray, P: np.ndarray, at: np.ndarray, n_eff: float) -> np.ndarray | None:
    """(D, n_u) d P / d Un at ``at`` (n_u,): P (N, D) regressed on Un (N, n_u) by weighted least
    squares, weights exp(-|Un - at|^2 / 2 h^2), h widened from 0.2 until the weights' effective
    number reaches ``n_eff``. None when too few rows."""
    N, n_u = Un.shape
    if N < n_u + 2:
        return None
    d2 = np.sum((Un - at) ** 2, axis=1)
    h = 0.2
    for _ in range(12):
        w = np.exp(-0.5 * d2 / h**2)
        if w.sum() ** 2 / max(float(np.sum(w**2)), 1e-300) >= n_eff:
            break
        h *= 1.4
    A = np.column_stack([np.ones(N), Un - at]) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(A, P * np.sqrt(w)[:, None], rcond=None)
    return coef[1:].T


def attribute_actuators(U: np.ndarray, held: np.ndarray, tails: dict[int, np.ndarray],
                        p_limit: float = 1e-3, dominance: float = 2.0) -> tuple[list[int], dict]:
    """(indices of the actuators named, per-actuator table) for holds that never settled.

    U: (N, n_u) commands; held: (N, M, 3) m where the markers were held at each command (NaN:
    unknown); tails: row -> (M, 3) m, a vector from where the markers are heading to where they
    are late in that hold (the fitted tail at its end, or what they moved over its last part,
    reversed). The table: 'moved_late_m' (n_u,) the median over the holds each actuator moved in
    of that vector's part along its own column, reversed (positive: still short of its command;
    NaN: fewer than 3 holds), 'positive' (n_u,) the share of those holds where it is positive,
    'p' (n_u,) the sign test's p-value of that share (one-sided), 'holds' (n_u,) how many."""
    U = np.asarray(U, float)
    N, n_u = U.shape
    span = np.ptp(U, axis=0)
    Un = (U - U.min(axis=0)) / np.where(span > 0, span, 1.0)
    P = np.asarray(held, float).reshape(N, -1)
    rows_ok = np.all(np.isfinite(P), axis=1)
    left: list[list[float]] = [[] for _ in range(n_u)]
    for i, d in sorted(tails.items()):
        if i < 1 or not rows_ok.sum() >= 2 * (n_u + 1):
            continue
        du = Un[i] - Un[i - 1]
        moved = np.abs(du) > MOVED_SHARE
        d = np.asarray(d, float).reshape(-1)
        use = np.isfinite(d)
        if not moved.any() or use.sum() < moved.sum() + 1:
            continue
        J = local_jacobian(Un[rows_ok], P[rows_ok], 0.5 * (Un[i] + Un[i - 1]), 4.0 * (n_u + 1))
        if J is None:
            continue
        G = J[:, moved] * du[moved]  # (D, k): the marker motion of each actuator's step
        norm = np.linalg.norm(G[use], axis=0)
        if not np.all(norm > 0):
            continue
        c, *_ = np.linalg.lstsq(G[use] / norm, d[use], rcond=None)
        for j, cj in zip(np.nonzero(moved)[0], c):
            left[j].append(-float(cj))  # positive: the actuator still short of its command
    med = np.full(n_u, np.nan)
    pval = np.ones(n_u)
    count = np.array([len(v) for v in left])
    pos = np.full(n_u, np.nan)
    for j in range(n_u):
        if count[j] >= 3:
            v = np.array(left[j])
            med[j] = float(np.median(v))
            pos[j] = float(np.mean(v > 0))
            pval[j] = float(binomtest(int(np.sum(v > 0)), len(v), 0.5, alternative="greater").pvalue)
    table = {"moved_late_m": med, "p": pval, "holds": count, "positive": pos}
    if not np.isfinite(med).any():
        return [], table
    top = int(np.nanargmax(med))
    others = np.abs(np.delete(med, top))
    others = others[np.isfinite(others)]
    second = float(others.max()) if others.size else 0.0
    if med[top] > 0 and pval[top] < p_limit / n_u and med[top] >= dominance * second:
        return [top], table
    return [], table
