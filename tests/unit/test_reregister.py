"""Re-registration (platkit.calibrate.reregister): a calibration carried to another motion-capture
set-up. The shipped stewart session's truth (truth.yaml) records a second session of the same stand
whose mocap transform moved (and, for the marker places, whose marker body was mounted again); the
calibration of the first session, re-registered on the second one's poses, recovers the new
set-up and predicts that session's markers as the truth does."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.calibrate.plan import random_candidates
from platkit.calibrate.reregister import check_registration, registration_blocks, reregister, rotated_scores
from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, rotvec_from_matrix
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.settle import load_poses
from tests.unit.test_simulate_calibrate import example_truth, true_markers

NOISE_M = 0.05e-3


@pytest.fixture(scope="module")
def stand():
    spec = get_platform("stewart")
    folder, td, T, names, S = example_truth(spec)
    cal = calibrate(load_poses(folder), spec)
    return spec, td, T, names, S, cal


def _session(spec, td, T, S, names, n, seed) -> PoseSet:
    """n new poses of the true stand seen through mocap_from_base T with markers S, noisy."""
    rng = np.random.default_rng(seed)
    U = random_candidates(spec, n, rng).controls
    Y = true_markers(spec, td, T, S, U) + rng.normal(0.0, NOISE_M, (n, len(names), 3))
    return PoseSet("stewart", U, Y, list(names), length_unit="mm", source="day2")


def _moved(T):
    """The set-up of another day: the cameras turned 0.4 rad and moved 0.3 m."""
    M = np.eye(4)
    M[:3, :3] = matrix_from_rotvec(np.array([0.1, -0.3, 0.25]))
    M[:3, 3] = [0.3, -0.1, 0.05]
    return M @ T


def test_reregistration_recovers_the_moved_mocap_transform(stand):
    spec, td, T, names, S, cal = stand
    T2 = _moved(T)
    day2 = _session(spec, td, T2, S, names, 12, seed=7)
    before, _, _, _ = predict_markers(cal, day2.controls)
    assert np.sqrt(np.mean(np.sum((before - day2.markers) ** 2, axis=2))) > 0.05  # as is: decimetres off
    moved, reg = reregister(cal, day2)
    # the set-up's move, applied to the calibration's own transform (its base frame is the
    # calibration's, a gauge away from the truth's: within a milliradian here)
    expected = T2 @ np.linalg.inv(T) @ cal.mocap_from_base
    turn = matrix_from_rotvec(reg.rotvec) @ expected[:3, :3].T
    assert np.linalg.norm(rotvec_from_matrix(turn)) < 5e-5  # measured 1e-5 rad
    assert np.linalg.norm(reg.translation - expected[:3, 3]) < 0.1e-3  # measured 0.04 mm
    assert reg.std[:3].max() < 3e-5 and reg.std[3:].max() < 0.06e-3  # 1e-5 rad, 0.03 mm: the errors' size
    assert not reg.markers and np.array_equal(moved.td, cal.td) and np.array_equal(moved.marker_positions,
                                                                                  cal.marker_positions)
    fresh = random_candidates(spec, 30, np.random.default_rng(11)).controls
    pred, _, _, ok = predict_markers(moved, fresh)
    err = np.linalg.norm(pred - true_markers(spec, td, T2, S, fresh), axis=2)
    assert ok.all() and np.sqrt(np.mean(err ** 2)) < 0.05e-3  # measured 0.017 mm; the first day's calibration, in the new frame
    assert reg.to_dict(cal)["turn_from_calibration_rad"] == pytest.approx(0.40, abs=0.01)


def test_marker_places_refitted_for_a_marker_body_mounted_again(stand):
    spec, td, T, names, S, cal = stand
    T2 = _moved(T)
    R = matrix_from_rotvec(np.array([0.0, 0.05, 0.02]))
    S2 = S @ R.T + [0.004, -0.003, 0.002]  # the body turned 3 degrees and moved 5 mm on the platform
    day2 = _session(spec, td, T2, S2, names, 20, seed=8)
    fresh = random_candidates(spec, 30, np.random.default_rng(12)).controls
    truth = true_markers(spec, td, T2, S2, fresh)

    def rms(c):
        pred, _, _, _ = predict_markers(c, fresh)
        return np.sqrt(np.mean(np.sum((pred - truth) ** 2, axis=2)))

    transform_only, _ = reregister(cal, day2)
    with_places, reg = reregister(cal, day2, markers=True)
    assert rms(transform_only) > 5e-3  # a transform alone cannot move the markers on the platform (22 mm)
    assert rms(with_places) < 0.06e-3  # measured 0.028 mm
    assert reg.markers and np.array_equal(with_places.td, cal.td)


def test_rotation_scores_every_pose_out_of_its_registration(stand):
    spec, td, T, names, S, cal = stand
    day2 = _session(spec, td, _moved(T), S, names, 23, seed=9)
    for k in (1, 5, 11, 20):
        for spread in (False, True):
            blocks = registration_blocks(23, k, spread)
            left_out = np.zeros(23, int)
            for blk in blocks:
                assert len(set(blk)) == k
                left_out[np.setdiff1d(np.arange(23), blk)] += 1
            assert left_out.min() >= 1
    assert list(registration_blocks(23, 5, spread=True)[1]) == [1, 6, 11, 16, 21]  # across the recording
    score = rotated_scores(cal, day2, 5)
    assert np.isfinite(score.sq).all() and len(score.registrations) == 5
    assert np.isfinite(rotated_scores(cal, day2, 5, spread=True).sq).all()
    assert score.rms < 0.15e-3  # measured 0.095 mm; noise 0.05 mm per axis: 0.087 mm 3-D, plus the calibration's own error


def test_bad_input_one_line(stand):
    spec, td, T, names, S, cal = stand
    day2 = _session(spec, td, _moved(T), S, names, 10, seed=10)
    with pytest.raises(BadInput, match=r"--heldout-register 10: day2 has 10 poses; re-registering on 10 leaves none"):
        rotated_scores(cal, day2, 10)
    with pytest.raises(BadInput, match=r"--heldout-register 0: give a number of poses"):
        rotated_scores(cal, day2, 0)
    with pytest.raises(BadInput, match=r"day2, poses 1-1: 1 pose cannot fix the base-to-mocap transform and the "
                                       r"marker places \(it needs the link to turn about two different axes"):
        rotated_scores(cal, day2, 1, markers=True)
    with pytest.raises(BadInput, match=r"day2, poses 1-1: 1 pose cannot fix the base-to-mocap transform and the "
                                       r"marker places \(it needs the link to turn about two different axes"):
        check_registration(cal, day2, 1, markers=True)  # the same line, nothing fitted
    one = PoseSet("stewart", day2.controls[:1], day2.markers[:1, :2], names[:2], source="day2")
    with pytest.raises(BadInput, match=f"day2: has no marker or rigid body {names[2]!r} of the calibration"):
        reregister(cal, one)
    hidden = PoseSet("stewart", day2.controls[:1], np.where(np.arange(len(names))[None, :, None] < 2,
                                                            day2.markers[:1], np.nan), names, source="day2")
    with pytest.raises(BadInput, match="day2: 2 points seen and predicted; fixing the base-to-mocap transform needs"):
        reregister(cal, hidden)


# ---------------------------------------------------------------------------- the command line


def _split_session(full, train, day2, n_train: int, move) -> None:
    """Rows before ``n_train`` of a simulated session as ``train``; the others as ``day2``, their
    markers seen through the set-up moved by ``move`` (4, 4), the poses' lengths in mm."""
    import csv

    for folder in (train, day2):
        folder.mkdir()
        (folder / "session.yaml").write_text((full / "session.yaml").read_text())
    for name in ("commands.csv", "poses.csv"):
        rows = list(csv.reader((full / name).open()))
        header, body = rows[0], rows[1:]
        for folder, part in ((train, body[:n_train]), (day2, body[n_train:])):
            if folder is day2 and name == "poses.csv":
                part = [list(r) for r in part]
                for r in part:
                    for m in ("M1", "M2", "M3", "M4", "M5"):
                        k = header.index(f"{m}_x")
                        p = move[:3, :3] @ np.array([float(x) for x in r[k:k + 3]]) + move[:3, 3] * 1e3
                        r[k:k + 3] = [f"{x:.4f}" for x in p]
            with (folder / name).open("w", newline="") as fh:
                csv.writer(fh, lineterminator="\n").writerows([header] + part)


