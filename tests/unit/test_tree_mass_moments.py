"""The every-joint compliance of a tree without inertias, its form with the whole tree's mass
moments estimated with the compliances (plugins/platkit_effects/tree_joints.py)."""
from __future__ import annotations

import numpy as np

from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects import Compliance
from platkit_effects.tree_compliance import joint_rotation_term, load_state, tree_stand
from platkit_effects.tree_joints import MASS_STEPS, JointsComplianceTerm, joints_compliance_term, tree_mass_basis
from tests.unit.test_tree_loads import _tree

LINKS = {"L": "l_lo", "R": "r_lo"}


def _session(spec, n=14, seed=3):
    C = np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 5)) * [1.0, 1.2, 1.2, 0.2, 1.2]
    return PoseSet(spec.name, C, np.zeros((n, 2, 3)), ["L", "R"], length_unit="m", moving_link=LINKS)


def _group(spec, poses) -> JointsComplianceTerm:
    return next(t for t in Compliance().candidates(spec, poses) if isinstance(t, JointsComplianceTerm))


def test_without_inertias_the_every_joint_term_offers_the_trees_mass_moments(tmp_path):
    (tmp_path / "bare").mkdir()
    bare = get_platform("urdf", _tree(tmp_path / "bare", masses=False), moving_link=LINKS)
    heavy = get_platform("urdf", _tree(tmp_path), moving_link=LINKS)
    poses = _session(bare)
    group = _group(bare, poses)
    theta = np.array([-2e-3, -4e-3, 1e-3, -3e-3, 2e-3])[: len(group.indices)]
    assert len(theta) >= 3
    forms = [(what, t) for what, t in group.alternatives(theta, poses, []) if "mass moments" in what]
    # every count offered (one not kept must not stop a larger one), up to the identifiable ones
    rank = forms[0][1].where["identifiable_mass_moments"]
    counts = [min(k, rank) for k in MASS_STEPS if k <= rank] + ([rank] if rank < MASS_STEPS[-1] else [])
    assert [t.n_masses for _, t in forms] == sorted(set(counts))
    assert f"({MASS_STEPS[0]} combinations)" in forms[0][0]
    alt = forms[0][1]
    K = alt.n_masses
    assert K == MASS_STEPS[0] and alt.parameter_names[-K:] == [f"mass_moments_{k + 1}" for k in range(K)]
    assert np.allclose(alt.initial, np.concatenate([theta, np.zeros(K)]))
    assert alt.where["identifiable_mass_moments"] > K  # more are identifiable than the first form keeps: said
    # with inertias the URDF's loads stand: no such form
    heavy_group = _group(heavy, _session(heavy))
    assert not [w for w, _ in heavy_group.alternatives(np.full(len(heavy_group.indices), -1e-3), _session(heavy), [])
                if "mass" in w]

    # the deflections: each joint's compliance times its load of the prior's mass moments moved by B delta
    delta = np.array([0.3, -0.2, 0.1, 0.05])
    full = np.concatenate([theta, delta])
    stand = tree_stand(bare)
    S = load_state(stand, poses.controls)
    S.slope(stand, alt.joints[0])
    cols = [stand.loads.index[n] for n in alt.joints]
    pi = stand.loads.mass_moments() + alt.masses @ delta
    tau = np.einsum("njp,p->nj", S.torque_regressor(stand)[:, cols], pi)
    gain = 1.0 / (1.0 - theta * stand.scale[alt.indices] * S.slopes["all"][:, cols])
    assert np.allclose(alt.control_offset(full, poses, 5)[:, alt.indices], theta * tau * gain, rtol=1e-9, atol=1e-15)
    assert not np.allclose(alt.control_offset(full, poses, 5), group.control_offset(theta, poses, 5))
    # its derivatives, against central differences
    d_u, _, _ = alt.offset_jacobians(full, poses, 5, None, None)
    for k in range(len(full)):
        h = 1e-8 * max(1.0, abs(full[k]) * 1e3)
        step = np.zeros(len(full))
        step[k] = h
        fd = (alt.control_offset(full + step, poses, 5) - alt.control_offset(full - step, poses, 5)) / (2 * h)
        assert np.allclose(d_u[..., k], fd, rtol=1e-5, atol=1e-12 * np.abs(fd).max())
    # stored and read back: the same deflections
    back = Compliance().from_dict(alt.to_dict(full))
    assert isinstance(back, JointsComplianceTerm) and back.n_masses == K
    assert np.allclose(back.control_offset(full, poses, 5), alt.control_offset(full, poses, 5))
    # the next form keeps more combinations and starts where this one left the mass moments
    more = [t for w, t in alt.alternatives(full, poses, []) if "mass moments" in w]
    assert more and more[0].n_masses == min(MASS_STEPS[1], alt.where["identifiable_mass_moments"])
    # once the mass moments are estimated: the trunk's bending under them (t1 and t2, the mimic joint,
    # carry both hands)
    trunk = [(w, t) for w, t in alt.alternatives(full, poses, []) if "under the tree's estimated loads" in w]
    assert [w for w, _ in trunk] == [f"link bending at {n} under the tree's estimated loads" for n in ("t1", "t2")]
    assert trunk[0][1].bends[0].joint == "t1" and np.allclose(trunk[0][1].initial, np.concatenate([theta, [0.0], delta]))
    assert not [w for w, _ in group.alternatives(theta, poses, []) if "under the tree's estimated loads" in w]
    K2 = more[0].n_masses
    assert np.allclose(more[0].masses @ more[0].initial[-K2:], alt.masses @ delta, atol=1e-9 * np.abs(pi).max())


