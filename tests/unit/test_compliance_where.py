"""A compliance term says the stand its loads come from in full (plugins/platkit_effects/compliance.py):
read back from calibration.yaml without a stand, a term of a tree rebuilds the whole tree (every
tracked link, every recorded joint), not the chain to its first link."""
from __future__ import annotations

import numpy as np

from platkit.plugins import get_platform, term_from_dict
from platkit_effects import Compliance
from platkit_effects.tree_compliance import tree_stand
from tests.unit.test_tree_loads import _tree


def test_a_tree_compliance_term_read_back_alone_rebuilds_the_tree(tmp_path):
    tree = get_platform("urdf", _tree(tmp_path), moving_link={"L": "l_lo", "R": "r_lo"})
    term = Compliance().term(tree, 1)
    back, theta = term_from_dict(term.to_dict(np.array([1e-4])), None)
    stand = back.stand()
    assert stand.n_u == tree.n_u and stand.control_names == tree.control_names
    assert tree_stand(stand).tracked == ["l_lo", "r_lo"] and theta.tolist() == [1e-4]
