"""Compliance of a URDF tree as diagnosis fits it (plugins/platkit_effects/tree_compliance.py and
compliance.py): the whole tree's loads, a mimic joint's elasticity and link bending as rotations
at the joint checked against pinocchio's kinematics, the fixed point, the mass-moment route."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects import Compliance, LinkBending
from platkit_effects.compliance import actuator_loads
from platkit_effects.tree_compliance import (
    JointRotationTerm,
    MassMomentTerm,
    across_axes,
    deflected_slope,
    deflected_torque,
    load_state,
    tree_stand,
)
from platkit_effects.tree_joints import JointsComplianceTerm
from platkit_effects.tree_mimic import coupled_offsets
from tests.unit.test_tree_loads import NAMES, _tree

U = np.array([[0.3, 0.4, -0.7], [-1.0, -0.2, 1.1], [0.0, 1.2, 0.3], [0.6, -0.9, 0.2], [-0.4, 0.7, -1.2]])


def _poses(spec, controls):
    n = len(controls)
    return PoseSet(spec.name, np.asarray(controls, float), np.zeros((n, 1, 3)), ["m"], length_unit="m")


def _moving_placement(free, q, link="l_lo"):
    data = free.createData()
    pin.framesForwardKinematics(free, data, q)
    M = data.oMf[free.getFrameId(link)]
    return M.translation.copy(), M.rotation.copy()


@pytest.fixture()
def arm(tmp_path):
    return get_platform("urdf", _tree(tmp_path), moving_link="l_lo")


def test_loads_are_the_whole_trees_with_the_mimic_joint_following(arm):
    stand = tree_stand(arm)
    assert stand.joints == ["t1", "l1", "l2"] and stand.chain == ["t1", "t2", "l1", "l2"]
    T = stand.loads
    Q = T.configuration(["t1", "l1", "l2"], U)
    want = T.loads(Q).torque[:, [T.index[n] for n in ("t1", "l1", "l2")]]
    assert np.allclose(actuator_loads(arm, U), want)
    assert np.all(np.abs(Q[:, T.index["t2"]] - (0.7 * U[:, 0] + 0.05)) < 1e-12)


def test_a_mimic_joints_elasticity_turns_the_moving_frame_at_the_joint(arm):
    terms = Compliance().candidates(arm, _poses(arm, U))
    mimic = [t for t in terms if isinstance(t, JointRotationTerm)]
    assert [t.joint for t in mimic] == ["t2"] and len(terms) == 4  # a chain: no term of every joint
    stand = tree_stand(arm)
    T, S = stand.loads, load_state(stand, U)
    free = pin.buildModelFromUrdf(str(T.path))
    c = 1e-6
    X = np.array([_moving_placement(free, q)[0] for q in S.Q])
    off = mimic[0].pose_offset(np.array([c]), _poses(arm, U), None, X)
    for k, q in enumerate(S.Q):
        bent = q.copy()
        bent[T.index["t2"]] += c * S.loads.torque[k, T.index["t2"]]
        x1, R1 = _moving_placement(free, bent)
        x0, R0 = _moving_placement(free, q)
        assert np.allclose(off[k, :3], x1 - x0, rtol=0, atol=1e-9)
        assert np.allclose(off[k, 3:], pin.log3(R1 @ R0.T), rtol=0, atol=1e-9)


def test_link_bending_turns_about_the_axes_across_under_the_moment_there(arm):
    terms = LinkBending().candidates(arm, _poses(arm, U))
    assert [t.joint for t in terms] == ["t1", "t2", "l1", "l2"]
    stand = tree_stand(arm)
    T, S = stand.loads, load_state(stand, U)
    term = terms[2]  # l1: bending of the upper arm
    j = T.index["l1"]
    X = np.array([_moving_placement(pin.buildModelFromUrdf(str(T.path)), q)[0] for q in S.Q])
    c = 2e-6
    off = term.pose_offset(np.array([c]), _poses(arm, U), None, X)
    u, v = across_axes(T.axes[j])
    assert abs(u @ T.axes[j]) < 1e-12 and abs(v @ T.axes[j]) < 1e-12
    for k in range(len(U)):
        w_joint = c * ((S.loads.moment[k, j] @ u) * u + (S.loads.moment[k, j] @ v) * v)
        assert np.allclose(w_joint, c * (S.loads.moment[k, j] - (S.loads.moment[k, j] @ T.axes[j]) * T.axes[j]))
        w = S.loads.rotation[k, j] @ w_joint
        assert np.allclose(off[k, 3:], w)
        assert np.allclose(off[k, :3], np.cross(w, X[k] - S.loads.origin[k, j]))
    # linear in theta: its Jacobian is exact
    _, pose_jac, _ = term.offset_jacobians(np.zeros(1), _poses(arm, U), 3, None, X)
    assert np.allclose(pose_jac @ np.array([c]), off)
    # stored and read back
    back = LinkBending().from_dict(term.to_dict(np.array([c])))
    assert np.allclose(back.pose_offset(np.array([c]), _poses(arm, U), None, X), off)


def test_the_fixed_point_holds_the_load_at_the_deflected_pose(arm):
    stand = tree_stand(arm)
    T = stand.loads
    plain = load_state(stand, U).loads.torque[:, T.index["l1"]]

    def held(c, tau):  # the load at the configuration deflected by c * tau
        Q = stand.configuration(U)
        Q[:, T.index["l1"]] += c * tau
        return T.loads(Q).torque[:, T.index["l1"]]

    # a large sag (|c g| past LINEAR_LIMIT): the fixed point itself, by iteration
    c = -0.05
    tau = deflected_torque(stand, U, "l1", c)
    assert np.allclose(held(c, tau), tau, atol=1e-8) and np.abs(tau - plain).max() > 1e-3
    # a sag of tens of mrad: to first order, what is left second order in the deflection
    c = -0.004
    tau = deflected_torque(stand, U, "l1", c)
    d = np.abs(c * tau).max()
    assert np.abs(tau - plain).max() > 1e-4 and d > 0.01
    assert np.abs(held(c, tau) - tau).max() < d ** 2 * np.abs(plain).max()  # (1/2) tau'' d^2, |tau''| <= amplitude
    assert np.abs(held(c, tau) - tau).max() < 0.1 * np.abs(held(c, plain) - plain).max()  # the commanded load's error
    # and its slope in c is the derivative of c * tau(c)
    h = 1e-7
    fd = ((c + h) * deflected_torque(stand, U, "l1", c + h) - (c - h) * deflected_torque(stand, U, "l1", c - h)) / (2 * h)
    assert np.allclose(deflected_slope(stand, U, "l1", c), fd, rtol=1e-6)
    assert np.allclose(deflected_torque(stand, U, "l1", 1e-9), plain, rtol=1e-7, atol=0)


def test_every_loaded_joint_in_one_term_is_the_joints_compliances_together(tmp_path):
    tree = get_platform("urdf", _tree(tmp_path), moving_link={"L": "l_lo", "R": "r_lo"})
    C = np.array([[0.3, 0.4, -0.7, 0.1, 0.5], [-1.0, -0.2, 1.1, -0.05, -0.8], [0.0, 1.2, 0.3, 0.2, 0.0],
                  [0.6, -0.9, 0.2, -0.3, 0.4]])
    poses = PoseSet(tree.name, C, np.zeros((4, 2, 3)), ["L", "R"], length_unit="m", moving_link={"L": "l_lo", "R": "r_lo"})
    terms = Compliance().candidates(tree, poses)
    group = [t for t in terms if isinstance(t, JointsComplianceTerm)]
    assert len(group) == 1 and group[0].joints == tree_stand(tree).joints == ["t1", "l1", "l2", "r1", "r2"]
    singles = {t.where["actuator"]: t for t in terms if type(t).__name__ == "ComplianceTerm"}
    theta = np.array([-2e-3, -4e-3, 1e-3, -3e-3, 2e-3])
    want = sum(singles[n].control_offset(np.array([c]), poses, 5) for n, c in zip(tree.control_names, theta))
    got = group[0].control_offset(theta, poses, 5)
    # each under its own load, then each load where the others have given (first order)
    cross = coupled_offsets(tree_stand(tree), C, group[0].indices, group[0].joints, [], theta, want)
    assert np.allclose(got, want + cross, rtol=1e-12, atol=0) and np.abs(got).min(axis=0).max() > 1e-3
    assert 1e-7 < np.abs(cross).max() < 0.05 * np.abs(want).max()
    d_u, d_pose, d_m = group[0].offset_jacobians(theta, poses, 5, None, None)
    h = 1e-8
    for k in range(5):
        step = np.zeros(5)
        step[k] = h
        fd = (group[0].control_offset(theta + step, poses, 5) - group[0].control_offset(theta - step, poses, 5)) / (2 * h)
        assert np.allclose(d_u[..., k], fd, rtol=1e-6, atol=1e-12)
    assert not d_pose.any() and not d_m.any()
    back = Compliance().from_dict(group[0].to_dict(theta))
    assert isinstance(back, JointsComplianceTerm) and back.joints == group[0].joints
    assert np.allclose(back.control_offset(theta, poses, 5), got)


def test_without_inertias_compliance_is_tried_through_the_mass_moments(tmp_path):
    heavy = get_platform("urdf", _tree(tmp_path), moving_link="l_lo")
    bare_dir = tmp_path / "bare"
    bare_dir.mkdir()
    bare = get_platform("urdf", _tree(bare_dir, masses=False), moving_link="l_lo")
    terms = Compliance().candidates(bare, _poses(bare, U))
    assert sum(isinstance(t, MassMomentTerm) for t in terms) == 3  # beside the prior's loads
    assert "prior of uniform links" in next(t for t in terms if not isinstance(t, MassMomentTerm)).where["load"]
    assert "prior of uniform links" in LinkBending().candidates(bare, _poses(bare, U))[0].where["load"]
    terms = [t for t in terms if isinstance(t, MassMomentTerm)]
    # l2 (the forearm about an oblique axis) has 2 identifiable mass moments on these poses, both
    # kept: the true loads (the heavy URDF's) lie in their span exactly
    term = next(t for t in terms if t.joint == "l2")
    assert (term.where["identifiable_mass_moments"], term.where["kept"]) == (2, 2)
    cols = term.columns(U)
    true = actuator_loads(heavy, U)[:, 2]
    fit = np.linalg.lstsq(cols, true, rcond=None)[0]
    assert np.abs(cols @ fit - true).max() < 1e-9 * np.abs(true).max()
    # t1 (the torso, both arms below it) has more than are kept: said in where
    t1 = next(t for t in terms if t.joint == "t1")
    assert t1.where["identifiable_mass_moments"] > t1.where["kept"] == 3
    back = Compliance().from_dict(term.to_dict(fit))
    assert isinstance(back, MassMomentTerm)
    assert np.allclose(back.control_offset(fit, _poses(bare, U), 3), term.control_offset(fit, _poses(bare, U), 3))


def test_without_inertias_the_loads_are_the_prior_of_uniform_links(tmp_path):
    from platkit.tree_loads import PRIOR_KG_PER_M, PRIOR_MIN_KG, TreeLoads

    path = _tree(tmp_path, masses=False)
    assert TreeLoads(path).total_mass == 0
    T = TreeLoads(path, prior=True)
    heavy = tmp_path / "heavy"
    heavy.mkdir()
    assert T.prior and not TreeLoads(_tree(heavy), prior=True).prior  # a URDF's own inertias stand
    # l1's body: l_up, reaching l2's origin; l2's: l_lo, reaching nothing (the least mass, at its origin)
    l2 = T.tree.joints["l2"].origin[:3, 3]
    up = T.model.inertias[T.index["l1"] + 1]
    assert np.isclose(up.mass, PRIOR_KG_PER_M * np.linalg.norm(l2)) and np.allclose(up.lever, 0.5 * l2)
    assert np.isclose(T.model.inertias[T.index["l2"] + 1].mass, PRIOR_MIN_KG)
    bare = get_platform("urdf", path, moving_link="l_lo")
    assert tree_stand(bare).loads.prior
    loads = actuator_loads(bare, U)  # t1 and l1 carry links that reach out; l2 a leaf's least mass at its axis
    assert np.ptp(loads[:, :2], axis=0).min() > 0.1 and not loads[:, 2].any()


def test_on_a_tree_a_rotation_at_the_trunk_moves_every_tracked_link(tmp_path):
    path = _tree(tmp_path)
    tree = get_platform("urdf", path, moving_link={"L": "l_lo", "R": "r_lo"})
    stand = tree_stand(tree)
    assert stand.tracked == ["l_lo", "r_lo"] and stand.shared == ["t1", "t2"]
    C = np.array([[0.3, 0.4, -0.7, 0.1, 0.5], [-1.0, -0.2, 1.1, -0.05, -0.8], [0.0, 1.2, 0.3, 0.2, 0.0]])
    poses = PoseSet(tree.name, C, np.zeros((3, 2, 3)), ["L", "R"], length_unit="m",
                    moving_link={"L": "l_lo", "R": "r_lo"})
    terms = LinkBending().candidates(tree, poses)
    assert [t.joint for t in terms] == ["t1", "t2", "l1", "l2", "r1", "r2"]  # an arm's joint: see below
    assert [t.joint for t in terms if not t.partial(stand)] == ["t1", "t2"]
    # the pose offset (the moving link's) plus the marker offset put a marker at link k's origin
    # where the rotation at the joint takes it: w x (X_k - o)
    term = terms[1]
    S = load_state(stand, C)
    X0, _ = S.link_in_base(stand, "l_lo")
    Xr, Rr = S.link_in_base(stand, "r_lo")
    theta = np.array([3e-6])
    dpose = term.pose_offset(theta, poses, None, X0)
    dm = term.marker_offset(theta, poses)
    assert np.allclose(dm[:, 0], 0.0)
    j = stand.loads.index["t2"]
    u, v = across_axes(stand.loads.axes[j])
    for k in range(len(C)):
        w = S.loads.rotation[k, j] @ (theta[0] * ((S.loads.moment[k, j] @ u) * u + (S.loads.moment[k, j] @ v) * v))
        assert np.allclose(dpose[k, 3:], w)
        assert np.allclose(dpose[k, :3] + Rr[k] @ dm[k, 1], np.cross(w, Xr[k] - S.loads.origin[k, j]))
    _, pose_jac, marker_jac = term.offset_jacobians(np.zeros(1), poses, 5, None, X0)
    assert np.allclose(marker_jac @ theta, dm) and np.allclose(pose_jac @ theta, dpose)
    back = LinkBending().from_dict(term.to_dict(theta))  # the tree rebuilt from where alone
    assert tree_stand(back.spec).tracked == ["l_lo", "r_lo"]
    assert np.allclose(back.marker_offset(theta, poses), dm)


def test_what_cannot_be_tried_is_said(tmp_path):
    bare = get_platform("urdf", _tree(tmp_path, masses=False), moving_link="l_lo")
    poses = _poses(bare, U)
    assert LinkBending().untried(bare, poses) == []  # tried on the prior's loads
    assert "mass-moment combinations" in Compliance().untried(bare, poses)[0]
    assert "no inertias: not with the URDF's loads, but with those of uniform links" in Compliance().untried(bare, poses)[0]
    heavy_dir = tmp_path / "heavy"
    heavy_dir.mkdir()
    arm = get_platform("urdf", _tree(heavy_dir), moving_link="l_lo")
    assert LinkBending().untried(arm, _poses(arm, U)) == []
    assert Compliance().untried(arm, _poses(arm, U)) == []
    light = tmp_path / "light"
    light.mkdir()
    upper = '<link name="l_up"><inertial><origin xyz="0.1 0.02 -0.1"/><mass value='
    (light / "tree.urdf").write_text(_tree(light).read_text().replace(upper + '"1.5"/>', upper + '"0"/>'))
    doubtful = get_platform("urdf", light / "tree.urdf", moving_link="l_lo")
    assert any("the links moved by l1 have no mass" in r for r in Compliance().untried(doubtful, _poses(doubtful, U)))
    still = _poses(arm, np.repeat(U[:1], 4, axis=0))  # one configuration: no load changes
    assert Compliance().candidates(arm, still) == []
    assert any("the gravity load of t1, l1, l2 does not change" in r for r in Compliance().untried(arm, still))


def test_the_tree_effects_conform_on_a_urdf_tree(tmp_path):
    from platkit.testing import check_effect

    tree = get_platform("urdf", _tree(tmp_path), moving_link={"L": "l_lo", "R": "r_lo"})
    for effect in (Compliance(), LinkBending()):
        report = check_effect(effect, tree)
        assert report["terms"] > 0, report


def test_predict_gives_the_terms_each_markers_link(tmp_path, monkeypatch):
    """A tree term moves each marker with its own link (marker_offset reads poses.marker_links):
    prediction must hand the terms the calibration's mapping, as the fit had it."""
    from types import SimpleNamespace

    import platkit.calibrate.predict as predict

    tree = get_platform("urdf", _tree(tmp_path), moving_link={"L": "l_lo", "R": "r_lo"})
    seen = {}

    def markers(cal, U, poses):
        seen["links"] = dict(poses.marker_links)
        n = len(U)
        return np.zeros((n, 2, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros((n, 3)), np.ones(n, bool)

    monkeypatch.setattr(predict, "predict_markers", markers)
    monkeypatch.setattr(predict, "predict_bodies", lambda cal, q, X, U, poses: np.zeros((len(U), 0, 7)))
    monkeypatch.setattr(predict, "predict_links", lambda cal, U, poses: (np.zeros((len(U), 2, 4)), np.zeros((len(U), 2, 3))))
    cal = SimpleNamespace(platform="urdf", marker_names=["L", "R"], length_unit="m", terms=[], spec=tree,
                          marker_links={"L": "l_lo", "R": "r_lo"}, body_names=[])
    predict.prediction_table(cal, np.zeros((3, 5)))
    assert seen["links"] == {"L": "l_lo", "R": "r_lo"}


def test_bending_at_a_joint_of_one_branch_turns_only_the_markers_it_carries(tmp_path):
    """On a two-handed session, bending at an arm's joint (which carries one hand) is offered: the
    markers it carries turned about the joint's origin (their places on the link registered from
    the session), the other hand's still; to first order the physical simulator's deflection."""
    from platkit.simulate.elastic_tree import ElasticTruth, simulate_elastic_tree

    nominal = _tree(tmp_path)
    links = {"L1": "l_lo", "L2": "l_lo", "L3": "l_lo", "R1": "r_lo", "R2": "r_lo", "R3": "r_lo"}
    tree = get_platform("urdf", nominal, moving_link=links)
    C = np.random.default_rng(3).uniform(-1.0, 1.0, size=(14, 5)) * [1.0, 1.0, 1.0, 0.1, 1.0]
    c = 2e-4
    rigid = simulate_elastic_tree(nominal, ElasticTruth(), C, NAMES, links, seed=5, noise_mm=0.0, workdir=tmp_path)
    bent = simulate_elastic_tree(nominal, ElasticTruth(bending={"l1": (c, c)}), C, NAMES, links, seed=5,
                                 noise_mm=0.0, workdir=tmp_path)
    poses = PoseSet(tree.name, C, rigid.exact, list(links), length_unit="m", moving_link=links)
    terms = {t.joint: t for t in LinkBending().candidates(tree, poses)}
    assert list(terms) == ["t1", "t2", "l1", "l2", "r1", "r2"]
    assert LinkBending().untried(tree, poses) == []
    stand = tree_stand(tree)
    S = load_state(stand, C)
    term = terms["l1"]
    for m, name in enumerate(links):  # the places registered from the rigid session put each marker back
        X, R = S.link_in_base(stand, links[name])
        seen = (X + np.einsum("nab,b->na", R, term.points[name])) @ rigid.mocap_from_base[:3, :3].T \
            + rigid.mocap_from_base[:3, 3]
        assert np.allclose(seen, rigid.exact[:, m], atol=1e-9)
    assert not term.pose_offset(np.array([-c]), poses, None, None).any()
    dm = term.marker_offset(np.array([-c]), poses)  # the simulator turns by -k M: a compliance of -k
    assert not dm[:, 3:].any()  # the right hand does not move
    A = rigid.mocap_from_base[:3, :3]
    for m in range(3):
        _, R = S.link_in_base(stand, "l_lo")
        moved = np.einsum("nab,nb->na", R, dm[:, m]) @ A.T
        sag = bent.exact[:, m] - rigid.exact[:, m]
        assert np.abs(sag).max() > 3e-5
        assert np.allclose(moved, sag, rtol=0, atol=1e-2 * np.abs(sag).max())
    _, pose_jac, marker_jac = term.offset_jacobians(np.zeros(1), poses, 5, None, None)
    assert not pose_jac.any() and np.allclose(marker_jac @ np.array([-c]), dm)
    back = LinkBending().from_dict(term.to_dict(np.array([-c])))  # the places travel in where
    assert np.allclose(back.marker_offset(np.array([-c]), poses), dm, rtol=0, atol=1e-12)
    with_bodies = PoseSet(tree.name, C, rigid.exact, list(links), length_unit="m", moving_link=links,
                          body_names=["B"], bodies=np.full((len(C), 1, 7), np.nan))
    assert "rigid bodies" in LinkBending().untried(tree, with_bodies)[0]
