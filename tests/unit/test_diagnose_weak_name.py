"""A name whose own held-out proof is weak yields to a generic probe that predicts better
(platkit.diagnose.naming._probe_beats): physics outside the library, a frame that sways with
time, must not be named as a leg's cyclic error (development seed 708230 of the proof benchmark,
its protocol: every fifth command held out and cut from the stream, conftest.proof_session); so
must one proven weakly beside a lack of fit, one that proves nothing beside the probe that still
beats the named model, or beside a model of the structure in time the location tests still find
(platkit.diagnose.naming)."""


def test_a_time_periodic_sway_is_unexplained_not_a_weakly_proven_cyclic_error(proof_session, calibrate_and_diagnose):
    d = calibrate_and_diagnose(proof_session("stewart", 708230, [("frame_wobble", 0.0927)])[0])
    # without the rule: cyclic_error (p = 0.03), cyclic_error, then unexplained
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert "time" in d["findings"][0]["where"]


def test_a_weakly_proven_name_beside_a_large_lack_of_fit_is_not_named(monkeypatch, proof_session, calibrate_and_diagnose):
    # proof seed 920222: a frame sway named a leg's scale nonlinearity at held-out p = 0.045, the
    # model then still 7 times the noise floor with structure located, and the truth's held-out
    # made worse, 0.232 -> 0.321 mm; no probe predicted better, so the rule above did not act.
    # Settled as it was then (no limit on a window's length; with the 1.5 s limit the scale
    # nonlinearity is not proven at all, see the next test)
    import platkit.settle._settle as settle_module

    monkeypatch.setattr(settle_module, "SettleOptions", _unlimited)
    d = calibrate_and_diagnose(proof_session("stewart", 920222, [("frame_wobble", 0.317)])[0])
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert any(r.get("not_named") == ["scale_nonlinearity (actuator L1)"] for r in d["rounds"])
    assert "passed the held-out test only weakly" in d["verdict"]


def _unlimited():
    from platkit.settle import SettleOptions

    return SettleOptions(max_window_s=None)


def test_the_same_sway_settled_with_the_window_limit_names_nothing_but_unexplained(proof_session,
                                                                                     calibrate_and_diagnose):
    d = calibrate_and_diagnose(proof_session("stewart", 920222, [("frame_wobble", 0.317)])[0])
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]


def test_a_name_that_proves_nothing_beside_the_final_probe_is_not_named(proof_session, calibrate_and_diagnose):
    # proof seed 961233: a psvr frame sway named a cyclic error of actuator A at held-out p = 0.0018
    # (a strong proof, so neither rule above acted), then the time probe beat the named model;
    # beside the probe the cyclic error predicts no better (p = 0.057), and the truth's held-out
    # had gone 0.060 -> 0.064 mm
    d = calibrate_and_diagnose(proof_session("psvr", 961233, [("frame_wobble", 0.09634128467490397)])[0])
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert "time" in d["findings"][0]["where"]
    beside = [r for r in d["rounds"] if r.get("round") == "beside the probe"]
    assert beside and beside[0]["not_named"] == ["cyclic_error (actuator A, period 256.0)"]
    assert "not beside the generic model" in d["verdict"]


def test_a_name_that_proves_nothing_beside_the_structure_in_time_is_not_named(proof_session,
                                                                                calibrate_and_diagnose):
    # proof seed 1100230: a weak stewart frame sway (period 65 s over a 300 s session) named a
    # cyclic error of leg L2 (period 0.01 m) at held-out p = 0.004, a 7% gain: not weak, and no
    # probe beat it (six time bins cannot follow the sway); the model was left at 2.05 times the
    # noise floor, its residuals autocorrelated in time, and the truth's held-out went 0.074 ->
    # 0.079 mm. Beside a time probe fine enough to follow the sway the cyclic error proves nothing
    d = calibrate_and_diagnose(proof_session("stewart", 1100230, [("frame_wobble", 0.08709367832661394)])[0])
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    beside = [r for r in d["rounds"] if r.get("round") == "beside the structure in time"]
    assert beside and beside[0]["not_named"] == ["cyclic_error (actuator L2, period 0.01)"]
    assert beside[0]["paired_p"]["cyclic_error (actuator L2, period 0.01)"] > 0.05 and beside[0]["time_bins"] > 6
    assert "not beside a model of the structure in time" in d["verdict"]


def test_a_weak_fitted_lag_is_not_named_when_the_stream_shows_the_holds_settled(proof_session,
                                                                                 calibrate_and_diagnose):
    # proof seed 1061233: a weak psvr frame sway (period 73 s) was named an additive settling_lag
    # along every actuator's last move at held-out p = 0.021, the one wrong name of 216
    # out-of-library sessions; the settling search had found the holds settled
    d = calibrate_and_diagnose(proof_session("psvr", 1061233, [("frame_wobble", 0.09484666623307283)])[0])
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    lag = [x for x in d["not_separable"] if x["effect"] == "settling_lag"]
    assert lag and lag[0]["from"].startswith("the stream")
    assert "Not named, proven only weakly while the stream shows the holds settled: settling_lag" in d["verdict"]
