"""Simulated IMU samples from a known platform motion.

The gyro sample k is the rotation from sample k-1 to k divided by dt (so that the strapdown
integration of :mod:`platkit.inertial` reproduces the motion exactly when the sensor is perfect);
the accelerometer measures the specific force f = a - g at the sensor's position (the platform
origin plus ``lever_arm``), both in sensor axes. Base frame z up, g = (0, 0, -|g|); with a
``base_tilt`` w (rad, about the base's x and y axes) the base is tilted against the level: the
level frame is R_tilt = exp([w_x, w_y, 0]x) from the base, and gravity in the base frame is
R_tilt^T (0, 0, -|g|). A platform holding still then reads f = R_SP R^T R_tilt^T (0, 0, |g|)
(R = R_base_from_platform, R_SP the sensor's mounting) plus its bias.

Sensor errors, applied as  y = scale * (A y_true) + bias(t) + noise  per axis, with A the axes'
non-orthogonality (identity + small off-diagonal terms) and bias(t) = bias + a random walk of
``bias_drift`` (rad/s/sqrt(s)) for the gyro.

IMU effects (:class:`platkit.effects.ImuEffect`, registered plugins, e.g. ``gyro_bias_drift``,
``imu_misalignment``, ``imu_base_tilt``) act through their own sensor model, the one the IMU
diagnosis fits: ``effects=[(effect, theta), ...]`` turn the sensor (``sensor_from_platform``,
after ``imu_from_platform``), tilt the base (``level_from_base``: R_tilt above) and add to the
gyro's and the accelerometer's bias (``gyro_bias``, ``accelerometer_bias``, time from the first
sample). ``base_tilt`` and ``bias_rate`` are the built-in ``imu_base_tilt`` and
``gyro_bias_drift`` given by their parameters.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.effects import ImuEffect, imu_sensor_model
from platkit.errors import BadInput
from platkit.geometry import (
    matrix_from_quat,
    quat_conjugate,
    quat_from_matrix,
    quat_from_rotvec,
    quat_from_rpy,
    quat_multiply,
    quat_normalize,
    rotvec_from_quat,
)
from platkit.io.atomic import atomic_output_dir
from platkit.io.imu import write_imu_csv
from platkit.kinematics import PlatformModel
from platkit.model import controls_from_si
from platkit.plugins import effect_library

G_STANDARD = 9.80665


def _six(value, default: float, what: str) -> np.ndarray:
    if value is None:
        return np.full(6, default)
    v = np.asarray(value, float)
    if v.shape == ():
        return np.full(6, float(v))
    if v.shape != (6,):
        raise BadInput(f"{what}: expected one number or 6 (gyro x, y, z, accelerometer x, y, z), got shape {v.shape}")
    return v


def _tilt(value) -> np.ndarray:
    """A base tilt (2,) rad about the base's x and y axes (None: level)."""
    if value is None:
        return np.zeros(2)
    w = np.asarray(value, float)
    if w.shape != (2,) or not np.all(np.isfinite(w)):
        raise BadInput(f"base_tilt: expected 2 finite numbers (rad about the base's x and y axes), got {value!r}")
    return w


def keyword_effect(keyword: str) -> ImuEffect:
    """The installed IMU effect whose theta the keyword ``keyword`` of :func:`imu_from_motion`
    gives (its ``simulation_keyword``); BadInput when no installed effect takes it."""
    for effect in effect_library().values():
        if isinstance(effect, ImuEffect) and effect.simulation_keyword == keyword:
            return effect
    raise BadInput(f"{keyword}: no installed IMU effect simulates it (an ImuEffect with simulation_keyword {keyword!r})")


def named_effects(base_tilt=None, bias_rate=None) -> list[tuple[ImuEffect, np.ndarray]]:
    """The installed IMU effects for a base tilt (2,) rad about the base's x and y axes and a
    linear gyro bias drift (3,) rad/s per s (None: none), as (effect, theta): the effects whose
    ``simulation_keyword`` is 'base_tilt' and 'bias_rate'."""
    out = []
    if base_tilt is not None:
        out.append((keyword_effect("base_tilt"), _tilt(base_tilt)))
    if bias_rate is not None:
        rate = np.asarray(bias_rate, float)
        if rate.shape != (3,) or not np.all(np.isfinite(rate)):
            raise BadInput(f"bias_rate: expected 3 numbers (gyro x, y, z rad/s per s), got shape {rate.shape}")
        out.append((keyword_effect("bias_rate"), rate))
    return out


