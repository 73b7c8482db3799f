"""A joint that gives and the link before it that bends, both at once (plugins/platkit_effects/
tree_joints.py: JointsComplianceTerm._given_back): the shoulder's roll l2 sits at the pitch l1's
origin with its axis across, as in a humanoid's spherical shoulder; diagnosis tells l2's
compliance apart as the bending at l1, then gives l2's compliance back beside it, and names both
(before, l2's compliance was lost: the bending took it, -9e-4 where the link bends by 5e-4)."""
from __future__ import annotations

import pytest

from platkit.diagnose import diagnose
from platkit.diagnose.fitting import Options
from platkit.simulate.elastic_tree import ElasticTruth
from tests.unit.test_tree_bending import _session


def test_a_joints_compliance_and_its_parents_bending_both_named(tmp_path):
    """Every arm joint gives; the left shoulder's link bends at l1, across l1's axis, about the
    horizontal axis (x, where gravity's moment is) more than about the vertical (z)."""
    truth = ElasticTruth(joint_compliance={n: 4e-4 for n in ("l1", "l2", "l3", "r1", "r2", "r3")},
                         bending={"l1": (2e-4, 5e-4)})
    spec, poses = _session(tmp_path, truth)
    d = diagnose(spec, poses, Options(max_effects=1))
    (f,) = d.findings
    assert f.effect == "compliance" and f.where["bends"] == ["l1"] and "l2" in f.where["joints"]
    assert f.parameters["bending_l1"]["value"] == pytest.approx(-5e-4, rel=0.1)
    assert f.parameters["compliance_l2"]["value"] == pytest.approx(-4e-4, rel=0.1)
    told = {t["change"]: t["kept"] for t in d.rounds[0]["told_apart"]}
    assert told["l2's compliance told apart as link bending at l1"]
    assert told["l2's compliance given back beside the link bending at l1"]
