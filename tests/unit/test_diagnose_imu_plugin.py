"""An IMU effect from outside platkit: a tiny plugin registers it on a host through the effects
hook, the IMU simulator plays it through its sensor model, and the IMU diagnosis names it with
its parameters, with no line of platkit knowing its name."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.diagnose.imu import diagnose_imu, td_covariance
from platkit.effects import ImuEffect
from platkit.errors import BadInput
from platkit.hookspecs import hookimpl
from platkit.inertial.simulate import imu_for_trajectory, imu_from_motion
from platkit.io.imu import ImuStream
from platkit.plugins import PluginHost, get_platform
from platkit.simulate import simulate

DEG = 180.0 / np.pi
BIAS = [0.003, -0.002, 0.001, 0.05, -0.03, 0.08]
PERIOD_S = 40.0
#: the true cycle of the z bias: 0.034 deg/s, about 6 times the noise of a segment's mean rate
CYCLE = np.array([4e-4, -4e-4])


class GyroBiasCycle(ImuEffect):
    """The gyro's z bias cycles with a heater's 40 s period (sin and cos parts, rad/s)."""

    name = "gyro_bias_cycle"
    summary = "the gyro's z bias cycles with the heater"
    sensor = "gyro"
    parameter_names = ("sin_z", "cos_z")
    display_unit = "deg/s"
    display_scale = DEG

    def gyro_bias(self, theta, t):
        w = 2 * np.pi / PERIOD_S * np.asarray(t, float)
        out = np.zeros((len(w), 3))
        out[:, 2] = theta[0] * np.sin(w) + theta[1] * np.cos(w)
        return out


class HeaterPlugin:
    @hookimpl
    def platkit_register_effects(self):
        return [GyroBiasCycle()]


@pytest.fixture(scope="module")
def host():
    h = PluginHost(entry_points=False)
    h.register(HeaterPlugin(), name="heater")
    return h


def test_the_outside_effect_is_in_the_library_beside_the_built_in_ones(host):
    lib = host.effects()
    assert isinstance(lib["gyro_bias_cycle"], ImuEffect)
    assert {"gyro_bias_drift", "imu_misalignment", "imu_base_tilt", "backlash"} <= set(lib)
    # no motion-capture term: pose diagnosis never proposes it
    assert lib["gyro_bias_cycle"].candidates(None, None) == []


def test_the_simulator_plays_it_through_its_sensor_model(host):
    effect = host.effects()["gyro_bias_cycle"]
    t = np.arange(0.0, 20.0, 0.01)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), effects=[(effect, CYCLE)])
    expected = CYCLE[0] * np.sin(2 * np.pi * t / PERIOD_S) + CYCLE[1] * np.cos(2 * np.pi * t / PERIOD_S)
    np.testing.assert_allclose(sim["gyr"][:, 2], expected, atol=1e-12)
    np.testing.assert_allclose(sim["gyr"][:, :2], 0.0, atol=1e-12)
    with pytest.raises(BadInput, match="gyro_bias_cycle.*expected 2 finite parameters"):
        imu_from_motion(t, q, np.zeros((len(t), 3)), effects=[(effect, [1.0])])


def test_diagnosis_names_the_outside_effect(host):
    lib = host.effects()
    spec = get_platform("stewart")
    sim = simulate(spec, seed=2, n_poses=60, plan="random",
                   imu=imu_for_trajectory(bias=BIAS, effects=[(lib["gyro_bias_cycle"], CYCLE)]))
    assert sim.imu["truth_imu"]["effects"] == {"gyro_bias_cycle": CYCLE.tolist()}
    cal = calibrate(sim.poses, spec)
    im = sim.imu
    d = diagnose_imu(spec, cal.td, sim.command_t, sim.commands, ImuStream(im["t"], im["gyr"], im["acc"]),
                     td_cov=td_covariance(cal), td_status=cal.td_status, library=lib)
    names = [f["effect"] for f in d.findings]
    assert "gyro_bias_cycle" in names and "imu_misalignment" not in names and "base_tilt" not in names
    f = d.findings[names.index("gyro_bias_cycle")]
    # the diagnosis takes time from the middle of the session: the cycle's phase moves with it
    w = 2 * np.pi / PERIOD_S * (d.segments.t_c - sim.imu["t"][0])
    c, s = np.cos(w), np.sin(w)
    truth = np.array([CYCLE[0] * c - CYCLE[1] * s, CYCLE[0] * s + CYCLE[1] * c]) * DEG
    for name, v in zip(("sin_z", "cos_z"), truth):
        p = f["parameters"][name]
        assert p["unit"] == "deg/s" and abs(p["value"] - v) < 3 * p["std"] + 1e-3, (name, p, v)
    assert f["heldout_rms_after"] < 0.8 * f["heldout_rms_before"] and "gyro_bias_cycle" in d.verdict
    # calibration.yaml's imu mapping gets the effect's default entry
    assert d.calibration_entry()["gyro_bias_cycle"]["effect"] == "gyro_bias_cycle"


def test_every_imu_effect_passes_the_conformance_checks(host):
    """platkit.testing.check_imu_effect: the built-in IMU effects and the outside one; a broken
    effect is named with what is wrong."""
    from platkit.testing import check_imu_effect

    lib = host.effects()
    names = [check_imu_effect(e)["effect"] for e in lib.values() if isinstance(e, ImuEffect)]
    assert sorted(names) == ["gyro_bias_cycle", "gyro_bias_drift", "imu_base_tilt", "imu_misalignment"]

    class AlwaysOn(GyroBiasCycle):
        name = "always_on"

        def gyro_bias(self, theta, t):
            return super().gyro_bias(theta, t) + 1e-3  # an offset even at theta = 0

    with pytest.raises(AssertionError, match="always_on: gyro_bias at theta = 0 is not 'no effect'"):
        check_imu_effect(AlwaysOn())
