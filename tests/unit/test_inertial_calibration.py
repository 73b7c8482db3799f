"""Sensor calibration: biases, scales, the misalignment fit, rest detection, low-pass filters."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_rotvec, quat_from_rpy, rotvec_from_matrix
from platkit.inertial.calibration import (
    ImuCalibration,
    detect_rest,
    fit_accelerometer,
    fit_imu_alignment,
    gyro_bias_at_rest,
    integrate_gyro,
    rest_segments,
    sensor_axis_directions,
    static_means,
)
from platkit.inertial.filters import cutoff_from_spectrum, lowpass
from platkit.inertial.simulate import imu_from_motion
from platkit.io.imu import ImuStream

G = 9.80665


def _angle_deg(Ra, Rb):
    return np.degrees(np.linalg.norm(rotvec_from_matrix(Ra @ Rb.T)))


def test_six_position_accelerometer_fit_recovers_bias_and_scale():
    rng = np.random.default_rng(1)
    bias = np.array([0.12, -0.08, 0.2])
    scale = np.array([1.01, 0.995, 1.004])
    dirs = np.vstack([np.eye(3), -np.eye(3), rng.normal(size=(6, 3))])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    means = scale * dirs * G + bias + rng.normal(0, 1e-3, dirs.shape)
    fit = fit_accelerometer(means)
    assert np.allclose(fit.bias, bias, atol=3e-3)
    assert np.allclose(fit.scale, scale, atol=3e-4)
    assert fit.rms < 3e-3
    assert np.all(fit.bias_std < 3e-3)


def test_accelerometer_fit_refuses_one_sided_positions():
    dirs = np.array([[0, 0, 1], [0.3, 0, 0.95], [-0.3, 0, 0.95], [0, 0.3, 0.95], [0, -0.3, 0.95], [0.2, 0.2, 0.96]])
    with pytest.raises(NotIdentifiable, match="axis x was not turned both up and down"):
        fit_accelerometer(dirs * G)


def test_misalignment_from_rotation_vectors():
    rng = np.random.default_rng(2)
    R_true = matrix_from_rotvec(np.array([0.02, -0.05, 0.6]))
    rp = rng.normal(0, 0.2, (20, 3))
    rs = rp @ R_true.T + rng.normal(0, 1e-4, rp.shape)
    fit = fit_imu_alignment(rp, rs)
    assert _angle_deg(fit.sensor_from_platform, R_true) < 0.01
    assert fit.rms < 3e-4


def test_misalignment_with_gyro_scale():
    rng = np.random.default_rng(3)
    R_true = matrix_from_rotvec(np.array([0.1, 0.03, -0.2]))
    s = np.array([1.02, 0.99, 1.005])
    rp = rng.normal(0, 0.3, (30, 3))
    rs = s * (rp @ R_true.T)
    fit = fit_imu_alignment(rp, rs, fit_scale=True)
    assert _angle_deg(fit.sensor_from_platform, R_true) < 1e-6
    assert np.allclose(fit.gyr_scale, s, atol=1e-9)


def test_misalignment_needs_two_axes():
    rp = np.outer(np.linspace(0.1, 1, 5), [1.0, 0, 0])
    with pytest.raises(NotIdentifiable, match="fewer than two independent axes"):
        fit_imu_alignment(rp, rp)


def test_paper_step_two_single_axis_rotations():
    """Rotations about the platform's x and y axes; their directions in the sensor frame by
    least squares, then the rotation R_SP (the paper's step 2)."""
    R_true = matrix_from_rotvec(np.array([0.03, 0.02, -0.4]))
    rng = np.random.default_rng(4)
    segs = []
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        rate = 0.5 * np.sin(np.linspace(0, 6, 400)) + 0.6
        w_s = (rate[:, None] * axis) @ R_true.T + rng.normal(0, 0.005, (400, 3))
        segs.append(w_s)
    d = sensor_axis_directions(segs)
    fit = fit_imu_alignment(np.eye(3)[:2], d)
    assert _angle_deg(fit.sensor_from_platform, R_true) < 0.1


def test_integrate_gyro_is_exact_for_a_constant_rate():
    w = np.array([0.3, -0.2, 0.5])
    r = integrate_gyro(np.tile(w, (100, 1)), 0.01)
    assert np.allclose(r, w * 1.0, atol=1e-12)


def _static_stream(rng, gyr_bias):
    t = np.arange(0, 30, 0.01)
    rpy = np.zeros((len(t), 3))
    # five positions held 5 s, with 1 s moves between them
    targets = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0], [-0.5, 0, 0], [0, -0.5, 0]])
    for i, tg in enumerate(targets):
        rpy[t >= 6 * i] = tg
    from scipy.ndimage import uniform_filter1d

    rpy = uniform_filter1d(rpy, 50, axis=0, mode="nearest")  # half-second moves, not jumps
    q = quat_from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[*gyr_bias, 0, 0, 0], noise=[1e-3, 1e-2], rng=rng)
    return ImuStream(t, sim["gyr"], sim["acc"])


