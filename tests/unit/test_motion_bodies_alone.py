"""Calibration from motion of a stream of rigid bodies alone (platkit.calibrate.motion_points).

A streamed session of the physical simulator with two rigid bodies (`platkit simulate --physics
--motion path --rigid-bodies 2 --noise-mm 0.2 --white-noise`, 10 s at 40 Hz), its markers stripped
(markers.csv: the time and the bodies' columns; session.yaml: no markers): `platkit calibrate` reads
each body as three points, calibrates from motion, and writes the bodies' placements read back.

What is compared does not depend on the link frame the fit chose: body T2 seen from body T1's frame
(the origin R1^T (o2 - o1) and the rotation R1^T R2), fitted against true. Tolerance from the noise
(tests/unit/test_motion_bodies.py's reasoning): sigma_p = 0.2 mm per axis on a body's origin,
sigma_r = 2 mrad on its orientation; N body samples place an origin to sigma_p / sqrt(N) and an
orientation to sigma_r / sqrt(N); the relative origin is within 3 (sqrt(6) sigma_p + sqrt(2)
sigma_r r) / sqrt(N) (r the distance between the bodies), the relative rotation within 3 sqrt(6)
sigma_r / sqrt(N). A placement read back wrongly (an axis swapped, a rotation transposed) is off by
tens of mrad or more.

With one body, the distances between its points are rigid by construction: the markers' noise from
pair distances reads about 0, and the misfit rule against it refuses the fit; against the points'
own noise (measured on the stream) the fit is kept.
"""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from bodies_alone import stewart_bodies_stream, strip_markers

from platkit.calibrate.estimate import marker_noise_floor
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_points import calibrate_motion_bodies, point_session
from platkit.cli import main
from platkit.errors import BadSession
from platkit.geometry import matrix_from_rotvec, rotvec_from_matrix
from platkit.io.session import load_session

SIGMA_P_MM, SIGMA_R_RAD = 0.2, 0.002
TREE = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"


def _settled_errors(sim, cal_yaml, controls, tmp_path, bodies) -> dict[str, tuple[float, float]]:
    """platkit predict of ``cal_yaml`` at the controls each command settled to (truth_settled.csv):
    per body, the median error of its origin (mm) and of its orientation (rad) against the true pose."""
    settled = np.genfromtxt(sim / "truth_settled.csv", delimiter=",", names=True)
    np.savetxt(tmp_path / "settled.csv", np.column_stack([settled[c] for c in controls]), delimiter=",",
               header=",".join(controls), comments="")
    pred = tmp_path / "pred.csv"
    assert main(["predict", "--calibration", str(cal_yaml), "--commands", str(tmp_path / "settled.csv"),
                 "--out", str(pred)]) == 0
    got = np.genfromtxt(pred, delimiter=",", names=True)
    out = {}
    for b in bodies:
        err = np.linalg.norm(np.column_stack([got[f"{b}_{c}"] - settled[f"{b}_{c}"] for c in "xyz"]), axis=1)
        qp, qt = (np.column_stack([g[f"{b}_q{c}"] for c in "wxyz"]) for g in (got, settled))
        turn = 2.0 * np.arccos(np.clip(np.abs(np.sum(qp * qt, axis=1)), 0.0, 1.0))
        out[b] = (float(np.median(err)), float(np.median(turn)))
    return out


@pytest.fixture(scope="module")
def bodies_only(tmp_path_factory):
    root = tmp_path_factory.mktemp("alone")
    return stewart_bodies_stream(root)


def test_bodies_alone_are_calibrated_from_motion_as_points_and_read_back(bodies_only, tmp_path, capsys):
    sim, folder = bodies_only
    session = load_session(folder)
    assert session.marker_names == [] and session.body_names == ["T1", "T2"]
    out = tmp_path / "cal"
    capsys.readouterr()
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(out)]) == 0
    said = capsys.readouterr()
    report = json.loads((out / "report.json").read_text())
    points = report["motion"]["bodies_as_points"]
    assert points["points"] == ["T1.o", "T1.x", "T1.y", "T2.o", "T2.x", "T2.y"]
    assert points["noise_source"] == "measured"
    # the points' noise measured on the moving stream: origins 0.2 mm, tips sqrt(0.2^2 + 2/3 0.2^2) mm
    assert 0.18e-3 < points["point_sigma_m"]["T1.o"] < 0.26e-3 and 0.23e-3 < points["point_sigma_m"]["T1.x"] < 0.32e-3
    bodies = report["motion"]["samples"]["rigid_bodies"]
    assert bodies["n_used"] > 0.9 * bodies["n_samples"]
    assert "no markers: rigid bodies T1, T2 read as 6 points" in said.out  # the summary line
    assert f"rigid bodies T1, T2 from {bodies['n_used']} of {bodies['n_samples']} samples" in said.out
    assert any(w.startswith("no markers: rigid bodies T1, T2 read as 6 points") for w in report["warnings"])
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert not cal.get("markers")  # the points are not written as markers
    truth = yaml.safe_load((sim / "truth.yaml").read_text())

    def relative(b1, b2, scale):
        R1, R2 = matrix_from_rotvec(np.array(b1["rotation_vector"])), matrix_from_rotvec(np.array(b2["rotation_vector"]))
        return R1.T @ (np.array(b2["position"]) - np.array(b1["position"])) * scale, R1.T @ R2

    fitted = cal["rigid_bodies"]["bodies"]
    p_fit, R_fit = relative(fitted["T1"], fitted["T2"], 1.0)  # mm
    p_true, R_true = relative(truth["rigid_bodies"]["T1"], truth["rigid_bodies"]["T2"], 1e3)
    n = min(bodies["per_body"][b]["n_used"] for b in ("T1", "T2"))
    r = float(np.linalg.norm(p_true))
    tol_p = 3.0 * (np.sqrt(6.0) * SIGMA_P_MM + np.sqrt(2.0) * SIGMA_R_RAD * r) / np.sqrt(n)
    tol_r = 3.0 * np.sqrt(6.0) * SIGMA_R_RAD / np.sqrt(n)
    assert np.linalg.norm(p_fit - p_true) < tol_p, (p_fit, p_true, tol_p)
    assert np.linalg.norm(rotvec_from_matrix(R_true.T @ R_fit)) < tol_r
    # the std read back: the origin's per axis, the rotation's from the tips over the lever, both finite
    std = np.array(fitted["T1"]["std_position"] + fitted["T1"]["std_rotation_vector"], float)
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    # platkit predict reads the bodies: at the controls each command settled to (truth_settled.csv), the
    # body's pose predicted against the true one (a development run: 0.06 mm and 0.3 mrad median; a tip
    # read as the origin is 100 mm off, a rotation read transposed tens of mrad or more)
    for b, (mm, rad) in _settled_errors(sim, out / "calibration.yaml", [f"L{k}" for k in range(1, 7)], tmp_path,
                                        ("T1", "T2")).items():
        assert mm < 0.25 and rad < 1.5e-3, (b, mm, rad)


