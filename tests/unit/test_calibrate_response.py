"""Per-actuator delays and rate limits (platkit.calibrate.response, platkit.simulate.actuator):
the fitted model against the simulator's own drive, the shift/delay gauge, the simulator's
seeded outputs unchanged without the new options, and a short streamed session whose legs' lags
and rate limits are fitted (physical simulator, fixed seed)."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_start import command_speed
from platkit.calibrate.response import ResponseModel, actuator_positions, lags, slew_reference
from platkit.io.calibration import read_calibration, write_calibration_yaml
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.actuator import ActuatorResponse, actuator_motion
from platkit.simulate.physics import simulate_physics, write_physical_session


def _log(n=120, n_u=2, seed=0):
    rng = np.random.default_rng(seed)
    T = 0.5 + np.arange(n) * 0.05
    return T, np.cumsum(rng.normal(size=(n, n_u)) * 0.002, axis=0)


def test_delayed_slewed_response_matches_the_simulator_drive():
    """Each actuator's own delay and a slewed step reference follow the simulator's drive (an
    independent integration) to a few micrometres over tens of millimetres of travel; the
    limited actuator lags its free twin."""
    T, U = _log()
    t = np.linspace(0.6, 6.5, 1500)
    model = ResponseModel("second_order", "step", 2, delays=True, rate_limit=True)
    assert model.blocks == ["tau_s", "damping", "rate", "delay_s"]
    theta = np.array([0.01, 0.08, 0.05, 1.0, 0.9, 0.02, 0.5, 0.03, 0.07])
    x = actuator_positions(model, theta, T, U, t)
    drive = ActuatorResponse(np.array([0.08, 0.05]), np.array([1.0, 0.9]), np.full(2, 1e6), np.full(2, 1e12),
                             streamed=True, delay_s=np.array([0.03, 0.07]), rate_limit=np.array([0.02, 0.5]))
    sim = actuator_motion(t - 0.01, T, U, U[0], drive, fine_step_s=1e-4)
    assert np.abs(x - sim).max() < 1e-5
    free = actuator_positions(ResponseModel("second_order", "step", 2, delays=True), np.delete(theta, [5, 6]), T, U, t)
    # the limit of 20 mm/s binds on this log (steps up to 6 mm in 50 ms); 0.5 m/s only ramps each step
    assert np.abs(x[:, 0] - free[:, 0]).max() > 5 * np.abs(x[:, 1] - free[:, 1]).max()


def test_slew_reference_reaches_and_is_cut():
    T = np.array([0.0, 1.0, 1.2])
    u = np.array([0.0, 1.0, 0.0])
    r = slew_reference(np.array([-1.0, 0.5, 1.1, 1.2, 1.3, 2.0]), T, u, rate=2.0)
    # on the first command before it; towards 1 at 2 per s from t = 1, cut at 1.2 at 0.4, then
    # back towards 0 from there
    assert np.allclose(r, [0.0, 0.0, 0.2, 0.4, 0.2, 0.0])


def test_shift_and_delays_are_one_gauge():
    """Only shift + delay_j reach the actuators: a constant moved from the delays to the shift
    changes nothing (the direction calibrate's identifiability holds)."""
    T, U = _log(n_u=3, seed=1)
    t = np.linspace(0.6, 6.5, 400)
    model = ResponseModel("first_order", "step", 3, delays=True)
    a = np.array([0.02, 0.05, 0.06, 0.07, 0.01, 0.03, 0.09])
    b = a + np.array([0.025, 0, 0, 0, -0.025, -0.025, -0.025])
    assert np.allclose(lags(model, a), lags(model, b))
    assert np.array_equal(actuator_positions(model, a, T, U, t), actuator_positions(model, b, T, U, t))


def test_simulator_without_the_options_is_unchanged():
    """Zero delays give the drive's output of no delays, and a profile's rate limit above its
    rate changes nothing (to rounding); a streamed drive's limit never reached moves it by under
    the fine grid's sample of each step (the step takes effect at the grid point after it)."""
    T, U = _log(n_u=2, seed=2)
    t = np.linspace(0.0, 7.0, 700)
    base = ActuatorResponse(np.array([0.06, 0.04]), np.array([1.0, 1.2]), np.array([0.3, 0.3]), np.array([3.0, 3.0]))
    for streamed in (True, False):
        base.streamed = streamed
        ref = actuator_motion(t, T, U, U[0], base)
        zero = ActuatorResponse(base.tau_s, base.damping, base.rate, base.accel, streamed, np.zeros(2))
        assert np.allclose(actuator_motion(t, T, U, U[0], zero), ref, rtol=0, atol=1e-12)
        fast = ActuatorResponse(base.tau_s, base.damping, base.rate, base.accel, streamed, None, np.full(2, 1e3))
        assert np.allclose(actuator_motion(t, T, U, U[0], fast), ref, rtol=0, atol=1e-12 if not streamed else 1e-4)


@pytest.fixture(scope="module")
def delayed(tmp_path_factory):
    spec = get_platform("stewart")
    seed, duration = 4111, 20.0
    free = simulate_physics(spec, seed=seed, motion="multisine", duration_s=duration, mocap_rate_hz=50.0)
    rate = np.full(spec.n_u, 1e3)
    rate[[1, 4]] = 0.8 * command_speed(free.command_t, free.commands)[[1, 4]]
    delay = np.array([0.02, 0.04, 0.06, 0.08, 0.10, 0.12])
    sim = simulate_physics(spec, seed=seed, motion="multisine", duration_s=duration, mocap_rate_hz=50.0,
                           actuator_delay_s=delay, actuator_rate_limit=rate)
    folder = tmp_path_factory.mktemp("response") / "session"
    write_physical_session(sim, folder)
    return sim, load_session(folder), delay, rate


def test_delays_and_rate_limits_fitted(delayed, tmp_path):
    sim, session, delay, rate = delayed
    cal, _ = calibrate_motion(session, session.spec, delays=True, rate_limit=True)
    # calibration.yaml keeps the new keys, and a file of the old layout (without them) reads
    (tmp_path / "new").mkdir()
    back = read_calibration(write_calibration_yaml(cal, tmp_path / "new"))
    assert back.motion["response"]["actuators"]["L2"]["lag_s"]["value"] == pytest.approx(
        cal.motion["response"]["actuators"]["L2"]["lag_s"]["value"])
    text = (tmp_path / "new" / "calibration.yaml").read_text()
    data = yaml.safe_load(text)
    response = data["actuator_response"]["response"]
    for key in ("delays", "rate_limit"):
        response.pop(key)
    for entry in response["actuators"].values():
        for key in ("delay_s", "lag_s", "rate"):
            entry.pop(key)
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "calibration.yaml").write_text(yaml.safe_dump(data))
    assert read_calibration(tmp_path / "old" / "calibration.yaml").motion["response"]["kind"] == "second_order"
    r = cal.motion["response"]
    assert r["delays"] and r["rate_limit"]
    names = list(session.spec.control_names)
    lag = np.array([r["actuators"][n]["lag_s"]["value"] for n in names])
    true_lag = sim.nuisances.time_shift_s + delay
    assert np.abs(lag - true_lag).max() < 0.015, (lag, true_lag)
    for j in (1, 4):  # the limited legs' rates, and the share of the log's steps the limit cut
        assert abs(r["actuators"][names[j]]["rate"]["value"] / rate[j] - 1) < 0.03
        assert r["actuators"][names[j]]["rate"]["binds_share"] > 0
    for j in (0, 2, 3, 5):  # the free legs' limits are not seen, and said so
        assert r["actuators"][names[j]]["rate"]["status"] == "does_not_bind"
    # exactly one of the shift and the six delays is held: the gauge, said
    gauge = [h for h in cal.motion["held"] if h.endswith("shift_s") or ".delay_s." in h]
    assert len(gauge) == 1, cal.motion["held"]
    pred, _, _, _ = predict_markers(cal, sim.commands)
    truth = np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2)))
    assert truth < 0.05e-3, truth


