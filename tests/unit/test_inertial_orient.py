"""platkit orient end to end on a simulated Stewart session with an IMU, and its bad inputs."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from platkit.cli import main
from platkit.geometry import matrix_from_rpy
from platkit.inertial.command_aided import estimate_timing
from platkit.inertial.simulate import platform_imu_session, write_platform_imu_session
from platkit.io.imu import ImuStream
from platkit.plugins import get_platform
from platkit.simulate import perturb_parameters

LAG_S, MOVE_S = 0.08, 1.0
R_SP = matrix_from_rpy(0.03, -0.02, 0.5)
BIAS = [0.01, -0.005, 0.003, 0.05, -0.03, 0.02]


@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    spec = get_platform("stewart")
    rng = np.random.default_rng(7)
    td_true = perturb_parameters(spec, rng, 0.2)
    sim = platform_imu_session(spec, td_true, spec.nominal_td(), rng, n_commands=16, rate_hz=100.0,
                               move_s=MOVE_S, lag_s=LAG_S, imu_from_platform=R_SP, bias=BIAS,
                               noise=[0.003, 0.03], lever_arm=[0.3, 0.2, 0.1])
    folder = tmp_path_factory.mktemp("imu") / "session"
    write_platform_imu_session(sim, spec, folder, {"gyr_bias_rad_s": BIAS[:3], "sensor_from_platform": R_SP})
    return folder, sim


def _copy(folder, tmp_path):
    dst = tmp_path / "s"
    shutil.copytree(folder, dst)
    return dst


def test_command_aided_beats_the_unaided_estimator(sim_session, tmp_path):
    folder, _ = sim_session
    reports = {}
    for method in ("command-aided", "platkit", "paper"):
        out = tmp_path / method
        assert main(["orient", str(folder), "--method", method, "--out", str(out)]) == 0
        reports[method] = json.loads((out / "report.json").read_text())
        lines = (out / "orientation.csv").read_text().splitlines()
        assert lines[0] == "t,qw,qx,qy,qz" and len(lines) == reports[method]["n_samples"] + 1
        assert (out / "report.html").read_text().count("<svg ") == 2
    ca, pk = reports["command-aided"], reports["platkit"]
    assert ca["truth"]["total_rmse_deg"] < 0.15
    assert ca["truth"]["total_rmse_deg"] < 0.5 * pk["truth"]["total_rmse_deg"]
    assert pk["truth"]["inclination_rmse_deg"] < 1.0
    assert reports["paper"]["truth"]["inclination_rmse_deg"] < 2.0
    # the misalignment and the bias the session itself gives
    assert ca["truth_imu"]["alignment_error_deg"] < 0.2
    assert np.max(np.abs(ca["truth_imu"]["gyr_bias_error_deg_s"])) < 0.02


def test_latency_is_measured(sim_session):
    folder, sim = sim_session
    imu = ImuStream(sim["t"], sim["gyr"], sim["acc"])
    timing = estimate_timing(imu, sim["t_cmd"], sim["q_cmd"], BIAS[:3])
    # onset = 5 % and end = 95 % of a minimum-jerk move (at 0.2 and 0.8 of its duration) after the lag
    assert timing.lag_s == pytest.approx(LAG_S + 0.21 * MOVE_S, abs=0.04)
    assert timing.settle_s == pytest.approx(LAG_S + 0.79 * MOVE_S, abs=0.06)


def test_bad_imu_cell_is_one_line_and_writes_nothing(sim_session, tmp_path, capsys):
    folder = _copy(sim_session[0], tmp_path)
    lines = (folder / "imu.csv").read_text().splitlines()
    cells = lines[10].split(",")
    cells[3] = "oops"
    lines[10] = ",".join(cells)
    (folder / "imu.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert main(["orient", str(folder), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "line 11, column 'gyr_z': expected a number, got 'oops'" in err
    assert not out.exists()


def test_repairs_are_reported(sim_session, tmp_path):
    folder = _copy(sim_session[0], tmp_path)
    lines = (folder / "imu.csv").read_text().splitlines()
    cells = lines[500].split(",")
    cells[5] = ""
    lines[500] = ",".join(cells)
    (folder / "imu.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert main(["orient", str(folder), "--method", "platkit-causal", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert any("'acc_y': 1 missing values" in w and "line 501" in w for w in report["warnings"])


def test_command_aided_needs_commands(sim_session, tmp_path, capsys):
    folder = _copy(sim_session[0], tmp_path)
    (folder / "commands.csv").unlink()
    assert main(["orient", str(folder), "--method", "command-aided", "--out", str(tmp_path / "o")]) == 2
    assert "needs a session with a platform and commands.csv" in capsys.readouterr().err


def test_missing_imu_and_bad_truth(sim_session, tmp_path, capsys):
    folder = _copy(sim_session[0], tmp_path)
    truth = (folder / "truth_orientation.csv").read_text().splitlines()
    truth[3] = truth[3].rsplit(",", 1)[0] + ",2.0"
    (folder / "truth_orientation.csv").write_text("\n".join(truth) + "\n")
    assert main(["orient", str(folder), "--method", "platkit-causal", "--out", str(tmp_path / "o")]) == 2
    assert "truth_orientation.csv row 3 (line 4)" in capsys.readouterr().err
    (folder / "imu.csv").unlink()
    assert main(["orient", str(folder), "--out", str(tmp_path / "o")]) == 2
    assert "imu.csv: file not found" in capsys.readouterr().err


def test_imu_only_session_in_milliseconds(tmp_path):
    """platform: null, time in ms: the sensor frame is the platform frame, heading relative."""
    from platkit.geometry import quat_from_rpy
    from platkit.inertial.simulate import imu_from_motion
    from platkit.io.imu import write_imu_csv

    t = np.arange(0, 40, 0.01)
    on = t > 8
    q = quat_from_rpy(0.2 * np.sin(0.9 * t) * on, 0.15 * np.sin(0.7 * t) * on, 0.3 * t * on)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[0.01, 0.0, -0.01, 0, 0, 0],
                          noise=[0.002, 0.02], rng=np.random.default_rng(3))
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "session.yaml").write_text("platform: null\nunits: {length: m, time: ms}\nimu: {rate_hz: 100}\n")
    write_imu_csv(folder / "imu.csv", t * 1000.0, sim["gyr"], sim["acc"])
    (folder / "truth_orientation.csv").write_text(
        "t,qw,qx,qy,qz\n" + "\n".join(f"{ti * 1000:.6f},{a:.10f},{b:.10f},{c:.10f},{d:.10f}"
                                        for ti, (a, b, c, d) in zip(t, q)) + "\n")
    out = tmp_path / "o"
    assert main(["orient", str(folder), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["rate_hz"] == pytest.approx(100.0)
    assert report["truth"]["inclination_rmse_deg"] < 0.2
    assert report["truth"]["total_rmse_heading_aligned_deg"] < 0.5
    assert report["gyr_bias_source"] == "first rest of the recording"
    assert any("sensor axes are taken as the platform axes" in w for w in report["warnings"])
    rows = np.loadtxt(out / "orientation.csv", delimiter=",", skiprows=1)
    assert rows[-1, 0] == pytest.approx(t[-1])  # seconds in the output
    assert main(["orient", str(folder), "--method", "command-aided", "--out", str(out)]) == 2


def test_commands_that_never_move_the_platform(sim_session, tmp_path, capsys):
    """Unaided methods go on without the commands (and say so); command-aided fails (exit 1)."""
    folder = _copy(sim_session[0], tmp_path)
    lines = (folder / "commands.csv").read_text().splitlines()
    first = lines[1].split(",", 1)[1]
    lines = [lines[0]] + [f"{row.split(',', 1)[0]},{first}" for row in lines[1:]]
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "o"
    assert main(["orient", str(folder), "--method", "platkit-causal", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert any("no command turned the platform enough" in w for w in report["warnings"])
    assert report["heading"].startswith("relative")
    assert main(["orient", str(folder), "--method", "command-aided", "--out", str(tmp_path / "o2")]) == 1
    assert "no command turned the platform enough" in capsys.readouterr().err


def test_level_base_takes_the_tilt_from_a_calibrated_accelerometer(tmp_path):
    """With the accelerometer calibrated and the base level, the holds' accelerometer tilt
    replaces the nominal model's (here off by the full perturbation of a real stand): the
    inclination error drops."""
    import yaml

    from platkit.inertial.calibration import ImuCalibration

    spec = get_platform("stewart")
    rng = np.random.default_rng(11)
    td_true = perturb_parameters(spec, rng, 1.0)
    sim = platform_imu_session(spec, td_true, spec.nominal_td(), rng, n_commands=12, rate_hz=100.0,
                               imu_from_platform=R_SP, bias=BIAS, noise=[0.003, 0.03])
    folder = write_platform_imu_session(sim, spec, tmp_path / "s")
    cal = ImuCalibration(gyr_bias=np.array(BIAS[:3]), acc_bias=np.array(BIAS[3:]), sensor_from_platform=R_SP)
    (tmp_path / "imu.yaml").write_text(yaml.safe_dump(cal.to_dict()))
    errs = {}
    for extra in ([], ["--level-base"]):
        out = tmp_path / ("lvl" if extra else "plain")
        assert main(["orient", str(folder), "--method", "command-aided", "--imu-calibration", str(tmp_path / "imu.yaml"),
                     "--out", str(out)] + extra) == 0
        report = json.loads((out / "report.json").read_text())
        errs[bool(extra)] = report["truth"]["inclination_rmse_deg"]
        assert report["estimator"]["tilt_from_accelerometer"]["used"]
        # the bias is reported in raw sensor units: the calibration's plus what the run found
        assert np.allclose(report["gyr_bias_end_rad_s"], BIAS[:3], atol=np.radians(0.02))
    assert errs[True] < 0.5 * errs[False]


def test_session_from_platkit_simulate_with_the_imu_hook(tmp_path):
    """platkit.simulate's imu hook takes imu_for_trajectory; its moves have different lengths
    and a settling wiggle, and the platform moves most of the time: every move is still timed
    and command aiding beats the unaided estimate."""
    from platkit.inertial.simulate import imu_for_trajectory
    from platkit.simulate import simulate, write_session

    sim = simulate(get_platform("stewart"), seed=2, n_poses=10,
                   imu=imu_for_trajectory(rate_hz=100.0, bias=[0.01, 0, 0, 0.05, 0, 0], noise=[0.002, 0.02]))
    folder = write_session(sim, tmp_path / "s")
    t, q = sim.imu["t"], sim.imu["q_base_from_platform"]
    (folder / "truth_orientation.csv").write_text(
        "t,qw,qx,qy,qz\n" + "\n".join(f"{a:.6f},{b[0]:.10f},{b[1]:.10f},{b[2]:.10f},{b[3]:.10f}" for a, b in zip(t, q)) + "\n")
    reports = {}
    for method in ("command-aided", "platkit"):
        assert main(["orient", str(folder), "--method", method, "--out", str(tmp_path / method)]) == 0
        reports[method] = json.loads((tmp_path / method / "report.json").read_text())
    assert reports["command-aided"]["timing"]["n_moves"] >= len(sim.command_t) - 2
    assert reports["command-aided"]["truth"]["total_rmse_deg"] < 0.5 * reports["platkit"]["truth"]["total_rmse_deg"]


def test_a_first_command_far_from_where_the_recording_starts(tmp_path):
    """The platform rests at the neutral pose until the first command and then makes a long move
    (2 s: half a stroke) to it, the later moves short (0.3 s). The first move is timed from the
    gyro (it is no step between commands: its start is no command's pose), so the gyro bias is
    not read while the platform turns; command aiding starts at the first hold's pose and
    integrates the gyro back from there. Before, the hold of the first command began after the
    median settling time (0.5 s) and command aiding started at the first command's pose at t = 0:
    total RMSE 8.0 deg (platkit), 5.0 deg (command-aided)."""
    first = [3401.265, 4687.730, 3931.397, 4210.550, 3298.741, 4209.152]  # x, y, z = 0, 0, 3000 mm, rpy 0.15, -0.1, 0.25
    rng = np.random.default_rng(0)
    rows = [first] + [np.clip(np.array(first) + rng.uniform(-40, 40, 6), 3300, 4790).tolist() for _ in range(9)]
    plan = tmp_path / "plan.csv"
    plan.write_text("L1,L2,L3,L4,L5,L6\n" + "\n".join(",".join(f"{v:.3f}" for v in r) for r in rows) + "\n")
    session = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--plan", str(plan), "--imu", "--out", str(session)]) == 0
    total = {}
    for method in ("platkit", "command-aided"):
        assert main(["orient", str(session), "--method", method, "--out", str(tmp_path / method)]) == 0
        total[method] = json.loads((tmp_path / method / "report.json").read_text())["truth"]["total_rmse_deg"]
    assert total["platkit"] < 1.0 and total["command-aided"] < 0.2, total


def test_declared_full_scale_flags_saturation(sim_session, tmp_path):
    import yaml

    folder = _copy(sim_session[0], tmp_path)
    y = yaml.safe_load((folder / "session.yaml").read_text())
    y["imu"]["acc_range_m_s2"] = 9.9  # a sensor that clips just above 1 g
    (folder / "session.yaml").write_text(yaml.safe_dump(y))
    out = tmp_path / "o"
    assert main(["orient", str(folder), "--method", "platkit-causal", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert any("of acc_z at the sensor's clipping limit" in w for w in report["warnings"])
