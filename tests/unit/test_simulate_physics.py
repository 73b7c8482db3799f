"""The time-domain simulator (platkit.simulate.physics): settling in the stream, the true settled
pose, effects where their physics acts, determinism, the truth files and the CLI."""
from __future__ import annotations

import csv

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.effects import Effect, EffectPhysics
from platkit.errors import BadInput
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.simulate.actuator import ActuatorResponse, actuator_motion
from platkit.simulate.physics import simulate_physics, write_physical_session
from platkit_effects.physics import play_operator

QUIET = {"noise_mm": 0.0, "occlusion": 0.0, "latency_s": 0.0, "clock_offset_s": 0.0, "coloured": False}


@pytest.fixture(scope="module")
def psvr():
    return get_platform("psvr")


def _exposure(sim):
    """Exposure times of the stream on the commands clock."""
    return sim.marker_t - sim.nuisances.time_shift_s


def _hold_end_samples(sim):
    return np.searchsorted(_exposure(sim), sim.hold_end_t, side="left") - 1


def test_actuator_step_is_the_critically_damped_response():
    tau = 0.2
    r = ActuatorResponse(np.array([tau]), np.array([1.0]), np.array([1e6]), np.array([1e9]))
    t = np.linspace(1.0, 3.0, 41)
    x = actuator_motion(t, np.array([1.0]), np.array([[1.0]]), np.array([0.0]), r, fine_step_s=1e-4)[:, 0]
    s = t - 1.0
    expected = 1 - (1 + s / tau) * np.exp(-s / tau)
    assert np.max(np.abs(x - expected)) < 2e-3


def test_actuator_respects_the_rate_limit():
    r = ActuatorResponse(np.array([0.01]), np.array([1.0]), np.array([0.5]), np.array([5.0]))
    t = np.arange(0.0, 6.0, 0.001)
    x = actuator_motion(t, np.array([0.0]), np.array([[2.0]]), np.array([0.0]), r)[:, 0]
    v = np.diff(x) / 0.001
    assert v.max() < 0.5 * 1.01 and v.max() > 0.49  # cruises at the limit
    assert abs(x[-1] - 2.0) < 1e-6  # 4.1 s of profile, then settled


def test_clean_holds_settle_to_the_forward_kinematics_of_the_command(psvr):
    sim = simulate_physics(psvr, seed=3, n_poses=12, **QUIET)
    fk = PlatformModel(psvr).forward_batch(sim.commands, td=sim.td)
    assert np.allclose(sim.settled_X, fk.X, atol=1e-12)
    assert np.allclose(sim.settled_controls, sim.commands)
    # the stream at the end of every hold is there (to the files' 1 um)
    k = _hold_end_samples(sim)
    assert np.max(np.abs(sim.markers[k] - sim.settled_markers)) < 2e-6
    # ... and was not there at the start of the hold: settling is in the stream
    start = np.searchsorted(_exposure(sim), sim.command_t[1:] + 0.05)
    moved = np.linalg.norm(sim.markers[start] - sim.settled_markers[1:], axis=2).max(axis=1)
    assert np.median(moved) > 1e-3


def test_a_slow_actuator_settles_with_its_time_constant(psvr):
    sim = simulate_physics(psvr, seed=5, n_poses=10, hold_s=2.5, effects=[("settling_lag", 0.2)], **QUIET)
    (_, slow), = sim.physics
    tau = sim.response.tau_s[slow.index]
    assert tau == pytest.approx(0.5)
    te = _exposure(sim)
    # the tail of the slowest moving hold: distance to rest decays as (a + b t) exp(-t / tau)
    steps = np.abs(np.diff(sim.commands[:, slow.index]))
    i = int(np.argmax(steps)) + 1
    w = (te > sim.hold_end_t[i] - 1.2) & (te < sim.hold_end_t[i])
    d = np.linalg.norm(sim.markers[w] - sim.settled_markers[i], axis=2).mean(axis=1)
    slope = np.polyfit(te[w], np.log(d), 1)[0]
    # the (a + b t) factor makes the decay a little slower than exp(-t / tau)
    assert -1.0 / tau < slope < -0.6 / tau
    # a clean session with the same seed is settled by then
    clean = simulate_physics(psvr, seed=5, n_poses=10, hold_s=2.5, **QUIET)
    k = _hold_end_samples(clean)
    assert np.abs(clean.markers[k] - clean.settled_markers).max() < 2e-6
    assert d[-1] > 1e-4


def test_play_operator():
    x = np.array([0.0, 1.0, 2.0, 1.8, 1.0, 0.5, 1.0])
    y = play_operator(x, 1.0, 0.0)
    assert np.allclose(y, [0.0, 0.5, 1.5, 1.5, 1.5, 1.0, 1.0])


def test_backlash_settles_by_approach_direction_by_the_play(psvr):
    sim = simulate_physics(psvr, seed=2, n_poses=16, plan="random", effects=[("backlash", 20.0)], **QUIET)
    (_, bl), = sim.physics
    j = bl.index
    assert bl.play == pytest.approx(20.0)  # counts
    steps = np.diff(np.vstack([psvr.neutral_u()[None], sim.commands])[:, j])
    direction = np.sign(steps)
    moved = direction != 0
    off = sim.settled_controls[:, j] - sim.commands[:, j]
    assert np.allclose(off[moved], -0.5 * bl.play * direction[moved])
    others = [i for i in range(psvr.n_u) if i != j]
    assert np.allclose(sim.settled_controls[:, others], sim.commands[:, others])
    # the stream agrees with the truth at the end of every hold
    k = _hold_end_samples(sim)
    assert np.max(np.abs(sim.markers[k] - sim.settled_markers)) < 2e-6


