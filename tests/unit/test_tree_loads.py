"""Gravity loads of a whole URDF tree (platkit.tree_loads) against pinocchio computed otherwise:
the potential energy's derivative, pinocchio's own mimic joints, and the mass-moment regressor."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from platkit.errors import BadDescription, BadInput
from platkit.tree_loads import Payload, TreeLoads

INERTIA = '<inertia ixx="0.01" iyy="0.02" izz="0.015" ixy="0" ixz="0" iyz="0"/>'


def _link(name, mass=None, com="0 0 0"):
    if mass is None:
        return f'<link name="{name}"/>'
    return (f'<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>{INERTIA}'
            f'</inertial></link>')


def _joint(name, parent, child, xyz, axis, kind="revolute", mimic=""):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="0.1 -0.2 0.3"/><axis xyz="{axis}"/>'
            f'<limit lower="-2" upper="2" effort="1" velocity="1"/>{mimic}</joint>')


def _tree(tmp_path, mimic_master="t1", masses=True):
    """A torso (t1, then t2 coupled to t1) carrying two arms (l1-l2, r1 prismatic-r2) and a
    head on a fixed joint: loads cross branches."""
    m = (lambda v: v) if masses else (lambda v: None)
    links = [_link("base"), _link("torso1", m(3.0), "0.02 0 0.2"), _link("torso2", m(5.0), "0 0.03 0.25"),
             _link("head", m(2.0), "0 0 0.1"), _link("l_up", m(1.5), "0.1 0.02 -0.1"),
             _link("l_lo", m(1.0), "0.15 0 0"), _link("r_up", m(1.2), "0 -0.1 0.05"),
             _link("r_lo", m(0.8), "0.05 0.1 0.1")]
    joints = [_joint("t1", "base", "torso1", "0 0 0.5", "0 0 1"),
              _joint("t2", "torso1", "torso2", "0 0 0.3", "0 1 0",
                     mimic=f'<mimic joint="{mimic_master}" multiplier="0.7" offset="0.05"/>'),
              '<joint name="neck" type="fixed"><parent link="torso2"/><child link="head"/>'
              '<origin xyz="0 0 0.4"/></joint>',
              _joint("l1", "torso2", "l_up", "0 0.2 0.35", "0 1 0"),
              _joint("l2", "l_up", "l_lo", "0.3 0 0", "1 0 1"),
              _joint("r1", "torso2", "r_up", "0 -0.2 0.35", "0 0 1", kind="prismatic"),
              _joint("r2", "r_up", "r_lo", "0 -0.3 0", "0 1 0")]
    path = tmp_path / "tree.urdf"
    path.write_text(f'<robot name="tree">{"".join(links)}{"".join(joints)}</robot>')
    return path


CONFIGS = np.array([[0.3, 0.4, -0.7, 0.1, 0.5], [-1.0, -0.2, 1.1, -0.05, -0.8], [0.0, 1.2, 0.3, 0.2, 0.0]])
NAMES = ["t1", "l1", "l2", "r1", "r2"]


def test_torques_are_the_potential_energys_slope_at_every_joint(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    assert T.recorded == NAMES and T.mimic == {"t2": ("t1", 0.7, 0.05)}
    Q = T.configuration(NAMES, CONFIGS)
    assert np.allclose(Q[:, T.index["t2"]], 0.7 * CONFIGS[:, 0] + 0.05)
    L = T.loads(Q)
    free = pin.buildModelFromUrdf(str(T.path))  # every joint free: V(q) of the physical tree
    data = free.createData()
    eps = 1e-6
    for q, tau in zip(Q, L.torque):
        slope = [(pin.computePotentialEnergy(free, data, q + eps * e) - pin.computePotentialEnergy(free, data, q - eps * e))
                 / (2 * eps) for e in np.eye(len(q))]
        assert np.allclose(tau, slope, atol=1e-6)
    assert np.all(np.abs(L.torque).max(axis=0) > 0.1)  # every joint loaded, the coupled one too


def test_mimic_folded_into_its_master_is_pinocchios_own_mimic_model(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    Q = T.configuration(NAMES, CONFIGS)
    coupled = pin.buildModelFromUrdf(str(T.path), mimic=True)
    assert coupled.nq == len(NAMES)
    data = coupled.createData()
    want = np.array([pin.computeGeneralizedGravity(coupled, data, q) for q in CONFIGS])
    assert np.allclose(T.generalized(T.loads(Q).torque), want, atol=1e-9)
    # the load model of a chain that locks the coupled joint at zero is wrong (issue 24's -122 N m)
    locked = Q.copy()
    locked[:, T.index["t2"]] = 0.0
    assert np.abs(T.loads(locked).torque - T.loads(Q).torque)[:, T.index["t1"]:T.index["t2"] + 1].max() > 0.1


def test_moments_and_torques_are_linear_in_the_mass_moments(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    Q = T.configuration(NAMES, CONFIGS)
    L = T.loads(Q)
    Y = T.moment_regressor(Q, L)
    phi = T.mass_moments()
    assert np.allclose(Y @ phi, L.moment, atol=1e-9)
    assert np.allclose(T.torque_regressor(Q, L, Y) @ phi, L.torque, atol=1e-9)
    # the moment is the whole 3-D moment: off-axis components are there (link bending's load)
    off = L.moment - L.torque[..., None] * T.axes[None]
    assert np.abs(off).max() > 1.0


def test_payload_adds_its_weights_slope(tmp_path):
    path = _tree(tmp_path)
    bare, loaded = TreeLoads(path), TreeLoads(path, Payload("l_lo", 2.5, (0.1, 0.0, 0.05)))
    Q = bare.configuration(NAMES, CONFIGS)
    free = pin.buildModelFromUrdf(str(path))
    data = free.createData()
    fid = free.getFrameId("l_lo")

    def payload_height(q):
        pin.framesForwardKinematics(free, data, q)
        return (data.oMf[fid].act(np.array([0.1, 0.0, 0.05])))[2]

    eps = 1e-6
    for q, tb, tl in zip(Q, bare.loads(Q).torque, loaded.loads(Q).torque):
        slope = [2.5 * 9.81 * (payload_height(q + eps * e) - payload_height(q - eps * e)) / (2 * eps) for e in np.eye(len(q))]
        assert np.allclose(tl - tb, slope, atol=1e-6)


def test_a_tree_without_inertias_weighs_nothing(tmp_path):
    T = TreeLoads(_tree(tmp_path, masses=False))
    assert T.total_mass == 0.0
    assert np.allclose(T.loads(T.configuration(NAMES, CONFIGS)).torque, 0.0)


def test_bad_input_names_the_field(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    with pytest.raises(BadInput, match="'x9' is not a moving joint"):
        T.configuration(["t1", "x9"], np.zeros((1, 2)))
    with pytest.raises(BadInput, match="'t2' is a mimic joint"):
        T.configuration(["t2"], np.zeros((1, 1)))
    with pytest.raises(BadInput, match="link 'nowhere'"):
        TreeLoads(T.path, Payload("nowhere", 1.0))
    with pytest.raises(BadInput, match="mass -1"):
        TreeLoads(T.path, Payload("l_lo", -1.0))
    bad = tmp_path / "bad"
    bad.mkdir()
    text = _tree(bad).read_text().replace('<mass value="1.5"/>', '<mass value="-1.5"/>')
    (bad / "tree.urdf").write_text(text)
    with pytest.raises(BadDescription, match="mass"):
        TreeLoads(bad / "tree.urdf")


def test_the_moment_is_the_subtrees_weight_about_the_joint(tmp_path):
    """About its pivot: a revolute joint's origin; the prismatic r1's placement on its parent,
    where its frame sits at zero travel (where the slide is guided), not where it has slid to."""
    T = TreeLoads(_tree(tmp_path))
    Q = T.configuration(NAMES, CONFIGS)
    L = T.loads(Q)
    r1 = T.index["r1"]
    at_zero = Q.copy()
    at_zero[:, r1] = 0.0
    assert np.allclose(L.pivot[:, r1], T.loads(at_zero).origin[:, r1], atol=1e-12)
    assert np.abs(L.pivot[:, r1] - L.origin[:, r1]).max() > 0.1  # it slid 0.2 m
    others = [j for j in range(len(T.joints)) if j != r1]
    assert np.array_equal(L.pivot[:, others], L.origin[:, others])
    data = T.model.createData()
    g = T.model.gravity.linear
    for k, q in enumerate(Q):
        pin.centerOfMass(T.model, data, q, True)  # data.com[j], data.mass[j]: the subtree below joint j
        for j in range(len(T.joints)):
            com = data.oMi[j + 1].act(data.com[j + 1])  # pinocchio keeps a subtree's CoM in its joint's frame
            held = -np.cross(com - L.pivot[k, j], data.mass[j + 1] * g)
            assert np.allclose(L.rotation[k, j] @ L.moment[k, j], held, atol=1e-9)


def test_a_continuous_joint_loads_as_a_revolute_one(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    wheel = tmp_path / "wheel"
    wheel.mkdir()
    text = _tree(wheel).read_text().replace('<joint name="l2" type="revolute">', '<joint name="l2" type="continuous">')
    (wheel / "tree.urdf").write_text(text)
    C = TreeLoads(wheel / "tree.urdf")
    assert C.model.nq == T.model.nq + 1  # pinocchio keeps (cos, sin) for it
    Q = T.configuration(NAMES, CONFIGS)
    assert np.allclose(C.loads(Q).torque, T.loads(Q).torque, atol=1e-12)


def test_a_floating_joint_is_held_at_rest(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    free = tmp_path / "free"
    free.mkdir()
    (free / "tree.urdf").write_text(_tree(free).read_text().replace('<joint name="neck" type="fixed">',
                                                                    '<joint name="neck" type="floating">'))
    F = TreeLoads(free / "tree.urdf")
    assert F.held == ["neck"] and F.joints == T.joints
    Q = T.configuration(NAMES, CONFIGS)
    assert np.allclose(F.loads(Q).torque, T.loads(Q).torque, atol=1e-12)


def test_each_joints_slope_is_its_torques_derivative_in_its_own_value(tmp_path):
    T = TreeLoads(_tree(tmp_path))
    Q = T.configuration(NAMES, CONFIGS)
    S = T.slopes(Q)
    h = 1e-6
    for j in range(len(T.joints)):  # the coupled t2 held where it is, as every other joint
        up, down = Q.copy(), Q.copy()
        up[:, j] += h
        down[:, j] -= h
        assert np.allclose(S[:, j], (T.loads(up).torque[:, j] - T.loads(down).torque[:, j]) / (2 * h), atol=1e-6)
    assert np.abs(S).max() > 1.0


def test_a_link_named_as_a_joint_is_found_as_the_link(tmp_path):
    """Unitree's Z1 arm (example-robot-data's b1-z1.urdf) names a fixed joint and its child link
    both 'gripperStator': pinocchio then holds two frames of that name, and the link is meant."""
    text = _tree(tmp_path).read_text().replace(
        "</robot>", '<link name="tool"/><joint name="tool" type="fixed"><parent link="l_lo"/><child link="tool"/>'
                    '<origin xyz="0.2 0 0"/></joint></robot>')
    path = tmp_path / "named.urdf"
    path.write_text(text)
    T = TreeLoads(path, payload=Payload("tool", 1.5, (0.0, 0.0, 0.1)))
    Q = T.configuration(NAMES, CONFIGS)
    origin, _ = T.link_placements(Q, "tool")
    lo, lo_R = T.link_placements(Q, "l_lo")
    assert np.allclose(origin, lo + lo_R @ np.array([0.2, 0.0, 0.0]))
    assert T._payload_mass()[T.index["l2"]] == 1.5
    bare = tmp_path / "named_bare.urdf"
    bare.write_text(_tree(tmp_path, masses=False).read_text().replace(
        "</robot>", '<link name="tool"/><joint name="tool" type="fixed"><parent link="l_lo"/><child link="tool"/>'
                    '<origin xyz="0.2 0 0"/></joint></robot>'))
    assert TreeLoads(bare, prior=True).prior
