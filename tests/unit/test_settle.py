"""Settling: windows where the stand is still, NaN-aware averages, drops with reasons."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from platkit.settle import (
    SettleOptions, direction_of_last_motion, estimate_noise, last_step, settle, still_mask,
)
from platkit.errors import BadSession
from platkit.io.session import Session
from platkit.plugins import get_platform

RATE = 100.0
SIGMA = 2e-4  # 0.2 mm


def _stream(targets, hold, rng, move=0.5, tau=0.1, sigma=SIGMA, occlude=None):
    """Markers (K, 3, 3) that travel between ``targets`` (N, 3) (one offset applied to three
    markers), minimum-jerk moves of ``move`` s then a decaying wiggle of time constant tau, held
    for ``hold[i]`` s after arriving; returns command times, t, markers, the true plateau."""
    body = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.1], [0.0, 0.4, 0.2]])
    t_cmd = [0.2]
    for h in hold[:-1]:
        t_cmd.append(t_cmd[-1] + move + h)
    t_cmd = np.array(t_cmd)
    t_end = t_cmd[-1] + move + hold[-1]
    t = np.arange(0, t_end, 1 / RATE)
    pos = np.zeros((len(t), 3))
    prev = np.zeros(3)
    for i, (tc, target) in enumerate(zip(t_cmd, targets)):
        sel = t >= tc
        s = np.clip((t[sel] - tc) / move, 0, 1)
        s = s**3 * (10 - 15 * s + 6 * s**2)
        after = np.maximum(t[sel] - tc - move, 0)
        wig = 0.08 * np.exp(-after / tau) * np.sin(2 * np.pi * 3 * after) * (after > 0)
        pos[sel] = prev + (s + wig)[:, None] * (target - prev)
        prev = target
    X = pos[:, None, :] + body[None] + rng.normal(size=(len(t), 3, 3)) * sigma
    if occlude is not None:
        X[occlude(t)] = np.nan
    return t_cmd, t, X, np.asarray(targets)[:, None, :] + body[None]


def _session(t_cmd, t, X, n_u=1):
    U = np.arange(len(t_cmd), dtype=float)[:, None].repeat(n_u, axis=1)
    return Session(folder=Path("synthetic"), platform="test", spec=None, description=None, length_unit="mm",
                   time_unit="s", marker_names=["A", "B", "C"], base_marker_names=[], mocap_rate_hz=RATE,
                   imu=None, moving_link=None, notes="", command_t=t_cmd, commands=U, marker_t=t, markers=X,
                   markers_source=Path("synthetic/markers.csv"))


def test_settled_means_match_the_plateaus_within_noise():
    rng = np.random.default_rng(0)
    targets = rng.uniform(-0.2, 0.2, size=(12, 3))
    t_cmd, t, X, truth = _stream(targets, [1.5] * 12, rng)
    poses, report = settle(_session(t_cmd, t, X))
    assert poses.n_poses == 12 and not poses.dropped
    err = poses.markers - truth
    # each average holds >= 50 samples: sigma / sqrt(50) = 0.028 mm per coordinate
    assert np.sqrt(np.mean(err**2)) < 0.045e-3
    assert np.max(np.abs(err)) < 0.15e-3
    # the window starts after the move (0.5 s) and after the wiggle has died into the noise
    assert np.all(poses.extras["settle_time"] > 0.6) and np.all(poses.extras["settle_time"] < 1.4)
    assert np.all(poses.extras["window_end"] <= np.append(t_cmd[1:], t[-1]))
    assert abs(report.sigma_m - SIGMA) < 0.1 * SIGMA
    assert poses.n_samples.min() >= 10


def test_noise_estimate_ignores_smooth_motion():
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.01)
    X = np.stack([np.sin(t), np.cos(0.5 * t), 0.1 * t], axis=1)[:, None, :] + rng.normal(size=(len(t), 1, 3)) * SIGMA
    assert abs(estimate_noise(X) - SIGMA) < 0.05 * SIGMA


def test_pure_noise_is_still_and_a_ramp_is_not():
    rng = np.random.default_rng(2)
    X = rng.normal(size=(400, 3, 3)) * SIGMA
    still = still_mask(X, 10, SIGMA, 1e-4)
    assert not still[0] and still[1:].mean() > 0.99
    ramp = X + (np.arange(400) * 5e-5)[:, None, None]  # 5 mm/s at 100 Hz, 0.5 mm per window
    assert not still_mask(ramp, 10, SIGMA, 1e-4)[11:-10].any()  # windows clipped at the end see less


def test_a_command_that_never_settles_is_dropped_with_a_reason():
    rng = np.random.default_rng(3)
    targets = rng.uniform(-0.2, 0.2, size=(6, 3))
    hold = [1.5, 1.5, 0.05, 1.5, 1.5, 1.5]  # row 2: the next command comes while still wiggling
    t_cmd, t, X, truth = _stream(targets, hold, rng)
    poses, _ = settle(_session(t_cmd, t, X))
    assert [r for r, _ in poses.dropped] == [2]
    assert "never settled" in poses.dropped[0][1]
    np.testing.assert_array_equal(poses.extras["row"], [0, 1, 3, 4, 5])


def test_motion_shortly_before_the_next_command_is_tolerated():
    rng = np.random.default_rng(8)
    targets = rng.uniform(-0.2, 0.2, size=(5, 3))
    t_cmd, t, X, truth = _stream(targets, [1.5] * 5, rng)
    # the motion-capture clock runs 0.1 s behind the command log: every move starts 0.1 s "early"
    poses, _ = settle(_session(t_cmd + 0.1, t, X))
    assert poses.n_poses == 5
    assert np.max(np.abs(poses.markers[1:] - truth[1:])) < 0.15e-3
    # 0.5 s early is not a clock offset: the stand left the command
    poses, _ = settle(_session(t_cmd + 0.5, t, X))
    assert [r for r, _ in poses.dropped] == [0, 1, 2, 3]
    assert all("moved again" in why for _, why in poses.dropped)


def test_a_recording_that_never_settles_is_an_error():
    rng = np.random.default_rng(4)
    t = np.arange(0, 10, 0.01)
    X = (np.sin(3 * t)[:, None, None] * 0.1 + np.zeros((1, 3, 3))) + rng.normal(size=(len(t), 3, 3)) * SIGMA
    with pytest.raises(BadSession, match="never settles"):
        settle(_session(np.array([0.5, 3.0, 6.0]), t, X))


def test_occluded_samples_are_skipped_and_counted():
    rng = np.random.default_rng(5)
    targets = rng.uniform(-0.2, 0.2, size=(4, 3))

    def occlude(t):
        mask = np.zeros((len(t), 3), bool)
        mask[:, 1] = (t > 2.0) & (t < 4.4)  # marker B hidden through the whole second hold
        mask[::7, 0] = True  # marker A flickers
        return mask

    t_cmd, t, X, truth = _stream(targets, [1.5] * 4, rng, occlude=occlude)
    poses, _ = settle(_session(t_cmd, t, X))
    assert poses.n_poses == 4
    assert np.all(np.isnan(poses.markers[1, 1])) and poses.n_samples[1, 1] == 0
    assert np.all(poses.n_samples[:, 0] < poses.n_samples[:, 2])
    ok = np.isfinite(poses.markers)
    assert np.max(np.abs(poses.markers[ok] - truth[ok])) < 0.15e-3


def test_commands_without_samples_are_dropped():
    rng = np.random.default_rng(6)
    targets = rng.uniform(-0.2, 0.2, size=(3, 3))
    t_cmd, t, X, _ = _stream(targets, [1.5] * 3, rng)
    t_cmd = np.append(t_cmd, t[-1] + 5.0)  # a command after the stream ended
    poses, _ = settle(_session(t_cmd, t, X))
    assert poses.dropped and poses.dropped[0][0] == 3 and "no motion-capture samples" in poses.dropped[0][1]


def test_direction_and_last_step_follow_the_history():
    U = np.array([[0, 5], [1, 5], [1, 4], [0.5, 4], [0.5, 6]], float)
    np.testing.assert_array_equal(direction_of_last_motion(U), [[0, 0], [1, 0], [1, -1], [-1, -1], [-1, 1]])
    np.testing.assert_array_equal(last_step(U)[3], [-0.5, 0])


def test_sigma_can_be_given():
    rng = np.random.default_rng(7)
    targets = rng.uniform(-0.2, 0.2, size=(3, 3))
    t_cmd, t, X, _ = _stream(targets, [1.5] * 3, rng)
    _, report = settle(_session(t_cmd, t, X), SettleOptions(sigma_m=1e-3))
    assert report.sigma_m == 1e-3


def test_settling_a_simulated_stand_session(tmp_path):
    from platkit.settle import load_poses
    from platkit.simulate import simulate, write_session

    spec = get_platform("psvr")
    sim = simulate(spec, seed=1, n_poses=10, mocap_rate_hz=60)
    folder = write_session(sim, tmp_path / "psvr")
    poses = load_poses(folder)
    np.testing.assert_allclose(poses.markers, sim.poses.markers, atol=2e-9, equal_nan=True)
    assert set(poses.extras) >= {"direction", "last_step", "elapsed", "settle_time", "row"}


# ---------------------------------------------------------------------------- physical approaches
def _approach_stream(targets, taus, rng, hold=2.5, sigma=5e-5, rate=RATE):
    """Markers (K, 3, 3) of a body whose offset follows each target (N, 3) as a critically damped
    approach with that hold's time constant (position and velocity carried from hold to hold):
    x(s) = target + (e0 + (v0 + e0 / tau) s) exp(-s / tau). Returns t_cmd, t, X, the true rest."""
    body = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.1], [0.0, 0.4, 0.2]])
    N = len(targets)
    t_cmd = 0.2 + hold * np.arange(N)
    t = np.arange(0, t_cmd[-1] + hold, 1 / rate)
    pos = np.zeros((len(t), 3))
    x, v = np.zeros(3), np.zeros(3)
    for i in range(N):
        sel = (t >= t_cmd[i]) & (t < t_cmd[i] + hold)
        s = t[sel] - t_cmd[i]
        e0, tau = x - targets[i], taus[i]
        c = v + e0 / tau
        E = np.exp(-s / tau)[:, None]
        pos[sel] = targets[i] + (e0 + c * s[:, None]) * E
        x = targets[i] + (e0 + c * hold) * np.exp(-hold / tau)
        v = (c - (e0 + c * hold) / tau) * np.exp(-hold / tau)
    X = pos[:, None, :] + body[None] + rng.normal(size=(len(t), 3, 3)) * sigma
    return t_cmd, t, X, np.asarray(targets)[:, None, :] + body[None]


def _along_step(poses, truth):
    """(n,) each pose's error (m) along its last step in marker space (all markers together)."""
    rows = poses.extras["row"].astype(int)
    step = (truth - np.vstack([np.zeros((1,) + truth.shape[1:]), truth[:-1]]))[rows].reshape(len(rows), -1)
    err = (poses.markers - truth[rows]).reshape(len(rows), -1)
    return np.sum(err * step, axis=1) / np.linalg.norm(step, axis=1)


