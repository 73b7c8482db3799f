"""`platkit predict` from a user's point of view: commands outside a stroke (a length in the
wrong unit, a typo) and times that run backwards are bad input, named by row and column, as in a
session's commands.csv; nothing is written."""
import pytest

from platkit.cli import main


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal")
    # predict reads calibration.yaml alone (test_thermal_warmup.py renders this calibration's report.html)
    assert main(["calibrate", "--platform", "psvr", "--quiet", "--no-report", "--out", str(out)]) == 0
    return str(out / "calibration.yaml")


def _predict(calibration, tmp_path, text):
    (tmp_path / "commands.csv").write_text(text)
    out = tmp_path / "p.csv"
    rc = main(["predict", "--calibration", calibration, "--commands", str(tmp_path / "commands.csv"), "--out", str(out)])
    return rc, out


@pytest.mark.parametrize("text, expected", [
    ("A,B,C\n2047.2,2047.2,9000\n", "row 1 (line 2) column 'C': 9000 is outside the stroke [1247.2, 2847.2] count"),
    ("t,A,B,C\n1,2047.2,2047.2,2047.2\n0,2047.2,2047.2,2047.2\n", "row 2 (line 3) column 't': 0 is earlier than the row before"),
    ("t,A,B,C\n0,2047.2,2047.2,2047.2\n,2047.2,2047.2,2047.2\n", "row 2 (line 3) column 't': empty or nan"),
    ("A,B,C\n2047.2,nan,2047.2\n", "row 1 (line 2) column 'B': the control is empty or nan"),
])
def test_bad_commands_are_bad_input(calibration, tmp_path, capsys, text, expected):
    rc, out = _predict(calibration, tmp_path, text)
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not out.exists()


def test_good_commands_give_one_row_each_in_the_spec_columns(calibration, tmp_path, capsys):
    rc, out = _predict(calibration, tmp_path, "t,A,B,C\n0,2047.2,2047.2,2047.2\n1,1900,2100,2000\n")
    assert rc == 0
    lines = out.read_text().splitlines()
    markers = [f"M{i}_{a}" for i in range(1, 6) for a in "xyz"]
    assert lines[0].split(",") == ["A", "B", "C", *markers, "x", "y", "z", "qw", "qx", "qy", "qz"]
    assert len(lines) == 3 and all("" not in line.split(",") for line in lines[1:])


TERMS = """terms:
- effect: backlash
  where: {actuator: A, actuator_index: 0, unit: count}
  parameters:
    half_play: {value: 2.0, std: 0.1, unit: count}
- effect: thermal_drift
  where: {time: 'the whole session, linear in the time since its first command'}
  parameters:
    vx: {value: 1.0e-05, std: 1.0e-07, unit: m/s}
    vy: {value: 0.0, std: 1.0e-07, unit: m/s}
    vz: {value: 0.0, std: 1.0e-07, unit: m/s}
"""


def _with_terms(calibration, tmp_path, terms):
    text = open(calibration).read()
    assert "terms: []\n" in text
    path = tmp_path / "calibration.yaml"
    path.write_text(text.replace("terms: []\n", terms))
    return str(path)


def test_a_time_dependent_model_needs_t(calibration, tmp_path, capsys):
    cal = _with_terms(calibration, tmp_path, TERMS)
    rc, out = _predict(cal, tmp_path, "A,B,C\n2047.2,2047.2,2047.2\n1900,2100,2000\n")
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no 't' column" in err[0] and "(thermal_drift)" in err[0], err
    assert not out.exists()
    rc, out = _predict(cal, tmp_path, "t,A,B,C\n0,2047.2,2047.2,2047.2\n100,1900,2100,2000\n")
    assert rc == 0


def test_a_history_only_model_takes_rows_without_t(calibration, tmp_path, capsys):
    backlash_only = TERMS.split("- effect: thermal_drift")[0]
    cal = _with_terms(calibration, tmp_path, backlash_only)
    rc, out = _predict(cal, tmp_path, "A,B,C\n2047.2,2047.2,2047.2\n1900,2100,2000\n")
    assert rc == 0 and len(out.read_text().splitlines()) == 3


def test_rows_without_a_solution_are_said_once_through_the_notices(calibration, tmp_path, capsys, monkeypatch):
    """The verb's own warnings take the one route of every warning (platkit.notices): printed
    once on stderr in the spec's form, never twice."""
    import platkit.calibrate.predict as predict

    real = predict.predict_file

    def two_failed(*args, **kwargs):
        res = real(*args, **kwargs)
        return {**res, "failed": 2, "warnings": ["a note", "a note"]}

    monkeypatch.setattr(predict, "predict_file", two_failed)
    rc, out = _predict(calibration, tmp_path, "t,A,B,C\n0,2047.2,2047.2,2047.2\n1,1900,2100,2000\n")
    err = capsys.readouterr().err.splitlines()
    assert rc == 0 and out.exists()
    assert err == ["platkit: warning: 2 of 2 rows have no forward-kinematics solution; their predicted cells are empty",
                   "platkit: warning: a note (said in the column thermal_note)"], err