def test_cli_response_parts(tmp_path, capsys):
    """platkit calibrate --response delays,rate-limit fits both on a session without holds; an
    unknown part is one line of bad input before any work."""
    from platkit.cli import main

    folder, out = tmp_path / "session", tmp_path / "cal"
    assert main(["calibrate", str(folder), "--response", "delay", "--out", str(out)]) != 0
    assert "--response delay: use delays and/or rate-limit" in capsys.readouterr().err
    assert not out.exists()
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "12",
                 "--rate-hz", "40", "--seed", "4112", "--out", str(folder)]) == 0
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--response", "delays,rate-limit",
                 "--out", str(out)]) == 0
    r = read_calibration(out / "calibration.yaml").motion["response"]
    assert r["delays"] and r["rate_limit"]
    assert all({"delay_s", "lag_s", "rate"} <= set(a) for a in r["actuators"].values())


def test_profile_with_delays_matches_the_simulator_drive():
    """A profile reference (holds) with each actuator's own delay follows the simulator's drive,
    whose rate limit below the profile's rate takes over."""
    Th, Uh = np.array([0.5, 3.5, 6.0, 9.0]), np.array([[0.0, 0.0], [0.1, -0.08], [-0.05, 0.02], [0.02, 0.0]])
    t = np.linspace(0.6, 12, 2000)
    model = ResponseModel("second_order", "profile", 2, delays=True)
    assert model.blocks == ["tau_s", "damping", "rate", "accel", "delay_s"]
    theta = np.array([0.004, 0.3, 0.1, 1.1, 1.0, 0.08, 0.05, 0.3, 0.6, 0.02, 0.11])
    x = actuator_positions(model, theta, Th, Uh, t)
    drive = ActuatorResponse(np.array([0.3, 0.1]), np.array([1.1, 1.0]), np.array([0.08, 0.2]), np.array([0.3, 0.6]),
                             delay_s=np.array([0.02, 0.11]), rate_limit=np.array([1.0, 0.05]))
    sim = actuator_motion(t - 0.004, Th, Uh, np.zeros(2), drive, fine_step_s=1e-4)
    assert np.abs(x - sim).max() < 1e-5
