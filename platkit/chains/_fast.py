"""The servo's fast paths for one task on one chain: the step computed with pinocchio's own
Jacobian and a dense solve (``_fast_step``), and a whole attempt run in compiled C
(``_compiled_attempt``, :mod:`platkit.chains.native_servo`) or in that numpy loop
(``_fast_attempt``); :class:`platkit.chains.servo.Servo` takes them where its general path would
give the same steps."""
from __future__ import annotations

import math
import time
import weakref

import numpy as np
import pinocchio as pin

from platkit.chains.chain import KinematicChain
from platkit.chains.native_servo import (
    CONVERGED,
    ITERATION_CAP,
    LINE_SEARCH_FAILED,
    STALLED,
    TIME_CAP,
    CompiledServo,
)
from platkit.chains.solve import StepInfo
from platkit.chains.tasks import ServoResult

_known: weakref.WeakKeyDictionary[KinematicChain, dict] = weakref.WeakKeyDictionary()


def _per_chain(chain: KinematicChain) -> dict:
    """What servos of one chain share (their active joints, the fast case's bounds), by key: a
    servo is made per target, and these took most of its making."""
    known = _known.get(chain)
    if known is None:
        known = _known[chain] = {}
    elif len(known) > 256:  # keys without end (many frames, locked sets, dt): keep it small
        known.clear()
    return known


