"""`platkit ik` on a stand with fewer than six pose coordinates refuses a pose the stand cannot
take (before: psvr printed controls for a yawed, shifted platform its cardan never allows)."""
import json

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
