"""thermal_drift: the actuators lengthen with the heat of the strokes they moved (cooling with a
screened time constant), or the moving frame drifts linearly in time."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.effects import CONTROL_SIZE_UNIT, Effect, SizeHelp, history
from platkit.effects import control_size as _size
from platkit.effects import stored_number as _number
from platkit.effects import stored_where as _where
from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm
from platkit_effects.physics import ThermalPhysics, thermal_state

#: cooling time constants (s) a thermal drift is screened at, a factor sqrt(2) apart (the simulator
#: draws 5 to 15 min); the score test picks among them
COOLING_TAUS_S = tuple(float(round(150.0 * 2 ** (k / 2))) for k in range(11))  # 150 s to 80 min


def motion_heat(poses: PoseSet, stroke: np.ndarray, tau_s: float) -> np.ndarray:
    """(N, n_u) each actuator's heat at each pose: the strokes it moved, cooling with ``tau_s``,
    ``theta_n = sum_k |u_k - u_(k-1)| / stroke exp(-(t_n - t_k) / tau)`` over the moves up to row n
    (rows in session order, times from the first command). A gap in the rows (commands that gave
    no pose) hides moves. The last hidden command c is known where the session reader kept each
    row's own last step (``extras['last_step']``, from the full command list: b - c), so its move
    into b counts exactly. The path from a to c over the k = g - 1 commands left is, for a random
    plan, its expectation with the hidden commands drawn from those seen, E|a - x| + (k - 2) m1 +
    E|x - c| (m1 the mean single move; exact, |c - a|, for k = 1), for a sweep |c - a|, blended
    per actuator by how much longer single moves are than moves across gaps (g m1 / m_gap, 1 to
    g). Computed on the full session and kept by subsets (the key 'heat_<tau>' of ``extras``),
    so a fold's refit sees the same heat."""
    key = f"heat_{tau_s:g}"
    if key in poses.extras and np.shape(poses.extras[key]) == poses.controls.shape:
        return np.asarray(poses.extras[key], float)
    U = np.asarray(poses.controls, float)
    N = len(U)
    if N == 0:
        return np.zeros_like(U)
    t = history(poses, "elapsed")
    row = history(poses, "row")
    order = np.argsort(row, kind="stable")
    Us = U[order] / stroke
    move = np.abs(np.diff(Us, axis=0))
    gap = np.maximum(np.diff(row[order]), 1.0)[:, None]
    single = gap[:, 0] == 1
    if np.any(~single):
        m1 = np.mean(move[single], axis=0) if single.sum() >= 3 else np.mean(move / gap, axis=0)
        across = np.sum(move[~single], axis=0) / np.sum(gap[~single], axis=0)  # move across a gap, per command
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(across > 0, m1 / across, 1.0)  # g m1 / m_gap
        share = np.clip((factor - 1.0) / np.maximum(gap - 1.0, 1.0), 0.0, 1.0)
        a, b = Us[:-1], Us[1:]
        into_b = np.zeros_like(b)
        steps = poses.extras.get("last_step")
        if steps is not None and np.shape(steps) == U.shape:
            ls = (np.asarray(steps, float)[order] / stroke)[1:]
            # the rows' own steps (a reader without the full commands) say nothing of c: b - a
            known = np.isfinite(ls).all(axis=1) & ~np.all(np.isclose(ls, b - a, rtol=1e-9, atol=1e-12), axis=1)
            if np.any(known & ~single):
                into_b = np.where((known & ~single)[:, None], np.nan_to_num(ls), 0.0)
                b = b - into_b
                gap = np.where((known & ~single)[:, None], gap - 1.0, gap)
        span = np.abs(b - a)
        reach_a = np.mean(np.abs(a[:, None, :] - Us[None]), axis=1)
        reach_b = np.mean(np.abs(b[:, None, :] - Us[None]), axis=1)
        expected = np.maximum(reach_a + reach_b + (gap - 2.0) * m1, span)
        hidden = np.where(gap > 1, span + share * (expected - span), span)
        move = np.where(single[:, None], move, hidden + np.abs(into_b))
    heat = np.zeros_like(U)
    ts = t[order]
    for k in range(1, N):
        decay = np.exp(-max(ts[k] - ts[k - 1], 0.0) / tau_s)
        heat[k] = heat[k - 1] * decay + move[k - 1]
    out = np.empty_like(heat)
    out[order] = heat
    return out


def remember_heat(poses: PoseSet, stroke: np.ndarray) -> None:
    """Store the heat at every screened time constant in ``poses.extras`` (from the full session)."""
    for tau in COOLING_TAUS_S:
        key = f"heat_{tau:g}"
        if key not in poses.extras or np.shape(poses.extras[key]) != poses.controls.shape:
            poses.extras[key] = motion_heat(poses, stroke, tau)


