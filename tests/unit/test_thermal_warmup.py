"""Warm-up with time since power-on: the physical simulator plays it, thermal_drift models it as a
third form beside the heat of work and the linear drift, diagnosis accepts a term that extrapolates
in time only where it predicts the later part of the session no worse than the model without it,
and predict states the thermal state it predicts for (and warns beyond the recorded span)."""
import numpy as np
import pytest
import yaml

from platkit.cli import main
from platkit.diagnose.fitting import Fit, Options
from platkit.diagnose.rounds import confirm, not_accepted
from platkit.errors import BadInput
from platkit.plugins import effect_library, get_platform
from platkit.poses import PoseSet
from platkit.simulate.physics import simulate_physics
from platkit.simulate.warmup import WarmupPhysics, draw_warmup
from platkit_effects.thermal import FORM_LINEAR, FORM_WARMUP, FORM_WORK, ThermalExpansionTerm, ThermalWarmupTerm


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


def test_a_visible_warm_up_grows_in_the_session_and_a_warm_one_does_not(stewart):
    base = simulate_physics(stewart, seed=4, n_poses=12, plan="random", noise_mm=0.0, coloured=False)
    grows = []
    for kind in ("visible", "warm"):
        sim = simulate_physics(stewart, seed=4, n_poses=12, plan="random", noise_mm=0.0, coloured=False, warmup=kind)
        (name, w), = [p for p in sim.physics if isinstance(p[1], WarmupPhysics)]
        assert name == "thermal_drift" and w.parameters()["form"] == FORM_WARMUP and w.kind == kind
        # the truth's settled controls carry the warm-up reached at the end of each hold, nothing else
        d = sim.settled_controls - base.settled_controls
        expected = w.warmth(sim.settled_controls[:, 0] * 0 + sim.hold_end_t - 1e-2)[:, None] * w.amplitude[None]
        assert np.allclose(d, expected, atol=2e-5 * np.max(w.amplitude) + 1e-9)
        assert 0.3e-3 <= np.max(w.amplitude) <= 1.0e-3 and 300 <= w.tau_s <= 1200
        grows.append(float(np.ptp(d[:, 0]) / w.amplitude[0]))
    assert grows[0] > 0.02 and grows[1] < 0.01, grows  # 'visible' shows the warm-up, 'warm' is at the equilibrium


def test_an_unknown_warm_up_kind_is_bad_input(stewart):
    with pytest.raises(BadInput, match="warm-up: kind must be one of visible, warm"):
        draw_warmup(stewart, "hot", np.random.default_rng(0), 0.5, "thermal_drift")


def _poses(n=20, t_end=600.0, seed=0):
    rng = np.random.default_rng(seed)
    U = 0.6 + 0.05 * rng.uniform(-1, 1, (n, 6))
    return PoseSet("stewart", U, np.full((n, 3, 3), np.nan), ["M1", "M2", "M3"], t=np.linspace(0, t_end, n),
                   length_unit="mm")


def test_the_three_forms_are_candidates_and_come_back_from_a_calibration(stewart):
    eff = effect_library()["thermal_drift"]
    assert eff.forecast
    cands = eff.candidates(stewart, _poses())
    forms = [c.where["form"] for c in cands]
    assert forms[0] == FORM_LINEAR and FORM_WORK in forms and FORM_WARMUP in forms
    assert all(c.where["recorded_s"] == [0.0, 600.0] for c in cands)
    for c in (cands[0], next(c for c in cands if c.where["form"] == FORM_WORK),
              next(c for c in cands if c.where["form"] == FORM_WARMUP)):
        back = eff.from_dict(c.to_dict(np.ones(len(c.initial))), stewart)
        assert type(back) is type(c) and back.where == c.where and back.parameter_names == c.parameter_names


def test_the_warm_up_term_reaches_its_amplitudes_once_warm(stewart):
    eff = effect_library()["thermal_drift"]
    term = eff.warmup(list(stewart.control_names), ["m"] * 6, 600.0)
    theta = np.arange(1, 7) * 1e-4
    poses = _poses(4)
    poses.extras = {"elapsed": np.array([0.0, 600.0, 6000.0, np.inf])}
    off = term.control_offset(theta, poses, 6)
    assert np.allclose(off[0], 0) and np.allclose(off[1], (1 - np.exp(-1)) * theta)
    assert np.allclose(off[3], theta) and np.allclose(off[2], theta, rtol=1e-4)


