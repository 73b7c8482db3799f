"""One tolerance policy for a control reading at a limit (platkit.limits), the same in every verb:
past a limit within the recording tolerance (1% of the stroke) a warning with the same text
everywhere, further out a refusal whose hint is true to the unit."""
from __future__ import annotations

import html
import json
import re
import warnings

import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.errors import BadInput, BadSession, OutOfWorkspace
from platkit.io.session import example_session
from platkit.kinematics import PlatformModel
from platkit.limits import check_strokes
from platkit.notices import PlatkitWarning
from platkit.plugins import get_platform

#: stewart's legs: stroke [3295, 4795] mm, so the recording tolerance is 15 mm
NEUTRAL = [4000.0] * 6


def _policy(U_mm):
    spec = get_platform("stewart")
    said = []
    check_strokes(spec, np.asarray(U_mm) * 1e-3, np.asarray(U_mm), "mm", lambda r, c: f"row {r} {c}", BadSession,
                  "session.yaml declares mm", said.append)
    return said


def test_inside_nothing_within_the_tolerance_a_warning_beyond_a_refusal():
    assert _policy([NEUTRAL, [4795.0] + NEUTRAL[1:]]) == []
    (said,) = _policy([NEUTRAL, [4800.0] + NEUTRAL[1:], [4798.0] + NEUTRAL[1:]])
    assert said.startswith("row 1 L1: 4800 is past the limit 4795 mm by 5 mm (2 rows past a limit, this one the furthest)")
    assert "within the recording tolerance (15 mm, 1% of the stroke [3295, 4795] mm" in said
    with pytest.raises(BadSession) as err:
        _policy([NEUTRAL, [4815.0] + NEUTRAL[1:]])
    msg = str(err.value)
    assert msg.startswith("row 1 L1: 4815 is outside the stroke [3295, 4795] mm: 20 mm past the limit 4795, "
                          "more than the recording tolerance (15 mm, 1% of the stroke)")
    assert "fits the stroke in" not in msg  # 4815 mm read as metres is no stroke either: no false hint


def test_the_unit_hint_only_where_the_value_is_in_the_other_unit():
    with pytest.raises(BadSession, match=r"4\.5 is outside .*; the value fits the stroke in m, but session.yaml "
                                         r"declares mm$"):
        _policy([[4.5] + NEUTRAL[1:]])
    # a reading just past the limit (the TIAGo torso: 0.3502 m against 0.35) is never "in mm"
    spec = get_platform("psvr")
    c = spec.controls[0]
    v = c.upper + 0.002 * (c.upper - c.lower)
    said = []
    U = np.array([[c.neutral for c in spec.controls]])
    U[0, 0] = v
    check_strokes(spec, U, U, "mm", lambda r, n: n, BadInput, "x", said.append)
    assert len(said) == 1 and "fits the stroke" not in said[0]


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    out = tmp_path_factory.mktemp("limits") / "cal"
    assert main(["calibrate", "--platform", "stewart", "--free", "none", "--out", str(out), "--quiet",
                 "--no-report"]) == 0
    return out / "calibration.yaml"


def _tail(line: str) -> str:
    """The policy's sentence without the place it names."""
    return re.sub(r"^.*?: (?=\d)", "", line)


def test_the_same_warning_in_every_verb(calibration, tmp_path, capsys):
    commands = tmp_path / "commands.csv"
    commands.write_text("L1,L2,L3,L4,L5,L6\n4000,4000,4000,4000,4000,4000\n4805,4000,4000,4000,4000,4000\n")
    assert main(["predict", "--calibration", str(calibration), "--commands", str(commands),
                 "--out", str(tmp_path / "p.csv")]) == 0
    predict_err = capsys.readouterr().err
    rows = (tmp_path / "p.csv").read_text().splitlines()
    assert len(rows) == 3 and "" not in rows[2].split(",")  # predicted, not left empty
    assert main(["fk", "--platform", "stewart", "--u", "4805,4000,4000,4000,4000,4000"]) == 0
    fk_err = capsys.readouterr().err
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        PlatformModel(get_platform("stewart")).forward_batch(np.array([NEUTRAL, [4805.0] + NEUTRAL[1:]]) * 1e-3)
    (model_warning,) = [str(w.message) for w in caught if issubclass(w.category, PlatkitWarning)]
    lines = [predict_err.strip(), fk_err.strip(), model_warning]
    assert predict_err.startswith(f"platkit: warning: {commands} row 2 (line 3) column 'L1': 4805 is past")
    assert fk_err.startswith("platkit: warning: stewart: control L1: 4805 is past")
    assert len({_tail(x) for x in lines}) == 1, lines
    assert _tail(model_warning).startswith("4805 is past the limit 4795 mm by 10 mm; kept as recorded")


