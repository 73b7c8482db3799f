"""Continuous-motion plans: commands streamed at a steady rate, without holds.

``multisine``: each actuator sums MULTISINE_COMPONENTS sines at frequencies spread
logarithmically over MULTISINE_BAND_HZ with random phases (its own per actuator);
``path``: a smooth random path, white noise through a second-order low-pass at PATH_CUTOFF_HZ
and back (zero phase); ``cue``: motion-cue-like, smoothed random steps (each held
CUE_HOLD_S on average) pulled back to neutral by a washout of CUE_WASHOUT_S. Every kind starts
and ends at the neutral controls at rest (a raised-cosine ramp of RAMP_S), and its amplitude
is the largest up to AMPLITUDE_SHARE of each half-stroke (slow and wide: the geometry is seen over
the workspace) that keeps every rate and acceleration
within LIMIT_SHARE of the drives' limits and every command reachable by the true stand. A control
whose neutral rests on a limit (a URDF joint's zero clipped into its limits) moves about the
middle of its stroke instead, reached from its neutral along the same ramp (its rate and
acceleration counted in the limits); the plan says which (``about_mid_stroke``).

A stand whose pose space is free (``PlatformSpec.free_space == 'pose'``: a cable robot, whose
commands must agree with a pose) takes the same shapes per pose coordinate instead, about its
neutral pose, each of amplitude up to AMPLITUDE_SHARE of the coordinate's half-box, and its
commands are their inverse kinematics at the plan's parameters; the amplitude is shrunk until
every control's rate and acceleration stay within LIMIT_SHARE of its drive's and every command
is reachable (the plan says ``space: pose`` and the amplitude per coordinate).
"""
from __future__ import annotations

import numpy as np
from scipy import signal

from platkit.calibrate.plan import feasible, read_plan_csv
from platkit.calibrate.plan_information import homed_at_middle
from platkit.errors import BadInput, BadSession, NotIdentifiable
from platkit.io.table import read_table
from platkit.kinematics.sampling import nominal_inverse

__all__ = ["KINDS", "continuous_plan", "read_streamed_commands"]

#: a streamed command log's intervals may differ from their median by this much (s): the files keep
#: microseconds
STEADY_TOL_S = 2e-6

KINDS = ("multisine", "path", "cue")
MULTISINE_COMPONENTS, MULTISINE_BAND_HZ = 6, (0.02, 0.25)
PATH_CUTOFF_HZ = 0.4
CUE_HOLD_S, CUE_WASHOUT_S, CUE_SMOOTH_HZ = 1.5, 4.0, 1.0
RAMP_S = 2.0
AMPLITUDE_SHARE, LIMIT_SHARE = 0.9, 0.7


def _shape(kind: str, t: np.ndarray, n_u: int, rate_hz: float, rng: np.random.Generator) -> np.ndarray:
    """(N, n_u) the plan's shape, each column of unit largest magnitude, before the ramp."""
    N = len(t)
    if kind == "multisine":
        f = np.geomspace(*MULTISINE_BAND_HZ, MULTISINE_COMPONENTS)
        out = np.zeros((N, n_u))
        for j in range(n_u):
            ph = rng.uniform(0, 2 * np.pi, len(f))
            a = 1.0 / np.sqrt(f / f[0])  # less amplitude at higher frequency: smoother
            out[:, j] = np.sum(a[None] * np.sin(2 * np.pi * f[None] * t[:, None] + ph[None]), axis=1)
    elif kind == "path":
        b, a = signal.butter(2, PATH_CUTOFF_HZ / (rate_hz / 2))
        out = signal.filtfilt(b, a, rng.normal(size=(N, n_u)), axis=0)
    elif kind == "cue":
        steps = np.zeros((N, n_u))
        k = 0
        while k < N:
            n = max(1, int(rng.exponential(CUE_HOLD_S) * rate_hz))
            steps[k:k + n] = rng.uniform(-1, 1, n_u)
            k += n
        b, a = signal.butter(2, CUE_SMOOTH_HZ / (rate_hz / 2))
        smooth = signal.filtfilt(b, a, steps, axis=0)
        bw, aw = signal.butter(1, 1.0 / (2 * np.pi * CUE_WASHOUT_S) / (rate_hz / 2), btype="high")
        out = signal.filtfilt(bw, aw, smooth, axis=0)
    else:
        raise BadInput(f"continuous motion: kind must be one of {', '.join(KINDS)}, not {kind!r}")
    out = out - out.mean(axis=0)
    return out / np.maximum(np.abs(out).max(axis=0), 1e-12)


