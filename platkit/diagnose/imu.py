"""Diagnosis of an IMU riding on a commanded platform: gyro bias drift, misalignment, and a base
tilted against the model's vertical.

When a session has imu.csv and logged commands, the calibrated model predicts the platform's
orientation at every command (forward kinematics with the calibration's td), so it predicts the
rotation the platform made between two holds. The gyro measured the same rotation. Between the
middles of two consecutive holds (:func:`platkit.inertial.command_aided.held_mask`), segment k of
duration dt_k, the gyro's mean rate y_k (rad/s, sensor axes; its integrated rotation over dt_k)
is compared with the model's mean rate p_k = log(q_a^-1 q_b) / dt_k (platform axes):

    y_k = R_SP p_k + mean of b(t) over the segment + noise

The base model is an aligned sensor (R_SP = I) with a constant bias b0 (a constant gyro bias is
normal and is not a finding). Two effects extend it:

- ``gyro_bias_drift``: b(t) = b0 + d (t - t_c), t_c the middle of the session; d (3) rad/s per s;
- ``imu_misalignment``: R_SP = exp([theta]x), theta (3) rad, a constant rotation of the IMU axes
  against the platform frame (fitted by Gauss-Newton on the exact rotation).

A drift is tested and reported with the rotation fitted too, named or not (the gyro sees the
IMU's mounting and the model's platform frame whether or not they are a finding, and a drift
fitted without them takes what they leave).

The accelerometer gives the third. While the platform holds command k it reads gravity alone:
f_k, the mean specific force over the second half of the hold (sensor axes, m/s^2; the first
half still carries the settling motion), is compared with

    f_k = diag(g_s) R_SP R_k^T R_tilt^T (0, 0, 1) + b_a + noise

R_k the model's orientation of the held command (base from platform), R_SP the sensor's
rotation against the model's platform frame as the gyro sees it (its misalignment fit, named or
not: the gyro sees R_SP whatever the base's tilt), g_s (3) the gravity each axis reads (local
gravity times the axis's scale) and b_a (3) a constant accelerometer bias. g_s and b_a are the
base model, always fitted, never a finding. The effect:

- ``base_tilt``: R_tilt = exp([w_x, w_y, 0]x), the level frame from the model's base frame:
  gravity in the model's base frame is R_tilt^T (0, 0, -g) (the conventions of
  :mod:`platkit.inertial.simulate`).

A tilt turns gravity alike at every pose, so most of what it does is a constant the bias takes;
only the platform's own rotation tells them apart: to first order the tilt adds
g phi_k x (w x e_z), phi_k the platform's rotation at hold k (its roll and pitch act on the z
axis, its yaw on x and y). The *separability* is the smallest share of a tilt's signature on the
holds that bias and gravity scale cannot mimic; below ``MIN_TILT_SEPARABILITY`` the tilt is not
tested and is reported not separable.

Each effect is tested as in pose diagnosis: an F test of the extended fit against the current one
(Holm over the candidates of the round), and a held-out test: the segments (gyro) or the holds
(accelerometer) are cut into blocks of consecutive ones in time, the model is fitted on the even
blocks and scores the odd ones and the reverse; accepted when the per-segment (per-hold)
held-out squared errors fall (one-sided Wilcoxon at ``alpha_heldout``) by at least
``min_relative_gain`` of the RMS. A Wald test then asks whether the parameters exceed what the
calibrated model's uncertainty allows, and a floor on the size applies (``MIN_ANGLE_DEG``,
``MIN_TILT_DEG``). Effects are added one at a time (the largest held-out gain first).

The model's frames. The calibration fixes the model's base and platform frames only up to the
parameters it holds at nominal (its gauge: the motion capture cannot see them). A real stand
whose held parameters differ from the description turns the model's base frame against the real
base (an accelerometer sees that as a tilt) and its platform frame against the real platform (a
gyro sees that as a misalignment). :func:`frame_gauge` computes how far, from the forward
kinematics, for held parameters off by a typical error (``HELD_PARAMETER_STD``); with the
calibration's statistical uncertainty (refits with td drawn from its covariance) it enters the
Wald tests and the findings' stds.

The exact rotation composition matters once the gyro bias is large (a bias of 0.01 rad/s over a
4 s segment that also turns 0.14 rad makes a cross term as large as the noise): the gyro is
integrated with a running bias (the per-hold mean rates, interpolated) removed, and that bias's
integral is added back, so y_k is the mean rate to first order in what remains.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import linalg as sla
from scipy import stats

from platkit.calibrate.plan import stand_length_scale
from platkit.diagnose.stats import column_basis, holm, paired_improvement
from platkit.errors import NotIdentifiable
from platkit.geometry import (
    matrix_from_quat,
    matrix_from_rotvec,
    quat_conjugate,
    quat_multiply,
    rotvec_from_matrix,
    rotvec_from_quat,
    skew,
)
from platkit.inertial.calibration import integrate_gyro
from platkit.inertial.command_aided import command_poses, estimate_timing, held_mask, hold_index
from platkit.io.imu import ImuStream
from platkit.kinematics import PlatformModel

GYRO_EFFECTS = ("gyro_bias_drift", "imu_misalignment")
IMU_EFFECTS = GYRO_EFFECTS + ("base_tilt",)
DEG = 180.0 / np.pi
G_STANDARD = 9.80665

#: a misalignment smaller than this (deg) is not named. The gyro is compared with the calibrated
#: model's platform frame, and that frame is tied to the parameters the calibration holds at
#: their nominal values (its gauge): a stand built a few tenths of a mm off them turns the model's
#: frame against the real one by a few hundredths of a degree, which the mocap cannot see and a
#: gyro can (0.06-0.08 deg in the simulated stewart sessions of tests/unit/test_diagnose_imu.py).
#: How far held parameters a few mm off can turn it is in the Wald test (:func:`frame_gauge`):
#: more than this floor on psvr (0.23 deg, 1 sigma, about y: a platform joint's height is held;
#: clean psvr sessions show 0.3-0.6 deg) and rotary (0.16 deg).
MIN_ANGLE_DEG = 0.25

#: a base tilt smaller than this (deg) is not named. Beyond the allowance of :func:`frame_gauge`
#: (which assumes how far the held parameters are off) and the noise, a floor: on the clean
#: sessions of benchmarks/diagnosis_proof_imu.py the tilt estimates reached 0.087 deg on stewart
#: (a session where the F and held-out tests passed and the Wald test alone, p = 0.03, kept it
#: out) and 0.038 deg on psvr; rotary's reached 0.24 deg, inside its allowance (0.115 deg, 1
#: sigma, its first joint's axis held). An accelerometer's axes are rarely square to its gyro's to
#: better than a few hundredths of a degree either, and that looks like a tilt where the platform
#: does not yaw.
MIN_TILT_DEG = 0.1

#: a base tilt is tested only where at least this share of its signature on the holds is beyond
#: what an accelerometer bias and gravity scale can mimic. Random plans give 0.10-0.13 on stewart
#: (+-8 deg of roll, pitch and yaw), 0.08-0.10 on psvr (no yaw), 0.5-0.9 on rotary; stewart legs
#: within 30 mm of neutral (about a degree of rotation) 0.003-0.017. Below 0.02 a tilt's estimate
#: is more than 50 times as sensitive to anything unmodelled in the specific force as where the
#: platform turns fully (an unmodelled 1 mm/s^2 would move it by 0.3 deg).
MIN_TILT_SEPARABILITY = 0.02

#: how far a real stand's held parameters are taken to differ from its description (1 sigma),
#: by unit; other units: this share of the nominal value. A real stand differs from its
#: description by a few mm (docs/stands.md); platkit.simulate draws its true stands the same way.
HELD_PARAMETER_STD = {"m": 2e-3, "rad": 2e-3}
HELD_PARAMETER_RELATIVE_STD = 1e-3


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


@dataclass
class ImuFit:
    effects: tuple[str, ...]
    b0: np.ndarray
    drift: np.ndarray
    theta: np.ndarray
    cov: np.ndarray  # covariance of the parameters (b0, [drift], [theta]) from the gyro noise
    resid: np.ndarray  # (K, 3) rad/s on all segments
    rss: float
    n_params: int
    cv: np.ndarray | None = None  # (K,) held-out squared error per segment, (rad/s)^2
    model_cov: np.ndarray | None = None  # parameter covariance from the calibrated model's uncertainty (td)

    @property
    def cv_rms(self) -> float:
        return float(np.sqrt(np.mean(self.cv) / 3.0))


@dataclass
class AccFit:
    """The accelerometer at the holds: ``scale`` (3) m/s^2 the gravity each axis reads, ``bias``
    (3) m/s^2, ``w`` (2) rad the base tilt (zero without it), ``cov`` the covariance of (scale,
    bias, [w]) from the noise, ``resid`` (H, 3) m/s^2 on all holds."""

    tilt: bool
    scale: np.ndarray
    bias: np.ndarray
    w: np.ndarray
    cov: np.ndarray
    resid: np.ndarray
    rss: float
    n_params: int
    separability: float = float("nan")
    theta: np.ndarray = field(default_factory=lambda: np.zeros(3))  # R_SP used (rotation vector, rad)
    cv: np.ndarray | None = None  # (H,) held-out squared error per hold, (m/s^2)^2
    tilt_cov: dict[str, np.ndarray] = field(default_factory=dict)  # (2, 2) rad^2 by source

    @property
    def cv_rms(self) -> float:
        return float(np.sqrt(np.mean(self.cv) / 3.0))

    @property
    def w_cov(self) -> np.ndarray:
        """(2, 2) rad^2: the tilt's covariance from every source (noise, model, sensor rotation, frame)."""
        return sum(self.tilt_cov.values(), np.zeros((2, 2)))


