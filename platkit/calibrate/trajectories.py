"""The drives' limits of a streamed plan and the periodic Fourier family its trajectories come
from: each actuator j follows u_j(t) = u0_j + A_j w(t) s_j(t) around the neutral controls u0,
s_j a Fourier series of H harmonics of 1 / ``period_s`` scaled to unit largest magnitude, w(t) a
raised-cosine window that starts and ends at rest. The amplitude A_j is the largest that keeps
every command (streamed at ``command_rate_hz``) inside the stroke box less ``margin``, its rate
(first differences) within ``rate`` and its acceleration (second differences) within ``accel``;
every command is then checked reachable and the amplitudes shrink together until it is. The
window lasts long enough for the limits to hold while it rises. Used by
:mod:`platkit.calibrate.excitation`, which designs the coefficients.

A stand whose pose space is free (``PlatformSpec.free_space == 'pose'``: a cable robot, whose
commands must agree with a pose) takes the family per pose coordinate instead: p_k(t) = p0_k +
A_k w(t) s_k(t) about the neutral pose p0, A_k at most the coordinate's room in the pose box less
``margin`` (:class:`PoseSpace`), the commands the inverse kinematics of p(t) at the plan's
parameters; the amplitudes shrink together until the commands keep the box, rate and acceleration
limits and are reachable."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from platkit.calibrate.plan import feasible, held_at_home, homed_at_middle, idle_controls, planning_bounds, unbounded_controls
from platkit.errors import BadInput, NotIdentifiable
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import nominal_inverse, pose_box
from platkit.model import PlatformSpec

__all__ = ["Limits", "PoseSpace", "FourierFamily", "drive_limits", "limit_violations", "trajectory", "Scaler", "RAMP_S"]

#: the window's shortest rise (s), doubled until the limits hold while it rises (at most one period)
RAMP_S = 2.0
#: amplitudes shrink by this factor until every command is reachable, at most SHRINK_TRIES times
SHRINK, SHRINK_TRIES = 0.9, 40
#: the smallest amplitude a control may be left with, as a share of its room around neutral: below
#: it the limits leave the stand nearly still (refused, naming the control)
MIN_AMPLITUDE_SHARE = 0.02
#: relative tolerance of the limit checks (rounding of the written commands)
LIMIT_RTOL = 1e-9


@dataclass
class PoseSpace:
    """Where a pose-free stand's motion plans are drawn: ``lower``/``upper`` (n_p,) the pose box less
    the margin, ``home`` (n_p,) the neutral pose; commands are the inverse kinematics of poses."""

    lower: np.ndarray
    upper: np.ndarray
    home: np.ndarray

    def scaled(self, share: float) -> PoseSpace:
        """The box scaled about the home pose by ``share``."""
        return PoseSpace(self.home - share * (self.home - self.lower), self.home + share * (self.upper - self.home),
                         self.home)

    def controls(self, P: np.ndarray, model: PlatformModel, td: np.ndarray) -> np.ndarray:
        """(N, n_u) the inverse kinematics of poses P (N, n_p) at td (NaN rows where none)."""
        return nominal_inverse(model, np.ascontiguousarray(np.atleast_2d(P), dtype=float), np.asarray(td, float))[0]


@dataclass
class Limits:
    """What every command must keep (internal units): ``lower``/``upper`` (n_u,) the box, ``rate``
    (n_u,) per s and ``accel`` (n_u,) per s^2 the drives' limits; ``home`` (n_u,) the controls the
    session starts and ends at rest on and its excitation moves about (None: the stand's neutral
    controls; :func:`drive_limits` says); ``space``: a pose-free stand's pose box (plans drawn in
    poses), None for plans drawn in controls."""

    lower: np.ndarray
    upper: np.ndarray
    rate: np.ndarray
    accel: np.ndarray
    source: dict = field(default_factory=dict)
    home: np.ndarray | None = None
    space: PoseSpace | None = None


def home_controls(spec: PlatformSpec, limits: Limits) -> np.ndarray:
    """The controls a motion session starts and ends on (``limits.home``, else neutral)."""
    return spec.neutral_u() if limits.home is None else np.asarray(limits.home, float)


def _declared_rates(spec: PlatformSpec) -> np.ndarray | None:
    """The controls' rate limits the stand's description declares, in the controls' units per s:
    a URDF's ``<limit velocity>`` (SI: rad/s, m/s) of the chain's movable joints, one per control
    in order, NaN where a joint declares none; None where the description is no URDF's."""
    path, chain = spec.extras.get("urdf_path"), spec.extras.get("chain")
    if not path or chain is None:
        return None
    movable = [j.name for j in getattr(chain, "joints", []) if j.type not in ("fixed",) and j.mimic is None]
    if len(movable) != spec.n_u:
        return None
    try:
        root = ET.parse(str(path)).getroot()
    except (OSError, ET.ParseError):
        return None
    rates = {}
    for joint in root.iter("joint"):
        lim = joint.find("limit")
        if lim is not None and lim.get("velocity") is not None:
            try:
                rates[joint.get("name")] = float(lim.get("velocity", "nan"))
            except ValueError:
                continue
    per_unit = {"deg": 180.0 / np.pi}  # the URDF's rad/s in a control counted in degrees
    out = np.array([rates.get(n, np.nan) * per_unit.get(c.unit, 1.0) for n, c in zip(movable, spec.controls)], float)
    return np.where(np.isfinite(out) & (out > 0), out, np.nan)