def test_a_tree_of_bodies_alone_keeps_each_body_on_its_link(tmp_path):
    """A tree (tests/data/trees/two_arm_torso.urdf, both hands tracked, one body on each) streamed with
    its bodies alone: each body's points ride its link, the body is written on it, and its poses are
    predicted (a development run: 0.2 and 0.3 mm, 0.4 mrad median; a body on the other hand's link is
    off by the distance between the hands)."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--platform", "urdf", "--description", str(TREE), "--moving-link", "right_tcp,left_tcp",
                 "--physics", "--motion", "path", "--duration-s", "10", "--rate-hz", "40", "--noise-mm", "0.2",
                 "--white-noise", "--rigid-bodies", "2", "--seed", "4112", "--out", str(sim)]) == 0
    strip_markers(sim, tmp_path / "bodies")
    out = tmp_path / "cal"
    assert main(["calibrate", str(tmp_path / "bodies"), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(out)]) == 0
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    bodies = cal["rigid_bodies"]["bodies"]
    assert {b: bodies[b]["link"] for b in bodies} == {"T1": "right_tcp", "T2": "left_tcp"}
    controls = open(sim / "commands.csv").readline().strip().split(",")[1:]
    for b, (mm, rad) in _settled_errors(sim, out / "calibration.yaml", controls, tmp_path, ("T1", "T2")).items():
        assert mm < 1.0 and rad < 2e-3, (b, mm, rad)


def test_point_noise_declared_and_the_placement_read_back_exactly():
    from platkit.bodies import body_frame_points, placement_from_point_fit
    from platkit.calibrate.motion_points import point_sigmas
    from platkit.geometry import quat_from_rotvec

    sig, source = point_sigmas(["T1"], {"position_m": 1e-4, "rotation_rad": 2e-3})
    assert source == "declared" and sig["T1.o"] == pytest.approx(1e-4)
    assert sig["T1.x"] == pytest.approx(np.sqrt(1e-8 + 2.0 / 3.0 * (2e-3 * 0.1) ** 2))
    rv, o = np.array([0.3, -1.2, 2.0]), np.array([0.05, -0.02, 0.3])
    pts = body_frame_points(np.concatenate([o, quat_from_rotvec(rv)])[None, None])[0]  # (3, 3)
    tip = sig["T1.x"]
    std = np.array([[1e-4] * 3, [tip] * 3, [tip] * 3])
    p, r, sd = placement_from_point_fit(pts, std)
    assert np.allclose(p, o) and np.allclose(r, rv)
    assert np.allclose(sd, [1e-4, 1e-4, 1e-4, 2e-3, 2e-3, 2e-3])  # the declared noise comes back


def test_one_body_alone_is_judged_against_its_points_noise_not_their_distances(bodies_only):
    _, folder = bodies_only
    session = load_session(folder)
    one = replace(session, body_names=["T1"], bodies=session.bodies[:, :1])
    points = point_session(one)
    with pytest.raises(BadSession) as err:  # the misfit rule against the pair distances' ~0 noise
        calibrate_motion(points, one.spec, kind="first_order")
    assert "times their own noise" in str(err.value)
    cal, poses = calibrate_motion_bodies(one, one.spec, kind="first_order")
    assert marker_noise_floor(poses) < 1e-9  # the points' distances: rigid by construction
    floor = cal.motion["bodies_as_points"]["noise_floor_m"]
    assert 0.2e-3 < floor < 0.3e-3 and cal.rms_after < 5.0 * np.sqrt(3) * floor
    assert cal.body_names == ["T1"] and cal.marker_names == [] and np.isfinite(cal.body_rho)
