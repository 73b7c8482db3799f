"""Orientation estimators on simulated motion with known truth."""
from __future__ import annotations

import math

import numpy as np
import pytest

from platkit.errors import BadInput
from platkit.geometry import matrix_from_rpy, quat_from_rotvec, quat_from_rpy, quat_multiply
from platkit.inertial import quat as Q
from platkit.inertial.estimator import PlatkitParams, estimate_offline, estimate_platkit
from platkit.inertial.metrics import heading_error, inclination_error, inclination_rmse_deg, rmse, total_error
from platkit.inertial.paper import PaperParams, estimate_paper
from platkit.inertial.simulate import imu_from_motion
from platkit.io.imu import ImuStream

RATE = 200.0


def _wobble(duration=60.0, still=10.0):
    t = np.arange(0, duration, 1 / RATE)
    on = t > still
    roll = 0.3 * np.sin(2 * np.pi * 0.2 * t) * on
    pitch = 0.2 * np.sin(2 * np.pi * 0.13 * t) * on
    yaw = 0.5 * np.sin(2 * np.pi * 0.05 * t) * on
    return t, quat_from_rpy(roll, pitch, yaw), on


def test_metrics_match_their_definitions():
    q_true = quat_from_rpy(0.1, -0.2, 0.3)[None, :]
    tilt = quat_from_rotvec(np.array([[0.02, 0.0, 0.0]]))
    turn = quat_from_rotvec(np.array([[0.0, 0.0, 0.5]]))
    # an earth-frame heading error leaves the inclination error zero, and vice versa
    assert inclination_error(quat_multiply(turn, q_true), q_true)[0] == pytest.approx(0.0, abs=1e-7)
    assert heading_error(quat_multiply(turn, q_true), q_true)[0] == pytest.approx(0.5)
    assert inclination_error(quat_multiply(tilt, q_true), q_true)[0] == pytest.approx(0.02)
    assert total_error(quat_multiply(tilt, q_true), q_true)[0] == pytest.approx(0.02)
    assert rmse(np.array([3.0, np.nan, 4.0]), np.array([True, True, True])) == pytest.approx(math.sqrt(12.5))


def test_quat_helpers_agree_with_geometry():
    a, b = quat_from_rpy(0.1, 0.2, 0.3), quat_from_rpy(-0.3, 0.1, 1.0)
    assert np.allclose(Q.mul(a, b), quat_multiply(a, b))
    v = (0.3, -1.0, 2.0)
    assert np.allclose(Q.rotate(a, v), matrix_from_rpy(0.1, 0.2, 0.3) @ np.array(v))
    r = Q.from_two_vectors((1.0, 2.0, 3.0), (0.0, 0.0, 1.0))
    assert np.allclose(Q.rotate(r, (1.0, 2.0, 3.0)), [0, 0, math.sqrt(14)])
    r = Q.from_two_vectors((0.0, 0.0, -1.0), (0.0, 0.0, 1.0))
    assert np.allclose(Q.rotate(r, (0.0, 0.0, -1.0)), [0, 0, 1])


def test_strapdown_reproduces_the_motion_of_a_perfect_sensor():
    t, q, _ = _wobble(30.0, 5.0)
    R = matrix_from_rpy(0.05, -0.03, 0.1)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), R)
    est = estimate_paper(ImuStream(t, sim["gyr"], sim["acc"]),
                         PaperParams(case_a=False, case_b=False, gyr_cutoff_hz=90, acc_cutoff_hz=90))
    assert inclination_rmse_deg(est.q, sim["q_earth_from_sensor"]) < 0.05


def test_platkit_estimator_finds_the_gyro_bias_and_the_vertical():
    t, q, on = _wobble()
    bias = np.array([0.01, -0.02, 0.005])
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), matrix_from_rpy(0.05, -0.03, 0.1),
                          bias=[*bias, 0, 0, 0], noise=[0.002, 0.02], rng=np.random.default_rng(1),
                          lever_arm=[0.2, 0.0, 0.3])
    imu = ImuStream(t, sim["gyr"], sim["acc"])
    est = estimate_platkit(imu)
    assert inclination_rmse_deg(est.q, sim["q_earth_from_sensor"], on) < 0.1
    assert np.allclose(est.bias[-1], bias, atol=np.radians(0.02))
    assert est.rest[int(8 * RATE)] and not est.rest[int(30 * RATE)]
    two = estimate_offline(imu)
    assert inclination_rmse_deg(two.q, sim["q_earth_from_sensor"], on) < 0.1
    # without bias estimation the same stream drifts: the bias estimate is doing the work
    raw = estimate_platkit(imu, PlatkitParams(estimate_bias=False))
    truth = sim["q_earth_from_sensor"]
    assert inclination_rmse_deg(raw.q, truth, on) > 3 * inclination_rmse_deg(est.q, truth, on)


