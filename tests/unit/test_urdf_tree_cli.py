"""Trees (issue 24) from the command line: a tree session calibrated, its results moved and
predicting; bad tree sessions one line each; a joint just past its limit warned alike in every
verb; fk per link. The tree and its helpers are test_urdf_tree's."""
from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml
from test_urdf_tree import MAPPING, MARKERS, SIGMA, URDF, commands, observe, tree_spec, true_td, write_session

from platkit.calibrate.problem import link_frames
from platkit.cli import main
from platkit.geometry import matrix_from_quat
from platkit.io.calibration import read_calibration
from platkit.plugins import get_platform


def test_cli_tree_session_calibrates_and_the_moved_results_still_predict(tmp_path, capsys):
    spec = tree_spec()
    rng = np.random.default_rng(21)
    td = true_td(spec, rng)
    U = commands(spec, 70, rng)
    Y = observe(spec, td, U, rng)
    session = write_session(tmp_path / "session", spec, U, Y)
    out = tmp_path / "results"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    data = yaml.safe_load((out / "calibration.yaml").read_text())
    import json

    per_link = json.loads((out / "report.json").read_text())["rms_after_per_link"]
    assert list(per_link) == ["right_tcp", "left_tcp"] and all(v < 0.2 for v in per_link.values())
    assert data["description"] == "description/robot.urdf"  # relative to calibration.yaml, copied beside it
    assert data["markers"]["L2"]["link"] == "left_tcp" and data["platform_options"]["moving_link"] == MAPPING
    # the session and its URDF gone, the results folder moved: it still predicts
    shutil.rmtree(session)
    moved = tmp_path / "elsewhere" / "sent"
    moved.parent.mkdir()
    shutil.move(str(out), str(moved))
    cmd = tmp_path / "cmd.csv"
    cmd.write_text(",".join(spec.control_names) + "\n"
                   + "\n".join(",".join(format(v, ".12g") for v in u) for u in U[:5]) + "\n")
    pred = tmp_path / "pred.csv"
    assert main(["predict", "--calibration", str(moved / "calibration.yaml"), "--commands", str(cmd),
                 "--out", str(pred)]) == 0
    lines = pred.read_text().splitlines()
    header = lines[0].split(",")
    got = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    P = got[:, [header.index(f"{m}_{a}") for m in MARKERS for a in "xyz"]].reshape(5, len(MARKERS), 3)
    assert np.max(np.linalg.norm(P - Y[:5] * 1e3, axis=2)) < 10 * SIGMA * 1e3
    cal = read_calibration(moved / "calibration.yaml")
    # the other hand's pose after the moving frame's: the frame its markers are predicted from
    X_left = got[:, [header.index(f"left_tcp_{a}") for a in "xyz"]]
    R_left = matrix_from_quat(got[:, [header.index(f"left_tcp_{a}") for a in ("qw", "qx", "qy", "qz")]])
    k = cal.marker_names.index("L2")
    L2 = (X_left + np.einsum("nab,b->na", R_left, cal.marker_positions[k] * 1e3)) @ cal.mocap_from_base[:3, :3].T \
        + cal.mocap_from_base[:3, 3] * 1e3
    assert np.allclose(L2, P[:, list(MARKERS).index("L2")], atol=1e-5)
    assert cal.marker_links == MAPPING and cal.spec.tracked_links == ["right_tcp", "left_tcp"]


@pytest.mark.parametrize("change, expected", [
    ("mapping", "moving_link 'no_hand' is not a link of the URDF"),
    ("missing", "commands.csv: missing column 'left_2_joint': joint 'left_2_joint' moves the tracked link 'left_tcp'"),
    ("extra", "commands.csv: column 'gripper' is no joint of the URDF"),
    ("mimic", "commands.csv: column 'torso_pitch_2' is a mimic joint of 'torso_pitch': it follows its master"),
    ("unmapped", "field 'moving_link' maps markers to links but not 'L3'"),
])
def test_bad_tree_sessions_are_one_line(tmp_path, capsys, change, expected):
    spec = tree_spec()
    rng = np.random.default_rng(5)
    U = commands(spec, 12, rng)
    Y = observe(spec, spec.nominal_td(), U, rng)
    columns = list(spec.control_names)
    mapping = dict(MAPPING)
    if change == "mapping":
        mapping["L1"] = "no_hand"
    elif change == "missing":
        columns.remove("left_2_joint")
    elif change == "extra":
        columns.append("gripper")
    elif change == "mimic":
        columns.append("torso_pitch_2")
    elif change == "unmapped":
        del mapping["L3"]
    session = write_session(tmp_path / "s", spec, U, Y, columns, mapping)
    out = tmp_path / "out"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not out.exists()


