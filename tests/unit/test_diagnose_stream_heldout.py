"""platkit diagnose of a stream without holds against a held-out stream of the same stand.

A 12 s path of the physical simulator (`platkit simulate --physics --motion path`, seed 4111, 0.2 mm
white noise) cut in time (tests/stream_split.py): the first 65 % calibrated from motion (a second-order
response with its delays and rate limits, which this stand's drives have), the rest held out. The
held-out stream has no settled holds (its last command's hold alone settles): diagnose reads it as a
stream, its windows cut once by the calibration given, each model reading the controls through its
own response; the markers' noise is measured on the stream, so the floor exists; the verdict speaks
of windowed poses.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from stream_split import split_stream

from platkit.cli import main

PATH = ["--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "12", "--rate-hz", "40",
        "--noise-mm", "0.2", "--white-noise", "--seed", "4111"]
RESPONSE = ["--response-kind", "second-order", "--response", "delays,rate-limit"]


@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    root = tmp_path_factory.mktemp("stream_heldout")
    assert main(["simulate", *PATH, "--out", str(root / "sim")]) == 0
    train, held = split_stream(root / "sim", root, 0.65)
    assert main(["calibrate", str(train), "--quiet", "--no-report", *RESPONSE, "--out", str(root / "cal")]) == 0
    return root, train, held


def _diagnose(root, train, held, out, *extra):
    return main(["diagnose", str(train), "--calibration", str(root / "cal" / "calibration.yaml"), "--heldout",
                 str(held), "--out", str(root / out), "--quiet", "--no-report", "--max-effects", "1", *extra])


def test_a_heldout_stream_is_scored_on_its_windows(streams, capsys):
    """Before, the held-out stream was read as settled poses: its last hold alone settled, and the
    held-out session was one pose; and the training stream's markers had no noise, so no floor."""
    root, train, held = streams
    capsys.readouterr()
    assert _diagnose(root, train, held, "diag") == 0
    err = capsys.readouterr().err
    assert err.count("the held-out stream scored on its") == 1, err
    assert err.count("the markers' noise measured on the stream") == 2, err  # the training and held-out streams
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    h = d["heldout_session"]
    assert h["n_poses"] >= 10, h  # ~3 windowed poses a second of the held-out stream, not its one settled hold
    assert 0.02 < h["rms_before"] < 0.5 and 0.02 < h["rms_after"] < 0.5, h  # mm: predicted, not off the stream
    assert d["noise_floor"] is not None and 0.05 < d["noise_floor"] < 0.3, d["noise_floor"]
    assert d["findings"] == []  # a clean stream with the stand's response: nothing named
    assert "windowed poses" in d["verdict"] and "settled poses" not in d["verdict"], d["verdict"]
    assert "actuator_response" in yaml.safe_load((root / "diag" / "calibration.yaml").read_text())


def test_each_model_reads_the_heldout_stream_through_its_own_response(streams):
    """The held-out windows are cut once by the calibration given; a model's controls at them are its
    own response's (a shift moved 20 ms moves them, the given response's are the windows' own), with
    no node left (the session diagnosed's response term adds nothing to another recording); and
    each model is scored on those controls."""
    from dataclasses import replace

    from platkit.calibrate.estimate import point_errors
    from platkit.diagnose.stream import heldout_stream, read_through, score_heldout_stream
    from platkit.io.calibration import read_calibration
    from platkit.io.session import load_session

    root, train, held = streams
    cal = read_calibration(str(root / "cal" / "calibration.yaml"))
    with pytest.warns(Warning, match="the held-out stream scored on its"):
        h = heldout_stream(held, load_session(held, spec=cal.spec, quiet=True), cal)
    theta = h.term.initial.copy()
    k = h.term.parameter_names.index("shift_s")
    moved = theta.copy()
    moved[k] += 0.02
    with_given = replace(cal, terms=[*cal.terms, h.term], theta=[*cal.theta, theta],
                         theta_std=[*cal.theta_std, np.full(len(theta), np.nan)])
    with_moved = replace(with_given, theta=[*cal.theta, moved])
    given = read_through(h, with_given, cal.spec)
    assert "node" not in given.extras
    np.testing.assert_allclose(given.controls, h.poses.controls, rtol=0, atol=1e-12)
    later = read_through(h, with_moved, cal.spec)
    assert np.abs(later.controls - given.controls).max() > 1e-4  # m: the path moves tens of mm a second
    np.testing.assert_array_equal(later.markers, given.markers)  # the same windows for every model
    s = score_heldout_stream(with_given, with_moved, h, cal.spec, [])
    e0, e1 = point_errors(cal, given), point_errors(cal, later)
    assert s["rms_before"] == pytest.approx(np.sqrt(np.nanmean(e0 ** 2)))
    assert s["rms_after"] == pytest.approx(np.sqrt(np.nanmean(e1 ** 2)))
    assert s["rms_after"] > s["rms_before"]  # 20 ms late is worse than the calibrated response
    assert s["n_poses"] == h.poses.n_poses