def continuous_plan(spec, kind: str | np.ndarray, duration_s: float, rate_hz: float, rng: np.random.Generator, model, td,
                    rate: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, dict]:
    """(N, n_u) commands streamed every 1/rate_hz s for duration_s s, and what the plan was (the
    module docstring); ``rate`` and ``accel`` (n_u,) the drives' limits (internal units per s,
    per s^2), ``td`` the true parameters (every command reachable). ``kind`` an (N, n_u) array:
    those commands, streamed as they are (a designed excitation, ``platkit plan --motion``;
    ``duration_s`` unused), with the largest share of the drives' limits they use said."""
    if not isinstance(kind, str):
        return _given(spec, np.asarray(kind, float), rate_hz, rate, accel)
    if not duration_s > 3 * RAMP_S:
        raise BadInput(f"continuous motion: a duration of {duration_s:g} s is too short (more than {3 * RAMP_S:g} s)")
    if not 0 < rate_hz <= 1000:
        raise BadInput(f"continuous motion: a command rate of {rate_hz:g} per s is out of range (0, 1000]")
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    if spec.pose_free:
        return _pose_plan(spec, kind, t, duration_s, rate_hz, rng, model, td, rate, accel)
    shape = _shape(kind, t, spec.n_u, rate_hz, rng)
    lo = np.array([c.lower for c in spec.controls], float)
    hi = np.array([c.upper for c in spec.controls], float)
    u0 = spec.neutral_u()
    # a control whose neutral rests on a limit (a URDF joint's zero clipped into its limits, as
    # Talos' elbows) moves about the middle of its stroke, reached from its neutral and back along
    # the ramp, which is then long enough for that move to take at most half of LIMIT_SHARE of the
    # drive's rate and acceleration; the others about their neutral
    center = np.where(homed_at_middle(u0, lo, hi), 0.5 * (lo + hi), u0)
    D = np.abs(center - u0)
    ramp_s = max([RAMP_S] + [max(np.pi / 2 * d / (0.5 * LIMIT_SHARE * r), np.pi * np.sqrt(d / (LIMIT_SHARE * ac)))
                             for d, r, ac in zip(D, rate, accel) if d > 0])
    if not duration_s > 3 * ramp_s:
        raise BadInput(f"continuous motion: a duration of {duration_s:g} s is too short for the controls that move "
                       f"from a limit to mid-stroke (more than {3 * ramp_s:.3g} s)")
    ramp = np.clip(np.minimum(t, t[-1] - t) / ramp_s, 0, 1)
    w = (0.5 - 0.5 * np.cos(np.pi * ramp))[:, None]
    shape = shape * w
    home = u0 + w * (center - u0)
    half = np.minimum(hi - center, center - lo)
    amp = AMPLITUDE_SHARE * np.where(np.isfinite(half) & (half > 0), half, 0.0)
    v = np.abs(np.diff(shape, axis=0)).max(axis=0) * rate_hz
    a = np.abs(np.diff(shape, 2, axis=0)).max(axis=0) * rate_hz ** 2
    v_home = np.abs(np.diff(home, axis=0)).max(axis=0) * rate_hz
    a_home = np.abs(np.diff(home, 2, axis=0)).max(axis=0) * rate_hz ** 2
    amp = np.minimum(amp, np.minimum(np.maximum(LIMIT_SHARE * rate - v_home, 0.0) / np.maximum(v, 1e-12),
                                     np.maximum(LIMIT_SHARE * accel - a_home, 0.0) / np.maximum(a, 1e-12)))
    for _ in range(8):
        U = home + shape * amp
        ok, _ = feasible(spec, U, td, model)
        if ok.all():
            info = {"kind": kind, "duration_s": float(duration_s), "command_rate_hz": float(rate_hz),
                    "amplitude": [float(x) for x in amp]}
            moved = [c for c, x, x0 in zip(spec.control_names, center, u0) if x != x0]
            if moved:  # said where it differs from the rule of every other control
                info["about_mid_stroke"] = moved
            return U, info
        amp = 0.7 * amp
    raise NotIdentifiable(f"{spec.name}: no {kind} motion around the neutral pose stays reachable")


#: a pose-space plan's amplitude is shrunk at most this many times (by the drives' limits, then by 0.7
#: while a command is unreachable)
POSE_ROUNDS = 12


