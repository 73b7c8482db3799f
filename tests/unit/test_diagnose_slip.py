"""A marker slip is named and corrected in the data; calibration.yaml takes the slip's model change
only where it predicts the poses from the slip on better (platkit.diagnose.recording._slip_not_kept),
in the proof benchmark's protocol (every fifth command held out and cut from the stream)."""
from platkit.io.calibration import read_calibration


def _assert_written_as_given(tmp_path):
    given = read_calibration(tmp_path / "cal" / "calibration.yaml")
    written = read_calibration(tmp_path / "diag" / "calibration.yaml")
    assert written.td.tolist() == given.td.tolist()
    assert written.marker_positions.tolist() == given.marker_positions.tolist()


def test_a_slip_the_geometric_fit_already_followed_leaves_the_calibration_as_given(tmp_path, proof_session,
                                                                                   calibrate_and_diagnose):
    # proof seed 931130: the robust geometric fit puts the slipped marker at its new place and
    # leaves its earlier half out; fitting both places brought that half back and the truth's
    # held-out prediction went 0.0053 -> 0.0056 mm (by chance: 7 of 21 such sessions worse).
    # Here both predict the poses after the slip at 0.027 mm (paired p = 0.73)
    d = calibrate_and_diagnose(proof_session("psvr", 931130, [("marker_slip", 1.0012402045946533)])[0])
    assert [f["effect"] for f in d["findings"]] == ["marker_slip"]
    assert "not 2% better: calibration.yaml is the fit without the slip" in d["findings"][0]["corrected"]
    _assert_written_as_given(tmp_path)


def test_a_slip_whose_model_predicts_only_slightly_better_leaves_the_calibration_as_given(tmp_path, proof_session,
                                                                                         calibrate_and_diagnose):
    # proof seed 960134: the slip's model predicted the held-out poses after it 0.8% better in
    # diagnose's folds (0.0531 against 0.0535 mm, p = 0.014) and was written; against the truth
    # it predicted them worse, 0.0115 -> 0.0121 mm. A written change must gain what every other
    # term must (min_relative_gain, 2%)
    d = calibrate_and_diagnose(proof_session("stewart", 960134, [("marker_slip", 0.9879552124517214)])[0])
    assert [f["effect"] for f in d["findings"]] == ["marker_slip"]
    assert "(paired p = 0.014), not 2% better" in d["findings"][0]["corrected"]
    _assert_written_as_given(tmp_path)


def test_a_slip_the_geometric_fit_did_not_follow_is_written(tmp_path, proof_session, calibrate_and_diagnose):
    # proof seed 942130: the geometric fit kept the marker's old place; the slip's model predicts
    # the poses after it far better, and calibration.yaml holds the marker's new place
    d = calibrate_and_diagnose(proof_session("rotary", 942130, [("marker_slip", 0.9118)])[0])
    assert [f["effect"] for f in d["findings"]] == ["marker_slip"]
    f = d["findings"][0]
    assert f["corrected"].endswith("calibration.yaml holds its place after the slip")
    m = f["where"]["marker_index"]
    given = read_calibration(tmp_path / "cal" / "calibration.yaml")
    written = read_calibration(tmp_path / "diag" / "calibration.yaml")
    moved = abs(written.marker_positions[m] - given.marker_positions[m]).max()
    assert moved > 0.5e-3  # metres: the marker at its new place, about the slip's 0.9 mm away
