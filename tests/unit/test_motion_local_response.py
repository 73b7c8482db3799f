"""The actuators' response as a diagnosis of a stream frees it (platkit.calibrate.motion.
LocalResponseTerm): its control offset is the exact response's at every theta; its Jacobian the
exact forward differences, reused while the response's change stays within LINEAR_SHARE of its
linear prediction, taken again past it; a subset of the nodes reads its rows, poses that are not
the stream's nodes get no offset."""
from __future__ import annotations

import numpy as np
from scipy import sparse

from platkit.calibrate.motion import LINEAR_FLOOR, LINEAR_SHARE, LocalResponseTerm, ResponseTerm
from platkit.calibrate.motion_start import fd_steps
from platkit.calibrate.response import ResponseModel
from platkit.poses import PoseSet


def _stream(cls=LocalResponseTerm):
    """A slow streamed log (two actuators, commands step-held at 50 Hz, sines of 0.1 and 0.17 Hz),
    its response model with per-actuator delays, the calibrated values, and the stream reduced to
    nodes at 3 Hz (each the mean of the 100 Hz samples of a third of a second)."""
    T = 0.5 + np.arange(1000) * 0.02
    U = np.column_stack([0.3 * np.sin(2 * np.pi * 0.1 * T), 0.2 * np.sin(2 * np.pi * 0.17 * T + 1.0)])
    model = ResponseModel("first_order", "step", 2, delays=True)
    theta0 = np.array([0.03, 0.05, 0.02, 0.004, -0.006])
    sample_t = np.arange(1.0, 19.5, 0.01)
    per = 33
    P = len(sample_t) // per
    proj = sparse.csr_matrix((np.full(P * per, 1 / per), np.arange(P * per), np.arange(0, P * per + 1, per)),
                             shape=(P, len(sample_t)))
    term = cls(model, T, U, ["a", "b"], theta0, fd_steps(model, theta0), proj=proj, sample_t=sample_t)
    nodes = PoseSet(platform="x", controls=np.zeros((P, 2)), markers=np.zeros((P, 1, 3)), marker_names=["m"],
                    t=proj @ sample_t, extras={"node": np.arange(P)})
    nodes.controls = ResponseTerm.reached(term, theta0, nodes).copy()
    return term, nodes, theta0


def _jac(term, theta, poses):
    return term.offset_jacobians(theta, poses, 2, None, None)[0]


def test_offsets_exact_and_the_jacobian_kept_while_the_response_is_linear():
    local, poses, theta0 = _stream()
    exact = _stream(ResponseTerm)[0]
    assert not local.uses_kinematics
    d0 = _jac(local, theta0, poses)
    assert np.array_equal(d0, _jac(exact, theta0, poses))  # the exact forward differences
    assert np.abs(d0).max() > 0.1  # the shift moves the controls by their speed
    x0 = local.reached(theta0, poses)

    def linear(theta):  # whether the rule keeps the Jacobian of theta0 at theta
        x = local.reached(theta, poses)
        return np.abs(x - x0 - d0 @ (theta - theta0)).max() <= LINEAR_SHARE * np.abs(x - x0).max() + LINEAR_FLOOR

    near = theta0 + np.array([2e-4, 5e-4, -4e-4, 1e-4, 2e-4])
    far = theta0 + np.array([0.0, 0.3, 0.3, 0.0, 0.0])  # lags of a third of a second: a sine bent
    assert linear(near) and not linear(far)
    for theta in (near, far):
        assert np.allclose(local.control_offset(theta, poses, 2), exact.control_offset(theta, poses, 2), atol=1e-15)
    assert np.array_equal(_jac(local, near, poses), d0)  # kept
    d_far = _jac(local, far, poses)
    assert np.array_equal(d_far, _jac(exact, far, poses))  # taken again, exactly, at far
    assert np.abs(d_far - d0).max() > 0.01


def test_a_subset_of_the_nodes_reads_its_own_rows_and_other_poses_none():
    local, poses, theta0 = _stream()
    rows = np.array([3, 10, 11, 40])
    sub = poses.subset(rows)
    moved = theta0 + 0.003
    assert np.allclose(local.control_offset(moved, sub, 2), local.control_offset(moved, poses, 2)[rows], atol=1e-15)
    assert np.array_equal(_jac(local, moved, sub), _jac(local, moved, poses)[rows])
    settled = PoseSet(platform="x", controls=np.ones((4, 2)), markers=np.zeros((4, 1, 3)), marker_names=["m"])
    assert not local.control_offset(moved, settled, 2).any()
    assert _jac(local, moved, settled).shape == (4, 2, 5) and not _jac(local, moved, settled).any()