def test_fk_gives_every_tracked_link_and_any_link_asked(capsys):
    import json

    u = "0,0.1,0.2,0.3,-0.2,0.1,-0.3,0.2,0.1"
    assert main(["fk", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
                 "--u", u, "--link", "head", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out["links"]) == ["right_tcp", "left_tcp", "head"]
    spec = get_platform("urdf", URDF, moving_link={"right_tcp": "right_tcp", "left_tcp": "left_tcp"})
    _, X = link_frames(spec, spec.nominal_td(), np.array([[float(v) for v in u.split(",")]]))
    assert np.allclose([out["links"]["left_tcp"][a] for a in "xyz"], X[0, 1] * 1e3, atol=1e-9)
    assert out["x"] == pytest.approx(out["links"]["right_tcp"]["x"])
    assert main(["fk", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
                 "--u", u, "--link", "nowhere"]) == 2
    assert "link 'nowhere' is not a link of the URDF" in capsys.readouterr().err


def test_a_joint_reading_just_past_its_limit_warns_alike_in_calibrate_and_predict(tmp_path, capsys):
    """A tree joint read 0.5 % of its stroke past its limit (within the recording tolerance) is kept
    with the one warning of platkit.limits, in calibrate and in predict."""
    spec = tree_spec()
    rng = np.random.default_rng(31)
    U = commands(spec, 40, rng)
    j = spec.control_names.index("left_1_joint")
    U[5, j] = spec.controls[j].upper + 0.005 * (spec.controls[j].upper - spec.controls[j].lower)
    session = write_session(tmp_path / "s", spec, U, observe(spec, spec.nominal_td(), U, rng))
    out = tmp_path / "cal"
    assert main(["calibrate", str(session), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if "left_1_joint" in line]
    assert len(said) == 2  # commands.csv, then poses.csv, each says it
    said = [line for line in said if "commands.csv" in line]
    assert len(said) == 1 and "kept as recorded" in said[0] and "past the limit 2" in said[0]
    cmd = tmp_path / "cmd.csv"
    cmd.write_text(",".join(spec.control_names) + "\n" + ",".join(format(v, ".12g") for v in U[5]) + "\n")
    assert main(["predict", "--calibration", str(out / "calibration.yaml"), "--commands", str(cmd),
                 "--out", str(tmp_path / "p.csv")]) == 0
    again = [line for line in capsys.readouterr().err.splitlines() if "left_1_joint" in line]
    assert len(again) == 1 and again[0].split(": ", 1)[1].split("kept as recorded")[0].split(" is past")[1] \
        == said[0].split(": ", 1)[1].split("kept as recorded")[0].split(" is past")[1]


def test_simulate_a_tree_then_calibrate_it(tmp_path, capsys):
    """`platkit simulate --moving-link a,b --poses-only` writes a tree session (markers on every
    tracked link, by default 3 on each as plan places them, the mapping in session.yaml) that
    calibrate fits to its noise (rigid bodies on a simulated tree: test_simulate_tree_bodies.py; its
    raw streams: test_tree_stream.py)."""
    folder = tmp_path / "sim"
    base = ["simulate", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
            "--seed", "3"]
    assert main(base + ["--out", str(folder), "--poses-only"]) == 0
    mapping = yaml.safe_load((folder / "session.yaml").read_text())["moving_link"]
    assert sorted(mapping.values()) == ["left_tcp"] * 3 + ["right_tcp"] * 3
    out = tmp_path / "cal"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    rms = yaml.safe_load((out / "calibration.yaml").read_text())["residual"]["rms_after"]
    assert rms < truth["marker_noise_m"] * 1e3  # below one sample's noise per axis: the settled poses average many


def test_a_comma_list_of_links_from_python_says_a_tree_is_a_mapping():
    """get_platform(..., moving_link='a,b') (the command line's form, given from Python) is one
    line saying how a tree's tracked links are given, not only that 'a,b' is no link."""
    from platkit.errors import BadInput

    with pytest.raises(BadInput, match=r"a mapping .*moving_link=\{'right_tcp': 'right_tcp', 'left_tcp': 'left_tcp'\}"):
        get_platform("urdf", URDF, moving_link="right_tcp, left_tcp")


def test_the_papers_method_on_a_tree_is_refused_in_one_line(tmp_path, capsys):
    """--method paper fits one rigid marker frame: on a tree its markers ride on several links, so
    it is refused before any work (it ran its whole Nelder-Mead budget from a registration 0.68 m
    off and said 'raise --max-evaluations')."""
    spec = tree_spec()
    rng = np.random.default_rng(26200)
    U = commands(spec, 20, rng)
    session = write_session(tmp_path / "session", spec, U, observe(spec, true_td(spec, rng), U, rng))
    assert main(["calibrate", str(session), "--method", "paper", "--max-evaluations", "40", "--quiet",
                 "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "--method paper fits one rigid frame to every marker" in err and "2 links (left_tcp, right_tcp)" in err
