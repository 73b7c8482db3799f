"""The tracking servo (Sorokin 2017, "building the tracking system") and the virtual servo that
follows a dense Cartesian trajectory ("linear interpolation").

For every controlled link (a *task*) the error is E = P^-1 U read as the 6-vector (r, rho):
translation and rotation vector between the link's placement P and its set point U. The joint
increments are chosen so that the link's twist is collinear with E (the inverse velocity
problem of :mod:`platkit.chains.solve`); the step's length is a fraction of |E| (gain <= 1:
aperiodic regulation, no overshoot), capped by the joints' rate limits without changing its
direction. A step that would increase the error is halved, so the error decreases monotonically.

Tasks may name a ``frame``: the set point is then given in the frame of another link, which may
itself move (control in a moving local frame); several tasks with a shared trunk (both arms of a
humanoid, the fingers of a hand) are solved jointly with a stacked Jacobian, by weight within a
priority level and by strict priority between levels.

What the servo is asked and answers (Task, ServoOptions, ServoResult, the failure messages) is
in :mod:`platkit.chains.tasks`; following a dense trajectory in :mod:`platkit.chains.trajectory`.

Units: metres and radians; time in seconds (``dt`` is the virtual servo's period).
"""
from __future__ import annotations

import math
import time
from typing import Sequence

import numpy as np

from platkit.chains._fast import FastPath, _per_chain
from platkit.chains.chain import KinematicChain
from platkit.chains.native_servo import (
    CompiledServo,
)
from platkit.chains.solve import (
    Level,
    joint_limit_gradient,
    manipulability,
    mid_range_gradient,
    solve_lp,
    solve_pinv,
)
from platkit.chains.tasks import (
    ServoOptions,
    ServoResult,
    Task,
    failure_message,
)
from platkit.chains.transforms import pose_error, rotation_action
from platkit.errors import BadInput, OutOfWorkspace


