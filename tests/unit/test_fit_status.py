"""No silent wrong answer from calibrate: a rigid body's quaternion in another order is refused
naming it, rejected body observations are counted and warned like markers', a fit that does not
converge (or ends worse than its start) exits 1 with its outputs whole and the warning in the
report, and every warning said while the verb ran is in report.json and report.html."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from platkit.cli import main
from platkit.commands.calibrate import fit_failure
from platkit.plugins import get_platform

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_rigid_bodies import BodyTruth, _write_session  # noqa: E402


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


def _body_session(folder, stewart, seed=9, n=30, order=(3, 4, 5, 6), spoil=()):
    truth = BodyTruth(stewart, seed=seed)
    U, bodies = truth.bodies(truth.controls(n))
    bodies = np.concatenate([bodies[..., :3], bodies[..., list(order)]], axis=2)
    for k in spoil:  # a few orientations from elsewhere
        bodies[k, 0, 3:] = [0.5, 0.5, 0.5, 0.5]
    return _write_session(folder, stewart, U, bodies, ["T1"], noise=False)


def test_a_quaternion_written_scalar_last_is_refused_naming_the_order(stewart, tmp_path, capsys):
    folder = _body_session(tmp_path / "s", stewart, order=(4, 5, 6, 3))  # x,y,z,w under qw,qx,qy,qz
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and not out.exists()
    assert err.startswith(f"platkit: error: {folder}: rigid body 'T1': ")
    assert "orientations rejected as outliers" in err
    assert "read as x,y,z,w (scalar last) they do" in err and "write them as qw,qx,qy,qz" in err


def test_the_same_session_in_the_spec_order_calibrates(stewart, tmp_path):
    folder = _body_session(tmp_path / "s", stewart)
    # report.json is read (the next test reads a body session's report.html)
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--no-report", "--out",
                 str(tmp_path / "o")]) == 0
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert not any("rigid body" in w for w in rep["warnings"])


def test_rejected_body_observations_are_counted_and_warned(stewart, tmp_path, capsys):
    folder = _body_session(tmp_path / "s", stewart, spoil=(2, 6, 9, 13, 15, 21, 27))
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "7 rigid-body observations rejected as outliers (T1 7 of 30)" in captured.out
    assert "(30 poses, 0 markers, 1 rigid body (rho " in captured.out  # one body said in the singular
    said = "rigid body T1: 7 of its 30 observations rejected as outliers"
    assert f"platkit: warning: {said}" in captured.err
    rep = json.loads((out / "report.json").read_text())
    assert any(w.startswith(said) for w in rep["warnings"])
    assert said in (out / "report.html").read_text()


def test_a_warning_said_on_stderr_is_in_both_reports(stewart, tmp_path, capsys):
    folder = _body_session(tmp_path / "s", stewart)
    out = tmp_path / "o"
    rc = main(["calibrate", "--platform", "rotary", "--method", "paper", "--max-evaluations", "10", "--out", str(out),
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1
    last = err.strip().splitlines()[-1]
    assert last.startswith("platkit: error: not converged: --method paper stopped after")
    assert last.endswith(f"the outputs in {out} are written for inspection only")
    rep = json.loads((out / "report.json").read_text())  # written whole
    assert rep["converged"] is False
    assert any(w.startswith("not converged: --method paper stopped after") for w in rep["warnings"])
    assert "not converged: --method paper" in (out / "report.html").read_text()
    assert (out / "calibration.yaml").is_file()
    # the rigid bodies --method paper leaves out: said on stderr and written in the reports
    _with_markers(folder)
    out2 = tmp_path / "o2"
    assert main(["calibrate", str(folder), "--method", "paper", "--max-evaluations", "10", "--out", str(out2),
                 "--quiet"]) == 1
    err = capsys.readouterr().err
    said = "rigid bodies T1 left out: --method paper reads the markers only"
    assert f"platkit: warning: {said}" in err
    assert said in json.loads((out2 / "report.json").read_text())["warnings"]
    assert said in (out2 / "report.html").read_text()


def test_the_paper_method_refuses_a_session_of_rigid_bodies_alone_as_bad_input(stewart, tmp_path, capsys):
    # it reads markers only and needs three for its marker frame: the option cannot serve the
    # session, known before any work, so exit 2 with one line naming the session, nothing written
    folder = _body_session(tmp_path / "s", stewart)
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--method", "paper", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "rigid bodies T1 left out: --method paper reads the markers only" in err
    lines = [ln for ln in err.splitlines() if ln.startswith("platkit: error:")]
    assert len(lines) == 1 and "--method paper needs at least 3 markers" in lines[0]
    assert "the session has 0" in lines[0] and str(folder) in lines[0]
    assert not out.exists()


def _with_markers(folder):
    """Three markers on the body (0.1 m along each of its axes) added to the session's poses.csv."""
    lines = (folder / "poses.csv").read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("T1_x")
    rows = []
    for line in lines[1:]:
        cells = line.split(",")
        o = np.array([float(c) for c in cells[k:k + 3]])
        w, x, y, z = (float(c) for c in cells[k + 3:k + 7])
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        rows.append(cells + [f"{v:.6f}" for a in range(3) for v in o + 100.0 * R[:, a]])
    header += [f"P{a}_{c}" for a in range(1, 4) for c in "xyz"]
    (folder / "poses.csv").write_text("\n".join(",".join(r) for r in [header] + rows) + "\n")
    yaml = (folder / "session.yaml").read_text().replace("markers: []", "markers: [P1, P2, P3]")
    (folder / "session.yaml").write_text(yaml)


def test_fit_failure_names_what_went_wrong():
    cal = SimpleNamespace(length_unit="mm", rms_before=1.148e-3, rms_after=1.319e-3, method="paper", iterations=3201, warnings=[],
                          converged=True)
    assert fit_failure(cal) == ("not converged to a better fit: --method paper ended worse than its start "
                                "(rms 1.148 -> 1.319 mm)")
    cal.converged = False
    assert fit_failure(cal).startswith("not converged: --method paper stopped after 3201 evaluations")
    cal.converged, cal.rms_after = True, 0.9e-3
    assert fit_failure(cal) is None
