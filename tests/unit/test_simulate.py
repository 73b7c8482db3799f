"""Simulated sessions: every registered stand, a known truth, effects through model terms."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.errors import BadInput, BadSession
from platkit.geometry import matrix_from_quat
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform, list_platforms
from platkit.settle import load_poses
from platkit.simulate import _commands_poseset, simulate, simulate_session
from platkit.simulate.effects import parse_effect, simulation_term
from platkit.terms import ModelTerm
from platkit_effects import BacklashTerm

EFFECTS = ["backlash", "compliance", "thermal_drift", "cyclic_error", "scale_nonlinearity", "settling_lag", "marker_slip",
           "base_tilt"]


def _true_markers(spec, truth, U, terms_offset=None):
    """Markers (N, M, 3) in the mocap frame computed from the truth alone."""
    model = PlatformModel(spec)
    fb = model.forward_batch(U if terms_offset is None else U + terms_offset, td=truth.td, strict=False)
    R = matrix_from_quat(fb.q)
    Y = fb.X[:, None, :] + np.einsum("kij,mj->kmi", R, truth.markers)
    T = truth.mocap_from_base
    return Y @ T[:3, :3].T + T[:3, 3]


@pytest.mark.parametrize("name", sorted(list_platforms()))
def test_every_stand_simulates_and_settles_to_its_truth(name):
    spec = get_platform(name)
    sim = simulate(spec, seed=11, n_poses=12, mocap_rate_hz=40, noise_mm=0.2)
    assert sim.poses.n_poses == 12 and not sim.poses.dropped
    err = sim.poses.markers - _true_markers(spec, sim.truth, sim.poses.controls)
    # averages over >= 20 samples of 0.2 mm noise: 0.045 mm per coordinate at most on average
    assert np.sqrt(np.nanmean(err**2)) < 0.06e-3, name
    assert np.nanmax(np.abs(err)) < 0.25e-3, name
    # the truth differs from nominal by a few mm / mrad, not more
    d = sim.truth.td - sim.truth.td_nominal
    lengths = np.array([p.unit == "m" and p.free for p in spec.parameters])
    if lengths.any():
        assert 0.3e-3 < np.sqrt(np.mean(d[lengths] ** 2)) < 5e-3


def test_direct_poses_match_the_truth_exactly_without_noise():
    spec = get_platform("stewart")
    sim = simulate(spec, seed=3, n_poses=10, raw=False, noise_mm=0.0, occlusion=0.0)
    np.testing.assert_allclose(sim.poses.markers, _true_markers(spec, sim.truth, sim.poses.controls), atol=1e-9)


def test_seed_fixes_everything():
    spec = get_platform("psvr")
    a = simulate(spec, seed=4, n_poses=6, raw=False)
    b = simulate(spec, seed=4, n_poses=6, raw=False)
    c = simulate(spec, seed=5, n_poses=6, raw=False)
    np.testing.assert_array_equal(a.poses.markers, b.poses.markers)
    np.testing.assert_array_equal(a.truth.td, b.truth.td)
    assert not np.allclose(a.truth.td, c.truth.td)


def test_a_term_acts_through_its_control_offset():
    spec = get_platform("stewart")
    term = BacklashTerm("backlash", ["half_play"], np.zeros(1), ["m"], {"actuator": "L2"}, index=1)
    theta = np.array([2e-3])
    sim = simulate(spec, seed=6, n_poses=10, raw=False, noise_mm=0.0, occlusion=0.0, terms=[(term, theta)])
    off = np.zeros_like(sim.poses.controls)
    off[:, 1] = theta[0] * sim.poses.extras["direction"][:, 1]
    assert np.any(off != 0)
    np.testing.assert_allclose(sim.poses.markers, _true_markers(spec, sim.truth, sim.poses.controls, off), atol=1e-9)
    plain = _true_markers(spec, sim.truth, sim.poses.controls)
    assert np.max(np.abs(sim.poses.markers - plain)) > 1e-3


def test_a_custom_term_with_pose_and_marker_offsets():
    class Lift(ModelTerm):
        def pose_offset(self, theta, poses, fk_q, fk_X):
            out = np.zeros((poses.n_poses, 6))
            out[:, 2] = theta[0]
            return out

        def marker_offset(self, theta, poses):
            out = np.zeros((poses.n_poses, poses.n_markers, 3))
            out[:, 0, 0] = theta[1]
            return out

    spec = get_platform("psvr")
    term = Lift("unexplained", ["dz", "dx0"], np.zeros(2))
    sim = simulate(spec, seed=7, n_poses=8, noise_mm=0.05, terms=[(term, np.array([3e-3, 2e-3]))], mocap_rate_hz=40)
    plain = _true_markers(spec, sim.truth, sim.poses.controls)
    R = sim.truth.mocap_from_base[:3, :3]
    shift = sim.poses.markers - plain
    # every marker lifted 3 mm along base z; marker 1 also 2 mm along the moving x axis
    lifted = shift[:, 1:] @ R  # back to base axes
    np.testing.assert_allclose(lifted[..., 2], 3e-3, atol=0.1e-3)
    assert np.all(np.linalg.norm(shift[:, 0] @ R - np.array([0, 0, 3e-3]), axis=1) > 1.5e-3)


@pytest.mark.parametrize("name", EFFECTS)
def test_every_built_in_effect_changes_the_poses(name):
    spec = get_platform("stewart")
    # a random plan: a grid's commands can sit at one phase of a screw's period
    base = simulate(spec, seed=8, n_poses=16, raw=False, noise_mm=0.0, occlusion=0.0, plan="random")
    size = 100.0 if name == "thermal_drift" else None  # mm per hour: a 70 s session needs a fast one
    commands = _commands_poseset(spec, base.commands, base.command_t, base.truth.marker_names)
    term = simulation_term(name, spec, size, np.random.default_rng(0), commands)  # the plugin's own
    sim = simulate(spec, seed=8, n_poses=16, raw=False, noise_mm=0.0, occlusion=0.0, terms=[term], plan="random")
    assert len(sim.truth.terms) == 1 and sim.truth.terms[0][0].effect == name
    diff = np.max(np.abs(sim.poses.markers - base.poses.markers))
    assert diff > 0.05e-3, f"{name} moved the markers by only {diff * 1e3:.4f} mm"
    assert diff < 20e-3
    yaml.safe_dump(sim.truth.to_dict())  # the truth stays plain YAML


def test_the_additive_mode_takes_the_registered_effects_simulation_term_and_no_other(monkeypatch):
    from platkit.plugins import default_host

    class Wobble:
        name = "backlash"

        def simulation_term(self, spec, size, rng, commands):
            """the wobble's size"""
            return BacklashTerm("backlash", ["half_play"], np.zeros(1), ["m"], {"actuator": "L6"}, index=5), np.array([size])

    host = default_host()
    monkeypatch.setattr(host, "effects", lambda: {"backlash": Wobble()})
    spec = get_platform("stewart")
    base = simulate(spec, seed=1, n_poses=6, raw=False)
    commands = _commands_poseset(spec, base.commands, base.command_t, base.truth.marker_names)
    term, theta = simulation_term("backlash", spec, 7.0, np.random.default_rng(0), commands)
    assert term.where == {"actuator": "L6"} and theta[0] == 7.0
    # no second implementation: a name no plugin registers is unknown
    with pytest.raises(BadInput, match="unknown effect 'base_tilt'"):
        simulation_term("base_tilt", spec, 1.0, np.random.default_rng(0), commands)


