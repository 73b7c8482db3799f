"""Hidden effects for simulated sessions, as model terms (platkit.terms.ModelTerm).

An effect is put into a simulation as a pair (term, theta): the term's ``control_offset``,
``pose_offset`` and ``marker_offset`` are evaluated on the command rows (a PoseSet whose ``t`` is
the command times and whose extras hold 'direction', 'last_step' and 'elapsed', exactly as the settled poses
have them), so the same term class fitted by diagnosis reproduces what was simulated.

``simulation_term(name, spec, size, rng, commands)`` looks the name up first among the effects
registered through the ``platkit_register_effects`` hook (an effect object offering
``simulation_term(spec, size, rng, commands) -> (term, theta)``), then among the simple ones
here. Sizes are in the units :data:`EFFECT_SIZES` states.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import matrix_from_rotvec
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.plugins import default_host
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: effect -> (what ``size`` means, default size)
EFFECT_SIZES = {
    "backlash": ("play of one actuator, full width, in mm for length controls (else the control's unit)", 1.0),
    "compliance": ("largest deflection of an actuator under the platform's weight, mm or the control's unit", 1.0),
    "thermal_drift": ("drift of the moving frame along base z, mm per hour", 2.0),
    "cyclic_error": ("amplitude of an error periodic in one actuator's travel, mm or the control's unit", 0.3),
    "scale_nonlinearity": ("largest deviation of one actuator from linear travel, mm or the control's unit", 1.0),
    "settling_lag": ("fraction of the last command step not yet reached when recorded", 0.003),
    "marker_slip": ("jump of one marker on the moving part halfway through the session, mm", 2.0),
    "base_tilt": ("tilt of the base against the model's vertical, mrad", 2.0),
}


def _control_size(spec: PlatformSpec, j: int, size: float) -> float:
    """``size`` in SI for control j: mm -> m for length controls, else the control's unit."""
    return size * 1e-3 if spec.controls[j].unit == "m" else size


def _unit(spec: PlatformSpec, j: int) -> str:
    return spec.controls[j].unit


@dataclass
class Backlash(ModelTerm):
    """Actuator ``actuator`` sits theta/2 further along the direction it last moved."""

    actuator: int = 0

    def control_offset(self, theta, poses: PoseSet, n_u: int):
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.actuator] = 0.5 * theta[0] * poses.extras["direction"][:, self.actuator]
        return out


@dataclass
class SettlingLag(ModelTerm):
    """Every actuator short of its command by theta x the last command step."""

    def control_offset(self, theta, poses: PoseSet, n_u: int):
        return -theta[0] * np.asarray(poses.extras["last_step"], float)


@dataclass
class CyclicError(ModelTerm):
    """Actuator error a sin(2 pi u / period) + b cos(2 pi u / period); theta = (a, b)."""

    actuator: int = 0
    period: float = 1.0

    def control_offset(self, theta, poses: PoseSet, n_u: int):
        out = np.zeros((poses.n_poses, n_u))
        ph = 2 * np.pi * poses.controls[:, self.actuator] / self.period
        out[:, self.actuator] = theta[0] * np.sin(ph) + theta[1] * np.cos(ph)
        return out


@dataclass
class ScaleNonlinearity(ModelTerm):
    """Actuator error theta x s^2, s in [-1, 1] across the stroke [lower, upper]."""

    actuator: int = 0
    lower: float = 0.0
    upper: float = 1.0

    def control_offset(self, theta, poses: PoseSet, n_u: int):
        out = np.zeros((poses.n_poses, n_u))
        s = (2 * poses.controls[:, self.actuator] - self.lower - self.upper) / (self.upper - self.lower)
        out[:, self.actuator] = theta[0] * s**2
        return out