def drive_limits(spec: PlatformSpec, max_rate: np.ndarray | None, max_accel: np.ndarray | None,
                 margin: float = 0.1, moving: np.ndarray | None = None) -> Limits:
    """The limits of a plan: the strokes (:func:`platkit.calibrate.plan.planning_bounds`: a control
    without a finite stroke over one turn either way) less ``margin`` of each at both ends, and the rate and
    acceleration limits given (internal units, one number or one per control), else those the
    description declares (a URDF's joint ``velocity``); BadInput naming what is missing.

    The home (``Limits.home``): the neutral controls, but a control whose neutral lies on or
    outside the box (a URDF joint whose zero is a limit: an elbow) is homed at the box's middle
    (``source['home']`` names it). A control that moves no tracked link (a tree's legs and head,
    :func:`platkit.calibrate.plan.idle_controls`) keeps its neutral command: its box is that
    point. ``moving`` (n_u,) bool, where given: the controls the session moves; every other is held
    at its home (:func:`platkit.calibrate.plan.held_at_home`: neutral, or the box's middle as
    above), its box that point (``source['held']`` names them)."""
    lo, hi = planning_bounds(spec)
    if not 0 <= margin < 0.5:
        raise BadInput(f"margin: must be in [0, 0.5), got {margin}")
    span = hi - lo
    source = {}
    unbounded = unbounded_controls(spec)
    if unbounded:
        source["stroke"] = ("one turn either way of neutral for " + ", ".join(unbounded)
                            + " (no finite stroke in the description)")
    rate = _per_control(spec, max_rate, "max_rate")
    if rate is None:
        rate = _declared_rates(spec)
        if rate is None or not np.all(np.isfinite(rate)):
            missing = spec.control_names if rate is None else [n for n, r in zip(spec.control_names, rate)
                                                               if not np.isfinite(r)]
            raise BadInput(f"max_rate: the {spec.name} stand's description declares no rate limit for "
                           f"{', '.join(missing)}; give the drives' limit (one number, or one per control)")
        source["rate"] = "description (URDF joint velocity)"
    else:
        source["rate"] = "given (max_rate)"
    accel = _per_control(spec, max_accel, "max_accel")
    if accel is None:
        raise BadInput(f"max_accel: the {spec.name} stand's description declares no acceleration limit for its "
                       "controls; give the drives' limit (one number, or one per control)")
    source["accel"] = "given (max_accel)"
    u0 = spec.neutral_u()
    lower, upper = lo + margin * span, hi - margin * span
    names = np.array(spec.control_names)
    if moving is None:
        idle = idle_controls(spec)
        outside = homed_at_middle(u0, lower, upper) & ~idle
        home = np.where(outside, 0.5 * (lower + upper), u0)
    else:
        idle, home = held_at_home(spec, moving, margin)
        outside = homed_at_middle(u0, lower, upper)
    if np.any(outside):
        source["home"] = ("the middle of the box for " + ", ".join(names[outside])
                          + " (neutral on or outside the strokes less the margin), neutral for the others")
    if np.any(idle):
        lower, upper = np.where(idle, home, lower), np.where(idle, home, upper)
        source["held"] = ("at neutral (they move no tracked link): " + ", ".join(names[idle]) if moving is None
                          else "at home (not moved by the plan): " + ", ".join(names[idle]))
    space = None
    if spec.pose_free:  # its commands agree with a pose: drawn in the pose box less the margin
        if moving is not None:
            raise BadInput(f"{spec.name}: its pose space is free (commands from poses through inverse kinematics); a "
                           "plan that holds some controls is not made for it")
        space = PoseSpace(*pose_box(spec, margin), spec.neutral_p())
        source["space"] = "pose: drawn in the pose box less the margin, commands by inverse kinematics"
    return Limits(lower, upper, rate, accel, source, home, space)


