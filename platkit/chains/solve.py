"""The inverse velocity problem (Sorokin 2017, section 6 and the notes after it).

Given the Jacobian J (m, n) of the controlled components and a wanted twist e (m,), find joint
increments dq (n,) with J dq = e. The problem may have one solution, many (redundant chains) or
none (singular poses, unreachable twists); a cost chooses among many.

Two solvers:

* :func:`solve_pinv`: weighted, damped pseudo-inverse. Task weights scale the rows (selective
  control: weight 0 drops a component), joint weights the columns; the damping grows as the
  smallest singular value falls below a threshold (Maciejewski-Nakamura), so a singular pose
  gives bounded steps; a secondary cost's gradient is projected into the null space; joints
  that would cross a position limit are clamped at it and the rest re-solved; the step is then
  scaled uniformly to the rate limits, which keeps its direction (the paper's collinearity).
  Several priority levels (a stacked Jacobian for tree-shaped chains) are solved one after
  another, each in the null space of those before it.
* :func:`solve_lp`: linear programming (scipy's HiGHS). The largest fraction t <= 1 of e that
  the joints can produce within their position and rate bounds, dq cheapest in a weighted L1
  norm plus a linear secondary cost; where no fraction is reachable (e outside the range of J),
  the L1 residual is minimised instead.

Units: dq in the joints' units (rad, m) per step; e in m and rad.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Damping:
    """Damping schedule: lambda^2 = max_damping^2 (1 - (sigma_min / threshold)^2) below the
    threshold, 0 above it (Maciejewski-Nakamura), times min(1, |e| / error_scale) so that the
    damping fades as the error vanishes and the last steps converge quadratically.
    ``threshold`` in the Jacobian's units (m/rad for positions); ``error_scale`` in m/rad
    (None: no fading)."""

    threshold: float = 2e-2
    max_damping: float = 5e-2
    error_scale: float | None = 1e-2

    def factor(self, sigma_min: float, error_norm: float = np.inf) -> float:
        if sigma_min >= self.threshold:
            return 0.0
        lam2 = self.max_damping**2 * (1.0 - (sigma_min / self.threshold) ** 2)
        if self.error_scale is not None:
            lam2 *= min(1.0, error_norm / self.error_scale)
        return lam2


@dataclass
class Level:
    """One priority level: stacked rows ``J`` (m, n), wanted twist ``e`` (m,), row weights (m,)."""

    J: np.ndarray
    e: np.ndarray
    weights: np.ndarray | None = None


@dataclass
class StepInfo:
    """What a solver met: smallest singular value and damping of the first level, joints
    clamped at a position limit, the rate scale applied, the LP's fraction t."""

    sigma_min: float = np.inf
    damping: float = 0.0
    clamped: list[int] = field(default_factory=list)
    rate_scale: float = 1.0
    fraction: float = 1.0


def damped_pinv(A: np.ndarray, damping: Damping, error_norm: float = np.inf, rank_tol: float = 1e-10):
    """(A^# (n, m), null-space projector N (n, n), sigma_min, lambda^2) by SVD.

    A^# = V diag(s / (s^2 + lambda^2)) U^T; N = I - V_r V_r^T over the singular values above
    ``rank_tol`` times the largest (the exact null space, undamped)."""
    m, n = A.shape
    if m == 0 or n == 0:
        return np.zeros((n, m)), np.eye(n), np.inf, 0.0
    U, s, Vt = np.linalg.svd(A, full_matrices=False)
    # directions with an exactly zero singular value (a structural rank deficit, e.g. a level
    # solved inside the null space of another) are dropped, not damped
    keep = s > rank_tol * max(1.0, s[0] if s.size else 0.0)
    sigma_min = float(s[keep][-1]) if np.any(keep) else 0.0
    lam2 = damping.factor(sigma_min, error_norm)
    inv = np.zeros_like(s)
    inv[keep] = s[keep] / (s[keep] ** 2 + lam2)
    pinv = (Vt.T * inv) @ U.T
    Vr = Vt[keep].T
    N = np.eye(n) - Vr @ Vr.T
    return pinv, N, sigma_min, lam2