def test_the_heat_of_work_starts_from_the_state_predict_asks_for(stewart):
    rate = np.full(6, 0.01)  # strokes per second
    term = ThermalExpansionTerm("thermal_drift", ["k"], np.zeros(1), ["m"], {}, tau_s=300.0, stroke=np.ones(6),
                                work_rate=rate)
    poses = _poses(3)
    poses.controls[:] = 0.6  # no moves in the rows themselves
    poses.extras = {"elapsed": np.array([0.0, 300.0, 600.0]), "row": np.arange(3.0)}
    assert np.allclose(term.control_offset(np.ones(1), poses, 6), 0)  # no state asked: cold
    poses.extras = dict(poses.extras, thermal_start_s=np.full(3, np.inf))
    assert np.allclose(term.control_offset(np.ones(1), poses, 6), 3.0)  # warm: rate x tau
    poses.extras = dict(poses.extras, thermal_start_s=np.full(3, 300.0))
    h0 = 3.0 * (1 - np.exp(-1))
    assert np.allclose(term.control_offset(np.ones(1), poses, 6)[:, 0], h0 * np.exp(-np.array([0, 1, 2])))


def _fit(rss, cv, later):
    N = len(cv)
    return Fit([], None, np.zeros(1), np.ones(1, bool), np.ones((N, 1)), np.zeros((N, 1, 3)), rss, 300, 10,
               cv=np.asarray(cv, float), later=later)


def test_a_term_that_forecasts_the_later_part_worse_is_not_accepted():
    opt = Options()
    cur = _fit(1.0, np.full(40, 4e-8), 2e-4)
    judged = np.ones(40, bool)
    better_here_worse_later = _fit(0.5, np.full(40, 1e-8), 3e-4)
    assert confirm([(0, better_here_worse_later, 1e-6)], [1.0], cur, judged, opt) is None
    cands = [(effect_library()["thermal_drift"], ThermalWarmupTerm("thermal_drift", ["a"], np.zeros(1)))]
    why = not_accepted([(0, better_here_worse_later, 1e-6)], cands, [1.0], cur, judged, opt)
    assert "later 30% of the session, held out, 1.50 times as far off" in why
    better_later = _fit(0.5, np.full(40, 1e-8), 1e-4)
    assert confirm([(0, better_later, 1e-6)], [1.0], cur, judged, opt) is not None
    unjudged = _fit(0.5, np.full(40, 1e-8), None)  # an effect that does not forecast: the old rules alone
    assert confirm([(0, unjudged, 1e-6)], [1.0], cur, judged, opt) is not None


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal")
    assert main(["calibrate", "--platform", "psvr", "--quiet", "--out", str(out)]) == 0
    return (out / "calibration.yaml").read_text()


WARMUP = """terms:
- effect: thermal_drift
  where: {actuator: all, form: warm-up with time, warmup_time_constant_s: 600.0, actuators: [A, B, C],
          units: [count, count, count], recorded_s: [0.0, 1200.0]}
  parameters:
    A_warm: {value: 20.0, std: 0.1, unit: count}
    B_warm: {value: 0.0, std: 0.1, unit: count}
    C_warm: {value: 0.0, std: 0.1, unit: count}
"""
LINEAR = """terms:
- effect: thermal_drift
  where: {time: 'the whole session, linear in the time since its first command', form: linear in time,
          recorded_s: [0.0, 1200.0]}
  parameters:
    vx: {value: 1.0e-06, std: 1.0e-08, unit: m/s}
    vy: {value: 0.0, std: 1.0e-08, unit: m/s}
    vz: {value: 0.0, std: 1.0e-08, unit: m/s}
"""
COMMANDS = "t,A,B,C\n0,2047.2,2047.2,2047.2\n100,1900,2100,2000\n"