def test_effect_option_parsing():
    assert parse_effect("backlash:1.5") == ("backlash", 1.5)
    assert parse_effect("thermal_drift") == ("thermal_drift", None)
    with pytest.raises(BadInput, match="must be a number"):
        parse_effect("backlash:wide")
    spec = get_platform("stewart")
    with pytest.raises(BadInput, match="unknown effect 'wobble'"):
        simulate(spec, n_poses=4, raw=False, effects=[("wobble", None)])


def test_simulate_session_writes_truth_and_reads_back(tmp_path):
    folder = simulate_session("rotary", tmp_path / "rot", seed=9, n_poses=8, mocap_rate_hz=30,
                              effects=[("backlash", 0.05)])
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    spec = get_platform("rotary")
    assert set(truth["parameters"]) == set(spec.parameter_names)
    assert truth["effects"][0]["effect"] == "backlash"
    T = np.array(truth["mocap_from_base"])
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    poses = load_poses(folder)
    assert poses.n_poses == 8 and poses.platform == "rotary"


def test_nothing_is_written_when_simulation_fails(tmp_path):
    plan = tmp_path / "plan.csv"
    plan.write_text("A,B,C\n2000,2000,2000\n9000,2000,2000\n")
    with pytest.raises(BadSession, match="row 2 .* column 'A'.*outside the stroke"):
        simulate_session("psvr", tmp_path / "out", plan=str(plan))
    assert not (tmp_path / "out").exists()