def _prioritized(levels: list[Level], cols: np.ndarray, wq_sqrt_inv: np.ndarray, damping: Damping,
                 fixed_dq: np.ndarray, secondary: np.ndarray | None, info: StepInfo) -> list[np.ndarray]:
    """Increments over the free columns ``cols`` (joints outside move by ``fixed_dq``): one per
    level, each in the null space of the levels before it, then the secondary step's projection."""
    n_free = cols.size
    y = np.zeros(n_free)                     # scaled variables: dq_free = wq_sqrt_inv * y
    N = np.eye(n_free)
    first = True
    increments = []
    for lev in levels:
        w = np.ones(len(lev.e)) if lev.weights is None else np.asarray(lev.weights, float)
        rows = w > 0
        if not np.any(rows):
            continue
        sw = np.sqrt(w[rows])
        J_rows = lev.J[rows]
        target = lev.e[rows] - J_rows @ fixed_dq
        A = (J_rows[:, cols] * wq_sqrt_inv) * sw[:, None]
        r = sw * target - A @ y
        AN = A @ N
        pinv, N_level, sigma_min, lam2 = damped_pinv(AN, damping, float(np.linalg.norm(r)))
        if first:
            info.sigma_min, info.damping = sigma_min, float(np.sqrt(lam2))
            first = False
        dy = pinv @ r
        y = y + dy
        increments.append(wq_sqrt_inv * dy)
        N = N @ N_level
    if secondary is not None:
        increments.append(wq_sqrt_inv * (N @ (secondary[cols] / wq_sqrt_inv)))
    return increments


