"""platkit's built-in diagnosis effects, registered through ``platkit_register_effects`` exactly as
an outside package registers its own.

Each effect is an :class:`platkit.effects.Effect`; its terms are
:class:`platkit.terms.ModelTerm` subclasses whose ``theta`` the estimator fits with the
geometry. SI inside; a control offset is in the control's internal unit (m for 'm' controls,
rad, deg or counts otherwise). Time is measured from the session's first command.

| effect | term (one per actuator unless said) | theta |
|---|---|---|
| backlash | u_i + b d_i, d_i = sign of the actuator's last move | b: half the play |
| compliance | parallel stand (one term): u + c f, f = J^-T w, the actuator forces holding a 1 N weight at the moving frame's origin; serial chain: q_j + c_j tau_j, tau = gravity torque of the URDF's inertias | c |
| thermal_drift | u_j + k h_j(t): every actuator longer by k times its heat h_j, the strokes it moved cooling with tau (150 s to 80 min, a factor sqrt(2) apart; one term, the physics); or X + v t, the moving frame translated linearly in time (the additive simulator's drift) | k; or v (3) |
| cyclic_error | u_i + a sin(2 pi u_i / P) + b cos(2 pi u_i / P), P from a short list per unit | a, b |
| scale_nonlinearity | u_i + a P2(s) + b P3(s), s = travel scaled to [-1, 1] over the stroke (Legendre) | a, b |
| settling_lag | u - l (u_k - u_k-1): short of the command by a fraction of the last step (one term) | l |
| marker_slip | marker m moved by d (moving frame) from time t_s on (t_s: the marker's change point) | d (3) |
| base_tilt | the pose turned about the base x and y axes: X + w x X, R' = exp(w) R (one term) | w_x, w_y |

``where`` of every term holds what ``from_dict`` needs to rebuild it without the spec
(actuator name and index, unit, period, marker index, slip time, and for compliance the stand).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from platkit.effects import Effect, history
from platkit.errors import BadInput
from platkit.hookspecs import hookimpl
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.terms import ModelTerm
from platkit_effects.imu import IMU_EFFECTS
from platkit_effects.physics import (
    BacklashPhysics,
    BaseTiltPhysics,
    CompliancePhysics,
    CyclicPhysics,
    MarkerSlipPhysics,
    ScalePhysics,
    SlowActuator,
    ThermalPhysics,
    thermal_state,
)


def _where(data: dict) -> dict:
    where = data.get("where") if isinstance(data, dict) else None
    return where if isinstance(where, dict) else {}


def _actuator(spec: PlatformSpec | None, data: dict, effect: str) -> tuple[int, str, str]:
    """(index, name, unit) of the actuator a stored term acts on."""
    where = _where(data)
    name, index, unit = where.get("actuator"), where.get("actuator_index"), where.get("unit")
    if spec is not None:
        if name not in spec.control_names:
            raise BadInput(f"effect {effect!r}: actuator {name!r} is not a control of {spec.name} "
                           f"({', '.join(spec.control_names)})")
        i = spec.control_names.index(name)
        return i, name, spec.controls[i].unit
    if not isinstance(index, int) or index < 0 or not isinstance(unit, str):
        raise BadInput(f"effect {effect!r}: where needs actuator_index (an integer >= 0) and unit")
    return index, str(name), unit


def _actuator_where(spec: PlatformSpec, i: int) -> dict:
    return {"actuator": spec.control_names[i], "actuator_index": i, "unit": spec.controls[i].unit}


def _size(spec: PlatformSpec, i: int, size: float | None, default: float) -> float:
    """A simulation size in SI for control i: mm -> m for length controls, else the control's unit."""
    size = default if size is None else float(size)
    return size * 1e-3 if spec.controls[i].unit == "m" else size


def _number(where: dict, key: str, effect: str, positive: bool = False) -> float:
    v = where.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (positive and not v > 0):
        raise BadInput(f"effect {effect!r}: where.{key} must be a{' positive' if positive else ''} number")
    return float(v)