def _pose_plan(spec, kind: str, t: np.ndarray, duration_s: float, rate_hz: float, rng: np.random.Generator, model, td,
               rate: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, dict]:
    """A pose-free stand's plan (module docstring): the shape per pose coordinate about the neutral
    pose through the raised-cosine ramp, mapped to commands by inverse kinematics at ``td``."""
    shape = _shape(kind, t, spec.n_p, rate_hz, rng)
    ramp = np.clip(np.minimum(t, t[-1] - t) / RAMP_S, 0, 1)
    shape = shape * (0.5 - 0.5 * np.cos(np.pi * ramp))[:, None]
    p0 = spec.neutral_p()
    lo, hi = spec.coordinate_bounds()
    half = np.minimum(hi - p0, p0 - lo)
    amp = AMPLITUDE_SHARE * np.where(np.isfinite(half) & (half > 0), half, 0.0)
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    for _ in range(POSE_ROUNDS):
        U = nominal_inverse(model, p0 + shape * amp, td)[0]
        if np.all(np.isfinite(U)):
            v = np.abs(np.diff(U, axis=0)).max(axis=0) * rate_hz
            a = np.abs(np.diff(U, 2, axis=0)).max(axis=0) * rate_hz ** 2
            share = max(float(np.max(v / rate)), float(np.max(a / accel))) / LIMIT_SHARE
            if share > 1:  # the controls' rates grow about in proportion to the amplitude
                amp = amp / (1.02 * share)
                continue
            if feasible(spec, U, td, model)[0].all():
                return U, {"kind": kind, "space": "pose", "duration_s": float(duration_s),
                           "command_rate_hz": float(rate_hz), "amplitude": [float(x) for x in amp]}
        amp = 0.7 * amp
    raise NotIdentifiable(f"{spec.name}: no {kind} motion around the neutral pose stays reachable within the drives' "
                          "limits")


def _given(spec, U: np.ndarray, rate_hz: float, rate: np.ndarray, accel: np.ndarray) -> tuple[np.ndarray, dict]:
    """Given commands (N, n_u) streamed every 1/rate_hz s: checked for shape and values; the
    largest share of the drives' rate and acceleration limits they ask for is said (a share over 1:
    the drives cannot follow them as commanded)."""
    if U.ndim != 2 or U.shape[1] != spec.n_u or len(U) < 3:
        raise BadInput(f"continuous motion: given commands must be (N >= 3, {spec.n_u}), got {U.shape}")
    if not np.all(np.isfinite(U)):
        raise BadInput("continuous motion: given commands hold a value that is not a number")
    if not 0 < rate_hz <= 1000:
        raise BadInput(f"continuous motion: a command rate of {rate_hz:g} per s is out of range (0, 1000]")
    v = np.abs(np.diff(U, axis=0)).max(axis=0) * rate_hz
    a = np.abs(np.diff(U, 2, axis=0)).max(axis=0) * rate_hz ** 2 if len(U) > 2 else np.zeros(spec.n_u)
    return U, {"kind": "given", "duration_s": float(len(U) / rate_hz), "command_rate_hz": float(rate_hz),
               "drive_rate_share": float(np.max(v / rate)), "drive_accel_share": float(np.max(a / accel))}


def read_streamed_commands(path, spec, length_unit: str) -> tuple[np.ndarray, float]:
    """(U (N, n_u) internal units, commands per s) of a streamed command log (commands.csv: ``t``
    at a steady rate, then the control columns in ``length_unit``), e.g. ``platkit plan --motion``'s;
    BadSession naming the file where ``t`` is missing or its rate is not steady."""
    table = read_table(path, "the streamed commands")
    if "t" not in table.header:
        raise BadSession(f"{path}: no 't' column; a streamed command log gives the time of every command")
    t = table.column("t")
    dt = np.diff(t)
    if len(t) < 3 or not np.all(np.isfinite(t)) or not np.all(dt > 0):
        raise BadSession(f"{path}: column 't' must hold at least 3 increasing times")
    med = float(np.median(dt))
    bad = np.nonzero(np.abs(dt - med) > STEADY_TOL_S + 1e-9 * med)[0]
    if len(bad):
        raise BadSession(f"{table.where(int(bad[0]) + 1, 't')}: the commands are not at a steady rate (interval "
                         f"{dt[bad[0]]:.6g} s, the log's {med:.6g} s); the simulator streams commands at one rate")
    return read_plan_csv(path, spec, length_unit), 1.0 / med
