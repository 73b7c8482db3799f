"""A slow actuator named on a session calibrated from motion because its holds never settled: the
settle search's refusal carries its summary (platkit.settle.HoldsNeverSettle.settling), and
diagnose names ``settling_lag`` on the actuator and with the time constant that summary gives
(platkit.diagnose.recording.lag_from_settle_summary, platkit.commands.diagnose
.named_from_settle_summary), beside the stream's lack of fit; a stream without holds names
nothing. The session is the proof benchmark's psvr settling_lag (clear) seed 981060
(docs/diagnosis.md, "A slow actuator refused one hold short of extrapolation"): 53 of 120 holds
settle, 43 never do (actuator B), only 34 of those extrapolate to rest (80% needed)."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.commands.calibrate import settling_notes
from platkit.commands.diagnose import ROUND_SETTLE_SUMMARY, named_from_settle_summary
from platkit.diagnose.fitting import Diagnosis, Finding
from platkit.diagnose.recording import FROM_SETTLE_SUMMARY, lag_from_settle_summary
from platkit.diagnose.stream import stream_why
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.settle import HoldsNeverSettle, NeverSettles, load_poses
from platkit.simulate.physics import simulate_physics, write_physical_session

MOTION_RESPONSE = {"actuators": {"A": {"tau_s": {"value": 0.05, "status": "estimated"}},
                                 "B": {"tau_s": {"value": 0.65, "status": "estimated"}},
                                 "C": {"tau_s": {"value": -0.007, "status": "estimated"}}}}


@pytest.fixture(scope="module")
def refused_981060(tmp_path_factory):
    """The refusal of the proof's psvr settling_lag (clear) session 981060, in its protocol (120
    commands, every fifth held out and cut from the stream: tests/proof_protocol.py)."""
    from proof_protocol import blank_held_out, held_out_rows

    sim = simulate_physics(get_platform("psvr"), seed=981060, n_poses=120, plan="random",
                           effects=[("settling_lag", 0.15)], coloured=True)
    folder = write_physical_session(sim, tmp_path_factory.mktemp("lag") / "session")
    blank_held_out(folder, sim, held_out_rows(len(sim.commands)))
    with pytest.raises(HoldsNeverSettle) as refused:
        load_poses(folder)
    return refused.value.settling, [p.actuator for _, p in sim.physics], folder


def test_the_refusal_carries_the_settle_summary_and_says_why(refused_981060):
    settling, slow, _ = refused_981060
    assert slow == ["B"]
    assert (settling["n_commands"], settling["n_settled"], settling["n_extrapolable"]) == (120, 53, 34)
    assert settling["unsettled"]["actuators"] == ["B"] and settling["unsettled"]["n"] == 43
    assert settling["reason"].startswith("53 of 120 holds settled; 43 never did (actuator B still moving")
    assert "only 34 of those extrapolate to rest (80% needed)" in settling["reason"]
    # diagnose's line says what is true: holds settled, too few of them
    assert stream_why(settling).startswith("too few settled holds: 53 of 120 holds settled")


def _stream_diagnosis(findings: list[Finding]) -> Diagnosis:
    """A diagnosis of a stream's windowed poses as diagnose leaves it (nothing named by the search
    or the stream's lack of fit), at a geometric held-out RMS of 1.26 mm over a floor of 0.08 mm."""
    poses = PoseSet("psvr", np.zeros((10, 3)), np.zeros((10, 5, 3)), [f"M{k}" for k in range(1, 6)],
                    extras={"node": np.arange(10)})
    return Diagnosis(findings=findings, verdict="", calibration=None, base=None, locations=[],  # type: ignore[arg-type]
                     locations_before=[], rounds=[], not_separable=[], unit="mm", poses=poses,
                     noise_floor=0.08e-3, heldout_geometric=1.26e-3)