# ---------------------------------------------------------------------------- backlash
@dataclass
class BacklashTerm(ModelTerm):
    index: int = 0

    def control_offset(self, theta, poses, n_u):
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * history(poses, "direction")[:, self.index]
        return out


class Backlash(Effect):
    name = "backlash"
    summary = "an actuator's position depends on the direction it last moved"

    def term(self, i, where):
        return BacklashTerm(self.name, ["half_play"], np.zeros(1), [where["unit"]], dict(where), index=i)

    def candidates(self, spec, poses, residuals=None):
        d = history(poses, "direction", spec)
        return [self.term(i, _actuator_where(spec, i)) for i in range(spec.n_u)
                if np.sum(d[:, i] > 0) >= 2 and np.sum(d[:, i] < 0) >= 2]

    def regressor(self, term, spec, poses):
        return history(poses, "direction", spec)[:, term.index]

    def regressor_label(self, term):
        return f"direction of the last move of {term.where['actuator']} (+1/-1)"

    def from_dict(self, data, spec=None):
        i, name, unit = _actuator(spec, data, self.name)
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit})

    def simulation_term(self, spec, size, rng, commands):
        """(term, theta) for the simulator: ``size`` the full play (mm for length controls)."""
        i = int(rng.integers(spec.n_u))
        return self.term(i, _actuator_where(spec, i)), np.array([0.5 * _size(spec, i, size, 1.0)])

    def physics(self, spec, size, rng, plan):
        """``size``: the full play (mm for length controls, else the control's unit), a deadband in the drive."""
        i = int(rng.integers(spec.n_u))
        return BacklashPhysics(i, spec.control_names[i], _size(spec, i, size, 1.0), spec.controls[i].unit)


# ---------------------------------------------------------------------------- compliance
def _urdf_of(spec: PlatformSpec) -> str | None:
    p = spec.extras.get("urdf_path")
    if p is not None and Path(p).is_file():
        return str(p)
    p = spec.description_path
    if p is not None and Path(p).suffix.lower() == ".urdf":
        return str(p)
    return None


@functools.lru_cache(maxsize=8)
def _gravity_model(urdf: str, joints: tuple[str, ...]):
    """pinocchio model of the whole URDF tree with every joint but ``joints`` locked at zero, and
    the q indices of ``joints`` (controls named otherwise, like the rotary's u1, u2, take the
    URDF's one-dof joints in order)."""
    import pinocchio as pin

    full = pin.buildModelFromUrdf(urdf)
    names = list(full.names[1:])
    use = list(joints) if all(j in names for j in joints) else \
        [n for n in names if full.joints[full.getJointId(n)].nq == 1][: len(joints)]
    if len(use) != len(joints):
        raise BadInput(f"{urdf}: cannot match the controls {', '.join(joints)} to the URDF's joints")
    lock = [full.getJointId(n) for n in names if n not in use]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    return model, [model.joints[model.getJointId(n)].idx_q for n in use]


def serial_gravity_torques(urdf: str, joints: tuple[str, ...], q: np.ndarray) -> np.ndarray:
    """(N, n) gravity torques (N m; N for prismatic joints) of ``joints`` at joint values q (N, n)
    (rad, m), from the URDF's inertias: pinocchio's computeGeneralizedGravity, gravity -z."""
    import pinocchio as pin

    model, order = _gravity_model(urdf, tuple(joints))
    data = model.createData()
    out = np.zeros((len(q), len(order)))
    for k, qk in enumerate(np.atleast_2d(q)):
        full_q = pin.neutral(model)
        full_q[order] = qk
        out[k] = pin.computeGeneralizedGravity(model, data, full_q)[order]
    return out


_MODELS: dict[int, tuple[PlatformSpec, Any]] = {}


def _platform_model(spec: PlatformSpec):
    """One PlatformModel per spec object (building one compiles CasADi functions)."""

    hit = _MODELS.get(id(spec))
    if hit is None or hit[0] is not spec:
        if len(_MODELS) > 16:
            _MODELS.clear()
        hit = _MODELS[id(spec)] = (spec, PlatformModel(spec))
    return hit[1]


