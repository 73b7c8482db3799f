"""What diagnosis could not try is said (Effect.untried -> Diagnosis.untried -> the verdict and
diagnosis.json), and a geometry chosen again beside the physics is said (issue 24)."""
from __future__ import annotations

import numpy as np

from platkit.diagnose.fitting import Diagnosis
from platkit.diagnose.verdict import verdict
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects import Compliance, LinkBending
from tests.unit.test_tree_loads import _tree


def _diagnosis(poses, untried=None, rounds=None):
    return Diagnosis(findings=[], verdict="", calibration=None, base=None, locations=[], locations_before=[],
                     rounds=rounds or [], not_separable=[], unit="mm", poses=poses, untried=untried or {})


def test_a_urdf_without_inertias_says_its_loads_are_the_priors(tmp_path):
    bare = get_platform("urdf", _tree(tmp_path, masses=False), moving_link="l_lo")
    U = np.array([[0.3, 0.4, -0.7], [-1.0, -0.2, 1.1], [0.0, 1.2, 0.3], [0.6, -0.9, 0.2]])
    poses = PoseSet(bare.name, U, np.zeros((4, 1, 3)), ["m"], length_unit="mm")
    untried = {e.name: r for e in (Compliance(), LinkBending()) if (r := e.untried(bare, poses))}
    assert set(untried) == {"compliance"}  # link bending is tried, on the prior of uniform links
    text = verdict(_diagnosis(poses, untried))
    assert ("Not tried: compliance where the URDF has no inertias: not with the URDF's loads, but with those of "
            "uniform links") in text
    assert "each joint's compliance also with its gravity load's best-determined mass-moment combinations" in text


def test_a_geometry_chosen_again_is_said(tmp_path):
    poses = PoseSet("urdf", np.zeros((2, 1)), np.zeros((2, 1, 3)), ["m"], length_unit="mm")
    note = {"after": "compliance (torso_2_joint)", "chosen": ["origin"], "held": ["scale", "offset"],
            "heldout_rms_before": 1.2e-3, "heldout_rms_after": 0.9e-3, "text": ""}
    text = verdict(_diagnosis(poses, rounds=[{"round": 1, "geometry_reselected": note}]))
    assert ("After compliance (torso_2_joint) was accepted, the geometry's model selection was made again beside "
            "it: it frees origin and holds scale, offset") in text