def test_a_slow_tail_does_not_bias_the_settled_pose():
    # tau 0.15 s in 2.5 s holds: the neighbouring-halves test calls the stand still while it still
    # creeps the last micrometres, and a window starting there lags along the step by ~3 times the
    # averaging noise (what settle did before fitting the approach)
    rng = np.random.default_rng(11)
    N = 100
    targets = rng.uniform(-0.03, 0.03, size=(N, 3))
    t_cmd, t, X, truth = _approach_stream(targets, np.full(N, 0.15), rng)
    poses, report = settle(_session(t_cmd, t, X))
    assert poses.n_poses == N and not poses.dropped
    noise = report.sigma_m / np.sqrt(np.mean(poses.n_samples))  # one pose's averaging noise
    along = _along_step(poses, truth)
    # the mean over 100 poses is known to 1/sqrt(100) = 0.1 of the averaging noise
    assert abs(np.mean(along)) < 0.35 * noise
    assert abs(np.mean(along)) / (np.std(along) / np.sqrt(N)) < 3.5
    assert np.all(np.isfinite(poses.extras["approach_tau_s"]))
    assert 0.1 < np.median(poses.extras["approach_tau_s"]) < 0.25


def test_a_creeping_window_is_no_settled_pose():
    rng = np.random.default_rng(12)
    targets = rng.uniform(-0.03, 0.03, size=(6, 3))
    t_cmd, t, X, truth = _approach_stream(targets, np.full(6, 0.05), rng)
    sel = (t >= t_cmd[3]) & (t < t_cmd[3] + 2.5)
    X[sel] += ((t[sel] - t_cmd[3]) * 2e-4)[:, None, None]  # 0.2 mm/s drift through the whole hold 3
    poses, _ = settle(_session(t_cmd, t, X))
    assert [r for r, _ in poses.dropped] == [3]
    assert poses.dropped[0][1].startswith("never settled")


