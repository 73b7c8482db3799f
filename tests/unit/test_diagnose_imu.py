"""Gyro diagnosis (platkit.diagnose.imu): a drifting bias and a misaligned IMU are named, with
their parameters; a clean IMU gives no finding. Simulated stewart sessions (60 random commands,
the IMU through platkit.simulate's ``imu=`` hook), calibrated on their own poses."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import calibrate
from platkit.cli import main
from platkit.diagnose.imu import diagnose_imu, td_covariance
from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_rotvec
from platkit.inertial.simulate import imu_for_trajectory
from platkit.io.imu import ImuStream
from platkit.plugins import effect_library, get_platform
from platkit.simulate import simulate

DEG = 180.0 / np.pi
#: a constant gyro bias in every case (rad/s): normal, never a finding
BIAS = [0.003, -0.002, 0.001, 0.0, 0.0, 0.0]
#: the misalignment's floor: smaller is not named (the registered effect's own)
MIN_ANGLE_DEG = effect_library()["imu_misalignment"].min_size
#: the misaligned sensor: R_SP = exp([ROTVEC]x), 2.2 deg
ROTVEC = np.array([0.02, -0.03, 0.015])


def _session(seed: int, n_poses: int = 60, **imu_kw):
    spec = get_platform("stewart")
    sim = simulate(spec, seed=seed, n_poses=n_poses, plan="random", imu=imu_for_trajectory(bias=BIAS, **imu_kw))
    return spec, sim


def _diagnose(seed: int, **imu_kw):
    spec, sim = _session(seed, **imu_kw)
    cal = calibrate(sim.poses, spec)
    im = sim.imu
    d = diagnose_imu(spec, cal.td, sim.command_t, sim.commands, ImuStream(im["t"], im["gyr"], im["acc"]),
                     td_cov=td_covariance(cal), td_status=cal.td_status)
    return sim, d


@pytest.fixture(scope="module")
def drift():
    return _diagnose(1, bias_drift=3e-4)  # random walk, rad/s/sqrt(s): 0.4-0.6 deg/s over the session


@pytest.fixture(scope="module")
def misaligned():
    return _diagnose(1, imu_from_platform=matrix_from_rotvec(ROTVEC))


def test_a_drifting_bias_is_named_with_its_slope(drift):
    sim, d = drift
    assert [f["effect"] for f in d.findings] == ["gyro_bias_drift"]
    f = d.findings[0]
    # the truth: the least-squares line through the bias actually applied, over the segments
    seg, t, b = d.segments, sim.imu["t"], sim.imu["gyr_bias"]
    m = (t >= seg.t_mid[0]) & (t <= seg.t_mid[-1])
    slope = np.polyfit(t[m] - seg.t_c, b[m], 1)[0] * DEG * 60.0  # deg/s per min
    for c, s in zip("xyz", slope):
        p = f["parameters"][f"drift_{c}"]
        assert p["unit"] == "deg/s per min"
        assert abs(p["value"] - s) < 3 * p["std"] + 0.005, (c, p, s)
    assert f["heldout_rms_after"] < 0.7 * f["heldout_rms_before"]
    assert f["unit"] == "deg/s" and f["p_heldout"] < 0.05 and "deg/s" in f["evidence"]


def test_a_misaligned_imu_is_named_with_its_rotation(misaligned):
    _, d = misaligned
    assert [f["effect"] for f in d.findings] == ["imu_misalignment"]
    f = d.findings[0]
    # within 0.1 deg per axis: the gyro is compared with the calibrated model's platform frame,
    # itself turned 0.06 deg against the true one here (see MIN_ANGLE_DEG)
    for c, v in zip("xyz", ROTVEC * DEG):
        assert f["parameters"][f"angle_{c}"]["value"] == pytest.approx(v, abs=0.1)
        assert 0 < f["parameters"][f"angle_{c}"]["std"] < 0.05
    assert f["parameters"]["angle"]["value"] == pytest.approx(np.linalg.norm(ROTVEC) * DEG, abs=0.1)
    assert f["heldout_rms_after"] < 0.2 * f["heldout_rms_before"]
    # the constant bias is the base model's, recovered, not a finding
    np.testing.assert_allclose(d.final.b0, BIAS[:3], atol=2e-4)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_clean_imu_gives_no_finding(seed):
    _, d = _diagnose(seed)
    assert d.findings == []
    assert "no gyro effect found" in d.verdict
    np.testing.assert_allclose(d.final.b0, BIAS[:3], atol=2e-4)
    rows = {r["effect"]: r for r in d.tests[0]["candidates"]}
    assert set(rows) == {"gyro_bias_drift", "imu_misalignment", "base_tilt"}
    assert not any(r["accepted"] for r in rows.values())
    # what the gyro sees of the model's frame is below the floor (and far below a real misalignment)
    assert rows["imu_misalignment"]["size"] < MIN_ANGLE_DEG
    # the accelerometer's tilt was tested (the platform turns enough) and is within what the frame allows
    assert rows["base_tilt"]["separability"] > 0.05 and not rows["base_tilt"].get("not_separable")
    assert "no base tilt" in d.verdict


def test_too_few_holds_is_not_identifiable():
    spec, sim = _session(1, n_poses=6)
    im = sim.imu
    with pytest.raises(NotIdentifiable, match="holds"):
        diagnose_imu(spec, sim.truth.td, sim.command_t, sim.commands, ImuStream(im["t"], im["gyr"], im["acc"]))


def test_platkit_diagnose_adds_the_imu_findings_to_diagnosis_json(tmp_path):
    """`platkit simulate --effect imu_misalignment=2.2 --imu` hides the IMU effect through its
    plugin; `platkit diagnose` names it in diagnosis.json and report.html."""
    assert main(["simulate", "--platform", "stewart", "--out", str(tmp_path / "s"), "--effect", "imu_misalignment=2.2",
                 "--imu", "--poses", "40", "--plan", "random", "--seed", "1",
                 "--imu-bias", ",".join(str(b) for b in BIAS)]) == 0
    truth = yaml.safe_load((tmp_path / "s" / "truth_imu.yaml").read_text())["effects"]["imu_misalignment"]
    assert np.linalg.norm(truth) * DEG == pytest.approx(2.2)
    # the calibration's report.html is not read here (test_diagnose_imu_tilt.py renders one of an IMU session)
    assert main(["calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "cal"), "--quiet", "--no-report"]) == 0
    assert main(["diagnose", str(tmp_path / "s"), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                 "--out", str(tmp_path / "d"), "--quiet"]) == 0
    out = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    imu = [f for f in out["findings"] if f["effect"] in ("gyro_bias_drift", "imu_misalignment")]
    assert [f["effect"] for f in imu] == ["imu_misalignment"]
    f = imu[0]
    for key in ("where", "parameters", "heldout_rms_before", "heldout_rms_after", "evidence"):
        assert key in f
    assert f["unit"] == "deg/s" and f["heldout_rms_after"] < f["heldout_rms_before"]
    assert set(f["parameters"]["angle"]) == {"value", "std", "unit"}
    assert out["imu"]["unit"] == "deg/s" and "IMU:" in out["verdict"]
    assert "imu_misalignment" in (tmp_path / "d" / "report.html").read_text()
