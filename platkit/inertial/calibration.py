"""Sensor calibration: zero biases, scale factors, and the IMU's misalignment on the platform.

Sensor model (per axis i, sensor frame S, platform frame P):

    gyr_i = s_gyr_i (R_SP omega_P)_i + b_gyr_i + noise
    acc_i = s_acc_i f_i + b_acc_i + noise          (f: specific force in S, |f| = |g| at rest)

- rest: :func:`detect_rest` (gyro and accelerometer steady over a window) and
  :func:`rest_segments`;
- gyro bias: :func:`gyro_bias_at_rest`, the mean rate over rest samples;
- accelerometer bias and scale: :func:`fit_accelerometer`, an axis-aligned ellipsoid fitted to
  the mean specific force of several static positions (six positions, each axis up and down, is
  the classic set; any set that tilts every axis both ways works);
- misalignment R_SP (and gyro scale): :func:`fit_imu_alignment`, least squares (Wahba / Kabsch)
  between rotation vectors the platform made (in P, from the calibrated model and the logged
  commands, or single platform axes as in the paper) and the ones the gyro integrated (in S).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from platkit.errors import BadInput, NotIdentifiable, PlatkitError
from platkit.geometry import quat_conjugate, quat_from_rotvec, quat_multiply, quat_normalize, rotvec_from_quat
from platkit.io.atomic import atomic_write_text
from platkit.io.imu import ImuStream, read_imu_csv

G_STANDARD = 9.80665


@dataclass
class ImuCalibration:
    """Everything needed to turn raw samples into platform-frame rates and specific forces.

    ``gyr_bias`` (3,) rad/s, ``gyr_scale`` (3,), ``acc_bias`` (3,) m/s^2, ``acc_scale`` (3,),
    ``sensor_from_platform`` (3, 3): R_SP. ``std``: standard deviations of the fitted numbers,
    same keys, where known.
    """

    gyr_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyr_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    acc_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    acc_scale: np.ndarray = field(default_factory=lambda: np.ones(3))
    sensor_from_platform: np.ndarray = field(default_factory=lambda: np.eye(3))
    std: dict = field(default_factory=dict)

    def apply(self, imu: ImuStream) -> ImuStream:
        """A stream with biases and scales removed (still in sensor axes)."""
        gyr = (imu.gyr - self.gyr_bias) / self.gyr_scale
        acc = (imu.acc - self.acc_bias) / self.acc_scale
        return ImuStream(imu.t, gyr, acc, imu.saturated, list(imu.repairs), imu.source)

    def to_dict(self) -> dict:
        return {
            "gyr_bias_rad_s": self.gyr_bias.tolist(), "gyr_scale": self.gyr_scale.tolist(),
            "acc_bias_m_s2": self.acc_bias.tolist(), "acc_scale": self.acc_scale.tolist(),
            "sensor_from_platform": np.asarray(self.sensor_from_platform).tolist(),
            "std": {k: np.asarray(v).tolist() for k, v in self.std.items()},
        }

    @classmethod
    def from_dict(cls, d: dict, source: str = "imu calibration") -> ImuCalibration:
        def arr(key, shape, default):
            if key not in d:
                return default
            a = np.asarray(d[key], float)
            if a.shape != shape or not np.all(np.isfinite(a)):
                raise BadInput(f"{source}: field {key!r} must be {shape} finite numbers")
            return a

        R = arr("sensor_from_platform", (3, 3), np.eye(3))
        if abs(np.linalg.det(R) - 1) > 1e-3 or np.abs(R @ R.T - np.eye(3)).max() > 1e-3:
            raise BadInput(f"{source}: field 'sensor_from_platform' is not a rotation matrix")
        return cls(arr("gyr_bias_rad_s", (3,), np.zeros(3)), arr("gyr_scale", (3,), np.ones(3)),
                   arr("acc_bias_m_s2", (3,), np.zeros(3)), arr("acc_scale", (3,), np.ones(3)), R)


def _moving_std(x: np.ndarray, k: int) -> np.ndarray:
    """Std over a centred window of k samples, per sample (N,) of (N, d) data (summed over d): the
    window of sample i is [i - k // 2, i + (k - 1) // 2], the ends padded with the first and last
    samples (scipy.ndimage.uniform_filter1d's mode "nearest", by running sums: no scipy.ndimage
    to import for a verb's start-up)."""
    x = np.asarray(x, float)
    pad = np.concatenate([np.repeat(x[:1], k // 2, axis=0), x, np.repeat(x[-1:], (k - 1) // 2, axis=0)])

    def mean(v):
        c = np.concatenate([np.zeros((1,) + v.shape[1:]), np.cumsum(v, axis=0)])
        return (c[k:] - c[:-k]) / k

    m = mean(pad)
    m2 = mean(pad * pad)
    return np.sqrt(np.clip(m2 - m * m, 0, None).sum(axis=1))


def detect_rest(imu: ImuStream, window_s: float = 1.0, gyr_threshold: float = np.radians(0.5),
                acc_threshold: float = 0.1) -> np.ndarray:
    """(N,) bool: samples inside a window of ``window_s`` where the gyro's std stays below
    ``gyr_threshold`` (rad/s) and the accelerometer's below ``acc_threshold`` (m/s^2).
    Offline (centred windows)."""
    k = max(3, int(round(window_s * imu.rate_hz)))
    return (_moving_std(imu.gyr, k) < gyr_threshold) & (_moving_std(imu.acc, k) < acc_threshold)


def rest_segments(mask: np.ndarray, t: np.ndarray, min_s: float = 1.0) -> list[tuple[int, int]]:
    """Runs of True in ``mask`` at least ``min_s`` long, as (start, stop) index pairs."""
    m = np.r_[False, np.asarray(mask, bool), False]
    starts = np.nonzero(m[1:] & ~m[:-1])[0]
    stops = np.nonzero(~m[1:] & m[:-1])[0]
    return [(int(a), int(b)) for a, b in zip(starts, stops) if t[b - 1] - t[a] >= min_s]


def gyro_bias_at_rest(imu: ImuStream, min_s: float = 2.0, first_only: bool = True, **rest_kw) -> np.ndarray:
    """Gyro zero bias (3,) rad/s: the mean rate over the first rest segment (or all of them).

    Raises NotIdentifiable when the stream has no rest of ``min_s`` seconds.
    """
    segs = rest_segments(detect_rest(imu, **rest_kw), imu.t, min_s)
    if not segs:
        raise NotIdentifiable(f"gyro bias: no rest of {min_s:g} s in {imu.source or 'the IMU stream'} "
                              "(record the sensor still, or give the bias from a calibration)")
    if first_only:
        segs = segs[:1]
    idx = np.concatenate([np.arange(a, b) for a, b in segs])
    return imu.gyr[idx].mean(axis=0)


@dataclass
class AccelFit:
    """Accelerometer bias (3,) m/s^2, scale (3,), their std, and the residual RMS (m/s^2)."""

    bias: np.ndarray
    scale: np.ndarray
    bias_std: np.ndarray
    scale_std: np.ndarray
    rms: float


def fit_accelerometer(static_means: np.ndarray, gravity: float = G_STANDARD) -> AccelFit:
    """Bias and scale from the mean specific force of static positions, ``static_means`` (J, 3).

    Minimises sum_j (|(m_j - b) / s| - g)^2 over b, s (an axis-aligned ellipsoid through the
    points). Needs at least 6 positions that turn every axis both up and down; otherwise
    NotIdentifiable names the axis that was not turned enough.
    """
    m = np.asarray(static_means, float)
    if m.ndim != 2 or m.shape[1] != 3:
        raise BadInput(f"static accelerometer means must be (J, 3), got {m.shape}")
    if len(m) < 6:
        raise NotIdentifiable(f"accelerometer bias and scale: {len(m)} static positions, need at least 6")
    names = "xyz"
    for i in range(3):
        if m[:, i].max() < 0.5 * gravity or m[:, i].min() > -0.5 * gravity:
            raise NotIdentifiable(f"accelerometer bias and scale: axis {names[i]} was not turned both up and down "
                                  f"(readings {m[:, i].min():.3g} .. {m[:, i].max():.3g} m/s^2)")

    def res(x):
        return np.linalg.norm((m - x[:3]) / x[3:], axis=1) - gravity

    from scipy.optimize import least_squares  # not at the top: scipy.optimize costs platkit orient's start-up

    sol = least_squares(res, np.r_[np.zeros(3), np.ones(3)], method="lm")
    J = sol.jac
    dof = max(1, len(m) - 6)
    sigma2 = float(sol.fun @ sol.fun) / dof
    try:
        cov = np.linalg.inv(J.T @ J) * sigma2
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        raise NotIdentifiable("accelerometer bias and scale: the positions do not fix all six numbers") from None
    return AccelFit(sol.x[:3], sol.x[3:], std[:3], std[3:], float(np.sqrt(np.mean(sol.fun**2))))


def static_means(imu: ImuStream, min_s: float = 2.0, **rest_kw) -> np.ndarray:
    """Mean accelerometer reading (J, 3) of every rest segment of at least ``min_s``."""
    segs = rest_segments(detect_rest(imu, **rest_kw), imu.t, min_s)
    return np.array([imu.acc[a:b].mean(axis=0) for a, b in segs]).reshape(-1, 3)


def integrate_gyro(gyr: np.ndarray, dt: float, bias=None) -> np.ndarray:
    """Rotation vector (3,) of the rotation the gyro measured over ``gyr`` (K, 3), expressed in
    the sensor frame at the start: log(prod_k exp(omega_k dt))."""

    b = np.zeros(3) if bias is None else np.asarray(bias, float)
    q = quat_from_rotvec((np.asarray(gyr, float).reshape(-1, 3) - b) * dt)
    if len(q) == 0:
        return np.zeros(3)
    # the ordered product q_0 q_1 ... q_K-1, pairwise (log2 K batched steps, not K scalar ones)
    while len(q) > 1:
        if len(q) % 2:
            q = np.vstack([q, [1.0, 0.0, 0.0, 0.0]])
        q = quat_multiply(q[0::2], q[1::2])
    return rotvec_from_quat(quat_normalize(q[0]))


def rotation_increments(q_base_from_platform: np.ndarray) -> np.ndarray:
    """Rotation vectors (J-1, 3) between consecutive platform orientations (J, 4), each in the
    platform frame of the earlier one."""
    q = np.asarray(q_base_from_platform, float)
    return rotvec_from_quat(quat_multiply(quat_conjugate(q[:-1]), q[1:]))


@dataclass
class AlignmentFit:
    """R_SP (3, 3), gyro scale (3,), residual RMS (rad) and the angle std of R_SP (rad)."""

    sensor_from_platform: np.ndarray
    gyr_scale: np.ndarray
    rms: float
    angle_std: float


def fit_imu_alignment(r_platform: np.ndarray, r_sensor: np.ndarray, fit_scale: bool = False) -> AlignmentFit:
    """Least-squares R_SP with r_sensor ~ diag(s) R_SP r_platform.

    ``r_platform`` (J, 3): rotation vectors (rad) the platform made, in its own frame (from the
    calibrated model on the logged commands, or single platform axes times angles);
    ``r_sensor`` (J, 3): what the gyro integrated over the same intervals (bias removed). Without
    ``fit_scale`` this is Wahba's problem (SVD); with it, the linear fit M = diag(s) R is split
    into scales (row norms) and the nearest rotation. Needs rotations about at least two
    independent axes (NotIdentifiable otherwise).
    """
    rp = np.asarray(r_platform, float)
    rs = np.asarray(r_sensor, float)
    if rp.shape != rs.shape or rp.ndim != 2 or rp.shape[1] != 3:
        raise BadInput(f"rotation vectors must be two (J, 3) arrays of the same size, got {rp.shape} and {rs.shape}")
    sv = np.linalg.svd(rp, compute_uv=False)
    if len(rp) < 2 or sv[1] < 1e-3 * max(sv[0], 1e-12):
        raise NotIdentifiable("IMU misalignment: the platform rotated about fewer than two independent axes "
                              "(rotate it about two platform axes, e.g. roll then pitch)")
    if fit_scale:
        if sv[2] < 0.1 * sv[0]:
            # a third axis turned ten times less than the first leaves its scale to the noise
            raise NotIdentifiable("gyro scale: the platform must rotate about three independent axes to fix three scales "
                                  f"(the rotations span {sv[2] / sv[0]:.2g} of their main axis in the third)")
        M = np.linalg.lstsq(rp, rs, rcond=None)[0].T
        s = np.linalg.norm(M, axis=1)
        U, _, Vt = np.linalg.svd(M / s[:, None])
        R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    else:
        U, _, Vt = np.linalg.svd(rs.T @ rp)
        R = U @ np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))]) @ Vt
        s = np.ones(3)
    resid = rs - (rp @ R.T) * s
    rms = float(np.sqrt(np.mean(np.sum(resid**2, axis=1))))
    # small-angle std of R: residual per component over the spread of the rotations
    angle_std = float(rms / np.sqrt(3) / max(sv[1], 1e-12))
    return AlignmentFit(R, s, rms, angle_std)


def sensor_axis_directions(omega_segments: list[np.ndarray]) -> np.ndarray:
    """The paper's step 2: for each recording of a rotation about one platform axis, the least-
    squares direction (3,) of that axis in the sensor frame: the principal eigenvector of
    sum omega omega^T, signed so that the rotation is positive about it. Returns (J, 3)."""
    out = []
    for w in omega_segments:
        w = np.asarray(w, float)
        vals, vecs = np.linalg.eigh(w.T @ w)
        d = vecs[:, -1]
        if np.sum(w @ d) < 0:
            d = -d
        out.append(d)
    return np.array(out)


def calibrate_static_test(imu: ImuStream, min_s: float = 1.0, gravity: float = G_STANDARD, **rest_kw) -> ImuCalibration:
    """Biases and accelerometer scales from a static multi-position test.

    The recording holds the sensor still in at least six positions (each axis up and down) with
    moves between them. Accelerometer bias and scale: :func:`fit_accelerometer` on the mean of
    every rest of ``min_s`` seconds; gyro bias: the mean rate over all those rests. The gyro
    scales need known rotations (:func:`fit_imu_alignment` with ``fit_scale``) and stay 1 here;
    R_SP stays identity (it needs the sensor on the platform).
    """
    segs = rest_segments(detect_rest(imu, **rest_kw), imu.t, min_s)
    if not segs:
        raise NotIdentifiable(f"static test: no rest of {min_s:g} s in {imu.source or 'the IMU stream'}")
    means = np.array([imu.acc[a:b].mean(axis=0) for a, b in segs])
    fit = fit_accelerometer(means, gravity)
    idx = np.concatenate([np.arange(a, b) for a, b in segs])
    gyr = imu.gyr[idx]
    gyr_bias = gyr.mean(axis=0)
    std = {"acc_bias_m_s2": fit.bias_std, "acc_scale": fit.scale_std,
           "gyr_bias_rad_s": gyr.std(axis=0) / np.sqrt(len(gyr))}
    return ImuCalibration(gyr_bias=gyr_bias, acc_bias=fit.bias, acc_scale=fit.scale, std=std)


def write_imu_calibration(path, cal: ImuCalibration) -> None:
    """The YAML that ``platkit orient --imu-calibration`` reads, written atomically."""
    import yaml


    atomic_write_text(path, "# platkit IMU calibration (SI: rad/s, m/s^2; sensor_from_platform maps platform to "
                            "sensor axes)\n" + yaml.safe_dump(cal.to_dict(), sort_keys=False))


def main(argv=None) -> int:
    """python -m platkit.inertial.calibration STATIC_IMU.csv OUT.yaml: a static multi-position test."""
    import sys


    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python -m platkit.inertial.calibration STATIC_IMU.csv OUT.yaml", file=sys.stderr)
        return 2
    try:
        cal = calibrate_static_test(read_imu_csv(args[0]))
    except PlatkitError as exc:
        print(f"platkit: error: {exc}", file=sys.stderr)
        return exc.exit_code
    write_imu_calibration(args[1], cal)
    print(f"accelerometer bias {np.round(cal.acc_bias, 4).tolist()} m/s^2, scale {np.round(cal.acc_scale, 5).tolist()}; "
          f"gyro bias {np.round(np.degrees(cal.gyr_bias), 4).tolist()} deg/s -> {args[1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
