"""Settling: windows where the stand is still, NaN-aware averages, drops with reasons."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from platkit.calibrate.settle import (
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
    from platkit.calibrate.settle import load_poses
    from platkit.simulate import simulate, write_session

    spec = get_platform("psvr")
    sim = simulate(spec, seed=1, n_poses=10, mocap_rate_hz=60)
    folder = write_session(sim, tmp_path / "psvr")
    poses = load_poses(folder)
    np.testing.assert_allclose(poses.markers, sim.poses.markers, atol=2e-9, equal_nan=True)
    assert set(poses.extras) >= {"direction", "last_step", "elapsed", "settle_time", "row"}
