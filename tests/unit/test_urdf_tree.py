"""Trees (issue 24): a session whose markers ride on several links of one URDF (two hands on one
torso) is one fit; mimic joints follow a master anywhere in the tree; results travel; bad input
is one line naming the file and field.

The tree is tests/data/trees/two_arm_torso.urdf: a torso yaw, a pitch and a second pitch coupled
to it by <mimic multiplier=0.5>, a head that moves no marker, two 3-joint arms."""
from __future__ import annotations

import shutil
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import calibrate, point_errors
from platkit.calibrate.problem import link_frames
from platkit.errors import BadDescription, BadInput
from platkit.geometry import matrix_from_rotvec
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.urdf import frame_jacobian

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
MARKERS = {"R1": ("right_tcp", [0.03, 0.0, 0.0]), "R2": ("right_tcp", [0.0, 0.03, 0.01]),
           "R3": ("right_tcp", [0.0, 0.0, 0.04]), "L1": ("left_tcp", [0.03, 0.0, 0.0]),
           "L2": ("left_tcp", [0.0, -0.03, 0.01]), "L3": ("left_tcp", [0.01, 0.01, 0.04])}
MAPPING = {n: link for n, (link, _) in MARKERS.items()}
SIGMA = 5e-5  # m per axis
MOCAP_ROTVEC, MOCAP_T = np.array([0.1, -0.2, 0.3]), np.array([1.0, 0.5, -0.2])


def tree_spec(path=URDF, **options):
    return get_platform("urdf", path, moving_link=MAPPING, **options)


def observe(spec, td, U, rng, sigma=SIGMA):
    """Markers (N, M, 3) m in the mocap frame of the true stand (td) under controls U."""
    R, X = link_frames(spec, td, U)
    A = matrix_from_rotvec(MOCAP_ROTVEC)
    cols = []
    for link, m in MARKERS.values():
        k = spec.tracked_links.index(link)
        cols.append((X[:, k] + np.einsum("nab,b->na", R[:, k], np.array(m))) @ A.T + MOCAP_T)
    Y = np.stack(cols, axis=1)
    return Y + rng.normal(0.0, sigma, Y.shape)


def true_td(spec, rng):
    td = spec.nominal_td().copy()
    for i, p in enumerate(spec.parameters):
        if p.group == "offset":
            td[i] += rng.normal(0.0, 2e-3)
        elif p.group == "origin":
            td[i] += rng.normal(0.0, 1e-3)
    return td


def commands(spec, n, rng):
    lo, hi = spec.control_bounds()
    return rng.uniform(0.8 * lo, 0.8 * hi, size=(n, spec.n_u))


def test_tree_controls_are_the_recorded_joints_and_each_link_matches_its_chain():
    spec = tree_spec()
    assert spec.tracked_links == ["right_tcp", "left_tcp"]
    assert spec.control_names == ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint",
                                  "right_3_joint", "left_1_joint", "left_2_joint", "left_3_joint"]
    mimic = [p for p in spec.parameters if p.group == "mimic"]
    assert [(p.name, p.nominal, p.free) for p in mimic] == [("torso_pitch_2.mimic_multiplier", 0.5, False),
                                                            ("torso_pitch_2.mimic_offset", 0.0, False)]
    rng = np.random.default_rng(3)
    U = commands(spec, 5, rng)
    td = true_td(spec, rng)
    R, X = link_frames(spec, td, U)
    for k, link in enumerate(spec.tracked_links):  # the same link through its own chain
        chain = get_platform("urdf", URDF, moving_link=link)
        cols = [spec.control_names.index(n) for n in chain.control_names]
        td_chain = np.array([td[spec.parameter_names.index(n)] for n in chain.parameter_names])
        for n in range(len(U)):
            q, Xc = chain.forward(U[n, cols], td_chain)
            assert np.allclose(np.asarray(Xc).ravel(), X[n, k], atol=1e-12)
    # the mimic joint moves with its master: half the pitch on the second torso joint
    u = np.zeros(spec.n_u)
    u[1] = 0.2
    _, X_half = link_frames(spec, spec.nominal_td(), u[None])
    u_unc = spec.nominal_td().copy()
    u_unc[spec.parameter_names.index("torso_pitch_2.mimic_multiplier")] = 0.0
    _, X_none = link_frames(spec, u_unc, u[None])
    assert not np.allclose(X_half, X_none)


