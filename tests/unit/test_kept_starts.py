"""A model selection's candidates share their start: the gauge analysis, the data's view of the
transform and markers and the registration-only stage are kept (platkit.calibrate.registration.kept)
while a selection runs, by everything they read. A kept result is what computing it again gives,
bit for bit; other inputs (another candidate set, another z, other poses, another loss) are
computed, never served a kept result; nothing is kept outside a selection.

The urdf stand's default arm (closed-form forward kinematics: fast), simulated with a fixed seed.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest
from simulated_arm import arm_poses

from platkit.calibrate import identifiability, registration, stages
from platkit.calibrate.estimate import calibrate
from platkit.calibrate.stages import CalibrationOptions, _registration_only, _start
from platkit.plugins import get_platform


@pytest.fixture(scope="module")
def arm():
    return get_platform("urdf")


@pytest.fixture(scope="module")
def poses(arm):
    return arm_poses(arm, 7, 60)


def _names(arm, groups):
    return [p.name for p in arm.parameters if p.group in groups]


def _gauge_state(g) -> tuple:
    return (list(g.held), list(g.held_names), g.ref_idx.tolist(), g.J_ref.tobytes(), int(g.rank_ref), g.shift.tobytes())


def _counting(monkeypatch, module, name):
    calls = []
    original = getattr(module, name)

    def counted(*args, **kwargs):
        calls.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


def test_the_generic_memo_keys_by_inputs_copies_and_forgets():
    computed = []

    def compute(v):
        def run():
            computed.append(v)
            return np.array([v, v])
        return run

    k1, k2 = registration.digest(np.array([1.0]), "a"), registration.digest(np.array([2.0]), "a")
    assert k1 != k2 and k1 == registration.digest(np.array([1.0]), "a")
    assert registration.digest(np.array([1.0])) != registration.digest([1.0])  # an array is not a list
    registration.kept("x", k1, compute(1.0), np.copy)
    registration.kept("x", k1, compute(1.0), np.copy)
    assert computed == [1.0, 1.0]  # outside a selection: computed every time, nothing kept
    assert not registration._KEPT
    with registration.kept_registrations():
        a = registration.kept("x", k1, compute(1.0), np.copy)
        a[:] = 9.0  # the caller writes into its copy
        b = registration.kept("x", k1, compute(1.0), np.copy)
        c = registration.kept("x", k2, compute(2.0), np.copy)  # another key: computed
        d = registration.kept("y", k1, compute(3.0), np.copy)  # another kind, same key: computed
        assert computed == [1.0, 1.0, 1.0, 2.0, 3.0]
        np.testing.assert_array_equal(b, [1.0, 1.0])
        np.testing.assert_array_equal(c, [2.0, 2.0])
        np.testing.assert_array_equal(d, [3.0, 3.0])

        def fails():
            raise RuntimeError("no")

        for _ in range(2):  # an exception is not kept: the second call computes again
            with pytest.raises(RuntimeError):
                registration.kept("z", k1, fails, np.copy)
        for v in range(10):  # only the last few of a kind stay
            registration.kept("x", registration.digest(float(v)), compute(float(v)), np.copy)
        assert sum(k[0] == "x" for k in registration._KEPT) == registration._KEEP
    assert not registration._KEPT


def test_a_candidate_s_start_is_a_copy_of_the_same_start_and_never_another(arm, poses, monkeypatch):
    gauge_calls = _counting(monkeypatch, stages, "nuisance_gauge")
    view_calls = _counting(monkeypatch, identifiability, "_data_view")
    fit_calls = _counting(monkeypatch, stages, "robust_fit")
    every = CalibrationOptions(free=_names(arm, ("offset", "origin", "scale")))
    fewer = CalibrationOptions(free=_names(arm, ("origin",)))
    fresh_every = _start(poses, arm, [], every)  # outside a selection: the reference values
    fresh_fewer = _start(poses, arm, [], fewer)
    fresh_reg = _registration_only(fresh_fewer, fewer)
    assert (len(gauge_calls), len(view_calls), len(fit_calls)) == (2, 2, 1)
    with registration.kept_registrations():
        s1 = _start(poses, arm, [], every)
        s1.gauge.held_names.append("written by its caller")  # a caller writes into what it got
        s2 = _start(poses, arm, [], fewer)  # another candidate set: its own gauge, the data's view kept
        assert (len(gauge_calls), len(view_calls)) == (4, 3)
        s3 = _start(poses, arm, [], fewer)  # the same inputs: the kept gauge
        assert len(gauge_calls) == 4
        for got, fresh in ((s2, fresh_fewer), (s3, fresh_fewer)):
            assert _gauge_state(got.gauge) == _gauge_state(fresh.gauge)
            np.testing.assert_array_equal(got.candidates, fresh.candidates)
        assert _gauge_state(s1.gauge)[2:] == _gauge_state(fresh_every.gauge)[2:]
        assert s2.candidates.sum() != s1.candidates.sum()  # the two candidate sets differ indeed
        # another z (another starting td): computed, not served the kept start
        moved = arm.nominal_td().copy()
        moved[[i for i, p in enumerate(arm.parameters) if p.group == "offset"][0]] += 0.05
        s4 = _start(poses, arm, [], CalibrationOptions(free=fewer.free, td_start=moved))
        assert (len(gauge_calls), len(view_calls)) == (5, 4)
        assert not np.array_equal(s4.z, s2.z)
        # stage 1: kept for the same start and loss, computed for another loss or other poses
        r1 = _registration_only(s2, fewer)
        r1.z[:] = 0.0  # the caller writes into its copy
        r2 = _registration_only(s3, fewer)
        assert len(fit_calls) == 2
        for got in (r2,):
            np.testing.assert_array_equal(got.z, fresh_reg.z)
            np.testing.assert_array_equal(got.state.r, fresh_reg.state.r)
            np.testing.assert_array_equal(got.weights, fresh_reg.weights)
            assert got.iterations == fresh_reg.iterations
        _registration_only(s3, CalibrationOptions(free=fewer.free, robust=False))
        assert len(fit_calls) == 3
        other = copy.deepcopy(poses)
        other.markers[5, 1, 0] += 2e-3
        s5 = _start(other, arm, [], fewer)
        _registration_only(s5, fewer)
        assert len(fit_calls) == 4 and (len(gauge_calls), len(view_calls)) == (6, 5)
        progress = CalibrationOptions(free=fewer.free, progress=lambda *a: None)
        _registration_only(s3, progress)  # a fit that reports its progress is computed
        assert len(fit_calls) == 5
    assert not registration._KEPT


def test_a_calibration_inside_a_selection_is_the_one_outside(arm, poses):
    free = _names(arm, ("origin",))
    alone = calibrate(poses, arm, free=free, robust=True)
    with registration.kept_registrations():
        calibrate(poses, arm, free=_names(arm, ("offset", "origin")), robust=True)
        calibrate(poses, arm, free=free, robust=True)
        kept = calibrate(poses, arm, free=free, robust=True)
        assert any(k[0] == "registration_only" for k in registration._KEPT)
    np.testing.assert_array_equal(kept.td, alone.td)
    np.testing.assert_array_equal(kept.td_std, alone.td_std)
    assert kept.rms_before == alone.rms_before and kept.rms_after == alone.rms_after
    assert kept.identifiability["singular_values"] == alone.identifiability["singular_values"]
    assert kept.identifiability["gauge"] == alone.identifiability["gauge"]