def parallel_actuator_forces(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """(N, n_u) actuator forces f = J^-T w holding a 1 N weight (gravity along base -z) at the
    moving frame's origin, at the nominal geometry: from F_u du + F_p dp = 0, J = du/dp, and
    virtual work J^T f = dz/dp. Unit: N per N of payload weight (counts, rad: per unit)."""
    import casadi as ca

    model = _platform_model(spec)
    fk = model.forward_batch(controls, strict=False)
    p = ca.SX.sym("p", spec.n_p)
    _, X = spec.pose(p)
    dz_dp = ca.Function("dz_dp", [p], [ca.jacobian(X[2], p)])
    td = spec.nominal_td()
    out = np.zeros_like(np.atleast_2d(controls), dtype=float)
    for k, (u, pk) in enumerate(zip(np.atleast_2d(controls), fk.p)):
        _, F_p, F_u, _ = model.F_jac(u, td, pk)
        du_dp = -np.linalg.lstsq(np.asarray(F_u), np.asarray(F_p), rcond=None)[0]
        out[k] = np.linalg.lstsq(du_dp.T, np.asarray(dz_dp(pk)).ravel(), rcond=None)[0]
    return out


def actuator_loads(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """(N, n_u) the load each actuator carries: gravity torques from the URDF for serial chains,
    J^-T w for a unit payload weight otherwise (see the two functions above)."""
    controls = np.atleast_2d(np.asarray(controls, float))
    urdf = _urdf_of(spec)
    if urdf is not None:
        scale = np.array([np.pi / 180 if c.unit == "deg" else 1.0 for c in spec.controls])
        return serial_gravity_torques(urdf, tuple(spec.control_names), controls * scale)
    return parallel_actuator_forces(spec, controls)


_LOADS: dict[tuple, np.ndarray] = {}


def cached_loads(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """actuator_loads, once per (stand, controls array): terms ask for them at every evaluation."""
    key = (spec.name, str(spec.description_path), np.ascontiguousarray(controls, float).tobytes())
    if key not in _LOADS:
        if len(_LOADS) > 256:
            _LOADS.clear()
        _LOADS[key] = actuator_loads(spec, controls)
    return _LOADS[key]


@dataclass
class ComplianceTerm(ModelTerm):
    index: int | None = None  # None: one compliance for every actuator (parallel stands)
    spec: PlatformSpec | None = field(default=None, repr=False)

    def stand(self) -> PlatformSpec:
        if self.spec is None:

            w = self.where
            self.spec = get_platform(w["platform"], w.get("description"), **(w.get("platform_options") or {}))
        return self.spec

    def control_offset(self, theta, poses, n_u):
        loads = cached_loads(self.stand(), poses.controls)
        out = np.zeros((poses.n_poses, n_u))
        if self.index is None:
            out[:] = theta[0] * loads
        else:
            out[:, self.index] = theta[0] * loads[:, self.index]
        return out


def _stand_where(spec: PlatformSpec) -> dict:
    chain = spec.extras.get("chain")
    options = {}
    if chain is not None and spec.name == "urdf":
        options = {"base_link": chain.base_link, "moving_link": chain.moving_link}
    return {"platform": spec.name, "description": None if spec.description_path is None else str(spec.description_path),
            "platform_options": options}


class Compliance(Effect):
    name = "compliance"
    summary = "deflection that grows with the load an actuator or joint carries"

    def term(self, spec, i):
        if i is None:
            unit = spec.controls[0].unit
            where = {"actuator": "all", "unit": unit, "load": "actuator force J^-T w for a 1 N payload weight"}
            where.update(_stand_where(spec))
            return ComplianceTerm(self.name, ["deflection_per_newton_payload"], np.zeros(1), [f"{unit}/N"], where,
                                  index=None, spec=spec)
        where = _actuator_where(spec, i)
        load_unit = "N" if spec.controls[i].unit == "m" else "N m"
        where.update({"load": f"gravity torque from the URDF inertias ({load_unit})"})
        where.update(_stand_where(spec))
        return ComplianceTerm(self.name, ["compliance"], np.zeros(1), [f"{where['unit']}/({load_unit})"], where,
                              index=i, spec=spec)

    def candidates(self, spec, poses, residuals=None):
        loads = cached_loads(spec, poses.controls)
        if _urdf_of(spec) is None:
            return [self.term(spec, None)] if np.ptp(loads) > 0 else []
        return [self.term(spec, i) for i in range(spec.n_u) if np.ptp(loads[:, i]) > 1e-9]

    def regressor(self, term, spec, poses):
        loads = cached_loads(spec, poses.controls)
        return loads[:, term.index] if term.index is not None else loads @ np.sign(np.mean(loads, axis=0))

    def regressor_label(self, term):
        if term.index is None:
            return "sum of the actuator forces for a 1 N payload (N/N)"
        return f"gravity load on {term.where['actuator']} ({term.where['load'].split('(')[-1].rstrip(')')})"

    def from_dict(self, data, spec=None):
        where = _where(data)
        if spec is None:

            if not isinstance(where.get("platform"), str):
                raise BadInput("effect 'compliance': where.platform must name the stand the loads come from")
            spec = get_platform(where["platform"], where.get("description"), **(where.get("platform_options") or {}))
        if where.get("actuator") == "all":
            return self.term(spec, None)
        i, _, _ = _actuator(spec, data, self.name)
        return self.term(spec, i)

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the largest deflection of an actuator over the commands (mm for lengths)."""
        loads = cached_loads(spec, commands.controls)
        if _urdf_of(spec) is None:
            term = self.term(spec, None)
            j = int(np.argmax(np.max(np.abs(loads), axis=0)))
        else:
            span = np.ptp(loads, axis=0)
            j = int(rng.choice(np.nonzero(span >= 0.5 * span.max())[0]))
            term = self.term(spec, j)
        peak = float(np.max(np.abs(loads[:, j])))
        if not peak > 0:
            raise BadInput(f"effect compliance: the {spec.name} stand carries no load on its actuators")
        return term, np.array([_size(spec, j, size, 1.0) / peak])

    def physics(self, spec, size, rng, plan):
        """``size``: the largest deflection of an actuator over the commands (mm for lengths)."""
        loads = cached_loads(spec, plan.commands)
        start = actuator_loads(spec, plan.start[None])[0]
        if _urdf_of(spec) is None:
            j, index, where = int(np.argmax(np.max(np.abs(loads), axis=0))), None, {"actuator": "all"}
        else:
            span = np.ptp(loads, axis=0)
            j = int(rng.choice(np.nonzero(span >= 0.5 * span.max())[0]))
            index, where = j, {"actuator": spec.control_names[j]}
        peak = float(np.max(np.abs(loads[:, j])))
        if not peak > 0:
            raise BadInput(f"effect compliance: the {spec.name} stand carries no load on its actuators")
        return CompliancePhysics(_size(spec, j, size, 1.0) / peak, loads, start, index, spec.controls[j].unit, where)


# ---------------------------------------------------------------------------- thermal drift
#: cooling time constants (s) a thermal drift is screened at, a factor sqrt(2) apart (the simulator
#: draws 5 to 15 min); the score test picks among them
COOLING_TAUS_S = tuple(float(round(150.0 * 2 ** (k / 2))) for k in range(11))  # 150 s to 80 min


def motion_heat(poses: PoseSet, stroke: np.ndarray, tau_s: float) -> np.ndarray:
    """(N, n_u) each actuator's heat at each pose: the strokes it moved, cooling with ``tau_s``,
    ``theta_n = sum_k |u_k - u_(k-1)| / stroke exp(-(t_n - t_k) / tau)`` over the moves up to row n
    (rows in session order, times from the first command). A gap in the rows (commands that gave
    no pose) hides moves: a gap of g commands counts the move across it times g m1 / m_gap, the
    mean single move over the mean move across gaps (per actuator, between 1 and g): g times for
    a random plan, once for a sweep. Computed on the full session and kept by subsets (the key
    'heat_<tau>' of ``extras``), so a fold's refit sees the same heat."""
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
    move = np.abs(np.diff(U[order], axis=0)) / stroke
    gap = np.maximum(np.diff(row[order]), 1.0)[:, None]
    single = gap[:, 0] == 1
    if np.any(~single):
        m1 = np.mean(move[single], axis=0) if single.sum() >= 3 else np.mean(move / gap, axis=0)
        across = np.sum(move[~single], axis=0) / np.sum(gap[~single], axis=0)  # move across a gap, per command
        with np.errstate(divide="ignore", invalid="ignore"):
            factor = np.where(across > 0, m1 / across, 1.0)  # g m1 / m_gap
        move = np.where(gap > 1, move * np.clip(factor, 1.0, gap), move)
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


# ---------------------------------------------------------------------------- cyclic error
#: candidate periods per control unit: one turn and its harmonics; screw leads for 'm'
PERIODS = {
    "rad": (2 * np.pi, np.pi, 2 * np.pi / 3, np.pi / 2),
    "deg": (360.0, 180.0, 120.0, 90.0),
    "m": (0.02, 0.01, 0.005),
    "count": (1024.0, 512.0, 256.0),
}


@dataclass
class CyclicTerm(ModelTerm):
    index: int = 0
    period: float = 1.0

    def control_offset(self, theta, poses, n_u):
        phase = 2 * np.pi * poses.controls[:, self.index] / self.period
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * np.sin(phase) + theta[1] * np.cos(phase)
        return out


class CyclicError(Effect):
    name = "cyclic_error"
    summary = "an error periodic in an actuator's angle or travel (gear or encoder eccentricity)"

    def term(self, i, where, period):
        where = dict(where, period=float(period))
        return CyclicTerm(self.name, ["sin_amplitude", "cos_amplitude"], np.zeros(2), [where["unit"]] * 2, where,
                          index=i, period=float(period))

    def candidates(self, spec, poses, residuals=None):
        out = []
        for i, c in enumerate(spec.controls):
            travel = np.ptp(poses.controls[:, i])
            for P in PERIODS.get(c.unit, ()):
                if travel > P / 2:  # less than half a period seen is an offset and a slope
                    out.append(self.term(i, _actuator_where(spec, i), P))
        return out

    def regressor(self, term, spec, poses):
        return np.mod(poses.controls[:, term.index], term.period) / term.period

    def regressor_label(self, term):
        return f"phase of {term.where['actuator']} in a period of {term.period:g} {term.where['unit']} (turns)"

    def from_dict(self, data, spec=None):
        i, name, unit = _actuator(spec, data, self.name)
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit},
                         _number(_where(data), "period", self.name, positive=True))

    def simulation_term(self, spec, size, rng, commands):
        """``size``: amplitude (mm for lengths); period: one of PERIODS the commands span."""
        options = [(i, P) for i, c in enumerate(spec.controls) for P in PERIODS.get(c.unit, ())
                   if np.ptp(commands.controls[:, i]) > P / 2]
        if not options:
            raise BadInput(f"effect cyclic_error: no actuator of {spec.name} spans half of a known period")
        i, P = options[int(rng.integers(len(options)))]
        a = _size(spec, i, size, 0.3)
        ph = rng.uniform(0, 2 * np.pi)
        return self.term(i, _actuator_where(spec, i), P), np.array([a * np.cos(ph), a * np.sin(ph)])

    def physics(self, spec, size, rng, plan):
        """``size``: the amplitude (mm for lengths) of a gear's error periodic in the actuator's true position."""
        options = [(i, P) for i, c in enumerate(spec.controls) for P in PERIODS.get(c.unit, ())
                   if np.ptp(plan.commands[:, i]) > P / 2]
        if not options:
            raise BadInput(f"effect cyclic_error: no actuator of {spec.name} spans half of a known period")
        i, P = options[int(rng.integers(len(options)))]
        a = _size(spec, i, size, 0.3)
        ph = rng.uniform(0, 2 * np.pi)
        return CyclicPhysics(i, spec.control_names[i], P, a * np.cos(ph), a * np.sin(ph), spec.controls[i].unit)


# ---------------------------------------------------------------------------- scale nonlinearity
@dataclass
class ScaleTerm(ModelTerm):
    index: int = 0
    lower: float = 0.0
    upper: float = 1.0

    def travel(self, controls):
        return (2 * controls[:, self.index] - (self.lower + self.upper)) / (self.upper - self.lower)

    def control_offset(self, theta, poses, n_u):
        s = self.travel(poses.controls)
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * 0.5 * (3 * s**2 - 1) + theta[1] * 0.5 * (5 * s**3 - 3 * s)
        return out


class ScaleNonlinearity(Effect):
    name = "scale_nonlinearity"
    summary = "an actuator's travel not linear in its command"

    def term(self, i, where, lower, upper):
        where = dict(where, travel=[float(lower), float(upper)])
        return ScaleTerm(self.name, ["quadratic", "cubic"], np.zeros(2), [where["unit"]] * 2, where,
                         index=i, lower=float(lower), upper=float(upper))

    def candidates(self, spec, poses, residuals=None):
        out = []
        for i, c in enumerate(spec.controls):
            lo, hi = c.lower, c.upper
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                lo, hi = float(np.min(poses.controls[:, i])), float(np.max(poses.controls[:, i]))
            if hi > lo and np.ptp(poses.controls[:, i]) > 0.2 * (hi - lo):
                out.append(self.term(i, _actuator_where(spec, i), lo, hi))
        return out

    def regressor(self, term, spec, poses):
        return term.travel(poses.controls)

    def regressor_label(self, term):
        return f"travel of {term.where['actuator']} over its stroke (-1..1)"

    def from_dict(self, data, spec=None):
        i, name, unit = _actuator(spec, data, self.name)
        travel = _where(data).get("travel")
        if not (isinstance(travel, list) and len(travel) == 2 and all(isinstance(v, (int, float)) for v in travel)
                and travel[1] > travel[0]):
            raise BadInput("effect 'scale_nonlinearity': where.travel must be [lower, upper] with lower < upper")
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit}, *travel)

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the largest deviation from linear travel, at the stroke ends (mm for lengths)."""
        terms = self.candidates(spec, commands)
        if not terms:
            raise BadInput(f"effect scale_nonlinearity: the commands use too little of {spec.name}'s strokes")
        t = terms[int(rng.integers(len(terms)))]
        return t, np.array([_size(spec, t.index, size, 1.0), 0.0])

    def physics(self, spec, size, rng, plan):
        """``size``: the largest deviation from linear travel, at the stroke ends (mm for lengths)."""
        terms = [t for t in self.candidates(spec, PoseSet(spec.name, plan.commands, np.zeros((len(plan.commands), 0, 3)), []))]
        if not terms:
            raise BadInput(f"effect scale_nonlinearity: the commands use too little of {spec.name}'s strokes")
        t = terms[int(rng.integers(len(terms)))]
        return ScalePhysics(t.index, t.where["actuator"], t.lower, t.upper, _size(spec, t.index, size, 1.0), 0.0,
                            t.where["unit"])


# ---------------------------------------------------------------------------- settling lag
@dataclass
class SettlingTerm(ModelTerm):
    def control_offset(self, theta, poses, n_u):
        return -theta[0] * history(poses, "last_step")


class SettlingLag(Effect):
    name = "settling_lag"
    summary = "the pose was recorded before the platform settled"

    def term(self):
        return SettlingTerm(self.name, ["lag_fraction"], np.zeros(1), ["1"],
                            {"actuator": "all", "along": "the last move, a fraction of its size"})

    def candidates(self, spec, poses, residuals=None):
        return [self.term()] if poses.n_poses > 2 else []

    def regressor(self, term, spec, poses):
        lo, hi = spec.control_bounds()
        span = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
        return np.linalg.norm(history(poses, "last_step") / span, axis=1)

    def regressor_label(self, term):
        return "size of the last move (fraction of the strokes)"

    def from_dict(self, data, spec=None):
        return self.term()

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the fraction of the last step not yet made."""
        return self.term(), np.array([0.003 if size is None else float(size)])

    def physics(self, spec, size, rng, plan):
        """``size``: the time constant of one slow actuator, as a share of the hold (default 0.5)."""
        i = int(rng.integers(spec.n_u))
        share = 0.5 if size is None else float(size)
        if not share > 0:
            raise BadInput("effect settling_lag: the slow actuator's time constant must be a positive share of the hold")
        return SlowActuator(i, spec.control_names[i], share * plan.hold_s, share)


