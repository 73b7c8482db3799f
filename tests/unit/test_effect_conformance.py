"""platkit.testing.check_effect on every built-in effect (a host of the built-ins alone), and on
broken effects, each caught by the check that names what is wrong."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.effects import Effect, SizeHelp
from platkit.plugins import PluginHost, get_platform
from platkit.terms import ModelTerm
from platkit.testing import check_effect


@pytest.fixture(scope="module")
def builtins():
    return PluginHost(entry_points=False).effects()


@pytest.mark.parametrize("stand", ["stewart", "psvr"])
def test_every_built_in_effect_conforms(builtins, stand):
    spec = get_platform(stand)
    reports = {name: check_effect(effect, spec) for name, effect in builtins.items()}
    assert set(reports) == set(builtins)
    motion = [r for r in reports.values() if "terms" in r]
    # every motion-capture effect was checked on at least one term, but a URDF tree's own (no term on a parallel stand)
    assert {r["effect"] for r in motion if r["terms"] == 0} <= {"link_bending"}
    assert {r["effect"] for r in motion if r["recording"]} == {"settling_lag", "marker_slip"}


class _Offset(ModelTerm):
    def pose_offset(self, theta, poses, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        out[:, 2] = theta[0] + 1e-4  # an offset where theta = 0: a model not nested in the one without it
        return out


class _Broken(Effect):
    name = "broken"
    summary = "a test effect"

    def term(self):
        return _Offset(self.name, ["z"], np.zeros(1), ["m"], {})

    def candidates(self, spec, poses, residuals=None):
        return [self.term()]

    def regressor(self, term, spec, poses):
        return np.zeros(poses.n_poses)

    def from_dict(self, data, spec=None):
        return self.term()


def test_a_term_that_acts_at_theta_zero_is_caught():
    with pytest.raises(AssertionError, match="broken term .*pose_offset at theta = 0"):
        check_effect(_Broken(), get_platform("stewart"))


def test_a_simulated_effect_without_its_size_help_is_caught():
    class Unsaid(_Broken):
        def term(self):
            return ModelTerm(self.name, ["z"], np.zeros(1), ["m"], {})

        def simulation_term(self, spec, size, rng, commands):
            return self.term(), np.array([1e-3])

    with pytest.raises(AssertionError, match="simulation_term simulates the effect, but its size help is missing"):
        check_effect(Unsaid(), get_platform("stewart"))
    Unsaid.simulation_size = SizeHelp("the offset", "mm")
    assert check_effect(Unsaid(), get_platform("stewart"))["simulated"]


def test_flags_and_the_lag_being_a_recording_artefact_are_checked():
    class Lag(_Broken):
        unsettled_holds = True

    with pytest.raises(AssertionError, match="an unsettled_holds effect is an artefact of the recording"):
        check_effect(Lag(), get_platform("stewart"))

    class NotBool(_Broken):
        direction = "yes"

    with pytest.raises(AssertionError, match="direction must be True or False"):
        check_effect(NotBool(), get_platform("stewart"))


def test_a_recording_artefact_that_moves_no_marker_of_the_stand_is_caught(builtins):
    """Every marker an artefact says it moved (``moved_markers``: a rigid body's three points, by
    default ``moved_marker``'s one) must be a marker of the poses."""
    slip = type(builtins["marker_slip"])

    class FarSlip(slip):
        def moved_markers(self, term, theta, std):
            return [*super().moved_markers(term, theta, std), (10_000, np.zeros(3), np.zeros(3))]

    with pytest.raises(AssertionError, match="moved_markers' index 10000 is no marker"):
        check_effect(FarSlip(), get_platform("stewart"))
