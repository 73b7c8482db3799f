"""`platkit track --trajectory`: a rotation given in part (roll,pitch without yaw; three of the
quaternion's four) is bad input (before: silently dropped, the path followed position only)."""
import pytest

from platkit.commands.track import read_trajectory
from platkit.errors import BadInput


@pytest.mark.parametrize("header, row, message", [
    ("t,x,y,z,roll,pitch", "0,0.3,0.2,0.4,0,0", "column 'roll' without 'yaw'"),
    ("t,x,y,z,qw,qx,qy", "0,0.3,0.2,0.4,1,0,0", "column 'qw' without 'qz'"),
])
def test_a_partial_rotation_is_refused(tmp_path, header, row, message):
    path = tmp_path / "path.csv"
    path.write_text(f"{header}\n{row}\n")
    with pytest.raises(BadInput, match=message):
        read_trajectory(str(path), 1.0)


def test_a_whole_rotation_is_read(tmp_path):
    path = tmp_path / "path.csv"
    path.write_text("t,x,y,z,roll,pitch,yaw\n0,0.3,0.2,0.4,0,0,0.5\n")
    times, poses, rotation = read_trajectory(str(path), 1.0)
    assert rotation and times.tolist() == [0.0] and poses.shape == (1, 4, 4)


@pytest.mark.parametrize("body, message", [
    ("0,0.3,0.2,0.4\n1,0.3,,0.4\n", r"path.csv row 2 \(line 3\) column 'y': empty or nan"),
    ("0,0.3,0.2,0.4\n1,0.3,inf,0.4\n", r"path.csv row 2 \(line 3\) column 'y': expected a finite number"),
    ("1,0.3,0.2,0.4\n0.5,0.3,0.2,0.4\n", r"path.csv row 2 \(line 3\) column 't': times must not decrease"),
    ("0,0.3,0.2\n", r"path.csv row 1 \(line 2\): 3 cells, expected 4"),
])
def test_a_malformed_trajectory_names_row_and_column_like_every_csv(tmp_path, body, message):
    path = tmp_path / "path.csv"
    path.write_text("t,x,y,z\n" + body)
    with pytest.raises(BadInput, match=message):
        read_trajectory(str(path), 1.0)


@pytest.mark.parametrize("option, value, message", [
    ("--seed", "-1", "--seed: must be 0 or more, got -1"),
    ("--max-iterations", "0", "--max-iterations: must be 1 or more, got 0"),
])
def test_counts_out_of_range_name_the_option(tmp_path, capsys, option, value, message):
    """(before: --seed -1 was 'ValueError: expected non-negative integer', exit 1)"""
    from reference_robots import example_robot_urdf

    from platkit.cli import main

    urdf = example_robot_urdf("ur_description/urdf/ur5_robot.urdf")
    rc = main(["track", "--urdf", str(urdf), "--link", "tool0", "--target", "0.3,0.2,0.4", "--restarts", "2",
               f"{option}={value}", "--out", str(tmp_path / "j.csv")])
    assert rc == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"platkit: error: {message}"]
