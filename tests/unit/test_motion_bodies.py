"""Rigid bodies in a calibration from motion (platkit.calibrate.motion_bodies).

A streamed session of the physical simulator with two rigid bodies (`platkit simulate --physics
--motion path --rigid-bodies 2 --noise-mm 0.2 --white-noise`, 10 s at 40 Hz: short, so every
window is kept as samples): `platkit calibrate` uses the body samples there, counts every body
sample used and not used, per body, in report.json (motion.samples.rigid_bodies), warns of those not
used, names the count in the summary line, and reads each body's placement back.

What is compared does not depend on the link frame the fit chose (as the settled-pose test,
tests/unit/test_simulate_physics_bodies.py): every marker seen from the body's frame,
R_body^T (m - o_body), fitted against true. The tolerance comes from the noise: a body sample has
sigma_p = 0.2 mm per axis on its origin and sigma_r = 2 mrad per axis on its orientation (0.2 mm
over the simulator's 0.1 m lever); N body samples used place the body's origin to sigma_p / sqrt(N)
per axis and its orientation to sigma_r / sqrt(N), the markers (from as many samples and more)
no worse. The difference of two points in 3 axes is then within 3 sqrt(6) sigma_p / sqrt(N) (three
sigmas), and the turn moves a marker r away by at most 3 sqrt(2) sigma_r r / sqrt(N) (two axes
across the lever). About 0.07 mm + 0.4 mrad x r for N near 450. A body sampled at another row than
its pose's (one sample off moves the stand about a millimetre), or not fitted at all, fails.
"""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml

from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_bodies import CAUSES
from platkit.cli import main
from platkit.errors import BadSession
from platkit.geometry import matrix_from_rotvec
from platkit.io.session import load_session

SIGMA_P_MM, SIGMA_R_RAD = 0.2, 0.002


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bodies") / "sim"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "10",
                 "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", "4111",
                 "--out", str(folder)]) == 0
    return folder


def _in_body(origin, rotvec, point) -> np.ndarray:
    """A point (mm) of the body's link seen from the body's frame."""
    return matrix_from_rotvec(np.asarray(rotvec, float)).T @ (np.asarray(point, float) - np.asarray(origin, float))


def test_bodies_in_a_fit_from_motion_are_used_counted_and_read_back(streamed, tmp_path, capsys):
    session = load_session(streamed)
    seen = np.isfinite(session.bodies).all(axis=2).sum(axis=0)  # (B,) samples of each body
    assert session.body_names == ["T1", "T2"] and seen.min() > 300
    out = tmp_path / "cal"
    capsys.readouterr()
    assert main(["calibrate", str(streamed), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(out)]) == 0
    said = capsys.readouterr()
    report = json.loads((out / "report.json").read_text())
    samples = report["motion"]["samples"]
    bodies = samples["rigid_bodies"]
    assert bodies["bodies"] == ["T1", "T2"] and bodies["n_samples"] == int(seen.sum())
    for k, b in enumerate(("T1", "T2")):
        mine = bodies["per_body"][b]
        assert mine["n_samples"] == int(seen[k])
        assert set(mine) == {"n_samples", "n_used", *CAUSES}  # the transient's count among them
        assert mine["n_used"] + sum(mine[c] for c in CAUSES) == mine["n_samples"]  # every sample said once
        assert mine["n_used"] > 0.9 * mine["n_samples"]  # a short stream: every window kept as samples
    left = bodies["n_samples"] - bodies["n_used"]
    assert left > 0  # those before the second command at least: said
    line = [w for w in report["warnings"] if w.startswith("rigid bodies T1, T2:")]
    assert len(line) == 1 and f"{bodies['n_used']} of {bodies['n_samples']} body samples used" in line[0]
    assert f"{left} not used" in line[0] and "rigid bodies T1, T2:" in said.err  # the warning printed
    assert f"rigid bodies T1, T2 from {bodies['n_used']} of {bodies['n_samples']} samples" in said.out  # summary
    truth = yaml.safe_load((streamed / "truth.yaml").read_text())
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    for body, fitted in cal["rigid_bodies"]["bodies"].items():
        true = truth["rigid_bodies"][body]
        n = bodies["per_body"][body]["n_used"]
        for m in session.marker_names:
            v_true = _in_body(np.array(true["position"]) * 1e3, true["rotation_vector"],
                              np.array(truth["markers"][m]) * 1e3)
            v_fit = _in_body(fitted["position"], fitted["rotation_vector"], cal["markers"][m]["position"])
            tol = 3.0 * (np.sqrt(6.0) * SIGMA_P_MM + np.sqrt(2.0) * SIGMA_R_RAD * np.linalg.norm(v_true)) / np.sqrt(n)
            assert np.linalg.norm(v_fit - v_true) < tol, (body, m, v_fit, v_true, tol)


def test_a_stream_of_bodies_alone_is_refused_in_one_line(streamed):
    session = load_session(streamed)
    bodies_only = replace(session, marker_names=[], markers=np.zeros((len(session.marker_t), 0, 3)))
    with pytest.raises(BadSession) as err:
        calibrate_motion(bodies_only, session.spec)
    text = str(err.value)
    assert "\n" not in text and "session.yaml" in text and "T1, T2" in text and "reads markers" in text
    assert "platkit.calibrate.motion_points" in text  # the route that calibrates bodies alone, named