def test_mimic_master_off_the_tracked_chain_and_jacobians(tmp_path):
    """A joint of the right arm mimics one of the left arm: a chain to the right hand refuses it,
    the tree follows it; the frame Jacobian of each link is the finite difference of its pose."""
    text = URDF.read_text().replace(
        '<joint name="right_3_joint" type="revolute"><parent link="right_2"/><child link="right_3"/>\n'
        '    <origin xyz="0 0 -0.25"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="1"/></joint>',
        '<joint name="right_3_joint" type="revolute"><parent link="right_2"/><child link="right_3"/>\n'
        '    <origin xyz="0 0 -0.25"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="50" velocity="1"/>'
        '<mimic joint="left_3_joint" multiplier="-1" offset="0.1"/></joint>')
    path = tmp_path / "coupled.urdf"
    path.write_text(text)
    with pytest.raises(BadInput, match="right_3_joint.*mimics 'left_3_joint', which is not an actuated joint of the chain"):
        get_platform("urdf", path, moving_link="right_tcp")
    spec = tree_spec(path)
    assert "right_3_joint" not in spec.control_names and "left_3_joint" in spec.control_names
    rng = np.random.default_rng(4)
    u = commands(spec, 1, rng)[0]
    td = spec.nominal_td()
    i = spec.control_names.index("left_3_joint")
    for link in spec.tracked_links:
        J_lin, J_ang = (np.asarray(a) for a in frame_jacobian(spec, link)(u, td))
        k = spec.tracked_links.index(link)
        h = 1e-6
        up, um = u.copy(), u.copy()
        up[i] += h
        um[i] -= h
        fd = (link_frames(spec, td, up[None])[1][0, k] - link_frames(spec, td, um[None])[1][0, k]) / (2 * h)
        assert np.allclose(J_lin[:, i], fd, atol=1e-7)
        assert np.linalg.norm(J_lin[:, i]) > 1e-3  # the left wrist moves both hands
    with pytest.raises(BadInput, match="not a link of the URDF"):
        frame_jacobian(spec, "no_such_link")


def test_two_hands_one_fit_heldout_within_the_noise():
    spec = tree_spec()
    rng = np.random.default_rng(11)
    td = true_td(spec, rng)
    U = commands(spec, 140, rng)
    Y = observe(spec, td, U, rng)
    poses = PoseSet("urdf", U, Y, list(MARKERS), moving_link=MAPPING)
    assert poses.marker_links == MAPPING
    cal = calibrate(poses.subset(np.arange(90)), spec)
    assert cal.rms_before > 1e-3 and cal.converged
    err = point_errors(cal, poses.subset(np.arange(90, 140)))  # (50, 6) m
    # clean 3-D noise of sigma per axis: a mean norm of 1.6 sigma; the fit's own error adds a little
    for hand in ("R", "L"):
        cols = [j for j, n in enumerate(MARKERS) if n.startswith(hand)]
        assert np.nanmean(err[:, cols]) < 2.2 * SIGMA, hand
    # the head moves no marker: a control whose parameters the data cannot fix, held and said
    status = dict(zip(spec.parameter_names, cal.td_status))
    assert status["head_yaw.offset"] == "held_at_nominal"
    held = {h["name"] if isinstance(h, dict) else h for h in cal.identifiability["held_at_nominal"]}
    assert "head_yaw.offset" in held
    # the trunk and both branches in the one fit
    for joint in ("torso_pitch", "right_2_joint", "left_2_joint"):
        assert any(st == "estimated" for n, st in status.items() if n.startswith(joint + ".")), joint


def test_free_mimic_recovers_the_coupling():
    spec = tree_spec()
    rng = np.random.default_rng(12)
    td = spec.nominal_td().copy()
    i = spec.parameter_names.index("torso_pitch_2.mimic_multiplier")
    td[i] = 0.47  # the coupling is not quite what the drawing says
    U = commands(spec, 80, rng)
    poses = PoseSet("urdf", U, observe(spec, td, U, rng), list(MARKERS), moving_link=MAPPING)
    cal = calibrate(poses, spec, free=["offset", "mimic"])
    assert abs(cal.td[i] - 0.47) < 4 * cal.td_std[i] + 1e-4 and cal.td_std[i] < 0.01
    with pytest.raises(BadInput, match="^free: nope is neither"):
        calibrate(poses, spec, free=["nope"])


