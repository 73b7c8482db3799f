"""The neighbour tests (platkit.diagnose.locate.neighbour_tests): with nothing named and the
geometric model within twice the noise floor held out, residuals alike at poses next in time or
at poses with near commands, in the motion capture frame or in the moving frame, are a weak
effect outside the library, reported ``unexplained``.

The sessions are from the proofs on the physical simulator (seeds 1031213, 1060230 and 1032232,
the proof's protocol: conftest.proof_session), where diagnosis said nothing before: a weak plate
that flexes with the pose, and weak sways of the marker mount."""
import numpy as np

from platkit.diagnose.locate import neighbour_tests
from platkit.diagnose.stats import neighbour_similarity
from platkit.effects import with_history
from platkit.plugins import get_platform
from platkit.poses import PoseSet


def test_neighbour_similarity_holds_its_level_on_independent_rows_and_sees_alike_ones():
    rng = np.random.default_rng(4)
    a = np.arange(47)
    p_white = np.array([neighbour_similarity(rng.normal(size=(48, 12)), a, a + 1, 199, rng)[1] for _ in range(300)])
    assert 0.02 < np.mean(p_white < 0.1) < 0.18  # about 10% under 0.1: the level holds
    smooth = rng.normal(size=(48, 12)) + np.sin(np.arange(48) / 3.0)[:, None]
    s, p = neighbour_similarity(smooth, a, a + 1, 999, rng)
    assert s > 0.2 and p <= 0.002
    assert neighbour_similarity(np.zeros((48, 12)), a, a + 1) == (0.0, 1.0)


def _poses(residual_of, rng):
    """48 poses of the stewart stand at random commands, one every 4 s, with 3 markers whose
    residuals are ``residual_of(t, u)`` plus white noise; returns (poses, residuals)."""
    spec = get_platform("stewart")
    lo, hi = spec.control_bounds()
    u = rng.uniform(lo, hi, size=(48, len(lo)))
    t = 4.0 * np.arange(48)
    r = rng.normal(scale=1e-4, size=(48, 3, 3)) + residual_of(t, (u - lo) / (hi - lo))
    poses = with_history(PoseSet("stewart", u, np.zeros((48, 3, 3)), ["m1", "m2", "m3"], t=t), spec)
    return poses, r


def _sway(t, u):
    return 1.5e-4 * np.sin(2 * np.pi * t / 60.0)[:, None, None] * np.ones((1, 3, 3))


def _bend(t, u):
    return 3e-3 * np.sum((u - 0.5) ** 2, axis=1)[:, None, None] * np.array([1.0, -1.0, 0.5])[None, :, None]


def _white(t, u):
    return 0.0


def test_neighbour_tests_say_whether_the_structure_follows_time_or_the_commands():
    rng = np.random.default_rng(5)
    poses, r = _poses(_sway, rng)
    tests = neighbour_tests({"motion capture": r}, poses)
    assert tests[0].test == "residuals alike at poses next in time" and tests[0].p_adjusted < 0.01
    assert tests[0].where == {"alike": "poses next in time", "frame": "motion capture"}
    poses, r = _poses(_bend, rng)
    tests = neighbour_tests({"motion capture": r}, poses)
    assert tests[0].test == "residuals alike at poses with near commands" and tests[0].p_adjusted < 0.01
    poses, r = _poses(_white, rng)
    assert min(x.p_adjusted for x in neighbour_tests({"motion capture": r}, poses)) > 0.01
    assert neighbour_tests({"motion capture": r}, poses, keep=np.arange(48) < 10) == []  # too few poses to judge


def test_a_weak_plate_flex_near_the_floor_is_unexplained(tmp_path, proof_session, calibrate_and_diagnose):
    d = calibrate_and_diagnose(proof_session("psvr", 1031213, [("plate_flex", 1.0309245573075836)])[0])
    # before: no finding, the geometric model at 1.6 times the noise floor held out
    assert d["heldout_rms_geometric"] < 2 * d["noise_floor"]
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert d["findings"][0]["where"]["alike"].startswith("poses with near commands")
    tests = [r for r in d["rounds"] if r.get("round") == "neighbours"][0]["tests"]
    assert tests[0]["p_adjusted"] < 0.01
    assert "residuals are alike at poses with near commands" in d["verdict"]
    assert "No hidden effect" not in d["verdict"]
    report = (tmp_path / "diag" / "report.html").read_text()  # each pose's error against its neighbour's, drawn
    assert "<h3>unexplained: errors of the geometric model at poses with near commands (3 nearest)</h3><img" in report


def test_a_weak_sway_of_the_marker_mount_is_unexplained(proof_session, calibrate_and_diagnose):
    d = calibrate_and_diagnose(proof_session("stewart", 1060230, [("frame_wobble", 0.09560564109299277)])[0])
    # before: no finding, the geometric model at 1.2 times the noise floor held out
    assert d["heldout_rms_geometric"] < 2 * d["noise_floor"]
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert d["findings"][0]["where"]["alike"] == "poses next in time"


def test_a_sway_of_the_mount_on_a_turning_stand_is_seen_in_the_moving_frame(proof_session, calibrate_and_diagnose):
    # proof seed 1032232: a weak rotary frame sway (period 48 s) along one direction of the moving
    # part, which turns with the table: in the motion capture frame poses next in time are not
    # alike (p = 0.6), in the moving frame they are
    d = calibrate_and_diagnose(proof_session("rotary", 1032232, [("frame_wobble", 0.08509048338658029)])[0])
    assert d["heldout_rms_geometric"] < 2 * d["noise_floor"]
    assert [f["effect"] for f in d["findings"]] == ["unexplained"]
    assert {k: d["findings"][0]["where"][k] for k in ("alike", "frame")} == {"alike": "poses next in time",
                                                                           "frame": "moving"}
    tests = {(t["test"], t["frame"]): t["p"] for t in [r for r in d["rounds"] if r.get("round") == "neighbours"][0]["tests"]}
    assert tests[("residuals alike at poses next in time, in the motion capture frame", "motion capture")] > 0.1
    assert "in the moving frame" in d["verdict"]


def test_no_neighbour_test_where_holds_were_extrapolated(proof_session, calibrate_and_diagnose, monkeypatch):
    # proof seed 1101122 (of 0af382d's proof): a weak slow psvr actuator B, read from the stream;
    # the settled poses carry its approach's remnant, alike over near commands (p = 0.001), and an
    # `unexplained` was said beside the lag. Its holds extrapolated to rest (28, beside 20 settled) make
    # calibrate read it as a stream (commands.calibrate.refuse_extrapolated_holds); that rule is held off here so
    # that the session is diagnosed on its poses, the path under test
    import platkit.commands.calibrate as calibrate_command

    monkeypatch.setattr(calibrate_command, "refuse_extrapolated_holds", lambda poses, folder: None)
    session, sim = proof_session("psvr", 1101122, [("settling_lag", 0.1)])
    assert [p.actuator for _, p in sim.physics] == ["B"]
    d = calibrate_and_diagnose(session)
    assert [(f["effect"], f["where"]["actuator"]) for f in d["findings"]] == [("settling_lag", "B")]
    assert not [r for r in d["rounds"] if r.get("round") == "neighbours"]
