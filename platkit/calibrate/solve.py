"""Solvers of the calibration problem: Levenberg-Marquardt, the robust fit, k-fold held-out errors.

The problem (residuals, Jacobians, priors) is :class:`platkit.calibrate.problem.CalibrationProblem`.
- :func:`levenberg_marquardt`: Marquardt-scaled LM over the active unknowns, with fixed weights;
- :func:`robust_fit`: Huber weights on each marker's 3-D error (scale from the median error),
  then outliers beyond REJECT_K sigma rejected outright and the fit repeated at full weight;
- :func:`kfold`: K-fold held-out prediction error (refits on K-1 folds).

A run stops where a step gains less than ``ftol`` of the cost or moves less than ``xtol``, or where
no step descends. A run that meets none of these within its iterations is judged on its last
WINDOW iterations (:func:`judge_window`): converged in the misfit where the cost left to gain,
extrapolated from how the window's gains shrink, is what a move of SETTLED_SD standard deviations
of the unknowns would gain (a flat valley, or steps that zig-zag across one); its record, with the
unknowns still moving and how, is the run's ``LMResult.window`` (a robust fit's: its last run's).

A problem with ``row_block`` set (a fit of thousands of poses from a motion stream) is solved
from normal equations and R factors summed over blocks of that many poses
(:meth:`CalibrationProblem.evaluate_blocks`, :func:`weighted_factor`): no Jacobian of every pose
is made, the sums run in another order (the same fit to rounding). Without it (the default) the
arithmetic is the whole Jacobian's, in its order.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit._threads import blas_threads  # every LM run enters it; estimators import it from here
from platkit.calibrate.point_columns import columns_by_structure, point_columns, runs_of_points, take
from platkit.calibrate.problem import CalibrationProblem, FitState, Progress
from platkit.calibrate.robust import HUBER_K, MAXWELL_MEDIAN, REJECT_K, robust_sigma
from platkit.errors import BadInput


@dataclass
class LMResult:
    z: np.ndarray
    state: FitState
    weights: np.ndarray  # (N, M)
    iterations: int
    converged: bool
    cost: float
    #: the judgement of a run that met no per-step rule within its iterations (:func:`judge_window`)
    window: WindowJudgement | None = None


#: iterations over which a run that met no per-step rule is judged (:func:`judge_window`)
WINDOW = 10
#: the misfit has converged where what is left to gain is what a move of this many standard
#: deviations of the unknowns (jointly, in the metric of their covariance) would gain
SETTLED_SD = 0.01
#: an unknown whose steps over the window add up to this many times its net move zig-zags
ZIGZAG_PATH = 3.0


@dataclass(frozen=True)
class Moving:
    """One unknown over the window: its net move and the sum of its steps' sizes, both in its
    standard deviations at the fit's end."""

    name: str
    net_sd: float
    path_sd: float

    @property
    def how(self) -> str:
        return "zig-zag" if self.path_sd >= ZIGZAG_PATH * abs(self.net_sd) else "drift"


@dataclass(frozen=True)
class WindowJudgement:
    """A run judged on its last ``iterations`` (:func:`judge_window`). fall: the cost's fall over
    them; left: the fall still to come (inf where the gains do not shrink); both relative to the
    cost; left_sd: the move of the unknowns, in standard deviations, that would gain ``left``;
    settled: left_sd <= SETTLED_SD; moving: the three unknowns whose steps added up to most of
    their standard deviations, largest first."""

    iterations: int
    fall: float
    left: float
    left_sd: float
    settled: bool
    moving: tuple[Moving, ...]

    def sentence(self, total_iterations: int | None = None) -> str:
        """What a user reads: whether the misfit converged, and what still moves and how."""
        ran = f"after {total_iterations} iterations " if total_iterations is not None else ""
        moving = ", ".join(f"{m.name} {m.net_sd:+.2g} sd net ({m.how}, {m.path_sd:.2g} sd of steps)"
                           for m in self.moving) or "nothing"
        how = ("zig-zag: steps that reverse, overshooting across a valley; drift: steps one way along it. Large "
               "residuals from an effect the model does not describe make both: run platkit diagnose on the outputs")
        if self.settled:
            return (f"the fit stopped {ran}with its misfit converged, not yet its parameters: over the last "
                    f"{self.iterations} iterations the cost fell by {self.fall:.2g} of itself, and the gain left "
                    f"({self.left:.2g}) is what a move of {self.left_sd:.2g} standard deviations of the parameters "
                    f"would give, so the estimate is that close to the least-squares one; moving over them: {moving} "
                    f"({how})")
        left = "its gains not shrinking" if not np.isfinite(self.left) else f"{self.left:.2g} of the cost left to gain"
        return (f"the fit stopped {ran}still descending, out of iterations: over the last {self.iterations} iterations "
                f"the cost fell by {self.fall:.2g} of itself ({left}, a move of {self.left_sd:.2g} standard "
                f"deviations of the parameters); moving over them: {moving} ({how})")


