"""Rigid bodies at the nodes of a stream (platkit.calibrate.motion_bodies): a window reduced to
nodes reduces a body's samples to its pose at the nodes, and a calibration from motion serves them.

1. The reduction itself, on a body whose origin is a quadratic in time and whose orientation turns
   about one axis at a constant rate (both exact for the window's polynomial of degree 2 in the
   tangent space at the mean): the nodes' poses are the body's true poses at the nodes' times, and
   each node is worth what the node of a marker seen at the same samples is.
2. A streamed Stewart session of the physical simulator with two bodies (20 s at 40 Hz, 0.2 mm white
   noise), fitted with few windows kept raw (raw_samples=100: one window in eight): the body samples
   of the other windows serve at the nodes (over 90% served: under 20% served without), every body
   sample is said once (used, or one cause), and each body's placement comes back within three
   sigmas of the samples served (tests/unit/test_motion_bodies.py's bound: 3 (sqrt(6) sigma_p +
   sqrt(2) sigma_r r) / sqrt(N), a marker r from the body's origin).
3. The stream a diagnosis reads (motion_stream: every window at its nodes) carries the bodies there,
   reduced as calibrate_motion reduces them.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from platkit.calibrate.motion import calibrate_motion, motion_stream
from platkit.calibrate.motion_bodies import CAUSES, bodies_at_samples
from platkit.calibrate.stream import stream_windows
from platkit.cli import main
from platkit.geometry import matrix_from_rotvec
from platkit.io.session import load_session

SIGMA_P_MM, SIGMA_R_RAD = 0.2, 0.002


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bodies_nodes") / "sim"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "20",
                 "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", "4112",
                 "--out", str(folder)]) == 0
    return load_session(folder), yaml.safe_load((folder / "truth.yaml").read_text())


def _exact_bodies(t: np.ndarray) -> tuple[np.ndarray, Rotation]:
    """A body's origin (quadratic in t) and orientation (a constant turn rate about one axis)."""
    origin = np.stack([0.1 + 0.02 * t - 0.003 * t ** 2, -0.2 + 0.01 * t ** 2, 0.5 - 0.04 * t], axis=1)
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    rot = Rotation.from_rotvec([0.3, -0.2, 0.1]) * Rotation.from_rotvec(0.15 * t[:, None] * axis)
    return origin, rot


def test_a_window_reduces_a_body_to_its_poses_at_the_nodes(streamed):
    session, _ = streamed
    t = session.marker_t
    origin, rot = _exact_bodies(t - t[0])
    bodies = np.concatenate([origin, rot.as_quat(scalar_first=True)], axis=1)[:, None, :].copy()
    bodies[5::7] = np.nan  # occluded now and then: fitted from the samples seen
    markers = session.markers.copy()
    markers[:, 0] = origin  # a marker seen where the body is: its nodes weighted as the body's
    markers[5::7, 0] = np.nan
    one = replace(session, body_names=["T1"], bodies=bodies, markers=markers)
    win = stream_windows(one, raw_samples=0)
    fields = bodies_at_samples(one, win)
    got, worth = fields["bodies"][:, 0], fields["n_body_samples"][:, 0]
    assert np.isfinite(got).all() and len(got) == len(win.t) > 30
    o_true, r_true = _exact_bodies(win.t - t[0])
    assert np.abs(got[:, :3] - o_true).max() < 1e-9
    turn = (Rotation.from_quat(got[:, 3:], scalar_first=True).inv() * r_true).magnitude()
    assert turn.max() < 1e-9
    np.testing.assert_allclose(worth, win.n_eff[:, 0], rtol=1e-12)  # each node worth what a marker's is
    seen = np.isfinite(bodies[:, 0]).all(axis=1)
    for p, a, n, _ in win.blocks:  # the samples a window's nodes stand for, near those seen in it
        assert worth[p:p + win.nodes].sum() == pytest.approx(seen[a:a + n].sum(), rel=0.05)


def _in_body(origin, rotvec, point) -> np.ndarray:
    """A point (mm) of the body's link seen from the body's frame."""
    return matrix_from_rotvec(np.asarray(rotvec, float)).T @ (np.asarray(point, float) - np.asarray(origin, float))


@pytest.fixture(scope="module")
def fitted(streamed):
    session, _ = streamed
    return calibrate_motion(session, session.spec, kind="first_order", raw_samples=100)[0]


def test_bodies_at_the_nodes_serve_a_calibration_from_motion(streamed, fitted):
    session, truth = streamed
    cal = fitted
    said = cal.motion["samples"]["rigid_bodies"]
    scale = 1e3  # the calibration in SI, the placements compared in mm
    for j, body in enumerate(session.body_names):
        mine = said["per_body"][body]
        assert set(mine) == {"n_samples", "n_used", *CAUSES}
        assert mine["n_used"] + sum(mine[c] for c in CAUSES) == mine["n_samples"]  # every sample said once
        assert mine["n_used"] > 0.9 * mine["n_samples"]  # served at the nodes (one window in eight kept raw)
        true = truth["rigid_bodies"][body]
        for i, m in enumerate(cal.marker_names):
            v_true = _in_body(np.array(true["position"]) * 1e3, true["rotation_vector"],
                              np.array(truth["markers"][m]) * 1e3)
            v_fit = _in_body(cal.body_positions[j] * scale, cal.body_rotvecs[j], cal.marker_positions[i] * scale)
            tol = 3.0 * (np.sqrt(6.0) * SIGMA_P_MM + np.sqrt(2.0) * SIGMA_R_RAD * np.linalg.norm(v_true)) / np.sqrt(
                mine["n_used"])
            assert np.linalg.norm(v_fit - v_true) < tol, (body, m, v_fit, v_true, tol)


def test_the_stream_a_diagnosis_reads_carries_the_bodies_at_its_nodes(streamed, fitted):
    session, _ = streamed
    poses, term = motion_stream(session, fitted)
    assert poses.body_names == ["T1", "T2"] and poses.bodies.shape == (poses.n_poses, 2, 7)
    seen = poses.n_body_samples > 0
    assert seen.mean() > 0.9 and np.isfinite(poses.bodies[seen]).all() and np.isnan(poses.bodies[~seen]).all()
    win = stream_windows(session, raw_samples=0, start_t=(term.start_transient or {}).get("until_s"))
    np.testing.assert_array_equal(poses.t, win.t)  # the same nodes, the bodies as calibrate_motion reduces them
    np.testing.assert_allclose(poses.bodies[seen], bodies_at_samples(session, win)["bodies"][seen], atol=1e-12)
