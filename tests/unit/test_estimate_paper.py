"""The paper's method (Burlakov et al. 2018): its three steps, and the default beating it."""
from __future__ import annotations

import numpy as np
import pytest
from test_estimate import Truth, prediction_error

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.paper import (
    _mismatch_operator,
    _residual_from,
    calibrate_paper,
    fit_qdelta,
    marker_frame,
    paper_J,
    qdelta_jacobian,
)
from platkit.geometry import matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, quat_normalize
from platkit.plugins import get_platform
from platkit.poses import PoseSet


def _same_rotation(a, b, atol):
    return min(np.max(np.abs(a - b)), np.max(np.abs(a + b))) < atol


def test_step1_procrustes_recovers_the_rigid_body():
    rng = np.random.default_rng(0)
    body = rng.normal(0, 0.2, (5, 3))
    q = quat_normalize(rng.normal(size=(40, 4)))
    shift = rng.normal(0, 1, (40, 3))
    markers = np.einsum("nab,mb->nma", matrix_from_quat(q), body) + shift[:, None, :]
    C, q_hat, S, iterations = marker_frame(markers)
    assert iterations < 20
    assert C == pytest.approx(shift + (matrix_from_quat(q) @ body.mean(axis=0)), abs=1e-12)
    # the recovered frame is the true one up to a constant rotation: S' is the centred body turned
    d = np.linalg.norm(S[:, None] - S[None], axis=2)
    d_true = np.linalg.norm(body[:, None] - body[None], axis=2)
    assert d == pytest.approx(d_true, abs=1e-12)
    rel = quat_multiply(quat_conjugate(q_hat), q)  # constant for every pose
    assert all(_same_rotation(rel[0], r, 1e-9) for r in rel)


def test_step3_finds_q_delta_and_the_base_rotation_on_the_sphere():
    rng = np.random.default_rng(1)
    q_model = quat_normalize(rng.normal(size=(30, 4)))
    a = quat_from_rotvec(np.array([0.3, -0.2, 1.0]))
    delta = quat_from_rotvec(np.array([-0.5, 0.1, 0.2]))
    q_real = quat_multiply(quat_multiply(a[None], q_model), quat_conjugate(delta)[None])
    assert paper_J(a, delta, q_real, q_model) == pytest.approx(0, abs=1e-12)
    a_hat, d_hat = fit_qdelta(q_real, q_model, quat_from_rotvec(np.array([0.25, -0.1, 0.9])),
                              quat_from_rotvec(np.array([-0.4, 0.0, 0.3])))
    assert np.linalg.norm(a_hat) == pytest.approx(1) and np.linalg.norm(d_hat) == pytest.approx(1)
    assert _same_rotation(a_hat, a, 1e-7) and _same_rotation(d_hat, delta, 1e-7)
    # the paper's literal assumption (mocap frame = base frame) fits q_delta alone
    q_real0 = quat_multiply(q_model, quat_conjugate(delta)[None])
    _, d0 = fit_qdelta(q_real0, q_model, fit_base=False)
    assert _same_rotation(d0, delta, 1e-7)


def test_step3_jacobian_is_exact():
    rng = np.random.default_rng(2)
    q_real, q_model = quat_normalize(rng.normal(size=(7, 4))), quat_normalize(rng.normal(size=(7, 4)))
    a, d = quat_normalize(rng.normal(size=4)), quat_normalize(rng.normal(size=4))
    M = _mismatch_operator(q_real, q_model)
    r0 = _residual_from(a, d, M).ravel()
    J = qdelta_jacobian(a, d, M)
    for j in range(6):
        e = np.zeros(3)
        e[j % 3] = 1e-7
        a2 = quat_normalize(quat_multiply(a, quat_from_rotvec(e))) if j >= 3 else a
        d2 = quat_normalize(quat_multiply(d, quat_from_rotvec(e))) if j < 3 else d
        fd = (_residual_from(a2, d2, M).ravel() - r0) / 1e-7
        assert np.max(np.abs(fd - J[:, j])) < 1e-6


def test_paper_lowers_its_functional_and_the_default_beats_it():
    spec = get_platform("psvr")
    truth = Truth(spec, seed=41, n_markers=4, marker_spread=0.2)
    poses = truth.poses(60, 1e-4)
    Y = poses.markers.copy()
    Y[3, 1] = np.nan  # the paper leaves out poses with a missing marker
    poses = PoseSet("psvr", poses.controls, Y, poses.marker_names)
    pap = calibrate_paper(poses, spec, max_evaluations=400)
    info = pap.paper
    assert info["poses_used"] == poses.n_poses - 1 and info["evaluations"] <= 402
    assert info["J_after"] < 0.5 * info["J_before"]
    assert pap.rms_after < pap.rms_before
    assert pap.method == "paper" and not np.isfinite(pap.td_std).any()
    lsq = calibrate(poses, spec)
    assert prediction_error(lsq, truth) < 0.5 * prediction_error(pap, truth)
    assert lsq.time_s < pap.time_s
