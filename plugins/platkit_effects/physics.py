"""The physics of the built-in effects, as the time-domain simulator (platkit.simulate.physics)
plays it out: each class is an :class:`platkit.effects.EffectPhysics` with its true parameters.
The effects in ``platkit_effects`` build them (``Effect.physics``); their model terms are what
diagnosis fits.

- backlash (drive): a deadband of width ``play`` between the drive and the actuator's output;
  the output stays until the drive has taken up the play, so at rest it trails the command by
  play/2 against the direction of approach.
- cyclic_error (drive): the output off by a sin(2 pi m / P) + b cos(2 pi m / P) of the drive's
  position m (a gear's or an encoder's eccentricity).
- scale_nonlinearity (drive): the output off by a P2(s) + b P3(s), s the drive's position over
  the stroke.
- thermal_drift (drive): each actuator lengthens by k theta_j; theta_j heats with the distance
  it moves (in strokes) and cools with time constant tau: theta' = |m'| / stroke - theta / tau.
  (The warm-up with time since power-on, the effect's other physical form, is a nuisance of the
  recording drawn by the simulator itself: platkit.simulate.warmup.)
- compliance (drive): each actuator yields by c f_j, f the load it carries (payload statics at
  the commanded pose, blended between poses along a move).
- settling_lag (response): one actuator slow, its time constant a given share of the hold.
- marker_slip (markers): one marker moves on the platform by d at the instant t_s.
- base_tilt (base): the base turned about its x and y axes against the level world (the mocap
  vertical).

Internal units (m for length controls, the control's unit otherwise), seconds, SI elsewhere.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.effects import EffectPhysics, PhysicsPlan, PhysicsSeries

__all__ = ["play_operator", "BacklashPhysics", "CyclicPhysics", "ScalePhysics", "ThermalPhysics", "CompliancePhysics",
           "SlowActuator", "MarkerSlipPhysics", "BaseTiltPhysics", "thermal_state"]


def play_operator(x: np.ndarray, width: float, start: float, tolerance: float = 0.0) -> np.ndarray:
    """(K,) the output of a deadband (play) of ``width`` driven by ``x`` (K,), starting at
    ``start``: the output moves only when the input is more than width/2 away, and then trails
    it by width/2. Moves of the input smaller than ``tolerance`` do not turn its direction."""
    x = np.asarray(x, float)
    h = 0.5 * float(width)
    y = np.empty_like(x)
    if x.size == 0:
        return y
    dx = np.diff(x)
    s = np.where(np.abs(dx) > tolerance, np.sign(dx), 0.0)
    # carry the last real direction across samples that hardly move
    idx = np.where(s != 0, np.arange(s.size), -1)
    np.maximum.accumulate(idx, out=idx)
    s = np.where(idx >= 0, s[np.maximum(idx, 0)], 0.0)
    turns = np.nonzero(np.diff(s) != 0)[0] + 1  # dx index where a run of one direction starts
    bounds = np.concatenate([[0], turns, [s.size]])
    cur = float(np.clip(start, x[0] - h, x[0] + h))
    y[0] = cur
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b <= a:
            continue
        seg = x[a + 1:b + 1]
        d = s[a]
        if d > 0:
            y[a + 1:b + 1] = np.maximum(cur, seg - h)
        elif d < 0:
            y[a + 1:b + 1] = np.minimum(cur, seg + h)
        else:
            y[a + 1:b + 1] = np.clip(cur, seg - h, seg + h)
        cur = float(y[b])
    return y


def _with_column(motor: np.ndarray, j: int, column: np.ndarray) -> np.ndarray:
    out = np.array(motor, float, copy=True)
    out[:, j] = column
    return out


@dataclass
class BacklashPhysics(EffectPhysics):
    """Play of width ``play`` in the drive of actuator ``index`` (named ``actuator``)."""

    index: int
    actuator: str
    play: float
    unit: str
    effect: str = "backlash"

    def parameters(self):
        return {"actuator": self.actuator, "play": float(self.play), "unit": self.unit,
                "model_half_play": -0.5 * float(self.play)}

    def drive(self, series: PhysicsSeries, plan: PhysicsPlan):
        m = series.motor[:, self.index]
        lo, hi = plan.spec.control_bounds()
        span = hi[self.index] - lo[self.index]
        tol = 1e-9 * (span if np.isfinite(span) and span > 0 else 1.0)
        return _with_column(series.motor, self.index, play_operator(m, self.play, m[0], tol))


@dataclass
class CyclicPhysics(EffectPhysics):
    """Actuator ``index`` off by a sin(2 pi m / period) + b cos(2 pi m / period)."""

    index: int
    actuator: str
    period: float
    a: float
    b: float
    unit: str
    effect: str = "cyclic_error"

    def parameters(self):
        return {"actuator": self.actuator, "period": float(self.period), "sin_amplitude": float(self.a),
                "cos_amplitude": float(self.b), "unit": self.unit}

    def drive(self, series, plan):
        m = series.motor[:, self.index]
        ph = 2 * np.pi * m / self.period
        return _with_column(series.motor, self.index, m + self.a * np.sin(ph) + self.b * np.cos(ph))


@dataclass
class ScalePhysics(EffectPhysics):
    """Actuator ``index`` off by a P2(s) + b P3(s), s = its position over [lower, upper] in [-1, 1]."""

    index: int
    actuator: str
    lower: float
    upper: float
    quadratic: float
    cubic: float
    unit: str
    effect: str = "scale_nonlinearity"

    def parameters(self):
        return {"actuator": self.actuator, "travel": [float(self.lower), float(self.upper)],
                "quadratic": float(self.quadratic), "cubic": float(self.cubic), "unit": self.unit}

    def drive(self, series, plan):
        m = series.motor[:, self.index]
        s = (2 * m - self.lower - self.upper) / (self.upper - self.lower)
        err = self.quadratic * 0.5 * (3 * s**2 - 1) + self.cubic * 0.5 * (5 * s**3 - 3 * s)
        return _with_column(series.motor, self.index, m + err)


def thermal_state(t: np.ndarray, motor: np.ndarray, stroke: np.ndarray, tau_s: float) -> np.ndarray:
    """(K, n_u) heat of each actuator: theta_k = exp(-dt / tau) theta_(k-1) + |m_k - m_(k-1)| / stroke,
    cold at the first sample; ``t`` (K,) evenly spaced (its median step is used)."""
    if len(t) < 2:
        return np.zeros_like(motor)
    dt = float(np.median(np.diff(t)))
    # imported here, not at the top: every stand lookup loads this plugin, and scipy.signal takes
    # longer to import than all of `platkit fk`
    from scipy.signal import lfilter

    heat = np.vstack([np.zeros((1, motor.shape[1])), np.abs(np.diff(motor, axis=0)) / stroke])
    return lfilter([1.0], [1.0, -np.exp(-dt / tau_s)], heat, axis=0)


@dataclass
class ThermalPhysics(EffectPhysics):
    """Every actuator lengthens by ``coefficient`` x its heat (strokes moved, first-order cooling
    with ``tau_s``); ``largest`` the largest lengthening over the session's rest series."""

    coefficient: float
    tau_s: float
    stroke: np.ndarray
    largest: float
    unit: str
    effect: str = "thermal_drift"

    def parameters(self):
        return {"actuator": "all", "coefficient_per_stroke": float(self.coefficient), "cooling_time_constant_s":
                float(self.tau_s), "largest_expansion": float(self.largest), "unit": self.unit}

    def drive(self, series, plan):
        return series.motor + self.coefficient * thermal_state(series.t, series.motor, self.stroke, self.tau_s)


