"""A candidate no marker moves with at any pose (on a tree: at a joint no tracked link hangs on) is
said as not seen, apart from what the geometry absorbs (platkit.diagnose.search.screened, verdict)."""
from __future__ import annotations

import numpy as np

from platkit.diagnose.fitting import FROM_NO_MARKER, Diagnosis
from platkit.diagnose.search import diagnose
from platkit.diagnose.verdict import verdict
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate import simulate
from platkit_effects import Backlash
from tests.unit.test_tree_loads import NAMES, _tree


def test_the_other_arms_backlash_is_not_seen_not_absorbed(tmp_path):
    spec = get_platform("urdf", _tree(tmp_path), moving_link={"A": "l_lo", "B": "l_lo", "C": "l_lo"}, joints=NAMES)
    poses = simulate(spec, seed=3, n_poses=40, plan="random", raw=False).poses
    d = diagnose(spec, poses, library={"backlash": Backlash()})
    froms = {x["where"]["actuator"]: x["from"] for x in d.not_separable}
    assert froms.get("r1") == FROM_NO_MARKER and froms.get("r2") == FROM_NO_MARKER
    assert all(f != FROM_NO_MARKER for a, f in froms.items() if a not in ("r1", "r2"))
    assert "Not seen: no marker moves with these at any pose of the session" in d.verdict
    assert "backlash (actuator r1" in d.verdict.split("Not seen:")[1].split(".")[0]


def test_the_verdict_says_unseen_terms_apart(tmp_path):
    poses = PoseSet("urdf", np.zeros((2, 1)), np.zeros((2, 1, 3)), ["m"], length_unit="mm")
    unseen = {"effect": "backlash", "where": {"actuator": "head_1_joint"}, "separability": 0.0, "from": FROM_NO_MARKER}
    absorbed = {"effect": "scale", "where": {"actuator": "arm_1_joint"}, "separability": 0.01, "from": "motion capture"}
    d = Diagnosis(findings=[], verdict="", calibration=None, base=None, locations=[], locations_before=[], rounds=[],
                  not_separable=[unseen, absorbed], unit="mm", poses=poses, untried={})
    text = verdict(d)
    seen_part, geometry_part = text.split("Not seen:")[1].split("Not separable from the geometry")
    assert "head_1_joint" in seen_part and "arm_1_joint" not in seen_part and "arm_1_joint" in geometry_part
