"""platkit's built-in IMU effects, registered through ``platkit_register_effects`` with the
motion-capture effects (see :class:`platkit.effects.ImuEffect` for the sensor model they share
between the IMU simulator and the IMU diagnosis).

| effect | acts through | theta (SI) | reported as |
|---|---|---|---|
| gyro_bias_drift | gyro bias d (t - t_ref) | d (3) rad/s per s, sensor axes | gyro_bias_drift |
| imu_misalignment | R_SP = exp([theta]x) | rotation vector (3) rad | imu_misalignment |
| imu_base_tilt | R_LB = exp([w_x, w_y, 0]x) | w (2) rad about base x, y | base_tilt |

The floors below are what the measurement and the model's frames leave open (measured on
benchmarks/diagnosis_proof_imu.py and tests/unit/test_diagnose_imu*.py).
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from platkit.effects import ImuEffect

DEG = 180.0 / np.pi

#: a misalignment smaller than this (deg) is not named. The gyro is compared with the calibrated
#: model's platform frame, and that frame is tied to the parameters the calibration holds at
#: their nominal values (its gauge): a stand built a few tenths of a mm off them turns the model's
#: frame against the real one by a few hundredths of a degree, which the mocap cannot see and a
#: gyro can (0.06-0.08 deg in the simulated stewart sessions of tests/unit/test_diagnose_imu.py).
#: How far held parameters a few mm off can turn it is in the Wald test (the diagnosis's frame
#: gauge): more than this floor on psvr (0.23 deg, 1 sigma, about y: a platform joint's height is
#: held; clean psvr sessions show 0.3-0.6 deg) and rotary (0.16 deg).
MIN_ANGLE_DEG = 0.25

#: a base tilt smaller than this (deg) is not named. Beyond the model frame's allowance (which
#: assumes how far the held parameters are off) and the noise, a floor: on the clean sessions of
#: benchmarks/diagnosis_proof_imu.py the tilt estimates reached 0.087 deg on stewart (a session
#: where the F and held-out tests passed and the Wald test alone, p = 0.03, kept it out) and
#: 0.038 deg on psvr; rotary's reached 0.24 deg, inside its allowance (0.115 deg, 1 sigma, its
#: first joint's axis held). An accelerometer's axes are rarely square to its gyro's to better
#: than a few hundredths of a degree either, and that looks like a tilt where the platform does
#: not yaw.
MIN_TILT_DEG = 0.1

#: a base tilt is tested only where at least this share of its signature on the holds is beyond
#: what an accelerometer bias and gravity scale can mimic. Random plans give 0.10-0.13 on stewart
#: (+-8 deg of roll, pitch and yaw), 0.08-0.10 on psvr (no yaw), 0.5-0.9 on rotary; stewart legs
#: within 30 mm of neutral (about a degree of rotation) 0.003-0.017. Below 0.02 a tilt's estimate
#: is more than 50 times as sensitive to anything unmodelled in the specific force as where the
#: platform turns fully (an unmodelled 1 mm/s^2 would move it by 0.3 deg).
MIN_TILT_SEPARABILITY = 0.02


_SEGMENTS = "segments' mean rate"
_HOLDS = "holds' specific force"


def matrix_from_rotvec(v) -> np.ndarray:
    """Rodrigues for one rotation vector (3,) rad -> (3, 3) (the diagnosis evaluates it thousands
    of times: a closed form on floats, not the batched one)."""
    x, y, z = (float(a) for a in v)
    th2 = x * x + y * y + z * z
    if th2 < 1e-16:
        a, b = 1.0 - th2 / 6.0, 0.5 - th2 / 24.0
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th2
    return np.array([[1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
                     [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
                     [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)]])


def _rms_sentence(c: dict[str, Any], what: str) -> str:
    return (f"predicts the held-out {what} with RMS {c['heldout_before']:.3g} -> {c['heldout_after']:.3g} "
            f"{c['heldout_unit']}")


class GyroBiasDrift(ImuEffect):
    name = "gyro_bias_drift"
    summary = "the gyro bias changes linearly in time"
    sensor = "gyro"
    parameter_names = ("drift_x", "drift_y", "drift_z")
    display_unit = "deg/s per min"
    display_scale = DEG * 60.0
    simulation_keyword = "bias_rate"

    def gyro_bias(self, theta, t):
        return np.asarray(t, float)[:, None] * np.asarray(theta, float)[None, :]

    def report(self, theta, cov, context):
        c = context
        sd = np.sqrt(np.clip(np.diag(cov), 0, None)) * self.display_scale
        d = np.asarray(theta) * self.display_scale
        params = {f"drift_{a}": {"value": float(v), "std": float(s), "unit": self.display_unit}
                  for a, v, s in zip("xyz", d, sd)}
        params.update({f"bias_{a}": {"value": float(v), "std": float(s), "unit": "deg/s"}
                       for a, v, s in zip("xyz", np.asarray(c["b0"]) * DEG, np.asarray(c["b0_std"]) * DEG)})
        span = c["span_s"]
        where = {"sensor": "gyro", "time_s": [round(span[0], 3), round(span[1], 3)],
                 "reference_time_s": round(c["t_ref"], 3), "frame": "sensor axes"}
        change = float(np.linalg.norm(theta) * (span[1] - span[0]) * DEG)
        evidence = (f"The gyro bias changes by {change:.3g} deg/s over the {span[1] - span[0]:.0f} s session "
                    f"({np.linalg.norm(d):.3g} deg/s per min; bias at {c['t_ref']:.0f} s: "
                    f"{', '.join(f'{v:.3g}' for v in np.asarray(c['b0']) * DEG)} deg/s): a bias drifting linearly "
                    f"{_rms_sentence(c, _SEGMENTS)} over {c['n']} segments "
                    f"(paired Wilcoxon p = {c['p_heldout']:.2g}; F test Holm p = {c['p_screen']:.2g}).")
        return {"parameters": params, "where": where, "evidence": evidence}

    def calibration_entry(self, theta, cov, context):
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        return {"gyro_bias": {"reference_time_s": float(context["t_ref"]), "bias": np.asarray(context["b0"]).tolist(),
                              "drift": np.asarray(theta, float).tolist(), "std_drift": std.tolist(),
                              "note": "b(t) = bias + drift (t - reference_time_s), rad/s and rad/s per s, sensor axes"}}


class ImuMisalignment(ImuEffect):
    name = "imu_misalignment"
    summary = "the IMU's axes turned against the platform frame"
    sensor = "gyro"
    parameter_names = ("angle_x", "angle_y", "angle_z")
    display_unit = "deg"
    display_scale = DEG
    min_size = MIN_ANGLE_DEG
    nuisance = True

    def sensor_from_platform(self, theta):
        return matrix_from_rotvec(np.asarray(theta, float))

    def frame_covariance(self, theta, frame_base, frame_platform):
        # the gyro sees R_SP P^T, P the model's platform frame against the real one: a left
        # rotation of -R_SP p
        if frame_platform is None:
            return np.zeros((3, 3))
        R = matrix_from_rotvec(np.asarray(theta, float))
        return R @ np.asarray(frame_platform, float) @ R.T

    def report(self, theta, cov, context):
        c = context
        ang = np.asarray(theta, float) * DEG
        sd = np.sqrt(np.clip(np.diag(cov), 0, None)) * DEG
        params = {f"angle_{a}": {"value": float(v), "std": float(s), "unit": "deg"} for a, v, s in zip("xyz", ang, sd)}
        total = float(np.linalg.norm(ang))
        J = ang / total if total > 0 else np.zeros(3)
        params["angle"] = {"value": total, "std": float(np.sqrt(J @ cov @ J)) * DEG, "unit": "deg"}
        where = {"sensor": "gyro", "frame": "sensor from platform, rotation vector",
                 "axis": [round(float(v), 4) for v in J]}
        evidence = (f"The gyro's rotations between holds are the model's turned by {total:.3g} deg "
                    f"(rotation vector {', '.join(f'{v:.3g}' for v in ang)} deg, IMU axes against the platform's): "
                    f"modelling the rotation {_rms_sentence(c, _SEGMENTS)} over {c['n']} "
                    f"segments (paired Wilcoxon p = {c['p_heldout']:.2g}; F test Holm p = {c['p_screen']:.2g}).")
        return {"parameters": params, "where": where, "evidence": evidence}

    def calibration_entry(self, theta, cov, context):
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        return {"sensor_from_platform": {
            "rotation_vector": np.asarray(theta, float).tolist(), "std_rotation_vector": std.tolist(),
            "rotation_matrix": matrix_from_rotvec(np.asarray(theta, float)).tolist(),
            "note": "IMU axes from the model's platform frame: v_sensor = R v_platform (rad)"}}


class ImuBaseTilt(ImuEffect):
    name = "imu_base_tilt"
    summary = "the base tilted against the model's vertical, as the accelerometer reads gravity"
    sensor = "accelerometer"
    parameter_names = ("tilt_x", "tilt_y")
    display_unit = "deg"
    display_scale = DEG
    min_size = MIN_TILT_DEG
    min_separability = MIN_TILT_SEPARABILITY
    simulation_keyword = "base_tilt"
    reported_as = "base_tilt"

    def level_from_base(self, theta):
        w = np.asarray(theta, float)
        return matrix_from_rotvec(np.array([w[0], w[1], 0.0]))

    def frame_covariance(self, theta, frame_base, frame_platform):
        return np.zeros((2, 2)) if frame_base is None else np.asarray(frame_base, float)[:2, :2]

    def report(self, theta, cov, context):
        c = context
        w = np.asarray(theta, float) * DEG
        C = np.asarray(cov, float) * DEG**2
        sd = np.sqrt(np.clip(np.diag(C), 0, None))
        total = float(np.linalg.norm(w))
        J = w / total if total > 0 else np.zeros(2)
        tsd = float(np.sqrt(J @ C @ J))
        params = {"tilt_x": {"value": float(w[0]), "std": float(sd[0]), "unit": "deg"},
                  "tilt_y": {"value": float(w[1]), "std": float(sd[1]), "unit": "deg"},
                  "tilt": {"value": total, "std": tsd, "unit": "deg"}}
        where = {"frame": "base", "from": "accelerometer", "axis": [round(float(J[0]), 4), round(float(J[1]), 4), 0.0],
                 "convention": "level frame from the model's base frame = exp([tilt_x, tilt_y, 0]x)"}
        evidence = (f"At {c['n']} holds the accelerometer reads gravity turned by {total:.3g} deg in the model's base "
                    f"frame (about x {w[0]:.3g} deg, about y {w[1]:.3g} deg; +- {tsd:.2g} deg with the calibration's "
                    f"uncertainty and its frame): a tilted base {_rms_sentence(c, _HOLDS)} "
                    f"(paired Wilcoxon p = {c['p_heldout']:.2g}; F test Holm p = {c['p_screen']:.2g}; separability "
                    f"from the accelerometer's bias {c['separability']:.2g}).")
        return {"parameters": params, "where": where, "evidence": evidence}

    def headline(self, parameters):
        t = parameters["tilt"]
        return f"the base is tilted {t['value']:.3g} +- {t['std']:.2g} deg against the model's vertical"

    def calibration_entry(self, theta, cov, context):
        std = np.sqrt(np.clip(np.diag(cov), 0, None))
        return {"base_tilt": {"rotation_vector": [float(theta[0]), float(theta[1]), 0.0],
                              "std_rotation_vector": std.tolist() + [0.0],
                              "note": ("the level frame from the model's base frame, rad: gravity in the base frame "
                                       "is R^T (0, 0, -g)")}}


IMU_EFFECTS = [GyroBiasDrift(), ImuMisalignment(), ImuBaseTilt()]
