"""The velocity Jacobian built from twists (Sorokin eqs. 15-21) against pinocchio, the three
interchangeable forms of H, the twist transport, and the safe URDF reader."""
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from reference_robots import example_robot_urdf

from platkit.chains import KinematicChain
from platkit.chains.transforms import (
    compose_quat_vec,
    dual_quat_from_transform,
    dual_quat_multiply,
    interpolate_pose,
    pose_error,
    quat_vec_from_transform,
    slerp,
    transform_from_dual_quat,
    transform_from_quat_vec,
    transport_matrix,
    unit_twist,
)
from platkit.errors import BadDescription, BadInput
from platkit.geometry import matrix_from_rotvec, quat_from_rotvec, rotvec_from_matrix

TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if not TIAGO.is_file():  # the checkout beside shared/, as CI has it
    TIAGO = Path("/work/shared/data/real/tiago/tiago_48_schunk.urdf")

ROBOTS = [
    (lambda: example_robot_urdf("ur_description/urdf/ur5_robot.urdf"), ["tool0", "wrist_2_link", "ee_link"]),
    (lambda: example_robot_urdf("panda_description/urdf/panda.urdf"), ["panda_hand", "panda_link4", "panda_leftfinger"]),
    (lambda: TIAGO, ["wrist_ft_tool_link", "arm_4_link", "gripper_left_finger_link", "head_2_link"]),
]
BASES = {"world": pin.LOCAL_WORLD_ALIGNED, "local": pin.LOCAL, "world_origin": pin.WORLD}


@pytest.mark.parametrize("path, frames", ROBOTS, ids=["ur5", "panda", "tiago"])
def test_jacobian_equals_pinocchio(path, frames):
    chain = KinematicChain.from_urdf(path())
    rng = np.random.default_rng(7)
    data = chain.model.createData()
    worst = 0.0
    for _ in range(5):
        theta = chain.random(rng)
        q = chain.pin_configuration(theta)
        for frame in frames:
            fid = chain.frame_id(frame)
            for basis, ref in BASES.items():
                J_ref = pin.computeFrameJacobian(chain.model, data, q, fid, ref)
                J = chain.jacobian(theta, frame, basis)
                assert J.shape == J_ref.shape
                worst = max(worst, float(np.abs(J - J_ref).max()))
                assert np.allclose(J, J_ref, atol=1e-9, rtol=0), (frame, basis)
    # the columns of joints that do not carry the frame are exactly zero
    J = chain.jacobian(theta, frames[0])
    carried = {jt.column for jt in chain.supporting_joints(frames[0])}
    for i in range(chain.n):
        if i not in carried:
            assert np.all(J[:, i] == 0)
    assert worst < 1e-9


def test_jacobian_matches_finite_differences_of_placements():
    chain = KinematicChain.from_urdf(example_robot_urdf("panda_description/urdf/panda.urdf"))
    theta = chain.random(np.random.default_rng(3))
    J = chain.jacobian(theta, "panda_hand", "world")
    H0 = chain.placement(theta, "panda_hand")
    h = 1e-7
    for i in range(7):
        t = theta.copy()
        t[i] += h
        H1 = chain.placement(t, "panda_hand")
        v = (H1[:3, 3] - H0[:3, 3]) / h
        w = rotvec_from_matrix(H1[:3, :3] @ H0[:3, :3].T) / h
        assert np.allclose(J[:3, i], v, atol=1e-6)
        assert np.allclose(J[3:, i], w, atol=1e-6)


def test_relative_jacobian_is_the_derivative_of_the_relative_placement():
    chain = KinematicChain.from_urdf(example_robot_urdf("talos_data/robots/talos_reduced.urdf"))
    rng = np.random.default_rng(5)
    theta = chain.random(rng, margin=0.1)
    J = chain.relative_jacobian(theta, "gripper_left_base_link", "gripper_right_base_link")
    H0 = chain.relative_placement(theta, "gripper_left_base_link", "gripper_right_base_link")
    h = 1e-7
    nonzero = 0
    for i in range(chain.n):
        t = theta.copy()
        t[i] += h
        H1 = chain.relative_placement(t, "gripper_left_base_link", "gripper_right_base_link")
        v = (H1[:3, 3] - H0[:3, 3]) / h
        w = rotvec_from_matrix(H1[:3, :3] @ H0[:3, :3].T) / h
        assert np.allclose(J[:, i], np.concatenate([v, w]), atol=2e-6), chain.joint_names[i]
        nonzero += bool(np.any(J[:, i] != 0))
    # both arms move it; the torso joints carry both grippers and cancel, the legs do nothing
    torso = [chain.joint_names.index(n) for n in ("torso_1_joint", "torso_2_joint")]
    assert np.all(J[:, torso] == 0)
    assert nonzero == 14


