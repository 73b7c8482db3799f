"""Rigid bodies in a calibration from motion: the fit from motion reads markers alone, and says so.

A streamed session of the physical simulator with two rigid bodies (`platkit simulate --physics
--motion path --rigid-bodies 2`, 10 s at 40 Hz, every body seen at every sample): `platkit
calibrate` on it counts every body sample left out, per body, in report.json
(motion.samples.rigid_bodies_not_used), says why, warns, and names them in the summary line. A
session whose only measurements are bodies is refused in one line naming session.yaml.
"""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from platkit.calibrate.motion import calibrate_motion
from platkit.cli import main
from platkit.errors import BadSession
from platkit.io.session import load_session


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bodies") / "sim"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", "path", "--duration-s", "10",
                 "--rate-hz", "40", "--rigid-bodies", "2", "--seed", "4111", "--out", str(folder)]) == 0
    return folder


def test_bodies_left_out_of_a_fit_from_motion_are_counted_and_said(streamed, tmp_path, capsys):
    session = load_session(streamed)
    seen = np.isfinite(session.bodies).all(axis=2).sum(axis=0)  # (B,) samples of each body
    assert session.body_names == ["T1", "T2"] and seen.min() > 100
    out = tmp_path / "cal"
    capsys.readouterr()
    assert main(["calibrate", str(streamed), "--quiet", "--no-report", "--response-kind", "first-order",
                 "--out", str(out)]) == 0
    said = capsys.readouterr()
    report = json.loads((out / "report.json").read_text())
    unused = report["motion"]["samples"]["rigid_bodies_not_used"]
    assert unused["bodies"] == ["T1", "T2"]
    assert unused["per_body"] == {"T1": int(seen[0]), "T2": int(seen[1])}
    assert unused["n_body_samples"] == int(seen.sum())
    assert "markers alone" in unused["why"]
    line = [w for w in report["warnings"] if w.startswith("rigid bodies T1, T2 not used")]
    assert len(line) == 1 and f"{int(seen.sum())} body samples" in line[0]
    assert "rigid bodies T1, T2 not used" in said.err  # the warning printed
    assert f"rigid bodies T1, T2 not used ({int(seen.sum())} body samples)" in said.out  # the summary line


def test_a_stream_of_bodies_alone_is_refused_in_one_line(streamed):
    session = load_session(streamed)
    bodies_only = replace(session, marker_names=[], markers=np.zeros((len(session.marker_t), 0, 3)))
    with pytest.raises(BadSession) as err:
        calibrate_motion(bodies_only, session.spec)
    text = str(err.value)
    assert "\n" not in text and "session.yaml" in text and "T1, T2" in text and "reads markers" in text