def _inverse_diagonal(H: np.ndarray) -> np.ndarray:
    """The diagonal of H^-1 for a symmetric positive semi-definite H, from the eigenvalues of H
    scaled to a unit diagonal, each floored at 1e-15 of the largest: a direction H does not bound
    (a flat valley) gives a large variance, never the zero that a truncated pseudo-inverse gives;
    inf where H's diagonal is 0."""
    d = np.diag(H).copy()
    out = np.full(d.shape, np.inf)
    on = d > 0
    if not on.any():
        return out
    s = 1 / np.sqrt(d[on])
    lam, V = np.linalg.eigh(H[np.ix_(on, on)] * s[:, None] * s[None, :])
    lam = np.maximum(lam, 1e-15 * max(float(lam[-1]), 1e-300))
    out[on] = (V * V) @ (1 / lam) * s * s
    return out


def judge_window(costs, steps, H, dof: int, names) -> WindowJudgement:
    """The judgement of a run from its last costs (W + 1 of them, the cost after each iteration),
    its steps over the active unknowns (W, n), the last Gauss-Newton matrix H (n, n) of the weighted
    problem the run formed, and the residual degrees of freedom.

    The noise variance is s2 = 2 cost / dof; a move d of the unknowns gains d^T H d / 2, so one of
    k standard deviations (jointly, in the metric of the covariance s2 H^-1) gains k^2 s2 / 2. The
    gain left is the second half-window's gains times q / (1 - q), q the ratio of those gains to the
    first half's (a geometric tail: Gauss-Newton's linear convergence where large residuals curve,
    or steps that zig-zag across a valley), and never less than the second half's gains."""
    costs = np.asarray(costs, float)
    cost = max(float(costs[-1]), 1e-300)
    gains = -np.diff(costs)
    h = len(gains) // 2
    first, last = float(np.sum(gains[-2 * h:-h])), float(np.sum(gains[-h:]))
    if last <= 0:
        left = 0.0
    elif first > last:
        q = last / first
        left = max(last * q / (1 - q), last)  # never less than the last half-window gained
    else:
        left = np.inf
    s2 = 2 * cost / max(dof, 1)
    left_sd = float(np.sqrt(2 * left / s2)) if np.isfinite(left) else np.inf
    sd = np.sqrt(s2 * _inverse_diagonal(H))
    steps = np.asarray(steps, float)
    net, path = steps.sum(axis=0) / sd, np.abs(steps).sum(axis=0) / sd
    order = [int(k) for k in np.argsort(-path)[:3] if path[k] > 0]
    moving = tuple(Moving(str(names[k]), float(net[k]), float(path[k])) for k in order)
    return WindowJudgement(len(gains), float((costs[0] - costs[-1]) / cost), float(left / cost), left_sd,
                           bool(left_sd <= SETTLED_SD), moving)


def _weighted(state: FitState, weights, active, prior=None, scratch: dict | None = None):
    """Weighted residual vector and Jacobian columns of the active unknowns; ``prior``: optional
    rows from :meth:`CalibrationProblem.prior_rows` (values, unknown index, slope).

    ``scratch``: a dict that keeps the weighted Jacobian's array from one call to the next (see
    :func:`_weighted_columns`); the array returned is overwritten by the next call with it."""
    sw, rw = _weighted_residuals(state, weights)
    Jw = None
    parts = state.parts
    if parts is not None:
        # one pass over the rows in 2-D (the Jacobian is often a strided view of the observation
        # function's output): a column gather, then the weights in place (18 ms for 150,000 x 51
        # where a gather on the 4-D view took 120 ms)
        rows = np.repeat(sw.ravel(), 3)[:, None]
        flat = [p.reshape(-1, p.shape[-1]) for p in parts]
        if scratch is not None and all(p.flags.c_contiguous for p in flat):
            Jw = _weighted_columns(flat, rows, active, scratch)
        else:
            J2 = state.J.reshape(-1, state.J.shape[-1])  # laid out whole
            if active.all():
                Jw = np.multiply(J2, rows)
            else:
                Jw = J2[:, np.nonzero(active)[0]]
                Jw *= rows
    if prior is not None:
        val, idx, slope = prior
        on = active[idx]  # a prior on a held unknown is a constant: no row
        val, idx, slope = val[on], idx[on], slope[on]
        if idx.size:
            rw = np.concatenate([rw, val])
            if Jw is not None:
                P = np.zeros((idx.size, int(np.sum(active))))
                cols = np.cumsum(active) - 1
                P[np.arange(idx.size), cols[idx]] = slope
                Jw = np.vstack([Jw, P])
    return rw, Jw