def split_imu_effects(effects: list[tuple[str, float | None]], seed: int = 0,
                      library=None) -> tuple[list[tuple[ImuEffect, np.ndarray]], list[tuple[str, float | None]]]:
    """``platkit simulate --effect NAME=SIZE`` for IMU effects: (the IMU effects among ``effects``
    as (effect, theta) in a random direction (from ``seed``) of ``SIZE`` in the effect's display
    unit, the other effects as given). ``library``: effect name -> effect (default: every
    installed one)."""
    lib = effect_library() if library is None else library
    rng = np.random.default_rng([seed, 7])
    imu, rest = [], []
    for name, size in effects:
        e = lib.get(name)
        if not isinstance(e, ImuEffect):
            rest.append((name, size))
            continue
        if size is None or not size > 0:
            raise BadInput(f"--effect {name}: an IMU effect needs its size, {name}=SIZE in {e.display_unit}")
        imu.append((e, e.simulation_theta(size, rng)))
    return imu, rest


def _check_effects(effects) -> list[tuple[ImuEffect, np.ndarray]]:
    out = []
    for item in effects or ():
        try:
            e, theta = item
        except (TypeError, ValueError):
            raise BadInput(f"IMU effects: expected (effect, theta) pairs, got {item!r}") from None
        theta = np.asarray(theta, float)
        if not isinstance(e, ImuEffect):
            raise BadInput(f"IMU effects: {e!r} is not an IMU effect (platkit.effects.ImuEffect)")
        if theta.shape != (e.n_params,) or not np.all(np.isfinite(theta)):
            raise BadInput(f"IMU effect {e.name!r}: expected {e.n_params} finite parameters "
                           f"({', '.join(e.parameter_names)}), got {theta.tolist()!r}")
        out.append((e, theta))
    return out


