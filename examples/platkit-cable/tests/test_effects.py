"""The cable robot's outside physics as effects (platkit_cable.effects): both pass platkit's
effect checks; planted by the simulator, each is named by diagnosis with its size, and the
held-out error falls; a clean session gets no finding."""
import numpy as np
import pytest
from platkit_cable.effects import EFFECTS, pulley_excess, tensions

from platkit import get_platform
from platkit.diagnose import Options, diagnose
from platkit.plugins import effect_library
from platkit.simulate import simulate
from platkit.testing import check_effect


@pytest.fixture(scope="module")
def spec():
    return get_platform("cable")


def test_both_effects_are_installed_and_pass_the_effect_checks(spec):
    library = effect_library()
    for effect in EFFECTS:
        assert library[effect.name] is effect
        report = check_effect(effect, spec)
        assert report["simulated"] and report["terms"] == 2


def test_the_tensions_hold_the_weight_and_the_pulley_wrap_vanishes_with_its_radius(spec):
    u = spec.neutral_u()[None]
    t = tensions(spec, u)[0]
    # symmetric platform at the centre: the upper cables share the weight above the pretension
    assert np.all(t > 0) and t[:4] == pytest.approx([t[0]] * 4) and t[4:] == pytest.approx([t[4]] * 4)
    assert t[0] > 1.0 > t[4]
    assert np.all(pulley_excess(spec, u, 0.0) == 0)
    small, larger = pulley_excess(spec, u, 1e-4)[0], pulley_excess(spec, u, 2e-4)[0]
    # first order in r: r times the wrap angle less the shortening of the straight part
    assert np.allclose(larger, 2 * small, rtol=1e-3) and np.all(small > 0)


#: small sessions (a test's time): 30 poses of platkit's own plan, at most one effect named
N_POSES = 30
ONE = Options(max_effects=1)


@pytest.mark.parametrize("effect, size, true_theta", [("pulley_radius", 20.0, 0.02), ("cable_elasticity", 2.0, None)])
def test_a_planted_effect_is_named_and_the_held_out_error_falls(spec, effect, size, true_theta):
    sim = simulate(spec, seed=5, n_poses=N_POSES, raw=False, effects=[(effect, size)])
    (term, theta), = sim.truth.terms
    d = diagnose(spec, sim.poses, ONE)
    assert [f.effect for f in d.findings] == [effect], d.verdict
    f = d.findings[0]
    fitted = f.parameters[term.parameter_names[0]]
    scale = 1e-3 if fitted["unit"] == "mm" else 1.0  # diagnosis shows lengths in mm
    assert abs(fitted["value"] * scale - theta[0]) < 4 * fitted["std"] * scale + 0.02 * abs(theta[0])
    if true_theta is not None:
        assert theta[0] == pytest.approx(true_theta)
    assert f.heldout_rms_after < 0.5 * f.heldout_rms_before


def test_a_clean_session_gets_no_finding(spec):
    d = diagnose(spec, simulate(spec, seed=5, n_poses=N_POSES, raw=False).poses, ONE)
    assert d.findings == [], d.verdict
