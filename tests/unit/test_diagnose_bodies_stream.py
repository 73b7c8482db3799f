"""platkit diagnose of a stream without holds whose motion capture gives rigid bodies alone.

A streamed session of the physical simulator with two rigid bodies (`platkit simulate --physics
--motion path --rigid-bodies 2 --noise-mm 0.2 --white-noise`, 10 s at 40 Hz, no effect), its markers
stripped as tests/unit/test_motion_bodies_alone.py strips them: `platkit calibrate` reads each body as
three points and calibrates from motion; `platkit diagnose` reads the stream's windows from the same
points through that calibration's response, their noise the points' own (the noise floor exists),
says once that the bodies were read as points, names no effect on this clean stream, and writes the
bodies again in calibration.yaml, which `platkit predict` reads.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from bodies_alone import stewart_bodies_stream, strip_markers

from platkit.cli import main


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    root = tmp_path_factory.mktemp("bodies_stream")
    sim, _ = stewart_bodies_stream(root)
    # the drives' own kind: diagnosis does not choose the response again, so a clean stream changes nothing
    assert main(["calibrate", str(root / "bodies"), "--quiet", "--no-report", "--response-kind", "second-order",
                 "--out", str(root / "cal")]) == 0
    return sim, root


def test_a_stream_of_bodies_alone_is_diagnosed_through_its_points(diagnosed, capsys):
    sim, root = diagnosed
    capsys.readouterr()
    assert main(["diagnose", str(root / "bodies"), "--calibration", str(root / "cal" / "calibration.yaml"),
                 "--out", str(root / "diag"), "--quiet", "--no-report", "--max-effects", "1"]) == 0
    err = capsys.readouterr().err
    # said once: the bodies read as points, and the stream read through the response
    assert err.count("diagnosed as three points each") == 1, err
    assert "no markers: rigid bodies T1, T2 diagnosed as three points each" in err
    assert err.count("no settled holds: diagnosed on the stream's") == 1
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    assert d["findings"] == []  # a clean stream: nothing named
    # the floor from the points' noise measured on the stream (0.2 mm white per axis, each node averaging its
    # window's samples): without their noise it would be None
    assert d["noise_floor"] is not None and 0.03 < d["noise_floor"] < 0.3, d["noise_floor"]
    assert d["heldout_rms_geometric"] < 1.0  # mm: the windows fitted through the calibrated response
    cal = yaml.safe_load((root / "diag" / "calibration.yaml").read_text())
    assert not cal.get("markers")  # the points are not written as markers
    assert sorted(cal["rigid_bodies"]["bodies"]) == ["T1", "T2"]
    assert "actuator_response" in cal  # the response back where calibrate wrote it
    # nothing named: each placement and its std as calibrate wrote them (read as points and back: the points'
    # std from the body's by the rule the read-back inverts; before, the rotation std grew by sqrt(1.5) a pass)
    given = yaml.safe_load((root / "cal" / "calibration.yaml").read_text())
    for b, body in cal["rigid_bodies"]["bodies"].items():
        for key in ("position", "rotation_vector", "std_position", "std_rotation_vector"):
            want = given["rigid_bodies"]["bodies"][b][key]
            assert np.allclose(body[key], want, rtol=1e-9, atol=1e-12), (b, key, body[key], want)
    # and the rest as calibrate wrote it: the response with its std, the residual block, the warnings
    for key in ("actuator_response", "residual", "parameters", "mocap_from_base"):
        assert cal[key] == given[key], key
    assert cal.get("warnings") == given.get("warnings")


def test_predict_reads_the_bodies_diagnose_wrote(diagnosed, tmp_path):
    """At the controls each command settled to (truth_settled.csv), the bodies' poses predicted from the
    calibration diagnose wrote against the true ones (a development run: 0.15 and 0.18 mm, 0.4 and 0.2
    mrad median, as from calibrate's: no effect named, so no change; a tip read as the origin is 100 mm
    off, a rotation read transposed tens of mrad or more)."""
    sim, root = diagnosed
    if not (root / "diag" / "calibration.yaml").is_file():
        assert main(["diagnose", str(root / "bodies"), "--calibration", str(root / "cal" / "calibration.yaml"),
                     "--out", str(root / "diag"), "--quiet", "--no-report", "--max-effects", "1"]) == 0
    settled = np.genfromtxt(sim / "truth_settled.csv", delimiter=",", names=True)
    controls = [f"L{k}" for k in range(1, 7)]
    np.savetxt(tmp_path / "settled.csv", np.column_stack([settled[c] for c in controls]), delimiter=",",
               header=",".join(controls), comments="")
    assert main(["predict", "--calibration", str(root / "diag" / "calibration.yaml"), "--commands",
                 str(tmp_path / "settled.csv"), "--out", str(tmp_path / "pred.csv")]) == 0
    got = np.genfromtxt(tmp_path / "pred.csv", delimiter=",", names=True)
    for b in ("T1", "T2"):
        err = np.linalg.norm(np.column_stack([got[f"{b}_{c}"] - settled[f"{b}_{c}"] for c in "xyz"]), axis=1)
        qp, qt = (np.column_stack([g[f"{b}_q{c}"] for c in "wxyz"]) for g in (got, settled))
        turn = 2.0 * np.arccos(np.clip(np.abs(np.sum(qp * qt, axis=1)), 0.0, 1.0))
        assert np.median(err) < 0.4 and np.median(turn) < 1.5e-3, (b, np.median(err), np.median(turn))


def test_a_play_is_named_from_the_bodies_alone(tmp_path):
    """A 20 s multisine stream of the two bodies alone with a 1 mm backlash (the truth's actuator):
    diagnose names backlash there (a development run: held-out 0.220 -> 0.194 mm, paired p = 7e-4,
    floor 0.123 mm over 66 windowed poses)."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "multisine", "--duration-s", "20",
                 "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", "4111",
                 "--effect", "backlash:1.0", "--out", str(sim)]) == 0
    strip_markers(sim, tmp_path / "bodies")
    assert main(["calibrate", str(tmp_path / "bodies"), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(tmp_path / "cal")]) == 0
    assert main(["diagnose", str(tmp_path / "bodies"), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                 "--out", str(tmp_path / "diag"), "--quiet", "--no-report", "--max-effects", "1"]) == 0
    truth = yaml.safe_load((sim / "truth.yaml").read_text())["effects"][0]["physics"]["actuator"]
    d = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert [(f["effect"], f["where"].get("actuator")) for f in d["findings"]] == [("backlash", truth)]
    assert d["noise_floor"] is not None
    cal = yaml.safe_load((tmp_path / "diag" / "calibration.yaml").read_text())
    assert sorted(cal["rigid_bodies"]["bodies"]) == ["T1", "T2"] and not cal.get("markers")