def write_session(folder: Path, spec, U, Y, columns=None, mapping=MAPPING):
    folder.mkdir(parents=True)
    shutil.copyfile(URDF, folder / "robot.urdf")
    (folder / "session.yaml").write_text(yaml.safe_dump({
        "platform": "urdf", "description": "robot.urdf", "units": {"length": "mm", "time": "s"},
        "markers": list(MARKERS), "moving_link": mapping, "mocap_rate_hz": 100}, sort_keys=False))
    columns = list(spec.control_names) if columns is None else columns
    head = ",".join(["t", *columns])
    rows = [",".join([f"{2.0 * n:.1f}"] + [format(U[n, spec.control_names.index(c)], ".12g") if c in spec.control_names
                                            else "0" for c in columns]) for n in range(len(U))]
    (folder / "commands.csv").write_text(head + "\n" + "\n".join(rows) + "\n")
    mhead = ",".join(["t", *columns] + [f"{m}_{a}" for m in MARKERS for a in "xyz"])
    mrows = [r + "," + ",".join(format(v * 1e3, ".9g") for v in Y[n].ravel()) for n, r in enumerate(rows)]
    (folder / "poses.csv").write_text(mhead + "\n" + "\n".join(mrows) + "\n")
    return folder


def test_mimic_whose_master_is_missing_names_the_file_and_joint(tmp_path):
    path = tmp_path / "broken.urdf"
    path.write_text(URDF.read_text().replace('<mimic joint="torso_pitch"', '<mimic joint="torso_pitch_x"'))
    with pytest.raises(BadDescription, match=r"broken.urdf: joint 'torso_pitch_2' <mimic joint='torso_pitch_x'>: "
                                             "the master names no joint"):
        tree_spec(path)


def test_link_poses_is_checked_by_validate_spec():
    from dataclasses import replace

    from platkit.model import validate_spec

    spec = tree_spec()
    u, td = ca.SX.sym("u", spec.n_u), ca.SX.sym("td", spec.n_td)
    wrong = ca.Function("link_poses", [u, td], [ca.DM.zeros(4), ca.DM.zeros(3)], ["u", "td"], ["q", "X"])
    with pytest.raises(BadDescription, match="link_poses output q has shape"):
        validate_spec(replace(spec, link_poses=wrong))