def test_unit_twists_and_transport():
    assert np.array_equal(unit_twist("revolute", [0, 0, 2]), [0, 0, 0, 0, 0, 1])
    assert np.array_equal(unit_twist("prismatic", [0, 3, 0], scale=2.0), [0, 2, 0, 0, 0, 0])
    with pytest.raises(ValueError):
        unit_twist("spherical", [1, 0, 0])
    # eq. 18: rotating about z at the origin moves the point (1, 0, 0) along +y
    twist = transport_matrix([1.0, 0, 0]) @ unit_twist("revolute", [0, 0, 1])
    assert np.allclose(twist, [0, 1, 0, 0, 0, 1])


def test_the_three_forms_of_h_compose_alike():
    rng = np.random.default_rng(11)
    Hs = []
    for _ in range(4):
        H = np.eye(4)
        H[:3, :3] = matrix_from_rotvec(rng.normal(size=3))
        H[:3, 3] = rng.normal(size=3)
        Hs.append(H)
    product = Hs[0] @ Hs[1] @ Hs[2] @ Hs[3]
    dq = dual_quat_from_transform(Hs[0])
    qv = quat_vec_from_transform(Hs[0])
    for H in Hs[1:]:
        dq = dual_quat_multiply(dq, dual_quat_from_transform(H))
        qv = compose_quat_vec(qv, quat_vec_from_transform(H))
    assert np.allclose(transform_from_dual_quat(dq), product, atol=1e-12)
    assert np.allclose(transform_from_quat_vec(*qv), product, atol=1e-12)
    assert np.allclose(transform_from_dual_quat(dual_quat_from_transform(Hs[2])), Hs[2], atol=1e-14)


def test_pose_error_and_slerp():
    P = np.eye(4)
    P[:3, :3] = matrix_from_rotvec([0, 0, np.pi / 2])
    U = P.copy()
    U[:3, 3] = [1.0, 0, 0]
    U[:3, :3] = matrix_from_rotvec([0.1, 0, 0]) @ P[:3, :3]
    E = pose_error(P, U)
    assert np.allclose(E, [1, 0, 0, 0.1, 0, 0])
    # in the link's own basis (rotated 90 deg about z) the same error reads differently
    assert np.allclose(pose_error(P, U, "local"), [0, -1, 0, 0, -0.1, 0])
    q0 = quat_from_rotvec(np.array([0, 0, 0.0]))
    q1 = quat_from_rotvec(np.array([0, 0, 1.0]))
    assert np.allclose(slerp(q0, q1, 0.25), quat_from_rotvec(np.array([0, 0, 0.25])))
    mid = interpolate_pose(P, U, 0.5)
    assert np.allclose(mid[:3, 3], [0.5, 0, 0])


def test_urdf_reader_refuses_entities_and_names_the_file(tmp_path):
    bad = tmp_path / "evil.urdf"
    bad.write_text('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY a "aaaa">]><robot name="r">&a;</robot>')
    with pytest.raises(BadDescription, match="evil.urdf.*DTDs and XML entities are not accepted"):
        KinematicChain.from_urdf(bad)
    notxml = tmp_path / "broken.urdf"
    notxml.write_text("<robot name='r'><link name='a'></robot>")
    with pytest.raises(BadDescription, match="broken.urdf:.*not well-formed XML"):
        KinematicChain.from_urdf(notxml)
    with pytest.raises(BadInput, match="no such URDF file"):
        KinematicChain.from_urdf(tmp_path / "missing.urdf")
    chain = KinematicChain.from_urdf(example_robot_urdf("ur_description/urdf/ur5_robot.urdf"))
    with pytest.raises(BadInput, match="no link named 'nope'; links: .*tool0"):
        chain.frame_id("nope")


def test_continuous_joints_map_to_cos_sin():
    chain = KinematicChain.from_urdf(TIAGO)
    wheel = chain.joint_names.index("wheel_left_joint")
    assert chain.kinds[wheel] == "continuous" and not np.isfinite(chain.lower[wheel])
    theta = chain.neutral()
    theta[wheel] = 0.7
    q = chain.pin_configuration(theta)
    jm = chain.model.joints[chain.joints[wheel].index]
    assert np.allclose(q[jm.idx_q:jm.idx_q + 2], [np.cos(0.7), np.sin(0.7)])