def test_cli_simulate_poses_only(tmp_path, capsys):
    out = tmp_path / "s"
    code = main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "7", "--poses-only",
                 "--effect", "backlash:3", "--seed", "2"])
    assert code == 0, capsys.readouterr().err
    assert (out / "poses.csv").is_file() and not (out / "markers.csv").exists()
    assert "hidden effect backlash" in capsys.readouterr().out
    assert load_poses(out).n_poses == 7
    code = main(["simulate", "--platform", "psvr", "--out", str(tmp_path / "t"), "--effect", "x:y"])
    assert code == 2 and not (tmp_path / "t").exists()


def test_imu_hook_writes_an_inertial_stream(tmp_path):
    from platkit.io.session import load_session
    from platkit.simulate import write_session

    seen = {}

    def imu(trajectory, rng):
        t = np.arange(0.0, trajectory.end_t, 0.005)
        q, X = trajectory.at(t)
        seen["q"], seen["X"] = q, X
        return {"t": t, "gyr": np.zeros((len(t), 3)), "acc": np.tile([0.0, 0.0, 9.81], (len(t), 1)),
                "entry": {"rate_hz": 200.0, "frame": "imu"}}

    spec = get_platform("psvr")
    sim = simulate(spec, seed=3, n_poses=5, mocap_rate_hz=30, imu=imu)
    assert seen["q"].shape[1] == 4 and np.allclose(np.linalg.norm(seen["q"], axis=1), 1)
    s = load_session(write_session(sim, tmp_path / "imu"))
    assert s.imu == {"rate_hz": 200.0, "frame": "imu"}
    assert s.imu_t.shape[0] == len(sim.imu["t"]) and np.allclose(s.imu_acc[:, 2], 9.81)


def test_serial_chain_link_options_travel_with_the_session(tmp_path):
    from platkit.io.session import load_session

    folder = simulate_session("urdf", tmp_path / "arm", moving_link="forearm_link", seed=1, n_poses=6,
                              mocap_rate_hz=30)
    s = load_session(folder)
    assert s.moving_link == "forearm_link" and s.spec.moving_frame == "forearm_link"
    assert s.spec.n_u == 3
    assert load_poses(folder).n_poses == 6


@pytest.mark.parametrize("poses_only", [False, True])
def test_base_markers_are_recorded_and_pin_the_transform(tmp_path, poses_only):
    spec = get_platform("psvr")
    folder = simulate_session(spec, tmp_path / "b", seed=4, n_poses=6, mocap_rate_hz=30, n_base_markers=3,
                              poses_only=poses_only)
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    B = np.array([truth["base_markers"][n] for n in ("B1", "B2", "B3")])
    T = np.array(truth["mocap_from_base"])
    poses = load_poses(folder)
    assert poses.base_markers.shape == (3, 3)
    np.testing.assert_allclose(poses.base_markers, B @ T[:3, :3].T + T[:3, 3], atol=0.05e-3)
    # without base markers the rest of the simulation is unchanged
    a = simulate(spec, seed=4, n_poses=6, raw=False)
    b = simulate(spec, seed=4, n_poses=6, raw=False, n_base_markers=2)
    np.testing.assert_array_equal(a.poses.markers, b.poses.markers)


def test_cli_simulate_with_an_imu(tmp_path, capsys):
    from platkit.io.session import load_session

    out = tmp_path / "imu"
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "4", "--rate-hz", "30",
                 "--imu-rate-hz", "100"]) == 0, capsys.readouterr().err
    s = load_session(out)
    assert s.imu["rate_hz"] == 100.0 and s.imu_gyr.shape[1] == 3
    assert (out / "truth_orientation.csv").is_file()
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert "imu" in truth
    # at rest before the first command the accelerometer reads gravity
    rest = s.imu_t < 0.4
    assert abs(np.linalg.norm(s.imu_acc[rest].mean(axis=0)) - 9.81) < 0.05