def _two_actuator_session(t_cmd, t, X, moves_b):
    """The session of a 2-control stand whose command changes u1 every row and u2 (back and forth) where ``moves_b``."""
    s = _session(t_cmd, t, X, n_u=2)
    U = np.column_stack([np.arange(len(t_cmd), dtype=float), (np.cumsum(moves_b) % 2).astype(float)])
    s.commands = U
    return s


def test_holds_that_never_settle_name_the_slow_actuator_and_its_time_constant():
    from platkit.errors import ComputationFailed

    rng = np.random.default_rng(13)
    N = 40
    moves_b = rng.random(N) < 0.7
    taus = np.where(moves_b, 1.2, 0.05)  # u2 approaches with tau about half the hold
    targets = rng.uniform(-0.03, 0.03, size=(N, 3))
    t_cmd, t, X, truth = _approach_stream(targets, taus, rng)
    with pytest.raises(ComputationFailed, match=r"holds never settled: actuator u2 still moving .*time constant of 1\.[12]"):
        settle(_two_actuator_session(t_cmd, t, X, moves_b))
    # without extrapolation the few that settle are no calibration either
    with pytest.raises(ComputationFailed, match="remnant"):
        settle(_two_actuator_session(t_cmd, t, X, moves_b), SettleOptions(extrapolate="never"))


