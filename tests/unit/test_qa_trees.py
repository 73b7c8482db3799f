"""Trees (issue 24) as a new user meets them from the command line: a link's mass negative or
absurd refused in one line by every verb (calibrate accepted it, diagnose refused it later naming
a joint); fk's link quaternions written like every other pose's (w >= 0); reports per tracked
link in report.html and diagnosis.json; a joint below a recorded one that commands.csv leaves out
said as a warning (it was held at zero silently, its load on the joints above it with it). The
tree and its helpers are test_urdf_tree's."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from test_urdf_tree import MAPPING, MARKERS, URDF, commands, observe, tree_spec, true_td, write_session

from platkit.cli import main
from platkit.urdf import link_pose_function


def _session(tmp_path, n=24, columns=None, seed=7):
    spec = tree_spec()
    rng = np.random.default_rng(seed)
    U = commands(spec, n, rng)
    return write_session(tmp_path / "s", spec, U, observe(spec, true_td(spec, rng), U, rng), columns)


@pytest.mark.parametrize("mass", ["-1.5", "2e6", "nan"])
def test_a_link_mass_negative_or_absurd_is_refused_in_one_line_by_every_verb(tmp_path, capsys, mass):
    session = _session(tmp_path)
    urdf = session / "robot.urdf"
    urdf.write_text(URDF.read_text().replace('<link name="left_2"><inertial><origin xyz="0 0 -0.12"/><mass value="1.5"/>',
                                             f'<link name="left_2"><inertial><origin xyz="0 0 -0.12"/><mass value="{mass}"/>'))
    expected = "robot.urdf: link 'left_2' <inertial> <mass value"
    out = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not out.exists()
    assert main(["fk", "--platform", "urdf", "--description", str(urdf), "--moving-link", "right_tcp,left_tcp",
                 "--u", ",".join(["0.1"] * 9)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err


def test_fk_writes_every_link_quaternion_with_w_nonnegative(capsys):
    spec = tree_spec()
    links = ["right_tcp", "left_tcp", "head"]
    f = link_pose_function(spec, links)
    rng = np.random.default_rng(3)
    # controls where some link's quaternion comes out of the kinematics with w < 0
    for _ in range(200):
        u = commands(spec, 1, rng)[0]
        q = np.asarray(f(u, spec.nominal_td())[0]).reshape(-1, 4)
        if np.any(q[:, 0] < 0):
            break
    assert np.any(q[:, 0] < 0)
    assert main(["fk", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
                 "--u", ",".join(format(v, ".17g") for v in u), "--link", "head", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    for k, link in enumerate(links):
        got = np.array([out["links"][link][a] for a in ("qw", "qx", "qy", "qz")])
        assert got[0] >= 0 and np.allclose(got, q[k] * np.sign(q[k, 0] or 1.0), atol=1e-12)
    # the moving frame's pose and its link's entry are the same numbers
    assert all(out[a] == pytest.approx(out["links"]["right_tcp"][a], abs=1e-12) for a in ("qw", "qx", "qy", "qz"))


def test_reports_of_a_tree_give_each_tracked_link_and_say_a_joint_left_out(tmp_path, capsys):
    """report.html of a tree named no link; diagnosis.json had no per-link figure. And head_yaw,
    which hangs on the torso and moves no tracked link, may be left out of commands.csv, but it is
    then held at zero and the torso's gravity load is computed with it there: it was silent; now
    said, in report.json and report.html, by calibrate and diagnose alike."""
    spec = tree_spec()
    session = _session(tmp_path, n=30, columns=[c for c in spec.control_names if c != "head_yaw"])
    cal = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-selection", "--out", str(cal)]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "head_yaw" in line]
    assert len(said) == 1 and said[0].startswith("platkit: warning: ") and "commands.csv: not recorded" in said[0]
    text = said[0].removeprefix("platkit: warning: ")
    report = json.loads((cal / "report.json").read_text())
    page = (cal / "report.html").read_text()
    assert text in report["warnings"] and "head_yaw" in page
    # the reports name the description as calibration.yaml does: the copy beside them, which travels
    assert report["description"] == "description/robot.urdf" and (cal / report["description"]).is_file()
    assert "description description/robot.urdf;" in page
    per_link = report["rms_after_per_link"]
    assert "<h2>Tracked links</h2>" in page and "each in its link's frame" in page
    for link in ("right_tcp", "left_tcp"):
        markers = ", ".join(m for m, (lk, _) in MARKERS.items() if lk == link)
        assert f"<td>{link}</td><td>{markers}</td><td>{per_link[link]:.4g}</td>" in page
    assert "<td>L2</td><td>left_tcp</td>" in page  # each marker with its link
    diag = tmp_path / "diag"
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--quiet",
                 "--out", str(diag)]) == 0
    d = json.loads((diag / "diagnosis.json").read_text())
    assert text in d["warnings"]
    assert list(d["rms_per_link"]) == ["right_tcp", "left_tcp"]
    for link, v in d["rms_per_link"].items():
        assert v["geometric"] == pytest.approx(per_link[link], rel=1e-6) and v["final"] > 0
        assert f"<td>{link}</td><td>{v['geometric']:.4g}</td>" in (diag / "report.html").read_text()
    # every joint recorded: nothing said
    capsys.readouterr()
    full = _session(tmp_path / "full", n=24)
    assert main(["calibrate", str(full), "--quiet", "--no-report", "--no-selection", "--out", str(tmp_path / "c2")]) == 0
    assert "not recorded" not in capsys.readouterr().err


def test_simulate_a_humanoid_without_plan_takes_random_poses_and_says_so(tmp_path, capsys):
    """PAL's Talos (example-robot-data, not written here): 32 recorded joints, too many for even a
    grid of two values each; simulate's default plan was refused ("no grid with 5 reachable
    points"), now random poses, said on stderr. An explicit --plan grid is still refused."""
    from importlib import metadata

    urdf = metadata.distribution("example-robot-data").locate_file(
        "cmeel.prefix/share/example-robot-data/robots/talos_data/robots/talos_reduced.urdf")
    base = ["simulate", "--platform", "urdf", "--description", str(urdf), "--moving-link",
            "gripper_left_base_link,gripper_right_base_link", "--poses-only", "--poses", "5", "--seed", "3"]
    assert main(base + ["--out", str(tmp_path / "s")]) == 0
    err = capsys.readouterr().err
    assert "no grid with 5 reachable points" in err and "random poses instead (--plan random)" in err
    assert len((tmp_path / "s" / "poses.csv").read_text().splitlines()) == 6
    assert main(base + ["--plan", "grid", "--out", str(tmp_path / "g")]) == 1
    assert not (tmp_path / "g").exists() or not any((tmp_path / "g").iterdir())


