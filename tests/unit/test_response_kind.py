"""The actuators' response chosen from the data in a calibration from motion
(platkit.calibrate.motion_kind): a response per actuator, the choice by determinacy and BIC, a
degenerate response said, and the report read back. Small streams of the physical simulator
(stewart, fixed seeds)."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.motion import calibrate_motion, motion_stream
from platkit.calibrate.motion_kind import not_determined, response_from_report
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate import nuisance
from platkit.simulate.physics import simulate_physics, write_physical_session


def _stream(tmp_path, seed: int, **kw):
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=seed, motion="multisine", duration_s=16.0, mocap_rate_hz=50.0, **kw)
    write_physical_session(sim, tmp_path / "s")
    return sim, load_session(tmp_path / "s")


def test_a_response_per_actuator():
    """Within a second-order response, the actuators named first order have no damping and follow
    the first-order response exactly; the vector's layout follows."""
    model = ResponseModel("second_order", "step", 3, delays=True, first=(1,))
    assert model.kinds == ["second_order", "first_order", "second_order"]
    assert model.names(["a", "b", "c"]) == ["shift_s", "tau_s.a", "tau_s.b", "tau_s.c", "damping.a", "damping.c",
                                            "delay_s.a", "delay_s.b", "delay_s.c"]
    assert not model.has("damping", 1) and model.index("delay_s", 1) == 7 and model.actuator_of(5) == 2
    rng = np.random.default_rng(1)
    T = np.arange(200) * 0.05
    U = np.cumsum(rng.normal(size=(200, 3)) * 0.01, axis=0)
    t = np.linspace(0.1, 9.5, 300)
    theta = np.array([0.01, 0.05, 0.07, 0.04, 0.8, 1.2, 0.0, 0.002, 0.0])
    x = actuator_positions(model, theta, T, U, t)
    one = actuator_positions(ResponseModel("first_order", "step", 3, delays=True),
                             np.array([0.01, 0.05, 0.07, 0.04, 0.0, 0.002, 0.0]), T, U, t)
    assert np.allclose(x[:, 1], one[:, 1], atol=1e-15)
    assert np.abs(x[:, 0] - one[:, 0]).max() > 1e-4  # the others are second order
    assert np.isnan(model.split(theta)["damping"][1])


def test_underdamped_drives_keep_the_second_order(tmp_path):
    """Drives that overshoot (damping 0.55-0.8): the second order is determined for every
    actuator and better by BIC: kept, near the truth; read back from the report."""
    sim, session = _stream(tmp_path, 4111, overshoot=True)
    cal, _ = calibrate_motion(session, session.spec)
    r = cal.motion["response"]
    assert r["kind"] == "second_order" and r["choice"]["asked"] == "auto"
    assert r["choice"]["bic"]["second_order"] < r["choice"]["bic"]["first_order"]
    zeta = np.array([r["actuators"][c]["damping"]["value"] for c in session.spec.control_names])
    assert np.all(np.abs(zeta / sim.response.damping - 1) < 0.15)
    assert not r["not_determined"]
    rmodel, theta = response_from_report(r, session.spec, "here")
    assert rmodel.kinds == ["second_order"] * 6 and theta[0] == r["shift_s"]["value"]


def test_a_lag_alone_keeps_the_first_order(tmp_path, monkeypatch):
    """Drives far overdamped (damping 8-9, time constant 5-6 ms: a lag of about 90 ms, the fast
    pole under a millisecond, unseen at 50 Hz): the second order's time constant and damping are
    not determined apart, the first order is kept, and said; named, the second order is fitted."""
    monkeypatch.setitem(nuisance.RANGES, "damping", (8.0, 9.0))
    monkeypatch.setitem(nuisance.RANGES, "tau_s", (0.005, 0.006))
    sim, session = _stream(tmp_path, 4112)
    cal, _ = calibrate_motion(session, session.spec)
    r = cal.motion["response"]
    assert r["kind"] == "first_order", r["choice"]
    assert r["choice"]["why"].startswith("first order")
    lag = 2 * sim.response.damping * sim.response.tau_s
    taus = np.array([r["actuators"][c]["tau_s"]["value"] for c in session.spec.control_names])
    assert np.all(np.abs(taus / lag - 1) < 0.15)
    assert all(e["kind"] == "first_order" and "damping" not in e for e in r["actuators"].values())
    poses, term = motion_stream(session, cal)  # read back through the report
    assert term.model.kinds == ["first_order"] * 6 and poses.n_poses > 20
    named, _ = calibrate_motion(session, session.spec, kind="second_order")
    assert named.motion["response"]["kind"] == "second_order"
    assert named.motion["response"]["choice"] == {"asked": "second_order", "rule": "named by the caller"}


def test_a_degenerate_response_is_said(tmp_path):
    """A time constant at the response's floor and a damping far past any drive's are not
    determined: each said with its reason; parameters held at their start are not judged."""
    from platkit.io.calibration import Calibration

    spec = get_platform("stewart")
    model = ResponseModel("second_order", "step", spec.n_u)
    theta = np.concatenate([[0.0], [0.001, 0.05, 0.05, 0.05, 0.05, 0.05], [1.0, 69.0, 1.0, 1.0, 1.0, 1.0]])
    cal = Calibration(platform="stewart", description=None, spec=spec, td=spec.nominal_td(),
                      td_std=np.zeros(spec.n_td), td_nominal=spec.nominal_td(), td_status=[],
                      mocap_rotvec=np.zeros(3), mocap_translation=np.zeros(3), mocap_std=np.zeros(6), marker_names=[],
                      marker_positions=np.zeros((0, 3)), marker_std=np.zeros((0, 3)), rms_before=1.0, rms_after=1.0,
                      length_unit="mm", theta=[theta], theta_std=[np.full(len(theta), 0.01)],
                      identifiability={"held_at_nominal": [{"name": "term.actuator_response.damping.L3"}]})
    bad = not_determined(model, spec, cal, sample_dt=0.01)
    names = spec.control_names
    assert set(bad) == {names[0], names[1]}
    assert "time constant 1 ms" in bad[names[0]] and "damping 69" in bad[names[1]]
    theta[1 + 6 + 2] = 50.0  # held at its start: not judged
    assert names[2] not in not_determined(model, spec, cal, sample_dt=0.01)


def test_an_unknown_kind_is_refused(tmp_path):
    from platkit.errors import BadInput

    with pytest.raises(BadInput, match="kind must be auto or one of first_order, second_order, not 'third'"):
        calibrate_motion(None, get_platform("stewart"), kind="third")  # type: ignore[arg-type]