def _predict(tmp_path, cal_text, *options):
    (tmp_path / "cal.yaml").write_text(cal_text)
    (tmp_path / "commands.csv").write_text(COMMANDS)
    out = tmp_path / "p.csv"
    rc = main(["predict", "--calibration", str(tmp_path / "cal.yaml"), "--commands", str(tmp_path / "commands.csv"),
               "--out", str(out), *options])
    return rc, out


def _rows(out):
    lines = out.read_text().splitlines()
    head = lines[0].split(",")
    return head, [dict(zip(head, line.split(",", len(head) - 1))) for line in lines[1:]]


def test_predict_states_the_thermal_state_and_warns_beyond_the_recorded_span(calibration, tmp_path, capsys):
    cal = calibration.replace("terms: []\n", WARMUP)
    rc, out = _predict(tmp_path, cal, "--at-time", "300")
    assert rc == 0
    said = capsys.readouterr()
    assert "thermal state: 300 s since power-on at the first row, later rows by their t" in said.out
    head, rows = _rows(out)
    assert head[-2:] == ["since_power_on_s", "thermal_note"]
    assert [r["since_power_on_s"] for r in rows] == ["300", "400"] and all(r["thermal_note"] == "" for r in rows)
    at_300 = [float(rows[0][k]) for k in ("M1_x", "M1_y", "M1_z", "z")]
    rc, out = _predict(tmp_path, cal, "--at-time", "1500")
    said = capsys.readouterr()
    _, rows = _rows(out)
    assert "beyond the recorded span (0 to 1200 s)" in rows[0]["thermal_note"]
    assert "2 of 2 rows" in said.err and "thermal_note" in said.err
    rc, out = _predict(tmp_path, cal, "--warm")
    said = capsys.readouterr()
    _, rows = _rows(out)
    assert "thermal state: warm" in said.out and rows[0]["since_power_on_s"] == "inf"
    assert "the equilibrium lies beyond the recorded span" in rows[0]["thermal_note"]  # 2 time constants recorded
    assert not np.allclose([float(rows[0][k]) for k in ("M1_x", "M1_y", "M1_z", "z")], at_300, rtol=0, atol=1e-6)


def test_warm_with_a_drift_that_has_no_equilibrium_is_said(calibration, tmp_path, capsys):
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", LINEAR), "--warm")
    assert rc == 0
    _, rows = _rows(out)
    assert rows[0]["since_power_on_s"] == "1200"
    assert "has no equilibrium (it drifts without end): predicted at the end of the recorded span" in rows[0]["thermal_note"]
    assert "no equilibrium" in capsys.readouterr().err


def test_the_options_on_a_model_without_time_are_accepted_with_a_note(calibration, tmp_path, capsys):
    rc, out = _predict(tmp_path, calibration, "--at-time", "300")
    assert rc == 0
    assert "no time-dependent term: the prediction is the same at any time (--at-time changes nothing)" \
        in capsys.readouterr().out
    head, _ = _rows(out)
    assert head[-1] == "qz"  # the spec's columns, nothing added
    rc, out = _predict(tmp_path, calibration, "--at-time", "-5")
    assert rc == 0  # nothing reads the time: the number is not used
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", WARMUP), "--at-time", "-5")
    assert rc == 2 and "--at-time must be a time since power-on" in capsys.readouterr().err


def test_a_session_says_its_power_on_and_the_thermal_terms_keep_it(stewart, tmp_path):
    from platkit.settle import load_poses
    from platkit.simulate.physics import write_physical_session

    sim = simulate_physics(stewart, seed=4, n_poses=6, plan="random", warmup="visible")
    (_, w), = [p for p in sim.physics if isinstance(p[1], WarmupPhysics)]
    folder = write_physical_session(sim, tmp_path / "s")
    assert f"power_on_t: {round(w.power_on_s, 6)}" in (folder / "session.yaml").read_text()
    poses = load_poses(folder)
    assert np.allclose(poses.extras["since_power_on"], poses.t - round(w.power_on_s, 6))
    warm_up = [c for c in effect_library()["thermal_drift"].candidates(stewart, poses) if c.where["form"] == FORM_WARMUP]
    start = poses.t[0] - round(w.power_on_s, 6)
    assert all(c.start_s == pytest.approx(start) and c.where["since_power_on_at_start_s"] == pytest.approx(start)
               for c in warm_up)
    text = (folder / "session.yaml").read_text().replace(f"power_on_t: {round(w.power_on_s, 6)}", "power_on_t: soon")
    (folder / "session.yaml").write_text(text)
    with pytest.raises(BadInput, match="session.yaml: field 'power_on_t' must be the time the stand was switched on"):
        load_poses(folder)