def test_a_small_remaining_approach_is_extrapolated_to_rest():
    rng = np.random.default_rng(14)
    N = 30
    taus = np.full(N, 0.5)  # 2.5 s holds: about 0.04 of each step (0.2-1 mm) still to go at the next command
    steps = rng.normal(size=(N, 3))
    steps *= (rng.uniform(5e-3, 2e-2, N) / np.linalg.norm(steps, axis=1))[:, None]
    targets = np.cumsum(steps, axis=0)
    t_cmd, t, X, truth = _approach_stream(targets, taus, rng)
    poses, report = settle(_session(t_cmd, t, X))
    ex = poses.extras["extrapolated"] > 0
    assert report.n_extrapolated == ex.sum() >= 0.8 * N
    assert report.unsettled["n"] >= 0.8 * N and abs(report.unsettled["time_constant_s"] - 0.5) < 0.1
    err = np.linalg.norm(poses.markers[ex] - truth[poses.extras["row"][ex].astype(int)], axis=2)
    std = report.sigma_m / np.sqrt(poses.n_samples[ex])  # the uncertainty settle gave each extrapolation
    assert np.median(err / (np.sqrt(3) * std)) < 2.0
    # a plain window average of the last second would be this far off
    assert np.median(err) < 0.3 * np.median(report.unsettled["remaining_m"])


def test_dropped_commands_are_counted_by_reason():
    from platkit.settle import dropped_by_reason, dropped_sentence

    dropped = [(1, "never settled: x"), (4, "moved again: y"), (7, "never settled: z")]
    assert dropped_by_reason(dropped) == {"never settled": 2, "moved again": 1}
    assert dropped_sentence(dropped, 10) == "3 of 10 commands gave no settled pose: 2 never settled, 1 moved again"
    assert dropped_sentence([], 10) == ""


def test_calibrate_counts_the_dropped_commands_on_stderr_in_report_json_and_html(tmp_path, capsys):
    import json

    from platkit.cli import main
    from platkit.simulate import simulate_session

    folder = tmp_path / "psvr"
    simulate_session(get_platform("psvr"), folder, seed=3, n_poses=16, mocap_rate_hz=60)
    lines = (folder / "commands.csv").read_text().splitlines()
    last_t = float(lines[-1].split(",")[0])
    extra = [",".join([f"{last_t + 60 + 2 * k:.3f}"] + lines[-1].split(",")[1:]) for k in range(2)]
    (folder / "commands.csv").write_text("\n".join(lines + extra) + "\n")  # two commands after the stream ended
    out = tmp_path / "cal"
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    n = len(lines) - 1 + 2
    assert f"2 of {n} commands gave no settled pose: 2 no motion-capture samples" in err
    rep = json.loads((out / "report.json").read_text())
    st = rep["settling"]
    assert st["n_commands"] == n and st["n_poses"] == n - 2 and st["dropped_by_reason"] == {"no motion-capture samples": 2}
    assert [d["row"] for d in st["dropped"]] == [n - 1, n]
    assert "2 dropped: 2 no motion-capture samples" in (out / "report.html").read_text()