def test_a_rigid_body_on_the_other_hand_exact_jacobian_and_fit():
    """Markers on the right hand, a 6-DOF body on the left: the body's orientation is read from its
    own link; the problem's Jacobian is its finite difference, and the fit finds the body's place."""
    from platkit.calibrate.problem import CalibrationProblem
    from platkit.geometry import quat_from_matrix

    mapping = {"R1": "right_tcp", "R2": "right_tcp", "R3": "right_tcp", "T": "left_tcp"}
    spec = get_platform("urdf", URDF, moving_link=mapping)
    rng = np.random.default_rng(8)
    td = true_td(spec, rng)
    U = commands(spec, 60, rng)
    R, X = link_frames(spec, td, U)
    A = matrix_from_rotvec(MOCAP_ROTVEC)
    markers = np.stack([(X[:, 0] + R[:, 0] @ np.array(MARKERS[n][1])) @ A.T + MOCAP_T for n in ("R1", "R2", "R3")],
                       axis=1) + rng.normal(0.0, SIGMA, (60, 3, 3))
    p_body, R_body = np.array([0.01, 0.02, 0.05]), matrix_from_rotvec([0.3, -0.1, 0.2])
    origin = (X[:, 1] + R[:, 1] @ p_body) @ A.T + MOCAP_T + rng.normal(0.0, SIGMA, (60, 3))
    quat = quat_from_matrix(np.einsum("ab,nbc,cd->nad", A, R[:, 1], R_body))
    bodies = np.concatenate([origin, quat], axis=1)[:, None, :]
    poses = PoseSet("urdf", U, markers, ["R1", "R2", "R3"], moving_link=mapping, bodies=bodies, body_names=["T"])
    problem = CalibrationProblem(spec, poses)
    assert problem.point_links == (0, 0, 0, 1)
    z = problem.initial_registration(spec.nominal_td()) + rng.normal(0.0, 1e-4, problem.n_z)
    st = problem.evaluate(z)
    cols = [problem.names.index(n) for n in ("left_2_joint.offset", "torso_pitch.offset", "mocap.rx", "body.T.rx",
                                             "body.T.y", "marker.R2.z")]
    for c in cols:
        h = 1e-7
        zp, zm = z.copy(), z.copy()
        zp[c] += h
        zm[c] -= h
        fd = (problem.evaluate(zp, with_jac=False).r - problem.evaluate(zm, with_jac=False).r) / (2 * h)
        assert np.allclose(st.J[..., c], fd, atol=1e-6), problem.names[c]
    cal = calibrate(poses, spec)
    assert cal.marker_links == mapping
    assert np.allclose(cal.body_positions[0], p_body, atol=2e-3)
    from platkit.calibrate.estimate import predict_bodies, predict_markers

    _, q, Xm, ok = predict_markers(cal, U)
    pred = predict_bodies(cal, q, Xm, U)
    assert ok.all() and np.max(np.linalg.norm(pred[:, 0, :3] - origin, axis=1)) < 6 * SIGMA
    turn = np.abs(np.einsum("na,na->n", pred[:, 0, 3:], quat))  # |cos(half the angle between)|
    assert np.min(turn) > np.cos(1e-3)


def test_exported_urdf_keeps_a_calibrated_mimic_coupling(tmp_path):
    """The calibrated URDF of a tree with a freed mimic coupling, read back as a chain, puts the
    hand where the calibrated tree does."""
    from platkit.io.urdf_export import export_calibrated_urdf

    spec = tree_spec()
    rng = np.random.default_rng(9)
    td = true_td(spec, rng)
    td[spec.parameter_names.index("torso_pitch_2.mimic_multiplier")] = 0.47
    td[spec.parameter_names.index("torso_pitch_2.mimic_offset")] = 0.01
    out = export_calibrated_urdf(spec, td, tmp_path / "calibrated.urdf")
    back = get_platform("urdf", out, moving_link="left_tcp")
    U = commands(spec, 4, rng)
    _, X = link_frames(spec, td, U)
    cols = [spec.control_names.index(n) for n in back.control_names]
    for n in range(len(U)):
        _, Xb = back.forward(U[n, cols], back.nominal_td())
        assert np.allclose(np.asarray(Xb).ravel(), X[n, 1], atol=1e-10)


def test_plan_for_a_tree_plans_for_every_branch():
    """The identification Jacobian of a tree puts markers on every tracked link: the plan's
    uncertainties cover both arms, and its rank is the chain's plus the other arm's."""
    from platkit.calibrate.plan import default_marker_layout, identification_jacobian, random_candidates

    spec = tree_spec()
    rng = np.random.default_rng(0)
    cand = random_candidates(spec, 30, rng)
    markers = default_marker_layout(spec, 6, np.random.default_rng(0))
    J = identification_jacobian(spec, cand.controls, markers).J
    left = [i for i, n in enumerate(spec.parameter_names) if spec.parameters[i].free and n.startswith("left_")]
    cols = [k for k, i in enumerate(np.nonzero([p.free for p in spec.parameters])[0]) if i in left]
    assert np.linalg.norm(J[:, :, cols]) > 0  # the left arm is seen
    chain = get_platform("urdf", URDF, moving_link="right_tcp")
    sub = [spec.control_names.index(n) for n in chain.control_names]
    J_chain = identification_jacobian(chain, cand.controls[:, sub], markers).J
    rank_tree = np.linalg.matrix_rank(J.reshape(-1, J.shape[-1]), tol=1e-9)
    rank_chain = np.linalg.matrix_rank(J_chain.reshape(-1, J_chain.shape[-1]), tol=1e-9)
    assert rank_tree > rank_chain + 10
