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
