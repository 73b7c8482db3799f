"""Link bending at a joint of one branch of a tree told apart from the compliance of the joint
next to it (plugins/platkit_effects/tree_joints.py: JointsComplianceTerm.alternatives, and
diagnosis's rule that keeps the form with the lower BIC): two arms whose second joint sits at the
first's origin with its axis across, simulated by the elastic tree simulator."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.diagnose.stats import bic
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.elastic_tree import ElasticTruth, simulate_elastic_tree
from platkit_effects import Compliance
from platkit_effects.tree_compliance import tree_stand
from platkit_effects.tree_joints import JointsComplianceTerm, same_place_parent

INERTIA = '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
JOINTS = ["t1", "l1", "l2", "l3", "r1", "r2", "r3"]
LINKS = {"L1": "l_hand", "L2": "l_hand", "L3": "l_hand", "R1": "r_hand", "R2": "r_hand", "R3": "r_hand"}


def _body(tmp_path):
    """A torso turning about z with two arms: a shoulder pitch (y), at its origin a roll (x), an
    elbow 0.3 m down the arm; a hand 0.25 m further."""
    def link(name, mass, com):
        return f'<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>{INERTIA}</inertial></link>'

    def joint(name, parent, child, xyz, axis):
        return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>'
                '<limit lower="-2" upper="2" effort="1" velocity="1"/></joint>')

    parts = ['<link name="base"/>', link("torso", 8.0, "0 0 0.2"), joint("t1", "base", "torso", "0 0 0.5", "0 0 1")]
    for s, y in (("l", 0.2), ("r", -0.2)):
        parts += [link(f"{s}_shoulder", 0.3, "0 0 0"), link(f"{s}_upper", 2.0, "0 0 -0.15"),
                  link(f"{s}_fore", 1.5, "0 0 -0.12"), link(f"{s}_hand", 0.5, "0 0 -0.05"),
                  joint(f"{s}1", "torso", f"{s}_shoulder", f"0 {y} 0.4", "0 1 0"),
                  joint(f"{s}2", f"{s}_shoulder", f"{s}_upper", "0 0 0", "1 0 0"),
                  joint(f"{s}3", f"{s}_upper", f"{s}_fore", "0 0 -0.3", "0 1 0"),
                  f'<joint name="{s}_wrist" type="fixed"><parent link="{s}_fore"/><child link="{s}_hand"/>'
                  '<origin xyz="0 0 -0.25"/></joint>']
    path = tmp_path / "body.urdf"
    path.write_text(f'<robot name="body">{"".join(parts)}</robot>')
    return path


def _session(tmp_path, truth, n=30, seed=11):
    path = _body(tmp_path)
    spec = get_platform("urdf", path, moving_link=LINKS)
    assert list(spec.control_names) == JOINTS
    C = np.random.default_rng(seed).uniform(-1.2, 1.2, size=(n, len(JOINTS)))
    sim = simulate_elastic_tree(path, truth, C, JOINTS, LINKS, seed=seed, noise_mm=0.02, workdir=tmp_path)
    return spec, PoseSet(spec.name, C, sim.markers, list(LINKS), length_unit="m", moving_link=LINKS)


def _every_joint(spec, poses):
    return next(t for t in Compliance().candidates(spec, poses) if isinstance(t, JointsComplianceTerm))


def _bic(spec, poses, term):
    cal = calibrate(poses, spec, terms=[term], free=["offset"], robust=False)
    r = np.nan_to_num(cal.fit.residuals_after)
    return bic(float(np.sum(r**2)), r.size, int(cal.fit.active.sum())), cal


def test_the_compliance_of_a_joint_at_its_parents_origin_has_the_parents_bending_as_alternative(tmp_path):
    spec, poses = _session(tmp_path, ElasticTruth())
    term = _every_joint(spec, poses)
    assert term.joints == ["t1", "l1", "l2", "l3", "r1", "r2", "r3"][1:] or "t1" not in term.joints
    alts = term.alternatives(np.arange(1.0, len(term.joints) + 1), poses, [])
    assert [w for w, _ in alts] == ["l2's compliance told apart as link bending at l1",
                                    "l2's compliance told apart as link bending at l1, stiffer one way than the other",
                                    "link bending at l1 beside l2's compliance",
                                    "r2's compliance told apart as link bending at r1",
                                    "r2's compliance told apart as link bending at r1, stiffer one way than the other",
                                    "link bending at r1 beside r2's compliance"]
    both = alts[2][1]  # the bending added, every compliance kept, the bending from zero
    assert both.joints == term.joints and both.where["bends"] == ["l1"] and both.parameter_names[-1] == "bending_l1"
    assert np.array_equal(both.initial, np.arange(1.0, len(term.joints) + 2) * (np.arange(len(term.joints) + 1)
                                                                               < len(term.joints)))
    assert alts[1][1].parameter_names[-2:] == ["bending_l1_u", "bending_l1_v"]
    alt = alts[0][1]
    assert alt.where["joint"] == term.where["joint"] and alt.where["bends"] == ["l1"]  # the same place
    assert "l2" not in alt.joints and alt.parameter_names[-1] == "bending_l1"
    k = term.joints.index("l2")
    assert alt.initial[-1] == k + 1.0  # the bending starts from the compliance (rad per N m)
    assert alt.bends[0].partial(tree_stand(spec)) and set(alt.bends[0].points) == set(LINKS)  # the markers' places
    # the offsets are the compliances' and the bending's, and the term travels whole
    theta = np.concatenate([np.full(len(alt.joints), -2e-4), [-3e-4]])
    bend = alt.bends[0].marker_offset(np.array([-3e-4]), poses)
    assert np.abs(bend[:, :3]).max() > 1e-5 and not bend[:, 3:].any()
    assert np.allclose(alt.marker_offset(theta, poses), bend)
    back = Compliance().from_dict(alt.to_dict(theta))
    assert back.bends[0].joint == "l1" and back.joints == alt.joints
    assert np.allclose(back.marker_offset(theta, poses), bend, rtol=0, atol=1e-11)  # the places kept to 1 nm
    assert np.allclose(back.control_offset(theta, poses, 7), alt.control_offset(theta, poses, 7))
    # told apart once: the bent joint offers no second bending there, only its form with two compliances;
    # first, l2's compliance given back beside the bending (both may give), starting from zero
    again = alt.alternatives(alt.initial, poses, [])
    assert [w for w, _ in again] == ["l2's compliance given back beside the link bending at l1", *[w for w, _ in alts[3:]],
                                     "link bending at l1, stiffer one way than the other"]
    back_l2 = again[0][1]
    assert back_l2.joints == term.joints and back_l2.where["bends"] == ["l1"]
    assert back_l2.initial[k] == 0.0 and np.allclose(np.delete(back_l2.initial, k), alt.initial)
    assert not any("given back" in w for w, _ in back_l2.alternatives(back_l2.initial, poses, []))  # once
    two = again[4][1]
    assert two.where["bends_about"] == ["across2"] and np.allclose(two.initial[-2:], alt.initial[-1])
    theta2 = np.concatenate([theta, [-3e-4]])
    assert np.allclose(two.marker_offset(theta2, poses), bend)  # equal compliances: the same bend
    back2 = Compliance().from_dict(two.to_dict(theta2))
    assert back2.bends[0].about == "across2" and np.allclose(back2.marker_offset(theta2, poses), bend, atol=1e-11)


def test_a_joint_out_along_its_own_axis_from_its_parent_has_the_parents_bending_as_alternative(tmp_path):
    """TIAGo's upper-arm roll sits 9 cm down the link from the shoulder joint, its axis along the
    link through the shoulder's origin (1.5 mm off it in the URDF): turning about that line is
    turning about it at the shoulder. Here l2 sits 9 cm out along its axis (1.5 mm off the line),
    r2 9 cm out and 4 mm off it: l2 is offered as the bending at l1, r2 not."""
    path = _body(tmp_path)
    text = path.read_text()
    for s, xyz in (("l", "0.09 0 -0.0015"), ("r", "0.09 0.004 0")):
        at = f'<child link="{s}_upper"/><origin xyz="0 0 0"'
        assert at in text
        text = text.replace(at, f'<child link="{s}_upper"/><origin xyz="{xyz}"')
    path.write_text(text)
    spec = get_platform("urdf", path, moving_link=LINKS)
    C = np.random.default_rng(11).uniform(-1.2, 1.2, size=(30, len(JOINTS)))
    sim = simulate_elastic_tree(path, ElasticTruth(), C, JOINTS, LINKS, seed=11, noise_mm=0.02, workdir=tmp_path)
    poses = PoseSet(spec.name, C, sim.markers, list(LINKS), length_unit="m", moving_link=LINKS)
    stand = tree_stand(spec)
    assert same_place_parent(stand, C, "l2") == "l1" and same_place_parent(stand, C, "r2") is None
    term = _every_joint(spec, poses)
    alts = term.alternatives(np.arange(1.0, len(term.joints) + 1), poses, [])
    assert [w for w, _ in alts] == ["l2's compliance told apart as link bending at l1",
                                    "l2's compliance told apart as link bending at l1, stiffer one way than the other",
                                    "link bending at l1 beside l2's compliance"]


@pytest.mark.parametrize("bent", [True, False])
def test_the_data_tell_a_shoulders_bending_from_the_next_joints_compliance(tmp_path, bent):
    """Truth: the left shoulder bends at l1 (every joint stiff but the elbows), or l2 gives; the
    every-joint term and its alternative fitted alike: the true form has the lower BIC."""
    elbows = {"l3": 2e-4, "r3": 2e-4}
    truth = ElasticTruth(joint_compliance=elbows, bending={"l1": (4e-4, 4e-4)}) if bent else \
        ElasticTruth(joint_compliance={**elbows, "l2": 4e-4})
    spec, poses = _session(tmp_path, truth)
    term = _every_joint(spec, poses)
    alt = dict(term.alternatives(np.zeros(len(term.joints)), poses, []))["l2's compliance told apart as link bending at l1"]
    b_joint, cal_joint = _bic(spec, poses, term)
    b_bend, cal_bend = _bic(spec, poses, alt)
    assert (b_bend < b_joint - 10) if bent else (b_joint < b_bend - 10)
    if bent:
        assert cal_bend.theta[0][-1] == pytest.approx(-4e-4, rel=0.05)


def test_diagnosis_keeps_the_form_the_data_choose(tmp_path):
    """The arms' joints give (r1, r2, the elbows) and the left shoulder's link bends at l1: the
    every-joint term is accepted with l2's compliance, then told apart as the bending at l1 (lower
    BIC, kept); r2's compliance, true, stays (its bending forms have a higher BIC)."""
    from platkit.diagnose import diagnose
    from platkit.diagnose.fitting import Options

    truth = ElasticTruth(joint_compliance={"l3": 4e-4, "r3": 4e-4, "r2": 4e-4, "r1": 4e-4}, bending={"l1": (2e-4, 2e-4)})
    spec, poses = _session(tmp_path, truth)
    d = diagnose(spec, poses, Options(max_effects=1))
    (f,) = d.findings
    assert f.effect == "compliance" and f.where["bends"] == ["l1"] and "l2" not in f.where["joints"]
    assert "r2" in f.where["joints"]
    assert f.parameters["bending_l1"]["value"] == pytest.approx(-2e-4, rel=0.05)
    assert f.parameters["compliance_r2"]["value"] == pytest.approx(-4e-4, rel=0.05)
    told = d.rounds[0]["told_apart"]
    assert told[0] == {"change": "l2's compliance told apart as link bending at l1", "bic_change": told[0]["bic_change"],
                       "kept": True} and told[0]["bic_change"] < -100
    assert not any(t["kept"] for t in told[1:])
    again = Compliance().from_dict(f.term.to_dict(d.calibration.theta[0]))  # what calibration.yaml holds
    assert again.where["bends"] == ["l1"]