def _weighted_residuals(state: FitState, weights):
    """(sqrt of the weights (N, M), an unseen point's 0; the residuals times them, flat)."""
    sw = np.sqrt(np.where(np.isfinite(state.r).all(axis=2), weights, 0.0))
    return sw, (np.nan_to_num(state.r) * sw[:, :, None]).ravel()


#: rows per block of the column gather in :func:`_weighted_columns`
GATHER_BLOCK = 1024


def _weighted_columns(J2: list[np.ndarray], rows: np.ndarray, active: np.ndarray, scratch: dict) -> np.ndarray:
    """``J2[:, active] * rows`` into ``scratch``'s array, allocated once per Levenberg-Marquardt
    run (75 MB for 10,000 poses) rather than at every step, and laid out as the plain expression
    lays it out (column-major after a column gather, row-major without one): the products that
    follow (H = Jw^T Jw) take the same BLAS path and give the same numbers bit for bit. ``J2``:
    the 2-D Jacobian's parts side by side (FitState.parts), each part's columns written in place.
    The gather goes in blocks of GATHER_BLOCK rows, which stay in the cache (16 -> 11 ms for
    150,000 x 60 of 63 columns, 2026-11-25)."""
    every = bool(active.all())
    edges = np.cumsum([0] + [p.shape[1] for p in J2])
    shape = (J2[0].shape[0], int(edges[-1]) if every else int(np.count_nonzero(active)))
    key = "Jw" if every else "Jw_columns"
    out = scratch.get(key)
    if out is None or out.shape != shape:
        out = scratch[key] = np.empty(shape, order="C" if every else "F")
    if every:
        for part, lo, hi in zip(J2, edges[:-1], edges[1:]):
            np.multiply(part, rows, out=out[:, lo:hi])
        return out
    cols = np.nonzero(active)[0]
    at = np.searchsorted(cols, edges)  # cols[at[i]:at[i + 1]] lie in part i
    for k in range(0, shape[0], GATHER_BLOCK):
        for part, lo, a, b in zip(J2, edges, at[:-1], at[1:]):
            out[k:k + GATHER_BLOCK, a:b] = part[k:k + GATHER_BLOCK, cols[a:b] - lo]
    out *= rows
    return out


#: active unknowns from which :func:`_normal_equations` tries the sum point by point
#: (:func:`_gram_by_point`)
GRAM_BY_POINT_FROM = 256


def _gram_by_point(state: FitState, weights, active):
    """(rw, H, g) of :func:`_weighted`'s rows summed point by point: each point's rows (a marker's,
    a rigid body's channel's) on the columns that move it, where most columns move few points (a
    probe with each marker's own offsets: 378 of 460 unknowns on a two-armed tree with six
    markers, each moving one marker's rows). None with fewer than GRAM_BY_POINT_FROM active
    unknowns, or where the points' blocks would cost more than half the whole product. H and g
    are the whole product's to rounding (the sums run point by point)."""
    cols = np.flatnonzero(active)
    n = cols.size
    if n < GRAM_BY_POINT_FROM or not state.has_jacobian or state.J.ndim != 4:
        return None
    J = state.J
    N, P = J.shape[:2]
    sw, rw = _weighted_residuals(state, weights)
    # each point's columns: those with a nonzero entry on a row of nonzero weight (the weighted
    # column's nonzeros), found on the Jacobian's zero pattern; only they are gathered and weighted
    supports = []
    for p in range(P):
        seen = sw[:, p] != 0
        Jp = J[:, p] if seen.all() else J[:, p][seen]  # (rows weighed, 3, n_z)
        supports.append(np.flatnonzero(Jp.any(axis=(0, 1))[cols]))  # a float is true where != 0 (NaN too)
    if sum(s.size ** 2 for s in supports) > 0.5 * P * n * n:
        return None
    H, g = np.zeros((n, n)), np.zeros(n)
    r = rw.reshape(N, P, 3)
    for p, s in enumerate(supports):
        A = (J[:, p][:, :, cols[s]] * sw[:, p, None, None]).reshape(-1, s.size)
        H[np.ix_(s, s)] += A.T @ A
        g[s] += A.T @ r[:, p].ravel()
    return rw, H, g