@dataclass
class CompliancePhysics(EffectPhysics):
    """Actuators yield by ``compliance`` x their load: ``loads`` (N, n_u) at the commands,
    ``start_loads`` (n_u,) at the start; along a move each actuator's load is blended from the
    previous command's to the next's by how far it has come. ``index`` None: every actuator."""

    compliance: float
    loads: np.ndarray
    start_loads: np.ndarray
    index: int | None
    unit: str
    where: dict = field(default_factory=dict)
    effect: str = "compliance"

    def parameters(self):
        return {**self.where, "compliance": float(self.compliance), "unit": self.unit,
                "largest_deflection": float(self.compliance * np.max(np.abs(self.loads)))}

    def drive(self, series, plan):
        seg = series.segment
        L = np.vstack([self.start_loads[None], self.loads])  # row 0: before the first command
        U = np.vstack([plan.start[None], plan.commands])
        cur, prev = seg + 1, np.maximum(seg, 0)
        if series.rest:
            load = L[cur]
        else:
            step = U[cur] - U[prev]
            moving = np.abs(step) > 0
            frac = np.where(moving, (series.motor - U[prev]) / np.where(moving, step, 1.0), 1.0)
            frac = np.where(seg[:, None] < 0, 1.0, np.clip(frac, 0.0, 1.0))
            load = L[prev] + frac * (L[cur] - L[prev])
        dz = self.compliance * load
        if self.index is not None:
            keep = np.zeros_like(dz)
            keep[:, self.index] = dz[:, self.index]
            dz = keep
        return series.motor + dz


@dataclass
class SlowActuator(EffectPhysics):
    """Actuator ``index`` approaches its commands with time constant ``tau_s`` (the rest keep theirs)."""

    index: int
    actuator: str
    tau_s: float
    hold_share: float
    effect: str = "settling_lag"

    def parameters(self):
        return {"actuator": self.actuator, "tau_s": float(self.tau_s), "share_of_hold": float(self.hold_share)}

    def respond(self, response):
        response.tau_s = np.array(response.tau_s, float)
        response.tau_s[self.index] = self.tau_s


@dataclass
class MarkerSlipPhysics(EffectPhysics):
    """Marker ``index`` moves by ``d`` (3,) m in the moving frame at ``t_s`` (commands clock)."""

    index: int
    marker: str
    t_s: float
    d: np.ndarray
    effect: str = "marker_slip"

    def parameters(self):
        return {"marker": self.marker, "marker_index": int(self.index), "time_s": float(self.t_s),
                "d_m": [float(v) for v in self.d]}

    def marker_offsets(self, t, plan):
        out = np.zeros((len(t), len(plan.marker_names), 3))
        out[np.asarray(t) >= self.t_s, self.index] = self.d
        return out


@dataclass
class BaseTiltPhysics(EffectPhysics):
    """The base turned by the rotation vector (tilt_x, tilt_y, 0) rad against the level world."""

    tilt: np.ndarray
    effect: str = "base_tilt"

    def parameters(self):
        return {"tilt_x_rad": float(self.tilt[0]), "tilt_y_rad": float(self.tilt[1])}

    def base_tilt(self):
        return np.asarray(self.tilt, float)
