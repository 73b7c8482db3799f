"""Rigid bodies in the physical simulator (issue 24): `platkit simulate --physics --rigid-bodies 2`
on a tree (tests/data/trees/two_arm_torso.urdf, both hands tracked) and on a Stewart stand writes
bodies T1, T2 in markers.csv, sampled with the markers from the true links' poses, that
`platkit calibrate` reads back: each body's fitted placement agrees with the truth's.

What is compared does not depend on the link frame the fit chose: every marker on the body's link
seen from the body's frame (R_body^T (m - o_body)), fitted against true. The tolerance comes from
the noise (--noise-mm 0.2, white): a settled pose averages at least 25 samples of its hold and 40
poses are fitted, so a point (a marker, a body's origin) is placed to 0.2 mm / sqrt(1000) = 0.006
mm per axis, about 0.015 mm for the difference of two points in 3 axes: 0.05 mm is three such
sigmas; a body's orientation sample has 2 mrad of noise per axis (0.2 mm over the 0.1 m lever,
platkit.simulate.physics.BODY_LEVER_M), 0.063 mrad once 1000 samples are averaged, which moves a
marker r away from the body by r times that: 0.2 mrad (three sigmas) per metre of lever. So 0.05
mm + 0.2 mrad x r. A body placed on the wrong link, or sampled from another pose than its link's,
is off by millimetres."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.geometry import matrix_from_rotvec

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
TREE = ["--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp"]
COMMON = ["--physics", "--rigid-bodies", "2", "--poses", "40", "--noise-mm", "0.2", "--white-noise", "--seed", "31"]


def _in_body(origin, rotvec, point) -> np.ndarray:
    """A point (mm) of the body's link seen from the body's frame."""
    return matrix_from_rotvec(np.asarray(rotvec, float)).T @ (np.asarray(point, float) - np.asarray(origin, float))


@pytest.mark.parametrize("stand", [TREE, ["--platform", "stewart"]], ids=["tree", "stewart"])
def test_physical_bodies_are_calibrated_back(stand, tmp_path):
    folder, out = tmp_path / "sim", tmp_path / "cal"
    assert main(["simulate", *stand, *COMMON, "--out", str(folder)]) == 0
    session = yaml.safe_load((folder / "session.yaml").read_text())
    assert session["rigid_bodies"] == ["T1", "T2"]
    header = (folder / "markers.csv").read_text().splitlines()[0].split(",")
    assert header[-14:] == [f"T{b}_{a}" for b in (1, 2) for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    mapping = session["moving_link"]
    if stand is TREE:
        assert mapping["T1"] == "right_tcp" and mapping["T2"] == "left_tcp"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert cal["residual"]["rms_after"] < 0.2  # mm: the settled noise, well under one sample's
    for body, fitted in cal["rigid_bodies"]["bodies"].items():
        true = truth["rigid_bodies"][body]
        mine = [m for m in session["markers"] if mapping is None or mapping[m] == mapping[body]]
        assert mine
        for m in mine:
            v_true = _in_body(np.array(true["position"]) * 1e3, true["rotation_vector"],
                              np.array(truth["markers"][m]) * 1e3)
            v_fit = _in_body(fitted["position"], fitted["rotation_vector"], cal["markers"][m]["position"])
            assert np.linalg.norm(v_fit - v_true) < 0.05 + 0.2e-3 * np.linalg.norm(v_true), (body, m, v_fit, v_true)


def test_physical_bodies_bad_count_is_one_line(tmp_path, capsys):
    """The refusal that stays true: a negative count, in one line, nothing written."""
    folder = tmp_path / "p"
    assert main(["simulate", "--platform", "stewart", "--physics", "--rigid-bodies", "-1", "--out", str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rigid-bodies must be 0 or more, got -1" in err[0]
    assert not folder.exists() or not any(folder.iterdir())
