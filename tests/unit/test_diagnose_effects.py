"""The built-in effect library: registration, terms, round trips through calibration.yaml, history."""
import numpy as np
import pytest

from platkit.effects import move_direction, with_history
from platkit.plugins import effect_library, term_from_dict
from platkit.errors import BadInput
from platkit.plugins import get_platform
from platkit.poses import PoseSet

NAMES = ["backlash", "compliance", "thermal_drift", "cyclic_error", "scale_nonlinearity", "settling_lag",
         "marker_slip", "base_tilt"]


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


def _poses(spec, n=40, seed=0, M=3):
    rng = np.random.default_rng(seed)
    lo, hi = spec.control_bounds()
    U = spec.neutral_u() + rng.uniform(-0.25, 0.25, (n, spec.n_u)) * (hi - lo)
    return with_history(PoseSet(spec.name, U, np.zeros((n, M, 3)), [f"M{k}" for k in range(M)], t=10 + 3.0 * np.arange(n)),
                        spec)


def test_every_named_effect_is_registered_through_the_hook():
    lib = effect_library()
    assert set(NAMES) <= set(lib)
    for name in NAMES:
        assert lib[name].name == name and lib[name].summary


def test_direction_keeps_the_last_move_and_starts_unknown():
    U = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [1.0, 0.0], [0.5, 2.0]])
    assert np.array_equal(move_direction(U), [[0, 0], [1, 0], [1, -1], [1, -1], [-1, 1]])


def test_history_is_computed_on_the_full_session_and_kept_by_subsets(stewart):
    poses = _poses(stewart)
    assert np.allclose(poses.extras["elapsed"], 3.0 * np.arange(40))
    sub = poses.subset(np.arange(1, 40, 2))
    assert np.array_equal(sub.extras["direction"], poses.extras["direction"][1::2])


def test_each_candidate_round_trips_through_to_dict(stewart):
    poses = _poses(stewart)
    lib = effect_library()
    residuals = np.random.default_rng(1).normal(0, 1e-5, (40, 3, 3))
    residuals[20:, 1] += 1e-4  # one marker steps (a slip moves one marker only)
    rng = np.random.default_rng(2)
    for name in NAMES:
        cands = lib[name].candidates(stewart, poses, residuals)
        assert cands, name
        term = cands[0]
        theta = rng.normal(0, 1e-4, len(term.initial))
        data = term.to_dict(theta, np.full(len(theta), 1e-6))
        for spec in (stewart, None):  # result.py passes no spec; the term's where is enough
            back, th = term_from_dict(data, spec)
            assert back.effect == name and np.allclose(th, theta)
            for a, b in ((term.control_offset(theta, poses, 6), back.control_offset(th, poses, 6)),
                         (term.marker_offset(theta, poses), back.marker_offset(th, poses))):
                assert np.allclose(a, b)
            q = np.tile([1.0, 0, 0, 0], (40, 1))
            X = np.random.default_rng(3).normal(size=(40, 3))
            assert np.allclose(term.pose_offset(theta, poses, q, X), back.pose_offset(th, poses, q, X))


def test_term_offsets_have_the_documented_form(stewart):
    poses = _poses(stewart)
    lib = effect_library()
    b = lib["backlash"].candidates(stewart, poses)[2]
    off = b.control_offset(np.array([1e-3]), poses, 6)
    assert np.allclose(off[:, b.index], 1e-3 * poses.extras["direction"][:, b.index])
    assert np.count_nonzero(off[:, [i for i in range(6) if i != b.index]]) == 0
    s = lib["scale_nonlinearity"].candidates(stewart, poses)[0]
    ends = PoseSet("stewart", np.tile(stewart.neutral_u(), (2, 1)), np.zeros((2, 3, 3)), ["a", "b", "c"])
    ends.controls[:, s.index] = [s.lower, s.upper]
    assert np.allclose(s.control_offset(np.array([2e-3, 0.0]), ends, 6)[:, s.index], 2e-3)  # P2(+-1) = 1
    lag = lib["settling_lag"].candidates(stewart, poses)[0]
    assert np.allclose(lag.control_offset(np.array([0.1]), poses, 6), -0.1 * poses.extras["last_step"])
    drift = lib["thermal_drift"].candidates(stewart, poses)[0]
    off = drift.pose_offset(np.array([0.0, 0.0, 1e-6]), poses, None, np.zeros((40, 3)))
    assert np.allclose(off[:, 2], 1e-6 * poses.extras["elapsed"]) and np.allclose(off[:, 3:], 0)


def test_parallel_compliance_load_is_the_static_force_balance(stewart):
    from platkit_effects import parallel_actuator_forces

    U = np.tile(stewart.neutral_u(), (1, 1))
    f = parallel_actuator_forces(stewart, U)[0]
    # symmetric neutral pose: six equal leg forces whose vertical parts carry the 1 N weight
    B = stewart.extras["base_joints_m"]
    P = stewart.extras["platform_joints_m"] + np.array([0, 0, 3.147])
    unit = (P - B) / np.linalg.norm(P - B, axis=1)[:, None]
    assert np.allclose(f, f[0], rtol=1e-6)
    assert np.isclose(np.sum(f * unit[:, 2]), 1.0, rtol=1e-6)


def test_serial_compliance_uses_the_urdf_gravity_torques():
    import pinocchio as pin
    from platkit_effects import serial_gravity_torques

    rotary = get_platform("rotary")
    urdf = str(rotary.extras["urdf_path"])
    q = np.array([[0.3, 0.2], [0.3, -0.5]])
    tau = serial_gravity_torques(urdf, tuple(rotary.control_names), q)
    model = pin.buildModelFromUrdf(urdf)
    ref = np.array([pin.computeGeneralizedGravity(model, model.createData(), qq) for qq in q])
    assert np.allclose(tau, ref)


def test_stored_terms_with_bad_fields_are_bad_input(stewart):
    with pytest.raises(BadInput, match="unknown effect"):
        term_from_dict({"effect": "gremlins", "parameters": {}}, stewart)
    with pytest.raises(BadInput, match="actuator"):
        term_from_dict({"effect": "backlash", "where": {"actuator": "L9"}, "parameters": {"half_play": {"value": 1}}},
                       stewart)
    with pytest.raises(BadInput, match="period"):
        term_from_dict({"effect": "cyclic_error", "where": {"actuator": "L1", "period": -1},
                        "parameters": {}}, stewart)
    with pytest.raises(BadInput, match="half_play"):
        term_from_dict({"effect": "backlash", "where": {"actuator": "L1"}, "parameters": {}}, stewart)


def test_simulation_terms_come_from_the_library(stewart):
    from platkit.simulate import simulate

    sim = simulate(stewart, seed=4, n_poses=30, raw=False, plan="random", effects=[("backlash", 2.0)])
    term, theta = sim.truth.terms[0]
    assert type(term).__name__ == "BacklashTerm" and np.isclose(theta[0], 1e-3)
