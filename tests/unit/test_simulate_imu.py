"""platkit simulate --imu: an inertial stream on the moving part, with the truth files that
platkit orient scores against (truth_orientation.csv, truth_imu.yaml)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.errors import BadInput
from platkit.inertial.orient import read_truth_imu, read_truth_orientation
from platkit.inertial.simulate import imu_for_trajectory
from platkit.io.session import load_session
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.simulate import simulate, write_session

#: gyro x, y, z (rad/s: 0.57, -0.29, 0.17 deg/s), accelerometer x, y, z (m/s^2)
BIAS = [0.01, -0.005, 0.003, 0.05, 0.0, 0.0]


@pytest.fixture(scope="module")
def imu_session(tmp_path_factory):
    out = tmp_path_factory.mktemp("imu") / "s"
    code = main(["simulate", "--platform", "stewart", "--out", str(out), "--poses", "8", "--rate-hz", "30",
                 "--imu", "--imu-bias", ",".join(str(b) for b in BIAS)])
    assert code == 0
    return out


def test_the_session_declares_and_holds_the_stream(imu_session):
    y = yaml.safe_load((imu_session / "session.yaml").read_text())
    assert y["imu"] == {"rate_hz": 200.0, "frame": "imu"}  # --imu alone: 200 Hz
    s = load_session(imu_session)
    assert s.platform == "stewart" and s.imu_stream.rate_hz == pytest.approx(200.0, rel=1e-9)
    assert s.imu_stream.repairs == []
    assert s.imu_t[0] == 0.0 and s.imu_t[-1] > s.command_t[-1]  # the stream covers the whole session
    # truth_orientation.csv: one row per IMU sample, on the same timestamps
    t_true, q_true = read_truth_orientation(imu_session / "truth_orientation.csv")
    np.testing.assert_array_equal(t_true, s.imu_t)
    # truth_imu.yaml: the errors given on the command line, the sensor on the platform's axes
    truth = read_truth_imu(imu_session / "truth_imu.yaml")
    np.testing.assert_allclose(truth["gyr_bias_rad_s"], BIAS[:3])
    np.testing.assert_allclose(truth["acc_bias_m_s2"], BIAS[3:])
    np.testing.assert_allclose(truth["sensor_from_platform"], np.eye(3))
    assert yaml.safe_load((imu_session / "truth.yaml").read_text())["imu"]["gyr_bias_rad_s"] == BIAS[:3]


def test_truth_orientation_is_the_platform_in_the_base_frame(imu_session):
    """At the end of every hold the platform has settled on the true stand's forward kinematics
    of the command: the truth file is q_base_from_platform, not the sensor's or the inverse."""
    spec = get_platform("stewart")
    s = load_session(imu_session)
    td = np.array([v["value"] for v in yaml.safe_load((imu_session / "truth.yaml").read_text())["parameters"].values()])
    t_true, q_true = read_truth_orientation(imu_session / "truth_orientation.csv")
    ends = np.append(s.command_t[1:], s.imu_t[-1]) - 0.05
    k = np.searchsorted(t_true, ends)
    fb = PlatformModel(spec).forward_batch(s.commands, td=td)
    dots = np.abs(np.sum(q_true[k] * fb.q, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-9)  # same rotation, to 1e-4 rad or better
    assert np.degrees(2 * np.arccos(np.min(np.abs(fb.q[:, 0])))) > 5  # and the platform really turns


def test_orient_recovers_the_truth(imu_session, tmp_path):
    """platkit orient on the simulated session: its report scores against the truth files.
    Tolerances: total orientation error RMSE below 1 deg while the platform turns about 10 deg
    RMS (0.4 to 0.65 deg over seeds 0-3: the stand is the nominal model, the truth is not),
    and the final gyro bias within 0.02 deg/s of the true 0.57, -0.29, 0.17 deg/s."""
    out = tmp_path / "o"
    assert main(["orient", str(imu_session), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    n = len(load_session(imu_session).imu_t)
    assert report["n_samples"] == n and report["truth"]["n_samples"] == n
    assert report["truth"]["total_rmse_deg"] < 1.0
    assert report["truth"]["inclination_rmse_deg"] < 1.0
    assert report["truth"]["heading_reference"] == "absolute"
    assert np.all(np.abs(report["truth_imu"]["gyr_bias_error_deg_s"]) < 0.02)
    rows = np.loadtxt(out / "orientation.csv", delimiter=",", skiprows=1)
    assert rows.shape == (n, 5)
    np.testing.assert_allclose(rows[:, 0], load_session(imu_session).imu_t, atol=1e-9)


def test_rate_and_noise_options(tmp_path):
    out = tmp_path / "s"
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "4", "--rate-hz", "30",
                 "--imu-rate-hz", "100", "--imu-noise", "0,0"]) == 0
    s = load_session(out)
    assert s.imu == {"rate_hz": 100.0, "frame": "imu"}
    assert s.imu_stream.rate_hz == pytest.approx(100.0, rel=1e-9)
    # no noise, no bias: at rest before the first command the sensor reads gravity exactly
    rest = s.imu_t < s.command_t[0] - 0.02  # clear of the first move (the acceleration is a central difference)
    assert rest.sum() >= 10
    np.testing.assert_allclose(s.imu_gyr[rest], 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(s.imu_acc[rest], axis=1), 9.80665, atol=1e-6)


@pytest.mark.parametrize("options,expect", [
    (["--imu", "--poses-only"], "--imu needs the simulated motion"),
    (["--imu-bias", "0.1,0.2"], "--imu-bias: expected 1 or 6 numbers"),
    (["--imu", "--imu-noise", "0.1"], "--imu-noise: expected 2 numbers"),
    (["--imu-noise", "0.1,-1"], "--imu-noise: standard deviations must be 0 or more"),
    (["--imu-rate-hz", "0"], "--imu-rate-hz must be a positive number"),
    (["--imu-bias", "a,b,c,d,e,f"], "--imu-bias: expected comma-separated numbers"),
])
def test_bad_imu_options_exit_2_and_write_nothing(tmp_path, capsys, options, expect):
    out = tmp_path / "s"
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "4"] + options) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err
    assert not out.exists()