def imu_from_motion(t, q_base_from_platform, X, imu_from_platform=None, bias=None, bias_drift: float = 0.0,
                    scale=None, misalignment=None, noise=None, rng: np.random.Generator | None = None,
                    lever_arm=None, gravity: float = G_STANDARD, base_tilt=None, bias_rate=None,
                    effects=()) -> dict:
    """IMU samples of a sensor riding on the platform.

    Args:
        t: (N,) s, uniform.
        q_base_from_platform: (N, 4) w x y z, the platform frame in the base frame (z up).
        X: (N, 3) m, the platform origin in the base frame.
        imu_from_platform: R_SP, (3, 3) matrix or (4,) quaternion (default identity).
        bias: (6,) gyro rad/s then accelerometer m/s^2 (or one number; default 0).
        bias_drift: gyro bias random walk, rad/s/sqrt(s).
        scale: (6,) scale factors (default 1).
        misalignment: (3, 3) axes non-orthogonality A, shared by both sensors (default identity).
        noise: (2,) white-noise std per sample: gyro rad/s, accelerometer m/s^2 (default 0).
        rng: numpy Generator (default: seed 0).
        lever_arm: (3,) m, the sensor's position in the platform frame (default origin).
        base_tilt: (2,) rad, the base tilted against the level about its x and y axes (default 0).
        bias_rate: (3,) rad/s per s, a gyro bias changing linearly from the first sample (default 0).
        effects: [(ImuEffect, theta (n,) SI)], IMU effects through their own sensor model.
    Returns a dict of arrays: ``t``, ``gyr`` (N, 3), ``acc`` (N, 3), ``gyr_true``, ``acc_true``
    (error-free, sensor axes), ``gyr_bias`` (N, 3) the bias actually applied, and
    ``q_earth_from_sensor`` (N, 4) the sensor's true orientation (earth: the level frame).
    """
    t = np.asarray(t, float)
    n = len(t)
    q = quat_normalize(np.asarray(q_base_from_platform, float))
    X = np.asarray(X, float)
    if q.shape != (n, 4) or X.shape != (n, 3):
        raise BadInput(f"motion arrays must be q (N, 4) and X (N, 3) for N = {n} times, got {q.shape} and {X.shape}")
    if n < 3:
        raise BadInput("a motion needs at least 3 samples")
    dt = np.diff(t)
    if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * np.mean(dt):
        raise BadInput("simulated IMU times must be uniform and increasing")
    dt = float(np.mean(dt))
    rng = rng if rng is not None else np.random.default_rng(0)
    if imu_from_platform is None:
        R_sp = np.eye(3)
    else:
        m = np.asarray(imu_from_platform, float)
        R_sp = matrix_from_quat(m) if m.shape == (4,) else m
    A = np.eye(3) if misalignment is None else np.asarray(misalignment, float)
    b = _six(bias, 0.0, "bias")
    s = _six(scale, 1.0, "scale")
    nz = np.zeros(2) if noise is None else np.broadcast_to(np.asarray(noise, float), (2,))
    r = np.zeros(3) if lever_arm is None else np.asarray(lever_arm, float)
    active = named_effects(base_tilt, bias_rate) + _check_effects(effects)
    R_eff, R_tilt = imu_sensor_model(active)
    R_sp = R_eff @ R_sp

    # rate: the rotation between consecutive samples, in the platform frame, over dt
    w_p = np.empty((n, 3))
    w_p[1:] = rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:])) / dt
    w_p[0] = w_p[1]
    R_bp = matrix_from_quat(q)
    pos = X + np.einsum("nij,j->ni", R_bp, r)
    acc_b = np.gradient(np.gradient(pos, dt, axis=0), dt, axis=0)
    f_b = acc_b - R_tilt.T @ np.array([0.0, 0.0, -gravity])
    f_p = np.einsum("nji,nj->ni", R_bp, f_b)
    gyr_true = w_p @ R_sp.T
    acc_true = f_p @ R_sp.T
    drift = np.zeros((n, 3))
    if bias_drift > 0:
        drift = np.cumsum(rng.normal(0.0, bias_drift * np.sqrt(dt), (n, 3)), axis=0)
        drift -= drift[0]
    tau = t - t[0]
    gyr_bias = b[:3] + drift + sum((np.asarray(e.gyro_bias(th, tau), float) for e, th in active), np.zeros((n, 3)))
    acc_bias = b[3:] + sum((np.asarray(e.accelerometer_bias(th, tau), float) for e, th in active), np.zeros((n, 3)))
    gyr = s[:3] * (gyr_true @ A.T) + gyr_bias + rng.normal(0.0, nz[0], (n, 3))
    acc = s[3:] * (acc_true @ A.T) + acc_bias + rng.normal(0.0, nz[1], (n, 3))
    q_es = quat_normalize(quat_multiply(quat_multiply(quat_from_matrix(R_tilt)[None, :], q),
                                        quat_conjugate(quat_from_matrix(R_sp))[None, :]))
    return {"t": t, "gyr": gyr, "acc": acc, "gyr_true": gyr_true, "acc_true": acc_true,
            "gyr_bias": gyr_bias, "q_earth_from_sensor": q_es}


def write_imu(path: str | Path, sim: dict) -> None:
    """Write the ``t``, ``gyr``, ``acc`` of :func:`imu_from_motion` as imu.csv (atomically)."""
    write_imu_csv(path, sim["t"], sim["gyr"], sim["acc"])


def smooth_motion_from_steps(t_cmd, q_cmd, X_cmd, rate_hz: float, move_s: float, lag_s: float = 0.0,
                             t_end: float | None = None):
    """A platform motion that follows step commands: after each command (lagging ``lag_s``)
    the platform moves to the commanded pose along a minimum-jerk path of ``move_s`` seconds
    (slerp in orientation), then holds. Returns (t (N,), q (N, 4), X (N, 3)) at ``rate_hz``.
    """
    t_cmd = np.asarray(t_cmd, float)
    q_cmd = quat_normalize(np.asarray(q_cmd, float))
    X_cmd = np.asarray(X_cmd, float)
    t_end = t_end if t_end is not None else t_cmd[-1] + lag_s + move_s + 1.0
    t = np.arange(t_cmd[0], t_end, 1.0 / rate_hz)
    q = np.empty((len(t), 4))
    X = np.empty((len(t), 3))
    k = np.clip(np.searchsorted(t_cmd + lag_s, t, side="right") - 1, 0, None)
    for i in range(len(t_cmd)):
        sel = k == i
        if not sel.any():
            continue
        prev = max(i - 1, 0)
        s = np.clip((t[sel] - t_cmd[i] - lag_s) / move_s, 0.0, 1.0) if i else np.ones(sel.sum())
        s = s**3 * (10 - 15 * s + 6 * s**2)
        d = rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[prev]), q_cmd[i]))

        q[sel] = quat_multiply(q_cmd[prev][None, :], quat_from_rotvec(s[:, None] * d[None, :]))
        X[sel] = X_cmd[prev] + s[:, None] * (X_cmd[i] - X_cmd[prev])
    before = t < t_cmd[0] + lag_s
    q[before] = q_cmd[0]
    X[before] = X_cmd[0]
    return t, quat_normalize(q), X


