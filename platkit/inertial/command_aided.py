"""What only a motion platform allows: the gyro fused with the orientation the calibrated model
predicts from the logged commands.

A command row says where the platform goes and holds. The calibrated model turns it into a pose
(``PlatformModel.forward_batch`` on the commands, with the calibration's td): an absolute
orientation with heading, free of drift, but only right once the platform has settled and only
as good as the calibration. The gyro is right at high frequency and drifts. The fusion:

1. the latency of the platform is measured: for every command that turns the platform, the
   time from the command to the onset of the gyro's rotation and to the end of it (95 % of the
   rotation angle); their medians are ``lag_s`` and ``settle_s``;
2. between a command's move and the next one's (see :func:`held_mask`), the platform holds the
   commanded pose: there the model's orientation is a reference, and the accelerometer, which
   then reads gravity alone, gives its tilt (:func:`accelerometer_tilt_references`);
3. a complementary filter on SO(3): the strapdown integration of the platform-frame rate,
   pulled towards the reference with time constant ``tau_ref`` where it holds, and an integral
   term (time constant ``tau_bias``) that estimates the gyro bias from the same pull.

Also :func:`estimate_alignment_from_commands`: the IMU's misalignment R_SP (and the gyro bias)
from the same session, by least squares between the rotations the model says the platform made
between held poses and the rotations the gyro integrated over the same intervals.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from platkit.errors import BadInput, NoConvergence, NotIdentifiable
from platkit.geometry import (
    matrix_from_quat,
    matrix_from_rotvec,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    rotvec_from_quat,
    skew,
)
from platkit.inertial import quat as Q
from platkit.inertial.calibration import fit_imu_alignment, integrate_gyro
from platkit.inertial.estimator import OrientationEstimate
from platkit.io.imu import ImuStream


@dataclass
class PlatformTiming:
    """How the platform follows its commands: ``lag_s`` (command to 5 % of the move's rotation)
    and ``settle_s`` (command to 95 %), medians over ``n_moves`` timed moves, their spreads
    (std, s), and per command row ``lag_by_command``/``settle_by_command`` (M,) s, NaN where a
    move could not be timed (moves of different sizes take different times)."""

    lag_s: float
    settle_s: float
    n_moves: int
    lag_std_s: float = float("nan")
    settle_std_s: float = float("nan")
    lag_by_command: np.ndarray | None = None
    settle_by_command: np.ndarray | None = None


def command_poses(model, U: np.ndarray, td=None) -> np.ndarray:
    """Orientations q_base_from_platform (N, 4) of command rows U (N, n_u) (SI controls).

    Raises ComputationFailed-family errors from forward kinematics for rows that do not
    converge."""

    fb = model.forward_batch(U, td=td, strict=False)
    if not np.all(fb.converged):
        i = int(np.nonzero(~fb.converged)[0][0])
        raise NoConvergence(f"forward kinematics of command row {i + 1}", int(fb.iterations[i]), float(fb.residual[i]))
    return fb.q


def hold_index(t: np.ndarray, t_cmd: np.ndarray) -> np.ndarray:
    """(n,) index of the command row in force at each time ``t`` (the last row sent at or before it)."""
    return np.clip(np.searchsorted(t_cmd, t, side="right") - 1, 0, len(t_cmd) - 1)


def estimate_timing(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, gyr_bias=None,
                    min_angle: float = math.radians(0.5)) -> PlatformTiming:
    """Latency and settling time of the platform from the gyro and the commands.

    For each command whose predicted rotation exceeds ``min_angle``, the gyro's rotation angle
    accumulated between this command and the next is found (rate above three times its 20th
    percentile: the noise, if the platform holds a fifth of the time); onset = 5 %, end = 95 %.
    The first command's move starts wherever the recording began, a pose no command gives: it is
    timed where the gyro turned by ``min_angle`` after it, for that command alone (the medians are
    the moves between commands).
    """
    b = np.zeros(3) if gyr_bias is None else np.asarray(gyr_bias, float)
    rate = np.linalg.norm(imu.gyr - b, axis=1)
    # the platform holds at least a fifth of the time: three times the 20th percentile of the
    # rate is above the noise, and only what exceeds it counts as motion (noise would otherwise
    # smear the onset and the end)
    rate = np.clip(rate - 3.0 * np.percentile(rate, 20), 0.0, None)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(imu.t))])
    steps = np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[:-1]), q_cmd[1:])), axis=1)
    lags, ends = [], []
    lag_k = np.full(len(t_cmd), np.nan)
    end_k = np.full(len(t_cmd), np.nan)
    for k in range(len(t_cmd)):
        if k > 0 and steps[k - 1] < min_angle:
            continue
        t0 = t_cmd[k]
        t1 = t_cmd[k + 1] if k + 1 < len(t_cmd) else imu.t[-1]
        i0, i1 = np.searchsorted(imu.t, [t0, t1])
        if i1 - i0 < 4:
            continue
        c = cum[i0:i1] - cum[i0]
        total = c[-1]
        if total < (0.5 * steps[k - 1] if k > 0 else min_angle):
            continue  # the gyro saw too little of this move (it ran into the next command)
        lag_k[k] = imu.t[i0 + np.searchsorted(c, 0.05 * total)] - t0
        end_k[k] = imu.t[min(i0 + np.searchsorted(c, 0.95 * total), i1 - 1)] - t0
        if k > 0:
            lags.append(lag_k[k])
            ends.append(end_k[k])
    if not lags:
        raise NotIdentifiable("platform latency: no command turned the platform enough to time it "
                              f"(need steps above {math.degrees(min_angle):.2g} deg with the gyro recording)")
    return PlatformTiming(float(np.median(lags)), float(np.median(ends)), len(lags),
                          float(np.std(lags)), float(np.std(ends)), lag_k, end_k)


def held_mask(t: np.ndarray, t_cmd: np.ndarray, timing: PlatformTiming, margin_s: float = 0.05) -> np.ndarray:
    """(N,) bool: samples where the platform holds the last command's pose.

    ``lag`` and ``settle`` mark 5 % and 95 % of a move (per command where it was timed, else the
    medians); the motion's slow start and end lie outside them, so the hold is taken from
    ``settle`` plus half the 5-95 % time (plus ``margin_s``) after a command, to the next
    command's ``lag`` minus as much (never before the next command). For a minimum-jerk move
    this is exactly its end and its start."""
    M = len(t_cmd)
    lag = np.full(M, timing.lag_s)
    settle = np.full(M, timing.settle_s)
    if timing.lag_by_command is not None and len(timing.lag_by_command) == M:
        known = np.isfinite(timing.lag_by_command) & np.isfinite(timing.settle_by_command)
        lag[known] = timing.lag_by_command[known]
        settle[known] = timing.settle_by_command[known]
    tail = 0.5 * np.clip(settle - lag, 0.0, None) + margin_s
    start = t_cmd + settle + tail                       # the hold of command k starts here
    end = np.append(t_cmd[1:] + np.clip(lag[1:] - tail[1:], 0.0, None), np.inf)  # and ends here
    k = hold_index(t, t_cmd)
    held = (t >= start[k]) & (t <= end[k]) & (t >= t_cmd[0])
    return held


def estimate_alignment_from_commands(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray,
                                     timing: PlatformTiming, fit_scale: bool = False, gyr_bias=None):
    """R_SP, gyro bias and (optionally) gyro scales from a session with commands.

    The gyro bias is the mean rate over the held samples; then for each pair of consecutive
    held intervals the gyro's integrated rotation (sensor frame) is matched with the model's
    rotation between the two commanded poses (platform frame) by least squares
    (:func:`platkit.inertial.calibration.fit_imu_alignment`). Returns (AlignmentFit, bias (3,)).
    """
    held = held_mask(imu.t, t_cmd, timing)
    if held.sum() < 10:
        raise NotIdentifiable("IMU alignment: the platform never held a pose long enough to use")
    bias = np.asarray(gyr_bias, float) if gyr_bias is not None else imu.gyr[held].mean(axis=0)
    k = hold_index(imu.t, t_cmd)
    # the middle sample of each held interval, per command
    mids = {}
    for i in np.unique(k[held]):
        idx = np.nonzero(held & (k == i))[0]
        mids[int(i)] = int(idx[len(idx) // 2])
    order = sorted(mids)
    r_p, r_s = [], []
    for a, b in zip(order[:-1], order[1:]):
        rp = rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b]))
        if np.linalg.norm(rp) < 1e-4:
            continue
        r_p.append(rp)
        r_s.append(integrate_gyro(imu.gyr[mids[a] + 1:mids[b] + 1], imu.dt, bias))
    if len(r_p) < 2:
        raise NotIdentifiable("IMU alignment: fewer than two moves between held poses")
    return fit_imu_alignment(np.array(r_p), np.array(r_s), fit_scale=fit_scale), bias


@dataclass
class CommandAidedParams:
    """``tau_ref`` (s): how fast the estimate is pulled to the model's orientation where the
    platform holds; ``tau_bias`` (s): the integral (bias) time constant; ``timing``: the
    platform's latency (None: estimated from the data); ``tilt_from_accelerometer``: replace the
    model's pose-dependent tilt by the accelerometer's at every hold (worth it only with a
    calibrated accelerometer: uncorrected scale errors of 0.5 % cost more than a calibrated
    model's tilt errors); ``level_base``: see :func:`accelerometer_tilt_references`."""

    tau_ref: float = 0.5
    tau_bias: float = 20.0
    timing: PlatformTiming | None = None
    tilt_from_accelerometer: bool = False
    level_base: bool = False
    extra: dict = field(default_factory=dict)


def accelerometer_tilt_references(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, held: np.ndarray,
                                  sensor_from_platform: np.ndarray, level_base: bool = False) -> tuple[np.ndarray, dict]:
    """Command poses (M, 4) with their tilt replaced by what the accelerometer measured while
    the platform held them, and a summary dict.

    While the platform holds a pose, the accelerometer reads gravity alone: the up direction in
    the platform frame, u_acc = R_SP^T mean(acc), free of the model's pose-dependent errors.
    What it shares with the model is only a constant: an accelerometer bias, a tilted base or a
    constant offset of the model all turn u_acc against the model's up u_cmd = R_bp^T e_z by the
    same small rotation at every pose. That rotation is fitted over all holds (least squares,
    small angle) and removed, so the base frame stays the model's; each command pose is then
    turned (in the platform frame, by the shortest rotation) until its up is the corrected
    u_acc. Heading stays the model's. Commands without a held interval keep the model's pose.

    ``level_base``: the base frame's z is known to be vertical and the accelerometer calibrated;
    then the constant part is kept too, and the tilt is the accelerometer's alone.
    """

    R_sp = np.asarray(sensor_from_platform, float)
    k = hold_index(imu.t, t_cmd)
    u_acc, u_cmd, which = [], [], []
    for i in np.unique(k[held]):
        sel = held & (k == i)
        if sel.sum() < 5:
            continue
        a = R_sp.T @ imu.acc[sel].mean(axis=0)
        u_acc.append(a / np.linalg.norm(a))
        u_cmd.append(matrix_from_quat(q_cmd[i])[2, :])  # R_bp^T e_z: the base's up in the platform frame
        which.append(int(i))
    q_out = q_cmd.copy()
    if len(which) < 3:
        return q_out, {"holds": len(which), "used": False}
    u_acc, u_cmd = np.array(u_acc), np.array(u_cmd)
    # u_cmd ~ u_acc + theta x u_acc = u_acc - skew(u_acc) theta, over all holds
    A = -skew(u_acc).reshape(-1, 3)
    theta = np.zeros(3) if level_base else np.linalg.lstsq(A, (u_cmd - u_acc).ravel(), rcond=1e-6)[0]
    u_fix = u_acc @ matrix_from_rotvec(theta).T
    u_fix /= np.linalg.norm(u_fix, axis=1, keepdims=True)
    for j, i in enumerate(which):
        # R_ref = R_cmd R(r) with R(r) u_fix = u_cmd, so that R_ref^T e_z = u_fix
        q_out[i] = quat_normalize(quat_multiply(q_cmd[i], np.array(Q.from_two_vectors(tuple(u_fix[j]), tuple(u_cmd[j])))))
    dis = np.degrees(np.arccos(np.clip(np.sum(u_fix * u_cmd, axis=1), -1, 1)))
    return q_out, {"holds": len(which), "used": True, "constant_offset_deg": float(np.degrees(np.linalg.norm(theta))),
                   "model_tilt_disagreement_rms_deg": float(np.sqrt(np.mean(dis**2)))}


def estimate_command_aided(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray,
                           sensor_from_platform: np.ndarray | None = None, gyr_bias=None,
                           params: CommandAidedParams | None = None) -> OrientationEstimate:
    """Complementary fusion of the gyro with the command-predicted orientation.

    ``imu``: calibrated stream (scale removed; the bias is estimated on top of ``gyr_bias``);
    ``t_cmd`` (M,) s and ``q_cmd`` (M, 4) q_base_from_platform of the command rows;
    ``sensor_from_platform``: R_SP (3, 3). Returns q_base_from_platform (N, 4) in ``q``, the
    bias in sensor axes in ``bias``, and ``rest`` = the samples where the reference was used.
    """
    p = params or CommandAidedParams()
    t_cmd = np.asarray(t_cmd, float)
    q_cmd = quat_normalize(np.asarray(q_cmd, float))
    if len(t_cmd) != len(q_cmd) or len(t_cmd) < 2:
        raise BadInput("command-aided orientation needs at least 2 command rows with their poses")
    R_sp = np.eye(3) if sensor_from_platform is None else np.asarray(sensor_from_platform, float)
    b0 = np.zeros(3) if gyr_bias is None else np.asarray(gyr_bias, float)
    timing = p.timing or estimate_timing(imu, t_cmd, q_cmd, b0)
    held = held_mask(imu.t, t_cmd, timing)
    tilt_info = {"used": False}
    if p.tilt_from_accelerometer:
        q_cmd, tilt_info = accelerometer_tilt_references(imu, t_cmd, q_cmd, held, R_sp, p.level_base)
    k_cmd = hold_index(imu.t, t_cmd)
    dt = imu.dt
    g_ref = dt / p.tau_ref
    g_bias = dt / p.tau_bias * g_ref
    Rt = R_sp.T.tolist()
    R = R_sp.tolist()
    gyr = imu.gyr.tolist()
    held_l = held.tolist()
    kc = k_cmd.tolist()
    qc = [tuple(x) for x in q_cmd.tolist()]
    # the estimate starts at the first held sample, at its command's pose: before the first
    # command arrives the platform holds a pose no command gives (wherever the recording began);
    # the samples before it are the gyro integrated back from there
    first = int(np.argmax(held)) if held.any() else 0
    q = qc[kc[first]]
    b = list(b0)
    n = imu.n
    out_q = np.empty((n, 4))
    out_b = np.empty((n, 3))
    for i in range(first, n):
        g = gyr[i]
        ws = (g[0] - b[0], g[1] - b[1], g[2] - b[2])
        wp = [Rt[r][0] * ws[0] + Rt[r][1] * ws[1] + Rt[r][2] * ws[2] for r in range(3)]
        if i > first:
            q = Q.normalize(Q.mul(q, Q.from_rotvec(wp[0] * dt, wp[1] * dt, wp[2] * dt)))
        if held_l[i]:
            # error rotation in the platform frame: q_ref = q * exp(e)
            d = Q.mul(Q.conj(q), qc[kc[i]])
            if d[0] < 0:
                d = (-d[0], -d[1], -d[2], -d[3])
            s = math.sqrt(d[1] ** 2 + d[2] ** 2 + d[3] ** 2)
            ang = 2.0 * math.atan2(s, d[0])
            f = ang / s if s > 1e-12 else 2.0
            e = (d[1] * f, d[2] * f, d[3] * f)
            q = Q.normalize(Q.mul(q, Q.from_rotvec(e[0] * g_ref, e[1] * g_ref, e[2] * g_ref)))
            es = [R[r][0] * e[0] + R[r][1] * e[1] + R[r][2] * e[2] for r in range(3)]
            b = [b[r] - g_bias * es[r] / dt for r in range(3)]
        out_q[i] = q
        out_b[i] = b
    q = tuple(out_q[first].tolist())
    for i in range(first, 0, -1):  # q_(i-1) = q_i exp(-w_i dt), the forward step undone
        g = gyr[i]
        ws = (g[0] - b0[0], g[1] - b0[1], g[2] - b0[2])
        wp = [Rt[r][0] * ws[0] + Rt[r][1] * ws[1] + Rt[r][2] * ws[2] for r in range(3)]
        q = Q.normalize(Q.mul(q, Q.from_rotvec(-wp[0] * dt, -wp[1] * dt, -wp[2] * dt)))
        out_q[i - 1] = q
        out_b[i - 1] = b0
    out_q *= np.where(out_q[:, :1] < 0, -1.0, 1.0)
    info = {"method": "command-aided", "lag_s": timing.lag_s, "settle_s": timing.settle_s,
            "timed_moves": timing.n_moves, "held_fraction": float(held.mean()),
            "tau_ref": p.tau_ref, "tau_bias": p.tau_bias, "tilt_from_accelerometer": tilt_info}
    return OrientationEstimate(imu.t.copy(), out_q, out_b, held, info)