@dataclass
class ThermalDrift(ModelTerm):
    """The moving frame drifts along base z at theta (m/s) times the time since the first command."""

    def pose_offset(self, theta, poses: PoseSet, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        out[:, 2] = theta[0] * np.asarray(poses.extras["elapsed"], float)
        return out


@dataclass
class MarkerSlip(ModelTerm):
    """Marker ``marker`` moves by theta (3,) m on the moving part at time ``t_slip``."""

    marker: int = 0
    t_slip: float = 0.0

    def marker_offset(self, theta, poses: PoseSet):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[np.nan_to_num(poses.t) >= self.t_slip, self.marker] = theta[:3]
        return out


@dataclass
class BaseTilt(ModelTerm):
    """The whole stand rotated about the base origin by the rotation vector (theta_x, theta_y, 0)."""

    def pose_offset(self, theta, poses: PoseSet, fk_q, fk_X):
        rv = np.array([theta[0], theta[1], 0.0])
        R = matrix_from_rotvec(rv)
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = fk_X @ R.T - fk_X
        out[:, 3:] = rv
        return out


@dataclass
class Compliance(ModelTerm):
    """Actuators yield by theta x the load each carries under a unit weight at the moving
    frame's origin (loads from the stand's residual: F_p^T lambda = -dX/dp^T (0, 0, -1),
    load = F_u^T lambda)."""

    spec: Any = None
    _model: Any = field(default=None, repr=False)

    def loads(self, poses: PoseSet) -> np.ndarray:

        if self._model is None:
            self._model = PlatformModel(self.spec)
        model = self._model
        td = self.spec.nominal_td()
        fb = model.forward_batch(poses.controls, strict=False)
        out = np.zeros((poses.n_poses, self.spec.n_u))
        import casadi as ca

        p = ca.SX.sym("p", self.spec.n_p)
        dXdp = ca.Function("dXdp", [p], [ca.jacobian(self.spec.pose(p)[1], p)])
        for i in range(poses.n_poses):
            _, F_p, F_u, _ = (np.asarray(a) for a in model.F_jac(poses.controls[i], td, fb.p[i]))
            Q = np.asarray(dXdp(fb.p[i])).T @ np.array([0.0, 0.0, -1.0])
            lam = np.linalg.lstsq(F_p.T, -Q, rcond=None)[0]
            out[i] = F_u.T @ lam
        return out

    def control_offset(self, theta, poses: PoseSet, n_u: int):
        return theta[0] * self.loads(poses)


def builtin_term(name: str, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                 commands: PoseSet) -> tuple[ModelTerm, np.ndarray]:
    """A simple built-in effect as (term, true theta). ``commands``: the command rows."""
    if name not in EFFECT_SIZES:
        raise BadInput(f"unknown effect {name!r}; known: {', '.join(EFFECT_SIZES)}")
    size = EFFECT_SIZES[name][1] if size is None else float(size)
    j = int(rng.integers(spec.n_u))
    cname = spec.controls[j].name
    if name == "backlash":
        th = _control_size(spec, j, size)
        return Backlash("backlash", ["width"], np.zeros(1), [_unit(spec, j)], {"actuator": cname}, actuator=j), np.array([th])
    if name == "settling_lag":
        return SettlingLag("settling_lag", ["fraction"], np.zeros(1), ["1"], {"actuators": "all"}), np.array([size])
    if name == "cyclic_error":
        c = spec.controls[j]
        period = (c.upper - c.lower) / 8.0
        amp = _control_size(spec, j, size)
        ph = rng.uniform(0, 2 * np.pi)
        return (CyclicError("cyclic_error", ["a_sin", "b_cos"], np.zeros(2), [c.unit] * 2,
                            {"actuator": cname, "period": float(period)}, actuator=j, period=period),
                np.array([amp * np.cos(ph), amp * np.sin(ph)]))
    if name == "scale_nonlinearity":
        c = spec.controls[j]
        return (ScaleNonlinearity("scale_nonlinearity", ["quadratic"], np.zeros(1), [c.unit],
                                  {"actuator": cname}, actuator=j, lower=c.lower, upper=c.upper),
                np.array([_control_size(spec, j, size)]))
    if name == "thermal_drift":
        return ThermalDrift("thermal_drift", ["rate_z"], np.zeros(1), ["m/s"], {"frame": "moving"}), np.array([size * 1e-3 / 3600.0])
    if name == "marker_slip":
        k = int(rng.integers(commands.n_markers))
        t = commands.t
        t_slip = float(t[len(t) // 2])
        d = rng.normal(size=3)
        d *= size * 1e-3 / np.linalg.norm(d)
        return (MarkerSlip("marker_slip", ["dx", "dy", "dz"], np.zeros(3), ["m"] * 3,
                           {"marker": commands.marker_names[k], "t_from": t_slip}, marker=k, t_slip=t_slip), d)
    if name == "base_tilt":
        a = rng.uniform(0, 2 * np.pi)
        return BaseTilt("base_tilt", ["rx", "ry"], np.zeros(2), ["rad"] * 2, {"frame": "base"}), size * 1e-3 * np.array([np.cos(a), np.sin(a)])
    # compliance: scale theta so the largest actuator deflection over the commands is ``size``
    term = Compliance("compliance", ["compliance"], np.zeros(1), ["per unit load"], {"actuators": "all"}, spec=spec)
    loads = term.loads(commands)
    peak = float(np.max(np.abs(loads)))
    if not peak > 0:
        raise BadInput(f"effect compliance: the {spec.name} stand carries no load along its actuators")
    jmax = int(np.argmax(np.max(np.abs(loads), axis=0)))
    return term, np.array([_control_size(spec, jmax, size) / peak])


def size_help() -> dict[str, str]:
    """Effect name -> what its size means: a registered effect's ``simulation_term`` docstring,
    else the built-in one's."""

    out = {n: f"{what} (default {d:g})" for n, (what, d) in EFFECT_SIZES.items()}
    for name, effect in default_host().effects().items():
        doc = getattr(getattr(effect, "simulation_term", None), "__doc__", None)
        if doc:
            text = " ".join(doc.split()).replace("``", "")
            for prefix in ("(term, theta) for the simulator:", "size:", "size"):
                text = text[len(prefix):].strip() if text.startswith(prefix) else text
            out[name] = text.rstrip(".")
    return out


def simulation_term(name: str, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                    commands: PoseSet) -> tuple[ModelTerm, np.ndarray]:
    """An effect by name as (term, theta): a registered effect's own ``simulation_term`` if it
    has one, else the built-in simple version."""

    registered = default_host().effects().get(name)
    if registered is not None and hasattr(registered, "simulation_term"):
        return registered.simulation_term(spec, size, rng, commands)
    return builtin_term(name, spec, size, rng, commands)


def parse_effect(text: str) -> tuple[str, float | None]:
    """'backlash:1.5' (or 'backlash=1.5') -> ('backlash', 1.5); 'backlash' -> ('backlash', None)."""
    name, _, size = text.partition(":" if ":" in text else "=")
    name = name.strip()
    if not name:
        raise BadInput(f"--effect {text!r}: expected NAME or NAME:SIZE")
    if not size:
        return name, None
    try:
        value = float(size)
    except ValueError:
        raise BadInput(f"--effect {text!r}: the size after ':' must be a number") from None
    if not np.isfinite(value) or value < 0:
        raise BadInput(f"--effect {text!r}: the size must be a finite number, 0 or more (it is a magnitude)")
    return name, value
