"""Via-point sweeps for calibration from motion (platkit.calibrate.via_points, `plan --motion --family via`)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from platkit.calibrate import excitation as ex
from platkit.calibrate import sweeps as sw
from platkit.calibrate import trajectories as tr
from platkit.calibrate import via_points as vp
from platkit.calibrate.plan import _Subspace, default_marker_layout, identification_jacobian
from platkit.cli import main
from platkit.errors import NotIdentifiable
from platkit.io.table import read_table
from platkit.plugins import get_platform
from tests.unit.test_plan_excitation import check_every_command as within_limits  # inside the box, rate, accel, reachable

RATE_HZ = 20.0


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def limits(stewart):
    return tr.drive_limits(stewart, np.array([0.2, 0.2, 0.25, 0.25, 0.3, 0.3]), np.array([0.6, 0.5, 0.6, 0.5, 0.6, 0.5]),
                           0.1)


@pytest.fixture(scope="module")
def markers(stewart):
    return default_marker_layout(stewart, 5, np.random.default_rng(0))


@pytest.fixture(scope="module")
def sweep(stewart, limits, markers):
    return vp.design_via(stewart, limits, markers, 60.0, RATE_HZ, np.random.default_rng(1))


def test_a_move_is_time_optimal_within_each_actuators_limits(stewart, limits):
    u0 = stewart.neutral_u()
    b = u0 + np.array([0.3, -0.2, 0.1, 0.0, -0.05, 0.25])
    U, knots = vp.via_trajectory(np.vstack([u0, b, u0]), limits, RATE_HZ)
    v, a = within_limits(stewart, U, limits)
    # the actuator with the longest move for its limits uses its whole rate; the others move proportionally
    j = int(np.argmax(np.abs(b - u0) / limits.rate))
    assert v[:, j].max() == pytest.approx(limits.rate[j], rel=1e-6)
    assert np.all(v.max(axis=0) <= limits.rate * (1 + 1e-9))
    d = np.abs(b - u0)
    T, rate, accel = vp.move_duration(b - u0, limits.rate, limits.accel)
    assert T == pytest.approx(d[j] / limits.rate[j] + rate / accel, rel=1e-9)  # trapezoid: rate reached
    assert knots[-1] == pytest.approx(2 * T)
    # a straight line in control space, at rest on each point (passed through, not held)
    np.testing.assert_allclose(U[0], u0, atol=1e-12)
    np.testing.assert_allclose(U[-1], u0, atol=1e-12)
    k = int(np.argmin(np.linalg.norm(U - b, axis=1)))
    assert np.linalg.norm(U[k] - b) < limits.accel.max() / RATE_HZ ** 2
    assert np.sum(np.all(np.abs(U - b) < 1e-9, axis=1)) <= 1  # no hold on the via point
    share = (U - u0) @ (b - u0) / np.dot(b - u0, b - u0)
    np.testing.assert_allclose(U, u0 + np.clip(share, 0, 1)[:, None] * (b - u0), atol=1e-12)


def test_a_short_move_never_reaches_the_rate(stewart, limits):
    u0 = stewart.neutral_u()
    b = u0 + 0.01
    U, _ = vp.via_trajectory(np.vstack([u0, b]), limits, RATE_HZ)
    v, a = within_limits(stewart, U, limits)
    assert v.max() < 0.5 * limits.rate.min()
    T, _, accel = vp.move_duration(b - u0, limits.rate, limits.accel)
    assert T == pytest.approx(2 * np.sqrt(1 / accel))


def test_the_limit_check_counts_every_command_past_a_limit(stewart, limits):
    u0 = stewart.neutral_u()
    U, _ = vp.via_trajectory(np.vstack([u0, u0 + 0.3, u0]), limits, RATE_HZ)
    tighter = tr.Limits(limits.lower, limits.upper, 0.9 * limits.rate, 0.9 * limits.accel)
    bad = tr.limit_violations(U, RATE_HZ, tighter)
    assert bad["rate"] > 0 and bad["accel"] > 0 and bad["rate_share"] > 1.05
    assert tr.limit_violations(U, RATE_HZ, limits)["rate"] == 0


def test_the_sweep_covers_the_strokes_within_the_limits(stewart, limits, sweep):
    U, _ = vp.via_trajectory(sweep.path, limits, RATE_HZ)
    assert len(U) / RATE_HZ <= 60.0 + 1 / RATE_HZ  # the session's length at most
    assert len(U) / RATE_HZ > 45.0  # as many via points as fit
    within_limits(stewart, U, limits)
    share = np.ptp(U, axis=0) / (limits.upper - limits.lower)
    assert share.min() > 0.9  # the whole box, where a multisine at these limits spans about half
    assert sweep.info["via_points"] == len(sweep.vias) >= 4 and sweep.info["tours"] == 1
    np.testing.assert_allclose(sweep.path[0], stewart.neutral_u())
    np.testing.assert_allclose(sweep.path[-1], stewart.neutral_u())


def test_d_optimal_via_points_beat_random_ones(stewart, limits, markers, sweep):
    rnd = vp.design_via(stewart, limits, markers, 60.0, RATE_HZ, np.random.default_rng(1), d_optimal_choice=False)
    assert rnd.info["choice"] == "random"
    k = min(len(sweep.vias), len(rnd.vias))
    ij = identification_jacobian(stewart, np.vstack([sweep.vias[:k], rnd.vias[:k]]), markers)
    Jr = _Subspace(ij.J).reduce(ij.J)

    def logdet(J):
        return np.linalg.slogdet(np.einsum("nri,nrj->ij", J, J))[1]

    # a subset of the D-optimal set against as many random points
    assert logdet(Jr[:k]) > logdet(Jr[k:]) + 1.0


def test_a_long_session_repeats_the_tour(stewart, limits, markers):
    fast = tr.Limits(limits.lower, limits.upper, 10 * limits.rate, 10 * limits.accel)
    d = vp.design_via(stewart, fast, markers, 150.0, RATE_HZ, np.random.default_rng(2))
    assert d.info["via_points"] == vp.MAX_VIAS and d.info["tours"] >= 2
    U, _ = vp.via_trajectory(d.path, fast, RATE_HZ)
    assert 140.0 < len(U) / RATE_HZ <= 150.0 + 1 / RATE_HZ  # the session filled, not cut at a whole tour
    within_limits(stewart, U, fast)


def test_a_session_too_short_for_a_sweep_is_refused(stewart, limits, markers):
    with pytest.raises(NotIdentifiable, match=r"try a longer session \(--duration-s \d+ or more\)$"):
        vp.design_via(stewart, limits, markers, 1.0, RATE_HZ, np.random.default_rng(1))


def test_slow_drives_sweep_a_smaller_box(stewart, markers, monkeypatch):
    # at 50 mm/s two via points fit a minute in the whole box; a box a third as wide fits more
    slow = tr.drive_limits(stewart, 0.05, 0.2, 0.1)
    information = ex.MotionInformation(stewart, markers)
    monkeypatch.setattr(sw, "VIA_SCALES", (1.0, 0.35))
    chosen, other = sw.design_sweep(stewart, slow, information, 60.0, RATE_HZ, 100.0, 1.0, 1e-4, 0)
    assert chosen.scale == 0.35 and chosen.design.info["via_points"] > 2
    monkeypatch.setattr(sw, "VIA_SCALES", (1.0,))
    whole, _ = sw.design_sweep(stewart, slow, information, 60.0, RATE_HZ, 100.0, 1.0, 1e-4, 0)
    assert chosen.p90 < 0.2 * whole.p90  # the prediction chose it
    assert chosen.p90 <= other.p90
    within_limits(stewart, chosen.U, slow)
    assert len(chosen.U) / RATE_HZ <= 60.0 + 1 / RATE_HZ


def test_plan_motion_family_via_writes_commands_and_report(tmp_path, capsys):
    out = tmp_path / "commands.csv"
    assert main(["plan", "--platform", "stewart", "--motion", "--family", "via", "--out", str(out), "--max-rate", "200",
                 "--max-accel", "500", "--duration-s", "40", "--noise-mm", "0.2", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "D-optimal via points" in said and "predicted marker error" in said and "random via points" in said
    table = read_table(out, "commands")
    assert table.header == ["t", "L1", "L2", "L3", "L4", "L5", "L6"]
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["family"]["name"] == "via" and report["duration_s"] <= 40.0 + 0.05
    assert report["checked"]["box"] == report["checked"]["rate"] == report["checked"]["accel"] == 0
    assert 0.99 < report["checked"]["rate_share"] <= 1 + 1e-9
    # the written commands (mm, 9 significant digits) keep the limits too
    spec = get_platform("stewart")
    lim = tr.drive_limits(spec, 0.2, 0.5, 0.1)
    U = table.data[:, 1:] * 1e-3
    v = np.abs(np.diff(U, axis=0)) * RATE_HZ
    assert np.all(v <= lim.rate * (1 + 1e-6))
    p = report["prediction"]
    assert 0 < p["marker_rms_m"] < p["marker_rms_p90_m"] and p["marker_rms_m_random"] > 0
    assert report["design"]["logdet_per_sample"] > report["design"]["logdet_per_sample_random"]


def test_plan_motion_family_via_for_a_target(tmp_path, capsys):
    out = tmp_path / "commands.csv"
    assert main(["plan", "--platform", "stewart", "--motion", "--out", str(out), "--max-rate", "200",
                 "--max-accel", "500", "--target-mm", "0.015", "--noise-mm", "0.2", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "target 0.015 mm (90% of sessions): met" in said
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["family"]["name"] == "via"  # the default family
    assert report["target"]["met"] and report["prediction"]["marker_rms_p90_m"] <= 1.5e-5
    assert report["duration_s"] < 55.0  # shorter than the first sweep (60 s, 0.0116 mm), which met it with room
    assert report["target"]["samples_needed"] <= report["prediction"]["samples_fitted"]


@pytest.mark.parametrize("args, code, said", [
    (["--motion", "--family", "via", "--max-rate", "200", "--max-accel", "500", "--duration-s", "1"], 1,
     "a longer session"),
    (["--motion", "--family", "spline", "--max-rate", "200", "--max-accel", "500", "--duration-s", "30"], 2,
     "--family"),
    (["--grid", "2", "--family", "via"], 2, "--family: only with --motion"),
])
def test_plan_motion_family_bad_input_in_one_line(tmp_path, capsys, args, code, said):
    out = tmp_path / "commands.csv"
    assert main(["plan", "--platform", "stewart", "--out", str(out), "--quiet"] + args) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0]
    assert not out.exists()


def test_no_reachable_candidate_says_which_option_to_change(stewart, limits, monkeypatch):
    # nothing inside the strokes less the margin reachable: the refusal ends on what to try
    monkeypatch.setattr(vp, "feasible", lambda spec, U, td, model: (np.zeros(len(U), bool), np.zeros((len(U), 6))))
    with pytest.raises(NotIdentifiable, match=r"are reachable; try a smaller --margin$"):
        vp._candidates(stewart, limits, 10, np.random.default_rng(0), None, None)