def test_calibrate_refuses_a_remnant(tmp_path, capsys):
    from platkit.cli import main
    from platkit.simulate import simulate_session

    folder = tmp_path / "psvr"
    simulate_session(get_platform("psvr"), folder, seed=4, n_poses=12, mocap_rate_hz=60)
    lines = (folder / "commands.csv").read_text().splitlines()
    last_t = float(lines[-1].split(",")[0])
    extra = [",".join([f"{last_t + 60 + 2 * k:.3f}"] + lines[-1].split(",")[1:]) for k in range(len(lines))]
    (folder / "commands.csv").write_text("\n".join(lines + extra) + "\n")  # more commands without samples than with
    assert main(["calibrate", str(folder), "--quiet", "--no-selection", "--out", str(tmp_path / "cal")]) == 1
    err = capsys.readouterr().err
    assert "no motion-capture samples" in err and "remnant" in err and not (tmp_path / "cal").exists()


def test_the_window_can_be_capped_to_the_end_of_the_hold():
    rng = np.random.default_rng(15)
    targets = rng.uniform(-0.03, 0.03, size=(5, 3))
    t_cmd, t, X, truth = _approach_stream(targets, np.full(5, 0.05), rng)
    poses, _ = settle(_session(t_cmd, t, X), SettleOptions(max_window_s=0.5))
    span = poses.extras["window_end"] - poses.extras["window_start"]
    assert poses.n_poses == 5 and np.all(span <= 0.5) and np.all(span >= 0.45)
    assert np.all(poses.extras["window_end"] > t_cmd + 2.0)  # the last half second of each 2.5 s hold


def test_settled_poses_of_a_physical_session_lag_the_true_rest_by_under_a_tenth_of_their_noise():
    # the physical simulator (drives with their own damped responses, coloured noise): the tail of
    # each approach is below each hold's own noise, but every window that starts in it lags the
    # same way. The bias is measured without the noise: the noise-free stream (same seed, noise
    # off) averaged over the windows settle chose, against the true rest, along the last step; in
    # units of the spread of the settled poses' errors. Before the tail bound and the pooled tail
    # timed from arrival this session lagged by 0.36 of the noise (the last second's mean: ~0).
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    spec = get_platform("psvr")
    sim = simulate_physics(spec, seed=700004, n_poses=120, plan="random")
    calm = simulate_physics(spec, seed=700004, n_poses=120, plan="random", noise_mm=1e-9, occlusion=0.0)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        poses, _ = settle(load_session(write_physical_session(sim, Path(tmp) / "s")))
    assert poses.n_poses == 120
    assert abs(_tail_along_step(poses, sim, calm)) < 0.1


def _tail_along_step(poses, sim, calm):
    """The noise-free stream averaged over the windows settle chose, minus the true rest, along
    each command's last step, mean over the poses, in units of the spread of the settled poses'
    errors along it (benchmarks/settle_bias.py's 'tail')."""
    T = sim.settled_markers
    rows = poses.extras["row"].astype(int)
    step = (T - np.vstack([T[:1], T[:-1]]))[rows].reshape(len(rows), -1)
    keep = np.linalg.norm(step, axis=1) > 0
    unit = step[keep] / np.linalg.norm(step[keep], axis=1)[:, None]
    err = np.sum((poses.markers - T[rows]).reshape(len(rows), -1)[keep] * unit, axis=1)
    tail = []
    for k, i in enumerate(rows[keep]):
        sel = ((calm.marker_t >= poses.extras["window_start"][keep][k])
               & (calm.marker_t <= poses.extras["window_end"][keep][k]))
        tail.append(np.mean((calm.markers[sel] - T[i]).reshape(sel.sum(), -1) @ unit[k]))
    return float(np.mean(tail) / np.std(err))


