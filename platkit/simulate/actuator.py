"""How a stand's actuators follow their commands, in time: a rate- and acceleration-limited
motion profile, followed by each actuator through its own damped second-order response.

The drive of every actuator j plans a trapezoidal velocity profile (rate limit ``rate[j]``,
acceleration limit ``accel[j]``) from where its profile stands to each new command, starting
when the command is sent; the actuator then follows that profile as a damped second-order
system

    x'' + 2 zeta w x' + w^2 x = w^2 r(t),   w = 1 / tau_s

(``tau_s`` its time constant, ``damping`` = zeta: 1 critically damped, below 1 an overshoot).
The follow is integrated exactly for a profile held constant over each fine step (zero-order
hold discretisation, scipy.signal), so the approach after the profile ends decays as
(a + b t) exp(-t / tau_s) for zeta = 1: settling is an event in the stream, of the length the
time constant says. Optionally, each actuator has its own pure delay (``delay_s``: it acts on
every command that much later than sent) and a speed limit of its own (``rate_limit``: a
streamed drive slews towards each held command at that rate from where it stood, cut by the next
command; a profile's rate is the smaller of the two). Internal units throughout (m for length controls, the control's unit
otherwise), times in seconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from platkit.errors import BadInput

__all__ = ["ActuatorResponse", "profile_duration", "motion_profile", "slewed", "follow", "actuator_motion"]


@dataclass
class ActuatorResponse:
    """Per-actuator response, arrays (n_u,): ``tau_s`` time constant 1/w of the second-order
    approach (s); ``damping`` zeta; ``rate`` the profile's rate limit (control unit per s);
    ``accel`` its acceleration limit (control unit per s^2); ``streamed``: the drive follows each
    command as it comes (a step reference held to the next command, no profile: commands
    streamed at a steady rate by a path or motion-cue follower); ``delay_s`` (n_u,) or None: each
    actuator's pure delay (s, >= 0: it acts on each command that much after it is sent);
    ``rate_limit`` (n_u,) or None: each actuator's speed limit (control unit per s; a streamed
    drive slews at it towards each held command, a profile's rate is the smaller of the two)."""

    tau_s: np.ndarray
    damping: np.ndarray
    rate: np.ndarray
    accel: np.ndarray
    streamed: bool = False
    delay_s: np.ndarray | None = None
    rate_limit: np.ndarray | None = None

    def check(self) -> None:
        for name in ("tau_s", "damping", "rate", "accel", "rate_limit"):
            if getattr(self, name) is None:
                continue
            v = np.asarray(getattr(self, name), float)
            if not np.all(np.isfinite(v) & (v > 0)):
                raise BadInput(f"actuator response: {name} must be positive and finite, got {v.tolist()}")
        if self.delay_s is not None:
            d = np.asarray(self.delay_s, float)
            if d.shape != np.shape(self.tau_s) or not np.all(np.isfinite(d) & (d >= 0)):
                raise BadInput(f"actuator response: delay_s must be one finite delay >= 0 per actuator, got {d.tolist()}")
        if self.rate_limit is not None and np.shape(self.rate_limit) != np.shape(self.tau_s):
            raise BadInput("actuator response: rate_limit must be one rate per actuator")

    def to_dict(self, names: list[str]) -> dict:
        """Per actuator name: tau_s, damping, rate, accel (plain floats, internal units), and
        delay_s, rate_limit_per_s where set."""
        out = {n: {"tau_s": float(a), "damping": float(z), "rate_per_s": float(r), "accel_per_s2": float(c)}
               for n, a, z, r, c in zip(names, self.tau_s, self.damping, self.rate, self.accel)}
        for j, n in enumerate(names):
            if self.delay_s is not None:
                out[n]["delay_s"] = float(self.delay_s[j])
            if self.rate_limit is not None:
                out[n]["rate_limit_per_s"] = float(self.rate_limit[j])
        return out