def test_the_floor_takes_the_points_noise_measured_on_the_stream_over_the_declared(diagnosed, tmp_path):
    """The noise floor judges the data: where the body stream can be measured, a declared
    ``rigid_body_noise`` ten times too large does not set the points' noise (the declaration serves
    calibrate's weights); without the stream's measure the points take the declared noise."""
    import shutil

    from platkit.diagnose.stream import stream_poses
    from platkit.io.calibration import read_calibration
    from platkit.io.session import load_session

    _, root = diagnosed
    folder = tmp_path / "declared"
    shutil.copytree(root / "bodies", folder)
    y = yaml.safe_load((folder / "session.yaml").read_text())
    y["rigid_body_noise"] = {"position_mm": 2.0, "rotation_deg": 1.0}  # about ten times the stream's noise
    (folder / "session.yaml").write_text(yaml.safe_dump(y, sort_keys=False))
    cal = read_calibration(str(root / "cal" / "calibration.yaml"))
    session = load_session(folder, spec=cal.spec, quiet=True)
    poses, _, noise = stream_poses(folder, session, cal)
    sig = poses.settling["point_sigma_m"]
    assert sorted(sig) == ["T1.o", "T1.x", "T1.y", "T2.o", "T2.x", "T2.y"]
    assert all(0.05e-3 < s < 0.6e-3 for s in sig.values()), sig  # measured (0.2 mm white), not 2 mm declared
    assert "measured" in noise, noise
