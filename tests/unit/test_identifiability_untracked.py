"""Why a parameter is held, said truly on a tree (platkit.calibrate.identifiability.classify_held):
a joint no tracked link hangs on moves no marker at any pose, and the report says that, not "a
symmetry"; a parameter a symmetry hides keeps its own reason."""
from __future__ import annotations

from platkit.calibrate.estimate import calibrate
from platkit.plugins import get_platform
from platkit.simulate import simulate
from tests.unit.test_tree_loads import NAMES, _tree


def test_a_joint_that_moves_no_tracked_link_is_held_for_that_reason(tmp_path):
    spec = get_platform("urdf", _tree(tmp_path), moving_link={"A": "l_lo", "B": "l_lo", "C": "l_lo"}, joints=NAMES)
    sim = simulate(spec, seed=1, n_poses=40, plan="random", raw=False)
    held = {h["name"]: h["reason"] for h in calibrate(sim.poses, spec).identifiability["held_at_nominal"]}
    other_arm = [n for n in held if n.startswith(("r1.", "r2."))]
    assert len(other_arm) == 14  # the offset and the six origin parameters of each of the other arm's joints
    assert all("no marker moves with it at any pose" in held[n] and "symmetry" not in held[n] for n in other_arm)
    assert "(a symmetry)" in held["t1.offset"]  # the trunk's first turn: a symmetry with the mocap frame