def test_a_slip_moves_one_marker_at_its_instant(psvr):
    slip = simulate_physics(psvr, seed=4, n_poses=12, effects=[("marker_slip", 3.0)], **QUIET)
    clean = simulate_physics(psvr, seed=4, n_poses=12, **QUIET)
    (_, p), = slip.physics
    te = _exposure(slip)
    diff = np.linalg.norm(slip.markers - clean.markers, axis=2)  # (K, M)
    others = [m for m in range(len(slip.marker_names)) if m != p.index]
    assert diff[:, others].max() < 2e-6
    before, after = te < p.t_s, te >= p.t_s
    assert diff[before, p.index].max() < 2e-6
    assert np.allclose(diff[after, p.index], 3e-3, atol=2e-6)


def test_determinism_per_seed(psvr):
    a = simulate_physics(psvr, seed=7, n_poses=8, effects=[("thermal_drift", None)])
    b = simulate_physics(psvr, seed=7, n_poses=8, effects=[("thermal_drift", None)])
    c = simulate_physics(psvr, seed=8, n_poses=8, effects=[("thermal_drift", None)])
    assert np.array_equal(a.markers, b.markers, equal_nan=True)
    assert a.nuisances.to_dict() == b.nuisances.to_dict()
    assert a.nuisances.to_dict() != c.nuisances.to_dict()
    # an effect leaves the stand and the nuisances as they were
    plain = simulate_physics(psvr, seed=7, n_poses=8)
    assert plain.nuisances.to_dict() == a.nuisances.to_dict()
    assert np.array_equal(plain.td, a.td)


def test_thermal_expansion_follows_the_motion(psvr):
    sim = simulate_physics(psvr, seed=6, n_poses=20, effects=[("thermal_drift", 5.0)], **QUIET)
    (_, th), = sim.physics
    grow = sim.settled_controls - sim.commands
    assert grow.max() == pytest.approx(5.0, rel=0.05)  # counts, the largest expansion
    assert np.all(grow >= 0)
    assert np.all(grow[-1] > grow[0])


def test_truth_files_hold_the_nuisances_and_the_settled_poses(psvr, tmp_path):
    sim = simulate_physics(psvr, seed=9, n_poses=8, effects=[("base_tilt", 3.0)], imu={"rate_hz": 100.0})
    out = write_physical_session(sim, tmp_path / "s")
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert truth["nuisances"] == yaml.safe_load(yaml.safe_dump(sim.nuisances.to_dict()))
    for key in ("hold_s", "marker_noise_white_m", "marker_noise_coloured_m", "occlusion", "mocap_latency_s",
                "clock_offset_s", "actuators"):
        assert key in truth["nuisances"]
    assert truth["effects"][0]["effect"] == "base_tilt"
    assert np.allclose(truth["mocap_from_base"], sim.mocap_from_base)
    rows = list(csv.DictReader((out / "truth_settled.csv").open()))
    assert len(rows) == len(sim.commands)
    assert float(rows[3]["M2_y"]) == pytest.approx(sim.settled_markers[3, 1, 1] * 1e3, abs=1e-4)
    session = yaml.safe_load((out / "session.yaml").read_text())
    assert session["imu"]["rate_hz"] == 100.0
    imu_truth = yaml.safe_load((out / "truth_imu.yaml").read_text())
    assert np.allclose(imu_truth["base_tilt_rad"], sim.physics[0][1].tilt)
    # the tilt is in the true mocap_from_base: the base's z against the mocap's vertical
    z = np.asarray(truth["mocap_from_base"])[:3, 2]
    assert np.degrees(np.arccos(z[2])) == pytest.approx(np.degrees(3e-3), rel=1e-6)


def test_cli_physics_writes_a_session_the_reader_takes(tmp_path, capsys):
    from platkit.io.session import load_session

    out = tmp_path / "s"
    assert main(["simulate", "--platform", "psvr", "--physics", "--poses", "6", "--seed", "1", "--out", str(out),
                 "--effect", "backlash=10"]) == 0
    assert "hidden effect backlash" in capsys.readouterr().out
    s = load_session(out)
    assert s.markers.shape[1] == 5 and len(s.command_t) == 6
    assert (out / "truth_settled.csv").is_file()


def test_cli_physics_bad_input(tmp_path, capsys):
    assert main(["simulate", "--platform", "psvr", "--physics", "--out", str(tmp_path / "a"),
                 "--effect", "no_such_effect"]) == 2
    assert "no_such_effect" in capsys.readouterr().err
    assert main(["simulate", "--platform", "psvr", "--out", str(tmp_path / "b"), "--overshoot"]) == 2
    assert "only with --physics" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_an_effect_without_physics_is_refused(psvr, monkeypatch):
    class Bare(Effect):
        name = "bare"

    from outside_plugins import library_with

    with pytest.raises(BadInput, match="no physics"):
        simulate_physics(psvr, seed=1, n_poses=4, effects=[("bare", None)], library=library_with(Bare()))


def test_an_outside_effect_with_physics_plays_out(psvr, monkeypatch):
    class Shift(EffectPhysics):
        effect = "shift"

        def drive(self, series, plan):
            return series.motor + np.array([5.0, 0.0, 0.0])

    class Outside(Effect):
        name = "shift"

        def physics(self, spec, size, rng, plan):
            return Shift()

    from outside_plugins import library_with

    sim = simulate_physics(psvr, seed=1, n_poses=4, effects=[("shift", None)], library=library_with(Outside()), **QUIET)
    assert np.allclose(sim.settled_controls - sim.commands, [5.0, 0.0, 0.0])
