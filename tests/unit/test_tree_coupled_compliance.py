"""A coupled joint's master that gives in its own joint alone (plugins/platkit_effects/tree_mimic.py,
the every-joint term's form ``where['alone']`` in tree_joints.py): the form's offsets and
Jacobians, its round trip, the data choosing it, and diagnosis naming no link bending at the
torso for it (the bending of the link below the master took the difference when the form was
missing). The elastic tree simulator's joint compliance at a master turns that joint alone."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.diagnose.stats import bic
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.elastic_tree import ElasticTruth, equilibrium, simulate_elastic_tree
from platkit_effects import Compliance
from platkit_effects.tree_compliance import load_state, tree_stand
from platkit_effects.tree_joints import JointsComplianceTerm
from platkit_effects.tree_mimic import coupled

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
JOINTS = ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint", "right_3_joint", "left_1_joint",
          "left_2_joint", "left_3_joint"]
LIMIT = np.array([1.5, 0.5, 1.0, 2.0, 1.5, 2.0, 2.0, 1.5, 2.0])
LINKS = {f"R{k}": "right_tcp" for k in (1, 2, 3)} | {f"L{k}": "left_tcp" for k in (1, 2, 3)}
ALONE = "torso_pitch's compliance in its own joint alone, its mimic joints held where commanded"


def _session(tmp_path, truth, n=24, seed=5):
    spec = get_platform("urdf", URDF, moving_link=LINKS)
    assert list(spec.control_names) == JOINTS
    C = np.random.default_rng(seed).uniform(-0.6, 0.6, size=(n, len(JOINTS))) * LIMIT
    sim = simulate_elastic_tree(URDF, truth, C, JOINTS, LINKS, seed=seed, noise_mm=0.02, workdir=tmp_path)
    return spec, PoseSet(spec.name, C, sim.markers, list(LINKS), length_unit="m", moving_link=LINKS)


def _every_joint(spec, poses) -> JointsComplianceTerm:
    return next(t for t in Compliance().candidates(spec, poses) if isinstance(t, JointsComplianceTerm))


def test_the_master_alone_turns_its_mimic_joint_back(tmp_path):
    spec, poses = _session(tmp_path, ElasticTruth(), n=8)
    stand = tree_stand(spec)
    assert coupled(stand, "torso_pitch") == [("torso_pitch_2", 0.5)] and coupled(stand, "torso_yaw") == []
    term = _every_joint(spec, poses)
    forms = dict(term.alternatives(np.zeros(len(term.joints)), poses, []))
    alone = forms[ALONE]
    assert alone.alone == ["torso_pitch"] and alone.parameter_names == term.parameter_names
    assert ALONE not in dict(alone.alternatives(np.zeros(len(term.joints)), poses, []))  # offered once
    theta = np.where(np.array(term.joints) == "torso_pitch", -2e-4, -1e-4)
    S = load_state(stand, poses.controls)
    X, _ = S.link_in_base(stand, stand.tracked[0])  # the moving link's origin
    # the same deflections under each joint's own load (the others' differ where the mimic is held);
    # the pose offset is torso_pitch_2 turned back by half torso_pitch's deflection
    assert np.allclose(alone._own_offset(theta, poses, spec.n_u), term._own_offset(theta, poses, spec.n_u))
    d = alone.control_offset(theta, poses, spec.n_u)[:, JOINTS.index("torso_pitch")]
    j = stand.loads.index["torso_pitch_2"]
    w = np.einsum("nab,b->na", S.loads.rotation[:, j], stand.loads.axes[j]) * (-0.5 * d)[:, None]
    w_base = np.einsum("nba,nb->na", S.base_rotation, w)
    pose = alone.pose_offset(theta, poses, None, X)
    assert np.allclose(pose[:, 3:], w_base, atol=1e-15) and np.abs(w_base).max() > 1e-4
    assert not term.pose_offset(theta, poses, None, X).any()
    # the Jacobians are the offsets' derivatives (the held mimic's linear in the deflections)
    J_control, J_pose, J_marker = alone.offset_jacobians(theta, poses, spec.n_u, None, X)
    for k in (term.joints.index("torso_pitch"), term.joints.index("right_1_joint")):
        h = np.zeros(len(theta))
        h[k] = 1e-6
        fd = (alone.control_offset(theta + h, poses, spec.n_u) - alone.control_offset(theta - h, poses, spec.n_u)) / 2e-6
        assert np.allclose(J_control[..., k], fd, rtol=1e-5, atol=1e-9)
        fd_pose = (alone.pose_offset(theta + h, poses, None, X) - alone.pose_offset(theta - h, poses, None, X)) / 2e-6
        fd_mark = (alone.marker_offset(theta + h, poses) - alone.marker_offset(theta - h, poses)) / 2e-6
        assert np.allclose(J_pose[..., k], fd_pose, rtol=1e-5, atol=1e-9)
        assert np.allclose(J_marker[..., k], fd_mark, rtol=1e-5, atol=1e-9)
    assert np.abs(J_pose[..., term.joints.index("torso_pitch")]).max() > 1.0
    # the deflections are the tree's equilibrium to second order: each load where every joint of the
    # term has given (the master alone, its mimic held), as the simulator solves it
    truth = {"torso_pitch": 2e-4, "right_1_joint": 4e-4, "left_2_joint": 3e-4}
    c = np.array([-truth.get(n, 0.0) for n in term.joints])
    T = stand.loads
    k = np.zeros(len(T.joints))
    for n, v in truth.items():
        k[T.index[n]] = v
    Qc = stand.configuration(poses.controls)
    Q = equilibrium(T, Qc, k)
    cols, tree = [JOINTS.index(n) for n in term.joints], [T.index[n] for n in term.joints]
    assert np.abs(Q - Qc).max() > 4e-3
    assert np.abs(alone.control_offset(c, poses, spec.n_u)[:, cols] - (Q - Qc)[:, tree]).max() < 1e-6
    # each load at its own joint's deflection alone misses the others' by more than ten times that
    assert np.abs(alone._own_offset(c, poses, spec.n_u)[:, cols] - (Q - Qc)[:, tree]).max() > 1e-5
    assert np.abs((Q - Qc)[:, T.index["torso_pitch_2"]]).max() == 0.0  # the simulator holds the mimic
    # calibration.yaml keeps the form; a form that is not the stand's is refused in one line
    back = Compliance().from_dict(alone.to_dict(theta))
    assert back.alone == ["torso_pitch"] and np.allclose(back.pose_offset(theta, poses, None, X), pose)
    bad = alone.to_dict(theta)
    bad["where"]["alone"] = ["torso_yaw"]
    with pytest.raises(Exception, match="where.alone"):
        Compliance().from_dict(bad)


def test_the_data_choose_the_master_alone_and_no_bending_is_named(tmp_path):
    """Truth: torso_pitch gives in its own joint (the simulator's joint compliance), the right
    shoulder too. The form with the master alone has the far lower BIC; diagnosis keeps it and
    names no link bending (it named bending at torso_yaw and torso_pitch while the form was
    missing: docs/trees.md)."""
    from platkit.diagnose import diagnose
    from platkit.diagnose.fitting import Options

    spec, poses = _session(tmp_path, ElasticTruth(joint_compliance={"torso_pitch": 2e-4, "right_1_joint": 4e-4}))
    term = _every_joint(spec, poses)
    alone = dict(term.alternatives(np.zeros(len(term.joints)), poses, []))[ALONE]
    fits = [calibrate(poses, spec, terms=[t], free=["offset"], robust=False) for t in (term, alone)]
    scores = [bic(float(np.sum(np.nan_to_num(c.fit.residuals_after) ** 2)), c.fit.residuals_after.size,
                  int(c.fit.active.sum())) for c in fits]
    assert scores[1] < scores[0] - 100
    assert fits[1].theta[0][term.joints.index("torso_pitch")] == pytest.approx(-2e-4, rel=0.05)
    d = diagnose(spec, poses, Options(max_effects=2))
    assert d.findings and d.findings[0].effect == "compliance" and d.findings[0].where.get("alone") == ["torso_pitch"]
    assert not [f for f in d.findings if f.effect == "link_bending" or f.where.get("bends")]
