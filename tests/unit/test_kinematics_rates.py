"""Velocity and acceleration kinematics from the residual, against finite differences of IK/FK
along a trajectory; the Stewart stand's paper relations (eqs. 4-8); conditioning."""
import numpy as np
import pytest

from platkit import get_platform
from platkit.geometry import matrix_from_quat, rotvec_from_matrix
from platkit.kinematics import PlatformModel
from platkit_stewart import leg_kinematics

H = 1e-4  # s, finite-difference step along the trajectory


@pytest.fixture(scope="module")
def spec():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def model(spec):
    return PlatformModel(spec)


def trajectory(spec, t):
    """A smooth 6-DOF motion around neutral: pose coordinates at time t (s)."""
    return spec.neutral_p() + np.array([
        0.2 * np.sin(t), 0.1 * np.cos(1.3 * t), 0.15 * np.sin(0.7 * t),
        0.1 * np.sin(t), 0.08 * np.cos(0.9 * t), 0.12 * np.sin(1.1 * t),
    ])


def fd(f, t, h=H):
    """(f(t), f'(t), f''(t)) by central differences."""
    a, b, c = f(t - h), f(t), f(t + h)
    return b, (c - a) / (2 * h), (c - 2 * b + a) / h**2


def omega_fd(model, spec, t, h=H):
    R0 = matrix_from_quat(model.pose(trajectory(spec, t - h))[0])
    R1 = matrix_from_quat(model.pose(trajectory(spec, t + h))[0])
    return rotvec_from_matrix(R1 @ R0.T) / (2 * h)


@pytest.mark.parametrize("t", [0.0, 0.4, 1.7, 2.9])
def test_pose_coordinate_form_against_finite_differences(spec, model, t):
    p, pd, pdd = fd(lambda s: trajectory(spec, s), t)
    u, ud, udd = fd(lambda s: model.inverse(*model.pose(trajectory(spec, s))), t)
    np.testing.assert_allclose(model.inverse_velocity(p, pd), ud, atol=1e-8)
    ud2, udd2 = model.inverse_acceleration(p, pd, pdd)
    np.testing.assert_allclose(ud2, ud, atol=1e-8)
    np.testing.assert_allclose(udd2, udd, atol=2e-6)
    # forward: from the legs' motion back to the platform's (paper eqs. 10, 11)
    np.testing.assert_allclose(model.forward_velocity(u, ud), pd, atol=1e-8)
    pd3, pdd3 = model.forward_acceleration(u, ud, udd)
    np.testing.assert_allclose(pd3, pd, atol=1e-8)
    np.testing.assert_allclose(pdd3, pdd, atol=2e-6)
    assert np.max(np.abs(udd)) > 1e-2  # the motion really accelerates the legs


@pytest.mark.parametrize("t", [0.3, 2.2])
def test_twist_form_against_finite_differences(spec, model, t):
    X_of = lambda s: model.pose(trajectory(spec, s))[1]  # noqa: E731
    X, v, a = fd(X_of, t)
    q = model.pose(trajectory(spec, t))[0]
    omega = omega_fd(model, spec, t)
    h2 = 1e-3
    alpha = (omega_fd(model, spec, t + h2) - omega_fd(model, spec, t - h2)) / (2 * h2)
    u, ud, udd = fd(lambda s: model.inverse(*model.pose(trajectory(spec, s))), t)
    np.testing.assert_allclose(model.inverse_velocity_twist(q, X, v, omega), ud, atol=1e-8)
    ud2, udd2 = model.inverse_acceleration_twist(q, X, v, omega, a, alpha)
    np.testing.assert_allclose(udd2, udd, atol=2e-6)
    v3, om3 = model.forward_velocity_twist(u, ud)
    np.testing.assert_allclose(v3, v, atol=1e-8)
    np.testing.assert_allclose(om3, omega, atol=1e-8)
    v4, om4, a4, al4 = model.forward_acceleration_twist(u, ud, udd)
    np.testing.assert_allclose(a4, a, atol=2e-6)
    np.testing.assert_allclose(al4, alpha, atol=2e-6)


def test_paper_leg_relations_match_the_generic_derivation(spec, model):
    rng = np.random.default_rng(7)
    for _ in range(5):
        p = spec.neutral_p() + rng.uniform(-1, 1, 6) * np.array([0.3, 0.3, 0.2, 0.15, 0.15, 0.15])
        q, X = model.pose(p)
        v, om, a, al = rng.normal(0, 0.5, (4, 3))
        legs = leg_kinematics(spec, q, X, v, om, a, al)
        ud, udd = model.inverse_acceleration_twist(q, X, v, om, a, al)
        np.testing.assert_allclose(legs["lengths"], model.inverse(q, X, strict=False), atol=1e-12)
        np.testing.assert_allclose(legs["rates"], ud, atol=1e-12)  # eq. 5
        np.testing.assert_allclose(legs["accelerations"], udd, atol=1e-12)  # eq. 8, sign corrected
        # eq. 7: the leg's angular velocity turns the leg into the transverse joint velocity
        n = legs["directions"]
        V_perp = legs["joint_velocities"] - np.sum(legs["joint_velocities"] * n, axis=0) * n
        np.testing.assert_allclose(np.cross(legs["leg_angular_velocities"].T, legs["legs"].T).T, V_perp, atol=1e-12)
        np.testing.assert_allclose(np.sum(legs["leg_angular_velocities"] * n, axis=0), 0, atol=1e-12)


def test_paper_printed_sign_of_eq8_would_be_wrong(spec, model):
    """The centripetal term enters with a plus: the paper's minus misses the FD truth."""
    q, X = model.pose(spec.neutral_p())
    om = np.array([0.0, 0.0, 0.5])
    legs = leg_kinematics(spec, q, X, np.zeros(3), om, np.zeros(3), np.zeros(3))
    wl2 = np.sum(legs["leg_angular_velocities"] ** 2, axis=0)
    printed = np.sum(legs["joint_accelerations"] * legs["directions"], axis=0) - legs["lengths"] * wl2
    _, udd = model.inverse_acceleration_twist(q, X, np.zeros(3), om, np.zeros(3), np.zeros(3))
    assert np.max(np.abs(printed - udd)) > 1e-3
    np.testing.assert_allclose(legs["accelerations"], udd, atol=1e-12)


def test_conditioning_and_the_yaw_singularity(spec, model):
    p0 = spec.neutral_p()
    c0 = model.conditioning(p0)
    assert 1.0 <= c0.condition_number < 3.0
    assert 0.5 < c0.characteristic_length < 5.0  # m, about the platform's size
    singular = p0.copy()
    singular[5] = np.pi / 2  # the classic 6-3 singularity: platform turned 90 degrees about z
    cs = model.conditioning(singular)
    assert cs.inverse_condition < 1e-10 and cs.condition_number > 1e10
    near = p0.copy()
    near[5] = np.radians(80)
    cn = model.conditioning(near)
    true_distance = np.radians(10) * cn.characteristic_length
    assert 0.5 * true_distance < cn.distance_to_singularity < 2.0 * true_distance
    assert c0.distance_to_singularity > cn.distance_to_singularity
    flagged = model.near_singular(np.array([p0, near, singular]), threshold=0.05)
    assert flagged.tolist() == [2]
    # the least-felt motion at the singularity is mostly a rotation about z
    assert int(np.argmax(np.abs(cs.direction))) == 5
