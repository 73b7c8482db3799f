"""Two names that made held-out prediction of the settled poses worse in the proof on the
physical simulator (seeds 1010000-1011999, the proof's protocol: every fifth command held out
and cut from the stream, conftest.proof_session), each now tested at the stricter held-out level:

- a held-out gain under ``small_gain`` (platkit.diagnose.rounds.confirm): a plate that flexes
  (physics the library does not hold) named a leg's scale nonlinearity at a 4% gain (now
  ``unexplained``, by the neighbour tests);
- any term in a session whose holds were extrapolated to rest
  (platkit.diagnose.recording.extrapolated_weak_echo): a slow psvr actuator A given a cyclic
  error on actuator C."""


def test_a_small_held_out_gain_must_prove_itself_strongly(proof_session, calibrate_and_diagnose):
    d = calibrate_and_diagnose(proof_session("stewart", 1010211, [("plate_flex", 0.922729524942375)])[0])
    # before: scale_nonlinearity (actuator L6) at a 4.1% gain, p = 0.019; the truth's held-out 0.068 -> 0.072 mm
    # since: unexplained, its residuals alike at poses with near commands (locate.neighbour_tests)
    assert [(f["effect"], f["where"].get("alike", "")[:24]) for f in d["findings"]] == \
        [("unexplained", "poses with near commands")]
    said = [r["not_accepted"] for r in d["rounds"] if r.get("not_accepted")]
    assert said and said[0].startswith("scale_nonlinearity (actuator L6): not accepted") and "under 5%" in said[0]
    assert "The closest candidate in the library: scale_nonlinearity (actuator L6)" in d["verdict"]


def test_a_weak_term_on_another_actuator_than_the_slow_one_is_not_named(proof_session, calibrate_and_diagnose,
                                                                        monkeypatch):
    # calibrate reads a session with holds extrapolated to rest as a stream (commands.calibrate.refuse_extrapolated_holds);
    # that rule is held off here so that the session is diagnosed on its poses, the path under test
    import platkit.commands.calibrate as calibrate_command

    monkeypatch.setattr(calibrate_command, "refuse_extrapolated_holds", lambda poses, folder: None)
    session, sim = proof_session("psvr", 1011112, [("settling_lag", 0.15)])
    assert [p.actuator for _, p in sim.physics] == ["A"]
    d = calibrate_and_diagnose(session)
    # before: cyclic_error (actuator C) at p = 0.0051 beside the lag; the truth's held-out 0.084 -> 0.092 mm
    assert [(f["effect"], f["where"]["actuator"]) for f in d["findings"]] == [("settling_lag", "A")]
    echo = [x for x in d["not_separable"] if x["effect"] == "cyclic_error"]
    assert echo and echo[0]["where"]["actuator"] == "C" and echo[0]["from"].startswith("the slow actuator")
    assert "Not told apart from the slow actuator's unfinished approach" in d["verdict"]