@dataclass
class ImuDiagnosis:
    findings: list[dict[str, Any]]
    base: ImuFit
    final: ImuFit
    segments: Segments
    tests: list[dict[str, Any]]
    verdict: str
    warnings: list[str] = field(default_factory=list)
    acc_base: AccFit | None = None
    acc_final: AccFit | None = None
    not_separable: list[dict[str, Any]] = field(default_factory=list)
    frame: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out = {"unit": "deg/s", "n_segments": int(len(self.segments.dt)),
               "session_s": float(self.segments.t_mid[-1] - self.segments.t_mid[0] + 0.5 * (self.segments.dt[0] + self.segments.dt[-1])),
               "constant_gyro_bias_deg_s": (self.final.b0 * DEG).tolist(),
               "heldout_rms_base": self.base.cv_rms * DEG, "heldout_rms_final": self.final.cv_rms * DEG,
               "tests": self.tests, "findings": self.findings, "verdict": self.verdict,
               "warnings": list(self.warnings),
               "method": ("mean gyro rate between the middles of consecutive holds against the calibrated model's "
                          "rotation between the commanded poses; mean specific force of each hold against gravity "
                          "turned by the model's orientation; F test (Holm over the candidates) and held-out test on "
                          "alternate blocks of consecutive segments or holds (one-sided Wilcoxon); Wald test against "
                          "the noise, the calibration's uncertainty and its gauge")}
        if self.acc_final is not None:
            a, b = self.acc_base, self.acc_final
            out["accelerometer"] = {
                "unit": "m/s^2", "n_holds": int(len(self.segments.holds.rows)),
                "constant_bias_m_s2": b.bias.tolist(), "gravity_m_s2": b.scale.tolist(),
                "heldout_rms_base": a.cv_rms, "heldout_rms_final": b.cv_rms,
                "tilt_separability": next((float(r["separability"]) for t in self.tests for r in t["candidates"]
                                           if r["effect"] == "base_tilt"), None),
                "sensor_from_platform_deg": (b.theta * DEG).tolist(),
                "note": ("gravity_m_s2: the gravity each axis reads (local gravity times its scale; on an axis that "
                         "stays near vertical it trades with that axis's bias, and only their sum is measured); "
                         "sensor_from_platform_deg: the rotation of the IMU axes against the model's platform "
                         "frame the gyro sees (rotation vector), used for the accelerometer")}
        out["not_separable"] = list(self.not_separable)
        if self.frame:
            out["model_frame"] = dict(self.frame)
        return out

    def calibration_entry(self) -> dict[str, Any]:
        """What the accepted findings add to the calibrated model, SI, for calibration.yaml's
        ``imu`` mapping (empty without findings)."""
        by = {fd["effect"]: fd["parameters"] for fd in self.findings}
        out: dict[str, Any] = {}
        f = self.final

        def std(effect, names, per):
            return [by[effect][n]["std"] / per for n in names]

        if "imu_misalignment" in by:
            out["sensor_from_platform"] = {
                "rotation_vector": f.theta.tolist(),
                "std_rotation_vector": std("imu_misalignment", ["angle_x", "angle_y", "angle_z"], DEG),
                "rotation_matrix": matrix_from_rotvec(f.theta).tolist(),
                "note": "IMU axes from the model's platform frame: v_sensor = R v_platform (rad)"}
        if "gyro_bias_drift" in by:
            out["gyro_bias"] = {"reference_time_s": float(self.segments.t_c), "bias": f.b0.tolist(),
                                "drift": f.drift.tolist(),
                                "std_drift": std("gyro_bias_drift", ["drift_x", "drift_y", "drift_z"], DEG * 60.0),
                                "note": "b(t) = bias + drift (t - reference_time_s), rad/s and rad/s per s, sensor axes"}
        if "base_tilt" in by and self.acc_final is not None:
            a = self.acc_final
            out["base_tilt"] = {"rotation_vector": [float(a.w[0]), float(a.w[1]), 0.0],
                                "std_rotation_vector": std("base_tilt", ["tilt_x", "tilt_y"], DEG) + [0.0],
                                "note": ("the level frame from the model's base frame, rad: gravity in the base frame "
                                         "is R^T (0, 0, -g)")}
        if out:
            out["source"] = "platkit diagnose: the IMU findings accepted on this session (platkit.diagnose.imu)"
        return out