def profile_duration(distance: np.ndarray, rate: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Duration (s) of a trapezoidal (or, for short moves, triangular) profile over
    ``distance`` (>= 0) with the given rate and acceleration limits (broadcast)."""
    d = np.abs(np.asarray(distance, float))
    v, a = np.asarray(rate, float), np.asarray(accel, float)
    triangular = d < v * v / a
    return np.where(triangular, 2.0 * np.sqrt(d / a), d / v + v / a)


def _trapezoid(s: np.ndarray, d: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Distance covered after time s (>= 0) by the profile over distance d >= 0 (broadcast)."""
    tri = d < v * v / a
    ta = np.where(tri, np.sqrt(d / a), v / a)  # end of the acceleration phase
    vp = a * ta  # peak speed
    T = np.where(tri, 2 * ta, d / v + v / a)
    s = np.clip(s, 0.0, None)
    acc = 0.5 * a * s**2
    cruise = 0.5 * a * ta**2 + vp * (s - ta)
    r = np.maximum(T - s, 0.0)
    dec = d - 0.5 * a * r**2
    return np.where(s <= ta, acc, np.where(s <= T - ta, cruise, np.where(s < T, dec, d)))


def motion_profile(t: np.ndarray, command_t: np.ndarray, commands: np.ndarray, start: np.ndarray,
                   response: ActuatorResponse) -> np.ndarray:
    """(K, n_u) the planned profile r(t) at times ``t`` (K,), sorted.

    ``command_t`` (N,) when each command (N, n_u) is sent; ``start`` (n_u,) where the stand rests
    before the first. A profile that has not ended when the next command comes is cut there
    and the next starts from where it stood (at rest: the planner does not blend moves).
    """
    N = len(command_t)
    seg = np.searchsorted(command_t, t, side="right") - 1  # command in force at each t (-1: before)
    origin = np.empty_like(commands)
    pos = np.asarray(start, float).copy()
    for i in range(N):
        origin[i] = pos
        d = commands[i] - pos
        if i + 1 < N:
            span = command_t[i + 1] - command_t[i]
            done = _trapezoid(np.full_like(d, span), np.abs(d), response.rate, response.accel)
            pos = pos + np.sign(d) * done
    # most samples lie where a profile has ended (the holds): only the moving ones are evaluated
    n_u = commands.shape[1]
    dist = np.abs(commands - origin)
    T = profile_duration(dist, response.rate[None], response.accel[None])  # (N, n_u)
    segc = np.maximum(seg, 0)
    out = np.where(seg[:, None] < 0, np.asarray(start, float)[None], commands[segc])
    s = t - command_t[segc]
    for j in range(n_u):
        k = np.nonzero((seg >= 0) & (s < T[segc, j]))[0]
        i = seg[k]
        out[k, j] = origin[i, j] + np.sign(commands[i, j] - origin[i, j]) * _trapezoid(
            s[k], dist[i, j], response.rate[j], response.accel[j])
    return out


def follow(reference: np.ndarray, dt: float, tau_s: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """(K, n_u) the actuators' positions following ``reference`` (K, n_u) sampled every ``dt``
    seconds, each as the damped second-order system of its (tau_s, damping), at rest on the
    reference's first value (exact for a reference held constant over each step)."""
    out = np.empty_like(reference)
    for j in range(reference.shape[1]):
        w = 1.0 / float(tau_s[j])
        z = float(damping[j])
        num, den, _ = signal.cont2discrete(([w * w], [1.0, 2 * z * w, w * w]), dt, method="zoh")
        num = np.ravel(num)
        x0 = reference[0, j]
        out[:, j] = x0 + signal.lfilter(num, den, reference[:, j] - x0)
    return out


def slewed(t: np.ndarray, command_t: np.ndarray, commands: np.ndarray, start: np.ndarray,
           rate: np.ndarray) -> np.ndarray:
    """(K, n_u) each command held to the next, approached at ``rate`` (n_u,) from where the drive
    stood when it came (a cut move leaves it short), at times ``t`` (K,); ``start`` before the
    first command."""
    N = len(command_t)
    origin = np.empty_like(commands, dtype=float)
    pos = np.asarray(start, float).copy()
    rate = np.asarray(rate, float)
    for i in range(N):
        origin[i] = pos
        if i + 1 < N:
            d = commands[i] - pos
            pos = pos + np.sign(d) * np.minimum(np.abs(d), rate * (command_t[i + 1] - command_t[i]))
    seg = np.searchsorted(command_t, t + 1e-9, side="right") - 1
    i = np.maximum(seg, 0)
    d = commands[i] - origin[i]
    moved = np.minimum(np.abs(d), rate[None] * np.maximum(t - command_t[i], 0.0)[:, None])
    return np.where(seg[:, None] < 0, np.asarray(start, float)[None], origin[i] + np.sign(d) * moved)


def _reference(fine: np.ndarray, command_t: np.ndarray, commands: np.ndarray, start: np.ndarray,
               response: ActuatorResponse) -> np.ndarray:
    """(K, n_u) the reference the actuators follow on the grid ``fine``, without their delays."""
    if response.streamed and response.rate_limit is not None:
        return slewed(fine, command_t, commands, start, response.rate_limit)
    if response.streamed:  # each command held to the next, from the grid point it falls on
        seg = np.searchsorted(command_t, fine + 1e-9, side="right") - 1
        return np.where(seg[:, None] < 0, np.asarray(start, float)[None], commands[np.maximum(seg, 0)])
    if response.rate_limit is not None:
        limited = ActuatorResponse(response.tau_s, response.damping, np.minimum(response.rate, response.rate_limit),
                                   response.accel)
        return motion_profile(fine, command_t, commands, start, limited)
    return motion_profile(fine, command_t, commands, start, response)


def actuator_motion(t: np.ndarray, command_t: np.ndarray, commands: np.ndarray, start: np.ndarray,
                    response: ActuatorResponse, fine_step_s: float = 1e-3) -> np.ndarray:
    """(K, n_u) the actuators' true positions at times ``t`` (K,) sorted: the profile (or, for a
    ``streamed`` response, each command held to the next, slewed at the rate limit where set),
    each actuator's commands taken its delay late, followed by the second-order response,
    integrated every ``fine_step_s`` from 0 s and interpolated linearly to ``t``."""
    response.check()
    t = np.asarray(t, float)
    delay = None if response.delay_s is None else np.asarray(response.delay_s, float)
    t_end = float(max(t[-1], command_t[-1] + (0.0 if delay is None else float(delay.max())))) + fine_step_s
    fine = np.arange(0.0, t_end + fine_step_s, fine_step_s)
    if delay is None:
        ref = _reference(fine, command_t, commands, start, response)
    else:  # each actuator on its own late copy of the command times
        ref = np.empty((len(fine), commands.shape[1]))
        for j in range(commands.shape[1]):
            one = ActuatorResponse(response.tau_s[j:j + 1], response.damping[j:j + 1], response.rate[j:j + 1],
                                   response.accel[j:j + 1], response.streamed, None,
                                   None if response.rate_limit is None else response.rate_limit[j:j + 1])
            ref[:, j] = _reference(fine, command_t + delay[j], commands[:, j:j + 1], np.asarray(start, float)[j:j + 1],
                                   one)[:, 0]
    x = follow(ref, fine_step_s, response.tau_s, response.damping)
    out = np.empty((len(t), commands.shape[1]))
    for j in range(commands.shape[1]):
        out[:, j] = np.interp(t, fine, x[:, j])
    return out