# ---------------------------------------------------------------------------- marker slip
def change_point(series: np.ndarray, min_segment: int = 3) -> tuple[int, float]:
    """The split k (rows k.. after it) that best separates the means of ``series`` (N, d) rows in
    time order: (k, F statistic of the step with d and n - 2d degrees of freedom); (-1, 0) when
    too short. Rows with NaN are skipped (k indexes the original rows)."""
    ok = np.all(np.isfinite(series), axis=1)
    idx = np.nonzero(ok)[0]
    x = series[ok] - series[ok].mean(axis=0)
    n, d = x.shape
    if n < 2 * min_segment + 1:
        return -1, 0.0
    csum = np.cumsum(x, axis=0)
    j = np.arange(min_segment, n - min_segment + 1)
    explained = np.sum(csum[j - 1] ** 2, axis=1) * n / (j * (n - j))
    b = int(np.argmax(explained))
    best = float(explained[b])
    F = (best / d) / max((np.sum(x**2) - best) / max(n - 2 * d, 1), 1e-300)
    return int(idx[j[b]]), float(F)


#: a slip moves one marker: at its split, its step is at least this many times any other marker's
SLIP_DOMINANCE = 3.0


def one_marker_steps(residuals: np.ndarray, k: int, m: int, dominance: float = SLIP_DOMINANCE) -> bool:
    """Whether the step at split k (rows k.. after it) of marker m's residuals (N, M, 3, moving
    frame, time order) is at least ``dominance`` times every other marker's step there: a slip
    moves one marker and leaves the others consistent; a step all markers share (the frame, a
    drift of the stand's actuators) is no slip."""
    with np.errstate(invalid="ignore"):
        step = np.linalg.norm(np.nanmean(residuals[k:], axis=0) - np.nanmean(residuals[:k], axis=0), axis=1)
    others = np.delete(step, m)
    others = others[np.isfinite(others)]
    return bool(np.isfinite(step[m]) and (others.size == 0 or step[m] >= dominance * np.max(others)))