#: active unknowns from which :func:`_normal_equations` tries the sum by runs of points
#: (:func:`_gram_by_runs`): below it the runs' gathers cost more than the flops they save
GRAM_BY_RUNS_FROM = 64


def _gram_by_runs(state: FitState, weights, active):
    """(rw, H, g) of :func:`_weighted`'s rows summed by runs of consecutive points that move on
    nearly the same columns (a tree's hand: its markers move on its arm's and the trunk's columns,
    not the other arm's), each run's rows on its own columns, one product each. A point's columns
    have a nonzero (or NaN) entry on one of its rows; a run takes the next point while their union
    is at most RUN_WIDENS wider than the wider of the two. None with fewer than GRAM_BY_RUNS_FROM
    active unknowns, or where the runs' products cost more than half the whole one's flops. H and
    g are the whole product's to rounding. Tried before :func:`_gram_by_point` (faster where both
    apply: a point a run, 262 of 364 columns, 3.1 -> 2.6 ms).

    A point's columns are read off the whole Jacobian (:func:`point_columns`), or, where the state
    knows its structure (FitState.structure), from the structure and the first pose
    (:func:`columns_by_structure`). The columns are taken from the Jacobian's parts
    (FitState.parts), which are not laid out whole for it."""
    parts, cols = state.parts, np.flatnonzero(active)
    n = cols.size
    if parts is None or parts[0].ndim != 4 or n < GRAM_BY_RUNS_FROM:
        return None
    N, P = parts[0].shape[:2]
    moves = columns_by_structure(parts, cols, state.structure)
    runs = runs_of_points(point_columns(state.J, cols) if moves is None else moves)
    if sum((p1 - p0) * s.size ** 2 for p0, p1, s in runs) > 0.5 * P * n * n:
        return None
    sw, rw = _weighted_residuals(state, weights)
    r, H, g = rw.reshape(N, P, 3), np.zeros((n, n)), np.zeros(n)
    for p0, p1, s in (run for run in runs if run[2].size):
        k = 3 * (p1 - p0)
        A = take(parts, cols[s], points=slice(p0, p1)).reshape(N * k, s.size)
        A *= np.repeat(sw[:, p0:p1].ravel(), 3)[:, None]
        H[np.ix_(s, s)] += A.T @ A
        g[s] += A.T @ r[:, p0:p1].ravel()
    return rw, H, g


def _normal_equations(state: FitState, weights, active, prior=None, scratch: dict | None = None):
    """(rw, H = Jw^T Jw, g = Jw^T rw) of :func:`_weighted` without keeping Jw: the prior rows,
    one unknown each, are added to H's diagonal and g directly. ``scratch``: see :func:`_weighted`.
    A large model whose columns each move few points is summed point by point
    (:func:`_gram_by_point`); one whose runs of points move on few of its columns, run by run
    (:func:`_gram_by_runs`)."""
    by_runs = _gram_by_runs(state, weights, active)
    if by_runs is not None:
        return _with_prior(*by_runs, active, prior)
    by_point = _gram_by_point(state, weights, active)
    if by_point is not None:
        return _with_prior(*by_point, active, prior)
    rw, Jw = _weighted(state, weights, active, scratch=scratch)
    H = Jw.T @ Jw
    g = Jw.T @ rw
    return _with_prior(rw, H, g, active, prior)


def _normal_equations_blocked(problem: CalibrationProblem, z, state: FitState, weights, active, prior=None):
    """:func:`_normal_equations` of a problem solved block by block (``problem.row_block`` poses
    at a time, :meth:`CalibrationProblem.evaluate_blocks`): H and g summed over the blocks, so that
    the memory is one block's Jacobian whatever the poses; ``state``: the residuals at ``z``."""
    rw, _ = _weighted(state, weights, active)
    n = int(np.count_nonzero(active))
    H, g = np.zeros((n, n)), np.zeros(n)
    for rows, part in problem.evaluate_blocks(z, problem.row_block):
        rb, Jb = _weighted(part, weights[rows], active)
        H += Jb.T @ Jb
        g += Jb.T @ rb
    return _with_prior(rw, H, g, active, prior)


