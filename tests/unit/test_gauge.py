"""Gauge freedoms: what no set of poses can fix is fixed by a stated convention and reported, never
an error; what the poses fail to excite is told apart from it on the stand's reference poses, the
same way `platkit plan` decides; the translation-only gantry and a turntable go through simulate,
calibrate, predict and diagnose."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from simulated_arm import TURNTABLE
from test_estimate import Truth, prediction_error

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.identifiability import GAUGE, NOT_EXCITED, rotation_fixed_directions
from platkit.calibrate.paper import calibrate_paper
from platkit.calibrate.plan import Plan, evaluate_plan, feasible
from platkit.cli import main
from platkit.errors import BadInput, NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.poses import PoseSet

REPO = Path(__file__).resolve().parents[2]
GANTRY = REPO / "descriptions" / "gantry_xyz.urdf"


def test_the_fixed_directions_of_a_set_of_rotations():
    assert rotation_fixed_directions(np.repeat(np.eye(3)[None], 4, axis=0)).shape == (3, 3)
    turns = matrix_from_rotvec(np.outer([0.1, -0.4, 0.9], [0.0, 0.6, 0.8]))  # about one axis
    axis = rotation_fixed_directions(turns)
    assert axis.shape == (3, 1) and abs(axis[:, 0] @ [0.0, 0.6, 0.8]) == pytest.approx(1.0)
    assert rotation_fixed_directions(matrix_from_rotvec([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]])).shape == (3, 0)


def test_a_translation_only_stand_calibrates_under_the_marker_centroid_convention():
    spec = get_platform("urdf", GANTRY)
    truth = Truth(spec, seed=3, n_markers=4, marker_spread=0.05)
    cal = calibrate(truth.poses(50, 1e-4, spread=0.45), spec)
    gauge = cal.identifiability["gauge"]
    assert gauge["dimensions"] == 21 and gauge["not_excited"] == 0
    assert "markers' centroid is put at the moving frame's origin" in gauge["conventions"][0]
    # the convention holds, and costs nothing: the fit is at the noise floor
    assert cal.marker_positions.mean(axis=0) == pytest.approx(np.zeros(3), abs=1e-12)
    assert cal.rms_after < 2.2e-4  # 0.1 mm per axis: 0.17 mm 3-D
    assert np.all(np.isfinite(cal.marker_std)) and np.all(cal.marker_std < 1e-4)
    kinds = {h["name"]: h.get("kind") for h in cal.identifiability["held_at_nominal"]}
    assert set(kinds.values()) == {GAUGE} and len(kinds) == 18  # the stand's: no marker is "held at nominal"
    assert len(gauge["held_during_the_fit"]) == 3 and all(n.startswith("marker.") for n in gauge["held_during_the_fit"])
    assert prediction_error(cal, truth) < 0.05e-3  # against the noise-free truth at new commands


def test_plan_and_calibrate_agree_on_the_gantry_and_the_stewart():
    for spec, seed in ((get_platform("urdf", GANTRY), 4), (get_platform("stewart"), 5)):
        truth = Truth(spec, seed=seed, n_markers=4, marker_spread=0.05)
        poses = truth.poses(40, 1e-4, spread=0.3)
        cal = calibrate(poses, spec)
        ok, P = feasible(spec, poses.controls)
        planned = evaluate_plan(spec, Plan(poses.controls, "given", {}, P), 1e-4, n_markers=4)
        assert planned["identifiable"] is True and planned["not_excited"] == 0 == cal.identifiability["gauge"]["not_excited"]
        assert planned["never_identifiable"] == planned["gauge_dimensions"] == cal.identifiability["gauge"]["dimensions"]


def test_what_calibrate_decides_does_not_hang_on_an_earlier_calibration_with_other_marker_names(builtin_host):
    """What a calibration decides (gauge and unexcited directions) is the same whatever calibrations
    of the same stand object came before: the reference problem kept between them matches the
    unknowns by name, so one built for other marker names is not lent (it counted 3 of the
    Stewart's directions not excited, where plan and a fresh process count 0)."""
    spec = builtin_host.build("stewart")  # a stand object no other test has calibrated
    poses = Truth(spec, seed=5, n_markers=4, marker_spread=0.05).poses(40, 1e-4, spread=0.3)
    renamed = PoseSet(spec.name, poses.controls, poses.markers, ["A", "B", "C", "D"], length_unit="mm")
    counts = []
    for session in (renamed, poses):  # the same data, the markers named otherwise first
        gauge = calibrate(session, spec).identifiability["gauge"]
        counts.append((gauge["dimensions"], gauge["not_excited"]))
    assert counts == [(12, 0), (12, 0)]


def test_poses_that_do_not_excite_the_markers_are_an_error_and_plan_says_so():
    spec = get_platform("stewart")
    truth = Truth(spec, seed=6)
    poses = truth.poses(2, 1e-4)
    with pytest.raises(NotIdentifiable, match="the poses cannot fix marker.*the stand's reach would"):
        calibrate(poses, spec)
    ok, P = feasible(spec, poses.controls)
    planned = evaluate_plan(spec, Plan(poses.controls, "given", {}, P), 1e-4, n_markers=4)
    assert planned["identifiable"] is False and planned["not_excited"] > 0


def _poses_with_joints_held(spec, truth, held):
    U = truth.controls(40, spread=0.3)
    U[:, held] = spec.neutral_u()[held]
    poses = truth.poses(1, 1e-4)
    poses.controls, poses.markers = truth.observe(U, 1e-4)
    ok, P = feasible(spec, poses.controls)
    return poses, evaluate_plan(spec, Plan(poses.controls, "given", {}, P), 1e-4, n_markers=4)


def test_stand_parameters_these_poses_do_not_excite_are_held_and_counted_as_plan_counts_them():
    spec = get_platform("urdf")  # the default three-joint arm
    poses, planned = _poses_with_joints_held(spec, Truth(spec, seed=7, n_markers=4, marker_spread=0.05), [2])
    cal = calibrate(poses, spec)  # the elbow never moves: what it would show is held at nominal
    gauge = cal.identifiability["gauge"]
    assert planned["identifiable"] is False
    assert (gauge["dimensions"], gauge["not_excited"]) == (planned["gauge_dimensions"], planned["not_excited"]) == (15, 4)
    unexcited = [h for h in cal.identifiability["held_at_nominal"] if h.get("kind") == NOT_EXCITED]
    assert unexcited and all("these poses do not excite it" in h["reason"] for h in unexcited)
    # the base yaw never turning leaves the arm in one vertical plane: a marker is not fixed
    poses, planned = _poses_with_joints_held(spec, Truth(spec, seed=7, n_markers=4, marker_spread=0.05), [0])
    with pytest.raises(NotIdentifiable, match="the poses cannot fix marker.*the stand's reach would"):
        calibrate(poses, spec)
    assert planned["identifiable"] is False and planned["not_excited"] > 0


def test_a_turntable_turns_about_one_axis_the_convention_is_along_it(tmp_path):
    path = tmp_path / "turntable.urdf"
    path.write_text(TURNTABLE, encoding="utf-8")
    spec = get_platform("urdf", path)
    truth = Truth(spec, seed=8, n_markers=4, marker_spread=0.05)
    cal = calibrate(truth.poses(30, 1e-4, spread=0.45), spec)
    gauge = cal.identifiability["gauge"]
    assert gauge["not_excited"] == 0 and gauge["marker_shift_directions"] == [pytest.approx([0, 0, 1])]
    assert "turns about one axis only" in gauge["conventions"][0]
    assert any("initial rigid registration" in c for c in gauge["conventions"])  # the turn with the mocap frame
    assert cal.marker_positions.mean(axis=0)[2] == pytest.approx(0.0, abs=1e-12)
    assert prediction_error(cal, truth) < 0.05e-3
    with pytest.raises(BadInput, match="--method paper cannot serve the urdf stand .* turns about one axis only"):
        calibrate_paper(truth.poses(10, 1e-4), spec)


def _true_markers(spec, truth: dict, U):
    td = np.array([truth["parameters"].get(p.name, {"value": p.nominal})["value"] for p in spec.parameters])
    fb = PlatformModel(spec).forward_batch(U, td=td, strict=False)
    S = np.array([truth["markers"][m] for m in sorted(truth["markers"])])
    T = np.array(truth["mocap_from_base"])
    pts = fb.X[:, None] + np.einsum("nij,mj->nmi", matrix_from_quat(fb.q), S)
    return pts @ T[:3, :3].T + T[:3, 3]


def test_the_gantry_goes_through_simulate_calibrate_predict_and_diagnose(tmp_path, capsys):
    session, out = tmp_path / "session", tmp_path / "cal"
    assert main(["simulate", "--platform", "urdf", "--description", str(GANTRY), "--out", str(session), "--poses", "50",
                 "--poses-only", "--seed", "11", "--noise-mm", "0.2"]) == 0
    assert main(["calibrate", str(session), "--quiet", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    # the markers' common shift at least; the rest depends on the groups the model selection frees
    assert report["gauge"]["dimensions"] >= 3 and report["gauge"]["not_excited"] == 0
    assert "markers' centroid is put at the moving frame's origin" in report["gauge"]["conventions"][0]
    spec = get_platform("urdf", GANTRY)
    rng = np.random.default_rng(12)
    lo, hi = spec.control_bounds()
    U = lo + rng.uniform(0.05, 0.95, (30, 3)) * (hi - lo)
    with open(tmp_path / "fresh.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(spec.control_names)
        w.writerows((U * 1e3).tolist())  # the session's unit: mm
    assert main(["predict", "--calibration", str(out / "calibration.yaml"), "--commands", str(tmp_path / "fresh.csv"),
                 "--out", str(tmp_path / "pred.csv")]) == 0
    with open(tmp_path / "pred.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    truth = yaml.safe_load((session / "truth.yaml").read_text())
    names = sorted(truth["markers"])
    pred = np.array([[[float(r[f"{m}_{a}"]) for a in "xyz"] for m in names] for r in rows]) * 1e-3
    err = np.linalg.norm(pred - _true_markers(spec, truth, U), axis=2)
    # 0.2 mm per axis, averaged over the settled window: the fit's own rms is ~0.04 mm
    assert np.sqrt(np.mean(err**2)) < 0.06e-3, np.sqrt(np.mean(err**2))
    assert main(["diagnose", str(session), "--calibration", str(out / "calibration.yaml"), "--out",
                 str(tmp_path / "diag")]) == 0
    assert json.loads((tmp_path / "diag" / "diagnosis.json").read_text())["findings"] == []
    # the paper's method sees orientations only: refused in one line, before any work, nothing written
    capsys.readouterr()
    assert main(["calibrate", str(session), "--method", "paper", "--quiet", "--out", str(tmp_path / "paper")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--method paper cannot serve the urdf stand" in err[0] and "never turns" in err[0]
    assert not (tmp_path / "paper").exists()


# ---------------------------------------------------------------------------- bad input on the way


def test_a_read_only_out_is_found_before_any_work(tmp_path, capsys, monkeypatch):
    import os

    from platkit.io.atomic import check_output_dir, check_output_file

    session = tmp_path / "session"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--poses", "12", "--poses-only"]) == 0
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    if os.geteuid() == 0:  # root writes anywhere but on a read-only mount: that is what os.access reports then
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == ro else real(p, mode))
    capsys.readouterr()
    for argv in (["calibrate", str(session), "--out", str(ro / "cal")],
                 ["calibrate", str(session), "--out", str(ro / "deeper" / "cal")],
                 ["plan", "--platform", "stewart", "--grid", "2", "--out", str(ro / "plan.csv")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{ro} is not writable" in err[0], err
        assert not any(ln.startswith("calibrate:") for ln in err)  # no fitting began
    # an existing output folder that is read-only itself, with a writable parent
    out = tmp_path / "kept"
    out.mkdir()
    out.chmod(0o555)
    if os.geteuid() == 0:
        monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) in (ro, out) else real(p, mode))
    with pytest.raises(BadInput, match="kept is not writable"):
        check_output_dir(out)
    check_output_dir(tmp_path / "new" / "folder")  # a folder that can be made is fine
    check_output_file(tmp_path / "new" / "file.csv")


def test_a_session_with_both_markers_and_poses_says_which_is_used(tmp_path, capsys):
    session = tmp_path / "both"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--poses", "12", "--seed", "3"]) == 0
    assert (session / "markers.csv").is_file() and not (session / "poses.csv").is_file()
    other = tmp_path / "settled"
    assert main(["simulate", "--platform", "stewart", "--out", str(other), "--poses", "12", "--seed", "3",
                 "--poses-only"]) == 0
    (session / "poses.csv").write_bytes((other / "poses.csv").read_bytes())
    capsys.readouterr()
    # what is said is read from stderr and report.json (test_calibrate_cli.py renders a stewart report.html)
    assert main(["calibrate", str(session), "--free", "none", "--quiet", "--no-report", "--out",
                 str(tmp_path / "cal")]) == 0
    err = capsys.readouterr().err
    assert "holds both markers.csv and poses.csv: markers.csv (the raw stream, settled by platkit) is used, " \
           "poses.csv is ignored" in err
    report = json.loads((tmp_path / "cal" / "report.json").read_text())
    assert any("poses.csv is ignored" in w for w in report.get("warnings", [])), report.get("warnings")


def test_without_reference_poses_nothing_is_called_a_gauge(monkeypatch):
    """A stand where no random command is reachable gives no reference: what the data cannot fix
    is then judged as before the gauge analysis (transform and markers an error), and said."""
    import platkit.calibrate.stages as stages

    spec = get_platform("urdf", GANTRY)
    empty = (np.zeros((0, spec.n_u)), np.zeros((0, spec.n_p)))
    monkeypatch.setattr(stages, "reference_poses_for", lambda spec, model=None: empty)
    truth = Truth(spec, seed=3, n_markers=4, marker_spread=0.05)
    with pytest.raises(NotIdentifiable, match="the poses cannot fix marker"):
        calibrate(truth.poses(30, 1e-4, spread=0.45), spec)
    stewart = get_platform("stewart")
    truth = Truth(stewart, seed=9, n_markers=4, marker_spread=0.05)
    gauge = calibrate(truth.poses(30, 1e-4), stewart).identifiability["gauge"]
    assert gauge["dimensions"] is None and "not classified" in gauge["conventions"][0]
