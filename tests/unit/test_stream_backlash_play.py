"""A backlash on a stream: within a move just after a turn the drive is still taking up its play,
so the actuator stays where it was until the commands have travelled the play's width back. The
term reads each move's turning point and reach from the command log (extras['run'],
platkit.calibrate.stream.commanded_direction) and places the play's output within the move, as the
simulator's deadband (platkit_effects.physics.play_operator) does; the direction alone (half_play
times +-1) is wrong by up to the whole play there."""
from __future__ import annotations

import numpy as np

from platkit.calibrate.stream import commanded_direction
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects.drive import Backlash
from platkit_effects.physics import play_operator


def _log():
    """A 40 Hz log of one actuator (stroke 1.5 m: DIRECTION_TRAVEL's travel 1.5 mm): up 6 mm, a
    slow turn, down 6 mm, a dither of 0.6 mm (under the play's width), up again."""
    T = np.arange(0.0, 12.0, 0.025)
    dither = np.where((T > 9.0) & (T < 10.0), 0.3e-3 * np.sin(2 * np.pi * (T - 9.0)), 0.0)
    x = 0.2 + 3e-3 * np.sin(2 * np.pi * T / 8.0) + dither
    return T, x


def _poses(d, run=None):
    """Poses of the stewart at rest whose extras carry the log's direction (and runs) on every actuator."""
    n_u = get_platform("stewart").n_u
    extras = {"direction": np.repeat(d, n_u, axis=1)}
    if run is not None:
        extras["run"] = np.repeat(run, n_u, axis=1)
    return PoseSet(platform="stewart", controls=np.full((len(d), n_u), 0.2), markers=np.zeros((len(d), 1, 3)),
                   marker_names=["M1"], extras=extras), n_u


def test_the_play_is_taken_up_within_a_move_as_the_deadband_does():
    T, x = _log()
    play = 1e-3
    truth = play_operator(x, play, x[0] - 0.5 * play) - x  # taken up upwards at the start
    d, run = commanded_direction(T, x[:, None], T, np.zeros(1), np.array([1.5]), runs=True)
    assert run.shape == (len(T), 1, 2)
    poses, n_u = _poses(d, run)
    term = Backlash().term(0, {"actuator": "L1", "actuator_index": 0, "unit": "m"})
    got = term.control_offset(np.array([-0.5 * play]), poses, n_u)[:, 0]
    moved = d[:, 0] != 0
    np.testing.assert_allclose(got[moved], truth[moved], atol=1e-9)
    turning = moved & (np.abs(np.abs(truth) - 0.5 * play) > 1e-6)  # within a move, taking up the play
    assert turning.sum() >= 5
    # the direction alone misses there by up to the whole play
    assert np.max(np.abs(-0.5 * play * d[turning, 0] - truth[turning])) > 0.8 * play
    # the mirror (a positive half_play) and the limit at 0
    np.testing.assert_allclose(term.control_offset(np.array([0.5 * play]), poses, n_u)[:, 0], -got, atol=1e-12)
    np.testing.assert_array_equal(term.control_offset(np.zeros(1), poses, n_u)[:, 0], 0.0)


def test_without_runs_the_direction_alone_as_before():
    T, x = _log()
    d = commanded_direction(T, x[:, None], T, np.zeros(1), np.array([1.5]))
    poses, n_u = _poses(d)
    term = Backlash().term(0, {"actuator": "L1", "actuator_index": 0, "unit": "m"})
    np.testing.assert_array_equal(term.control_offset(np.array([-5e-4]), poses, n_u)[:, 0], -5e-4 * d[:, 0])
