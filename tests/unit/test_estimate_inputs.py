"""What calibration takes from a user's own files: joint readings at a limit, URDF limits, and a fit
that stops without describing the data (issue 11: readings, limits, rms_after of tens of mm)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import MISFIT_ABSOLUTE_M, calibrate, fit_warnings, marker_noise_floor
from platkit.cli import main
from platkit.errors import BadDescription, BadSession
from platkit.geometry import matrix_from_quat
from platkit.io.session import load_session
from platkit.io.session_checks import STROKE_TOLERANCE
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.urdf import read_urdf

URDF = """<?xml version="1.0"?>
<robot name="lift">
  <link name="base"/><link name="carriage"/><link name="tool"/>
  <joint name="lift" type="prismatic">
    <parent link="base"/><child link="carriage"/><axis xyz="0 0 1"/>
    <limit lower="{lower}" upper="{upper}" effort="1" velocity="1"/>
  </joint>
  <joint name="turn" type="revolute">
    <parent link="carriage"/><child link="tool"/><origin xyz="0.1 0 0.05" rpy="0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/>
  </joint>
</robot>
"""


def _session(folder, urdf_text, lift_values, seed=0, sigma=1e-4):
    """A poses.csv session of the two-joint 'lift' URDF in metres, markers from the nominal stand."""
    folder.mkdir()
    (folder / "lift.urdf").write_text(urdf_text, encoding="utf-8")
    (folder / "session.yaml").write_text("platform: urdf\ndescription: lift.urdf\nunits: {length: m, time: s}\n"
                                         "markers: [A, B, C]\n", encoding="utf-8")
    rng = np.random.default_rng(seed)
    n = len(lift_values)
    U = np.column_stack([lift_values, rng.uniform(-1.5, 1.5, n)])
    spec = get_platform("urdf", folder / "lift.urdf")
    fb = PlatformModel(spec).forward_batch(np.column_stack([np.clip(U[:, 0], 0, 0.35), U[:, 1]]), strict=False)
    S = np.array([[0.05, 0.0, 0.0], [0.0, 0.05, 0.02], [0.0, 0.0, 0.08]])
    Y = fb.X[:, None] + np.einsum("nab,mb->nma", matrix_from_quat(fb.q), S) + rng.normal(0, sigma, (n, 3, 3))
    rows = ["t,lift,turn," + ",".join(f"{m}_{a}" for m in "ABC" for a in "xyz")]
    rows += [",".join(f"{v:.10g}" for v in [k, *u, *y.ravel()]) for k, (u, y) in enumerate(zip(U, Y))]
    (folder / "poses.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    return folder


def _lifts(n=24, top=0.35):
    return np.linspace(0.0, top, n)


def test_a_reading_a_fraction_past_a_limit_is_kept_with_a_warning(tmp_path):
    lifts = _lifts()
    lifts[5] = 0.350181  # the TIAGo torso against its 0.35 m limit
    folder = _session(tmp_path / "s", URDF.format(lower=0, upper=0.35), lifts)
    s = load_session(folder)
    assert s.poses["controls"][5, 0] == pytest.approx(0.350181, abs=1e-12)  # kept as recorded
    (note,) = s.extras["control_notes"]
    assert "poses.csv row 6 (line 7) column 'lift'" in note
    assert "0.350181 is past the limit 0.35 m" in note and "kept as recorded" in note


def test_the_warning_reaches_the_report(tmp_path, capsys):
    lifts = _lifts()
    lifts[3] = 0.3501
    folder = _session(tmp_path / "s", URDF.format(lower=0, upper=0.35), lifts)
    assert main(["calibrate", str(folder), "--no-selection", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "platkit: warning:" in err and "0.3501 is past the limit 0.35 m" in err
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert any("0.3501 is past the limit" in w for w in rep["warnings"])
    written = yaml.safe_load((tmp_path / "o" / "calibration.yaml").read_text())
    assert any("0.3501 is past the limit" in w for w in written["warnings"])


def test_a_reading_far_past_a_limit_stays_an_error(tmp_path):
    lifts = _lifts()
    lifts[7] = 0.35 + 2 * STROKE_TOLERANCE * 0.35
    folder = _session(tmp_path / "s", URDF.format(lower=0, upper=0.35), lifts)
    where = r"poses\.csv row 8 \(line 9\) column 'lift'"
    with pytest.raises(BadSession, match=where + r": 0\.357 is outside the stroke \[0, 0\.35\] m"):
        load_session(folder)


def test_a_urdf_limit_with_lower_above_upper_is_one_line(tmp_path):
    path = tmp_path / "lift.urdf"
    path.write_text(URDF.format(lower=0.35, upper=0), encoding="utf-8")
    with pytest.raises(BadDescription, match=r"joint 'lift' <limit lower='0.35' upper='0'>: lower is above upper"):
        read_urdf(path)
    path.write_text(URDF.format(lower=0, upper=0), encoding="utf-8")  # the URDF's 'no limit' stays so
    assert np.isinf(read_urdf(path).joints["lift"].upper)


def test_the_noise_floor_comes_from_the_distances_between_markers(tmp_path):
    folder = _session(tmp_path / "s", URDF.format(lower=0, upper=0.35), _lifts(60), sigma=3e-4)
    s = load_session(folder)
    p = s.poses
    poses = PoseSet("urdf", p["controls"], p["markers"], ["A", "B", "C"], length_unit="m")
    assert marker_noise_floor(poses) == pytest.approx(3e-4, rel=0.3)


def test_a_fit_that_stops_far_above_the_noise_warns_what_to_check(tmp_path, capsys):
    folder = _session(tmp_path / "s", URDF.format(lower=0, upper=0.35), _lifts(30))
    s = load_session(folder)
    p = s.poses
    good = PoseSet("urdf", p["controls"], p["markers"], ["A", "B", "C"], length_unit="m")
    cal = calibrate(good, s.spec)
    assert cal.converged and fit_warnings(cal, good) == [] and cal.warnings == []
    # the controls in the wrong order: a plausible-looking session the model cannot describe
    swapped = PoseSet("urdf", p["controls"][:, ::-1] * [0.1, 1], p["markers"], ["A", "B", "C"], length_unit="m")
    bad = calibrate(swapped, s.spec, free=[])
    assert bad.rms_after > MISFIT_ABSOLUTE_M
    (warning,) = bad.warnings
    assert warning.startswith(f"rms_after {bad.rms_after:.4g} m is far above any measurement noise")
    assert "control columns are in the stand's order and units" in warning