def _fraction_within(dq: np.ndarray, delta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """The largest beta in [0, 1] with lower <= dq + beta delta <= upper."""
    beta = 1.0
    with np.errstate(divide="ignore", invalid="ignore"):
        up = np.where(delta > 0, (upper - dq) / delta, np.inf)
        lo = np.where(delta < 0, (lower - dq) / delta, np.inf)
    beta = min(beta, float(np.min(up)), float(np.min(lo)))
    return max(0.0, beta)


def solve_pinv(levels: list[Level] | Level, *, lower_step: np.ndarray | None = None,
               upper_step: np.ndarray | None = None, rate_step: np.ndarray | None = None,
               joint_weights: np.ndarray | None = None, damping: Damping | None = None,
               secondary: np.ndarray | None = None, active: np.ndarray | None = None) -> tuple[np.ndarray, StepInfo]:
    """dq (n,) for prioritised levels by the weighted damped pseudo-inverse, and a StepInfo.

    ``lower_step``/``upper_step`` (n,): how far each joint may move before a position limit
    (lower <= 0 <= upper). For the first level, joints that would cross are clamped there and
    the rest re-solved; the later levels' increments and the secondary step are shortened to fit
    (never at the first level's expense).
    ``rate_step`` (n,): the most a joint may move in this step; dq is scaled uniformly to meet it.
    ``joint_weights`` (n,): a heavier joint moves less. ``secondary`` (n,): a joint-space step
    (e.g. minus a cost's gradient) added in the null space of all levels. ``active`` (n,) bool:
    joints allowed to move (others stay).
    """
    if isinstance(levels, Level):
        levels = [levels]
    n = levels[0].J.shape[1]
    damping = damping or Damping()
    lower_step = np.full(n, -np.inf) if lower_step is None else np.asarray(lower_step, float)
    upper_step = np.full(n, np.inf) if upper_step is None else np.asarray(upper_step, float)
    wq = np.ones(n) if joint_weights is None else np.asarray(joint_weights, float)
    free = np.ones(n, bool) if active is None else np.asarray(active, bool).copy()
    info = StepInfo()
    fixed = np.zeros(n)
    increments: list[np.ndarray] = []
    cols = np.flatnonzero(free)
    for _ in range(n + 1):
        cols = np.flatnonzero(free)
        dq = fixed.copy()
        increments = []
        if cols.size:
            increments = _prioritized(levels, cols, 1.0 / np.sqrt(wq[cols]), damping, fixed, secondary, info)
            if increments:
                dq[cols] += increments[0]
        over = free & ((dq > upper_step + 1e-15) | (dq < lower_step - 1e-15))
        if not np.any(over):
            break
        # clamp the worst offender at its limit and re-solve for the others
        excess = np.maximum(dq - upper_step, lower_step - dq)
        excess[~over] = -np.inf
        worst = int(np.argmax(excess))
        fixed[worst] = np.clip(dq[worst], lower_step[worst], upper_step[worst])
        free[worst] = False
        info.clamped.append(worst)
    dq = np.clip(dq, lower_step, upper_step)
    lo, hi = lower_step, upper_step
    if rate_step is not None:
        # the first level's step scaled uniformly to the rate limits (its direction kept) ...
        rate_step = np.asarray(rate_step, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.abs(dq) > 0, rate_step / np.abs(dq), np.inf)
        scale = float(min(1.0, np.min(ratio))) if ratio.size else 1.0
        info.rate_scale = scale
        dq = dq * scale
        lo, hi = np.maximum(lower_step, -rate_step), np.minimum(upper_step, rate_step)
    # ... then the later levels and the secondary step, each shortened to what is left
    for inc in increments[1:]:
        delta = np.zeros(n)
        delta[cols] = inc
        dq = dq + _fraction_within(dq, delta, lo, hi) * delta
    return np.clip(dq, lo, hi), info


def solve_lp(J: np.ndarray, e: np.ndarray, *, weights: np.ndarray | None = None,
             lower_step: np.ndarray | None = None, upper_step: np.ndarray | None = None,
             rate_step: np.ndarray | None = None, joint_cost: np.ndarray | None = None,
             secondary: np.ndarray | None = None, active: np.ndarray | None = None) -> tuple[np.ndarray, StepInfo]:
    """dq (n,) by linear programming, and a StepInfo (``fraction`` = t reached).

    maximise t, then minimise sum c_i |dq_i| + g.dq, subject to W (J dq) = t W e, 0 <= t <= 1,
    max(lower, -rate) <= dq <= min(upper, rate). The step stays collinear with e (the servo's
    direction) and its length is what the bounds allow. Where t = 0 is all that is feasible,
    minimise the weighted L1 residual |W (J dq - e)| plus the same cost instead.
    ``joint_cost`` c (n,) > 0 (default 1); ``secondary`` g (n,): a linear cost, scaled so that
    |g_i| < c_i (it chooses among the solutions, never against the task).
    """
    from scipy.optimize import linprog

    m, n = J.shape
    w = np.ones(m) if weights is None else np.asarray(weights, float)
    rows = w > 0
    A = J[rows] * w[rows, None]
    b = e[rows] * w[rows]
    lo = np.full(n, -np.inf) if lower_step is None else np.asarray(lower_step, float)
    hi = np.full(n, np.inf) if upper_step is None else np.asarray(upper_step, float)
    if rate_step is not None:
        lo = np.maximum(lo, -np.asarray(rate_step, float))
        hi = np.minimum(hi, np.asarray(rate_step, float))
    if active is not None:
        off = ~np.asarray(active, bool)
        lo = np.where(off, 0.0, lo)
        hi = np.where(off, 0.0, hi)
    lo = np.minimum(lo, 0.0)
    hi = np.maximum(hi, 0.0)
    c = np.ones(n) if joint_cost is None else np.asarray(joint_cost, float)
    g = np.zeros(n) if secondary is None else np.asarray(secondary, float)
    gmax = np.max(np.abs(g) / c) if np.any(g) else 0.0
    if gmax > 0:
        g = g * (0.5 / gmax)
    # variables: dq+ (n), dq- (n), t ; dq = dq+ - dq-
    big = 1e3 * (1.0 + float(np.sum(c)) * max(1.0, float(np.max(np.abs(hi - lo)[np.isfinite(hi - lo)], initial=1.0))))
    cost = np.concatenate([c + g, c - g, [-big]])
    A_eq = np.hstack([A, -A, -b[:, None]])
    bounds = [(0.0, None if not np.isfinite(h) else h) for h in hi]
    bounds += [(0.0, None if not np.isfinite(-l) else -l) for l in lo]
    bounds += [(0.0, 1.0)]
    info = StepInfo()
    res = linprog(cost, A_eq=A_eq, b_eq=np.zeros(A.shape[0]), bounds=bounds, method="highs", options={"time_limit": 5.0})
    if res.status == 0 and res.x[-1] > 1e-9:
        x = res.x
        info.fraction = float(x[-1])
        return x[:n] - x[n:2 * n], info
    # e is not (even partly) reachable in the linearisation: least L1 residual
    k = A.shape[0]
    cost = np.concatenate([c + g, c - g, np.full(2 * k, big)])
    A_eq = np.hstack([A, -A, -np.eye(k), np.eye(k)])
    bounds = bounds[:2 * n] + [(0.0, None)] * (2 * k)
    res = linprog(cost, A_eq=A_eq, b_eq=b, bounds=bounds, method="highs", options={"time_limit": 5.0})
    info.fraction = 0.0
    if res.status != 0:
        return np.zeros(n), info
    return res.x[:n] - res.x[n:2 * n], info


# ----------------------------------------------------------------------------- secondary costs


def mid_range_gradient(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Gradient of H = 1/2 sum ((q - mid) / range)^2 (0 for unbounded joints) (n,)."""
    span = upper - lower
    ok = np.isfinite(span) & (span > 0)
    g = np.zeros_like(theta)
    g[ok] = (theta[ok] - 0.5 * (upper[ok] + lower[ok])) / span[ok] ** 2
    return g


def joint_limit_gradient(theta: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Gradient of H = sum range^2 / (4 (upper - q)(q - lower)), which grows without bound at a
    limit and is 1 per joint at mid-range (Zghal et al.) (n,)."""
    span = upper - lower
    ok = np.isfinite(span) & (span > 0)
    g = np.zeros_like(theta)
    a = np.maximum(upper[ok] - theta[ok], 1e-9 * span[ok])
    b = np.maximum(theta[ok] - lower[ok], 1e-9 * span[ok])
    g[ok] = span[ok] ** 2 * (b - a) / (4.0 * a**2 * b**2)
    return g


def manipulability(J: np.ndarray) -> float:
    """Yoshikawa's measure sqrt(det(J J^T)) of a Jacobian (m, n)."""
    return float(np.sqrt(max(np.linalg.det(J @ J.T), 0.0)))
