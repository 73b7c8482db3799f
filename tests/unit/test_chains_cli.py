"""`platkit track`: targets, trees, trajectories, units, failures and bad input."""
import csv
import json

import numpy as np
import pytest
from reference_robots import example_robot_urdf

from platkit.chains import KinematicChain
from platkit.cli import main
from platkit.geometry import matrix_from_rpy, rotvec_from_matrix

UR5 = str(example_robot_urdf("ur_description/urdf/ur5_robot.urdf"))
TALOS = str(example_robot_urdf("talos_data/robots/talos_reduced.urdf"))


@pytest.fixture(scope="module")
def ur5():
    return KinematicChain.from_urdf(UR5)


def _read(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], np.array([[float(v) for v in r] for r in rows[1:]])


def test_target_reached_and_path_written(tmp_path, ur5, capsys):
    out = tmp_path / "joints.csv"
    rc = main(["track", "--urdf", UR5, "--link", "tool0", "--target", "0.3,0.2,0.4,3.0,0.1,-0.4", "--out", str(out)])
    assert rc == 0
    header, rows = _read(out)
    assert header == ["step"] + ur5.joint_names
    assert np.array_equal(rows[:, 0], np.arange(len(rows)))
    assert np.allclose(rows[0, 1:], ur5.mid_range())
    P = ur5.placement(rows[-1, 1:], "tool0")
    assert np.linalg.norm(P[:3, 3] - [0.3, 0.2, 0.4]) <= 1e-6
    assert np.linalg.norm(rotvec_from_matrix(matrix_from_rpy(3.0, 0.1, -0.4) @ P[:3, :3].T)) <= 1e-6
    text = capsys.readouterr().out
    assert text.startswith("reached tool0: position error ") and "iterations" in text