# ---------------------------------------------------------------------------- data
def _held_intervals(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, timing=None) -> list[tuple[int, np.ndarray]]:
    """[(command row, sample indices)] of the holds with at least 10 held samples."""

    timing = timing or estimate_timing(imu, t_cmd, q_cmd)
    held = held_mask(imu.t, t_cmd, timing)
    k = hold_index(imu.t, t_cmd)
    holds = []
    for i in np.unique(k[held]):
        idx = np.nonzero(held & (k == i))[0]
        if len(idx) >= 10:
            holds.append((int(i), idx))
    return holds


def segments_from_session(imu: ImuStream, t_cmd: np.ndarray, q_cmd: np.ndarray, timing=None) -> Segments:
    """The segments between consecutive holds of a session, with the accelerometer at the holds
    (see the module docstring)."""
    t_cmd = np.asarray(t_cmd, float)
    holds = _held_intervals(imu, t_cmd, q_cmd, timing)
    if len(holds) < 12:
        raise NotIdentifiable(f"IMU diagnosis: {len(holds)} holds found, at least 12 are needed")
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
    # the accelerometer: the second half of each hold (the first still carries the settling motion)
    tail = [idx[len(idx) // 2:] for _, idx in holds]
    rows = np.array([i for i, _ in holds])
    acc = Holds(rows, np.array([imu.t[j].mean() for j in tail]), np.array([imu.acc[j].mean(axis=0) for j in tail]),
                np.array([len(j) for j in tail], float), matrix_from_quat(np.asarray(q_cmd, float)[rows]))
    return Segments(t_mid, np.array(dts), np.array(y), np.array(p), float(0.5 * (t_mid[0] + t_mid[-1])), hold_b, hold_t,
                    np.array(pairs), acc)


def _model_rates(seg: Segments, q_cmd: np.ndarray) -> np.ndarray:
    """(K, 3) rad/s the model's mean rates of ``seg`` with other command orientations."""
    a, b = seg.pairs[:, 0], seg.pairs[:, 1]
    return rotvec_from_quat(quat_multiply(quat_conjugate(q_cmd[a]), q_cmd[b])) / seg.dt[:, None]


# ---------------------------------------------------------------------------- gyro fitting
def _fit(seg: Segments, effects: tuple[str, ...], rows: np.ndarray | None = None, iterations: int = 4) -> ImuFit:
    """Weighted least squares (weight dt_k: the noise of a mean rate falls as 1/sqrt(dt)) of the
    model with ``effects`` on the segments ``rows`` (default all); residuals on all segments."""
    rows = np.ones(len(seg.dt), bool) if rows is None else rows
    drift, misal = "gyro_bias_drift" in effects, "imu_misalignment" in effects
    K = len(seg.dt)
    theta = np.zeros(3)
    w = np.sqrt(seg.dt / seg.dt.mean())
    tau = seg.t_mid - seg.t_c
    for _ in range(iterations if misal else 1):
        R = matrix_from_rotvec(theta)
        Rp = seg.p @ R.T
        cols = [np.broadcast_to(np.eye(3), (K, 3, 3))]
        if drift:
            cols.append(tau[:, None, None] * np.eye(3)[None])
        if misal:
            cols.append(-np.einsum("kij,jl->kil", skew(Rp), np.eye(3)))  # d(R p)/d(dtheta) = -[R p]x
        A = np.concatenate(cols, axis=2)  # (K, 3, n)
        rhs = seg.y - Rp
        if misal:
            rhs = rhs + np.einsum("kij,j->ki", A[:, :, -3:], theta)
        Aw = (A * w[:, None, None])[rows].reshape(-1, A.shape[2])
        bw = (rhs * w[:, None])[rows].reshape(-1)
        x = np.linalg.lstsq(Aw, bw, rcond=None)[0]
        if misal:
            theta = x[-3:].copy()
    R = matrix_from_rotvec(theta)
    model = seg.p @ R.T + x[:3] + (tau[:, None] * x[3:6] if drift else 0.0)
    resid = seg.y - model
    n = len(x)
    rss = float(np.sum((resid * w[:, None])[rows] ** 2))
    dof = max(3 * int(rows.sum()) - n, 1)
    cov = np.linalg.pinv(Aw.T @ Aw) * rss / dof
    return ImuFit(tuple(effects), x[:3], x[3:6] if drift else np.zeros(3), theta, cov, resid, rss, n)


def _blocks(K: int, block: int) -> np.ndarray:
    """(K,) bool: item k in an even block of ``block`` consecutive items."""
    return (np.arange(K) // block) % 2 == 0


def _cv(seg: Segments, effects: tuple[str, ...], block: int) -> np.ndarray:
    even = _blocks(len(seg.dt), block)
    out = np.empty(len(seg.dt))
    for train in (even, ~even):
        f = _fit(seg, effects, train)
        out[~train] = np.sum(f.resid[~train] ** 2, axis=1)
    return out


def _index(effects: tuple[str, ...], effect: str) -> slice:
    """Where ``effect``'s three parameters sit in the fit's vector (b0, [drift], [theta])."""
    if effect == "gyro_bias_drift":
        return slice(3, 6)
    return slice(3 + 3 * ("gyro_bias_drift" in effects), 6 + 3 * ("gyro_bias_drift" in effects))


def _vec(f: ImuFit) -> np.ndarray:
    return np.concatenate([f.b0] + ([f.drift] if "gyro_bias_drift" in f.effects else [])
                          + ([f.theta] if "imu_misalignment" in f.effects else []))


def _model_cov(seg: Segments, effects: tuple[str, ...], p_draws: list[np.ndarray] | None) -> np.ndarray:
    """Covariance of the fit's parameters due to the calibrated model's own uncertainty: the
    spread of the refits with the model's rotations from td drawn from its covariance."""
    n = 3 + 3 * len(effects)
    if not p_draws or len(p_draws) < 2:
        return np.zeros((n, n))
    xs = np.array([_vec(_fit(replace(seg, p=p), effects)) for p in p_draws])
    return np.atleast_2d(np.cov(xs.T))


def _with_rotation(seg: Segments, cur: ImuFit, block: int, p_draws=None) -> ImuFit:
    """``cur`` with the sensor's rotation fitted too (a nuisance where it is not named): the gyro
    sees the IMU's mounting and the model's platform frame whether or not either is a finding,
    and a drift fitted without them takes what they leave."""
    if "imu_misalignment" in cur.effects:
        return cur
    f = _fit(seg, cur.effects + ("imu_misalignment",))
    f.cv = _cv(seg, f.effects, block)
    if p_draws is not None:
        f.model_cov = _model_cov(seg, f.effects, p_draws)
    return f


def _theta_cov(f: ImuFit, i: slice, frame_platform: np.ndarray | None = None) -> np.ndarray:
    """(3, 3) rad^2: a misalignment's covariance from the noise, the model's uncertainty and
    (``frame_platform``, platform axes) the model's platform frame against the real one: the gyro
    sees R_SP P^T with P that frame error, a left rotation of -R_SP p."""
    C = f.cov[i, i] + (f.model_cov[i, i] if f.model_cov is not None else 0.0)
    if frame_platform is not None:
        R = matrix_from_rotvec(f.theta)
        C = C + R @ frame_platform @ R.T
    return C


def _f_test(small, big, n_obs: int) -> tuple[float, float]:
    k = big.n_params - small.n_params
    dof = n_obs - big.n_params
    F = ((small.rss - big.rss) / k) / max(big.rss / dof, 1e-300)
    return float(F), float(stats.f.sf(F, k, dof))


def _sensor_rotation(seg: Segments, effects: tuple[str, ...], p: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The gyro's R_SP (rotation vector, rad) and its noise covariance (3, 3): the misalignment
    fitted with the gyro ``effects`` accepted so far, named or not."""
    eff = tuple(e for e in GYRO_EFFECTS if e in effects or e == "imu_misalignment")
    f = _fit(seg if p is None else replace(seg, p=p), eff)
    i = _index(eff, "imu_misalignment")
    return f.theta, f.cov[i, i]


# ---------------------------------------------------------------------------- accelerometer fitting
def _tilt_rotation(w: np.ndarray) -> np.ndarray:
    """R_tilt (3, 3): the level frame from the base frame for a tilt (2,) rad about base x, y."""
    return matrix_from_rotvec(np.array([w[0], w[1], 0.0]))


def up_in_sensor(R: np.ndarray, R_sp: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(H, 3): the up direction in sensor axes, R_SP R_k^T R_tilt^T e_z, for the model's
    orientations R (H, 3, 3) base from platform, the sensor's rotation R_SP (3, 3) and a base
    tilt w (2,) rad: a still platform's accelerometer reads g times this, plus its bias."""
    v = _tilt_rotation(w)[2]  # R_tilt^T e_z
    return np.einsum("kji,j->ki", R, v) @ R_sp.T


def _acc_fit(holds: Holds, R_sp: np.ndarray, tilt: bool, rows: np.ndarray | None = None, R: np.ndarray | None = None,
             iterations: int = 4) -> AccFit:
    """Weighted least squares (weight: the samples averaged) of the accelerometer model on the
    holds ``rows`` (default all), with or without the tilt; residuals on all holds. ``R``: other
    model orientations of the holds (H, 3, 3) (default the holds' own)."""
    H = len(holds.rows)
    rows = np.ones(H, bool) if rows is None else rows
    R = holds.R if R is None else R
    wt = np.sqrt(holds.n / holds.n.mean())
    w = np.zeros(2)
    s = np.full(3, G_STANDARD)
    h = 1e-6
    for _ in range(iterations if tilt else 1):
        u = up_in_sensor(R, R_sp, w)
        cols = [u[:, :, None] * np.eye(3)[None], np.broadcast_to(np.eye(3), (H, 3, 3))]
        rhs = holds.f.copy()
        if tilt:
            D = np.stack([(up_in_sensor(R, R_sp, w + h * e) - up_in_sensor(R, R_sp, w - h * e)) / (2 * h) for e in np.eye(2)], axis=2)
            Aw_t = s[None, :, None] * D  # d f / d w at the current scales
            cols.append(Aw_t)
            rhs = rhs + np.einsum("kij,j->ki", Aw_t, w)
        A = np.concatenate(cols, axis=2)
        Aw = (A * wt[:, None, None])[rows].reshape(-1, A.shape[2])
        bw = (rhs * wt[:, None])[rows].reshape(-1)
        x, _, rank, _ = np.linalg.lstsq(Aw, bw, rcond=1e-10)
        s = x[:3]
        if tilt:
            w = x[6:8].copy()
    u = up_in_sensor(R, R_sp, w)
    resid = holds.f - (u * x[:3] + x[3:6])
    rss = float(np.sum((resid * wt[:, None])[rows] ** 2))
    dof = max(3 * int(rows.sum()) - int(rank), 1)
    cov = np.linalg.pinv(Aw.T @ Aw) * rss / dof
    sep = float("nan")
    if tilt:
        # the smallest share of a tilt's signature (any direction) beyond what bias and scale can mimic
        J_t = Aw[:, 6:8]
        U = column_basis(Aw[:, :6])
        Jp = J_t - U @ (U.T @ J_t)
        ev = sla.eigh(Jp.T @ Jp, J_t.T @ J_t, eigvals_only=True)
        sep = float(np.sqrt(max(float(ev[0]), 0.0)))
    return AccFit(tilt, x[:3], x[3:6], w, cov, resid, rss, int(rank), sep, rotvec_from_matrix(R_sp))


def _acc_cv(holds: Holds, R_sp: np.ndarray, tilt: bool, block: int) -> np.ndarray:
    even = _blocks(len(holds.rows), block)
    out = np.empty(len(holds.rows))
    for train in (even, ~even):
        f = _acc_fit(holds, R_sp, tilt, train)
        out[~train] = np.sum(f.resid[~train] ** 2, axis=1)
    return out


def _acc_state(seg: Segments, gyro_effects: tuple[str, ...], tilt: bool, block: int, q_draws=None,
               frame_base: np.ndarray | None = None) -> AccFit:
    """The accelerometer fit with R_SP from the gyro (see :func:`_sensor_rotation`), its held-out
    errors, and with ``tilt`` the tilt's covariance by source: ``noise``, ``model`` (refits with
    td drawn from the calibration's covariance: other model orientations and R_SP), ``sensor``
    (the gyro noise in R_SP) and ``frame`` (the model's base frame against the real one)."""
    theta, C_theta = _sensor_rotation(seg, gyro_effects)
    R_sp = matrix_from_rotvec(theta)
    a = _acc_fit(seg.holds, R_sp, tilt)
    a.cv = _acc_cv(seg.holds, R_sp, tilt, block)
    if not tilt:
        return a
    a.tilt_cov["noise"] = a.cov[6:8, 6:8]
    if q_draws:
        ws = []
        for q in q_draws:
            th, _ = _sensor_rotation(seg, gyro_effects, _model_rates(seg, q))
            ws.append(_acc_fit(seg.holds, matrix_from_rotvec(th), True, R=matrix_from_quat(q[seg.holds.rows])).w)
        if len(ws) >= 2:
            a.tilt_cov["model"] = np.atleast_2d(np.cov(np.array(ws).T))
    h = 1e-4
    J = np.stack([(_acc_fit(seg.holds, matrix_from_rotvec(theta + h * e), True).w
                   - _acc_fit(seg.holds, matrix_from_rotvec(theta - h * e), True).w) / (2 * h) for e in np.eye(3)], axis=1)
    a.tilt_cov["sensor"] = J @ C_theta @ J.T
    if frame_base is not None:
        a.tilt_cov["frame"] = np.asarray(frame_base, float)[:2, :2]
    return a


# ---------------------------------------------------------------------------- the model's frames
def held_parameter_std(spec) -> np.ndarray:
    """(n_td,) how far each parameter of a real stand is taken to be from its description."""
    out = np.empty(spec.n_td)
    for i, p in enumerate(spec.parameters):
        sd = HELD_PARAMETER_STD.get(p.unit)
        out[i] = sd if sd is not None else HELD_PARAMETER_RELATIVE_STD * (abs(p.nominal) if p.nominal != 0 else 1.0)
    return out


def frame_gauge(spec, td, U: np.ndarray, td_status, model=None) -> tuple[np.ndarray, np.ndarray, int]:
    """How far the parameters a calibration held at nominal can turn the model's frames.

    A held parameter's error is invisible to the motion capture: the estimated parameters, the
    mocap transform (a rigid motion of the base) and the marker positions (a rigid motion of the
    platform) take it. From forward kinematics at the command rows ``U`` (N, n_u, SI) the held
    parameter's effect on the poses is split (least squares) into the estimated parameters'
    effects and the two rigid motions; the rotation parts b_j (base frame axes) and p_j (platform
    axes) are how far the model's base and platform frames turn per unit of parameter j. With
    the errors of :func:`held_parameter_std`, independent: C_base = sum s_j^2 b_j b_j^T and
    C_platform alike. Returns (C_base (3, 3), C_platform (3, 3)) rad^2 and the number of held
    parameters (0: both zero)."""

    status = list(td_status)
    held = [i for i, s in enumerate(status) if s == "held_at_nominal"]
    if not held:
        return np.zeros((3, 3)), np.zeros((3, 3)), 0
    free = [i for i, s in enumerate(status) if s == "estimated"]
    model = model or PlatformModel(spec)
    td = np.asarray(td, float)
    U = np.atleast_2d(np.asarray(U, float))
    fb = model.forward_batch(U, td=td, strict=False)
    ok = fb.converged
    R0, X0 = matrix_from_quat(fb.q[ok]), fb.X[ok]
    K = len(X0)
    L = stand_length_scale(spec)

    def effect(i: int) -> np.ndarray:
        """(K, 6): rotation (base axes, times L) and translation of the poses per unit of td_i."""
        hstep = 1e-5 * max(1.0, abs(td[i])) if spec.parameters[i].unit not in ("m", "rad") else 1e-5
        d = np.zeros_like(td)
        d[i] = hstep
        a = model.forward_batch(U[ok], td=td + d, strict=False)
        b = model.forward_batch(U[ok], td=td - d, strict=False)
        rot = rotvec_from_matrix(matrix_from_quat(a.q) @ np.transpose(matrix_from_quat(b.q), (0, 2, 1))) / (2 * hstep)
        return np.concatenate([L * rot, (a.X - b.X) / (2 * hstep)], axis=1)

    eye = np.broadcast_to(np.eye(3), (K, 3, 3))
    zero = np.zeros((K, 3, 3))
    rigid = np.concatenate([
        np.concatenate([L * eye, -skew(X0)], axis=1),  # base rotation b: X -> X + b x X
        np.concatenate([zero, eye], axis=1),  # base translation
        np.concatenate([L * R0, zero], axis=1),  # platform rotation p (platform axes)
        np.concatenate([zero, R0], axis=1),  # platform translation
    ], axis=2)  # (K, 6, 12)
    A = np.concatenate([np.stack([effect(i) for i in free], axis=2) if free else np.zeros((K, 6, 0)), rigid], axis=2)
    A = A.reshape(-1, A.shape[2])
    nf = len(free)
    sd = held_parameter_std(spec)
    C_b, C_p = np.zeros((3, 3)), np.zeros((3, 3))
    for j in held:
        x = np.linalg.lstsq(A, effect(j).reshape(-1), rcond=1e-12)[0]
        b, p = x[nf:nf + 3] * sd[j], x[nf + 6:nf + 9] * sd[j]
        C_b += np.outer(b, b)
        C_p += np.outer(p, p)
    return C_b, C_p, len(held)


# ---------------------------------------------------------------------------- findings
def _finding(effect: str, fit: ImuFit, before: ImuFit, p_held: float, p_f: float, seg: Segments,
             frame_platform: np.ndarray | None = None) -> dict[str, Any]:
    cov = fit.cov + (fit.model_cov if fit.model_cov is not None else 0.0)
    std = np.sqrt(np.clip(np.diag(cov), 0, None))
    span = (float(seg.t_mid[0] - 0.5 * seg.dt[0]), float(seg.t_mid[-1] + 0.5 * seg.dt[-1]))
    a, b = before.cv_rms * DEG, fit.cv_rms * DEG
    if effect == "gyro_bias_drift":
        d, sd = fit.drift * DEG * 60.0, std[3:6] * DEG * 60.0
        params = {f"drift_{c}": {"value": float(v), "std": float(s), "unit": "deg/s per min"}
                  for c, v, s in zip("xyz", d, sd)}
        params.update({f"bias_{c}": {"value": float(v), "std": float(s), "unit": "deg/s"}
                       for c, v, s in zip("xyz", fit.b0 * DEG, std[:3] * DEG)})
        where = {"sensor": "gyro", "time_s": [round(span[0], 3), round(span[1], 3)], "reference_time_s": round(seg.t_c, 3),
                 "frame": "sensor axes"}
        change = float(np.linalg.norm(fit.drift) * (span[1] - span[0]) * DEG)
        evidence = (f"The gyro bias changes by {change:.3g} deg/s over the {span[1] - span[0]:.0f} s session "
                    f"({np.linalg.norm(d):.3g} deg/s per min; bias at {seg.t_c:.0f} s: "
                    f"{', '.join(f'{v:.3g}' for v in fit.b0 * DEG)} deg/s): a bias drifting linearly predicts the held-out "
                    f"segments' mean rate with RMS {a:.3g} -> {b:.3g} deg/s over {len(seg.dt)} segments "
                    f"(paired Wilcoxon p = {p_held:.2g}; F test Holm p = {p_f:.2g}).")
    else:
        ang = fit.theta * DEG
        i = _index(fit.effects, "imu_misalignment")
        C = _theta_cov(fit, i, frame_platform)
        sd = np.sqrt(np.clip(np.diag(C), 0, None)) * DEG
        params = {f"angle_{c}": {"value": float(v), "std": float(s), "unit": "deg"} for c, v, s in zip("xyz", ang, sd)}
        total = float(np.linalg.norm(ang))
        J = ang / total if total > 0 else np.zeros(3)
        tsd = float(np.sqrt(J @ C @ J)) * DEG
        params["angle"] = {"value": total, "std": tsd, "unit": "deg"}
        where = {"sensor": "gyro", "frame": "sensor from platform, rotation vector",
                 "axis": [round(float(v), 4) for v in J]}
        evidence = (f"The gyro's rotations between holds are the model's turned by {total:.3g} deg "
                    f"(rotation vector {', '.join(f'{v:.3g}' for v in ang)} deg, IMU axes against the platform's): "
                    f"modelling the rotation predicts the held-out segments' mean rate with RMS {a:.3g} -> {b:.3g} deg/s "
                    f"over {len(seg.dt)} segments (paired Wilcoxon p = {p_held:.2g}; F test Holm p = {p_f:.2g}).")
    return {"effect": effect, "where": where, "parameters": params, "heldout_rms_before": a, "heldout_rms_after": b,
            "unit": "deg/s", "evidence": evidence, "p_heldout": p_held, "p_screen": p_f, "warnings": []}


def _tilt_finding(fit: AccFit, before: AccFit, p_held: float, p_f: float, n_holds: int) -> dict[str, Any]:
    w = fit.w * DEG
    C = fit.w_cov * DEG**2
    sd = np.sqrt(np.clip(np.diag(C), 0, None))
    total = float(np.linalg.norm(w))
    J = w / total if total > 0 else np.zeros(2)
    tsd = float(np.sqrt(J @ C @ J))
    params = {"tilt_x": {"value": float(w[0]), "std": float(sd[0]), "unit": "deg"},
              "tilt_y": {"value": float(w[1]), "std": float(sd[1]), "unit": "deg"},
              "tilt": {"value": total, "std": tsd, "unit": "deg"}}
    a, b = before.cv_rms, fit.cv_rms
    where = {"frame": "base", "from": "accelerometer", "axis": [round(float(J[0]), 4), round(float(J[1]), 4), 0.0],
             "convention": "level frame from the model's base frame = exp([tilt_x, tilt_y, 0]x)"}
    evidence = (f"At {n_holds} holds the accelerometer reads gravity turned by {total:.3g} deg in the model's base frame "
                f"(about x {w[0]:.3g} deg, about y {w[1]:.3g} deg; +- {tsd:.2g} deg with the calibration's uncertainty "
                f"and its frame): a tilted base predicts the held-out holds' specific force with RMS {a:.3g} -> {b:.3g} "
                f"m/s^2 (paired Wilcoxon p = {p_held:.2g}; F test Holm p = {p_f:.2g}; separability from the "
                f"accelerometer's bias {fit.separability:.2g}).")
    return {"effect": "base_tilt", "where": where, "parameters": params, "heldout_rms_before": a, "heldout_rms_after": b,
            "unit": "m/s^2", "evidence": evidence, "p_heldout": p_held, "p_screen": p_f,
            "separability": fit.separability, "warnings": []}


def diagnose_segments(seg: Segments, alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4,
                      min_relative_gain: float = 0.02, q_draws: list[np.ndarray] | None = None,
                      frame_base: np.ndarray | None = None, frame_platform: np.ndarray | None = None,
                      min_angle_deg: float = MIN_ANGLE_DEG, min_tilt_deg: float = MIN_TILT_DEG,
                      min_separability: float = MIN_TILT_SEPARABILITY) -> ImuDiagnosis:
    """Forward selection of the IMU effects on the segments (and holds) of one session.
    ``q_draws``: the model's command orientations (M, 4) recomputed with td drawn from the
    calibration's covariance; ``frame_base``, ``frame_platform`` (3, 3) rad^2: how far the
    model's frames can be turned against the real ones (:func:`frame_gauge`). An effect must
    exceed what they allow (Wald test with every covariance at ``alpha``). A misalignment below
    ``min_angle_deg`` and a tilt below ``min_tilt_deg`` are not named; a tilt is not tested
    where its separability is below ``min_separability``."""
    p_draws = [_model_rates(seg, q) for q in q_draws] if q_draws else None
    cur = _fit(seg, ())
    cur.model_cov = _model_cov(seg, (), p_draws)
    cur.cv = _cv(seg, (), block)
    base = cur
    has_acc = seg.holds is not None
    acc = _acc_state(seg, (), False, block) if has_acc else None
    acc_base = acc
    findings, tests, not_separable = [], [], []
    tilt_with: tuple[str, ...] = ()
    while True:
        left = [e for e in IMU_EFFECTS if e not in cur.effects and (e != "base_tilt" or (has_acc and not acc.tilt))]
        if not left:
            break
        if has_acc and not acc.tilt:
            acc = _acc_state(seg, cur.effects, False, block)  # R_SP from the gyro model of this round
        cands = []
        for e in left:
            if e == "base_tilt":
                f = _acc_state(seg, cur.effects, True, block, q_draws, frame_base)
                F, p = _f_test(acc, f, 3 * len(seg.holds.rows))
                before = acc
            else:
                before = cur if e == "imu_misalignment" else _with_rotation(seg, cur, block)
                f = _fit(seg, before.effects + (e,))
                f.cv = _cv(seg, f.effects, block)
                F, p = _f_test(before, f, 3 * len(seg.dt))
            cands.append((e, f, F, p, before))
        tilt_sep = next((c[1].separability for c in cands if c[0] == "base_tilt"), None)
        separable = tilt_sep is None or tilt_sep >= min_separability
        tested = [c for c in cands if c[0] != "base_tilt" or separable]
        p_adj = dict(zip([c[0] for c in tested], holm(np.array([c[3] for c in tested]))))
        rows = []
        for e, f, F, p, before in cands:
            if e == "base_tilt":
                v = f.w
                C = f.w_cov
                dof = 2
                size, unit = float(np.linalg.norm(v)) * DEG, "deg"
                big = size >= min_tilt_deg
                extra = {"heldout_unit": "m/s^2", "separability": f.separability,
                         "std_by_source_deg": {k: np.sqrt(np.clip(np.diag(c), 0, None)).tolist() for k, c in
                                               ((k, c * DEG**2) for k, c in f.tilt_cov.items())}}
            else:
                # larger than the calibrated model's own uncertainty can make it? (Wald, all covariances)
                f.model_cov = _model_cov(seg, f.effects, p_draws)
                i = _index(f.effects, e)
                C = _theta_cov(f, i, frame_platform) if e == "imu_misalignment" else f.cov[i, i] + f.model_cov[i, i]
                v = _vec(f)[i]
                dof = 3
                size = float(np.linalg.norm(v)) * (DEG if e == "imu_misalignment" else DEG * 60.0)
                unit = "deg" if e == "imu_misalignment" else "deg/s per min"
                big = e != "imu_misalignment" or size >= min_angle_deg
                extra = {"heldout_unit": "deg/s"}
            scale = 1.0 if e == "base_tilt" else DEG
            ph = paired_improvement(before.cv, f.cv)
            gain = 1.0 - f.cv_rms / before.cv_rms
            wald = float(v @ np.linalg.pinv(C) @ v)
            pw = float(stats.chi2.sf(wald, dof))
            # the smallest size the Wald test lets through in the worst direction, and the floor
            shown = DEG if e != "gyro_bias_drift" else DEG * 60.0
            detectable = float(np.sqrt(stats.chi2.ppf(1 - alpha, dof) * max(np.linalg.eigvalsh(C)[-1], 0.0))) * shown
            detectable = max(detectable, min_tilt_deg if e == "base_tilt" else min_angle_deg if e == "imu_misalignment" else 0.0)
            row = {"effect": e, "F": F, "p_adjusted": float(p_adj.get(e, 1.0)), "p_heldout": ph,
                   "heldout_rms_before": before.cv_rms * scale, "heldout_rms_after": f.cv_rms * scale,
                   "relative_gain": gain, "p_beyond_model": pw, "size": size, "size_unit": unit,
                   "detectable_size": detectable, **extra}
            if e == "base_tilt" and not separable:
                row.update(not_separable=True, accepted=False)
            else:
                row["accepted"] = bool(row["p_adjusted"] < alpha and ph < alpha_heldout and gain >= min_relative_gain
                                       and pw < alpha and big)
            rows.append(row)
        tests.append({"round": len(findings) + 1, "candidates": rows})
        if not separable and not any(x["effect"] == "base_tilt" for x in not_separable):
            not_separable.append({"effect": "base_tilt", "where": {"frame": "base", "from": "accelerometer"},
                                  "separability": float(tilt_sep),
                                  "why": (f"the platform turns too little between holds: {100 * tilt_sep:.2g}% of a tilt's "
                                          f"signature is beyond what the accelerometer's bias can take "
                                          f"(at least {100 * min_separability:.2g}% is needed)")})
        ok = [(r["relative_gain"], i) for i, r in enumerate(rows) if r["accepted"]]
        if not ok:
            break
        i = max(ok)[1]
        e, f, before = cands[i][0], cands[i][1], cands[i][4]
        if e == "base_tilt":
            findings.append(_tilt_finding(f, acc, rows[i]["p_heldout"], rows[i]["p_adjusted"], len(seg.holds.rows)))
            acc, tilt_with = f, cur.effects
        else:
            findings.append(_finding(e, f, before, rows[i]["p_heldout"], rows[i]["p_adjusted"], seg, frame_platform))
            if f.effects == cur.effects + (e,):
                cur = f
            else:  # the rotation was a nuisance: the model goes on without it, to test it on its own
                cur = _fit(seg, cur.effects + (e,))
                cur.cv = _cv(seg, cur.effects, block)
                cur.model_cov = _model_cov(seg, cur.effects, p_draws)
    if has_acc and acc.tilt and tilt_with != cur.effects:
        # the tilt with R_SP from the final gyro model
        acc = _acc_state(seg, cur.effects, True, block, q_draws, frame_base)
    # each finding's parameters from the final model (the other effects fitted with it)
    for fd in findings:
        if fd["effect"] == "base_tilt":
            fd["parameters"] = _tilt_finding(acc, acc_base, 1.0, 1.0, len(seg.holds.rows))["parameters"]
        else:
            full = cur if fd["effect"] == "imu_misalignment" else _with_rotation(seg, cur, block, p_draws)
            fd["parameters"] = _finding(fd["effect"], full, full, fd["p_heldout"], fd["p_screen"], seg,
                                        frame_platform)["parameters"]
    return ImuDiagnosis(findings, base, cur, seg, tests, _verdict(findings, base, cur, acc_base, acc, tests),
                        acc_base=acc_base, acc_final=acc, not_separable=not_separable)


def _verdict(findings, base: ImuFit, final: ImuFit, acc_base: AccFit | None, acc: AccFit | None, tests) -> str:
    named = [f["effect"] for f in findings]
    gyro = [e for e in named if e != "base_tilt"]
    if gyro:
        text = (f"IMU: the gyro shows {', '.join(gyro)}; modelling {'it' if len(gyro) == 1 else 'them'} brings the "
                f"held-out mean-rate RMS from {base.cv_rms * DEG:.3g} to {final.cv_rms * DEG:.3g} deg/s.")
    else:
        text = (f"IMU: no gyro effect found; a constant gyro bias ({', '.join(f'{v:.3g}' for v in base.b0 * DEG)} deg/s) "
                f"and the model's rotations leave a held-out RMS of {base.cv_rms * DEG:.3g} deg/s, and neither a "
                "drifting bias nor a misalignment predicts held-out segments significantly better.")
    if acc is None:
        return text
    if "base_tilt" in named:
        f = next(f for f in findings if f["effect"] == "base_tilt")
        tilt = f["parameters"]["tilt"]
        return text + (f" The accelerometer shows base_tilt: the base is tilted {tilt['value']:.3g} +- {tilt['std']:.2g} deg "
                       f"against the model's vertical; modelling it brings the held-out specific-force RMS at the holds "
                       f"from {acc_base.cv_rms:.3g} to {acc.cv_rms:.3g} m/s^2.")
    row = next((r for t in tests[::-1] for r in t["candidates"] if r["effect"] == "base_tilt"), None)
    if row is None:
        return text
    if row.get("not_separable"):
        return text + (f" A base tilt cannot be told from the accelerometer's bias on these holds (separability "
                       f"{row['separability']:.2g}, at least {MIN_TILT_SEPARABILITY:g} needed): the platform turns too "
                       "little between them; not tested.")
    return text + (f" The accelerometer shows no base tilt beyond what the model's frame allows (estimate {row['size']:.2g} deg; "
                   f"held-out specific-force RMS {row['heldout_rms_before']:.3g} -> {row['heldout_rms_after']:.3g} m/s^2, "
                   f"p = {row['p_heldout']:.2g}; beyond the calibration's uncertainty p = {row['p_beyond_model']:.2g}).")


def td_covariance(cal) -> np.ndarray:
    """(n_td, n_td) covariance of a Calibration's td: the estimator's full covariance when the
    calibration was fitted in this process, else its stds (NaN: held or fixed, 0)."""
    n = len(cal.td)
    ex = getattr(cal, "extras", None) or {}
    if "cov" in ex and "active" in ex:
        active = np.asarray(ex["active"], bool)
        full = np.zeros((len(active), len(active)))
        idx = np.nonzero(active)[0]
        full[np.ix_(idx, idx)] = ex["cov"]
        return full[:n, :n]
    return np.diag(np.nan_to_num(np.asarray(cal.td_std, float)) ** 2)


def diagnose_imu(spec, td, t_cmd: np.ndarray, U: np.ndarray, imu: ImuStream, td_cov: np.ndarray | None = None,
                 td_status=None, alpha: float = 0.01, alpha_heldout: float = 0.05, block: int = 4, draws: int = 32,
                 seed: int = 0) -> ImuDiagnosis:
    """IMU diagnosis of a session: ``spec`` and ``td`` the calibrated stand, ``td_cov`` its
    covariance (:func:`td_covariance`; None: the model is taken as exact), ``td_status`` the
    calibration's parameter statuses (None: its frames are taken as exact; else the parameters
    'held_at_nominal' make the allowance of :func:`frame_gauge`), ``t_cmd`` (M,) s and ``U``
    (M, n_u) SI the logged commands, ``imu`` the stream. See the module docstring."""

    model = PlatformModel(spec)
    U = np.asarray(U, float)
    td = np.asarray(td, float)
    q_cmd = command_poses(model, U, td=td)
    seg = segments_from_session(imu, np.asarray(t_cmd, float), q_cmd)
    q_draws = None
    if td_cov is not None and np.any(np.asarray(td_cov) != 0):
        rng = np.random.default_rng(seed)
        L = _sqrt_psd(np.asarray(td_cov, float))
        q_draws = []
        for _ in range(draws):
            fb = model.forward_batch(U, td=td + L @ rng.standard_normal(len(td)), strict=False)
            if not np.all(fb.converged):
                continue
            q_draws.append(fb.q)
    frame_base = frame_platform = None
    frame: dict[str, Any] = {}
    if td_status is not None:
        rows = np.unique(seg.holds.rows)
        frame_base, frame_platform, n_held = frame_gauge(spec, td, U[rows], td_status, model)
        frame = {"held_parameters": n_held,
                 "base_tilt_std_deg": (np.sqrt(np.diag(frame_base)[:2]) * DEG).tolist(),
                 "platform_rotation_std_deg": (np.sqrt(np.diag(frame_platform)) * DEG).tolist(),
                 "note": ("how far the parameters the calibration held at nominal can turn the model's base and "
                          "platform frames against the real stand's, for held parameters off by 2 mm or 2 mrad "
                          "(1 sigma): allowed for in the Wald tests")}
    d = diagnose_segments(seg, alpha, alpha_heldout, block, q_draws=q_draws, frame_base=frame_base,
                          frame_platform=frame_platform)
    d.frame = frame
    return d


def _sqrt_psd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    return V * np.sqrt(np.clip(w, 0, None))
