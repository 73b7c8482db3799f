"""`platkit ik` on a stand with fewer than six pose coordinates refuses a pose the stand cannot
take (before: psvr printed controls for a yawed, shifted platform its cardan never allows)."""
import json
from pathlib import Path

import pytest

from platkit.cli import main


@pytest.mark.parametrize("pose", ["0,0,600,0,0,0.5", "10,0,600,0,0,0"])
def test_psvr_refuses_a_pose_off_its_coordinates(capsys, pose):
    assert main(["ik", "--platform", "psvr", "--pose", pose]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip().splitlines()
    assert len(err) == 1
    assert "psvr cannot take this pose" in err[0] and "alpha, beta, h" in err[0]
    assert "x,y,z = 0, 0, 600 mm" in err[0]


def test_psvr_fk_pose_goes_back_through_ik(capsys):
    u = [1991.415325606886, 2194.760954409563, 1953.7403037474678]
    assert main(["fk", "--platform", "psvr", "--u", ",".join(map(str, u)), "--json"]) == 0
    fk = json.loads(capsys.readouterr().out)
    pose = ",".join(str(fk[k]) for k in ("x", "y", "z", "qw", "qx", "qy", "qz"))
    assert main(["ik", "--platform", "psvr", "--pose", pose, "--json"]) == 0
    ik = json.loads(capsys.readouterr().out)
    assert [ik["controls"][n] for n in "ABC"] == pytest.approx(u, abs=1e-6)


def test_stewart_takes_any_six_dof_pose(capsys):
    assert main(["ik", "--platform", "stewart", "--pose", "100,50,3147,0.1,0.05,0.2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["controls"]["L1"] == pytest.approx(3450.891844, abs=1e-5)


TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if not TIAGO.is_file():  # the checkout beside shared/, as CI has it
    TIAGO = Path("/work/shared/data/real/tiago/tiago_48_schunk.urdf")


@pytest.mark.parametrize("u", [[100, 0.5, 0, 0, 1, 0, 0, 0], [200, 1.0, -0.5, -1, 1.5, 0.3, 0.2, 0.1]])
def test_ik_of_a_redundant_arm_finds_controls_inside_the_strokes(capsys, u):
    """TIAGo's 8-joint arm: the pose of an in-stroke configuration goes back through ik (before:
    'out of reach', arm_2_joint at -12.6 rad, a solution outside the strokes)."""
    chain = ["--platform", "urdf", "--description", str(TIAGO), "--moving-link", "wrist_ft_tool_link"]
    assert main(["fk", *chain, "--u", ",".join(map(str, u)), "--json"]) == 0
    fk = json.loads(capsys.readouterr().out)
    pose = ",".join(repr(fk[k]) for k in ("x", "y", "z", "qw", "qx", "qy", "qz"))
    assert main(["ik", *chain, "--pose", pose, "--json"]) == 0
    u_ik = list(json.loads(capsys.readouterr().out)["controls"].values())
    assert main(["fk", *chain, "--u", ",".join(map(repr, u_ik)), "--json"]) == 0
    back = json.loads(capsys.readouterr().out)
    assert [back[k] for k in ("x", "y", "z")] == pytest.approx([fk[k] for k in ("x", "y", "z")], abs=1e-6)
    assert abs(sum(back[k] * fk[k] for k in ("qw", "qx", "qy", "qz"))) == pytest.approx(1.0, abs=1e-12)
