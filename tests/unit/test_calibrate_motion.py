"""Calibration from motion (platkit.calibrate.motion): the actuators' response, sessions without
holds, and the bad input it refuses. Small sessions of the physical simulator (fixed seeds)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.stream import check_motion_session
from platkit.errors import BadSession
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.actuator import ActuatorResponse, actuator_motion
from platkit.simulate.physics import simulate_physics, write_physical_session


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=4101, motion="multisine", duration_s=24.0, mocap_rate_hz=50.0)
    folder = tmp_path_factory.mktemp("motion") / "session"
    write_physical_session(sim, folder)
    return sim, load_session(folder)


def test_response_matches_the_simulator_drive():
    """The exact step response and the profile's fine-grid response follow the simulator's own
    drive (an independent integration) to well below a micrometre per mm of travel."""
    rng = np.random.default_rng(0)
    T = 0.5 + np.arange(120) * 0.05
    U = np.cumsum(rng.normal(size=(120, 1)) * 0.002, axis=0)
    t = np.linspace(0.6, 6.5, 1500)
    step = actuator_positions(ResponseModel("second_order", "step", 1), np.array([0.0, 0.08, 1.0]), T, U, t)[:, 0]
    sim = actuator_motion(t, T, U, U[0], ActuatorResponse(np.array([0.08]), np.array([1.0]), np.array([1e6]),
                                                          np.array([1e12])), fine_step_s=1e-5)[:, 0]
    assert np.abs(step - sim).max() < 2e-6
    Th, Uh = np.array([0.5, 3.5, 6.0, 9.0]), np.array([[0.0], [0.1], [-0.05], [0.02]])
    t = np.linspace(0.6, 12, 2000)
    prof = actuator_positions(ResponseModel("second_order", "profile", 1), np.array([0.0, 0.3, 1.1, 0.08, 0.3]),
                              Th, Uh, t)[:, 0]
    sim = actuator_motion(t, Th, Uh, np.array([0.0]), ActuatorResponse(np.array([0.3]), np.array([1.1]),
                                                                        np.array([0.08]), np.array([0.3])),
                          fine_step_s=1e-4)[:, 0]
    assert np.abs(prof - sim).max() < 1e-5


def test_no_hold_session_calibrated(streamed):
    sim, session = streamed
    cal, poses = calibrate_motion(session, session.spec)
    samples = cal.motion["samples"]
    assert samples["n_fitted"] == poses.n_poses
    # every sample from the second command on serves, or is counted as not seen or left out
    after = int(np.sum(session.marker_t >= session.command_t[1]))
    assert samples["n_used"] + samples["n_unseen"] >= after - 3 * 2 * 3
    pred, _, _, _ = predict_markers(cal, sim.commands)
    truth = np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2)))
    rms_before = cal.rms_before
    assert truth < 0.05e-3 < rms_before  # the settled poses of every command, against the truth
    r = cal.motion["response"]
    assert r["reference"] == "step"
    assert abs(r["shift_s"]["value"] - sim.nuisances.time_shift_s) < 3e-3
    taus = np.array([r["actuators"][c]["tau_s"]["value"] for c in session.spec.control_names])
    assert np.all(np.abs(taus / sim.response.tau_s - 1) < 0.1)
    assert cal.terms == [] and "actuator_response" in cal.to_dict()


def test_clocks_that_do_not_overlap_are_refused(streamed):
    _, session = streamed
    late = dataclasses.replace(session, marker_t=session.marker_t + 1000.0)
    with pytest.raises(BadSession, match="commands.csv.*do not overlap"):
        check_motion_session(late)


def test_a_command_log_sparser_than_the_motion_is_refused(streamed):
    """Six seconds of commands missing from a streamed log while the stand moved: refused in one
    line naming commands.csv, before any fit."""
    _, session = streamed
    keep = (session.command_t < 8.0) | (session.command_t > 14.0)
    sparse = dataclasses.replace(session, command_t=session.command_t[keep], commands=session.commands[keep])
    with pytest.raises(BadSession, match=r"commands.csv: no command from t=7\.9.* the log is sparser than the motion"):
        check_motion_session(sparse)


def test_cli_simulates_a_session_without_holds_and_calibrates_it(tmp_path, capsys):
    """platkit simulate --physics --motion writes a streamed session; platkit calibrate, whose
    settling finds no holds, calibrates it from motion and keeps the response."""
    from platkit.cli import main
    from platkit.io.calibration import read_calibration

    folder, out = tmp_path / "session", tmp_path / "cal"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "20",
                 "--rate-hz", "40", "--seed", "4102", "--out", str(folder)]) == 0
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--out", str(out)]) == 0
    line = capsys.readouterr()
    assert "from motion" in line.out and "calibrated from the whole stream" in line.err
    cal = read_calibration(out / "calibration.yaml")
    assert cal.motion["response"]["reference"] == "step"
    assert set(cal.motion["response"]["actuators"]) == set(cal.spec.control_names)


def test_slow_actuator_calibrated_with_its_time_constant(tmp_path):
    """One actuator's time constant half the hold (settling_lag physics): settling refuses the
    session; the motion model calibrates it and recovers that time constant within 10%."""
    from platkit.settle import HoldsNeverSettle, NeverSettles, load_poses

    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=4103, n_poses=12, plan="random", effects=[("settling_lag", 0.5)],
                           mocap_rate_hz=50.0)
    write_physical_session(sim, tmp_path / "slow")
    session = load_session(tmp_path / "slow")
    with pytest.raises((HoldsNeverSettle, NeverSettles)):
        load_poses(session.folder, spec=session.spec, session=session)
    cal, _ = calibrate_motion(session, session.spec, raw_samples=600)  # the rest of the 58 s as windows
    assert 0 < cal.motion["samples"]["n_kept_raw"] <= 700 < cal.motion["samples"]["n_used"]
    j = int(np.argmax(sim.response.tau_s))
    tau = cal.motion["response"]["actuators"][spec.control_names[j]]["tau_s"]["value"]
    assert cal.motion["response"]["reference"] == "profile"
    assert abs(tau / sim.response.tau_s[j] - 1) < 0.1
    assert cal.rms_after < 0.5 * cal.rms_before
    pred, _, _, _ = predict_markers(cal, sim.commands)  # 12 poses fix the geometry to a few tenths of a mm
    assert np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2))) < 0.5e-3


def test_windows_keep_every_sample_and_the_geometry_exactly(streamed, tmp_path):
    """The stream reduced to windows: each window's nodes stand for its samples (their weights sum
    to the window's samples), and a noise-free stream fitted from the windows alone (none kept
    raw) gives the true settled poses to the files' micrometre (the curvature correction: without
    it a window's quadratic fit of the markers is not the stand at the fit of the controls)."""
    from platkit.calibrate.stream import stream_windows

    _, session = streamed
    win = stream_windows(session, raw_samples=0)
    assert win.n_raw == 0 and len(win.t) == 3 * win.n_windows
    p, a, n, per = win.blocks[1]
    full = [m for m, (k, _) in per.items() if k is None]
    assert full and np.allclose(win.n_eff[p:p + 3, full].sum(axis=0), n, rtol=2e-3)
    assert np.allclose(np.asarray(win.proj.sum(axis=1)).ravel(), 1.0)  # a constant is fitted as itself
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=4104, motion="multisine", duration_s=30.0, mocap_rate_hz=50.0, noise_mm=0.0,
                           coloured=False, occlusion=0.0)
    write_physical_session(sim, tmp_path / "clean")
    clean = load_session(tmp_path / "clean")
    cal, poses = calibrate_motion(clean, clean.spec, raw_samples=0)
    assert cal.motion["samples"]["n_kept_raw"] == 0 and poses.n_poses == 3 * cal.motion["samples"]["n_windows"]
    pred, _, _, _ = predict_markers(cal, sim.commands)
    assert np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2))) < 1e-6