def test_predict_says_which_joint_columns_it_ignores(tmp_path, capsys):
    """predict reads the controls (and t) of a commands file and lets other columns be; a column
    naming a mimic joint or a joint the calibration does not record was ignored silently (calibrate
    refuses a mimic column): now said, once per kind, and the prediction is the same."""
    spec = tree_spec()
    session = _session(tmp_path, n=20, columns=[c for c in spec.control_names if c != "head_yaw"])
    cal = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    lines = (session / "commands.csv").read_text().splitlines()
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(lines) + "\n")
    odd = tmp_path / "odd.csv"
    odd.write_text("\n".join([lines[0] + ",torso_pitch_2,head_yaw"] + [r + ",0.3,0.4" for r in lines[1:]]) + "\n")
    capsys.readouterr()
    assert main(["predict", "--calibration", str(cal / "calibration.yaml"), "--commands", str(plain),
                 "--out", str(tmp_path / "p1.csv")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["predict", "--calibration", str(cal / "calibration.yaml"), "--commands", str(odd),
                 "--out", str(tmp_path / "p2.csv")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2, err
    assert "column 'torso_pitch_2' (a mimic joint of 'torso_pitch'): ignored" in err[0]
    assert "column 'head_yaw': a joint of the URDF that the calibration does not record: ignored" in err[1]
    assert (tmp_path / "p1.csv").read_text() == (tmp_path / "p2.csv").read_text()


def test_describe_a_tree_names_its_tracked_links_and_mimic_joints(tmp_path, capsys):
    """describe on a tree said neither the links it tracks nor the joints that follow another (a
    mimic coupling across the arms here), and its columns ran out of line with a URDF's long names."""
    urdf = tmp_path / "cross.urdf"
    urdf.write_text(URDF.read_text().replace(
        '<joint name="left_3_joint" type="revolute"><parent link="left_2"/><child link="left_3"/>',
        '<joint name="left_3_joint" type="revolute"><parent link="left_2"/><child link="left_3"/>'
        '<mimic joint="right_3_joint" multiplier="-1" offset="0.1"/>'))
    args = ["describe", "--platform", "urdf", "--description", str(urdf), "--moving-link", "right_tcp,left_tcp"]
    assert main(args) == 0
    text = capsys.readouterr().out.splitlines()
    assert "tracked links: right_tcp, left_tcp (the pose is the first's)" in text
    assert "  mimic joint left_3_joint = -1 * right_3_joint + 0.1" in text
    assert "  mimic joint torso_pitch_2 = 0.5 * torso_pitch + 0" in text
    params = [line for line in text if line.startswith("  ") and " origin" in line and "." in line.split()[0]]
    assert len({line.index(" mm ") if " mm " in line else line.index(" rad ") for line in params}) == 1  # one column
    assert main(args + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["tracked_links"] == ["right_tcp", "left_tcp"]
    assert {"joint": "left_3_joint", "master": "right_3_joint", "multiplier": -1.0, "offset": 0.1} in out["mimic_joints"]
    assert "left_3_joint" not in [c["name"] for c in out["controls"]]


def test_ik_on_a_tree_gives_the_joints_off_the_moving_link_at_neutral_and_says_so(capsys):
    """ik on a tree solves for the moving link (the first tracked); the other arm and the head were
    left wherever the solver put them (at a stroke's end, some), with nothing said."""
    chain = ["--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp"]
    u = [0.2, 0.1, 0.4, 0.3, -0.2, 0.5, -0.6, 0.7, 0.3]
    assert main(["fk", *chain, "--u", ",".join(map(str, u)), "--json"]) == 0
    fk = json.loads(capsys.readouterr().out)
    pose = ",".join(repr(fk[k]) for k in ("x", "y", "z", "qw", "qx", "qy", "qz"))
    assert main(["ik", *chain, "--pose", pose, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    spec = tree_spec()
    off = ["head_yaw", "left_1_joint", "left_2_joint", "left_3_joint"]
    assert all(out["controls"][n] == 0.0 for n in off)  # their neutral
    assert any(f"the 4 joints that do not move it ({', '.join(off)}) are given at their neutral" in w
               for w in out["warnings"])
    assert any("9 controls for 6 pose coordinates" in w for w in out["warnings"])
    u_ik = [out["controls"][n] for n in spec.control_names]
    assert main(["fk", *chain, "--u", ",".join(map(repr, u_ik)), "--json"]) == 0
    back = json.loads(capsys.readouterr().out)
    assert [back[k] for k in ("x", "y", "z")] == pytest.approx([fk[k] for k in ("x", "y", "z")], abs=1e-6)


def test_fk_with_the_wrong_count_of_controls_names_them_in_order(capsys):
    """A tree's controls are its recorded joints depth-first: a count mismatch now says which, in
    which order (it said only '--u: expected 9 numbers, got 2')."""
    assert main(["fk", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
                 "--u", "0,0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(
        "--u: expected 9 numbers, got 2 (torso_yaw, torso_pitch, head_yaw, right_1_joint, right_2_joint, "
        "right_3_joint, left_1_joint, left_2_joint, left_3_joint, in this order)"), err


def test_a_mapping_in_the_description_yaml_serves_the_session_in_calibrate_and_diagnose(tmp_path, capsys):
    """The urdf stand's YAML description may map markers to links (moving_link: {R1: right_tcp,
    ...}); a session naming that description without a mapping of its own was fitted with every
    marker on the first link (on Talos: 564 -> 285 mm, exit 0), and diagnose did the same. The
    description's mapping now serves the session, and its recorded joints are the controls."""
    session = _session(tmp_path, n=24)
    (session / "robot.yaml").write_text(yaml.safe_dump({"urdf": "robot.urdf", "moving_link": MAPPING}))
    y = yaml.safe_load((session / "session.yaml").read_text())
    y.update(description="robot.yaml", moving_link=None)
    (session / "session.yaml").write_text(yaml.safe_dump(y, sort_keys=False))
    cal = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    report = json.loads((cal / "report.json").read_text())
    assert report["rms_after"] < 0.2 and set(report["rms_after_per_link"]) == {"right_tcp", "left_tcp"}
    assert yaml.safe_load((cal / "calibration.yaml").read_text())["markers"]["L2"]["link"] == "left_tcp"
    diag = tmp_path / "diag"
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--quiet",
                 "--out", str(diag)]) == 0
    d = json.loads((diag / "diagnosis.json").read_text())
    assert d["rms_geometric"] == pytest.approx(report["rms_after"], rel=1e-6)


def test_diagnose_refuses_a_session_that_maps_a_marker_to_another_link_than_the_calibration(tmp_path, capsys):
    """diagnose kept the calibration's link for a marker that session.yaml maps elsewhere, and said
    nothing of the session's mapping: now one line naming the file, the marker and both links."""
    session = _session(tmp_path, n=20)
    cal = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    y = yaml.safe_load((session / "session.yaml").read_text())
    y["moving_link"]["L1"] = "right_tcp"
    (session / "session.yaml").write_text(yaml.safe_dump(y, sort_keys=False))
    capsys.readouterr()
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--quiet",
                 "--out", str(tmp_path / "diag")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "session.yaml: field 'moving_link' maps 'L1' to 'right_tcp', the calibration" in err[0] \
        and "to 'left_tcp'" in err[0], err
    assert not (tmp_path / "diag").exists()
