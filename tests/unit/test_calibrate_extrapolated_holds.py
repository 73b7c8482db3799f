"""Holds extrapolated to rest: the stream is the data, however many settled
(platkit.commands.calibrate.refuse_extrapolated_holds; docs/diagnosis.md, "Too few settled holds: the stream" and
"Any hold extrapolated: the stream")."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from platkit.commands.calibrate import refuse_extrapolated_holds
from platkit.diagnose.search import settled_needed
from platkit.settle import HoldsNeverSettle


def _poses(n_poses: int, n_extrapolated: int, n_commands: int = 120) -> SimpleNamespace:
    return SimpleNamespace(n_poses=n_poses, dropped=[], settling={
        "n_commands": n_commands, "n_extrapolated": n_extrapolated,
        "unsettled": {"n": n_extrapolated, "actuators": ["B"], "time_constant_s": 0.5, "sentence": "holds never settled"}})


def test_too_few_settled_beside_extrapolated_holds_is_refused_as_a_stream():
    need = settled_needed()
    with pytest.raises(HoldsNeverSettle) as exc:
        refuse_extrapolated_holds(_poses(need - 1 + 80, 80), "s")
    assert exc.value.settling["n_settled"] == need - 1 and exc.value.settling["n_extrapolated"] == 80
    assert exc.value.settling["unsettled"]["actuators"] == ["B"]  # the summary diagnosis names the lag from


def test_any_hold_extrapolated_is_refused_as_a_stream_however_many_settled():
    """Settled fewer than extrapolated (the benchmark's rotary 5212100: 32 beside 53), as many, or
    the majority (psvr 5330110: 62 beside 34; 60 beside 35; 94 beside 1): the stream is the data."""
    need = settled_needed()
    for n_settled, n_extrapolated in ((62, 34), (60, 35), (94, 1), (need + need, need), (need, 80), (32, 53)):
        with pytest.raises(HoldsNeverSettle) as exc:
            refuse_extrapolated_holds(_poses(n_settled + n_extrapolated, n_extrapolated), "s")
        assert exc.value.settling["n_settled"] == n_settled
        assert exc.value.settling["n_extrapolated"] == n_extrapolated
        assert "the extrapolated poses carry what the approach model missed" in exc.value.settling["reason"]


def test_nothing_extrapolated_stays_poses():
    refuse_extrapolated_holds(_poses(10, 0, 12), "s")  # no stream beyond the holds to read
    refuse_extrapolated_holds(_poses(120, 0), "s")


def test_calibrate_reads_the_stream_of_holds_extrapolated_with_too_few_settled(tmp_path):
    """A rotary with a slow actuator (time constant 0.15 of the hold): 13 of 16 holds extrapolated
    to rest, 2 settled: calibrate fits the motion model to the stream, not the 15 poses."""
    from platkit.cli import main
    from platkit.io.session import load_session
    from platkit.plugins import get_platform
    from platkit.settle import load_poses
    from platkit.simulate.physics import simulate_physics, write_physical_session

    sim = simulate_physics(get_platform("rotary"), seed=100, n_poses=16, plan="random",
                           effects=[("settling_lag", 0.15)], mocap_rate_hz=50.0)
    folder = write_physical_session(sim, tmp_path / "slow")
    s = load_session(folder)
    poses = load_poses(s.folder, spec=s.spec, session=s)
    assert 0 < poses.n_poses - poses.settling["n_extrapolated"] < settled_needed()  # the case this rule is for
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--out", str(tmp_path / "cal")]) == 0
    report = json.loads((tmp_path / "cal" / "report.json").read_text())
    assert report.get("motion"), "calibrated from the extrapolated poses, not the stream"
    # diagnose reads the stream through that calibration's response too, not the extrapolated poses
    assert main(["diagnose", str(folder), "--calibration", str(tmp_path / "cal" / "calibration.yaml"), "--quiet",
                 "--no-report", "--out", str(tmp_path / "diag")]) == 0
    diag = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert any(r.get("round") == "settle summary" for r in diag["rounds"])


def test_a_stream_the_motion_model_does_not_explain_is_calibrated_from_the_holds_poses(tmp_path, monkeypatch):
    """Where every hold settled or was extrapolated to rest and the fitted motion model does not
    explain the stream (psvr 5470190: 20.2 mm after the fit, 121 times the noise), calibrate uses
    the holds' poses and says so, instead of refusing a session its poses calibrate."""
    import platkit.calibrate.motion as motion
    from platkit.cli import main
    from platkit.plugins import get_platform
    from platkit.simulate.physics import simulate_physics, write_physical_session

    sim = simulate_physics(get_platform("rotary"), seed=100, n_poses=16, plan="random",
                           effects=[("settling_lag", 0.15)], mocap_rate_hz=50.0)
    folder = write_physical_session(sim, tmp_path / "slow")

    def unexplained(session, *a, **k):
        raise motion.MotionUnexplained(f"{session.folder / 'commands.csv'}: the command log does not explain the "
                                       "motion (test)")

    monkeypatch.setattr(motion, "calibrate_motion", unexplained)
    import platkit.commands.calibrate as calibrate_command
    import platkit.io.session as session_module
    from platkit.io.shipped import shipped_dir

    reads, second = [], []
    read = session_module.load_session
    monkeypatch.setattr(session_module, "load_session", lambda *a, **k: reads.append(a) or read(*a, **k))
    load_other = calibrate_command.load_for_calibration
    monkeypatch.setattr(calibrate_command, "load_for_calibration",
                        lambda *a, **k: second.append(a) or load_other(*a, **k))
    validate = shipped_dir("sessions") / "rotary"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--validate", str(validate),
                 "--out", str(tmp_path / "cal")]) == 0
    report = json.loads((tmp_path / "cal" / "report.json").read_text())
    assert not report.get("motion")
    assert len(second) == 1 and report["heldout"].get("second_session")  # --validate read once, and scored
    fell_back = [w for w in report["warnings"] if "calibrated from the holds' poses instead" in w]
    assert len(fell_back) == 1 and "too few holds settle: 2 of 16 holds settled" in fell_back[0]  # both reasons
    assert "does not explain the motion (test)" in fell_back[0]
    # what did not happen is not said: no calibration from the stream in a report without one
    assert not any("calibrated from the whole stream" in w for w in report["warnings"])
    assert sum(Path(a[0]) == folder for a in reads) == 1  # read once, the fallback's poses those first read
    # a refusal whose poses are not usable (under half the commands gave one) is still a refusal
    from platkit.commands.calibrate import motion_or_poses
    from platkit.errors import BadSession

    refused = HoldsNeverSettle("s: under half", {"reason": "under half", "n_commands": 16, "n_settled": 2})
    args = SimpleNamespace(session=str(folder), platform=None, description=None, quiet=True, free=None,
                           validate=None, prior_strength=None, no_robust=False, out=str(tmp_path / "cal2"))
    with pytest.raises(BadSession, match="does not explain"):
        motion_or_poses(args, refused, [])