def weighted_factor(problem: CalibrationProblem, z, state: FitState, weights, active, prior=None) -> np.ndarray:
    """An upper-triangular R (n_active, n_active) with R^T R = Jw^T Jw, Jw the weighted Jacobian
    of :func:`_weighted` at ``z`` (``state``: the residuals there; the prior rows stacked below
    where given), from the blocks of :meth:`CalibrationProblem.evaluate_blocks` (the R factor of
    each block stacked on the last R: QR of n_active + a block's rows at a time). R has Jw's
    column inner products, singular values and spans; it stands in for Jw where a problem is
    solved block by block."""
    n = int(np.count_nonzero(active))
    R = np.zeros((0, n))
    for rows, part in problem.evaluate_blocks(z, problem.row_block):
        _, Jb = _weighted(part, weights[rows], active)
        R = np.linalg.qr(np.vstack([R, Jb]), mode="r")
    if prior is not None:
        val, idx, slope = prior
        on = active[idx]  # a prior on a held unknown is a constant: no row
        if on.any():
            P = np.zeros((int(on.sum()), n))
            P[np.arange(P.shape[0]), (np.cumsum(active) - 1)[idx[on]]] = slope[on]
            R = np.linalg.qr(np.vstack([R, P]), mode="r")
    return R


def _with_prior(rw, H, g, active, prior):
    """The prior rows, one unknown each, added to H's diagonal and g, their values to rw."""
    if prior is not None:
        val, idx, slope = prior
        on = active[idx]
        val, idx, slope = val[on], idx[on], slope[on]
        if idx.size:
            cols = (np.cumsum(active) - 1)[idx]
            np.add.at(H, (cols, cols), slope * slope)
            np.add.at(g, cols, slope * val)
            rw = np.concatenate([rw, val])
    return rw, H, g


def levenberg_marquardt(problem: CalibrationProblem, z0, active, weights, max_iter=60, ftol=1e-10, xtol=1e-10,
                        progress: Progress | None = None, stage: str = "iteration", it0: int = 0,
                        jacobian_at_end: bool = True) -> LMResult:
    """Minimise 1/2 sum_nm w_nm |r_nm(z)|^2 over z[active], from z0 (Marquardt-scaled LM).

    A trial step is judged on residuals alone; the Jacobian is evaluated only where a step is
    accepted and another iteration follows, or, with ``jacobian_at_end``, at the last accepted
    step too (the problem keeps its last evaluation, so the next robust round, the
    identifiability and the covariance start from it without evaluating again). A caller that
    reads only the solution and its residuals (a held-out refit) passes False: the result's
    state then has no Jacobian, its residuals are the same."""
    with blas_threads(1):
        return _levenberg_marquardt(problem, z0, active, weights, max_iter, ftol, xtol, progress, stage, it0,
                                    jacobian_at_end)


