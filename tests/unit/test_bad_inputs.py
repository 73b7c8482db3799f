"""Bad inputs the sweep (benchmarks/bad_inputs_sweep.py) found answered wrongly, one test per class
of fix: a quaternion that is not unit, clocks that do not overlap, an IMU rate the times
contradict, a track start just past a joint limit; and the warnings of simulate, plan and track in
the files (or the JSON object) they write, not on stderr only."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.errors import BadSession
from platkit.io.imu import read_imu_csv
from platkit.io.session import example_session
from platkit.notices import units_checked

#: the real TIAGo's URDF in the shared data beside the checkout (tests/conftest.py says in one line when it is absent)
TIAGO_URDF = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("platkit: error: ")
    return lines[0]


# ------------------------------------------------------------------ a quaternion that is not unit
def test_ik_refuses_a_quaternion_that_is_not_unit_and_takes_one_to_four_decimals(capsys):
    assert main(["ik", "--platform", "stewart", "--pose", "0,0,3700,2,0,0,0"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--pose: the quaternion qw,qx,qy,qz has norm 2, expected 1 (within 0.001)" in line
    # 4 decimals of a 90 deg yaw (norm 0.99998) are a unit quaternion
    assert main(["ik", "--platform", "stewart", "--pose", "0,0,3700,0.7071,0,0,0.7071", "--json"]) in (0, 1)
    assert "norm" not in capsys.readouterr().err


# ------------------------------------------------------------------ clocks that do not overlap
def test_a_stream_on_another_clock_than_the_commands_is_refused_naming_both_files(tmp_path, capsys):
    s = tmp_path / "s"
    shutil.copytree(example_session("rotary"), s)
    with (s / "markers.csv").open(newline="") as fh:
        rows = list(csv.reader(fh))
    for r in rows[1:]:
        r[0] = f"{float(r[0]) + 1e4:.6f}"
    (s / "markers.csv").write_text("\n".join(",".join(r) for r in rows) + "\n")
    assert main(["calibrate", str(s), "--out", str(tmp_path / "out"), "--no-selection", "--no-report", "--quiet"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "markers.csv: column 't' runs from 10000 to" in line
    assert "commands.csv's from 0.5 to" in line and "the two clocks do not overlap" in line
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------ an IMU rate the times contradict
def _write_imu(path, rate_hz: float, n: int = 400) -> None:
    rng = np.random.default_rng(0)
    t = np.arange(n) / rate_hz
    gyr = rng.normal(0, 0.01, (n, 3))
    acc = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    lines = ["t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [
        ",".join(f"{v:.6f}" for v in (ti, *g, *a)) for ti, g, a in zip(t, gyr, acc)]
    path.write_text("\n".join(lines) + "\n")


def test_an_imu_rate_the_times_contradict_by_more_than_twice_is_refused_as_mocap_rate_hz_is(tmp_path):
    p = tmp_path / "imu.csv"
    _write_imu(p, 200.0)
    assert read_imu_csv(p, declared_rate_hz=390.0).n == 400  # within a factor 2: kept
    with pytest.raises(BadSession, match=r"imu.csv: column 't': the median time step is 0.005 s \(200 Hz\) but "
                                         r"session.yaml declares the IMU at rate_hz 600.*correct the imu entry's "
                                         r"rate_hz or the times; if the file is right as written, run again with "
                                         r"--units-checked"):
        read_imu_csv(p, declared_rate_hz=600.0)
    with units_checked():
        stream = read_imu_csv(p, declared_rate_hz=600.0)
    assert any("rate_hz 600" in n and "--units-checked" in n for n in stream.notes)


# ------------------------------------------------------------------ track: a start just past a limit
def test_track_q0_just_past_a_joint_limit_is_a_warning_in_the_json_further_a_refusal(tmp_path, capsys):
    args = ["track", "--urdf", str(TIAGO_URDF), "--link", "arm_tool_link", "--target", "0.6,0.2,0.8", "--json"]
    # arm_1_joint's range is [0, 2.74889357189] rad: the recording tolerance is 0.0275 rad
    assert main(args + ["--out", str(tmp_path / "a.csv"), "--q0", "arm_1_joint=2.7631"]) == 0
    cap = capsys.readouterr()
    (w,) = json.loads(cap.out)["warnings"]
    assert w.startswith("--q0 joint 'arm_1_joint': 2.7631 is past the limit 2.74889 rad by 0.0142 rad")
    assert "within the recording tolerance (0.0275 rad, 1% of the range" in w
    assert cap.err.strip() == f"platkit: warning: {w}"
    assert main(args + ["--out", str(tmp_path / "b.csv"), "--q0", "arm_1_joint=3.0"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "--q0 joint 'arm_1_joint': 3 is past the limit 2.74889 rad by 0.251 rad" in line
    assert "more than the recording tolerance (0.0275 rad" in line
    assert not (tmp_path / "b.csv").exists()
    assert main(args + ["--out", str(tmp_path / "c.csv")]) == 0  # inside the limits: nothing said
    assert json.loads(capsys.readouterr().out)["warnings"] == []


# ------------------------------------------------------------------ simulate and plan: warnings in what they write
def test_simulate_keeps_its_warnings_in_session_yaml_notes(tmp_path, capsys):
    plan = tmp_path / "plan.csv"
    plan.write_text("L1,L2,L3,L4,L5,L6\n" + "4045,4045,4045,4045,4045,4045\n"
                    + "4802.5,4045,4045,4045,4045,4045\n" + "4045,4045,4045,4045,4045,4045\n")
    assert main(["simulate", "--platform", "stewart", "--plan", str(plan), "--poses-only", "--out",
                 str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    said = [ln.removeprefix("platkit: warning: ") for ln in err.splitlines() if ln.startswith("platkit: warning: ")]
    assert said and any("plan.csv row 2 (line 3) column 'L1': 4802.5 is past the limit 4795 mm by 7.5 mm" in w
                        for w in said)
    notes = yaml.safe_load((tmp_path / "s" / "session.yaml").read_text())["notes"]
    assert notes.startswith("simulated by platkit (seed 0); the true stand is in truth.yaml; warning: ")
    assert all(f"warning: {w}" in notes for w in said)
    # a clean run's notes are as before
    assert main(["simulate", "--platform", "stewart", "--poses", "6", "--poses-only", "--out", str(tmp_path / "c")]) == 0
    assert yaml.safe_load((tmp_path / "c" / "session.yaml").read_text())["notes"] == \
        "simulated by platkit (seed 0); the true stand is in truth.yaml"


def test_plan_json_lists_every_warning_said_while_planning(tmp_path, monkeypatch, capsys):
    import platkit.calibrate.plan as pl
    from platkit.notices import warn

    evaluate = pl.evaluate_plan

    def evaluate_and_warn(*a, **k):  # a warning said deep inside the verb, as any library code says one
        warn("a caveat said while planning")
        return evaluate(*a, **k)

    monkeypatch.setattr(pl, "evaluate_plan", evaluate_and_warn)
    assert main(["plan", "--platform", "rotary", "--grid", "3", "--out", str(tmp_path / "plan.csv")]) == 0
    assert capsys.readouterr().err.strip() == "platkit: warning: a caveat said while planning"
    assert json.loads((tmp_path / "plan.json").read_text())["warnings"] == ["a caveat said while planning"]
    monkeypatch.setattr(pl, "evaluate_plan", evaluate)
    assert main(["plan", "--platform", "rotary", "--grid", "3", "--out", str(tmp_path / "p2.csv")]) == 0
    assert json.loads((tmp_path / "p2.json").read_text())["warnings"] == []


# ------------------------------------------------------------------ a mimic joint whose master is missing
def test_track_refuses_a_mimic_joint_whose_master_the_urdf_lacks_as_the_urdf_stand_does(tmp_path, capsys):
    tag = '<joint name="arm_3_joint" type="revolute">'
    text = TIAGO_URDF.read_text()
    assert tag in text
    urdf = tmp_path / "robot.urdf"
    urdf.write_text(text.replace(tag, tag + '<mimic joint="nosuch_joint"/>', 1))
    out = tmp_path / "path.csv"
    assert main(["track", "--urdf", str(urdf), "--link", "arm_tool_link", "--target", "0.6,0.2,0.8",
                 "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert line == f"platkit: error: {urdf}: joint 'arm_3_joint' <mimic joint='nosuch_joint'> names no joint of the file"
    assert not out.exists()
    assert main(["fk", "--platform", "urdf", "--description", str(urdf), "--moving-link", "arm_tool_link",
                 "--u", "0,0,0,0,0,0,0,0"]) == 2
    assert "joint 'arm_3_joint' <mimic joint='nosuch_joint'> names no joint of the file" in capsys.readouterr().err


# ------------------------------------------------------------------ a command log sparser than the motion
def test_a_command_log_missing_every_second_command_is_warned_of_in_report_json(tmp_path, capsys):
    s = tmp_path / "s"
    shutil.copytree(example_session("rotary"), s)
    lines = (s / "commands.csv").read_text().splitlines()
    (s / "commands.csv").write_text("\n".join(lines[:1] + lines[1::2]) + "\n")
    assert main(["calibrate", str(s), "--out", str(tmp_path / "out"), "--no-selection", "--no-report", "--quiet"]) == 0
    warnings = json.loads((tmp_path / "out" / "report.json").read_text())["warnings"]
    (w,) = [w for w in warnings if "far above any measurement noise" in w]
    assert "that the command log holds every command sent" in w
    assert f"platkit: warning: {w}" in capsys.readouterr().err


# ------------------------------------------------------------------ fk: warnings in its JSON object
def test_fk_json_lists_the_warning_of_a_control_just_past_its_limit(capsys):
    assert main(["fk", "--platform", "rotary", "--u", "181.8,0", "--json"]) == 0
    cap = capsys.readouterr()
    (w,) = json.loads(cap.out)["warnings"]
    assert w.startswith("rotary: control u1: 181.8 is past the limit 180 deg by 1.8 deg; kept as recorded")
    assert cap.err.strip() == f"platkit: warning: {w}"
    assert main(["fk", "--platform", "rotary", "--u", "90,0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []
