"""An effect from outside platkit that is an artefact of the recording (tests/outside_plugins/
camera_heat.py: a marker's image drifting as the camera warms up), registered through a plugin
host of the test's own: diagnosis names it, corrects it in the data and leaves it out of the
stand's calibration, with nothing in platkit knowing its name."""
from __future__ import annotations

import numpy as np
import pytest
from outside_plugins import camera_heat

from platkit.diagnose import Options, diagnose
from platkit.plugins import PluginHost, get_platform
from platkit.simulate import simulate
from platkit.testing import check_effect


@pytest.fixture(scope="module")
def library():
    host = PluginHost(entry_points=False)
    host.register(camera_heat, name="camera_heat", source="tests")
    return host.effects()


def test_the_outside_effect_conforms(library):
    report = check_effect(library["camera_heat"], get_platform("stewart"))
    assert report["recording"] and report["simulated"]


def test_diagnose_names_the_outside_artefact_and_corrects_it_in_the_data(library):
    spec = get_platform("stewart")
    effect = library["camera_heat"]
    plan = simulate(spec, seed=41, n_poses=48, raw=False, plan="random", noise_mm=0.0, occlusion=0.0).commands
    term = effect.term("M3", 2)
    d_true = 0.6e-3 * np.array([0.6, -0.7, 0.4]) / np.linalg.norm([0.6, -0.7, 0.4])
    sim = simulate(spec, seed=40, n_poses=48, raw=False, plan=plan, terms=[(term, d_true)], noise_mm=0.1,
                   occlusion=0.0)
    diag = diagnose(spec, sim.poses, Options(max_effects=2), library=library)
    named = [(f.effect, f.where.get("marker")) for f in diag.findings]
    assert named == [("camera_heat", "M3")]
    finding = diag.findings[0]
    np.testing.assert_allclose(np.array([finding.parameters[n]["value"] for n in ("dx", "dy", "dz")]), d_true,
                               atol=1.5e-4)
    assert finding.corrected.startswith("in the data: marker M3's image drifting with the camera's warm-up")
    assert finding.heldout_rms_after < 0.5 * finding.heldout_rms_before
    # the fitted model holds the artefact; the stand's calibration leaves it out, the marker where it is
    assert [t.effect for t in diag.fitted.terms] == ["camera_heat"]
    assert diag.calibration.terms == []
    np.testing.assert_allclose(diag.calibration.marker_positions, diag.fitted.marker_positions, atol=0)
    assert "camera_heat describes the recording, not the stand" in diag.verdict