def _clip(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """np.clip(x, lower, upper) for lower <= upper, without its wrapper's microseconds."""
    return np.minimum(np.maximum(x, lower), upper)



class FastPath:
    """The fast single-task methods of :class:`platkit.chains.servo.Servo` (a base class of it: they
    read and write the servo's own state)."""

    def _fast_case(self) -> dict | None:
        """What the common case needs, or None: one task in the world frame and basis, the
        pseudo-inverse solver, no secondary cost, equal joint weights. Then the placement, the
        error and the Jacobian come from pinocchio in one call each (the same quantities as
        :meth:`KinematicChain.relative_placement` / ``relative_jacobian``, which assemble them
        joint by joint in Python), and a step that hits no position limit is the damped
        pseudo-inverse of that one level directly (a target took 15-60 times
        pinocchio's own damped least squares)."""
        o, c = self.options, self.chain
        if (len(self.tasks) != 1 or self.ref_ids[0] != 0 or self.tasks[0].basis != "reference" or o.solver != "pinv"
                or o.secondary != "none" or (o.joint_weights is not None and np.any(self.joint_weights != 1.0))):
            return None
        # the bounds depend on the chain, the active joints and dt only: made once per chain
        known = _per_chain(c)
        key = ("fast", self.active.tobytes(), o.dt)
        bounds = known.get(key)
        if bounds is None:
            rate_step = np.where(np.isfinite(c.rate), c.rate * o.dt, np.inf)
            bounds = known[key] = {
                "model": c.model,
                # pinocchio's q is theta itself unless a continuous joint is stored as (cos, sin)
                "direct": c.model.nq == c.model.nv,  # every joint of a chain has one degree of freedom
                "cols": np.flatnonzero(self.active), "every_joint": bool(self.active.all()),
                # lower_active - theta: the room below for an active joint, +inf (then 0) for a locked one
                "lower_active": np.where(self.active, c.lower, np.inf),
                "upper_active": np.where(self.active, c.upper, -np.inf),
                "rate_step": rate_step, "minus_rate_step": -rate_step}
        task = self.tasks[0]
        rows = task.weights > 0
        unit_weights = bool(np.all(task.weights == 1.0))
        every_row = unit_weights or bool(rows.all())
        return {**bounds, "data": None, "fid": self.frame_ids[0],  # data: made by _fast_data on first use
                "target_t": task.target[:3, 3].copy(), "target_R": task.target[:3, :3].copy(),
                "rows": rows, "sw": np.ones(6) if unit_weights else np.sqrt(task.weights[rows]),
                "unit_weights": unit_weights, "all_active": bounds["every_joint"] and unit_weights,
                "plain_command": o.gain == 1.0 and every_row}

    def _fast_data(self) -> pin.Data:
        """Pinocchio's work data for the fast case, made on first use and shared by the servos of
        a chain (the compiled loop needs it only to explain a failure; making it costs 15 us)."""
        f = self._fast
        if f["data"] is None:
            # one per chain, as the chain's own (KinematicChain.data): each use computes and reads at once
            known = _per_chain(self.chain)
            data = known.get("fast data")
            if data is None:
                data = known["fast data"] = f["model"].createData()
            f["data"] = data
        return f["data"]

    def _fast_q(self, theta: np.ndarray) -> np.ndarray:
        return theta if self._fast["direct"] else self.chain.pin_configuration(theta)

    def _fast_error(self, theta: np.ndarray) -> np.ndarray:
        """E (6,) = (t_U - t_P, rotvec(R_U R_P^T)) as :func:`pose_error` in the reference basis."""
        f = self._fast
        data = self._fast_data()
        pin.forwardKinematics(f["model"], data, self._fast_q(theta))
        M = pin.updateFramePlacement(f["model"], data, f["fid"])
        E = np.empty(6)
        E[:3] = f["target_t"] - M.translation
        E[3:] = pin.log3(f["target_R"] @ M.rotation.T)
        return E

    def _fast_jacobian(self, theta: np.ndarray) -> np.ndarray:
        """J (6, n): the frame origin's twist (v, omega) in world axes (LOCAL_WORLD_ALIGNED)."""
        f = self._fast
        return pin.computeFrameJacobian(f["model"], self._fast_data(), self._fast_q(theta), f["fid"],
                                        pin.LOCAL_WORLD_ALIGNED)

    def _fast_step(self, theta: np.ndarray, E: np.ndarray):
        """:func:`solve_pinv`'s step for this one level, without its generality (levels, joint
        weights, a secondary step): the damped pseudo-inverse by SVD, a joint that would cross
        a position limit clamped there and the rest re-solved, then the uniform scaling to the
        rate limits. Returns (dq (n,), StepInfo). Each numpy call on these small arrays costs
        microseconds, so the bounds are prepared once (:meth:`_fast_case`) and the common case
        (every component weighted 1, no joint at a limit) skips what it does not need."""
        o, c, f = self.options, self.chain, self._fast
        if f["plain_command"]:  # gain 1, every component: _commanded's numbers without its products
            x, y, z, rx, ry, rz = E.tolist()
            lin = math.sqrt(x * x + y * y + z * z)
            ang = math.sqrt(rx * rx + ry * ry + rz * rz)
            scale = min(1.0, o.max_linear_step / lin if lin > 0 else math.inf,
                        o.max_angular_step / ang if ang > 0 else math.inf)
            e = E if scale == 1.0 else E * scale
        else:
            e = self._commanded(E, self.tasks[0].weights)
        J = self._fast_jacobian(theta)
        if f["unit_weights"]:
            Jw, ew = J, e
        else:
            Jw = J[f["rows"]] * f["sw"][:, None]
            ew = f["sw"] * e[f["rows"]]
        lower_step = np.minimum(f["lower_active"] - theta, 0.0)  # 0 for a joint that may not move
        upper_step = np.maximum(f["upper_active"] - theta, 0.0)
        free = None
        fixed = None
        info = StepInfo()
        first = None  # the first pass's SVD, for the loop to reuse
        if f["all_active"]:
            # the first pass of the loop below in a few calls: every joint free, a full-rank J,
            # no joint crossing a limit; anything else goes through the loop (same numbers)
            U, sv, Vt = first = np.linalg.svd(Jw, full_matrices=False)
            smin = float(sv[-1])
            if smin > 1e-10 * max(1.0, float(sv[0])):
                lam2 = o.damping.factor(smin, math.sqrt(float(ew @ ew)))
                dq = Vt.T @ (sv / (sv * sv + lam2) * (U.T @ ew))
                if not ((dq > upper_step + 1e-15).any() or (dq < lower_step - 1e-15).any()):
                    info.sigma_min, info.damping = smin, math.sqrt(lam2)
                    return self._fast_rate_limited(_clip(dq, lower_step, upper_step), lower_step, upper_step, info)
        for _ in range(c.n + 1):
            if free is None:  # first pass: every active joint free, nothing fixed
                cols, r = f["cols"], ew
                dq = np.zeros(c.n)
            else:
                cols = np.flatnonzero(free)
                dq = fixed.copy()
                r = ew - Jw @ fixed
            if cols.size:
                if free is None and first is not None:
                    U, sv, Vt = first  # every column: the SVD above
                else:
                    U, sv, Vt = np.linalg.svd(Jw[:, cols], full_matrices=False)
                keep = sv > 1e-10 * max(1.0, float(sv[0]) if sv.size else 0.0)
                everything = bool(keep.all())
                info.sigma_min = float(sv[-1]) if everything else (float(sv[keep][-1]) if keep.any() else 0.0)
                lam2 = o.damping.factor(info.sigma_min, float(np.linalg.norm(r)))
                info.damping = math.sqrt(lam2)
                if everything:
                    inv = sv / (sv * sv + lam2)
                else:
                    inv = np.zeros_like(sv)
                    inv[keep] = sv[keep] / (sv[keep] ** 2 + lam2)
                dq[cols] += Vt.T @ (inv * (U.T @ r))
            high, low = dq > upper_step + 1e-15, dq < lower_step - 1e-15
            if not (high.any() or low.any()):
                break
            if free is None:
                free, fixed = self.active.copy(), np.zeros(c.n)
            over = free & (high | low)
            if not over.any():
                break
            excess = np.maximum(dq - upper_step, lower_step - dq)
            excess[~over] = -np.inf
            worst = int(np.argmax(excess))
            fixed[worst] = min(max(dq[worst], lower_step[worst]), upper_step[worst])
            free[worst] = False
            info.clamped.append(worst)
        return self._fast_rate_limited(_clip(dq, lower_step, upper_step), lower_step, upper_step, info)

    def _fast_rate_limited(self, dq: np.ndarray, lower_step: np.ndarray, upper_step: np.ndarray, info: StepInfo):
        """The step (n,) scaled uniformly to the rate limits and clipped to both bounds, and ``info``."""
        if not self.options.use_rate_limits:
            return dq, info
        f = self._fast
        rate_step = f["rate_step"]
        # a joint that does not move allows any scale (rate / 1e-300 is beyond 1)
        info.rate_scale = min(1.0, float(np.min(rate_step / np.maximum(np.abs(dq), 1e-300)))) if dq.size else 1.0
        if info.rate_scale < 1.0:
            dq = dq * info.rate_scale
        return _clip(dq, np.maximum(lower_step, f["minus_rate_step"]), np.minimum(upper_step, rate_step)), info

    # ------------------------------------------------------------------ errors and Jacobians

    def _compiled_attempt(self, compiled: CompiledServo, theta: np.ndarray, start: float) -> ServoResult:
        """:meth:`_fast_attempt` by the compiled loop (:mod:`platkit.chains.native_servo`): the
        same steps, stopping rules and result; the time cap is checked between chunks of
        iterations, the reasons worded here."""
        o = self.options
        work = compiled.start(theta)
        state = work[18 + self.chain.n:29 + self.chain.n]  # a view: the chunks update it
        rows = [theta.reshape(1, -1)]
        history: list[float] = []
        first = True
        while True:
            time_over = time.perf_counter() - start > o.max_seconds
            code, E, merit, steps, merits, norms = compiled.chunk(work, first, time_over)
            if first:
                history.append(float(state[10]))
                first = False
            if steps.shape[0]:
                rows.append(steps)
                history.extend(merits.tolist())
            if code not in (CONVERGED, LINE_SEARCH_FAILED, STALLED, ITERATION_CAP, TIME_CAP):
                continue  # a chunk ended, the attempt goes on
            break
        iterations = int(state[0])
        theta = work[18:18 + self.chain.n].copy()
        reason = ""
        if code in (LINE_SEARCH_FAILED, STALLED):
            reason = self.diagnose(theta, [E], stalled=True)
        elif code in (ITERATION_CAP, TIME_CAP):
            reason = self._capped(iterations if code == ITERATION_CAP else 0, start)
            why = self.diagnose(theta, [E], stalled=False)
            reason = reason + ("; " + why if why else "")
        pos, rot, bpos, brot = norms  # Servo._norms of E and of the best E, taken in C
        return ServoResult(theta=theta, converged=code == CONVERGED, iterations=iterations, position_errors=[pos],
                           rotation_errors=[rot], path=np.vstack(rows), merit_history=history, reason=reason,
                           best_position_errors=[bpos], best_rotation_errors=[brot],
                           seconds=time.perf_counter() - start)

    def _fast_attempt(self, theta: np.ndarray, start: float) -> ServoResult:
        """:meth:`_attempt` for the common case of :meth:`_fast_case` (one level of one task, no
        secondary cost): the same steps, line search, stall test and result, with the merit a
        plain float and no per-level bookkeeping (a step's Python overhead was most of its time)."""
        o, c = self.options, self.chain
        weights = self.tasks[0].weights
        lower, upper = c.lower, c.upper
        E = self._fast_error(theta)
        merit = float(np.dot(weights, E**2))
        path = [theta.copy()]
        history = [merit]
        best_merit, best_E = merit, E
        stall_ref, stall_at = merit, 0
        floor = 1e-2 * (o.tol_position**2 + o.tol_rotation**2)
        reason = ""
        iterations = 0
        pos, rot = self._norms([E])
        converged = self._done(pos, rot)
        while not converged:
            reason = self._capped(iterations, start)
            if reason:
                break
            dq, _info = self._fast_step(theta, E)
            accepted = False
            alpha = 1.0
            better_than = merit * (1.0 - 1e-12)  # Servo._better with one level
            for _ in range(12):
                trial = _clip(theta + alpha * dq, lower, upper)
                trial_E = self._fast_error(trial)
                trial_merit = float(np.dot(weights, trial_E**2))
                if trial_merit < better_than:
                    accepted = True
                    break
                alpha *= 0.5
            iterations += 1
            if not accepted:
                reason = self.diagnose(theta, [E], stalled=True)
                break
            theta, E, merit = trial, trial_E, trial_merit  # trial is a new array: path may keep it
            path.append(theta)
            history.append(merit)
            if merit < best_merit:
                best_merit, best_E = merit, E
            pos, rot = self._norms([E])
            converged = self._done(pos, rot)
            if merit < (1.0 - 1e-3) * stall_ref and stall_ref > floor:
                stall_ref, stall_at = merit, iterations
            elif iterations - stall_at >= o.stall_iterations and not converged:
                reason = self.diagnose(theta, [E], stalled=True)
                break
        if not converged and reason.startswith("stopped at"):
            why = self.diagnose(theta, [E], stalled=False)
            reason = reason + ("; " + why if why else "")
        bpos, brot = self._norms([best_E])
        return ServoResult(theta=theta, converged=converged, iterations=iterations, position_errors=pos,
                           rotation_errors=rot, path=np.array(path), merit_history=history, reason=reason,
                           best_position_errors=bpos, best_rotation_errors=brot,
                           seconds=time.perf_counter() - start)