def test_predict_reads_the_time_since_the_sessions_power_on(calibration, tmp_path, capsys):
    # the session was switched on 100 s before its first command: --at-time 300 is 200 s after that command
    cal = calibration.replace("terms: []\n", WARMUP.replace("recorded_s: [0.0, 1200.0]",
                                                            "recorded_s: [0.0, 1200.0], since_power_on_at_start_s: 100.0"))
    rc, out = _predict(tmp_path, cal, "--at-time", "1250")
    assert rc == 0
    _, rows = _rows(out)
    assert rows[0]["thermal_note"] == "" and "beyond the recorded span (100 to 1300 s)" in rows[1]["thermal_note"]
    # a drift linear in the time since the session's first command: 1250 s after power-on is 1150 s after it
    keys = ("M1_x", "M1_y", "M1_z")
    said = LINEAR.replace("recorded_s: [0.0, 1200.0]", "recorded_s: [0.0, 1200.0], since_power_on_at_start_s: 100.0")
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", said), "--at-time", "1250")
    first = [_rows(out)[1][0][k] for k in keys]
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", LINEAR), "--at-time", "1150")
    assert [_rows(out)[1][0][k] for k in keys] == first
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", LINEAR), "--at-time", "1250")
    assert [_rows(out)[1][0][k] for k in keys] != first


def test_by_default_the_rows_t_are_read_on_the_sessions_clock(calibration, tmp_path, capsys):
    # the session's first command at t = 50 s, switched on 100 s before it
    cal = calibration.replace("terms: []\n", WARMUP.replace(
        "recorded_s: [0.0, 1200.0]", "recorded_s: [0.0, 1200.0], first_command_t: 50.0, since_power_on_at_start_s: 100.0"))
    (tmp_path / "cal.yaml").write_text(cal)
    (tmp_path / "later.csv").write_text("t,A,B,C\n650,2047.2,2047.2,2047.2\n750,1900,2100,2000\n")
    out = tmp_path / "p.csv"
    assert main(["predict", "--calibration", str(tmp_path / "cal.yaml"), "--commands", str(tmp_path / "later.csv"),
                 "--out", str(out)]) == 0
    assert "700 s since power-on at the first row, the rows' t read on the clock of the session" in capsys.readouterr().out
    _, rows = _rows(out)
    assert [r["since_power_on_s"] for r in rows] == ["700", "800"]


def test_warm_with_a_heat_of_work_that_kept_no_work_rate_is_refused(calibration, tmp_path, capsys):
    old = """terms:
- effect: thermal_drift
  where: {actuator: all, unit: count, cooling_time_constant_s: 600.0, stroke: [1600.0, 1600.0, 1600.0]}
  parameters:
    expansion_per_stroke: {value: 5.0, std: 0.1, unit: count}
"""
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", old), "--warm")
    assert rc == 2 and not out.exists()
    assert "--warm: the model's thermal_drift cannot say its equilibrium" in capsys.readouterr().err
    rc, out = _predict(tmp_path, calibration.replace("terms: []\n", old), "--at-time", "60")
    assert rc == 0
    _, rows = _rows(out)
    assert all(np.isfinite(float(r["M1_x"])) for r in rows)


def test_simulate_cli_plays_a_warm_up_and_says_its_power_on(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--physics", "--warmup", "visible", "--poses", "6", "--seed", "3",
                 "--out", str(out)]) == 0
    session = yaml.safe_load((out / "session.yaml").read_text())
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    assert session["power_on_t"] < 0  # switched on before the first command
    assert "form: warm-up with time" in (out / "truth.yaml").read_text()
    assert "thermal_drift" in str(truth)
    capsys.readouterr()
    assert main(["simulate", "--platform", "stewart", "--warmup", "warm", "--out", str(tmp_path / "t")]) == 2
    assert "--warmup: only with --physics" in capsys.readouterr().err