def test_short_holds_whose_session_bears_out_its_tails_let_the_bound_cut_deeper(tmp_path):
    # psvr with 2 s holds: the tail bound would leave 25-40% of many still stretches, where the
    # estimate used to decide (each hold alone hardly supports its tail) and the window started
    # in the tail. Pooled over the session the still stretches bear their fitted tails out by
    # dozens of standard errors, and the bound's cut stands. Measured: -0.207 -> -0.058.
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    spec = get_platform("psvr")
    sim = simulate_physics(spec, seed=700205, n_poses=60, plan="random", hold_s=2.0)
    calm = simulate_physics(spec, seed=700205, n_poses=60, plan="random", hold_s=2.0, noise_mm=1e-9, occlusion=0.0)
    session = load_session(write_physical_session(sim, tmp_path / "s"))
    poses, _ = settle(session, SettleOptions(max_window_s=None))  # the bound's cut alone, no length limit
    alone, _ = settle(session, SettleOptions(tail_evidence_z=np.inf, max_window_s=None))  # never the deeper cut
    assert poses.n_poses == alone.n_poses == 60
    assert abs(_tail_along_step(poses, sim, calm)) < 0.1 < abs(_tail_along_step(alone, sim, calm))


def test_a_long_still_stretch_is_averaged_over_its_last_one_and_a_half_seconds(tmp_path):
    # psvr, holds of 2-5 s, rate-limited moves ending in an overdamped approach: several windows
    # started where the approach was still a fifth of a millimetre from rest (its tail below the
    # stillness test) and lagged their hold by 10-15 um along the step. The window is at most
    # max_window_s (1.5 s) long, ending where the hold does. Measured: -0.135 -> -0.046.
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    spec = get_platform("psvr")
    sim = simulate_physics(spec, seed=700316, n_poses=60, plan="random")
    calm = simulate_physics(spec, seed=700316, n_poses=60, plan="random", noise_mm=1e-9, occlusion=0.0)
    session = load_session(write_physical_session(sim, tmp_path / "s"))
    capped, _ = settle(session)
    whole, _ = settle(session, SettleOptions(max_window_s=None))
    assert capped.n_poses == whole.n_poses
    assert np.nanmax(capped.extras["window_end"] - capped.extras["window_start"]) <= 1.5 + 1e-9
    assert abs(_tail_along_step(capped, sim, calm)) < 0.08 < 0.1 < abs(_tail_along_step(whole, sim, calm))


def test_a_wobble_fitted_as_a_decay_keeps_its_windows():
    # the additive simulator's example session: short holds, a wobble the approach fit takes for
    # a decay; the still stretches, pooled, do not bear those tails out, so no window is cut
    # deeper than bound_keeps (cutting anyway loses a fifth of the samples)
    from platkit.io.session import example_session, load_session

    session = load_session(example_session("stewart"))
    kept, always, never = (settle(session, SettleOptions(tail_evidence_z=z))[0] for z in (3.0, -np.inf, np.inf))

    def samples(p):
        return float(np.nansum(p.extras["window_end"] - p.extras["window_start"]))

    assert np.array_equal(kept.markers, never.markers, equal_nan=True)
    assert samples(always) < 0.9 * samples(kept)


def test_a_slow_actuator_of_a_physical_session_is_named_with_its_time_constant(tmp_path):
    # one drive slow (settling_lag: its time constant a tenth of the hold): most holds never
    # settle, every actuator moves in every command (no contrast between holds), and the old
    # search said "no one actuator stands out". What the markers still move late in each hold
    # lies along that actuator's column of the Jacobian the session itself shows.
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=700102, n_poses=60, plan="random", effects=[("settling_lag", 0.1)])
    poses, report = settle(load_session(write_physical_session(sim, tmp_path / "s")))
    slow = sim.response.to_dict(spec.control_names)["L3"]
    zeta = slow["damping"]
    mode = slow["tau_s"] / (zeta - np.sqrt(zeta**2 - 1))  # the slowest part of its approach decays so
    un = report.unsettled
    assert un["actuators"] == ["L3"] and "actuator L3 still moving" in un["sentence"]
    assert abs(un["time_constant_s"] / mode - 1) < 0.3
    assert report.n_extrapolated >= 0.8 * un["n"] and poses.n_poses >= 55
    from platkit.settle import settling_summary

    late = settling_summary(poses)["unsettled"]["moved_late_along_actuator"]  # report.json, mm
    assert max(late, key=lambda k: late[k]) == "L3" and late["L3"] > 0