def test_a_motion_calibrated_session_names_the_slow_actuator_beside_the_lack_of_fit(refused_981060):
    """Before: diagnose called the session 'unexplained' only (the stream's lack of fit)."""
    settling, _, _ = refused_981060
    unexplained = Finding(effect="unexplained", where={"marker": "M3", "axis": "z"}, parameters={},
                          heldout_rms_before=1.26e-3, heldout_rms_after=1.26e-3, evidence="lack of fit")
    d = _stream_diagnosis([unexplained])
    cal = type("Cal", (), {"motion": {"response": MOTION_RESPONSE}})()
    named_from_settle_summary(d, settling, cal)
    assert [f.effect for f in d.findings] == ["settling_lag", "unexplained"]
    lag = d.findings[0]
    assert lag.where["actuator"] == "B" and lag.where["holds"] == 43 and lag.where["of_commands"] == 120
    assert lag.where["from"] == FROM_SETTLE_SUMMARY
    assert lag.parameters["time_constant"]["value"] == pytest.approx(settling["unsettled"]["time_constant_s"])
    assert 0.5 < lag.parameters["time_constant"]["value"] < 1.0 and lag.parameters["time_constant"]["unit"] == "s"
    assert lag.heldout_rms_before == lag.heldout_rms_after == 1.26e-3 and lag.term is None  # nothing changed
    assert "settle summary of a session calibrated from motion" in lag.evidence
    assert "fitted response agrees: slowest B" in lag.evidence
    assert lag.warnings == [
        "the stream's lack of fit (unexplained at marker M3, one of the markers the slow actuator still moved "
        "(M3, M2, M4, M1)) stays beside it: naming the lag changes nothing in the model, so the two are not told "
        "apart on this session (a response that does not follow this lag, or marker noise correlated over the "
        "windows beyond what the noise floor counts, would read so)"]
    said = next(r for r in d.rounds if r["round"] == ROUND_SETTLE_SUMMARY)
    assert said["named"] == ["settling_lag"] and said["from"] == FROM_SETTLE_SUMMARY
    assert "settling_lag (actuator B)" in d.verdict
    assert "corrected by the calibration from motion" in d.verdict and "corrected in the data" not in d.verdict


def test_a_summary_naming_no_actuator_or_with_no_holds_settled_names_nothing(refused_981060):
    settling, _, _ = refused_981060
    anonymous = {**settling, "unsettled": {**settling["unsettled"], "actuators": []}}
    assert lag_from_settle_summary(anonymous, MOTION_RESPONSE, 1e-3, "settling_lag", 0.1) is None
    none_settled = {**settling, "n_settled": 1}  # a stream: its last hold alone settles
    assert lag_from_settle_summary(none_settled, MOTION_RESPONSE, 1e-3, "settling_lag", 0.1) is None
    few = {**settling, "unsettled": {**settling["unsettled"], "n": 12}}  # 10% of 120: no pattern
    assert lag_from_settle_summary(few, MOTION_RESPONSE, 1e-3, "settling_lag", 0.1) is None


def test_a_clean_stream_without_holds_names_nothing(tmp_path):
    """A clean streamed session (a multisine, no holds): settling refuses it, its refusal carries no
    summary of unsettled holds, and diagnose adds no finding (its round says so)."""
    sim = simulate_physics(get_platform("stewart"), seed=4101, motion="multisine", duration_s=24.0,
                           mocap_rate_hz=50.0)
    folder = write_physical_session(sim, tmp_path / "session")
    poses = load_poses(folder)
    with pytest.raises((HoldsNeverSettle, NeverSettles)) as refused:
        settling_notes(poses, folder)
    settling = refused.value.settling
    assert settling["n_settled"] <= 1 and not settling["unsettled"]
    assert "under half" in settling["reason"]
    d = _stream_diagnosis([])
    named_from_settle_summary(d, settling, type("Cal", (), {"motion": {"response": MOTION_RESPONSE}})())
    assert d.findings == [] and d.rounds[-1]["named"] == []


def test_calibrate_says_why_it_falls_back_and_which_response_each_fit_fits(refused_981060):
    """The warning says why the holds were refused (before: 'the holds do not settle or there are
    none'); the motion fits' progress lines say the response's kind and that each is one of several
    (before: 'rms 13.85 -> 15.37 mm' read as a fit getting worse). The events are 981060's."""
    import io

    from platkit.commands.calibrate import fallback_note, motion_progress_printer

    settling, _, _ = refused_981060
    note = fallback_note(settling["reason"])
    assert note.startswith("too few holds settle: 53 of 120 holds settled; 43 never did (actuator B")
    assert "(80% needed): calibrated from the whole stream" in note
    out = io.StringIO()
    show = motion_progress_printer("mm", "auto", out)
    for n, held, before, after, kind in ((51, 6, 28.91, 24.51, "first_order"), (53, 7, 13.85, 15.37, "second_order"),
                                         (56, 4, 22.09, 1.027, "second_order"), (55, 3, 1.2, 0.62, "per_actuator")):
        show("iteration", {"iteration": 1, "rms": before * 1e-3})
        show("identifiability", {"n_identifiable": n, "held": [f"p{k}" for k in range(held)], "response_kind": kind})
        show("done", {"rms_before": before * 1e-3, "rms_after": after * 1e-3, "time_s": 1.0})
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("calibrate: from motion: the actuators' response fitted first order, then second")
    done = [x for x in lines if " -> " in x]
    assert done == ["calibrate: fit 1 (first-order response) rms 28.91 -> 24.51 mm from its own start, in 1.00 s",
                    "calibrate: fit 2 (second-order response) rms 13.85 -> 15.37 mm from its own start, in 1.00 s",
                    "calibrate: fit 3 (second-order response) rms 22.09 -> 1.027 mm from its own start, in 1.00 s",
                    "calibrate: fit 4 (second-order response for some actuators) rms 1.2 -> 0.62 mm from its own "
                    "start, in 1.00 s"]


def test_calibrate_warns_with_the_reason_where_the_motion_fit_fails(refused_981060, tmp_path, monkeypatch, capsys):
    """platkit calibrate on 981060, the fit from motion stopped at once by the test: the one-line
    warning carries the settle search's reason and says the stream was tried, not that it calibrated."""
    import platkit.calibrate.motion as motion
    from platkit.cli import main
    from platkit.errors import ComputationFailed

    def stop(*args, **kwargs):
        raise ComputationFailed("stopped by the test")

    monkeypatch.setattr(motion, "calibrate_motion", stop)
    _, _, folder = refused_981060
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--out", str(tmp_path / "cal")]) == 1
    err = capsys.readouterr().err
    assert ("too few holds settle: 53 of 120 holds settled; 43 never did (actuator B still moving, time constant "
            "0.801 s), and only 34 of those extrapolate to rest (80% needed): the whole stream was tried") in err
    assert "calibrated from the whole stream" not in err and "stopped by the test" in err


def test_a_lag_the_stream_search_named_itself_is_not_named_twice(refused_981060):
    """Where diagnosis of the stream named the lag as a term of its own (unseen seed 1621060's search
    tried settling_lag on every actuator), the settle summary's reading goes into that finding."""
    settling, _, _ = refused_981060
    term = Finding(effect="settling_lag", where={"actuator": "all"}, parameters={}, heldout_rms_before=1.38e-3,
                   heldout_rms_after=1.37e-3, evidence="a lag along every actuator's last move")
    d = _stream_diagnosis([term])
    named_from_settle_summary(d, settling, type("Cal", (), {"motion": {"response": MOTION_RESPONSE}})())
    assert d.findings == [term] and d.rounds[-1]["named"] == [] and d.rounds[-1]["already_named"] == "settling_lag"
    assert term.evidence.endswith("; the settle summary of a session calibrated from motion names it too, on actuator "
                                  "B (43 of 120 holds never settled, time constant 0.801 s)")
