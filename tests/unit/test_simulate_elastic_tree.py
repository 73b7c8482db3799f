"""The elastic tree simulator (platkit.simulate.elastic_tree): its equilibrium is the torque
balance of the deflected tree, its bending pair turns the link about the axes across the joint,
and a stiff robot is the rigid one."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.errors import NoConvergence
from platkit.simulate.elastic_tree import (
    ElasticTruth,
    across,
    equilibrium,
    simulate_elastic_tree,
    true_urdf,
    write_elastic_session,
)
from platkit.tree_loads import TreeLoads
from tests.unit.test_tree_loads import CONFIGS, NAMES, _tree

MARKERS = {"L1": "l_lo", "R1": "r_lo"}


def test_the_equilibrium_balances_the_loads_of_the_deflected_tree(tmp_path):
    nominal = _tree(tmp_path)
    truth = ElasticTruth(joint_compliance={"t1": 2e-3, "t2": 3e-3, "l1": 5e-3}, bending={"t2": (4e-3, 1e-3)})
    T = TreeLoads(true_urdf(nominal, truth, tmp_path / "true.urdf"))
    assert {"t2__bend_u", "t2__bend_v"} <= set(T.joints)
    u, v = across(T.axes[T.index["t2"]])
    assert np.allclose(T.axes[T.index["t2__bend_u"]], u) and np.allclose(T.axes[T.index["t2__bend_v"]], v)
    k = np.zeros(len(T.joints))
    for n, c in {"t1": 2e-3, "t2": 3e-3, "l1": 5e-3, "t2__bend_u": 4e-3, "t2__bend_v": 1e-3}.items():
        k[T.index[n]] = c
    Q_cmd = T.configuration(NAMES, CONFIGS)
    Q = equilibrium(T, Q_cmd, k)
    assert np.allclose(Q, Q_cmd - k * T.loads(Q).torque, atol=1e-11)
    assert np.abs(Q - Q_cmd).max() > 1e-3  # it sags
    with pytest.raises(NoConvergence, match="compliances are too large"):
        equilibrium(T, Q_cmd, k * 1e3)


def test_a_stiff_robot_is_the_rigid_one_and_sessions_are_written_whole(tmp_path):
    nominal = _tree(tmp_path)
    stiff = simulate_elastic_tree(nominal, ElasticTruth(), CONFIGS, NAMES, MARKERS, seed=4, noise_mm=0.0)
    assert np.allclose(stiff.exact, stiff.rigid)
    soft = simulate_elastic_tree(nominal, ElasticTruth(joint_compliance={"t2": 5e-3}, bending={"l1": (5e-3, 5e-3)}),
                                 CONFIGS, NAMES, MARKERS, seed=4, noise_mm=0.0)
    assert np.allclose(soft.rigid, stiff.rigid)  # the same stand and markers from the seed
    assert np.linalg.norm(soft.exact - soft.rigid, axis=2).max() > 1e-3
    out = write_elastic_session(soft, nominal, tmp_path / "session", MARKERS)
    rows = (out / "poses.csv").read_text().splitlines()
    assert rows[0].split(",")[:6] == ["t", *NAMES] and len(rows) == 1 + len(CONFIGS)
    assert (out / "tree.urdf").is_file() and (out / "session.yaml").is_file()
