"""platkit's orientation estimator: VQF (Laidig and Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection", Information Fusion 91, 2023)
from the maintained ``vqf`` package, with platkit's checks and frames around it.

The method (what the package computes):

1. strapdown: q_I_from_S integrates the bias-corrected gyro;
2. the accelerometer is rotated into that near-inertial frame I and low-pass filtered there (time
   constant ``tau_acc``): in I, accelerations that are not gravity average out, while gravity
   stays put; a correction rotation q_E_from_I turns the filtered vector to the vertical;
3. the gyro bias is a Kalman state: at rest (gyro and accelerometer steady for ``rest_min_s``)
   measured by the low-passed gyro; in motion by the inclination correction the accelerometer
   asks for.

:func:`estimate_platkit` is the causal filter (``vqf.VQF.updateBatch``), :func:`estimate_offline`
the offline one (``vqf.offlineVQF``: forward-backward bias, zero-phase inertial-frame filter),
which ``platkit orient`` uses on files. platkit's part, kept thin:

- the stream: at least 2 samples, finite, on the uniform clock :class:`ImuStream` guarantees;
- a known gyro bias (``initial_bias``, from a calibration or a rest) is removed before the filter
  and added back to its bias estimate, and the filter starts with the bias uncertainty of a
  measured one (twice ``bias_sigma_rest``) instead of ``bias_sigma_init``;
- clipped accelerometer samples say nothing about the vertical: the causal filter skips them
  (VQF ignores a zero sample), the offline one sees them interpolated from their neighbours;
- ``shock_threshold`` (off by default) clamps the specific force's magnitude to |g| +- the
  threshold before the filter. Measured on BROAD with platkit's former own implementation it
  helped tapping a little (0.607 -> 0.579 deg at 0.5 g) and ruined fast translation
  (0.539 -> 13.6 deg): clamping breaks the zero mean of non-gravity acceleration in the inertial
  frame, which the filter relies on. An option for stands with hard end stops, not a default.

Output: q_earth_from_sensor (N, 4) w x y z, earth frame z up, heading relative to the start.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
from vqf import VQF, offlineVQF

from platkit.errors import BadInput
from platkit.io.imu import ImuStream

GRAVITY = 9.80665  # m/s^2, only used as the scale of the shock bound


@dataclass
class PlatkitParams:
    """Tuning of the estimators (VQF's parameters in SI). Times in s, rates in rad/s,
    accelerations in m/s^2."""

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

    def vqf_params(self) -> dict:
        """The ``vqf`` package's parameters (degrees where it takes degrees; no magnetometer)."""
        sigma_init = 2.0 * self.bias_sigma_rest if self.initial_bias is not None else self.bias_sigma_init
        return {"tauAcc": self.tau_acc, "restFilterTau": self.rest_tau, "restMinT": self.rest_min_s,
                "restThGyr": math.degrees(self.rest_gyr_threshold), "restThAcc": self.rest_acc_threshold,
                "biasSigmaInit": math.degrees(sigma_init), "biasForgettingTime": self.bias_forgetting_s,
                "biasSigmaMotion": math.degrees(self.bias_sigma_motion),
                "biasVerticalForgettingFactor": self.bias_vertical_factor,
                "biasSigmaRest": math.degrees(self.bias_sigma_rest), "biasClip": math.degrees(self.bias_clip),
                "motionBiasEstEnabled": self.estimate_bias, "restBiasEstEnabled": self.estimate_bias,
                "magDistRejectionEnabled": False}


@dataclass
class OrientationEstimate:
    """``t`` (N,) s; ``q`` (N, 4) q_earth_from_sensor; ``bias`` (N, 3) rad/s; ``rest`` (N,) bool;
    ``info``: the method and its settings."""

    t: np.ndarray
    q: np.ndarray
    bias: np.ndarray
    rest: np.ndarray
    info: dict = field(default_factory=dict)


def _inputs(imu: ImuStream, p: PlatkitParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(gyro with the known bias removed, accelerometer after the shock clamp, known bias (3,)),
    contiguous float64, and the checks."""
    if imu.n < 2:
        raise BadInput("the IMU stream needs at least 2 samples")
    if not (np.all(np.isfinite(imu.gyr)) and np.all(np.isfinite(imu.acc))):
        raise BadInput(f"{imu.source or 'the IMU stream'}: non-finite samples (read it with platkit.io.imu, which "
                       "repairs or refuses them)")
    b0 = np.zeros(3) if p.initial_bias is None else np.asarray(p.initial_bias, float)
    gyr = np.ascontiguousarray(imu.gyr - b0, dtype=float)
    acc = np.array(imu.acc, dtype=float)
    if p.shock_threshold is not None:
        norm = np.linalg.norm(acc, axis=1)
        off = (np.abs(norm - GRAVITY) > p.shock_threshold) & (norm > 0)
        bound = GRAVITY + np.copysign(p.shock_threshold, norm[off] - GRAVITY)
        acc[off] *= (bound / norm[off])[:, None]
    return gyr, acc, b0


def _q_out(q: np.ndarray) -> np.ndarray:
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def estimate_platkit(imu: ImuStream, params: PlatkitParams | None = None) -> OrientationEstimate:
    """The causal estimator over a stream (``vqf.VQF.updateBatch``; see the module docstring)."""
    p = params or PlatkitParams()
    gyr, acc, b0 = _inputs(imu, p)
    sat = imu.saturated[:, 3:].any(axis=1)
    acc[sat] = 0.0  # VQF skips a zero accelerometer sample: a clipped one says nothing new
    f = VQF(imu.dt, **p.vqf_params())
    out = f.updateBatch(gyr, np.ascontiguousarray(acc))
    return OrientationEstimate(imu.t.copy(), _q_out(np.asarray(out["quat6D"])), np.asarray(out["bias"]) + b0,
                               np.asarray(out["restDetected"], bool), {"method": "platkit", "params": p.as_dict()})


def estimate_offline(imu: ImuStream, params: PlatkitParams | None = None) -> OrientationEstimate:
    """The offline estimator (``vqf.offlineVQF``): the gyro bias from a forward and a backward
    pass, the inertial-frame accelerometer filtered with zero phase. Not causal: for files, not for
    live tracking. Clipped accelerometer samples are interpolated from their neighbours first."""
    p = params or PlatkitParams()
    gyr, acc, b0 = _inputs(imu, p)
    sat = imu.saturated[:, 3:].any(axis=1)
    if sat.any() and not sat.all():
        good = np.nonzero(~sat)[0]
        for j in range(3):
            acc[sat, j] = np.interp(np.nonzero(sat)[0], good, acc[good, j])
    out = offlineVQF(gyr, np.ascontiguousarray(acc), None, imu.dt, p.vqf_params())
    return OrientationEstimate(imu.t.copy(), _q_out(np.asarray(out["quat6D"])), np.asarray(out["bias"]) + b0,
                               np.asarray(out["restDetected"], bool),
                               {"method": "platkit-offline", "params": p.as_dict()})