def test_a_session_of_slow_drives_and_short_holds_is_not_refused(tmp_path):
    # no slow actuator, 2 s holds, drives at the slow end of the drawn range, and the motion
    # capture's clock 0.13 s ahead of the command log: the next move starts in the last samples
    # of each hold, where the still test's clipped half-window flickers "still" for a sample.
    # The old search took that flicker for the last still stretch and refused the session
    # (19 of 60 holds "never settled").
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    sim = simulate_physics(get_platform("rotary"), seed=700203, n_poses=60, plan="random", hold_s=2.0)
    assert sim.nuisances.time_shift_s < -0.1
    poses, report = settle(load_session(write_physical_session(sim, tmp_path / "s")))
    assert poses.n_poses == 60 and not poses.dropped and report.n_extrapolated == 0
    err = np.linalg.norm(poses.markers - sim.settled_markers, axis=2)
    assert np.nanmedian(err) < 0.1e-3


def test_attribution_names_the_actuator_whose_column_the_late_motion_follows():
    from platkit.settle import attribute_actuators

    rng = np.random.default_rng(21)
    N, n_u = 50, 3
    U = rng.uniform(0, 1, size=(N, n_u))
    A = rng.normal(size=(9, n_u)) * 0.1  # a linear stand: 3 markers, m per unit of control
    held = (U @ A.T).reshape(N, 3, 3)
    du = np.vstack([np.zeros((1, n_u)), np.diff(U, axis=0)])
    lagging = {i: (-0.02 * A[:, 1] * du[i, 1] + rng.normal(size=9) * 2e-5).reshape(3, 3) for i in range(1, N)}
    named, table = attribute_actuators(U, held, lagging)
    assert named == [1] and table["positive"][1] > 0.9 and table["p"][1] < 1e-6
    noise = {i: rng.normal(size=(3, 3)) * 2e-5 for i in range(1, N)}  # nothing moves along any column
    assert attribute_actuators(U, held, noise)[0] == []


def test_approach_fits_of_many_holds_at_once_are_each_holds_own_fit():
    # stretches of different lengths, decays and noise, with and without occluded samples, a
    # marker seen too little, one with its time constant given and one too short: fitted together
    # (batched, padded) each gives the fit it gives alone
    from platkit.settle import fit_approach
    from platkit.settle._fits import fit_approaches

    rng = np.random.default_rng(2801)
    stretches = []
    for j in range(12):
        K = int(rng.integers(40, 400))
        t = 3.0 + np.arange(K) / RATE
        tau = float(rng.uniform(0.05, 1.0))
        s = t - t[0]
        amp = rng.normal(size=(4, 3)) * 1e-3 * (j % 3)  # every third without a decay
        X = 0.1 * rng.normal(size=(1, 4, 3)) + amp[None] * ((1 + 2 * s / tau) * np.exp(-s / tau))[:, None, None]
        X = X + rng.normal(size=X.shape) * SIGMA
        if j % 2:
            X[rng.random((K, 4)) < 0.1] = np.nan
        if j == 5:
            X[5:, 2] = np.nan  # a marker seen for five samples only
        stretches.append((t, X, SIGMA, t[-1] + 0.05, 0.3 if j == 7 else None))
    stretches.append((np.arange(6) / RATE, np.zeros((6, 4, 3)), SIGMA))  # too short to fit
    together = fit_approaches(stretches)
    assert together[-1] is None and fit_approach(*stretches[-1]) is None
    assert together[7].tau == 0.3
    assert {f.significant for f in together[:-1]} == {True, False}
    for x, f in zip(stretches[:-1], together[:-1]):
        alone = fit_approach(*x)
        assert f.tau == pytest.approx(alone.tau, rel=1e-9) and f.significant == alone.significant
        assert f.at_limit == alone.at_limit
        np.testing.assert_allclose(f.x_inf, alone.x_inf, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.a, alone.a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.b, alone.b, rtol=0, atol=1e-12)
        assert f.chi2_per_dof == pytest.approx(alone.chi2_per_dof, rel=1e-9)
    assert np.isnan(together[5].x_inf[2]).all() and np.isfinite(together[5].x_inf[[0, 1, 3]]).all()
