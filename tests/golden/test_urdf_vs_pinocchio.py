"""The URDF route against pinocchio, an independent implementation of URDF kinematics.

For the arms shipped by example-robot-data and the real TIAGo description: the moving link's pose
in the base link and its frame Jacobian (linear and angular velocity in base axes) from platkit's
CasADi functions agree with pinocchio to 1e-9 (m, rad) at random configurations within the joint
limits, at nominal parameters.
"""
from importlib import metadata
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from platkit.geometry import matrix_from_quat
from platkit.urdf import chain_spec, frame_jacobian, read_urdf, serial_chain

TOL = 1e-9
N_CONFIGS = 25
ROBOTS = Path(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data")) / "robots"
TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if not TIAGO.is_file():  # a checkout whose shared/ sits inside it
    TIAGO = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"

CASES = [
    # (urdf, base link, moving link, expected controls)
    (ROBOTS / "ur_description/urdf/ur5_robot.urdf", "world", "tool0", 6),
    (ROBOTS / "panda_description/urdf/panda.urdf", "panda_link0", "panda_hand_tcp", 7),
    (ROBOTS / "xarm_description/urdf/xarm7.urdf", "world", "link_eef", 7),
    (ROBOTS / "z1_description/urdf/z1.urdf", "world", "gripperMover", 7),
    (ROBOTS / "so_arm_description/urdf/so101.urdf", "base_link", "gripper_frame_link", 5),
    (TIAGO, "base_link", "wrist_ft_tool_link", 8),
]


def _pinocchio_pose_and_jacobian(model, data, chain, u):
    """Moving link in base link (R, p) and its 6 x n_u Jacobian in base axes, from pinocchio."""
    q = pin.neutral(model)
    cols_v = []
    for j, value in zip(chain.actuated, u):
        joint = model.joints[model.getJointId(j.name)]
        if joint.nq == 2:  # continuous joints are (cos, sin) in pinocchio
            q[joint.idx_q:joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            q[joint.idx_q] = value
        cols_v.append(joint.idx_v)
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    base = data.oMf[model.getFrameId(chain.base_link, pin.BODY)]
    fid = model.getFrameId(chain.moving_link, pin.BODY)
    tip = data.oMf[fid]
    rel = base.inverse() * tip
    J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL_WORLD_ALIGNED)[:, cols_v]
    Rb = base.rotation
    return rel.rotation, rel.translation, Rb.T @ J[:3], Rb.T @ J[3:]


@pytest.mark.parametrize("urdf, base, tip, n_u", CASES, ids=[c[0].stem for c in CASES])
def test_forward_and_jacobian_match_pinocchio(urdf, base, tip, n_u):
    assert urdf.is_file(), f"reference URDF missing: {urdf}"
    chain = serial_chain(read_urdf(urdf), base, tip)
    spec = chain_spec(chain, name="urdf", title=urdf.stem)
    assert spec.n_u == n_u
    jac = frame_jacobian(spec)
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    td = spec.nominal_td()
    lo, hi = spec.control_bounds()
    lo, hi = np.maximum(lo, -np.pi), np.minimum(hi, np.pi)
    rng = np.random.default_rng(7)
    worst = {"position": 0.0, "rotation": 0.0, "J_lin": 0.0, "J_ang": 0.0}
    for _ in range(N_CONFIGS):
        u = rng.uniform(lo, hi)
        q, X = (np.asarray(a).ravel() for a in spec.forward(u, td))
        J_lin, J_ang = (np.asarray(a) for a in jac(u, td))
        R_ref, X_ref, J_lin_ref, J_ang_ref = _pinocchio_pose_and_jacobian(model, data, chain, u)
        worst["position"] = max(worst["position"], np.max(np.abs(X - X_ref)))
        worst["rotation"] = max(worst["rotation"], np.max(np.abs(matrix_from_quat(q) - R_ref)))
        worst["J_lin"] = max(worst["J_lin"], np.max(np.abs(J_lin - J_lin_ref)))
        worst["J_ang"] = max(worst["J_ang"], np.max(np.abs(J_ang - J_ang_ref)))
    print(f"{urdf.name}: worst differences vs pinocchio {worst}")
    assert max(worst.values()) < TOL, f"{urdf.name}: platkit vs pinocchio {worst}"
    # the configurations were not degenerate: the chain moved the tip
    assert np.ptp([np.asarray(spec.forward(rng.uniform(lo, hi), td)[1]).ravel() for _ in range(3)], axis=0).max() > 1e-3