def _per_control(spec: PlatformSpec, value, option: str) -> np.ndarray | None:
    if value is None:
        return None
    v = np.atleast_1d(np.asarray(value, float))
    if v.size == 1:
        v = np.full(spec.n_u, float(v[0]))
    if v.size != spec.n_u:
        raise BadInput(f"{option}: expected 1 or {spec.n_u} numbers (one per control: {', '.join(spec.control_names)}), "
                       f"got {v.size}")
    if not np.all(np.isfinite(v) & (v > 0)):
        raise BadInput(f"{option}: every limit must be a positive number, got {', '.join(f'{x:g}' for x in v)}")
    return v


@dataclass
class FourierFamily:
    """The periodic family: ``period_s``, ``harmonics`` H, for ``n_u`` actuators; coefficients
    (n_u, H, 2): (a, b) of sin and cos of each harmonic."""

    period_s: float
    harmonics: int
    n_u: int

    def __post_init__(self):
        if not (self.period_s > 0 and math.isfinite(self.period_s)):
            raise BadInput(f"period_s: must be a positive number of seconds, got {self.period_s:g}")
        if self.harmonics < 1:
            raise BadInput(f"harmonics: must be at least 1, got {self.harmonics}")

    @property
    def size(self) -> int:
        return self.n_u * self.harmonics * 2

    def random_multisine(self, rng: np.random.Generator) -> np.ndarray:
        """Coefficients of a multisine with random phases and amplitude 1/sqrt(k) per harmonic k."""
        k = np.arange(1, self.harmonics + 1)
        ph = rng.uniform(0, 2 * np.pi, (self.n_u, self.harmonics))
        amp = 1.0 / np.sqrt(k)[None, :]
        return np.stack([amp * np.cos(ph), amp * np.sin(ph)], axis=2)

    def raw(self, coef: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(K, n_u) the series at times t (K,), unscaled."""
        w = 2 * np.pi / self.period_s * np.arange(1, self.harmonics + 1)
        arg = np.asarray(t, float)[:, None] * w[None, :]
        c = np.asarray(coef, float).reshape(self.n_u, self.harmonics, 2)
        return np.sin(arg) @ c[:, :, 0].T + np.cos(arg) @ c[:, :, 1].T


def _periodic_rates(s: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(largest rate, largest acceleration) per column of a period of values ``s`` (n, k) streamed
    at ``rate_hz`` (periodic first and second differences)."""
    v = np.max(np.abs(np.roll(s, -1, axis=0) - s), axis=0) * rate_hz
    a = np.max(np.abs(np.roll(s, -1, axis=0) - 2 * s + np.roll(s, 1, axis=0)), axis=0) * rate_hz * rate_hz
    return v, a


def _window(t: np.ndarray, duration_s: float, ramp_s: float) -> np.ndarray:
    r = np.clip(np.minimum(t, duration_s - t) / ramp_s, 0, 1)
    return 0.5 - 0.5 * np.cos(np.pi * r)


def limit_violations(U: np.ndarray, command_rate_hz: float, limits: Limits) -> dict:
    """Commands (N, n_u) streamed every 1/command_rate_hz s against the limits: the number of
    samples past the box, the rate (first differences) and the acceleration (second differences),
    and the largest share of each limit used."""
    U = np.asarray(U, float)
    v = np.abs(np.diff(U, axis=0)) * command_rate_hz
    a = np.abs(np.diff(U, 2, axis=0)) * command_rate_hz ** 2
    tol = 1 + LIMIT_RTOL
    span = limits.upper - limits.lower
    box = (U < limits.lower - LIMIT_RTOL * span) | (U > limits.upper + LIMIT_RTOL * span)
    return {"box": int(np.sum(np.any(box, axis=1))), "rate": int(np.sum(np.any(v > limits.rate * tol, axis=1))),
            "accel": int(np.sum(np.any(a > limits.accel * tol, axis=1))),
            "rate_share": float(np.max(v / limits.rate)) if len(v) else 0.0,
            "accel_share": float(np.max(a / limits.accel)) if len(a) else 0.0}


class Scaler:
    """Amplitudes within the limits, and reachability, of shapes of one family (module docstring)."""

    def __init__(self, spec: PlatformSpec, family: FourierFamily, limits: Limits, command_rate_hz: float,
                 model: PlatformModel, td: np.ndarray):
        self.spec, self.family, self.limits, self.rate_hz, self.model, self.td = spec, family, limits, command_rate_hz, model, td
        n = int(round(family.period_s * command_rate_hz))
        if n < 8:
            raise BadInput(f"period_s: {family.period_s:g} s gives fewer than 8 commands per period at {command_rate_hz:g} "
                           "per s")
        self.t_period = np.arange(n) / command_rate_hz
        self.space = limits.space
        if self.space is None:
            self.u0 = home_controls(spec, limits)
            self.half = np.minimum(limits.upper - self.u0, self.u0 - limits.lower)
        else:  # a pose-free stand: the series move its pose coordinates
            self.u0 = self.space.home
            self.half = np.minimum(self.space.upper - self.u0, self.u0 - self.space.lower)
        self.names = spec.control_names if self.space is None else spec.coordinate_names

    def commands(self, offsets: np.ndarray) -> np.ndarray:
        """(K, n_u) the commands of the series' values ``offsets`` (K, n) about the home: the controls
        themselves, or a pose-free stand's inverse kinematics of the poses."""
        if self.space is None:
            return self.u0 + offsets
        return self.space.controls(self.u0 + offsets, self.model, self.td)

    def amplitudes(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A (n,), shape over one period (n, n) of unit largest magnitude) within the box, rate
        and acceleration limits (periodic differences), before reachability."""
        s = self.family.raw(coef, self.t_period)
        peak = np.max(np.abs(s), axis=0)
        if np.any(peak <= 0):
            raise BadInput("excitation: an actuator's series is zero everywhere")
        s = s / peak
        if self.space is not None:
            A = self._pose_amplitudes(s)
        else:
            v, a = _periodic_rates(s, self.rate_hz)
            A = np.minimum(self.half, np.minimum(self.limits.rate / np.maximum(v, 1e-300),
                                                 self.limits.accel / np.maximum(a, 1e-300)))
        small = A < MIN_AMPLITUDE_SHARE * self.half
        if np.any(small):
            j = int(np.argmax(small))
            raise BadInput(f"{self.spec.name}: the rate and acceleration limits leave {self.names[j]} "
                           f"{100 * A[j] / self.half[j]:.2g}% of its room around neutral over a {self.family.period_s:g} s "
                           "period: raise the rate or acceleration limits or lengthen the period")
        return A, s

    def _pose_amplitudes(self, s: np.ndarray) -> np.ndarray:
        """A pose-free stand's amplitudes (n_p,): the pose box's room, shrunk together until the
        commands of a period (inverse kinematics) keep the control box, rate and acceleration."""
        A = self.half.copy()
        lim = self.limits
        for _ in range(SHRINK_TRIES):
            U = self.commands(s * A)
            if np.all(np.isfinite(U)):
                v, a = _periodic_rates(U, self.rate_hz)
                share = max(float(np.max(v / lim.rate)), float(np.max(a / lim.accel)))
                inside = bool(np.all((U >= lim.lower) & (U <= lim.upper)))
                if share <= 1 and inside:
                    return A
                A = A * (min(SHRINK, 1 / (share * (1 + 1e-6))) if inside else SHRINK)
            else:
                A = A * SHRINK
        return np.zeros_like(A)  # nothing within the limits: refused by the caller as too small

    def reachable_period(self, coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A, shape) with every command of a period reachable (amplitudes shrunk together);
        NotIdentifiable where no amplitude is."""
        A, s = self.amplitudes(coef)
        for _ in range(SHRINK_TRIES):
            ok, _ = feasible(self.spec, self.commands(s * A), self.td, self.model)
            if ok.all():
                return A, s
            A = A * SHRINK
        raise NotIdentifiable(f"{self.spec.name}: no excitation of this shape around the neutral controls stays "
                              "reachable; a larger margin or fewer harmonics")


def trajectory(spec: PlatformSpec, family: FourierFamily, coef: np.ndarray, limits: Limits, duration_s: float,
               command_rate_hz: float, model: PlatformModel | None = None, td=None) -> tuple[np.ndarray, dict]:
    """(U (N, n_u) commands every 1/command_rate_hz s for duration_s s, what it is): the family's
    member ``coef`` within the limits (module docstring), windowed to start and end at rest on the
    neutral controls. Every command is checked: reachable, inside the box, rate and acceleration
    within the limits (NotIdentifiable if the window cannot rise within them in one period)."""
    model = model or PlatformModel(spec)
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    scaler = Scaler(spec, family, limits, command_rate_hz, model, td)
    A, _ = scaler.reachable_period(coef)
    t = np.arange(int(round(duration_s * command_rate_hz))) / command_rate_hz
    end = float(t[-1]) if len(t) else 0.0
    raw = family.raw(coef, t)
    peak = np.max(np.abs(family.raw(coef, scaler.t_period)), axis=0)
    ramp = RAMP_S
    while True:
        if ramp > min(family.period_s, 0.5 * end):
            raise NotIdentifiable(f"{spec.name}: the session cannot rise to its excitation and back within the rate "
                                  f"and acceleration limits in {duration_s:g} s (ramps up to {min(family.period_s, 0.5 * end):g} "
                                  "s each); try a longer session (--duration-s)")
        U = scaler.commands(_window(t, end, ramp)[:, None] * raw / peak * A)
        bad = limit_violations(U, command_rate_hz, limits)
        if not (bad["box"] or bad["rate"] or bad["accel"]):
            break
        ramp *= 1.5
    for _ in range(SHRINK_TRIES):
        ok, _ = feasible(spec, U, td, model)
        if ok.all():
            break
        A = A * SHRINK
        U = scaler.commands(_window(t, end, ramp)[:, None] * raw / peak * A)
    else:
        raise NotIdentifiable(f"{spec.name}: the excitation's commands do not all stay reachable")
    return U, {"ramp_s": float(ramp), "amplitude": [float(x) for x in A], **limit_violations(U, command_rate_hz, limits)}
