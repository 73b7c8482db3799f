"""Work skipped for speed gives the numbers it gave before (issue 24's tree against a chain, the
sixth pass): a term's Jacobian column by differences without the products by the offsets' zero
columns; a model selection's scored candidates without the figures only a written calibration
reports (platkit.calibrate.stages.scored_only); the identifiability's singular values and the
gauge's reference rank computed when first read.

The urdf stand's default arm (closed-form forward kinematics: fast), simulated with a fixed seed.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from simulated_arm import TURNTABLE, arm_poses

from platkit.calibrate import identifiability, stages
from platkit.calibrate import problem as problem_module
from platkit.calibrate.estimate import calibrate
from platkit.calibrate.identifiability import select_identifiable, singular_values
from platkit.calibrate.problem import CalibrationProblem
from platkit.calibrate.selection import select_model
from platkit.calibrate.term_columns import offset_column, support
from platkit.plugins import get_platform
from platkit.terms import ModelTerm


@pytest.fixture(scope="module")
def arm():
    return get_platform("urdf")


@pytest.fixture(scope="module")
def poses(arm):
    return arm_poses(arm, 11, 48)


@dataclass
class _Controls(ModelTerm):
    """theta[0] times a function of the pose on the controls ``joints`` (its Jacobian by differences)."""

    joints: tuple[int, ...] = (0,)
    uses_kinematics = False

    def control_offset(self, theta, poses, n_u):
        out = np.zeros((poses.n_poses, n_u))
        for j in self.joints:
            out[:, j] = theta[0] * np.sin(poses.controls[:, j])
        return out


@dataclass
class _Marker(ModelTerm):
    """theta[0] along x of the first marker, whatever the pose: one column of its marker offsets."""

    uses_kinematics = False

    def marker_offset(self, theta, poses):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[:, 0, 0] = theta[0]
        return out


def _terms():
    return [_Controls("a", ["a"], np.zeros(1), joints=(1,)), _Controls("b", ["b"], np.zeros(1), joints=(0, 2)),
            _Marker("c", ["c"], np.zeros(1)), ModelTerm("none", ["n"], np.zeros(1))]


def test_an_offset_column_is_the_sum_of_its_parts_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(200):
        parts = []
        for k in (6, 4, 9):
            Y = rng.normal(size=(5, 4, k))
            Y[rng.random(Y.shape) < 0.3] = 0.0
            Y[rng.random(Y.shape) < 0.1] = -0.0
            d = np.zeros((5, k))
            kind = rng.integers(0, 4)
            if kind == 1:  # one column, some poses at zero
                d[:, rng.integers(k)] = rng.normal(size=5) * (rng.random(5) < 0.7)
            elif kind == 2:  # a column of negative zeros
                d[:, rng.integers(k)] = -0.0
            elif kind == 3:  # several columns: the whole sum
                d[:, rng.choice(k, 3, replace=False)] = rng.normal(size=(5, 3))
            parts.append((Y, d))
        whole = sum((np.einsum("nak,nk->na", Y, d) for Y, d in parts[1:]), np.einsum("nak,nk->na", *parts[0]))
        got = offset_column(parts, tuple(support(d) for _, d in parts))
        assert np.array_equal(whole, got) and np.array_equal(np.signbit(whole), np.signbit(got))
        assert np.array_equal(whole, offset_column(parts, None))


def test_term_columns_by_differences_skip_the_products_by_zeros_and_give_the_same_jacobian(arm, poses, monkeypatch):
    rng = np.random.default_rng(5)
    base = calibrate(poses, arm)
    z = np.concatenate([base.fit.z, rng.normal(0, 1e-3, 4)])
    einsums = []
    real = np.einsum
    monkeypatch.setattr(np, "einsum", lambda *a, **k: einsums.append(a[0]) or real(*a, **k))
    fast = CalibrationProblem(arm, poses, _terms()).evaluate(z)
    # one product for term b's two controls; none for a (one control), c (one marker column), none
    assert einsums.count("nak,nk->na") == 1
    monkeypatch.setattr(problem_module, "support", lambda d: np.arange(d.shape[1]))  # every column: every product
    plain = CalibrationProblem(arm, poses, _terms()).evaluate(z)
    assert einsums.count("nak,nk->na") == 1 + 3 * 4
    assert np.array_equal(fast.J, plain.J) and np.array_equal(np.signbit(fast.J), np.signbit(plain.J))
    assert np.array_equal(fast.r, plain.r, equal_nan=True)


def test_figures_are_computed_when_first_read_and_equal_the_direct_ones():
    rng = np.random.default_rng(9)
    J = rng.normal(size=(40, 6))
    J[:, 5] = J[:, 0] + J[:, 1]  # aliased: held
    res = select_identifiable(J, [f"p{i}" for i in range(6)], np.ones(6), [0] * 6)
    assert "singular_values" not in res.__dict__ and "condition_number" not in res.__dict__
    Js = np.linalg.qr(J, mode="r")
    np.testing.assert_array_equal(res.singular_values, singular_values(Js))
    s = singular_values(Js[:, res.chosen])
    assert res.condition_number == s[0] / s[-1]
    assert res.to_dict()["n_identifiable"] == 5


def test_a_scored_candidate_is_the_same_fit_without_the_reported_figures(arm, poses, monkeypatch):
    free = [p.name for p in arm.parameters if p.group in ("offset", "origin")]
    full = calibrate(poses, arm, free=free)
    classified = []
    real = stages.classify_held
    monkeypatch.setattr(stages, "classify_held", lambda *a, **k: classified.append(1) or real(*a, **k))
    with stages.scored_only():
        scored = calibrate(poses, arm, free=free)
    assert not classified  # nor the gauge's reference rank, read only by the classification
    assert "not_computed" in scored.identifiability and "singular_values" not in scored.identifiability
    assert "singular_values_at_estimate" in full.identifiability and "not_computed" not in full.identifiability
    for a, b in ((full.fit.z, scored.fit.z), (full.fit.active, scored.fit.active), (full.td, scored.td),
                 (full.td_std, scored.td_std), (full.fit.weights, scored.fit.weights)):
        assert np.array_equal(a, b, equal_nan=True)
    assert (full.td_status, full.rms_after, full.noise_sigma) == (scored.td_status, scored.rms_after, scored.noise_sigma)
    assert [h["name"] for h in full.identifiability["held_at_nominal"]] == \
        [h["name"] for h in scored.identifiability["held_at_nominal"]]
    with stages.scored_only():
        with stages.scored_only():
            pass
        assert stages._SCORED.on  # a nested block restores what was there
    assert not stages._SCORED.on


def test_a_selection_scores_its_candidates_only_and_writes_the_full_chosen_one(arm, poses, monkeypatch):
    report_flags = []
    real = stages._uncertainty
    monkeypatch.setattr(stages, "_uncertainty", lambda *a, **k: report_flags.append(a[4]) or real(*a, **k))
    cal = select_model(poses, arm)
    assert report_flags[0] is True and report_flags[-1] is True  # the reference and the chosen model, written
    assert False in report_flags  # the scored candidates
    assert "singular_values_at_estimate" in cal.identifiability and "not_computed" not in cal.identifiability
    gauge = identifiability.Gauge([], [], np.arange(3), np.eye(3), [0, 0, 0], 1e-6, np.zeros((3, 0)),
                                  np.zeros((0, 6)), np.zeros((0, 6)))
    assert "rank_ref" not in gauge.__dict__ and gauge.rank_ref == 3




def test_a_scored_candidate_holds_the_gauges_a_full_calibration_holds(tmp_path, monkeypatch):
    from test_estimate import Truth

    turntable = tmp_path / "turntable.urdf"
    turntable.write_text(TURNTABLE, encoding="utf-8")
    gantry = Path(__file__).resolve().parents[2] / "descriptions" / "gantry_xyz.urdf"
    analysed = []
    real = stages.nuisance_gauge
    monkeypatch.setattr(stages, "nuisance_gauge", lambda *a, **k: analysed.append(int(a[2].sum())) or real(*a, **k))
    for path, seed, n in ((gantry, 3, 50), (turntable, 8, 30)):
        spec = get_platform("urdf", path)
        poses = Truth(spec, seed=seed, n_markers=4, marker_spread=0.05).poses(n, 1e-4, spread=0.45)
        full = calibrate(poses, spec)
        with stages.scored_only():
            scored = calibrate(poses, spec)
        assert full.identifiability["gauge"]["held_during_the_fit"]  # gauges held: the case that matters
        assert analysed[-1] == 6 + 3 * 4 < analysed[-2]  # the transform's and markers' columns alone
        for a, b in ((full.fit.z, scored.fit.z), (full.fit.active, scored.fit.active), (full.td, scored.td),
                     (full.marker_positions, scored.marker_positions), (full.fit.weights, scored.fit.weights)):
            assert np.array_equal(a, b, equal_nan=True)
        assert (full.td_status, full.rms_after) == (scored.td_status, scored.rms_after)
