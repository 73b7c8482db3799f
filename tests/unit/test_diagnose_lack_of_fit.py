"""Physics the effect library does not hold: when nothing in the library predicts held-out poses
better and the geometric model stays well above the noise floor, diagnosis says `unexplained` (a
lack of fit, with the ratio to the floor), never a clean bill and never a library name."""
from outside_plugins import library_with
from outside_plugins.outside_physics import OutsideEffect, PlateFlex

from platkit.diagnose import Options, diagnose
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.settle import settle
from platkit.simulate.physics import simulate_physics, write_physical_session


def _session(tmp_path, monkeypatch, effects):
    # the plate's physics through a plugin host of the simulation's own: diagnose never sees it
    sim = simulate_physics(get_platform("psvr"), seed=706500, n_poses=40, plan="random", effects=effects,
                           library=library_with(OutsideEffect("plate_flex", PlateFlex)))
    return write_physical_session(sim, tmp_path / "s")


def test_a_non_rigid_marker_plate_is_unexplained_by_the_marker_probe(tmp_path, monkeypatch, calibrate_and_diagnose):
    diag = calibrate_and_diagnose(_session(tmp_path, monkeypatch, [("plate_flex", 2.0)]))
    assert [f["effect"] for f in diag["findings"]] == ["unexplained"]
    assert "markers" in diag["findings"][0]["where"]  # each marker its own offset with the pose
    assert "moves each marker on its own" in diag["findings"][0]["evidence"]
    assert diag["findings"][0]["heldout_rms_after"] < 0.6 * diag["heldout_rms_geometric"]
    assert diag["heldout_rms_geometric"] > 2 * diag["noise_floor"]


def test_without_probes_the_plate_is_a_lack_of_fit(tmp_path, monkeypatch):
    spec = get_platform("psvr")
    poses, _ = settle(load_session(_session(tmp_path, monkeypatch, [("plate_flex", 2.0)]), platform="psvr"))
    d = diagnose(spec, poses, Options(probes=False))
    assert [f.effect for f in d.findings] == ["unexplained"]
    assert "times the noise floor" in d.findings[0].evidence


def test_the_same_session_without_it_has_no_finding(tmp_path, monkeypatch, calibrate_and_diagnose):
    diag = calibrate_and_diagnose(_session(tmp_path, monkeypatch, []))
    assert diag["findings"] == []
    assert diag["heldout_rms_geometric"] < 2 * diag["noise_floor"]
