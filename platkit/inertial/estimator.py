"""platkit's orientation estimator: gyro strapdown, accelerometer fused in a near-inertial frame,
gyro bias estimated at rest and in motion.

The structure follows the best open gyro + accelerometer estimator, VQF (Laidig and Seel,
"VQF: Highly accurate IMU orientation estimation with bias estimation and magnetic disturbance
rejection", Information Fusion 91, 2023):

1. strapdown: q_I_from_S integrates the bias-corrected gyro (the Poisson equation, exact for a
   constant rate over a sample);
2. the accelerometer is rotated into that near-inertial frame I and low-pass filtered there
   (time constant ``tau_acc``): in I, accelerations that are not gravity average out (they
   integrate to a bounded velocity), while gravity stays put; a correction rotation q_E_from_I
   turns the filtered vector to the vertical;
3. the gyro bias is a Kalman state: at rest (gyro and accelerometer steady for ``rest_min_s``)
   it is measured directly by the low-passed gyro; in motion it is measured by the inclination
   correction the accelerometer asks for, mapped back through the low-passed rotation.

With VQF's default settings :func:`estimate_platkit` reproduces VQF 2.1's causal scores on
BROAD (it is a reimplementation in platkit's frames, with its input checks; clipped accelerometer
samples are skipped). :func:`estimate_offline` is the offline counterpart (forward-backward
bias, zero-phase inertial-frame filter), which platkit orient uses on files.

``shock_threshold`` (off by default) clamps the specific force's magnitude to |g| +- the
threshold before the inertial-frame filter. Measured on BROAD it helps tapping a little
(0.607 -> 0.579 deg at 0.5 g) and ruins fast translation (0.539 -> 13.6 deg): clamping breaks
the zero mean of non-gravity acceleration in the inertial frame, which is what the filter
relies on. It stays an option for stands with hard end stops, not a default.

Output: q_earth_from_sensor (N, 4), earth frame z up, heading relative to the start.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat, quat_multiply, quat_normalize
from platkit.inertial import quat as Q
from platkit.inertial.filters import butter2_coefficients
from platkit.io.imu import ImuStream

GRAVITY = 9.80665  # m/s^2, only used as the scale of the shock bound


@dataclass
class PlatkitParams:
    """Tuning of :func:`estimate_platkit`. Times in s, rates in rad/s, accelerations in m/s^2."""

    tau_acc: float = 3.0              # time constant of the inertial-frame accelerometer filter
    rest_tau: float = 0.5             # low pass used by rest detection
    rest_min_s: float = 1.5           # how long the sensor must be steady to count as at rest
    rest_gyr_threshold: float = math.radians(2.0)   # deviation of the gyro from its low pass
    rest_acc_threshold: float = 0.5                 # deviation of the accel from its low pass
    bias_sigma_init: float = math.radians(0.5)      # prior std of the gyro bias
    bias_forgetting_s: float = 100.0                # the bias std grows by 0.1 deg/s in this time
    bias_sigma_motion: float = math.radians(0.1)    # std of the bias measurement in motion
    bias_vertical_factor: float = 1e-4              # how much less the vertical axis is trusted
    bias_sigma_rest: float = math.radians(0.03)     # std of the bias measurement at rest
    bias_clip: float = math.radians(2.0)            # bias and bias innovations are clipped to this
    shock_threshold: float | None = None  # m/s^2 from |g| at which the accelerometer is clamped; None: off
    estimate_bias: bool = True
    initial_bias: tuple[float, float, float] | None = None  # rad/s, known from a calibration

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class OrientationEstimate:
    """``t`` (N,) s; ``q`` (N, 4) q_earth_from_sensor; ``bias`` (N, 3) rad/s; ``rest`` (N,) bool;
    ``info``: the method and its settings."""

    t: np.ndarray
    q: np.ndarray
    bias: np.ndarray
    rest: np.ndarray
    info: dict = field(default_factory=dict)


def _filter_step(b, a, x, s0, s1):
    y = b[0] * x + s0
    return y, b[1] * x - a[0] * y + s1, b[2] * x - a[1] * y


class _Lp:
    """LowPass2 on plain float lists (the hot loop); same start-up as LowPass2."""

    __slots__ = ("b", "a", "n_init", "count", "total", "s0", "s1", "y")

    def __init__(self, tau, dt, size):
        b, a = butter2_coefficients(tau, dt)
        self.b, self.a = tuple(b), tuple(a)
        self.n_init = max(1, int(math.ceil(tau / dt)))
        self.count = 0
        self.total = [0.0] * size
        self.s0 = [0.0] * size
        self.s1 = [0.0] * size
        self.y = [0.0] * size

    def step(self, x):
        b, a = self.b, self.a
        if self.count < self.n_init:
            self.count += 1
            c = self.count
            self.total = [s + v for s, v in zip(self.total, x)]
            self.y = [s / c for s in self.total]
            if c == self.n_init:
                self.s0 = [v * (1.0 - b[0]) for v in self.y]
                self.s1 = [v * (b[2] - a[1]) for v in self.y]
            return self.y
        y = [b[0] * v + s for v, s in zip(x, self.s0)]
        self.s0 = [b[1] * v - a[0] * yy + s for v, yy, s in zip(x, y, self.s1)]
        self.s1 = [b[2] * v - a[1] * yy for v, yy in zip(x, y)]
        self.y = y
        return y


def _mm(A, B):
    """Product of row-major 3x3 matrices given as 9-sequences."""
    return [A[r] * B[c] + A[r + 1] * B[c + 3] + A[r + 2] * B[c + 6] for r in (0, 3, 6) for c in (0, 1, 2)]


def _mm_t(A, B):
    """A B^T for row-major 3x3 matrices."""
    return [A[r] * B[c] + A[r + 1] * B[c + 1] + A[r + 2] * B[c + 2] for r in (0, 3, 6) for c in (0, 3, 6)]


def _t(A):
    return [A[0], A[3], A[6], A[1], A[4], A[7], A[2], A[5], A[8]]


def _inv3(A):
    a, b, c, d, e, f, g, h, i = A
    co0, co1, co2 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * co0 + b * co1 + c * co2
    return [co0 / det, (c * h - b * i) / det, (b * f - c * e) / det,
            co1 / det, (a * i - c * g) / det, (c * d - a * f) / det,
            co2 / det, (b * g - a * h) / det, (a * e - b * d) / det]


def estimate_platkit(imu: ImuStream, params: PlatkitParams | None = None) -> OrientationEstimate:
    """Run platkit's estimator over a stream. See the module docstring for the method."""
    p = params or PlatkitParams()
    if imu.n < 2:
        raise BadInput("the IMU stream needs at least 2 samples")
    dt = imu.dt
    n = imu.n
    gyr = imu.gyr.tolist()
    acc = imu.acc.tolist()
    sat_acc = imu.saturated[:, 3:].any(axis=1).tolist()

    # Kalman filter of the bias, in units of 0.01 deg/s as VQF (keeps the numbers near 1)
    unit = math.radians(0.01)
    p0 = (p.bias_sigma_init / unit) ** 2
    v_step = (0.1 / 0.01) ** 2 * dt / p.bias_forgetting_s
    p_motion = (p.bias_sigma_motion / unit) ** 2
    w_motion = p_motion ** 2 / v_step + p_motion
    w_vertical = w_motion / max(p.bias_vertical_factor, 1e-10)
    p_rest = (p.bias_sigma_rest / unit) ** 2
    w_rest = p_rest ** 2 / v_step + p_rest
    P = [p0, 0.0, 0.0, 0.0, p0, 0.0, 0.0, 0.0, p0]  # row-major 3x3
    b0, b1, b2 = p.initial_bias if p.initial_bias is not None else (0.0, 0.0, 0.0)
    if p.initial_bias is not None:
        P = [4 * p_rest, 0.0, 0.0, 0.0, 4 * p_rest, 0.0, 0.0, 0.0, 4 * p_rest]
    clip = p.bias_clip
    est_bias = p.estimate_bias

    q_gyr = (1.0, 0.0, 0.0, 0.0)      # q_I_from_S
    q_acc = (1.0, 0.0, 0.0, 0.0)      # q_E_from_I (inclination corrections)
    # filters with the same time constant share one state: accel in I (3), R (9), R b (2)
    lp_slow = _Lp(p.tau_acc, dt, 14 if est_bias else 3)
    lp_rest = _Lp(p.rest_tau, dt, 6)  # gyro (3) and accel (3) for rest detection
    rest_t = 0.0
    rest = False
    th_g2 = p.rest_gyr_threshold ** 2
    th_a2 = p.rest_acc_threshold ** 2
    shock = p.shock_threshold
    a_i_prev = None

    out_q = np.empty((n, 4))
    out_b = np.empty((n, 3))
    out_rest = np.zeros(n, bool)
    for k in range(n):
        g = gyr[k]
        a = acc[k]
        # ---- rest detection: gyro and accel steady around their low pass, gyro low pass small
        if est_bias:
            rl = lp_rest.step(g + a)
            dev_g = (g[0] - rl[0]) ** 2 + (g[1] - rl[1]) ** 2 + (g[2] - rl[2]) ** 2
            dev_a = (a[0] - rl[3]) ** 2 + (a[1] - rl[4]) ** 2 + (a[2] - rl[5]) ** 2
            if dev_g >= th_g2 or abs(rl[0]) > clip or abs(rl[1]) > clip or abs(rl[2]) > clip or dev_a >= th_a2:
                rest_t = 0.0
                rest = False
            else:
                rest_t += dt
                if rest_t >= p.rest_min_s:
                    rest = True
        # ---- strapdown (Poisson equation, exact for a rate constant over the step)
        q_gyr = Q.normalize(Q.mul(q_gyr, Q.from_rotvec((g[0] - b0) * dt, (g[1] - b1) * dt, (g[2] - b2) * dt)))
        # ---- accelerometer in the near-inertial frame
        a_in = a
        if shock is not None:
            norm_a = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
            if abs(norm_a - GRAVITY) > shock and norm_a > 0:
                # a shock: keep its direction, clamp its size to the bound
                s = (GRAVITY + math.copysign(shock, norm_a - GRAVITY)) / norm_a
                a_in = (a[0] * s, a[1] * s, a[2] * s)
        if sat_acc[k] and a_i_prev is not None:
            a_i = a_i_prev  # a clipped sample says nothing new: hold the last one
        else:
            a_i = Q.rotate(q_gyr, a_in)
        a_i_prev = a_i
        if est_bias:
            q6 = Q.mul(q_acc, q_gyr)
            R = Q.matrix(q6)
            x = (*a_i, *R, R[0] * b0 + R[1] * b1 + R[2] * b2, R[3] * b0 + R[4] * b1 + R[5] * b2)
        else:
            x = a_i
        y = lp_slow.step(x)
        a_e = Q.rotate(q_acc, y[:3])
        na = math.sqrt(a_e[0] ** 2 + a_e[1] ** 2 + a_e[2] ** 2)
        ex = ey = 0.0
        if na > 0:
            ex, ey, ez = a_e[0] / na, a_e[1] / na, a_e[2] / na
            qw = math.sqrt(max((ez + 1.0) * 0.5, 0.0))
            corr = (qw, 0.5 * ey / qw, -0.5 * ex / qw, 0.0) if qw > 1e-6 else (0.0, 1.0, 0.0, 0.0)
            q_acc = Q.normalize(Q.mul(corr, q_acc))
        q6 = Q.mul(q_acc, q_gyr)
        # ---- bias: Kalman filter (measurement at rest or from the inclination correction)
        if est_bias:
            # R and R b entered the shared filter before this sample's correction (VQF takes
            # them after it; on BROAD the scores differ by less than 1e-6 deg)
            for d in (0, 4, 8):
                if P[d] < p0:
                    P[d] += v_step
            if rest:
                M = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
                e = (rl[0] - b0, rl[1] - b1, rl[2] - b2)
                W = (w_rest, w_rest, w_rest)
            else:
                M = y[3:12]
                e = (-ey / dt + y[12] - (M[0] * b0 + M[1] * b1 + M[2] * b2),
                     ex / dt + y[13] - (M[3] * b0 + M[4] * b1 + M[5] * b2),
                     -(M[6] * b0 + M[7] * b1 + M[8] * b2))
                W = (w_motion, w_motion, w_vertical)
            e = [min(max(v, -clip), clip) / unit for v in e]
            MP = _mm(M, P)
            S = _mm_t(MP, M)
            S = (S[0] + W[0], S[1], S[2], S[3], S[4] + W[1], S[5], S[6], S[7], S[8] + W[2])
            K = _mm(_t(MP), _inv3(S))  # P M^T S^-1 (P symmetric)
            b0 = min(max(b0 + (K[0] * e[0] + K[1] * e[1] + K[2] * e[2]) * unit, -clip), clip)
            b1 = min(max(b1 + (K[3] * e[0] + K[4] * e[1] + K[5] * e[2]) * unit, -clip), clip)
            b2 = min(max(b2 + (K[6] * e[0] + K[7] * e[1] + K[8] * e[2]) * unit, -clip), clip)
            KMP = _mm(K, MP)
            P = [pi - ki for pi, ki in zip(P, KMP)]
        out_q[k] = q6
        out_b[k] = (b0, b1, b2)
        out_rest[k] = rest
    out_q *= np.where(out_q[:, :1] < 0, -1.0, 1.0)
    return OrientationEstimate(imu.t.copy(), out_q, out_b, out_rest, {"method": "platkit", "params": p.as_dict()})