@dataclass
class MarkerSlipTerm(ModelTerm):
    marker: int = 0
    t_slip: float = 0.0

    def marker_offset(self, theta, poses, *args):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[history(poses, "elapsed") >= self.t_slip, self.marker] = np.asarray(theta)[:3]
        return out


class MarkerSlip(Effect):
    name = "marker_slip"
    summary = "a marker moved on the platform during the session"

    def term(self, name, m, t_slip):
        return MarkerSlipTerm(self.name, ["dx", "dy", "dz"], np.zeros(3), ["m"] * 3,
                              {"marker": str(name), "marker_index": int(m), "from_time_s": float(t_slip)},
                              marker=int(m), t_slip=float(t_slip))

    def candidates(self, spec, poses, residuals=None):
        if residuals is None or poses.n_markers < 2:
            return []
        t = history(poses, "elapsed")
        order = np.argsort(t, kind="stable")
        out = []
        ts = t[order]
        for m in range(poses.n_markers):
            k, _ = change_point(residuals[order, m, :])
            if k > 0 and not one_marker_steps(residuals[order], k, m):
                continue
            # the geometry absorbs part of a step, which can move the residual's change point by
            # a row: the neighbours are candidates too, and the score test picks among them
            for j in (k - 1, k, k + 1):
                if k > 0 and 1 <= j < len(ts):
                    out.append(self.term(poses.marker_names[m], m, 0.5 * (ts[j - 1] + ts[j])))
        return out

    def regressor(self, term, spec, poses):
        return (history(poses, "elapsed") >= term.t_slip).astype(float)

    def regressor_label(self, term):
        return f"before (0) or after (1) {term.t_slip:.4g} s"

    def from_dict(self, data, spec=None):
        where = _where(data)
        m = where.get("marker_index")
        if isinstance(m, bool) or not isinstance(m, int) or m < 0:
            raise BadInput("effect 'marker_slip': where.marker_index must be an integer >= 0")
        return self.term(where.get("marker", m), m, _number(where, "from_time_s", self.name))

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the jump in mm, halfway through the session, of a random marker."""
        m = int(rng.integers(commands.n_markers))
        t = history(commands, "elapsed")
        t_slip = 0.5 * (t[len(t) // 2 - 1] + t[len(t) // 2])
        d = rng.normal(size=3)
        d *= (2.0 if size is None else float(size)) * 1e-3 / np.linalg.norm(d)
        return self.term(commands.marker_names[m], m, t_slip), d

    def physics(self, spec, size, rng, plan):
        """``size``: the jump in mm of a random marker, at a random instant in the middle half of the session."""
        m = int(rng.integers(len(plan.marker_names)))
        t0 = float(plan.command_t[0])
        t_s = float(rng.uniform(t0 + 0.25 * (plan.end_s - t0), t0 + 0.75 * (plan.end_s - t0)))
        d = rng.normal(size=3)
        d *= (2.0 if size is None else float(size)) * 1e-3 / np.linalg.norm(d)
        return MarkerSlipPhysics(m, plan.marker_names[m], t_s, d)


# ---------------------------------------------------------------------------- base tilt
@dataclass
class BaseTiltTerm(ModelTerm):
    def pose_offset(self, theta, poses, fk_q, fk_X):
        w = np.array([theta[0], theta[1], 0.0])
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = np.cross(w[None, :], fk_X)
        out[:, 3:] = w
        return out


class BaseTilt(Effect):
    name = "base_tilt"
    summary = "the base, or the mocap vertical, tilted against the model's"

    def term(self):
        return BaseTiltTerm(self.name, ["tilt_x", "tilt_y"], np.zeros(2), ["rad", "rad"], {"frame": "base"})

    def candidates(self, spec, poses, residuals=None):
        return [self.term()]

    def regressor(self, term, spec, poses):
        z = _platform_model(spec).forward_batch(poses.controls, strict=False).X[:, 2]
        return z - np.mean(z)

    def regressor_label(self, term):
        return "height of the moving frame above its mean (m)"

    def from_dict(self, data, spec=None):
        return self.term()

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the tilt in mrad, about a random horizontal axis."""
        a = rng.uniform(0, 2 * np.pi)
        return self.term(), (2.0 if size is None else float(size)) * 1e-3 * np.array([np.cos(a), np.sin(a)])

    def physics(self, spec, size, rng, plan):
        """``size``: the tilt in mrad of the base against the level world, about a random horizontal axis."""
        a = rng.uniform(0, 2 * np.pi)
        return BaseTiltPhysics((2.0 if size is None else float(size)) * 1e-3 * np.array([np.cos(a), np.sin(a)]))


EFFECTS = [Backlash(), Compliance(), ThermalDrift(), CyclicError(), ScaleNonlinearity(), SettlingLag(), MarkerSlip(),
           BaseTilt()]


@hookimpl
def platkit_register_effects():
    return list(EFFECTS) + list(IMU_EFFECTS)