@dataclass
class ThermalDriftTerm(ModelTerm):
    """The moving frame translated linearly in time (the additive simulator's drift)."""

    def pose_offset(self, theta, poses, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = history(poses, "elapsed")[:, None] * np.asarray(theta)[None, :3]
        return out


@dataclass
class ThermalExpansionTerm(ModelTerm):
    """Every actuator longer by k times its heat (strokes moved, cooling with ``tau_s``)."""

    tau_s: float = 600.0
    stroke: np.ndarray = field(default_factory=lambda: np.ones(1))

    def control_offset(self, theta, poses, n_u):
        heat = motion_heat(poses, self.stroke, self.tau_s)
        return theta[0] * heat[:, :n_u]


def _strokes(spec: PlatformSpec) -> np.ndarray:
    lo, hi = spec.control_bounds()
    return np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)


class ThermalDrift(Effect):
    name = "thermal_drift"
    summary = "actuators that lengthen with the heat of their own motion, or a slow drift in time"
    simulation_size = SizeHelp("the drift of the moving frame, in a random horizontal-ish direction", "mm per hour")
    physics_size = SizeHelp("the largest lengthening of an actuator over the session, from heat that grows with the "
                            "distance each actuator moves and cools with a time constant of 5 to 15 minutes",
                            CONTROL_SIZE_UNIT)

    def term(self):
        return ThermalDriftTerm(self.name, ["vx", "vy", "vz"], np.zeros(3), ["m/s"] * 3,
                                {"time": "the whole session, linear in the time since its first command"})

    def expansion(self, unit: str, stroke, tau_s: float):
        stroke = np.asarray(stroke, float)
        where = {"actuator": "all", "unit": unit, "cooling_time_constant_s": float(tau_s),
                 "stroke": [float(s) for s in stroke],
                 "heat": "strokes each actuator moved, cooling with the time constant"}
        return ThermalExpansionTerm(self.name, ["expansion_per_stroke"], np.zeros(1), [unit], where,
                                    tau_s=float(tau_s), stroke=stroke)

    def candidates(self, spec, poses, residuals=None):
        if not np.ptp(history(poses, "elapsed")) > 0:
            return []
        stroke = _strokes(spec)
        remember_heat(poses, stroke)
        units = {c.unit for c in spec.controls}
        out = [self.term()]
        if len(units) == 1 and np.ptp(poses.controls, axis=0).max() > 0:
            out += [self.expansion(spec.controls[0].unit, stroke, tau) for tau in COOLING_TAUS_S]
        return out

    def regressor(self, term, spec, poses):
        if isinstance(term, ThermalExpansionTerm):
            return np.mean(motion_heat(poses, term.stroke, term.tau_s), axis=1)
        return history(poses, "elapsed")

    def regressor_label(self, term):
        if isinstance(term, ThermalExpansionTerm):
            return f"mean heat of the actuators (strokes moved, cooling over {term.tau_s:g} s)"
        return "time since the first command (s)"

    def from_dict(self, data, spec=None):
        where = _where(data)
        if "cooling_time_constant_s" not in where:
            return self.term()
        tau = _number(where, "cooling_time_constant_s", self.name, positive=True)
        stroke = where.get("stroke")
        if not (isinstance(stroke, list) and stroke and all(isinstance(s, (int, float)) and s > 0 for s in stroke)):
            raise BadInput("effect 'thermal_drift': where.stroke must list each actuator's stroke (> 0)")
        if spec is not None and len(stroke) != spec.n_u:
            raise BadInput(f"effect 'thermal_drift': where.stroke has {len(stroke)} strokes, {spec.name} "
                           f"has {spec.n_u} actuators")
        unit = where.get("unit")
        return self.expansion(unit if isinstance(unit, str) else "m", stroke, tau)

    def simulation_term(self, spec, size, rng, commands):
        """``size``: drift of the moving frame in mm per hour, in a random horizontal-ish direction."""
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        return self.term(), (2.0 if size is None else float(size)) * 1e-3 / 3600.0 * d

    def physics(self, spec, size, rng, plan):
        """``size``: the largest lengthening of an actuator over the session (mm for lengths), from heat
        that grows with the distance each actuator moves and cools with a time constant of 5 to 15 minutes."""
        tau = float(rng.uniform(300.0, 900.0))
        lo, hi = spec.control_bounds()
        stroke = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
        t = np.arange(0.0, plan.end_s, 0.1)
        seg = np.searchsorted(plan.command_t, t, side="right") - 1
        motor = np.where(seg[:, None] < 0, plan.start[None], plan.commands[np.maximum(seg, 0)])
        peak = float(np.max(thermal_state(t, motor, stroke, tau)))
        if not peak > 0:
            raise BadInput("effect thermal_drift: the commands never move the stand, nothing heats")
        largest = _size(spec, 0, size, 2.0)
        return ThermalPhysics(largest / peak, tau, stroke, largest, spec.controls[0].unit)
