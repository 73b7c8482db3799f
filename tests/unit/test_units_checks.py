"""Plausibility checks of units judge only where the data can tell, and every one can be answered
(--units-checked): a stationary stream is not refused for its gyro's unit; a gyro in deg/s that
turns gravity is refused with a line that says how to answer; answered, the data are kept with a
warning that reaches the report."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from platkit.cli import main
from platkit.errors import BadSession
from platkit.io.imu import (
    DEG_RATIO_TOLERANCE,
    MIN_R2_FOR_RATIO,
    MIN_TILT_FOR_RATIO,
    gravity_turn_fit,
    read_imu_csv,
    write_imu_csv,
)
from platkit.io.session import example_session
from platkit.notices import units_checked

SESSION = "platform: none\nunits: {length: m, time: s}\nmarkers: []\n"


def _session(folder, t, gyr, acc):
    folder.mkdir(parents=True)
    (folder / "session.yaml").write_text(SESSION)
    write_imu_csv(folder / "imu.csv", t, gyr, acc)
    return folder


def _stationary():
    """Ten minutes at rest: a gyro bias of 0.02 rad/s and a gravity direction that drifts a
    little (a thermal tilt), under the accelerometer's noise."""
    rng = np.random.default_rng(7)
    n = 60000
    t = np.arange(n) / 100.0
    gyr = np.array([0.02, 0.0, 0.0]) + 0.003 * rng.standard_normal((n, 3))
    ang = 0.0129 * 0.02 * t
    acc = 9.81 * np.column_stack([np.zeros(n), np.sin(ang), np.cos(ang)]) + 0.05 * rng.standard_normal((n, 3))
    return t, gyr, acc


def _turning(deg: bool):
    """A minute of slow turns about x (gravity turns with them); the gyro in rad/s or deg/s."""
    n = 6000
    t = np.arange(n) / 100.0
    ang = 0.3 * np.sin(2 * np.pi * t / 7.0)
    rate = 0.3 * 2 * np.pi / 7.0 * np.cos(2 * np.pi * t / 7.0)  # at most 15.4 deg/s: within a gyro's range
    gyr = np.column_stack([rate, np.zeros(n), np.zeros(n)]) * (180 / np.pi if deg else 1.0)
    # the sensor turns by ang about x: gravity in the sensor's axes turns by -ang
    acc = 9.81 * np.column_stack([np.zeros(n), np.sin(ang), np.cos(ang)])
    return t, gyr, acc


def test_a_stationary_stream_is_not_judged_by_its_gravity_ratio(tmp_path, capsys):
    t, gyr, acc = _stationary()
    k, tilt, r2 = gravity_turn_fit(t, gyr, acc)
    # the ratio alone looks like deg/s (the refusal a real resting BROAD sensor met), but the gyro's
    # rotations explain almost none of the gravity direction's changes: nothing to judge
    assert np.pi / 180 / DEG_RATIO_TOLERANCE <= k <= np.pi / 180 * DEG_RATIO_TOLERANCE and tilt >= MIN_TILT_FOR_RATIO
    assert r2 < MIN_R2_FOR_RATIO
    folder = _session(tmp_path / "rest", t, gyr, acc)
    assert main(["orient", str(folder), "--out", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    note = "would say deg/s, but the stream cannot tell: its rotations explain 1% of the gravity direction's changes"
    assert note in err
    assert any(note in w for w in json.loads((tmp_path / "o" / "report.json").read_text())["warnings"])


def test_a_gyro_in_deg_s_is_refused_with_the_answer_and_answered_kept(tmp_path, capsys):
    folder = _session(tmp_path / "deg", *_turning(deg=True))
    assert main(["orient", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"platkit: error: {folder / 'imu.csv'}: columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro turns")
    assert "(that is deg/s: multiply by pi/180)" in err
    assert err.endswith("if the file is right as written, run again with --units-checked") and "\n" not in err
    assert not (tmp_path / "o").exists()
    assert main(["orient", str(folder), "--out", str(tmp_path / "o"), "--units-checked"]) == 0
    err = capsys.readouterr().err
    assert "that is deg/s" in err and "(kept as written: --units-checked)" in err
    assert any("--units-checked" in w for w in json.loads((tmp_path / "o" / "report.json").read_text())["warnings"])


def test_rad_s_turning_passes_without_a_note(tmp_path):
    folder = _session(tmp_path / "rad", *_turning(deg=False))
    stream = read_imu_csv(folder / "imu.csv")
    assert stream.notes == []


def test_an_accelerometer_in_g_is_answerable(tmp_path):
    t, gyr, acc = _turning(deg=False)
    folder = _session(tmp_path / "g", t, gyr, acc / 9.80665)
    with pytest.raises(BadSession, match=r"\(that is g: multiply by 9\.80665\); expected m/s\^2, about 9\.81 at "
                                         r"rest; if the file is right as written, run again with --units-checked$"):
        read_imu_csv(folder / "imu.csv")
    with units_checked():
        stream = read_imu_csv(folder / "imu.csv")
    assert any("that is g" in n and "--units-checked" in n for n in stream.notes)


def test_marker_lengths_in_the_wrong_unit_are_answerable(tmp_path, capsys):
    folder = tmp_path / "s"
    shutil.copytree(example_session("stewart"), folder)
    lines = (folder / "markers.csv").read_text().splitlines()
    scaled = [lines[0]] + [",".join([c[0]] + [f"{1000 * float(v):.3f}" if v else "" for v in c[1:]])
                           for c in (x.split(",") for x in lines[1:])]
    (folder / "markers.csv").write_text("\n".join(scaled) + "\n")  # micrometres in a session of mm
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "o"), "--quiet", "--no-report"]) == 2
    err = capsys.readouterr().err
    assert "is beyond any motion-capture volume; is the file in mm?" in err and "--units-checked" in err