def platform_imu_session(spec, td_true, td_model, rng: np.random.Generator, n_commands: int = 30,
                         hold_s: float = 3.0, move_s: float = 1.0, lag_s: float = 0.08, rate_hz: float = 200.0,
                         tilt_max: float = np.radians(8.0), yaw_max: float = np.radians(8.0),
                         shift_max: float = 0.1, controls_fraction: float | None = None, **imu_kw) -> dict:
    """A simulated platform session with an IMU, for a stand ``spec``.

    Desired poses are drawn around the neutral pose (roll, pitch within ``tilt_max``, yaw within
    ``yaw_max``, position within ``shift_max`` m); the commands are their inverse kinematics with
    the model parameters ``td_model`` (what a user's calibration knows); the platform really goes
    to the forward kinematics with ``td_true``, lagging ``lag_s`` and moving for ``move_s`` after
    each command (minimum jerk), holding ``hold_s`` between commands. With ``controls_fraction``
    the commands are drawn instead uniformly in control space, within that fraction of each
    stroke around the neutral controls (any stand, e.g. one without yaw). ``imu_kw`` go to
    :func:`imu_from_motion`. Returns a dict: ``t_cmd`` (M,), ``U`` (M, n_u) SI, ``q_cmd`` (M, 4)
    (the model's poses), ``t``, ``q_true`` (N, 4) q_base_from_platform, ``X_true`` (N, 3), and
    the IMU arrays of :func:`imu_from_motion`.
    """

    model = PlatformModel(spec)
    if controls_fraction is not None:
        lo, hi = spec.control_bounds()
        u0 = spec.neutral_u()
        half = controls_fraction * np.minimum(hi - u0, u0 - lo)
        U = u0 + rng.uniform(-1, 1, (n_commands, spec.n_u)) * half
        U[0] = u0
    else:
        q0, X0 = model.pose(spec.neutral_p())
        rpy = rng.uniform(-1, 1, (n_commands, 3)) * np.array([tilt_max, tilt_max, yaw_max])
        rpy[0] = 0.0
        dX = rng.uniform(-1, 1, (n_commands, 3)) * shift_max
        dX[0] = 0.0
        q_des = quat_multiply(q0[None, :], quat_from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2]))
        U = np.array([model.inverse(q_des[i], X0 + dX[i], td=td_model, strict=False) for i in range(n_commands)])
    true = model.forward_batch(U, td=td_true, strict=False)
    pred = model.forward_batch(U, td=td_model, strict=False)
    t_cmd = 2.0 + hold_s * np.arange(n_commands)
    t, q, X = smooth_motion_from_steps(t_cmd, true.q, true.X, rate_hz, move_s, lag_s, t_end=t_cmd[-1] + hold_s)
    sim = imu_from_motion(t, q, X, rng=rng, **imu_kw)
    sim.update({"t_cmd": t_cmd, "U": U, "q_cmd": pred.q, "q_true": q, "X_true": X})
    return sim