def test_the_same_refusal_in_every_verb(calibration, tmp_path, capsys):
    commands = tmp_path / "commands.csv"
    commands.write_text("L1,L2,L3,L4,L5,L6\n4830,4000,4000,4000,4000,4000\n")
    assert main(["predict", "--calibration", str(calibration), "--commands", str(commands),
                 "--out", str(tmp_path / "p.csv")]) == 2
    predict_err = capsys.readouterr().err
    assert not (tmp_path / "p.csv").exists()
    assert main(["fk", "--platform", "stewart", "--u", "4830,4000,4000,4000,4000,4000"]) == 1
    fk_err = capsys.readouterr().err
    with pytest.raises(OutOfWorkspace) as err:
        PlatformModel(get_platform("stewart")).forward(np.array([4830.0] + NEUTRAL[1:]) * 1e-3)
    tails = {_tail(x.strip()) for x in (predict_err, fk_err, str(err.value))}
    assert tails == {"4830 is outside the stroke [3295, 4795] mm: 35 mm past the limit 4795, more than the "
                     "recording tolerance (15 mm, 1% of the stroke)"}


def test_calibrate_reads_the_session_under_the_same_policy(tmp_path, capsys):
    folder = tmp_path / "s"
    src = example_session("stewart")
    folder.mkdir()
    for f in src.iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
    lines = (folder / "commands.csv").read_text().splitlines()
    cells = lines[2].split(",")
    cells[1] = "4805.000"
    lines[2] = ",".join(cells)
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--free", "none", "--out", str(out), "--quiet", "--no-report"]) == 0
    err = capsys.readouterr().err
    assert "column 'L1': 4805 is past the limit 4795 mm by 10 mm; kept as recorded" in err
    rep = json.loads((out / "report.json").read_text())
    assert any("4805 is past the limit 4795 mm" in w for w in rep["warnings"])


def test_diagnose_says_the_reading_and_writes_it_in_its_reports(tmp_path, capsys):
    import shutil

    folder = tmp_path / "s"
    shutil.copytree(example_session("rotary"), folder)
    lines = (folder / "commands.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[2] = "90.5"  # u2's stroke is [-90, 90] deg: 0.5 deg past, within the 1.8 deg tolerance
    lines[3] = ",".join(cells)
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "cal"), "--quiet", "--no-report",
                 "--no-selection"]) == 0
    capsys.readouterr()
    out = tmp_path / "diag"
    assert main(["diagnose", str(folder), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                 "--out", str(out), "--quiet"]) == 0
    said = (f"{folder / 'commands.csv'} row 3 (line 4) column 'u2': 90.5 is past the limit 90 deg by 0.5 deg; "
            "kept as recorded")
    assert f"platkit: warning: {said}" in capsys.readouterr().err
    assert any(w.startswith(said) for w in json.loads((out / "diagnosis.json").read_text())["warnings"])
    assert html.escape(said) in (out / "report.html").read_text()


@pytest.mark.parametrize("physics", [False, True])
def test_simulate_says_a_plan_row_past_a_limit_once(tmp_path, capsys, physics):
    """simulate --plan FILE: a row within the recording tolerance is said once, by file, row and
    column (the plan's reader), not a second time by the simulator."""
    plan = tmp_path / "plan.csv"
    plan.write_text("A,B,C\n2047.2,2047.2,2047.2\n2850,2047.2,2047.2\n1900,2100,2000\n2000,2000,2000\n")
    out = tmp_path / "s"
    args = ["simulate", "--platform", "psvr", "--plan", str(plan), "--out", str(out)] + (["--physics"] if physics else [])
    assert main(args) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if line.startswith("platkit: warning:")]
    assert len(said) == 1 and "plan.csv row 2 (line 3) column 'A': 2850 is past the limit" in said[0], said
    notes = yaml.safe_load((out / "session.yaml").read_text())["notes"]
    assert "warning: " + said[0].removeprefix("platkit: warning: ") in notes


def test_calibrate_from_motion_says_the_reading_and_reports_it(tmp_path, capsys):
    """A stream without holds goes to the calibration from motion: the reading's warning (a control
    just past its limit) is said and reported there as on the settled path."""
    from platkit.simulate.physics import simulate_physics, write_physical_session

    sim = simulate_physics(get_platform("rotary"), seed=4101, motion="multisine", duration_s=6.5, mocap_rate_hz=40.0)
    folder = write_physical_session(sim, tmp_path / "s")
    lines = (folder / "commands.csv").read_text().splitlines()
    cells = lines[5].split(",")
    cells[2] = "90.5"  # u2's stroke is [-90, 90] deg: 0.5 deg past, within the 1.8 deg tolerance
    lines[5] = ",".join(cells)
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "o"
    assert main(["calibrate", str(folder), "--free", "none", "--response-kind", "first-order", "--out", str(out),
                 "--quiet", "--no-report"]) == 0
    said = (f"{folder / 'commands.csv'} row 5 (line 6) column 'u2': 90.5 is past the limit 90 deg by 0.5 deg; "
            "kept as recorded")
    err = capsys.readouterr().err
    assert f"platkit: warning: {said}" in err and "calibrated from the whole stream" in err
    assert sum(w.startswith(said) for w in json.loads((out / "report.json").read_text())["warnings"]) == 1
