"""Identifiability: pivoted orthogonalisation in priority tiers, named combinations, singular values."""
from __future__ import annotations

import numpy as np
import pytest
from test_estimate import Truth

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.identifiability import null_space_combinations, select_identifiable, singular_values
from platkit.calibrate.problem import CalibrationProblem
from platkit.errors import NotIdentifiable
from platkit.plugins import get_platform
from platkit.poses import PoseSet


def test_a_column_that_is_a_sum_of_others_is_held_with_its_combination():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3))
    J = np.column_stack([A, A[:, 0] + 2 * A[:, 1], np.zeros(50)])
    names = ["a", "b", "c", "d", "e"]
    res = select_identifiable(J, names, np.ones(5), [0, 0, 2, 2, 2])
    assert sorted(res.chosen) == [0, 1, 2]
    held = {h.name: h for h in res.held}
    assert set(held) == {"d", "e"}
    assert held["d"].combination["d"] == 1.0
    assert held["d"].combination["a"] == pytest.approx(-1.0) and held["d"].combination["b"] == pytest.approx(-2.0)
    assert "c" not in held["d"].combination
    assert "at all" in held["e"].reason and held["e"].remaining == 0.0
    assert res.singular_values[-2:] == pytest.approx([0, 0], abs=1e-6)


def test_tiers_decide_which_of_two_aliased_columns_is_kept():
    rng = np.random.default_rng(1)
    x = rng.normal(size=40)
    J = np.column_stack([x, 3 * x, rng.normal(size=40)])
    res = select_identifiable(J, ["td", "mocap", "other"], np.ones(3), [2, 0, 2])
    assert [h.name for h in res.held] == ["td"]
    assert res.held[0].combination["mocap"] == pytest.approx(-1 / 3)
    # the scaling decides nothing about which is kept, only the tiers
    res2 = select_identifiable(J, ["td", "mocap", "other"], np.array([100.0, 1e-3, 1.0]), [2, 0, 2])
    assert [h.name for h in res2.held] == ["td"]


def test_singular_values_match_the_svd():
    A = np.random.default_rng(2).normal(size=(200, 7)) * np.logspace(0, -3, 7)
    assert singular_values(A) == pytest.approx(np.linalg.svd(A, compute_uv=False), rel=1e-8)


def test_null_space_is_named():
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(2, 30))
    J = np.column_stack([a, b, a - b])
    combos = null_space_combinations(J, ["p", "q", "r"], np.ones(3))
    assert len(combos) == 1
    c = combos[0]
    assert set(c) == {"p", "q", "r"}
    assert c["p"] == pytest.approx(-c["q"]) and c["r"] == pytest.approx(-c["p"])


def test_stewart_structural_redundancy_is_the_two_rigid_motions():
    spec = get_platform("stewart")
    truth = Truth(spec, seed=31)
    poses = truth.poses(60, 1e-4)
    problem = CalibrationProblem(spec, poses)
    z = problem.initial_registration(spec.nominal_td())
    J = problem.evaluate(z).J.reshape(-1, problem.n_z)
    combos = null_space_combinations(J, problem.names, problem.scale)
    assert len(combos) == 12  # base joints with the mocap transform (6), platform joints with the markers (6)
    for c in combos:
        kinds = {n.split(".")[0][0] if not n.startswith(("mocap", "marker")) else n.split(".")[0] for n in c}
        assert kinds <= {"B", "P", "mocap", "marker"} and not any(n.startswith("dL") for n in c)


def test_two_poses_cannot_fix_the_transform():
    spec = get_platform("stewart")
    truth = Truth(spec, seed=32)
    poses = truth.poses(2, 1e-4)
    with pytest.raises(NotIdentifiable, match="cannot fix marker"):
        calibrate(poses, spec)


def test_a_marker_never_seen_is_named_not_guessed():
    spec = get_platform("stewart")
    truth = Truth(spec, seed=33)
    poses = truth.poses(30, 1e-4)
    Y = poses.markers.copy()
    Y[:, 1] = np.nan
    with pytest.raises(NotIdentifiable, match="marker.M2"):
        calibrate(PoseSet("stewart", poses.controls, Y, poses.marker_names), spec)