@pytest.fixture(scope="module")
def two_days(tmp_path_factory):
    from platkit.cli import main

    root = tmp_path_factory.mktemp("reregister")
    full, train, day2 = root / "full", root / "train", root / "day2"
    assert main(["simulate", "--platform", "stewart", "--out", str(full), "--effect", "backlash:1.0", "--seed", "5",
                 "--poses", "60", "--plan", "random", "--poses-only"]) == 0
    _split_session(full, train, day2, 40, _moved(np.eye(4)))
    assert main(["calibrate", str(train), "--out", str(root / "cal"), "--quiet", "--no-report"]) == 0
    return root, train, day2, root / "cal" / "calibration.yaml"


def test_diagnose_scores_a_heldout_day_re_registered(two_days):
    import json

    from platkit.cli import main

    root, train, day2, cal = two_days
    out = root / "diag"
    assert main(["diagnose", str(train), "--calibration", str(cal), "--heldout", str(day2), "--heldout-register", "5",
                 "--out", str(out), "--quiet"]) == 0
    h = json.loads((out / "diagnosis.json").read_text())["heldout_session"]
    r = h["registered"]
    assert [f["effect"] for f in json.loads((out / "diagnosis.json").read_text())["findings"]] == ["backlash"]
    assert h["rms_after"] > 100.0  # mm: the training day's set-up, as is, on the moved one
    assert r["k"] == 5 and r["n_registrations"] == 4 and not r["marker_places_refitted"]
    assert r["median_turn_from_calibration_rad"] == pytest.approx(0.40, abs=0.01)
    # measured 0.078 against 0.27 mm: the backlash holds out on the new set-up
    assert r["rms_after"] < 0.12 and r["rms_after"] < 0.5 * r["rms_before"]
    assert set(r["per_marker"]) == {"M1", "M2", "M3", "M4", "M5"}


