"""Excitation trajectories for calibration from motion (platkit.calibrate.excitation, `plan --motion`)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from platkit.calibrate import excitation as ex
from platkit.calibrate import trajectories as tr
from platkit.calibrate.plan import default_marker_layout, feasible
from platkit.cli import main
from platkit.errors import BadInput, NotIdentifiable
from platkit.io.table import read_table
from platkit.plugins import get_platform
from platkit.simulate.continuous import continuous_plan

RATE_HZ = 20.0


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def information(stewart):
    return ex.MotionInformation(stewart, default_marker_layout(stewart, 5, np.random.default_rng(0)))


@pytest.fixture(scope="module")
def limits(stewart):
    return tr.drive_limits(stewart, np.array([0.2, 0.2, 0.25, 0.25, 0.3, 0.3]), 0.4, 0.1)


def check_every_command(spec, U, limits, rate_hz=RATE_HZ):
    v = np.abs(np.diff(U, axis=0)) * rate_hz
    a = np.abs(np.diff(U, 2, axis=0)) * rate_hz ** 2
    assert np.all(v <= limits.rate * (1 + 1e-9))
    assert np.all(a <= limits.accel * (1 + 1e-9))
    assert np.all((U >= limits.lower - 1e-12) & (U <= limits.upper + 1e-12))
    ok, _ = feasible(spec, U)
    assert ok.all()
    return v, a


def test_every_command_within_the_limits_and_reachable(stewart, limits):
    family = tr.FourierFamily(20.0, 5, stewart.n_u)
    coef = family.random_multisine(np.random.default_rng(3))
    U, meta = tr.trajectory(stewart, family, coef, limits, 30.0, RATE_HZ)
    assert U.shape == (600, 6)
    v, a = check_every_command(stewart, U, limits)
    # starts and ends at rest on the neutral controls
    np.testing.assert_allclose(U[0], stewart.neutral_u(), atol=1e-12)
    np.testing.assert_allclose(U[-1], stewart.neutral_u(), atol=1e-9)
    assert np.all(v[0] < 0.05 * limits.rate) and np.all(v[-1] < 0.05 * limits.rate)
    # the amplitudes are the largest the limits allow: each actuator meets one of its limits
    share = np.maximum.reduce([v.max(axis=0) / limits.rate, a.max(axis=0) / limits.accel,
                               np.abs(U - stewart.neutral_u()).max(axis=0)
                               / np.minimum(limits.upper - stewart.neutral_u(), stewart.neutral_u() - limits.lower)])
    assert np.all(share > 0.5) and share.max() > 0.99
    assert meta["rate"] == meta["accel"] == meta["box"] == 0


def test_the_design_improves_the_d_criterion_within_the_limits(stewart, information, limits):
    family = tr.FourierFamily(20.0, 4, stewart.n_u)
    design = ex.design_excitation(stewart, family, limits, information, RATE_HZ, np.random.default_rng(5), evaluations=12)
    assert np.isfinite(design.criterion_start)
    assert design.criterion > design.criterion_start + 1.0
    assert design.history == sorted(design.history)  # the best so far never falls
    U, _ = tr.trajectory(stewart, family, design.coef, limits, 25.0, RATE_HZ)
    check_every_command(stewart, U, limits)


def test_the_criterion_weighs_the_response_told_apart_from_the_geometry(information):
    rng = np.random.default_rng(4)
    n = information.rank
    A = rng.normal(size=(3 * n, n))
    info = A.T @ A
    r = information.V_static.shape[1]
    left = info[r:, r:] - info[r:, :r] @ np.linalg.solve(info[:r, :r], info[:r, r:])
    expected = np.linalg.slogdet(info)[1] + ex.RESPONSE_WEIGHT * np.linalg.slogdet(left)[1]
    assert information.criterion(info) == pytest.approx(expected, rel=1e-12)
    info[r:, r:] = info[r:, :r] @ np.linalg.solve(info[:r, :r], info[:r, r:])  # the response all in the geometry
    assert information.criterion(info) == -np.inf


def test_prediction_falls_as_one_over_root_samples(stewart, information, limits):
    family = tr.FourierFamily(20.0, 4, stewart.n_u)
    coef = family.random_multisine(np.random.default_rng(1))
    U, _ = tr.trajectory(stewart, family, coef, limits, 30.0, RATE_HZ)
    pred, n = ex.predict_trajectory(information, U, RATE_HZ, 30.0, 100.0, 1.0, 2e-4)
    assert n == 2995  # every sample from the second command on
    T = np.arange(len(U)) / RATE_HZ
    info = information.per_sample(T, U, np.linspace(T[1], T[-1], 800).reshape(100, 8))
    one, four = information.prediction(info, 1000, 2e-4), information.prediction(info, 4000, 2e-4)
    # the slow part of windows of 0.4 s: near the prediction from windows of 0.5 s
    assert one["marker_rms_m"] / np.sqrt(2995 / 1000) == pytest.approx(pred["marker_rms_m"], rel=0.1)
    assert one["identifiable"]
    assert four["marker_rms_m"] == pytest.approx(one["marker_rms_m"] / 2, rel=1e-9)
    assert four["marker_rms_p90_m"] == pytest.approx(one["marker_rms_p90_m"] / 2, rel=1e-9)
    assert one["marker_rms_m"] < one["marker_rms_p90_m"] < 2 * one["marker_rms_m"]
    length = ex.session_length_for(information, info, 0.5 * one["marker_rms_p90_m"], 2e-4, 100.0)
    assert length["samples"] == pytest.approx(4000, rel=1e-3)
    assert length["duration_s"] == pytest.approx(40.0, rel=1e-3)
    with pytest.raises(NotIdentifiable, match="over 3600 s"):
        ex.session_length_for(information, info, 1e-3 * one["marker_rms_p90_m"], 2e-4, 100.0)


def test_limits_said_in_one_line(stewart):
    with pytest.raises(BadInput, match="max_rate: the stewart stand's description declares no rate limit"):
        tr.drive_limits(stewart, None, 1.0)
    with pytest.raises(BadInput, match="max_accel"):
        tr.drive_limits(stewart, 0.2, None)
    with pytest.raises(BadInput, match="max_rate: expected 1 or 6 numbers"):
        tr.drive_limits(stewart, np.array([0.1, 0.2]), 1.0)
    # a URDF declares its joints' velocity: the rate limit comes from it
    rotary = get_platform("rotary")
    lim = tr.drive_limits(rotary, None, 2.0)
    np.testing.assert_allclose(lim.rate, [np.degrees(1.0)] * 2)  # velocity="1" rad/s, controls in degrees
    assert lim.source["rate"].startswith("description")
    # limits that leave the stand still
    family = tr.FourierFamily(20.0, 4, stewart.n_u)
    still = tr.drive_limits(stewart, 1e-6, 1e-6)
    with pytest.raises(BadInput, match=r"limits leave L\d .* of its room"):
        tr.trajectory(stewart, family, family.random_multisine(np.random.default_rng(0)), still, 30.0, RATE_HZ)


def test_given_commands_are_streamed_by_the_simulator(stewart, limits):
    family = tr.FourierFamily(20.0, 4, stewart.n_u)
    U, _ = tr.trajectory(stewart, family, family.random_multisine(np.random.default_rng(2)), limits, 25.0, RATE_HZ)
    out, info = continuous_plan(stewart, U, 0.0, RATE_HZ, np.random.default_rng(0), None, None, 2 * limits.rate,
                                4 * limits.accel)
    assert out is U or np.array_equal(out, U)
    assert info["kind"] == "given" and info["drive_rate_share"] <= 0.5 + 1e-9 and info["drive_accel_share"] <= 0.25 + 1e-9
    with pytest.raises(BadInput, match="given commands must be"):
        continuous_plan(stewart, U[:, :3], 0.0, RATE_HZ, np.random.default_rng(0), None, None, limits.rate, limits.accel)


def test_plan_motion_writes_commands_and_report(tmp_path, capsys):
    out = tmp_path / "commands.csv"
    code = main(["plan", "--platform", "stewart", "--motion", "--family", "fourier", "--out", str(out), "--max-rate", "200",
                 "--max-accel", "400", "--duration-s", "30", "--period-s", "20", "--harmonics", "4",
                 "--evaluations", "6", "--noise-mm", "0.2", "--quiet"])
    assert code == 0
    said = capsys.readouterr().out
    assert "predicted marker error" in said and "random multisine" in said
    table = read_table(out, "commands")
    assert table.header == ["t", "L1", "L2", "L3", "L4", "L5", "L6"]
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["n_commands"] == 600 and report["checked"]["rate"] == report["checked"]["accel"] == 0
    assert report["checked"]["rate_share"] <= 1 + 1e-9 and report["checked"]["accel_share"] <= 1 + 1e-9
    p = report["prediction"]
    assert 0 < p["marker_rms_m"] and p["samples_fitted"] == int((30.0 - 0.05) * 100)
    assert report["design"]["criterion"] >= report["design"]["criterion_random"]


@pytest.mark.parametrize("extra, code, said", [
    ([], 2, "--max-rate: the stewart stand's description declares no rate limit"),
    (["--max-rate", "0", "--max-accel", "400"], 2, "--max-rate: every limit must be positive"),
    (["--max-rate", "200,200", "--max-accel", "400"], 2, "--max-rate: expected 1 or 6 numbers"),
    (["--max-rate", "200", "--max-accel", "400", "--duration-s", "3"], 1, "cannot rise to its excitation"),
    (["--max-rate", "200", "--max-accel", "400", "--target-mm", "0.000001"], 1, "--target-mm 1e-06: needs"),
    (["--max-rate", "200", "--max-accel", "400"], 2, "give --duration-s S or --target-mm E"),
    (["--max-rate", "200", "--max-accel", "400", "--duration-s", "30", "--grid", "3"], 2, "--grid: applies to hold plans"),
])
def test_plan_motion_bad_input_in_one_line(tmp_path, capsys, extra, code, said):
    out = tmp_path / "commands.csv"
    args = ["plan", "--platform", "stewart", "--motion", "--family", "fourier", "--out", str(out), "--period-s", "20",
            "--harmonics", "4", "--evaluations", "3", "--quiet"] + extra
    assert main(args) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0]
    assert not out.exists()


def test_motion_options_need_motion(tmp_path, capsys):
    assert main(["plan", "--platform", "stewart", "--grid", "2", "--out", str(tmp_path / "p.csv"),
                 "--max-rate", "200"]) == 2
    assert "--max-rate: only with --motion" in capsys.readouterr().err


def test_simulate_streams_a_planned_commands_file(tmp_path, capsys):
    plan = tmp_path / "commands.csv"
    assert main(["plan", "--platform", "stewart", "--motion", "--family", "fourier", "--out", str(plan), "--max-rate", "200",
                 "--max-accel", "400", "--duration-s", "25", "--period-s", "20", "--harmonics", "3",
                 "--evaluations", "2", "--quiet"]) == 0
    session = tmp_path / "session"
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", str(plan), "--seed", "3",
                 "--out", str(session)]) == 0
    capsys.readouterr()
    written = read_table(session / "commands.csv", "commands")
    planned = read_table(plan, "plan")
    assert len(written.data) == len(planned.data) == 500
    np.testing.assert_allclose(written.data[:, 1:], planned.data[:, 1:], atol=5e-4 + 1e-9)  # the session keeps um
    np.testing.assert_allclose(np.diff(written.column("t")), 0.05, atol=2e-6)
    # a log whose rate is not steady is refused in one line naming the file and row
    rows = plan.read_text().splitlines()
    t, rest = rows[3].split(",", 1)
    rows[3] = f"{float(t) + 0.01:.6f},{rest}"
    uneven = tmp_path / "uneven.csv"
    uneven.write_text("\n".join(rows) + "\n")
    assert main(["simulate", "--platform", "stewart", "--physics", "--motion", str(uneven),
                 "--out", str(tmp_path / "s2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "uneven.csv row" in err[0] and "not at a steady rate" in err[0]
