"""`platkit diagnose` end to end: a simulated session with a concealed backlash, calibrated, then
diagnosed; the outputs' fields; `predict` reproduces the accepted effect; errors are one line."""
import json

import numpy as np
import pytest
import yaml

from platkit.cli import main


@pytest.fixture(scope="module")
def diagnosed(tmp_path_factory):
    root = tmp_path_factory.mktemp("diag")
    session, cal, out = root / "session", root / "cal", root / "diag"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--effect", "backlash:1.0",
                 "--seed", "5", "--poses", "50", "--plan", "random", "--poses-only"]) == 0
    # the calibration's report.html is not read here (test_calibrate_cli.py renders it); diagnose's is
    assert main(["calibrate", str(session), "--out", str(cal), "--quiet", "--no-report"]) == 0
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--out", str(out),
                 "--quiet"]) == 0
    return session, cal, out


def test_diagnosis_json_names_the_concealed_backlash(diagnosed):
    session, _, out = diagnosed
    d = json.loads((out / "diagnosis.json").read_text())
    truth = yaml.safe_load((session / "truth.yaml").read_text())
    true_actuator = truth["effects"][0]["where"]["actuator"]
    assert [f["effect"] for f in d["findings"]] == ["backlash"]
    f = d["findings"][0]
    assert set(f) >= {"effect", "where", "parameters", "heldout_rms_before", "heldout_rms_after", "evidence"}
    assert f["where"]["actuator"] == true_actuator
    half = f["parameters"]["half_play"]
    assert f["unit"] == "mm" and half["unit"] == "mm"
    assert abs(half["value"] - 0.5) < 4 * half["std"] + 0.02  # 1.0 mm of play, half on each side
    assert f["heldout_rms_after"] < 0.5 * f["heldout_rms_before"]
    assert isinstance(d["verdict"], str) and "backlash" in d["verdict"]
    assert "<img" in (out / "report.html").read_text()


def test_predict_uses_the_accepted_effect(diagnosed, tmp_path):
    session, cal, out = diagnosed
    written = yaml.safe_load((out / "calibration.yaml").read_text())
    assert [t["effect"] for t in written["terms"]] == ["backlash"]
    plain, with_effect = tmp_path / "plain.csv", tmp_path / "effect.csv"
    assert main(["predict", "--calibration", str(cal / "calibration.yaml"), "--commands",
                 str(session / "commands.csv"), "--out", str(plain)]) == 0
    assert main(["predict", "--calibration", str(out / "calibration.yaml"), "--commands",
                 str(session / "commands.csv"), "--out", str(with_effect)]) == 0
    a = np.genfromtxt(plain, delimiter=",", names=True)
    b = np.genfromtxt(with_effect, delimiter=",", names=True)
    poses = np.genfromtxt(session / "poses.csv", delimiter=",", names=True)
    cols = [n for n in poses.dtype.names if n.endswith(("_x", "_y", "_z"))]
    err = {k: np.sqrt(np.nanmean([(p[c] - poses[c]) ** 2 for c in cols])) for k, p in (("plain", a), ("effect", b))}
    assert err["effect"] < 0.5 * err["plain"]


def test_bad_input_exits_2_with_one_line(diagnosed, tmp_path, capsys):
    session, cal, _ = diagnosed
    assert main(["diagnose", str(session), "--calibration", str(tmp_path / "none.yaml"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "none.yaml" in err
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--out",
                 str(tmp_path / "o"), "--folds", "1"]) == 2
    assert main(["diagnose", str(tmp_path / "missing"), "--calibration", str(cal / "calibration.yaml"), "--out",
                 str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()


def test_no_report_writes_the_same_diagnosis_without_report_html(diagnosed, tmp_path, capsys):
    session, cal, out = diagnosed
    quiet = tmp_path / "quiet"
    assert main(["diagnose", str(session), "--calibration", str(cal / "calibration.yaml"), "--out", str(quiet),
                 "--quiet", "--no-report"]) == 0
    assert sorted(p.name for p in quiet.iterdir() if p.suffix != ".urdf") == ["calibration.yaml", "diagnosis.json"]
    assert "report.html" not in capsys.readouterr().out
    full, bare = (json.loads((d / "diagnosis.json").read_text()) for d in (out, quiet))
    assert [f["effect"] for f in bare["findings"]] == [f["effect"] for f in full["findings"]] == ["backlash"]
    assert bare["verdict"] == full["verdict"]
    assert yaml.safe_load((quiet / "calibration.yaml").read_text())["terms"] == \
        yaml.safe_load((out / "calibration.yaml").read_text())["terms"]
