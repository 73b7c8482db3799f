"""A base tilted against the model's vertical, named from the accelerometer at the holds
(platkit.diagnose.imu): a concealed tilt is named with the truth in its interval, alone or with a
misalignment; holds that barely turn leave it untested and say so; the simulator's sign
conventions; the model frame's allowance; diagnosis.json and calibration.yaml from the CLI.
Simulated stewart sessions (60 random commands), calibrated on their own poses."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import calibrate
from platkit.cli import main
from platkit.diagnose.imu import DEG, diagnose_imu, frame_gauge, td_covariance, up_in_sensor
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.inertial.simulate import imu_for_trajectory
from platkit.io.calibration import read_calibration
from platkit.io.imu import ImuStream
from platkit.plugins import default_host, effect_library, get_platform
from platkit.simulate import simulate

#: a constant gyro bias (rad/s) and accelerometer bias (m/s^2) in every case: normal, never a finding
BIAS = [0.003, -0.002, 0.001, 0.05, -0.03, 0.08]
#: the tilted base: 0.34 deg about an axis 37 deg off base x (the level frame from the base)
TILT = np.array([0.0048, 0.0036])
ROTVEC = np.array([0.02, -0.03, 0.015])  # a misaligned IMU, 2.2 deg
#: the registered IMU tilt effect: its level frame and its separability floor
TILT_EFFECT = effect_library()["imu_base_tilt"]
MIN_TILT_SEPARABILITY = TILT_EFFECT.min_separability


def _tilt_term():
    """The base_tilt effect as the simulator applies it (platkit simulate --effect base_tilt)."""
    return default_host().effects()["base_tilt"].term()


def _diagnose(seed=1, plan="random", terms=(), **imu_kw):
    spec = get_platform("stewart")
    sim = simulate(spec, seed=seed, n_poses=60, plan=plan, terms=list(terms), imu=imu_for_trajectory(bias=BIAS, **imu_kw))
    cal = calibrate(sim.poses, spec)
    im = sim.imu
    d = diagnose_imu(spec, cal.td, sim.command_t, sim.commands, ImuStream(im["t"], im["gyr"], im["acc"]),
                     td_cov=td_covariance(cal), td_status=cal.td_status)
    return sim, d


def _check_tilt(f, truth):
    """Each tilt angle within 3 std of the truth (the std allows for the model's frame)."""
    assert f["where"]["from"] == "accelerometer" and f["where"]["frame"] == "base" and f["unit"] == "m/s^2"
    for c, v in zip("xy", truth * DEG):
        p = f["parameters"][f"tilt_{c}"]
        assert p["unit"] == "deg" and 0 < p["std"] < 0.06
        assert abs(p["value"] - v) < 3 * p["std"], (c, p, v)
    assert f["parameters"]["tilt"]["value"] == pytest.approx(np.linalg.norm(truth) * DEG, abs=3 * f["parameters"]["tilt"]["std"])
    assert f["heldout_rms_after"] < 0.8 * f["heldout_rms_before"] and f["p_heldout"] < 0.05
    assert "deg" in f["evidence"] and "m/s^2" in f["evidence"]


def test_the_accelerometer_reads_the_tilt_the_simulator_conceals():
    """A still platform reads g R_SP R^T R_tilt^T e_z + b (platkit.inertial.simulate's signs), and
    the pose-level base_tilt term (the stand turned in the level world) reads the same as
    gravity turned in the base frame."""
    spec = get_platform("stewart")
    R_sp = matrix_from_rotvec(ROTVEC)
    a = simulate(spec, seed=4, n_poses=8, plan="random", terms=[(_tilt_term(), TILT)],
                 imu=imu_for_trajectory(imu_from_platform=R_sp, bias=BIAS, noise=(0.0, 0.0)))
    b = simulate(spec, seed=4, n_poses=8, plan="random",
                 imu=imu_for_trajectory(imu_from_platform=R_sp, bias=BIAS, noise=(0.0, 0.0), base_tilt=TILT))
    assert a.imu["truth_imu"]["base_tilt_rad"] == pytest.approx(TILT.tolist())
    assert b.imu["truth_imu"]["base_tilt_rad"] == pytest.approx(TILT.tolist())
    # the last sample of each hold: the platform is still there
    t = a.imu["t"]
    ends = np.searchsorted(t, np.append(a.command_t[1:], t[-1])) - 2
    R_model = matrix_from_quat(np.asarray(b.imu["q_base_from_platform"])[ends])
    expected = 9.80665 * up_in_sensor(R_model, R_sp, TILT_EFFECT.level_from_base(TILT)) + np.array(BIAS[3:])
    np.testing.assert_allclose(b.imu["acc"][ends], expected, atol=2e-3)
    # the pose-level tilt turns the poses themselves: undo it to get the model's orientation
    R_level = matrix_from_quat(np.asarray(a.imu["q_base_from_platform"])[ends])
    R_model_a = matrix_from_rotvec(np.array([TILT[0], TILT[1], 0.0])).T @ R_level
    R_lb = TILT_EFFECT.level_from_base(TILT)
    np.testing.assert_allclose(a.imu["acc"][ends], 9.80665 * up_in_sensor(R_model_a, R_sp, R_lb) + np.array(BIAS[3:]),
                               atol=2e-3)
    untilted = 9.80665 * up_in_sensor(R_model_a, R_sp) + np.array(BIAS[3:])
    assert np.max(np.abs(a.imu["acc"][ends] - untilted)) > 0.03  # the tilt is there to see


def test_a_tilted_base_is_named_with_its_tilt():
    sim, d = _diagnose(1, terms=[(_tilt_term(), TILT)])
    assert [f["effect"] for f in d.findings] == ["base_tilt"]
    _check_tilt(d.findings[0], TILT)
    row = next(r for r in d.tests[0]["candidates"] if r["effect"] == "base_tilt")
    assert row["accepted"] and row["separability"] > 0.05 and row["detectable_size"] < 0.2
    # the accelerometer's bias is the base model's, not a finding; on z it trades with the gravity
    # that axis reads (the platform tilts a few degrees): their sum is what the holds fix
    np.testing.assert_allclose(d.acc_final.bias[:2], BIAS[3:5], atol=0.01)
    assert d.acc_final.bias[2] + d.acc_final.scale[2] == pytest.approx(9.80665 + BIAS[5], abs=0.01)
    assert "base_tilt" in d.verdict and d.not_separable == []


def test_a_tilt_with_a_misaligned_imu_names_both():
    _, d = _diagnose(2, terms=[(_tilt_term(), TILT)], imu_from_platform=matrix_from_rotvec(ROTVEC))
    assert sorted(f["effect"] for f in d.findings) == ["base_tilt", "imu_misalignment"]
    by = {f["effect"]: f for f in d.findings}
    _check_tilt(by["base_tilt"], TILT)
    for c, v in zip("xyz", ROTVEC * DEG):
        p = by["imu_misalignment"]["parameters"][f"angle_{c}"]
        assert abs(p["value"] - v) < 3 * p["std"] + 0.01, (c, p, v)


def test_holds_that_barely_turn_leave_the_tilt_untested():
    """Legs within 30 mm of neutral: the platform turns about a degree between holds, too little
    to tell a tilt from the accelerometer's bias; reported not separable, not named."""
    spec = get_platform("stewart")
    rng = np.random.default_rng(5)
    U = spec.neutral_u() + rng.uniform(-1, 1, (60, 6)) * 0.03
    _, d = _diagnose(2, plan=U, terms=[(_tilt_term(), TILT)])
    assert "base_tilt" not in [f["effect"] for f in d.findings]
    row = next(r for r in d.tests[0]["candidates"] if r["effect"] == "base_tilt")
    assert row["not_separable"] and not row["accepted"] and row["separability"] < MIN_TILT_SEPARABILITY
    assert [x["effect"] for x in d.not_separable] == ["base_tilt"]
    assert "cannot be told" in d.verdict
    assert d.to_dict()["not_separable"][0]["separability"] == row["separability"]


def test_the_model_frame_allowance_of_the_rotary_stand():
    """The rotary's first joint axis is held at nominal (the motion capture cannot see it turn
    against the base): its 2 mrad are exactly how far the model's vertical is known."""
    spec = get_platform("rotary")
    U = np.array([[a, b] for a in (-120.0, -30.0, 45.0, 150.0) for b in (-60.0, 0.0, 40.0)])
    status = ["estimated"] * spec.n_td
    names = spec.parameter_names
    for n in ("joint1.origin_rx", "joint1.origin_ry"):
        status[names.index(n)] = "held_at_nominal"
    C_base, C_platform, n_held = frame_gauge(spec, spec.nominal_td(), U, status)
    assert n_held == 2
    np.testing.assert_allclose(np.sqrt(np.diag(C_base)[:2]), [2e-3, 2e-3], rtol=1e-3)
    assert C_base[2, 2] < 1e-10  # no turn about the vertical


def test_platkit_diagnose_names_the_tilt_and_keeps_it_in_calibration_yaml(tmp_path):
    s = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--out", str(s), "--effect", "base_tilt=6", "--imu", "--poses", "40",
                 "--plan", "random", "--seed", "3", "--imu-bias", ",".join(str(b) for b in BIAS)]) == 0
    truth = np.array(yaml.safe_load((s / "truth_imu.yaml").read_text())["base_tilt_rad"])
    assert np.linalg.norm(truth) == pytest.approx(6e-3)
    assert main(["calibrate", str(s), "--out", str(tmp_path / "cal"), "--quiet"]) == 0
    assert main(["diagnose", str(s), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                 "--out", str(tmp_path / "d"), "--quiet"]) == 0
    out = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    tilt = [f for f in out["findings"] if f["effect"] == "base_tilt"]
    assert len(tilt) == 1 and tilt[0]["where"]["from"] == "accelerometer"
    f = tilt[0]
    assert set(f["parameters"]) == {"tilt_x", "tilt_y", "tilt"}
    for c, v in zip("xy", truth * DEG):
        assert abs(f["parameters"][f"tilt_{c}"]["value"] - v) < 3 * f["parameters"][f"tilt_{c}"]["std"]
    rows = out["imu"]["tests"][0]["candidates"]
    assert any(r["effect"] == "base_tilt" and r["accepted"] for r in rows)
    assert out["imu"]["accelerometer"]["unit"] == "m/s^2" and out["imu"]["model_frame"]["held_parameters"] > 0
    assert "base_tilt" in out["imu"]["verdict"]
    # the motion capture cannot see it (the geometry absorbs a tilt on this plan): only the
    # accelerometer names it
    assert [f for f in out["findings"] if f["effect"] == "base_tilt" and f["where"].get("from") != "accelerometer"] == []
    cal = read_calibration(tmp_path / "d" / "calibration.yaml")
    w = cal.imu["base_tilt"]["rotation_vector"]
    assert w[:2] == pytest.approx([f["parameters"]["tilt_x"]["value"] / DEG, f["parameters"]["tilt_y"]["value"] / DEG])
    assert "m/s^2" in (tmp_path / "d" / "report.html").read_text()


def test_calibration_yaml_keeps_the_imu_block_and_names_a_bad_one(tmp_path):
    from platkit.errors import BadInput

    spec = get_platform("psvr")
    cal = calibrate(simulate(spec, seed=1, n_poses=20, raw=False).poses, spec)
    cal.imu = {"base_tilt": {"rotation_vector": [0.001, -0.002, 0.0]}}
    path = tmp_path / "calibration.yaml"
    path.write_text(cal.to_yaml())
    assert read_calibration(path).imu == cal.imu
    data = yaml.safe_load(path.read_text())
    data["imu"] = [1, 2]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(BadInput, match=r"calibration.yaml: field 'imu' must be a mapping"):
        read_calibration(path)
