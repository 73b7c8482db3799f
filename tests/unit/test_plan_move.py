"""`platkit plan --move` (issue 24): a plan that moves only the controls named (names or shell-style
patterns) and holds every other at its home (its neutral, or the middle of its stroke less the
margin where the neutral lies on or outside it), the file still carrying every control, and the
prediction told with them held.

The tree is tests/data/trees/two_arm_torso.urdf (a torso yaw and pitch, a head that moves no
marker, two 3-joint arms), both hands tracked."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from platkit.calibrate import plan as pl
from platkit.cli import main
from platkit.plugins import get_platform

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
LINKS = "right_tcp,left_tcp"
STAND = ["--platform", "urdf", "--moving-link", LINKS]


def _read(path: Path) -> tuple[list[str], np.ndarray]:
    header = path.read_text().splitlines()[0].split(",")
    return header, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_optimal_plan_moves_the_arms_and_holds_the_torso_at_home(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    assert main(["plan", *STAND, "--description", str(URDF), "--optimal", "16", "--candidates", "80",
                 "--move", "right_*, left_*", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    header, U = _read(out)
    spec = get_platform("urdf", URDF, moving_link={k: k for k in LINKS.split(",")})
    assert header == spec.control_names  # every control is a column, the held ones too
    for name in ("torso_yaw", "torso_pitch", "head_yaw"):
        assert np.all(U[:, header.index(name)] == 0.0)  # neutral 0 inside the box: home is neutral
    for name in header[3:]:
        assert np.ptp(U[:, header.index(name)]) > 0.3
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["move"] == header[3:] and report["held"] == {"torso_yaw": 0.0, "torso_pitch": 0.0, "head_yaw": 0.0}
    assert "holds 3 at home: torso_yaw, torso_pitch, head_yaw" in printed
    # told at the reference poses with the torso held (over poses that move it, a plan that never
    # moves the torso leaves its geometry unfixed): every hand's directions seen, a finite prediction
    assert report["plan"]["identifiable"] and report["plan"]["predicted_marker_rms_m"] > 0
    assert all(v["identifiable"] for v in report["plan"]["links"].values())


def test_grid_moves_only_the_controls_named():
    spec = get_platform("urdf", URDF, moving_link={k: k for k in LINKS.split(",")})
    moving = np.array([n.startswith("right_") for n in spec.control_names])
    held = pl.held_at_home(spec, moving, 0.1)
    U = pl.grid_points(spec, 3, 0.1, held)
    assert U.shape == (27, spec.n_u)  # 3 values of each of the 3 controls moved
    assert np.all(U[:, ~moving] == held[1][~moving])
    assert np.all(np.abs(np.diff(U[:, moving], axis=0)) .astype(bool).sum(axis=1) == 1)  # still a snake path


def test_held_joint_whose_zero_is_a_limit_sits_mid_stroke_in_a_motion(tmp_path, capsys):
    """right_2_joint's stroke made [0, 1.5] (as Talos' elbows) and held: at the middle of [0.15, 1.35]
    in every row; the torso and head held at neutral; the arms moved; the held controls' response is
    no column of the prediction."""
    text = URDF.read_text()
    old = '<origin xyz="0 0 -0.25"/><axis xyz="1 0 0"/><limit lower="-1.5" upper="1.5" effort="50" velocity="1"/>'
    urdf = tmp_path / "elbow.urdf"
    urdf.write_text(text.replace(old, old.replace('lower="-1.5"', 'lower="0"'), 1))
    out = tmp_path / "session" / "commands.csv"
    assert main(["plan", *STAND, "--description", str(urdf), "--motion", "--max-accel", "2", "--duration-s", "20",
                 "--family", "fourier", "--period-s", "8", "--harmonics", "3", "--evaluations", "8",
                 "--move", "right_1_joint,right_3_joint,left_*", "--quiet", "--out", str(out)]) == 0
    header, U = _read(out)
    assert header[0] == "t" and header[1:] == ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint",
                                                "right_3_joint", "left_1_joint", "left_2_joint", "left_3_joint"]
    assert np.all(U[:, header.index("right_2_joint")] == pytest.approx(0.75))
    for name in ("torso_yaw", "torso_pitch", "head_yaw"):
        assert np.all(U[:, header.index(name)] == 0.0)
    for name in ("right_1_joint", "right_3_joint", "left_1_joint", "left_2_joint", "left_3_joint"):
        assert np.ptp(U[:, header.index(name)]) > 0.3
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["held"]["right_2_joint"] == pytest.approx(0.75)
    assert "not moved by the plan" in report["limits"]["source"]["held"]
    std = report["prediction"]["parameter_std"]
    assert not any(n.startswith("response.") and n.split(".")[-1] in ("right_2_joint", "torso_yaw") for n in std)
    assert any(n.startswith("response.") and n.endswith(".left_2_joint") for n in std)
    assert all(v["marker_rms_m"] > 0 for v in report["prediction"]["links"].values())


@pytest.mark.parametrize("move, expected", [
    ("arm_*", "--move: 'arm_*' is not a control of the urdf stand"),
    ("right_1_joint,nope", "--move: 'nope' is not a control of the urdf stand"),
    (" , ", "--move: no control named"),
    ("head_*", "--move 'head_*': moves no control that moves a tracked link (right_tcp, left_tcp)"),
    ("right_1_joint,,left_1_joint", "--move 'right_1_joint,,left_1_joint': an empty name between commas"),
])
def test_bad_move_is_one_line_naming_the_option_and_name(tmp_path, capsys, move, expected):
    out = tmp_path / "p" / "plan.csv"
    assert main(["plan", *STAND, "--description", str(URDF), "--grid", "2", "--move", move, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0]
    assert not out.exists()