def test_the_trees_mass_moments_span_what_the_compliances_cannot_carry(tmp_path):
    """With every identifiable combination, the true robot's deflections (its own inertias) are
    each joint's compliance times the loads of the prior's mass moments moved along B: the
    combinations cover what a compliance's scale on the prior's loads cannot."""
    (tmp_path / "bare").mkdir()
    bare = get_platform("urdf", _tree(tmp_path / "bare", masses=False), moving_link=LINKS)
    heavy = get_platform("urdf", _tree(tmp_path), moving_link=LINKS)
    poses = _session(bare, n=30)
    stand, truth = tree_stand(bare), tree_stand(heavy)
    joints = _group(bare, poses).joints
    c = np.array([-2e-4, -4e-4, 1e-4, -3e-4, 2e-4])[: len(joints)]
    B, rank = tree_mass_basis(stand, poses.controls, joints, c, 100)
    assert B.shape[1] == rank
    S = load_state(stand, poses.controls)
    Y = S.torque_regressor(stand)[:, [stand.loads.index[n] for n in joints]]
    prior = Y @ stand.loads.mass_moments()
    true = load_state(truth, poses.controls).loads.torque[:, [truth.loads.index[n] for n in joints]]
    # unknowns: a scale per joint (the compliance's) and delta; rows: c_j tau_true_j per pose and joint
    N, J = true.shape
    A = np.zeros((N, J, J + rank))
    A[:, np.arange(J), np.arange(J)] = c * prior
    A[..., J:] = c[None, :, None] * (Y @ B)
    want = (c * true).ravel()
    x = np.linalg.lstsq(A.reshape(N * J, -1), want, rcond=None)[0]
    assert np.abs(A.reshape(N * J, -1) @ x - want).max() < 1e-8 * np.abs(want).max()
    # the first combinations alone leave part of it: the prior's shape is not the robot's
    few = np.linalg.lstsq(A[..., : J + 1].reshape(N * J, -1), want, rcond=None)[0]
    assert np.abs(A[..., : J + 1].reshape(N * J, -1) @ few - want).max() > 1e-3 * np.abs(want).max()


def test_a_bend_in_the_term_turns_under_the_estimated_moments(tmp_path):
    bare = get_platform("urdf", _tree(tmp_path, masses=False), moving_link=LINKS)
    poses = _session(bare)
    group = _group(bare, poses)
    stand = tree_stand(bare)
    J = len(group.indices)
    B, rank = tree_mass_basis(stand, poses.controls, group.joints, np.full(J, 1e-3), 4)
    points = {"L": np.array([0.05, 0.01, -0.02])}
    for joint, about in (("l1", "across2"), ("t1", "across")):  # one arm's (its markers), the trunk's (a pose offset)
        bend = joint_rotation_term("link_bending", bare, joint, about, points if joint == "l1" else None)
        term = joints_compliance_term("compliance", bare, group.indices, [bend], masses=B, identifiable=rank)
        nb = len(bend.parameter_names)
        t = np.array([-3e-3, 2e-3][:nb])
        delta = np.array([0.4, -0.3, 0.2, 0.1])
        full = np.concatenate([np.full(J, -1e-3), t, delta])
        fk_q, fk_X = np.zeros((poses.n_poses, 5)), np.zeros((poses.n_poses, 3))
        S = load_state(stand, poses.controls)
        M = S.loads.moment[:, stand.loads.index[joint]] + S.moment_regressor(stand)[:, stand.loads.index[joint]] @ B @ delta
        want_pose, want_marker = bend.turned(t, M, poses, fk_X)
        assert np.allclose(term.pose_offset(full, poses, fk_q, fk_X), want_pose, rtol=1e-10, atol=1e-15)
        assert np.allclose(term.marker_offset(full, poses), want_marker, rtol=1e-10, atol=1e-15)
        assert np.abs(want_pose).max() + np.abs(want_marker).max() > 1e-4
        _, d_pose, d_marker = term.offset_jacobians(full, poses, 5, fk_q, fk_X)
        for k in range(J, len(full)):
            h = 1e-6 * max(1e-3, abs(full[k]))
            step = np.zeros(len(full))
            step[k] = h
            fd_p = (term.pose_offset(full + step, poses, fk_q, fk_X) - term.pose_offset(full - step, poses, fk_q, fk_X)) / (2 * h)
            fd_m = (term.marker_offset(full + step, poses) - term.marker_offset(full - step, poses)) / (2 * h)
            assert np.allclose(d_pose[..., k], fd_p, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(fd_p).max()))
            assert np.allclose(d_marker[..., k], fd_m, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(fd_m).max()))
        back = Compliance().from_dict(term.to_dict(full))
        assert np.allclose(back.marker_offset(full, poses), term.marker_offset(full, poses))
