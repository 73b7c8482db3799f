"""Forward selection on simulated stewart sessions: nothing on clean data, the slipped marker
named with its place and time, structure outside the library reported as unexplained."""
from dataclasses import dataclass

import numpy as np
import pytest

from platkit.diagnose import Options, diagnose
from platkit.plugins import get_platform
from platkit.simulate import simulate
from platkit.terms import ModelTerm


@pytest.fixture(scope="module")
def spec():
    return get_platform("stewart")


def _session(spec, seed, terms=(), effects=()):
    plan = simulate(spec, seed=seed + 1, n_poses=45, raw=False, plan="random", noise_mm=0.0, occlusion=0.0).commands
    return simulate(spec, seed=seed, n_poses=45, raw=False, plan=plan, terms=list(terms), effects=list(effects))


def test_clean_session_gives_no_finding(spec):
    d = diagnose(spec, _session(spec, 11).poses)
    assert d.findings == []
    assert "shows no hidden effect" in d.verdict
    assert d.calibration.terms == []


def test_marker_slip_is_named_with_its_marker_and_time(spec):
    sim = _session(spec, 12, effects=[("marker_slip", 0.5)])
    term, theta = sim.truth.terms[0]
    d = diagnose(spec, sim.poses, Options(max_effects=2))
    assert [f.effect for f in d.findings] == ["marker_slip"]
    assert not any(r.get("at_cap") for r in d.rounds) and "stopped at the cap" not in d.verdict  # the tests ended the search
    f = d.findings[0]
    assert f.where["marker"] == term.where["marker"]
    t = sim.poses.extras["elapsed"]
    step = np.median(np.diff(t))
    assert abs(f.where["from_time_s"] - term.t_slip) < 1.5 * step
    est = np.array([f.parameters[n]["value"] for n in ("dx", "dy", "dz")])
    std = np.array([f.parameters[n]["std"] for n in ("dx", "dy", "dz")])
    assert np.all(np.abs(est - theta) < 4 * std + 2e-5)
    assert f.heldout_rms_after < 0.5 * f.heldout_rms_before


@dataclass
class _Wave(ModelTerm):
    """Not in any library: the moving frame oscillates along x with time."""

    period_s: float = 60.0

    def pose_offset(self, theta, poses, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        out[:, 0] = theta[0] * np.sin(2 * np.pi * np.asarray(poses.extras["elapsed"]) / self.period_s)
        return out


def test_structure_outside_the_library_is_unexplained_not_misnamed(spec):
    plan = _session(spec, 13).commands
    t_end = float(simulate(spec, seed=13, n_poses=45, raw=False, plan=plan).poses.extras["elapsed"][-1])
    wave = _Wave("wave", ["amplitude"], np.zeros(1), ["m"], {}, period_s=t_end / 2.5)
    d = diagnose(spec, _session(spec, 13, terms=[(wave, np.array([3e-4]))]).poses)
    names = [f.effect for f in d.findings]
    assert names and set(names) == {"unexplained"}
    assert "time" in d.findings[0].where
    assert "unexplained" in d.verdict
