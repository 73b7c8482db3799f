"""thermal_drift in three forms: the actuators lengthen with the heat of the work they do (the
strokes they moved, cooling with a screened time constant), the actuators lengthen as the stand
warms up with time since power-on towards an equilibrium (a screened time constant), or the
moving frame drifts linearly in time. The three are variants of one place; diagnosis chooses among
them by how each predicts the later part of the session from the earlier (``Effect.forecast``).

Time: a term reads ``elapsed``, the seconds since the session's first command. The power-on is
session.yaml's ``power_on_t`` where it says it (extras ``since_power_on``; a term's
``where['since_power_on_at_start_s']`` keeps the time from power-on to the first command), else the
first command stands for it (a warm-up's constant part before it is then the geometry's, and its
amplitudes are what was left to warm). ``platkit predict`` sets ``elapsed`` to the thermal state
it is asked for (``--at-time``: seconds since power-on, or ``--warm``: the equilibrium, ``inf``)
and, for the heat of work, ``thermal_start_s``: the time since power-on of the first row, whose
heat is that of work at the recorded session's rate (``where.work_rate_per_s``). Every term's
``where`` keeps ``recorded_s``, the span of the session it was fitted on (seconds since its first
command), so that ``predict`` warns beyond it."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.effects import (
    CONTROL_SIZE_UNIT,
    Effect,
    SizeHelp,
    control_size,
    history,
    stored_number,
    stored_where,
)
from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm
from platkit_effects.physics import ThermalPhysics, thermal_state

#: cooling time constants (s) a thermal drift is screened at, a factor sqrt(2) apart (the simulator
#: draws 5 to 15 min); the score test picks among them
COOLING_TAUS_S = tuple(float(round(150.0 * 2 ** (k / 2))) for k in range(11))  # 150 s to 80 min
#: time constants (s) of a warm-up with time since power-on, screened like the cooling ones (the
#: physical simulator's warm-up draws 5 to 20 min)
WARMUP_TAUS_S = COOLING_TAUS_S
#: the forms of a thermal drift (``where['form']``: the variants of one form compete by BIC, the
#: forms by held-out prediction of the later part of the session)
FORM_LINEAR, FORM_WORK, FORM_WARMUP = "linear in time", "heat from work", "warm-up with time"


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


def _start_heat(poses: PoseSet, work_rate: np.ndarray | None, tau_s: float) -> np.ndarray | None:
    """(n_u,) the heat at the first row when ``predict`` gave a thermal state (extras
    'thermal_start_s', seconds since power-on at the first row, ``inf`` warm): that of work at
    the recorded ``work_rate`` (strokes per second) since power-on, ``rate tau (1 - exp(-s / tau))``;
    None when no state was given (the first row is cold) or the rate is unknown."""
    start = poses.extras.get("thermal_start_s")
    if start is None or work_rate is None or poses.n_poses == 0:
        return None
    s0 = float(np.asarray(start, float).reshape(-1)[0])
    warmth = 1.0 if np.isinf(s0) else 1.0 - np.exp(-max(s0, 0.0) / tau_s)
    return np.asarray(work_rate, float) * tau_s * warmth


def work_rate(poses: PoseSet, stroke: np.ndarray) -> np.ndarray:
    """(n_u,) the strokes each actuator moved per second over the session (rows in session order;
    a gap in the rows counts its move across the gap)."""
    t = history(poses, "elapsed")
    span = float(np.ptp(t)) if t.size else 0.0
    if poses.n_poses < 2 or not span > 0:
        return np.zeros(poses.controls.shape[1])
    order = np.argsort(history(poses, "row"), kind="stable")
    U = np.asarray(poses.controls, float)[order] / stroke
    return np.sum(np.abs(np.diff(U, axis=0)), axis=0) / span


def warmth(poses: PoseSet, tau_s: float, start_s: float = 0.0) -> np.ndarray:
    """(N,) the share of the warm-up's equilibrium reached at each row, ``1 - exp(-(elapsed +
    start_s) / tau)``, ``start_s`` the time from power-on to the session's first command
    (``elapsed`` ``inf``: warm, 1)."""
    t = np.maximum(history(poses, "elapsed") + start_s, 0.0)
    return 1.0 - np.exp(-t / tau_s)


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
    work_rate: np.ndarray | None = None

    def control_offset(self, theta, poses, n_u):
        h0 = _start_heat(poses, self.work_rate, self.tau_s)
        if h0 is not None and np.isinf(np.asarray(poses.extras["thermal_start_s"], float).reshape(-1)[0]):
            return theta[0] * np.broadcast_to(h0[:n_u], (poses.n_poses, n_u)).copy()  # warm: work at the recorded rate
        heat = motion_heat(poses, self.stroke, self.tau_s)
        if h0 is not None:  # the heat the first row starts with, cooling from there
            t = history(poses, "elapsed")
            heat = heat + h0[None] * np.exp(-(t - np.min(t)) / self.tau_s)[:, None]
        return theta[0] * heat[:, :n_u]


@dataclass
class ThermalWarmupTerm(ModelTerm):
    """Every actuator j longer by theta_j times the warm-up reached, ``1 - exp(-(elapsed + start_s) /
    tau_s)`` (theta_j: its lengthening once warm; where the power-on is unknown, beyond what it had
    at the first command)."""

    tau_s: float = 600.0
    start_s: float = 0.0  # from power-on to the session's first command (0: the first command stands for it)

    def control_offset(self, theta, poses, n_u):
        return warmth(poses, self.tau_s, self.start_s)[:, None] * np.asarray(theta, float)[None, :n_u]


def _strokes(spec: PlatformSpec) -> np.ndarray:
    lo, hi = spec.control_bounds()
    return np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)


def _clock(poses: PoseSet) -> dict:
    """The session's clock a thermal term keeps in its ``where``: ``recorded_s`` (first, last
    seconds since the first command), ``first_command_t`` (the time t of the first command, where
    the rows have times) and, where the session says its power-on, ``since_power_on_at_start_s``."""
    t = history(poses, "elapsed")
    out: dict = {"recorded_s": [float(np.min(t)), float(np.max(t))] if t.size else [0.0, 0.0]}
    clock = np.asarray(poses.t, float) if poses.t is not None else np.full(t.shape, np.nan)
    if clock.shape == t.shape and t.size and np.all(np.isfinite(clock)):
        out["first_command_t"] = float(np.median(clock - t))  # the session's clock at its first command
    since = poses.extras.get("since_power_on")
    if since is not None and np.shape(since) == t.shape and t.size and np.all(np.isfinite(since)):
        out["since_power_on_at_start_s"] = float(np.median(np.asarray(since, float) - t))
    return out


def _clock_from(where: dict) -> dict:
    out: dict = {}
    span = where.get("recorded_s")
    if isinstance(span, list) and len(span) == 2 and all(isinstance(v, (int, float)) for v in span):
        out["recorded_s"] = [float(v) for v in span]
    for key in ("first_command_t", "since_power_on_at_start_s"):
        if key in where:
            out[key] = stored_number(where, key, "thermal_drift")
    return out


class ThermalDrift(Effect):
    name = "thermal_drift"
    summary = ("actuators that lengthen with the heat of their own motion or as the stand warms up after power-on, "
               "or a slow drift in time")
    forecast = True
    warm_up = True
    simulation_size = SizeHelp("the drift of the moving frame, in a random horizontal-ish direction", "mm per hour")
    physics_size = SizeHelp("the largest lengthening of an actuator over the session, from heat that grows with the "
                            "distance each actuator moves and cools with a time constant of 5 to 15 minutes",
                            CONTROL_SIZE_UNIT)

    def term(self, clock: dict | None = None):
        where: dict = {"time": "the whole session, linear in the time since its first command", "form": FORM_LINEAR,
                       **(clock or {})}
        return ThermalDriftTerm(self.name, ["vx", "vy", "vz"], np.zeros(3), ["m/s"] * 3, where)

    def expansion(self, unit: str, stroke, tau_s: float, rate=None, clock: dict | None = None):
        stroke = np.asarray(stroke, float)
        where = {"actuator": "all", "unit": unit, "cooling_time_constant_s": float(tau_s),
                 "stroke": [float(s) for s in stroke], "form": FORM_WORK,
                 "heat": "strokes each actuator moved, cooling with the time constant"}
        if rate is not None:
            where["work_rate_per_s"] = [float(r) for r in rate]
        where.update(clock or {})
        return ThermalExpansionTerm(self.name, ["expansion_per_stroke"], np.zeros(1), [unit], where,
                                    tau_s=float(tau_s), stroke=stroke,
                                    work_rate=None if rate is None else np.asarray(rate, float))

    def warmup(self, names: list[str], units: list[str], tau_s: float, clock: dict | None = None):
        """The warm-up with time since power-on: one amplitude per actuator (``names``, ``units``)."""
        where: dict = {"actuator": "all", "form": FORM_WARMUP, "warmup_time_constant_s": float(tau_s),
                       "actuators": list(names), "units": list(units),
                       "warmup": "each actuator longer by its amplitude times 1 - exp(-t / tau), t the time since "
                                 "power-on (where the session does not say it, since the first command)", **(clock or {})}
        start = float(where.get("since_power_on_at_start_s", 0.0))
        return ThermalWarmupTerm(self.name, [f"{n}_warm" for n in names], np.zeros(len(names)), list(units), where,
                                 tau_s=float(tau_s), start_s=start)

    def candidates(self, spec, poses, residuals=None):
        if not np.ptp(history(poses, "elapsed")) > 0:
            return []
        stroke = _strokes(spec)
        remember_heat(poses, stroke)
        units = {c.unit for c in spec.controls}
        clock = _clock(poses)
        out = [self.term(clock)]
        if len(units) == 1 and np.ptp(poses.controls, axis=0).max() > 0:
            rate = work_rate(poses, stroke)
            out += [self.expansion(spec.controls[0].unit, stroke, tau, rate, clock) for tau in COOLING_TAUS_S]
        names, cunits = list(spec.control_names), [c.unit for c in spec.controls]
        out += [self.warmup(names, cunits, tau, clock) for tau in WARMUP_TAUS_S]
        return out

    def regressor(self, term, spec, poses):
        if isinstance(term, ThermalExpansionTerm):
            return np.mean(motion_heat(poses, term.stroke, term.tau_s), axis=1)
        if isinstance(term, ThermalWarmupTerm):
            return warmth(poses, term.tau_s, term.start_s)
        return history(poses, "elapsed")

    def regressor_label(self, term):
        if isinstance(term, ThermalExpansionTerm):
            return f"mean heat of the actuators (strokes moved, cooling over {term.tau_s:g} s)"
        if isinstance(term, ThermalWarmupTerm):
            return f"warm-up reached, 1 - exp(-t / {term.tau_s:g} s), t since power-on"
        return "time since the first command (s)"

    def from_dict(self, data, spec=None):
        where = stored_where(data)
        clock = _clock_from(where)
        if where.get("form") == FORM_WARMUP:
            return self._warmup_from(where, spec, clock)
        if "cooling_time_constant_s" not in where:
            return self.term(clock)
        tau = stored_number(where, "cooling_time_constant_s", self.name, positive=True)
        stroke = where.get("stroke")
        if not (isinstance(stroke, list) and stroke and all(isinstance(s, (int, float)) and s > 0 for s in stroke)):
            raise BadInput("effect 'thermal_drift': where.stroke must list each actuator's stroke (> 0)")
        if spec is not None and len(stroke) != spec.n_u:
            raise BadInput(f"effect 'thermal_drift': where.stroke has {len(stroke)} strokes, {spec.name} "
                           f"has {spec.n_u} actuators")
        unit = where.get("unit")
        rate = where.get("work_rate_per_s")
        if rate is not None and not (isinstance(rate, list) and len(rate) == len(stroke)
                                     and all(isinstance(r, (int, float)) and r >= 0 for r in rate)):
            raise BadInput("effect 'thermal_drift': where.work_rate_per_s must list each actuator's strokes per "
                           "second (>= 0), one per stroke")
        return self.expansion(unit if isinstance(unit, str) else "m", stroke, tau, rate, clock)

    def _warmup_from(self, where: dict, spec, clock: dict):
        tau = stored_number(where, "warmup_time_constant_s", self.name, positive=True)
        names, units = where.get("actuators"), where.get("units")
        if not (isinstance(names, list) and names and all(isinstance(n, str) for n in names)
                and isinstance(units, list) and len(units) == len(names) and all(isinstance(u, str) for u in units)):
            raise BadInput("effect 'thermal_drift': a warm-up's where needs 'actuators' (names) and 'units', one each")
        if spec is not None and list(names) != list(spec.control_names):
            raise BadInput(f"effect 'thermal_drift': where.actuators {names} are not {spec.name}'s controls "
                           f"({', '.join(spec.control_names)})")
        return self.warmup(names, units, tau, clock)

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
        largest = control_size(spec, 0, size, 2.0)
        return ThermalPhysics(largest / peak, tau, stroke, largest, spec.controls[0].unit)