def test_the_imu_hook_needs_the_motion():
    with pytest.raises(BadInput, match="IMU stream needs the simulated motion"):
        simulate(get_platform("psvr"), n_poses=4, raw=False, imu=imu_for_trajectory())


def test_a_hook_with_the_wrong_shapes_is_refused(tmp_path):
    def imu(trajectory, rng):
        t = np.arange(0.0, trajectory.end_t, 0.01)
        return {"t": t, "gyr": np.zeros((len(t), 3)), "acc": np.zeros((len(t), 3)),
                "q_base_from_platform": np.zeros((len(t) - 1, 4))}

    sim = simulate(get_platform("psvr"), n_poses=4, mocap_rate_hz=30, imu=imu)
    with pytest.raises(BadInput, match=r"'q_base_from_platform' of shape \(\d+, 4\), expected"):
        write_session(sim, tmp_path / "s")
    assert not (tmp_path / "s").exists()


def test_an_imu_only_copy_reads_without_a_stand_and_orients(imu_session, tmp_path):
    """The same recording as an IMU-only session (platform: none, imu.csv alone): no stand is
    built, and platkit orient runs on it with a heading relative to the start."""
    folder = tmp_path / "imu_only"
    folder.mkdir()
    y = yaml.safe_load((imu_session / "session.yaml").read_text())
    y.update(platform="none", markers=[], mocap_rate_hz=None)
    (folder / "session.yaml").write_text(yaml.safe_dump(y))
    (folder / "imu.csv").write_bytes((imu_session / "imu.csv").read_bytes())
    s = load_session(folder)
    assert s.platform is None and s.spec is None and s.commands is None and s.command_t is None
    out = tmp_path / "o"
    assert main(["orient", str(folder), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert "platform" not in report and report["heading"].startswith("relative to the start")
    assert len(np.loadtxt(out / "orientation.csv", delimiter=",", skiprows=1)) == len(s.imu_t)


def test_a_tilted_base_and_a_drifting_gyro_bias_reach_the_truth_files(tmp_path):
    """--effect base_tilt=SIZE (mrad) with --imu: the accelerometer sees the tilt and truth_imu.yaml
    carries it; a linear gyro bias drift (bias_rate) is applied and recorded; bad values named."""
    out = tmp_path / "s"
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "6", "--rate-hz", "30",
                 "--effect", "base_tilt=3", "--imu"]) == 0
    truth = read_truth_imu(out / "truth_imu.yaml")
    effect = yaml.safe_load((out / "truth.yaml").read_text())["effects"][0]
    assert effect["effect"] == "base_tilt"
    w = [effect["parameters"]["tilt_x"]["value"], effect["parameters"]["tilt_y"]["value"]]
    np.testing.assert_allclose(truth["base_tilt_rad"], w)
    assert np.linalg.norm(w) == pytest.approx(3e-3)
    spec = get_platform("psvr")
    hook = imu_for_trajectory(bias=BIAS, bias_rate=[1e-5, 0.0, -2e-5], noise=(0.0, 0.0))
    sim = simulate(spec, n_poses=4, mocap_rate_hz=30, imu=hook)
    t, b = sim.imu["t"], sim.imu["gyr_bias"]
    np.testing.assert_allclose(b, BIAS[:3] + (t - t[0])[:, None] * np.array([1e-5, 0.0, -2e-5]), atol=1e-12)
    assert sim.imu["truth_imu"]["gyr_bias_rate_rad_s2"] == [1e-5, 0.0, -2e-5]
    with pytest.raises(BadInput, match="base_tilt: expected 2 finite numbers"):
        imu_for_trajectory(base_tilt=[0.1, 0.2, 0.0])
    with pytest.raises(BadInput, match="bias_rate: expected 3 numbers"):
        simulate(spec, n_poses=4, mocap_rate_hz=30, imu=imu_for_trajectory(bias_rate=[1e-5]))