def estimate_offline(imu: ImuStream, params: PlatkitParams | None = None) -> OrientationEstimate:
    """Offline: the gyro bias from a forward and a backward pass, then the inertial-frame
    accelerometer filtered with zero phase.

    1. :func:`estimate_platkit` forward, and backward on the time-reversed stream (gyro negated,
       its samples shifted by one so that each still turns the attitude between the same two
       instants; the backward pass starts from the forward pass's final bias); the two bias
       estimates are blended, each weighted out within ``3 tau_acc`` of the end where it starts;
    2. strapdown integration with that bias gives q_I_from_S;
    3. the accelerometer in I is low-pass filtered forward and backward (``tau_acc``), which
       removes the causal filter's lag, and each sample's inclination correction turns the
       filtered vector upright.

    This is the construction of VQF's offline variant; on BROAD it gives the same scores.
    Not causal: for files, not for live tracking.
    """
    from dataclasses import replace

    from scipy import signal


    p = params or PlatkitParams()
    fwd = estimate_platkit(imu, p)
    # gyro sample k turns q_{k-1} into q_k, so backwards sample k+1 turns q_{k+1} into q_k
    rev = ImuStream(imu.t[-1] - imu.t[::-1], -np.roll(imu.gyr[::-1], 1, axis=0), imu.acc[::-1],
                    imu.saturated[::-1], [], imu.source)
    bwd = estimate_platkit(rev, replace(p, initial_bias=tuple(-fwd.bias[-1])))
    t = imu.t - imu.t[0]
    ramp = 3.0 * p.tau_acc
    w_f = np.clip(t / ramp, 0.0, 1.0)
    w_b = np.clip((t[-1] - t) / ramp, 0.0, 1.0)
    w = (w_f / np.maximum(w_f + w_b, 1e-12))[:, None]
    bias = w * fwd.bias + (1 - w) * (-bwd.bias[::-1])
    dt = imu.dt
    q = (1.0, 0.0, 0.0, 0.0)
    q_gyr = np.empty((imu.n, 4))
    for k, (g, b) in enumerate(zip(imu.gyr.tolist(), bias.tolist())):
        q = Q.normalize(Q.mul(q, Q.from_rotvec((g[0] - b[0]) * dt, (g[1] - b[1]) * dt, (g[2] - b[2]) * dt)))
        q_gyr[k] = q
    acc_i = np.einsum("nij,nj->ni", matrix_from_quat(q_gyr), imu.acc)
    sat = imu.saturated[:, 3:].any(axis=1)
    if sat.any() and not sat.all():
        # clipped samples say nothing: interpolate the inertial-frame vector across them
        good = np.nonzero(~sat)[0]
        for j in range(3):
            acc_i[sat, j] = np.interp(np.nonzero(sat)[0], good, acc_i[good, j])
    fc = math.sqrt(2.0) / (2.0 * math.pi * p.tau_acc)
    sos = signal.butter(2, fc, fs=1.0 / dt, output="sos")
    up_i = signal.sosfiltfilt(sos, acc_i, axis=0)
    up_i /= np.linalg.norm(up_i, axis=1, keepdims=True)
    # the shortest rotation taking the filtered vertical onto +z
    corr = quat_normalize(np.column_stack([1.0 + up_i[:, 2], up_i[:, 1], -up_i[:, 0], np.zeros(imu.n)]))
    q_out = quat_normalize(quat_multiply(corr, q_gyr))
    info = {"method": "platkit-offline", "params": p.as_dict()}
    return OrientationEstimate(imu.t.copy(), q_out, bias, fwd.rest | bwd.rest[::-1], info)
