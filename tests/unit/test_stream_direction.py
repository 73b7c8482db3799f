"""The direction of an actuator's last move at a stream's windowed poses (a history effect's
'direction', such as backlash reads): from the command log through the actuator's response lag, not
from the controls the response reaches at the windows. An underdamped response overshoots its last
command and swings back while the stand rests: the windows' fitted controls fall there, while the
last command moved the actuator up."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.stream import NODES, window_fit
from platkit.effects import move_direction
from platkit.plugins import get_platform


def _stream():
    """A 40 Hz command log of six actuators: actuator 0 rises 5.3 mm over 2 s, then rests for 4 s;
    actuator 1 falls 5 mm over 2 s, then dithers 0.4 mm about where it stopped (under
    DIRECTION_TRAVEL of the stroke, 1.5 mm); the others hold. An underdamped second-order response
    (tau 0.1 s, damping 0.3, shift 30 ms), its positions at 200 Hz samples reduced to 1 s windows of
    NODES nodes (platkit.calibrate.stream)."""
    T = np.arange(0.0, 6.0, 0.025)
    U = np.full((len(T), 6), 0.2)
    U[:, 0] += np.clip(T / 2.0, 0.0, 1.0) * 5.3e-3
    U[:, 1] -= np.clip(T / 2.0, 0.0, 1.0) * 5e-3 - np.where(T > 2.0, 0.4e-3 * np.sin(2 * np.pi * (T - 2.0)), 0.0)
    model = ResponseModel("second_order", "step", 6)
    theta = np.concatenate([[0.03], np.full(6, 0.1), np.full(6, 0.3)])
    ts, controls = [], []
    for a in np.arange(0.5, 5.5, 1.0):
        t = a + np.arange(200) / 200.0
        A, _ = window_fit(t, NODES)
        x = actuator_positions(model, theta, T, U, t)
        half = 0.5 / 200.0
        ts.append(t[0] - half + (np.polynomial.legendre.leggauss(NODES)[0] + 1.0) * 0.5 * (t[-1] - t[0] + 2 * half))
        controls.append(A @ x)
    return T, U, model, theta, np.concatenate(ts), np.concatenate(controls)


def test_the_last_move_is_read_from_the_command_log_not_the_fitted_overshoot():
    from platkit.diagnose.stream import stream_direction

    spec = get_platform("stewart")
    T, U, model, theta, t, controls = _stream()
    rest = t > 3.0  # the stand at rest after the last command (2 s) and its swing
    # the windows' fitted controls swing back down at rest: the old reading turned the direction
    assert (move_direction(controls, spec)[rest, 0] < 0).any()
    d = stream_direction(SimpleNamespace(command_t=T, commands=U), SimpleNamespace(model=model, initial=theta), spec, t)
    assert d.shape == controls.shape
    np.testing.assert_array_equal(d[t > 1.0, 0], 1.0)  # moved up, then rested: up
    np.testing.assert_array_equal(d[t > 1.0, 1], -1.0)  # moved down; its dither under the travel is no move
    assert (move_direction(controls, spec)[rest, 1] > 0).any()  # where the fitted controls' reading turns
    np.testing.assert_array_equal(d[:, 2:], 0.0)  # never moved