def write_platform_imu_session(sim: dict, spec, out: str | Path, truth_imu: dict | None = None,
                               length_unit: str = "mm") -> Path:
    """Write :func:`platform_imu_session`'s output as a session folder: session.yaml,
    commands.csv, imu.csv, truth_orientation.csv, and truth_imu.yaml (``truth_imu``: the
    sensor's true errors, keys as docs/inertial.md lists them). Written whole or not at all."""
    import yaml


    rate = 1.0 / float(np.mean(np.diff(sim["t"])))
    with atomic_output_dir(out) as tmp:
        (tmp / "session.yaml").write_text(yaml.safe_dump({
            "platform": spec.name, "description": None, "units": {"length": length_unit, "time": "s"},
            "markers": [], "imu": {"rate_hz": round(rate, 6), "frame": "imu"},
            "notes": "simulated platform session with an IMU (platkit.inertial.simulate)"}, sort_keys=False))
        U = controls_from_si(spec, sim["U"], length_unit)
        lines = [",".join(["t"] + spec.control_names)]
        lines += [",".join(f"{v:.10g}" for v in [t, *u]) for t, u in zip(sim["t_cmd"], U)]
        (tmp / "commands.csv").write_text("\n".join(lines) + "\n")
        write_imu_csv(tmp / "imu.csv", sim["t"], sim["gyr"], sim["acc"])
        lines = ["t,qw,qx,qy,qz"] + [f"{t:.9g},{a:.10f},{b:.10f},{c:.10f},{d:.10f}"
                                      for t, (a, b, c, d) in zip(sim["t"], sim["q_true"])]
        (tmp / "truth_orientation.csv").write_text("\n".join(lines) + "\n")
        if truth_imu:
            plain = {k: np.asarray(v, float).tolist() for k, v in truth_imu.items()}
            (tmp / "truth_imu.yaml").write_text(yaml.safe_dump(plain, sort_keys=False))
    return Path(out)


def imu_for_trajectory(rate_hz: float = 200.0, imu_from_platform=None, bias=None, bias_drift: float = 0.0,
                       scale=None, misalignment=None, noise=(0.002, 0.02), lever_arm=None, base_tilt=None,
                       bias_rate=None, effects=()):
    """A callable ``imu(trajectory, rng) -> dict`` for :func:`platkit.simulate.simulate`'s ``imu``
    hook: it samples the true trajectory (``trajectory.at(t)`` -> q, X) at ``rate_hz`` from 0 to
    ``trajectory.end_t`` and returns :func:`imu_from_motion`'s arrays plus ``entry`` (the
    session.yaml ``imu`` mapping), ``q_base_from_platform`` (N, 4) (the truth for
    truth_orientation.csv) and ``truth_imu`` (the sensor's true errors for truth_imu.yaml; IMU
    ``effects`` [(ImuEffect, theta)] under ``effects``, name -> theta SI).
    Before the first command the platform rests where the trajectory has it at that command
    (with any pose effects of the first row, e.g. a tilted base, already there)."""
    tilt = None if base_tilt is None else _tilt(base_tilt)
    extra = _check_effects(effects)
    named_effects(tilt, bias_rate)  # bad values are named before any simulation

    def imu(trajectory, rng):
        t = np.arange(0.0, float(trajectory.end_t), 1.0 / rate_hz)
        t0 = float(trajectory.command_t[0]) if len(trajectory.command_t) else 0.0
        q, X = trajectory.at(np.maximum(t, t0))
        out = imu_from_motion(t, q, X, imu_from_platform, bias, bias_drift, scale, misalignment, noise, rng, lever_arm,
                              base_tilt=tilt, bias_rate=bias_rate, effects=extra)
        R = np.eye(3) if imu_from_platform is None else np.asarray(imu_from_platform, float)
        if R.shape == (4,):
            R = matrix_from_quat(R)
        R = imu_sensor_model(extra)[0] @ R
        b = _six(bias, 0.0, "bias")
        s = _six(scale, 1.0, "scale")
        out["entry"] = {"rate_hz": float(rate_hz), "frame": "imu"}
        out["q_base_from_platform"] = quat_normalize(q)
        out["truth_imu"] = {"gyr_bias_rad_s": b[:3].tolist(), "acc_bias_m_s2": b[3:].tolist(),
                            "gyr_scale": s[:3].tolist(), "acc_scale": s[3:].tolist(),
                            "sensor_from_platform": R.tolist()}
        if tilt is not None:
            out["truth_imu"]["base_tilt_rad"] = tilt.tolist()
        if bias_rate is not None:
            out["truth_imu"]["gyr_bias_rate_rad_s2"] = np.asarray(bias_rate, float).tolist()
        if extra:
            out["truth_imu"]["effects"] = {e.name: th.tolist() for e, th in extra}
        return out

    return imu
