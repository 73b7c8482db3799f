"""Link bending at a prismatic joint (a mobile manipulator's torso lift carrying two arms): the
column bends where the slide is guided, its placement on the parent, not at the height the lift
has reached (platkit.tree_loads: a joint's pivot), checked against the elastic tree simulator."""
from __future__ import annotations

import numpy as np

from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.elastic_tree import ElasticTruth, simulate_elastic_tree
from platkit_effects.tree_compliance import joint_rotation_term, load_state, tree_stand

INERTIA = '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>'
JOINTS = ["lift", "l1", "l2", "r1", "r2"]
LINKS = {"L": "l_hand", "R": "r_hand"}


def _lift(tmp_path):
    """A column on a base; on it a lift (0-0.4 m along z) carrying two arms: a shoulder pitch (y),
    an elbow 0.3 m down the arm, a hand 0.25 m further."""
    def link(name, mass, com):
        return f'<link name="{name}"><inertial><origin xyz="{com}"/><mass value="{mass}"/>{INERTIA}</inertial></link>'

    def joint(name, parent, child, xyz, axis, kind="revolute", limits="-2 2"):
        lo, hi = limits.split()
        return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="{axis}"/>'
                f'<limit lower="{lo}" upper="{hi}" effort="1" velocity="1"/></joint>')

    parts = ['<link name="base"/>', link("torso", 8.0, "0.05 0 0.1"),
             joint("lift", "base", "torso", "0 0 0.6", "0 0 1", "prismatic", "0 0.4")]
    for s, y in (("l", 0.2), ("r", -0.2)):
        parts += [link(f"{s}_upper", 2.0, "0.1 0 -0.15"), link(f"{s}_fore", 1.5, "0 0 -0.12"),
                  link(f"{s}_hand", 0.5, "0 0 -0.05"),
                  joint(f"{s}1", "torso", f"{s}_upper", f"0.05 {y} 0.3", "0 1 0"),
                  joint(f"{s}2", f"{s}_upper", f"{s}_fore", "0.1 0 -0.3", "0 1 0"),
                  f'<joint name="{s}_wrist" type="fixed"><parent link="{s}_fore"/><child link="{s}_hand"/>'
                  '<origin xyz="0 0 -0.25"/></joint>']
    path = tmp_path / "lift.urdf"
    path.write_text(f'<robot name="lift">{"".join(parts)}</robot>')
    return path


def test_a_lifts_column_bends_where_the_slide_is_guided(tmp_path):
    path = _lift(tmp_path)
    spec = get_platform("urdf", path, moving_link=LINKS)
    assert list(spec.control_names) == JOINTS
    rng = np.random.default_rng(3)
    C = np.column_stack([rng.uniform(0.05, 0.4, 12), rng.uniform(-1.5, 1.5, (12, 4))])
    k = 2e-6  # rad/(N m): a bend of ~20 urad, where the first order in the deflection is exact to 1e-9 m
    truth = ElasticTruth(bending={"lift": (k, k)})
    sim = simulate_elastic_tree(path, truth, C, JOINTS, LINKS, seed=5, noise_mm=0.0, marker_spread_m=0.0,
                                workdir=tmp_path)
    M = sim.mocap_from_base
    moved = (sim.exact - sim.rigid) @ M[:3, :3]  # (N, 2, 3) each hand's displacement, base frame
    assert np.abs(moved).max() > 1e-5  # the bend moves the hands by tens of micrometres

    poses = PoseSet(spec.name, C, sim.exact, list(LINKS), length_unit="m", moving_link=LINKS)
    term = joint_rotation_term("link_bending", spec, "lift", "across")  # the lift carries both hands
    stand = tree_stand(spec)
    assert stand.shared == ["lift"]
    S = load_state(stand, C)
    X0, _ = S.link_in_base(stand, "l_hand")
    Xr, Rr = S.link_in_base(stand, "r_hand")
    theta = np.array([-k])  # a joint that gives under its load has a negative compliance
    dpose = term.pose_offset(theta, poses, None, X0)
    dm = term.marker_offset(theta, poses)
    model = np.stack([dpose[:, :3], dpose[:, :3] + np.einsum("nab,nb->na", Rr, dm[:, 1])], axis=1)
    # turned at the lift's origin where it has slid to, the hands miss it by the bend times the
    # travel (19 um here)
    assert np.abs(model - moved).max() < 2e-8