def test_paper_case_a_removes_the_tilt_error_at_rest():
    """A wrong gyro bias tilts the integrated attitude during motion; when the platform comes
    to rest, case A aligns the averaged accelerometer with the vertical."""
    t = np.arange(0, 40, 1 / RATE)
    moving = (t > 5) & (t < 25)
    roll = 0.3 * np.sin(2 * np.pi * 0.25 * (t - 5)) * moving
    q = quat_from_rpy(roll, 0 * t, 0 * t)
    # a bias error below the rest threshold (6 x the gyro noise), as after a coarse calibration
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[0.0, 0.003, 0, 0, 0, 0],
                          noise=[1e-3, 1e-2], rng=np.random.default_rng(2))
    imu = ImuStream(t, sim["gyr"], sim["acc"])
    with_a = estimate_paper(imu, PaperParams(case_b=False))
    without = estimate_paper(imu, PaperParams(case_a=False, case_b=False))
    late = t > 30
    err_a = inclination_rmse_deg(with_a.q, sim["q_earth_from_sensor"], late)
    err_0 = inclination_rmse_deg(without.q, sim["q_earth_from_sensor"], late)
    assert err_0 > 3.0  # 0.003 rad/s for 20 s of motion and 15 s of rest
    assert err_a < 0.3
    assert with_a.info["case_a_samples"] > 0


def test_paper_case_b_corrects_the_component_along_the_rotation_axis():
    """Rotation about the platform's x axis only, the sensor off the axis (centripetal and
    tangential accelerations lie in the plane normal to x): case B keeps the angle between
    gravity and the x axis right although the gyro bias about y would tilt it."""
    t = np.arange(0, 40, 1 / RATE)
    moving = t > 3
    roll = (0.4 * np.sin(2 * np.pi * 0.3 * (t - 3)) + 0.2 * (t - 3) * 0.3) * moving
    q = quat_from_rpy(roll, 0 * t, 0 * t)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[0.0, 0.005, 0.0, 0, 0, 0],
                          noise=[1e-3, 1e-2], rng=np.random.default_rng(3), lever_arm=[0.0, 0.3, 0.2])
    imu = ImuStream(t, sim["gyr"], sim["acc"])
    params = dict(case_a=False, min_rate_case_b=math.radians(2.0), axis_tolerance=math.radians(5.0))
    with_b = estimate_paper(imu, PaperParams(**params))
    without = estimate_paper(imu, PaperParams(case_a=False, case_b=False))
    late = t > 20
    err_b = inclination_rmse_deg(with_b.q, sim["q_earth_from_sensor"], late)
    err_0 = inclination_rmse_deg(without.q, sim["q_earth_from_sensor"], late)
    assert with_b.info["case_b_samples"] > 0.5 * len(t)
    assert err_0 > 5.0
    assert err_b < 0.2 * err_0


def test_imu_from_motion_checks_its_input():
    t = np.arange(0, 1, 0.01)
    with pytest.raises(BadInput, match="motion arrays must be"):
        imu_from_motion(t, np.tile([1.0, 0, 0, 0], (5, 1)), np.zeros((5, 3)))
    with pytest.raises(BadInput, match="expected one number or 6"):
        imu_from_motion(t, np.tile([1.0, 0, 0, 0], (len(t), 1)), np.zeros((len(t), 3)), bias=[1, 2])


def test_imu_from_motion_at_rest_reads_gravity_up():
    t = np.arange(0, 1, 0.01)
    sim = imu_from_motion(t, np.tile([1.0, 0, 0, 0], (len(t), 1)), np.zeros((len(t), 3)),
                          bias=[0.1, 0, 0, 0, 0, 0.2], scale=[1, 1, 1, 1, 1, 1.01])
    assert np.allclose(sim["acc"], [0, 0, 9.80665 * 1.01 + 0.2])
    assert np.allclose(sim["gyr"], [0.1, 0, 0])