def test_gyro_bias_and_rest_segments():
    rng = np.random.default_rng(5)
    b = np.array([0.01, -0.02, 0.004])
    imu = _static_stream(rng, b)
    segs = rest_segments(detect_rest(imu), imu.t, 1.0)
    assert len(segs) == 5
    assert np.allclose(gyro_bias_at_rest(imu), b, atol=3e-4)
    assert static_means(imu).shape == (5, 3)


def test_no_rest_is_not_identifiable():
    t = np.arange(0, 5, 0.01)
    gyr = np.column_stack([np.sin(3 * t), np.cos(2 * t), 0 * t])
    imu = ImuStream(t, gyr, np.tile([0, 0, G], (len(t), 1)), source="moving.csv")
    with pytest.raises(NotIdentifiable, match="no rest of 2 s in moving.csv"):
        gyro_bias_at_rest(imu)


def test_calibration_apply_and_round_trip():
    cal = ImuCalibration(np.array([0.1, 0, 0]), np.array([2.0, 1, 1]), np.array([0, 0, 0.5]), np.array([1, 1, 0.5]))
    imu = ImuStream(np.arange(3.0), np.tile([2.1, 1, 1], (3, 1)), np.tile([0, 0, 10.5], (3, 1)))
    out = cal.apply(imu)
    assert np.allclose(out.gyr[0], [1.0, 1.0, 1.0]) and np.allclose(out.acc[0], [0, 0, 20.0])
    back = ImuCalibration.from_dict(cal.to_dict())
    assert np.allclose(back.gyr_scale, cal.gyr_scale) and np.allclose(back.acc_bias, cal.acc_bias)


def test_cutoff_from_spectrum_sits_above_the_motion():
    rng = np.random.default_rng(6)
    rate = 200.0
    t = np.arange(0, 60, 1 / rate)
    x = np.sin(2 * np.pi * 1.5 * t) + 0.5 * np.sin(2 * np.pi * 4.0 * t) + rng.normal(0, 0.05, len(t))
    c = cutoff_from_spectrum(x, rate, min_hz=1.0)
    assert 4.0 <= c.signal_edge_hz <= 6.0
    assert c.cutoff_hz == pytest.approx(4 * c.signal_edge_hz)


def test_lowpass_starts_in_steady_state():
    x = np.full((100, 2), 3.0)
    assert np.allclose(lowpass(x, 5.0, 100.0), 3.0)


def test_static_multi_position_test_end_to_end(tmp_path, capsys):
    """Twelve static positions written as imu.csv; the module's entry point fits them and the
    YAML it writes is what orient --imu-calibration reads."""
    from platkit.geometry import matrix_from_rotvec, quat_from_matrix
    from platkit.inertial.calibration import main as calibrate_main
    from platkit.io.description import load_yaml
    from platkit.io.imu import write_imu_csv

    rng = np.random.default_rng(8)
    dirs = np.vstack([np.eye(3), -np.eye(3), rng.normal(size=(6, 3))])
    t = np.arange(0, 3.0 * len(dirs), 0.01)
    q = np.empty((len(t), 4))
    for i, d in enumerate(dirs):
        d = d / np.linalg.norm(d)
        v = np.cross(d, [0.0, 0.0, 1.0])
        R = (matrix_from_rotvec(v / np.linalg.norm(v) * np.arccos(np.clip(d[2], -1, 1))) if np.linalg.norm(v) > 1e-9
             else (np.eye(3) if d[2] > 0 else np.diag([1.0, -1.0, -1.0])))
        q[(t >= 3.0 * i) & (t < 3.0 * (i + 1))] = quat_from_matrix(R)
    bias = np.array([0.01, -0.02, 0.005, 0.1, -0.05, 0.08])
    scale = np.array([1, 1, 1, 1.01, 0.99, 1.005])
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=bias, scale=scale, noise=[1e-3, 1e-2], rng=rng)
    write_imu_csv(tmp_path / "static.csv", t, sim["gyr"], sim["acc"])
    assert calibrate_main([str(tmp_path / "static.csv"), str(tmp_path / "imu_cal.yaml")]) == 0
    cal = ImuCalibration.from_dict(load_yaml(tmp_path / "imu_cal.yaml"))
    assert np.allclose(cal.acc_bias, bias[3:], atol=3e-3)
    assert np.allclose(cal.acc_scale, scale[3:], atol=5e-4)
    assert np.allclose(cal.gyr_bias, bias[:3], atol=2e-4)
    # a recording that never rests is refused in one line
    moving = ImuStream(t, sim["gyr"] + np.sin(t)[:, None], sim["acc"])
    write_imu_csv(tmp_path / "moving.csv", moving.t, moving.gyr, moving.acc)
    assert calibrate_main([str(tmp_path / "moving.csv"), str(tmp_path / "x.yaml")]) == 1
    assert "static test: no rest" in capsys.readouterr().err