def test_a_heldout_stream_is_reregistered(streams):
    """--heldout-register K on a held-out stream: blocks of K windowed poses re-register each model,
    the controls again through its own response."""
    root, train, held = streams
    assert _diagnose(root, train, held, "diag_reg", "--heldout-register", "5") == 0
    r = json.loads((root / "diag_reg" / "diagnosis.json").read_text())["heldout_session"]["registered"]
    assert r["k"] == 5 and r["n_registrations"] >= 2, r
    assert 0.0 < r["rms_before"] < 0.5 and 0.0 < r["rms_after"] < 0.5, r


def test_markers_noise_is_measured_marker_by_marker(streams):
    """Each marker's noise per coordinate on the stream: 0.2 mm white in the simulator."""
    from platkit.diagnose.stream import marker_sigmas
    from platkit.io.session import load_session

    root, train, _ = streams
    sig = marker_sigmas(load_session(train, quiet=True))
    assert sorted(sig) == [f"M{k}" for k in range(1, 6)]
    assert all(1.6e-4 < s < 2.5e-4 for s in sig.values()), sig


def test_a_heldout_stream_with_a_calibration_not_from_motion_is_refused(tmp_path, capsys):
    """A calibration of settled holds has no response to read a held-out stream through: one line."""
    assert main(["simulate", "--platform", "stewart", "--poses", "20", "--seed", "4111", "--out",
                 str(tmp_path / "holds")]) == 0
    assert main(["calibrate", str(tmp_path / "holds"), "--quiet", "--no-report", "--out", str(tmp_path / "cal")]) == 0
    assert main(["simulate", *PATH, "--out", str(tmp_path / "sim")]) == 0
    _, held = split_stream(tmp_path / "sim", tmp_path, 0.65)
    capsys.readouterr()
    rc = main(["diagnose", str(tmp_path / "holds"), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
               "--heldout", str(held), "--out", str(tmp_path / "diag"), "--quiet", "--no-report"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1 and len(err) == 1, err
    assert "a held-out stream without settled holds is read through the actuator response" in err[0], err


def test_a_lack_of_fit_on_a_stream_speaks_of_windowed_poses_and_the_response(streams):
    """The unexplained finding of a geometric model held out at 2.5 times the floor (a first-order
    response on this stream did so on a development run): on the stream's windowed poses it speaks
    of them and of the calibrated response, whose misfit shows there too; on settled poses as before."""
    from types import SimpleNamespace

    from platkit.diagnose.fitting import Options
    from platkit.diagnose.floor import pose_words
    from platkit.diagnose.lack_of_fit import lack_of_fit
    from platkit.diagnose.stream import training_stream
    from platkit.io.calibration import read_calibration
    from platkit.io.session import load_session

    root, train, _ = streams
    cal = read_calibration(str(root / "cal" / "calibration.yaml"))
    with pytest.warns(Warning, match="no settled holds: diagnosed on the stream's"):
        poses = training_stream(train, load_session(train, spec=cal.spec, quiet=True), cal)[0]
    settled = poses.subset(np.arange(poses.n_poses))
    settled.extras = {k: v for k, v in poses.extras.items() if k != "node"}
    assert (pose_words(poses), pose_words(settled)) == ("windowed poses", "settled poses")
    cur = SimpleNamespace(r=np.zeros((poses.n_poses, poses.n_markers, 3)), cv_rms=2.5e-4)
    for p, words, response in ((poses, "windowed poses", True), (settled, "settled poses", False)):
        f = lack_of_fit(cur, p, 1e-4, 2.5e-4, Options(), lambda line: None)[0]
        assert f is not None and f.effect == "unexplained"
        assert f"the noise floor of these {words}" in f.evidence, f.evidence
        assert ("calibrated actuator response" in f.evidence) is response, f.evidence