def test_json_mm_and_position_only(tmp_path, ur5, capsys):
    out = tmp_path / "j.csv"
    rc = main(["track", "--urdf", UR5, "--link", "tool0", "--target", "300,-200,500", "--unit", "mm",
               "--tol-pos", "0.001", "--out", str(out), "--json"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert report["converged"] and report["unit"] == "mm"
    assert report["position_errors"][0] <= 0.001
    theta = np.array([report["final_joints"][n] for n in ur5.joint_names])
    assert np.linalg.norm(ur5.placement(theta, "tool0")[:3, 3] - [0.3, -0.2, 0.5]) <= 1e-6


def test_unreachable_target_exits_1_with_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "j.csv"
    rc = main(["track", "--urdf", UR5, "--link", "tool0", "--target", "2,0,0.4", "--out", str(out)])
    assert rc == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert err.startswith("platkit: error: link 'tool0' did not reach its target: closest ")
    assert "reaches at most" in err
    assert not out.exists()


@pytest.mark.parametrize("argv, expected", [
    (["--link", "nope", "--target", "1,2,3"], "no link named 'nope'"),
    (["--link", "tool0", "--target", "1,2"], "--target: expected x,y,z"),
    (["--link", "tool0", "--target", "0.3,0.2,0.4", "--select", "xq"], "--select: unknown component"),
    (["--link", "tool0", "--target", "0.3,0.2,0.4", "--q0", "1,2"], "--q0: expected 6 numbers"),
    (["--link", "tool0", "--target", "0.3,0.2,0.4", "--q0", "elbow_joint=9"], "--q0 joint 'elbow_joint': 9 is past the limit"),
    (["--link", "tool0", "--link", "wrist_1_link", "--target", "0.3,0.2,0.4"], "--target: one per --link (2), got 1"),
    (["--link", "tool0", "--target", "0.3,0.2,0.4", "--lock", "knee"], "locked joints not in the chain: knee"),
])
def test_bad_input_exits_2_naming_the_option(tmp_path, capsys, argv, expected):
    rc = main(["track", "--urdf", UR5, "--out", str(tmp_path / "j.csv")] + argv)
    assert rc == 2
    err = capsys.readouterr().err
    assert expected in err and err.count("\n") == 1


def test_trajectory_file(tmp_path, ur5):
    theta = np.array([0.2, -1.2, 1.4, -0.8, -1.5, 0.3])
    P = ur5.placement(theta, "tool0")
    traj = tmp_path / "traj.csv"
    x, y, z = P[:3, 3]
    traj.write_text("t,x,y,z\n" f"0,{x},{y},{z}\n" f"1,{x + 0.05},{y},{z}\n" f"3,{x + 0.05},{y + 0.05},{z - 0.02}\n")
    out = tmp_path / "path.csv"
    rc = main(["track", "--urdf", UR5, "--link", "tool0", "--trajectory", str(traj), "--out", str(out),
               "--q0", ",".join(map(str, theta))])
    assert rc == 0
    header, rows = _read(out)
    assert header[0] == "t" and rows[0, 0] == 0.0 and rows[-1, 0] == 3.0
    tips = np.array([ur5.placement(r[1:], "tool0")[:3, 3] for r in rows])
    assert np.max(np.linalg.norm(np.diff(tips, axis=0), axis=1)) <= 0.005 + 1e-6
    assert np.linalg.norm(tips[-1] - [x + 0.05, y + 0.05, z - 0.02]) <= 1e-6
    i1 = int(np.flatnonzero(rows[:, 0] == 1.0)[0])
    assert np.linalg.norm(tips[i1] - [x + 0.05, y, z]) <= 1e-6


def test_bad_trajectory_names_row_and_column(tmp_path, capsys):
    traj = tmp_path / "traj.csv"
    traj.write_text("t,x,y,z\n0,0.3,0.2,0.4\n1,0.3,oops,0.4\n")
    rc = main(["track", "--urdf", UR5, "--link", "tool0", "--trajectory", str(traj), "--out", str(tmp_path / "o.csv")])
    assert rc == 2
    assert "traj.csv row 2 (line 3) column 'y': expected a number, got 'oops'" in capsys.readouterr().err


def test_two_arms_of_a_tree_at_once(tmp_path):
    talos = KinematicChain.from_urdf(TALOS)
    locked = ",".join(n for n in talos.joint_names if not n.startswith(("arm", "torso")))
    out = tmp_path / "both.csv"
    rc = main(["track", "--urdf", TALOS, "--link", "gripper_left_base_link", "--target", "0.35,0.25,0.0",
               "--link", "gripper_right_base_link", "--target", "0.35,-0.25,0.0", "--lock", locked,
               "--base", "torso_2_link", "--out", str(out), "--restarts", "3"])
    assert rc == 0
    header, rows = _read(out)
    theta = rows[-1, 1:]
    for link, goal in (("gripper_left_base_link", [0.35, 0.25, 0.0]), ("gripper_right_base_link", [0.35, -0.25, 0.0])):
        rel = talos.relative_placement(theta, link, "torso_2_link")
        assert np.linalg.norm(rel[:3, 3] - goal) <= 1e-6


def test_quaternion_trajectory_and_secondary_cost_report(tmp_path, ur5, capsys):
    theta = np.array([0.2, -1.2, 1.4, -0.8, -1.5, 0.3])
    P = ur5.placement(theta, "tool0")
    from platkit.geometry import quat_from_matrix

    q = quat_from_matrix(P[:3, :3])
    x, y, z = P[:3, 3]
    traj = tmp_path / "q.csv"
    traj.write_text("t,x,y,z,qw,qx,qy,qz\n" f"0,{x},{y},{z},{q[0]},{q[1]},{q[2]},{q[3]}\n"
                    f"0.5,{x},{y},{z + 0.02},{q[0]},{q[1]},{q[2]},{q[3]}\n")
    out = tmp_path / "q_path.csv"
    assert main(["track", "--urdf", UR5, "--link", "tool0", "--trajectory", str(traj), "--out", str(out),
                 "--q0", ",".join(map(str, theta))]) == 0
    _, rows = _read(out)
    last = ur5.placement(rows[-1, 1:], "tool0")
    assert np.linalg.norm(last[:3, 3] - [x, y, z + 0.02]) <= 1e-6
    assert np.linalg.norm(rotvec_from_matrix(last[:3, :3] @ P[:3, :3].T)) <= 1e-6
    capsys.readouterr()
    # position only on a 6-joint arm leaves 3 free directions: manipulability rises in them
    assert main(["track", "--urdf", UR5, "--link", "tool0", "--target", "0.3,0.2,0.4", "--secondary",
                 "manipulability", "--out", str(tmp_path / "m.csv"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["refine_iterations"] > 0
    assert report["secondary_cost"] < report["secondary_cost_before"]