def test_diagnose_re_registers_each_block_once_per_model(two_days, tmp_path, monkeypatch):
    """--heldout-register K checks its blocks without fitting (check_registration), then fits each
    block once for the geometric model and once for the diagnosed one: 2 x 4 blocks of 5 poses
    among day 2's 20."""
    import platkit.calibrate.reregister as rr
    from platkit.cli import main

    root, train, day2, cal = two_days
    fits = []
    fit_setup = rr.fit_setup
    monkeypatch.setattr(rr, "fit_setup", lambda *a, **k: fits.append(a[2]) or fit_setup(*a, **k))
    assert main(["diagnose", str(train), "--calibration", str(cal), "--heldout", str(day2), "--heldout-register", "5",
                 "--out", str(tmp_path / "d"), "--quiet"]) == 0
    assert len(fits) == 8


@pytest.mark.parametrize("extra, message", [
    (["--heldout-register", "5"], "--heldout-register 5: give --heldout SESSION"),
    (["--heldout", "DAY2", "--heldout-register", "20"], "--heldout-register 20: DAY2 has 20 poses; re-registering on "
                                                        "20 leaves none to score (give fewer than 20)"),
    (["--heldout", "DAY2", "--heldout-register", "1", "--register-markers"],
     "--heldout-register 1: DAY2, poses 1-1: 1 pose cannot fix the base-to-mocap transform and the marker places"),
    (["--heldout", "DAY2", "--register-markers"], "--register-markers: give --heldout-register K"),
    (["--heldout", "DAY2", "--register-spread"], "--register-spread: give --heldout-register K"),
])
def test_diagnose_register_bad_input(two_days, tmp_path, capsys, extra, message):
    from platkit.cli import main

    root, train, day2, cal = two_days
    extra = [str(day2) if x == "DAY2" else x for x in extra]
    assert main(["diagnose", str(train), "--calibration", str(cal), "--out", str(tmp_path / "d"), "--quiet",
                 *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert message.replace("DAY2", str(day2)) in err[-1] and len([e for e in err if "error" in e]) == 1
    assert not (tmp_path / "d").exists()


def test_predict_register_predicts_in_the_new_set_up(two_days, tmp_path, capsys):
    import csv

    from platkit.cli import main
    from platkit.io.calibration import read_calibration

    root, train, day2, cal = two_days
    out, kept = tmp_path / "pred.csv", tmp_path / "registered"
    assert main(["predict", "--calibration", str(cal), "--commands", str(day2 / "commands.csv"), "--out", str(out),
                 "--register", str(day2), "--registered-calibration", str(kept)]) == 0
    said = capsys.readouterr().out
    assert f"re-registered on {day2} (20 poses" in said and "mocap_from_base turned 40" in said  # 0.40 rad, in mrad
    pred = list(csv.DictReader(out.open()))
    seen = list(csv.DictReader((day2 / "poses.csv").open()))
    err = [float(p[f"{m}_{a}"]) - float(s[f"{m}_{a}"]) for p, s in zip(pred, seen) for m in ("M1", "M5") for a in "xyz"]
    assert len(pred) == 20 and np.sqrt(np.mean(np.square(err))) < 0.5  # mm, in day 2's frame (decimetres as is)
    text = (kept / "calibration.yaml").read_text()
    assert "registration:" in text and f"session: {day2}" in text
    again = read_calibration(kept / "calibration.yaml")
    first = read_calibration(cal)
    assert np.array_equal(again.td, first.td) and not np.allclose(again.mocap_translation, first.mocap_translation)
    # the kept calibration predicts the same without --register
    assert main(["predict", "--calibration", str(kept / "calibration.yaml"), "--commands", str(day2 / "commands.csv"),
                 "--out", str(tmp_path / "again.csv")]) == 0
    assert (tmp_path / "again.csv").read_text() == out.read_text()


@pytest.mark.parametrize("extra, message", [
    (["--register-markers"], "--register-markers: give --register SESSION"),
    (["--registered-calibration", "KEPT"], "--registered-calibration: give --register SESSION"),
    (["--register", "NOWHERE"], "NOWHERE"),
])
def test_predict_register_bad_input(two_days, tmp_path, capsys, extra, message):
    from platkit.cli import main

    root, train, day2, cal = two_days
    subst = {"KEPT": str(tmp_path / "kept"), "NOWHERE": str(tmp_path / "nowhere")}
    extra = [subst.get(x, x) for x in extra]
    assert main(["predict", "--calibration", str(cal), "--commands", str(day2 / "commands.csv"),
                 "--out", str(tmp_path / "p.csv"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and subst.get(message, message) in err[0]
    assert not (tmp_path / "p.csv").exists() and not (tmp_path / "kept").exists()


def test_rigid_bodies_follow_the_new_set_up(tmp_path):
    """A body's origin is one more point of the fit; its orientation, never fitted, comes out right
    through the new transform."""
    from platkit.calibrate.estimate import predict_bodies
    from platkit.cli import main
    from platkit.geometry import quat_from_matrix
    from platkit.io.calibration import read_calibration

    assert main(["simulate", "--platform", "stewart", "--out", str(tmp_path / "s"), "--seed", "3", "--poses", "30",
                 "--plan", "random", "--poses-only", "--rigid-bodies", "1"]) == 0
    assert main(["calibrate", str(tmp_path / "s"), "--out", str(tmp_path / "c"), "--quiet", "--no-report"]) == 0
    cal = read_calibration(tmp_path / "c" / "calibration.yaml")
    poses = load_poses(tmp_path / "s", spec=cal.spec)
    T2 = _moved(np.eye(4))
    poses.markers = poses.markers @ T2[:3, :3].T + T2[:3, 3]
    bodies = poses.bodies.copy()
    bodies[..., :3] = bodies[..., :3] @ T2[:3, :3].T + T2[:3, 3]
    bodies[..., 3:] = quat_from_matrix(np.einsum("ab,nkbc->nkac", T2[:3, :3], matrix_from_quat(bodies[..., 3:])))
    poses.bodies = bodies
    moved, reg = reregister(cal, poses)
    assert reg.n_points + reg.n_rejected == 30 * 6  # five markers and the body's origin
    pred, q, X, _ = predict_markers(moved, poses.controls, poses)
    body = predict_bodies(moved, q, X, poses.controls, poses)
    assert np.sqrt(np.mean(np.sum((pred - poses.markers) ** 2, axis=2))) < 0.06e-3  # measured 0.04 mm
    assert np.sqrt(np.mean(np.sum((body[..., :3] - bodies[..., :3]) ** 2, axis=2))) < 0.04e-3  # 0.02 mm
    assert np.max(1 - np.abs(np.sum(body[..., 3:] * bodies[..., 3:], axis=2))) < 1e-6  # the same orientation


def test_a_tree_re_registers_both_hands_with_one_transform():
    """Markers on two tracked links (test_urdf_tree's two-armed torso): one transform for both
    hands, each marker's place on its own link."""
    from test_urdf_tree import MAPPING, MARKERS, SIGMA, commands, observe, tree_spec, true_td

    spec = tree_spec()
    rng = np.random.default_rng(21)
    td = true_td(spec, rng)
    U = commands(spec, 90, rng)
    Y = observe(spec, td, U, rng)
    cal = calibrate(PoseSet("urdf", U[:60], Y[:60], list(MARKERS), moving_link=MAPPING), spec)
    T2 = _moved(np.eye(4))
    day2 = PoseSet("urdf", U[60:], Y[60:] @ T2[:3, :3].T + T2[:3, 3], list(MARKERS), moving_link=MAPPING,
                   source="day2")
    for markers in (False, True):
        moved, reg = reregister(cal, day2.subset(np.arange(15)), markers=markers)
        pred, _, _, _ = predict_markers(moved, day2.controls[15:], day2.subset(np.arange(15, 30)))
        err = np.linalg.norm(pred - day2.markers[15:], axis=2)
        assert np.mean(err) < 2.2 * SIGMA, markers  # as the same set-up's held-out poses (test_urdf_tree)
        assert reg.shift(cal)[0] == pytest.approx(np.linalg.norm([0.1, -0.3, 0.25]), abs=1e-3)  # _moved's turn