class Servo(FastPath):
    """The tracking servo over ``tasks`` of one chain; :meth:`run` from a configuration."""

    def __init__(self, chain: KinematicChain, tasks: Sequence[Task], options: ServoOptions | None = None):
        if not tasks:
            raise BadInput("the servo needs at least one task (a link and its target)")
        self.chain = chain
        self.tasks = list(tasks)
        self.options = options or ServoOptions()
        self.options.check()
        self.frame_ids = [chain.frame_id(t.link) for t in self.tasks]
        self.ref_ids = [chain.frame_id(t.frame) for t in self.tasks]
        for t, f, r in zip(self.tasks, self.frame_ids, self.ref_ids):
            if f == r:
                raise BadInput(f"task {t.link!r}: the link cannot be its own reference frame")
        unknown = [n for n in self.options.locked if n not in chain.joint_names]
        if unknown:
            raise BadInput(f"locked joints not in the chain: {', '.join(unknown)}; joints: {', '.join(chain.joint_names)}")
        known = _per_chain(chain)
        key = ("active", tuple(self.frame_ids), tuple(self.ref_ids), tuple(self.options.locked))
        active = known.get(key)
        if active is None:
            active = np.zeros(chain.n, bool)
            for f, r in zip(self.frame_ids, self.ref_ids):
                for jt in chain.supporting_joints(f) + (chain.supporting_joints(r) if r else []):
                    active[jt.column] = True
            for name in self.options.locked:
                active[chain.joint_names.index(name)] = False
            if not np.any(active):
                raise BadInput("no joint moves the controlled link(s): " + ", ".join(t.link for t in self.tasks))
            known[key] = active
        self.active = active.copy()
        if self.options.joint_weights is None:
            w = np.ones(chain.n)
        else:
            w = np.asarray(self.options.joint_weights, float)
            if w.shape != (chain.n,) or np.any(w <= 0):
                raise BadInput(f"joint weights must be {chain.n} positive numbers")
        self.joint_weights = w
        self._fast = None
        self._fast = self._fast_case()
        self._compiled: CompiledServo | None = None
        #: run the one-world-target case by the compiled loop where a C compiler is there
        #: (False: the Python loop, e.g. to compare the two)
        self.compile = True

    # ------------------------------------------------------------------ one world target, fast

    def task_error(self, theta: np.ndarray, k: int) -> np.ndarray:
        """E (6,) of task k in its basis (m, rad)."""
        if self._fast is not None:
            return self._fast_error(theta)
        task = self.tasks[k]
        P = self.chain.relative_placement(theta, self.frame_ids[k], self.ref_ids[k])
        return pose_error(P, task.target, "local" if task.basis == "local" else "reference")

    def task_jacobian(self, theta: np.ndarray, k: int) -> np.ndarray:
        """J (6, n) of task k in its basis."""
        if self._fast is not None:
            return self._fast_jacobian(theta)
        task = self.tasks[k]
        J = self.chain.relative_jacobian(theta, self.frame_ids[k], self.ref_ids[k])
        if task.basis == "local":
            R = self.chain.relative_placement(theta, self.frame_ids[k], self.ref_ids[k])[:3, :3]
            J = rotation_action(R.T) @ J
        return J

    def errors(self, theta: np.ndarray) -> list[np.ndarray]:
        if self._fast is not None:
            return [self._fast_error(theta)]
        return [self.task_error(theta, k) for k in range(len(self.tasks))]

    def merit(self, errors: list[np.ndarray]) -> float:
        """The weighted squared error summed over all tasks (m^2 + rad^2)."""
        if len(self.tasks) == 1:
            return float(np.dot(self.tasks[0].weights, errors[0] ** 2))
        return float(sum(np.sum(t.weights * E**2) for t, E in zip(self.tasks, errors)))

    def level_merits(self, errors: list[np.ndarray]) -> np.ndarray:
        """The weighted squared error of each priority level, most important first."""
        if len(self.tasks) == 1:
            return np.array([float(np.dot(self.tasks[0].weights, errors[0] ** 2))])
        levels = sorted({t.priority for t in self.tasks})
        out = np.zeros(len(levels))
        for t, E in zip(self.tasks, errors):
            out[levels.index(t.priority)] += np.sum(t.weights * E**2)
        return out

    def _better(self, trial: np.ndarray, current: np.ndarray) -> bool:
        """Lexicographic progress over the priority levels: a level may not get worse (beyond a
        hair under the tolerance) for the sake of a later one."""
        o = self.options
        floor = 1e-2 * (o.tol_position**2 + o.tol_rotation**2)
        for a, b in zip(trial, current):
            if a < b * (1.0 - 1e-12):
                return True
            if a > max(b * (1.0 + 1e-9), floor):
                return False
        return False

    def _norms(self, errors: list[np.ndarray]) -> tuple[list[float], list[float]]:
        if len(self.tasks) == 1 and np.all(self.tasks[0].weights > 0):
            x, y, z, rx, ry, rz = errors[0].tolist()
            return [math.sqrt(x * x + y * y + z * z)], [math.sqrt(rx * rx + ry * ry + rz * rz)]
        pos, rot = [], []
        for t, E in zip(self.tasks, errors):
            sel = t.weights > 0
            pos.append(float(np.linalg.norm(E[:3][sel[:3]])))
            rot.append(float(np.linalg.norm(E[3:][sel[3:]])))
        return pos, rot

    def _capped(self, iterations: int, start: float) -> str:
        """Why an attempt stops here (the iteration or the time cap), or '' to go on."""
        o = self.options
        if iterations >= o.max_iterations:
            return f"stopped at the iteration cap ({o.max_iterations})"
        if time.perf_counter() - start > o.max_seconds:
            return f"stopped at the time cap ({o.max_seconds:g} s)"
        return ""

    def _done(self, pos, rot) -> bool:
        o = self.options
        return all(p <= o.tol_position for p in pos) and all(r <= o.tol_rotation for r in rot)

    # ------------------------------------------------------------------ one step

    def _commanded(self, E: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """gain * E, shortened (direction kept) so the commanded twist respects the step caps."""
        o = self.options
        e = o.gain * E * (weights > 0)
        x, y, z, rx, ry, rz = e.tolist()  # six numbers: plain floats are faster than numpy here
        lin = math.sqrt(x * x + y * y + z * z)
        ang = math.sqrt(rx * rx + ry * ry + rz * rz)
        scale = min(1.0, o.max_linear_step / lin if lin > 0 else math.inf, o.max_angular_step / ang if ang > 0 else math.inf)
        return e * scale

    def secondary_value(self, theta: np.ndarray) -> float:
        """The secondary cost H(theta) being minimised (the negated measure for manipulability)."""
        o = self.options
        c = self.chain
        ok = self.active & np.isfinite(c.lower) & np.isfinite(c.upper) & (c.upper > c.lower)
        span = c.upper[ok] - c.lower[ok]
        if o.secondary == "mid_range":
            return float(0.5 * np.sum(((theta[ok] - 0.5 * (c.upper[ok] + c.lower[ok])) / span) ** 2))
        if o.secondary == "joint_limits":
            a = np.maximum(c.upper[ok] - theta[ok], 1e-9 * span)
            b = np.maximum(theta[ok] - c.lower[ok], 1e-9 * span)
            return float(np.sum(span**2 / (4.0 * a * b)))
        if o.secondary == "manipulability":
            return -manipulability(self.task_jacobian(theta, 0)[self.tasks[0].weights > 0])
        return 0.0

    def secondary_gradient(self, theta: np.ndarray) -> np.ndarray:
        """dH/dtheta (n,) over the active joints (zero elsewhere)."""
        o = self.options
        c = self.chain
        if o.secondary == "mid_range":
            g = mid_range_gradient(theta, c.lower, c.upper)
        elif o.secondary == "joint_limits":
            g = joint_limit_gradient(theta, c.lower, c.upper)
        elif o.secondary == "manipulability":  # central differences over the active joints
            g = np.zeros(c.n)
            h = 1e-6
            for i in np.flatnonzero(self.active):
                tp = theta.copy()
                tm = theta.copy()
                tp[i] += h
                tm[i] -= h
                g[i] = (self.secondary_value(tp) - self.secondary_value(tm)) / (2 * h)
        else:
            g = np.zeros(c.n)
        return g * self.active

    def _secondary(self, theta: np.ndarray) -> np.ndarray | None:
        """The null-space step during the approach: -gain * dH, at most ``secondary_gain`` rad."""
        o = self.options
        if o.secondary == "none":
            return None
        g = self.secondary_gradient(theta)
        return -o.secondary_gain * g / max(1.0, float(np.max(np.abs(g))))

    def step(self, theta: np.ndarray, errors: list[np.ndarray], secondary: np.ndarray | None = None,
             solver: str | None = None):
        """Joint increments (n,) for one servo step, and the solver's StepInfo. ``secondary``
        (n,) replaces the null-space step of the secondary cost; ``solver`` the options' one."""
        o = self.options
        c = self.chain
        if self._fast is not None and secondary is None and (solver or o.solver) == "pinv":
            return self._fast_step(theta, errors[0])
        lower_step = np.where(self.active, c.lower - theta, 0.0)
        upper_step = np.where(self.active, c.upper - theta, 0.0)
        lower_step = np.minimum(lower_step, 0.0)
        upper_step = np.maximum(upper_step, 0.0)
        rate_step = None
        if o.use_rate_limits:
            rate_step = np.where(np.isfinite(c.rate), c.rate * o.dt, np.inf)
        if secondary is None:
            secondary = self._secondary(theta)
        levels: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
        for k, task in enumerate(self.tasks):
            e = self._commanded(errors[k], task.weights)
            levels.setdefault(task.priority, []).append((self.task_jacobian(theta, k), e, task.weights))
        stacked = []
        for p in sorted(levels):
            J = np.vstack([x[0] for x in levels[p]])
            e = np.concatenate([x[1] for x in levels[p]])
            w = np.concatenate([x[2] for x in levels[p]])
            stacked.append(Level(J, e, w))
        if (solver or o.solver) == "lp":
            # the LP takes one level: priorities become weights 10^-3 per level
            J = np.vstack([lv.J for lv in stacked])
            e = np.concatenate([lv.e for lv in stacked])
            w = np.concatenate([lv.weights * 1e-3**i for i, lv in enumerate(stacked)])
            return solve_lp(J, e, weights=w, lower_step=lower_step, upper_step=upper_step, rate_step=rate_step,
                            joint_cost=self.joint_weights, secondary=None if secondary is None else -secondary,
                            active=self.active)
        return solve_pinv(stacked, lower_step=lower_step, upper_step=upper_step, rate_step=rate_step,
                          joint_weights=self.joint_weights, damping=o.damping, secondary=secondary,
                          active=self.active)

    # ------------------------------------------------------------------ the loop

    def run(self, theta0: np.ndarray) -> ServoResult:
        """Servo from theta0 (n,); with ``options.restarts``, failed attempts are retried from
        random configurations of the active joints (a seeded generator), within the same time
        cap. The result is the first converged attempt, else the closest one."""
        o = self.options
        theta0 = self.chain.clip(self.chain.check_configuration(theta0, "starting configuration"))
        start = time.perf_counter()
        self._compiled = None
        if self._fast is not None and self.compile:  # built here: the options as they are now
            task = self.tasks[0]
            self._compiled = CompiledServo.build(self.chain, self.frame_ids[0], task.target, task.weights, o,
                                                 self.active)
        rng = np.random.default_rng(o.seed) if o.restarts else None
        result = self._attempt(theta0, start)
        best = result
        total = result.iterations
        for k in range(o.restarts):
            if result.converged or result.reason.startswith("stopped at the time cap") or "reaches at most" in result.reason:
                break
            assert rng is not None
            theta = np.where(self.active, self.chain.random(rng), theta0)
            result = self._attempt(theta, start)
            result.restarts = k + 1
            total += result.iterations
            if result.converged or (sum(result.best_position_errors) + sum(result.best_rotation_errors)
                                    < sum(best.best_position_errors) + sum(best.best_rotation_errors)):
                best = result
        best.iterations_total = total
        best.seconds = time.perf_counter() - start
        return best

    def _attempt(self, theta: np.ndarray, start: float) -> ServoResult:
        if self._fast is not None:
            if self._compiled is not None:
                return self._compiled_attempt(self._compiled, theta, start)
            return self._fast_attempt(theta, start)
        o = self.options
        c = self.chain
        errors = self.errors(theta)
        merit = self.merit(errors)
        path = [theta.copy()]
        history = [merit]
        best = (merit, theta.copy(), errors)
        stall_ref, stall_at = self.level_merits(errors), 0
        floor = 1e-2 * (o.tol_position**2 + o.tol_rotation**2)
        reason = ""
        iterations = 0
        pos, rot = self._norms(errors)
        converged = self._done(pos, rot)
        while not converged:
            reason = self._capped(iterations, start)
            if reason:
                break
            dq, _info = self.step(theta, errors)
            accepted = False
            alpha = 1.0
            current_levels = self.level_merits(errors)
            for _ in range(12):
                trial = c.clip(theta + alpha * dq)
                trial_errors = self.errors(trial)
                trial_merit = self.merit(trial_errors)
                trial_levels = self.level_merits(trial_errors)
                if self._better(trial_levels, current_levels):
                    accepted = True
                    break
                alpha *= 0.5
            iterations += 1
            if not accepted:
                reason = self.diagnose(theta, errors, stalled=True)
                break
            theta, errors, merit = trial, trial_errors, trial_merit
            path.append(theta.copy())
            history.append(merit)
            if merit < best[0]:
                best = (merit, theta.copy(), errors)
            pos, rot = self._norms(errors)
            converged = self._done(pos, rot)
            levels_now = trial_levels
            if np.any((levels_now < (1.0 - 1e-3) * stall_ref) & (stall_ref > floor)):
                stall_ref, stall_at = levels_now, iterations
            elif iterations - stall_at >= o.stall_iterations and not converged:
                reason = self.diagnose(theta, errors, stalled=True)
                break
        if not converged and reason.startswith("stopped at"):
            why = self.diagnose(theta, errors, stalled=False)
            reason = reason + ("; " + why if why else "")
        refined, H0, H1 = 0, None, None
        if converged and o.secondary != "none" and o.refine_iterations > 0:
            theta, errors, refined, H0, H1 = self._refine(theta, errors, path, history, start)
            best = (self.merit(errors), theta.copy(), errors)
        bpos, brot = self._norms(best[2])
        pos, rot = self._norms(errors)
        return ServoResult(theta=theta, converged=converged, iterations=iterations, position_errors=pos,
                           rotation_errors=rot, path=np.array(path), merit_history=history, reason=reason,
                           best_position_errors=bpos, best_rotation_errors=brot,
                           seconds=time.perf_counter() - start, refine_iterations=refined,
                           secondary_cost=H1, secondary_cost_before=H0)

    def _refine(self, theta, errors, path, history, start):
        """After the targets are met: steps along minus the secondary cost's gradient projected
        into the tasks' null space (by the pseudo-inverse, whatever the solver), each followed by
        a few servo steps that remove the second-order drift it causes; a step is kept only if
        every target is again within tolerance and the cost fell."""
        o = self.options
        H = H0 = self.secondary_value(theta)
        refined = 0
        zero = np.zeros(self.chain.n)
        for _ in range(o.refine_iterations):
            if time.perf_counter() - start > o.max_seconds:
                break
            g = self.secondary_gradient(theta)
            gmax = float(np.max(np.abs(g)))
            if gmax == 0.0:
                break
            size = o.refine_step
            accepted = False
            for _ in range(8):
                dq, _info = self.step(theta, errors, secondary=-g * (size / gmax), solver="pinv")
                trial = self.chain.clip(theta + dq)
                trial_errors = self.errors(trial)
                pieces = [(trial, trial_errors)]  # every intermediate step goes into the path
                for _ in range(10):
                    if self._done(*self._norms(trial_errors)):
                        break
                    dq, _info = self.step(trial, trial_errors, secondary=zero, solver="pinv")
                    trial = self.chain.clip(trial + dq)
                    trial_errors = self.errors(trial)
                    pieces.append((trial, trial_errors))
                H_trial = self.secondary_value(trial)
                if self._done(*self._norms(trial_errors)) and H_trial < H - 1e-9 * max(1.0, abs(H)):
                    accepted = True
                    break
                size *= 0.5
            if not accepted:
                break
            theta, errors, H = trial, trial_errors, H_trial
            for th, er in pieces:
                path.append(th.copy())
                history.append(self.merit(er))
            refined += 1
        return theta, errors, refined, H0, H

    # ------------------------------------------------------------------ why it failed

    def _reach_bound(self, theta: np.ndarray, fid: int) -> tuple[float, np.ndarray] | None:
        """:meth:`KinematicChain.reach_bound` of frame ``fid``. For a frame that revolute and
        continuous joints alone move it does not depend on theta (a rotation about a joint's
        axis keeps the distances from its origin to the next joint's and to the frame's, and
        the first joint's origin is fixed to the root), so it is computed once per chain and
        frame: a failed target's diagnosis spent 0.1 ms on it."""
        known = _per_chain(self.chain)
        key = ("reach bound", fid)
        hit = known.get(key)
        if hit is None:
            fixed = all(jt.kind != "prismatic" for jt in self.chain.supporting_joints(fid))
            hit = known[key] = (fixed, self.chain.reach_bound(theta, fid))
            return hit[1]
        return hit[1] if hit[0] else self.chain.reach_bound(theta, fid)

    def diagnose(self, theta: np.ndarray, errors: list[np.ndarray], stalled: bool) -> str:
        """One clause saying why the error stopped falling at ``theta``."""
        c = self.chain
        reasons = []
        for k, (task, E) in enumerate(zip(self.tasks, errors)):
            if task.frame != "world" or np.any(task.weights[:3] == 0):
                continue
            bound = self._reach_bound(theta, self.frame_ids[k])
            if bound is None:
                continue
            reach, origin = bound
            ref = self.ref_ids[k]  # the world frame's placement is the identity: no FK for it
            goal = task.target[:3, 3] if ref == 0 else (c.placement(theta, ref) @ task.target)[:3, 3]
            dist = float(np.linalg.norm(goal - origin))
            if dist > reach + 1e-9:
                first = c.supporting_joints(self.frame_ids[k])[0].name
                reasons.append(f"the target of {task.link!r} is {dist:.4g} m from {first!r} but the chain reaches at most {reach:.4g} m")
        # the descent direction of the error in joint space: J^T W E
        J = np.vstack([self.task_jacobian(theta, k) * (t.weights > 0)[:, None] for k, t in enumerate(self.tasks)])
        W = np.concatenate([t.weights for t in self.tasks])
        E = np.concatenate(errors)
        d = J.T @ (W * E)
        tol = 1e-9 * (1 + np.abs(theta))
        at_upper = self.active & (theta >= c.upper - tol) & (d > 0)
        at_lower = self.active & (theta <= c.lower + tol) & (d < 0)
        held = [c.joint_names[i] for i in np.flatnonzero(at_upper | at_lower)]
        Ja = J[:, self.active] * np.sqrt(W)[:, None]
        if held:
            reasons.append(f"held by the limits of {', '.join(held)}")
        if not reasons:
            # how much of the error the joints can still reduce (its projection on range(J))
            U, s_full, _ = np.linalg.svd(Ja, full_matrices=False)
            sigma_min = float(s_full[-1]) if s_full.size else 0.0
            e = np.sqrt(W) * E
            # directions a near-singular Jacobian barely moves (sigma < 1e-3) count as unreachable
            in_range = U[:, s_full > 1e-3 * max(1.0, s_full[0])] if s_full.size else U[:, :0]
            frac = float(np.linalg.norm(in_range.T @ e) / max(np.linalg.norm(e), 1e-300))
            if sigma_min < 1e-3 and frac < 0.5:
                reasons.append(f"the chain is at a singular pose (smallest singular value {sigma_min:.2g}) "
                               "and the remaining error points where no joint can move the link: the target is out of reach")
            elif stalled:
                reasons.append("the error stopped decreasing (a local minimum of the distance to the target, "
                               "or a target outside the workspace)")
        return "; ".join(reasons)


def track(chain: KinematicChain, tasks: Sequence[Task] | Task, theta0: np.ndarray | None = None,
          options: ServoOptions | None = None) -> ServoResult:
    """Run the servo to the tasks' targets; OutOfWorkspace (one sentence) if they are not met."""
    if isinstance(tasks, Task):
        tasks = [tasks]
    servo = Servo(chain, tasks, options)
    result = servo.run(chain.neutral() if theta0 is None else theta0)
    if not result.converged:
        raise OutOfWorkspace(failure_message(tasks, result))
    return result


__all__ = ["Servo", "track"]
