"""`platkit calibrate` and `platkit predict` end to end on session folders written here."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from test_estimate import Truth

from platkit.cli import main
from platkit.io.calibration import read_calibration
from platkit.plugins import get_platform


def write_session(folder: Path, truth: Truth, n: int, sigma: float, unit: str = "mm") -> tuple[np.ndarray, np.ndarray]:
    """A session folder with session.yaml, commands.csv and poses.csv; returns (U SI, markers SI)."""
    spec = truth.spec
    U, Y = truth.observe(truth.controls(n), sigma)
    s = 1e-3 if unit == "mm" else 1.0
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"M{i + 1}" for i in range(Y.shape[1])]
    (folder / "session.yaml").write_text(yaml.safe_dump({
        "platform": spec.name, "description": None, "units": {"length": unit, "time": "s"}, "markers": names,
        "base_markers": [], "mocap_rate_hz": 100, "imu": None, "moving_link": None, "notes": "simulated"}))
    Uf = np.array([[u / s if c.unit == "m" else u for u, c in zip(row, spec.controls)] for row in U])
    with (folder / "commands.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t"] + spec.control_names)
        for k, row in enumerate(Uf):
            w.writerow([2.0 * k] + list(row))
    with (folder / "poses.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(spec.control_names + [f"{m}_{a}" for m in names for a in "xyz"])
        for row, ys in zip(Uf, Y):
            w.writerow(list(row) + list(ys.ravel() / s))
    return U, Y


@pytest.fixture(scope="module")
def stewart_session(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sessions") / "stewart"
    truth = Truth(get_platform("stewart"), seed=21)
    write_session(folder, truth, 120, 1e-4)
    return folder, truth


@pytest.fixture(scope="module")
def calibrated(stewart_session, tmp_path_factory):
    folder, _ = stewart_session
    out = tmp_path_factory.mktemp("out") / "cal"
    assert main(["calibrate", str(folder), "--folds", "3", "--out", str(out)]) == 0
    return out


def test_calibrate_writes_the_three_outputs(calibrated, capsys):
    rep = json.loads((calibrated / "report.json").read_text())
    for key in ("rms_before", "rms_after", "unit", "n_poses", "n_markers", "converged"):
        assert key in rep, key
    assert rep["unit"] == "mm" and rep["converged"] is True
    assert rep["n_poses"] == 120 and rep["n_markers"] == 4
    assert rep["rms_after"] == pytest.approx(0.1 * np.sqrt(3), rel=0.15)  # mm: the noise
    assert rep["rms_before"] > 2 * rep["rms_after"]
    assert rep["heldout"]["folds"] == 3 and rep["heldout"]["rms"] < 1.5 * 0.1 * np.sqrt(3)
    assert len(rep["held_at_nominal"]) == 12
    html = (calibrated / "report.html").read_text()
    assert html.count("data:image/png;base64,") >= 5
    data = yaml.safe_load((calibrated / "calibration.yaml").read_text())
    p = data["parameters"]["dL1"]
    assert set(p) >= {"value", "std", "nominal", "unit"} and p["unit"] == "mm"
    held = data["identifiability"]["held_at_nominal"][0]["name"]
    assert data["parameters"][held]["status"] == "held_at_nominal" and data["parameters"][held]["std"] is None
    assert len(data["mocap_from_base"]["rotation_matrix"]) == 3 and set(data["markers"]) == {"M1", "M2", "M3", "M4"}


def test_calibration_yaml_round_trips(calibrated):
    cal = read_calibration(calibrated / "calibration.yaml")
    data = yaml.safe_load((calibrated / "calibration.yaml").read_text())
    spec = get_platform("stewart")
    i = spec.parameter_names.index("B1_x")
    assert cal.td[i] == pytest.approx(data["parameters"]["B1_x"]["value"] * 1e-3, abs=1e-12)
    assert cal.marker_positions.shape == (4, 3)
    assert cal.mocap_from_base[:3, :3] @ cal.mocap_from_base[:3, :3].T == pytest.approx(np.eye(3), abs=1e-12)


def test_predict_reproduces_the_measured_markers(stewart_session, calibrated, tmp_path):
    folder, truth = stewart_session
    out = tmp_path / "pred.csv"
    assert main(["predict", "--calibration", str(calibrated / "calibration.yaml"), "--commands",
                 str(folder / "commands.csv"), "--out", str(out)]) == 0
    with out.open() as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    spec = get_platform("stewart")
    assert header == spec.control_names + [f"M{i}_{a}" for i in range(1, 5) for a in "xyz"] + \
        ["x", "y", "z", "qw", "qx", "qy", "qz"]
    pred = np.array(rows[1:], float)
    with (folder / "poses.csv").open() as fh:
        meas = np.array(list(csv.reader(fh))[1:], float)
    assert pred.shape[0] == meas.shape[0] == 120
    assert np.array_equal(pred[:, :6].round(6), meas[:, :6].round(6))
    d = np.linalg.norm((pred[:, 6:18] - meas[:, 6:18]).reshape(-1, 4, 3), axis=2)
    assert np.sqrt(np.mean(d ** 2)) < 0.25  # mm: noise 0.1 per axis
    q = pred[:, -4:]
    assert np.allclose(np.linalg.norm(q, axis=1), 1, atol=1e-8)
    assert np.all(pred[:, 20] > 2000)  # z of the platform in the base frame, mm


def test_predict_names_the_missing_column(calibrated, tmp_path, capsys):
    bad = tmp_path / "cmd.csv"
    bad.write_text("t,L1,L2,L3,L4,L5\n0,4000,4000,4000,4000,4000\n")
    rc = main(["predict", "--calibration", str(calibrated / "calibration.yaml"), "--commands", str(bad),
               "--out", str(tmp_path / "p.csv")])
    err = capsys.readouterr().err
    assert rc == 2 and "cmd.csv" in err and "'L6'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "p.csv").exists()


def test_bad_inputs_exit_2_in_one_line(stewart_session, tmp_path, capsys):
    folder, _ = stewart_session
    cases = [
        ["calibrate", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o1")],
        ["calibrate", str(folder), "--folds", "1", "--out", str(tmp_path / "o2")],
        ["calibrate", str(folder), "--free", "wheels", "--out", str(tmp_path / "o3")],
        ["calibrate", "--out", str(tmp_path / "o4")],
        ["calibrate", str(folder), "--method", "paper", "--max-evaluations", "0", "--out", str(tmp_path / "o5")],
        ["calibrate", str(folder), "--method", "paper", "--folds", "3", "--out", str(tmp_path / "o6")],
        ["calibrate", str(folder), "--validate", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o7")],
    ]
    for argv in cases:
        rc = main(argv)
        err = capsys.readouterr().err
        assert rc == 2, (argv, err)
        assert len(err.strip().splitlines()) == 1 and err.startswith("platkit: error: "), err
        assert not Path(argv[-1]).exists()


def test_a_failed_calibration_writes_nothing(tmp_path, capsys):
    truth = Truth(get_platform("stewart"), seed=22)
    folder = tmp_path / "one"
    write_session(folder, truth, 2, 1e-4)
    out = tmp_path / "out"
    rc = main(["calibrate", str(folder), "--quiet", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 1 and "cannot fix" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_paper_method_from_the_command_line(tmp_path, capsys):
    truth = Truth(get_platform("rotary"), seed=23, n_markers=3, marker_spread=0.1)
    folder = tmp_path / "rotary"
    write_session(folder, truth, 40, 5e-5)
    out = tmp_path / "paper"
    # 300 evaluations do not meet Nelder-Mead's tolerance: exit 1, the outputs whole for inspection
    assert main(["calibrate", str(folder), "--method", "paper", "--max-evaluations", "300", "--out", str(out)]) == 1
    rep = json.loads((out / "report.json").read_text())
    assert rep["converged"] is False and any(w.startswith("not converged") for w in rep["warnings"])
    assert rep["method"] == "paper" and rep["paper"]["evaluations"] <= 302
    assert rep["paper"]["J_after"] <= rep["paper"]["J_before"]
    assert "nelder-mead" in capsys.readouterr().err


def test_example_session_recovers_the_simulated_truth(tmp_path, capsys):
    from platkit.io.session import example_session

    out = tmp_path / "example"
    # calibration.yaml and stderr are read (the `calibrated` fixture renders a report.html)
    assert main(["calibrate", "--platform", "stewart", "--no-report", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "iteration" in err and "identifiable" in err  # progress on stderr
    truth = yaml.safe_load((example_session("stewart") / "truth.yaml").read_text())
    cal = read_calibration(out / "calibration.yaml")
    # leg-length offsets are gauge-free: compare them with the truth in standard deviations
    z = []
    for k in range(1, 7):
        i = cal.spec.parameter_names.index(f"dL{k}")
        assert cal.td_status[i] == "estimated"
        z.append((cal.td[i] - truth["parameters"][f"dL{k}"]["value"]) / cal.td_std[i])
    z = np.array(z)
    assert np.all(np.abs(z) < 4) and np.sum(z ** 2) < 22.5, z  # chi-square(6) 0.999 quantile 22.5


def test_model_terms_survive_the_file_and_predict(stewart_session, tmp_path):
    from platkit.calibrate.estimate import calibrate, predict_markers
    from platkit.calibrate.report import write_outputs
    from platkit.effects import with_history
    from platkit.io.session import load_session
    from platkit.plugins import effect_library
    from platkit.settle import load_poses

    folder, _ = stewart_session
    spec = get_platform("stewart")
    poses = with_history(load_poses(folder, spec=load_session(folder).spec), spec)
    term = effect_library()["backlash"].candidates(spec, poses)[0]
    cal = calibrate(poses, spec, terms=[term])
    write_outputs(cal, tmp_path / "cal", poses, with_html=False)  # calibration.yaml is what is read back
    back = read_calibration(tmp_path / "cal" / "calibration.yaml")
    assert [t.effect for t in back.terms] == ["backlash"] and back.terms[0].where == term.where
    assert back.theta[0] == pytest.approx(cal.theta[0], rel=1e-9, abs=1e-15)
    out = tmp_path / "pred.csv"
    assert main(["predict", "--calibration", str(tmp_path / "cal" / "calibration.yaml"), "--commands",
                 str(folder / "commands.csv"), "--out", str(out)]) == 0
    pred = np.array([r for r in csv.reader(out.open())][1:], float)
    expected, _, _, _ = predict_markers(cal, poses.controls, poses)
    assert pred[:, 6:18] == pytest.approx(expected.reshape(len(expected), -1) * 1e3, abs=1e-6)


def test_validate_on_a_second_session(stewart_session, tmp_path):
    folder, truth = stewart_session
    second = tmp_path / "second"
    write_session(second, truth, 40, 1e-4)
    out = tmp_path / "cal"
    # report.json and calibration.yaml are read (test_qa_calibrate_summary renders a --validate report.html)
    assert main(["calibrate", str(folder), "--validate", str(second), "--quiet", "--no-report", "--out",
                 str(out)]) == 0
    h = json.loads((out / "report.json").read_text())["heldout"]["second_session"]
    assert h["n_poses"] == 40 and h["unit"] == "mm"
    assert 0.1 * np.sqrt(3) < h["rms"] < 1.5 * 0.1 * np.sqrt(3)  # mm: the second session's own noise
    assert set(h["rms_per_marker"]) == {"M1", "M2", "M3", "M4"}
    assert yaml.safe_load((out / "calibration.yaml").read_text())["heldout"]["second_session"]["rms"] == \
        pytest.approx(h["rms"])


def test_no_report_skips_only_the_html_and_figures_need_no_pyplot(stewart_session, tmp_path):
    """`--no-report`: calibration.yaml and report.json as always, no report.html (issue 13: its
    figures take longer than a small calibration); the figures of the report are bare matplotlib
    Figures, so rendering it leaves pyplot's figure registry empty."""
    import sys

    folder, _ = stewart_session
    out = tmp_path / "cal"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["calibration.yaml", "report.json"]
    assert json.loads((out / "report.json").read_text())["n_poses"] == 120
    out2 = tmp_path / "cal2"
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--out", str(out2)]) == 0
    assert (out2 / "report.html").read_text().count("data:image/png;base64,") >= 5
    if "matplotlib.pyplot" in sys.modules:
        assert sys.modules["matplotlib.pyplot"].get_fignums() == []
