"""What the IMU diagnosis measures: the gyro's rotation between consecutive holds and the
accelerometer at the holds, against the calibrated model's commanded orientations.

Between the middles of two consecutive holds (:func:`platkit.inertial.command_aided.held_mask`),
segment k of duration dt_k, the gyro's mean rate y_k (rad/s, sensor axes; its integrated rotation
over dt_k) is compared with the model's mean rate p_k = log(q_a^-1 q_b) / dt_k (platform axes).
The exact rotation composition matters once the gyro bias is large (a bias of 0.01 rad/s over a
4 s segment that also turns 0.14 rad makes a cross term as large as the noise): the gyro is
integrated with a running bias (the per-hold mean rates, interpolated) removed, and that bias's
integral is added back, so y_k is the mean rate to first order in what remains.

While the platform holds command k the accelerometer reads gravity alone: f_k is its mean over
the second half of the hold (sensor axes, m/s^2; the first half still carries the settling motion).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_quat, quat_conjugate, quat_multiply, rotvec_from_quat
from platkit.inertial.calibration import integrate_gyro
from platkit.inertial.command_aided import estimate_timing, held_mask, hold_index
from platkit.io.imu import ImuStream

#: fewest holds the IMU diagnosis works with
MIN_HOLDS = 12
#: fewest held samples that make a hold
MIN_HELD_SAMPLES = 10


@dataclass
class Holds:
    """Hold h: the platform at command row ``rows[h]``; the accelerometer's mean over the second
    half of its held samples."""

    rows: np.ndarray  # (H,) command rows
    t: np.ndarray  # (H,) s, the middle of the averaged samples
    f: np.ndarray  # (H, 3) m/s^2, mean specific force, sensor axes
    n: np.ndarray  # (H,) samples averaged
    R: np.ndarray  # (H, 3, 3) the model's base_from_platform of the held command


@dataclass
class Segments:
    """Segment k: from the middle of hold a to the middle of hold b (consecutive holds)."""

    t_mid: np.ndarray  # (K,) s
    dt: np.ndarray  # (K,) s
    y: np.ndarray  # (K, 3) rad/s, measured mean rate, sensor axes
    p: np.ndarray  # (K, 3) rad/s, model's mean rate, platform axes
    t_c: float  # s, the middle of the session
    hold_bias: np.ndarray  # (H, 3) rad/s, the mean rate of each hold
    hold_t: np.ndarray  # (H,) s
    pairs: np.ndarray  # (K, 2) the command rows (a, b) of each segment
    holds: Holds | None = None  # the accelerometer at the same holds

    @property
    def span_s(self) -> tuple[float, float]:
        """(first, last) s: from the start of the first segment to the end of the last."""
        return float(self.t_mid[0] - 0.5 * self.dt[0]), float(self.t_mid[-1] + 0.5 * self.dt[-1])


def held_intervals(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, timing=None) -> list[tuple[int, np.ndarray]]:
    """[(command row, sample indices)] of the holds with at least MIN_HELD_SAMPLES held samples."""
    timing = timing or estimate_timing(imu, t_cmd, q_cmd)
    held = held_mask(imu.t, t_cmd, timing)
    k = hold_index(imu.t, t_cmd)
    holds = []
    for i in np.unique(k[held]):
        idx = np.nonzero(held & (k == i))[0]
        if len(idx) >= MIN_HELD_SAMPLES:
            holds.append((int(i), idx))
    return holds


def segments_from_session(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, timing=None) -> Segments:
    """The segments between consecutive holds of a session, with the accelerometer at the holds
    (see the module docstring). ``t_cmd`` (M,) s, ``q_cmd`` (M, 4) the model's orientations."""
    t_cmd = np.asarray(t_cmd, float)
    holds = held_intervals(imu, t_cmd, q_cmd, timing)
    if len(holds) < MIN_HOLDS:
        raise NotIdentifiable(f"IMU diagnosis: {len(holds)} holds found, at least {MIN_HOLDS} are needed")
    hold_t = np.array([imu.t[idx].mean() for _, idx in holds])
    hold_b = np.array([imu.gyr[idx].mean(axis=0) for _, idx in holds])
    # running bias: the hold means, interpolated (only to keep the integration linear in the rest)
    run = np.stack([np.interp(imu.t, hold_t, hold_b[:, j]) for j in range(3)], axis=1)
    dt = imu.dt
    cum_run = np.concatenate([np.zeros((1, 3)), np.cumsum(run[1:], axis=0) * dt])
    t_mid, dts, y, p, pairs = [], [], [], [], []
    for (a, ia), (b, ib) in zip(holds[:-1], holds[1:]):
        i0, i1 = int(ia[len(ia) // 2]), int(ib[len(ib) // 2])
        T = imu.t[i1] - imu.t[i0]
        r_s = integrate_gyro(imu.gyr[i0 + 1:i1 + 1] - run[i0 + 1:i1 + 1], dt) + (cum_run[i1] - cum_run[i0])
        r_p = rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b]))
        t_mid.append(0.5 * (imu.t[i0] + imu.t[i1]))
        dts.append(T)
        y.append(r_s / T)
        p.append(r_p / T)
        pairs.append((a, b))
    t_mid = np.array(t_mid)
    tail = [idx[len(idx) // 2:] for _, idx in holds]
    rows = np.array([i for i, _ in holds])
    acc = Holds(rows, np.array([imu.t[j].mean() for j in tail]), np.array([imu.acc[j].mean(axis=0) for j in tail]),
                np.array([len(j) for j in tail], float), matrix_from_quat(np.asarray(q_cmd, float)[rows]))
    return Segments(t_mid, np.array(dts), np.array(y), np.array(p), float(0.5 * (t_mid[0] + t_mid[-1])), hold_b, hold_t,
                    np.array(pairs), acc)


def model_rates(seg: Segments, q_cmd: np.ndarray) -> np.ndarray:
    """(K, 3) rad/s the model's mean rates of ``seg`` with other command orientations (M, 4)."""
    a, b = seg.pairs[:, 0], seg.pairs[:, 1]
    return rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b])) / seg.dt[:, None]


def blocks(n: int, block: int) -> np.ndarray:
    """(n,) bool: item k in an even block of ``block`` consecutive items (the held-out split)."""
    return (np.arange(n) // block) % 2 == 0
