"""The cap on the effects diagnosis names (platkit.diagnose.search.effect_cap): three on a stand or
a chain, three for each tracked link of a tree, ``max_effects`` where given; a search the cap
ended says so in its rounds and its verdict, one the tests ended does not."""
from __future__ import annotations

import pytest

from platkit.diagnose import diagnose
from platkit.diagnose.fitting import Options
from platkit.diagnose.search import effect_cap
from platkit.plugins import get_platform
from platkit.simulate.elastic_tree import ElasticTruth
from tests.unit.test_tree_bending import _session

# a tree with two tracked hands whose truth holds four effects: every arm joint gives, the torso's
# column bends at t1 and each forearm bends at its elbow (l3, r3)
TRUTH = ElasticTruth(joint_compliance={j: 4e-4 for j in ("l1", "l2", "l3", "r1", "r2", "r3")},
                     bending={"t1": (5e-5, 5e-5), "l3": (5e-4, 5e-4), "r3": (5e-4, 5e-4)})


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    return _session(tmp_path_factory.mktemp("cap"), TRUTH)


def test_a_tree_with_two_tracked_links_names_its_fourth_effect_by_default(tree):
    """The cap of a stand or a chain (three) would end this search before the elbows' second bend."""
    spec, poses = tree
    assert len(spec.tracked_links) == 2 and effect_cap(spec) == 6 and effect_cap(get_platform("stewart")) == 3
    d = diagnose(spec, poses)
    named = {(f.effect, f.where.get("joint")) for f in d.findings}
    assert named == {("compliance", "every loaded joint (6)"), ("link_bending", "t1"), ("link_bending", "l3"),
                     ("link_bending", "r3")}
    assert not any(r.get("at_cap") for r in d.rounds) and "stopped at the cap" not in d.verdict  # the tests ended it


def test_a_given_cap_that_ends_the_search_is_said(tree):
    spec, poses = tree
    d = diagnose(spec, poses, Options(max_effects=1))
    assert [f.effect for f in d.findings] == ["compliance"]
    assert "The search stopped at the cap of 1 effect (--max-effects), not at a test" in d.verdict