def _levenberg_marquardt(problem, z0, active, weights, max_iter, ftol, xtol, progress, stage, it0,
                         jacobian_at_end=True) -> LMResult:
    z = np.array(z0, float)
    active = np.asarray(active, bool)
    blocked = problem.row_block is not None  # the normal equations summed block by block
    st = problem.evaluate(z, with_jac=not blocked)
    scratch: dict = {}  # the weighted Jacobian's array, reused by every step of this run
    if blocked:
        rw, H, g = _normal_equations_blocked(problem, z, st, weights, active, problem.prior_rows(z))
    else:
        rw, H, g = _normal_equations(st, weights, active, problem.prior_rows(z), scratch)
    cost = 0.5 * rw @ rw
    lam = 1e-5
    converged = False
    it = 0
    costs, steps = [cost], []  # for the window judgement of a run that meets no per-step rule
    for it in range(1, max_iter + 1):
        D = np.maximum(np.diag(H), 1e-12 * max(1.0, np.max(np.diag(H))))
        accepted = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(H + lam * np.diag(D), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            z_new = z.copy()
            z_new[active] += step
            st_new = problem.evaluate(z_new, with_jac=False)
            rw_new, _ = _weighted(st_new, weights, active, problem.prior_rows(z_new))
            cost_new = 0.5 * rw_new @ rw_new
            # a step that loses poses (forward kinematics fails there) only looks cheaper
            lost = np.sum(st_new.converged) < np.sum(st.converged)
            if np.isfinite(cost_new) and cost_new <= cost and not lost:
                accepted = True
                break
            lam *= 10
        if not accepted:
            converged = True  # no descent direction left: at a minimum to working precision
            break
        small_step = np.linalg.norm(step * np.sqrt(D)) <= xtol * (np.linalg.norm(rw) + xtol)
        small_gain = (cost - cost_new) <= ftol * max(cost, 1e-300)
        done = small_step or small_gain or it == max_iter
        if not done or jacobian_at_end:  # the Jacobian: for the next iteration or round
            st_new = problem.evaluate(z_new, with_jac=not blocked)
        if not done and blocked:
            rw_new, H, g = _normal_equations_blocked(problem, z_new, st_new, weights, active, problem.prior_rows(z_new))
        elif not done:
            rw_new, H, g = _normal_equations(st_new, weights, active, problem.prior_rows(z_new), scratch)
        z, st, rw, cost = z_new, st_new, rw_new, cost_new
        costs, steps = costs[-WINDOW:] + [cost], steps[-(WINDOW - 1):] + [step]
        lam = max(lam / 10, 1e-12)
        if progress is not None:
            n_w = max(1.0, float(np.sum(weights * np.isfinite(st.r).all(axis=2))))
            progress(stage, {"iteration": it0 + it, "rms": float(np.sqrt(2 * cost / n_w)), "lambda": lam})
        if small_step or small_gain:
            converged = True
            break
    window = None
    if not converged and len(steps) == WINDOW:  # the iterations ran out: judged on the last WINDOW
        n_w = int(np.sum((weights > 0) & np.isfinite(st.r).all(axis=2)))
        window = judge_window(costs, steps, H, 3 * n_w - int(np.sum(active)),
                              [problem.names[k] for k in np.flatnonzero(active)])
        converged = window.settled
    return LMResult(z, st, weights, it, converged, cost, window)


def robust_fit(problem: CalibrationProblem, z0, active, robust: bool = True, max_iter: int = 60,
               progress: Progress | None = None, stage: str = "iteration") -> LMResult:
    """LM with iteratively reweighted Huber weights, then hard rejection beyond REJECT_K sigma.

    Weights start from ``problem.base_weights`` (the samples averaged into each marker position,
    relative to the median); errors are compared in units of their own expected size.
    """
    vis = problem.visible
    base = problem.base_weights
    weights = base.copy()
    res = levenberg_marquardt(problem, z0, active, weights, max_iter, progress=progress, stage=stage)
    if not robust:
        return res
    total_it = res.iterations

    def standardized(state):
        return np.linalg.norm(state.r, axis=2) * np.sqrt(base)

    for _ in range(3):  # Huber rounds
        d = standardized(res.state)
        sigma = robust_sigma(d[vis])
        if not np.isfinite(sigma) or sigma <= 0:
            break
        c = HUBER_K * sigma
        new_w = np.where(vis & np.isfinite(d), base * np.minimum(1.0, c / np.maximum(d, 1e-300)), 0.0)
        res = levenberg_marquardt(problem, res.z, active, new_w, max_iter, progress=progress, stage=stage, it0=total_it)
        total_it += res.iterations
        if np.max(np.abs(new_w - weights) / np.maximum(base, 1e-300)) < 0.05:
            weights = new_w
            break
        weights = new_w
    keep_prev, recentred = None, False
    for _ in range(3):  # hard rejection rounds: inliers get full weight (no efficiency lost)
        d = standardized(res.state)
        sigma = robust_sigma(d[vis])
        keep = vis & np.isfinite(d) & (d <= REJECT_K * sigma)
        if not recentred:  # once: a marker that would lose most of its observations is misplaced
            recentred = True
            z = _recentred_markers(problem, res, keep, active)
            if z is not None:
                state = problem.evaluate(z, with_jac=problem.row_block is None)
                res = LMResult(z, state, res.weights, res.iterations, res.converged, res.cost)
                d = standardized(state)
                keep = vis & np.isfinite(d) & (d <= REJECT_K * sigma)
        if keep_prev is not None and np.array_equal(keep, keep_prev):
            break
        res = levenberg_marquardt(problem, res.z, active, np.where(keep, base, 0.0), max_iter, progress=progress,
                                  stage=stage, it0=total_it)
        total_it += res.iterations
        keep_prev = keep
    res.iterations = total_it
    return res


def _recentred_markers(problem: CalibrationProblem, res: LMResult, keep: np.ndarray,
                       active: np.ndarray) -> np.ndarray | None:
    """``res.z`` with each marker that the rejection would leave with fewer than half of its seen
    observations (at least 8) moved to the median, axis by axis, of where each of its
    observations puts it (its active coordinates); None when no marker would.

    Rejection is for outliers: a marker that loses most of its observations is misplaced, not
    noisy. A marker that slips partway through a session sits, after the least-squares start and
    the Huber rounds, between its two places, where every one of its observations can lie beyond
    REJECT_K sigma and rejection would leave it there, at neither place. From the median, the
    larger share of its observations is kept and the rest rejected (and counted)."""
    blocked = problem.row_block is not None  # a marker's columns then come block by block, if asked
    state = res.state if res.state.has_jacobian or blocked else problem.evaluate(res.z, with_jac=True)
    r = state.r
    seen_all = problem.visible[:, :problem.M] & np.isfinite(r[:, :problem.M]).all(axis=2)
    z, moved = res.z.copy(), False
    for m in range(problem.M):
        seen = seen_all[:, m]
        if seen.sum() < 8 or keep[seen, m].sum() >= 0.5 * seen.sum():
            continue
        cols = np.arange(problem.i_m.start + 3 * m, problem.i_m.start + 3 * m + 3)
        if not active[cols].any():
            continue
        if state.has_jacobian:
            Jm = state.J[seen, m][:, :, cols]  # (n, 3, 3): the predicted marker against its place
        else:
            Jm = np.empty((problem.N, 3, 3))
            for rows, part in problem.evaluate_blocks(res.z, problem.row_block):
                Jm[rows] = part.J[:, m][:, :, cols]
            Jm = Jm[seen]
        step = -np.einsum("nij,nj->ni", np.linalg.pinv(Jm), r[seen, m])  # where each observation puts it
        shift = np.median(step, axis=0)
        z[cols[active[cols]]] += shift[active[cols]]
        moved = True
    return z if moved else None


def _rms(state: FitState, weights) -> float:
    d2 = np.sum(np.nan_to_num(state.r) ** 2, axis=2)
    keep = (weights > 0) & np.isfinite(state.r).all(axis=2)
    return float(np.sqrt(np.mean(d2[keep]))) if keep.any() else float("nan")


def kfold(problem: CalibrationProblem, z, active, folds: int, robust: bool = True, max_iter: int = 60,
          progress: Progress | None = None) -> dict:
    """K-fold held-out point RMS (m): refit on K-1 folds from z, predict the left-out poses.

    Poses are assigned to folds in an interleaved order (pose n to fold n mod K) so every fold
    spans the session.
    """
    poses = problem.poses
    N = poses.n_poses
    if folds > N:
        raise BadInput(f"folds: {folds} is more than the {N} poses")
    fold_of = np.arange(N) % folds
    errs = np.full(problem.visible.shape, np.nan)  # markers, then rigid bodies' channels
    per_fold = []
    for k in range(folds):
        train = poses.subset(fold_of != k)
        test = poses.subset(fold_of == k)
        sub = CalibrationProblem(problem.spec, train, problem.terms)
        sub.prior_center, sub.prior_scale = problem.prior_center, problem.prior_scale
        sub.half_width = problem.half_width
        sub.body_rho, sub.rho_source = problem.body_rho, problem.rho_source
        sub.row_block = problem.row_block
        fit = robust_fit(sub, z, active, robust, max_iter)
        st = sub.evaluate(fit.z, with_jac=False, poses=test)
        d = np.linalg.norm(st.r, axis=2)
        errs[fold_of == k] = d
        per_fold.append(float(np.sqrt(np.nanmean(d ** 2))))
        if progress is not None:
            progress("fold", {"fold": k + 1, "folds": folds, "rms": per_fold[-1]})
    d = errs[np.isfinite(errs)]
    med = np.median(d) if d.size else np.nan
    inl = d[d <= REJECT_K * med / MAXWELL_MEDIAN] if d.size else d
    return {"folds": folds, "rms": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
            "rms_inliers": float(np.sqrt(np.mean(inl ** 2))) if inl.size else float("nan"),
            "rms_per_fold": per_fold}
