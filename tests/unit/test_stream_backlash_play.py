"""A backlash on a stream: the play is a deadband in the drive (platkit_effects.physics.play_operator),
whose input is the drive's position, not its command: an underdamped drive overshoots each turn of
its commands and swings back, and a play turns at every reversal, however small. At a stream's node
the term carries the settled sessions' play (platkit.play.play_memory, play_offset) from the
memory at the first sample the node's window weighs through the drive's positions at its samples
(platkit.diagnose.stream.stream_play), and weighs it as the controls are weighed; the step
(half_play times the commanded direction) misses by up to the whole play within a take-up."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy import sparse

from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.stream import NODES, window_fit
from platkit.effects import with_history
from platkit.play import play_cut, play_memory
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects.drive import Backlash
from platkit_effects.physics import play_operator

PLAY = 1e-3
RATE = 200.0


def _stream():
    """A 40 Hz command log of six actuators: actuator 0 swings 3 mm with a period of 2.5 s plus a
    0.6 mm wobble at 1.3 Hz (reversals between the play's width and more), the others hold; an
    underdamped second-order response (tau 0.08 s, damping 0.3, shift 30 ms) at 200 Hz samples from
    0.5 s, reduced to 1 s windows of NODES nodes (platkit.calibrate.stream.window_fit) as rows of a
    projection."""
    T = np.arange(0.0, 12.0, 0.025)
    U = np.full((len(T), 6), 0.2)
    U[:, 0] += 3e-3 * np.sin(2 * np.pi * T / 2.5) + 0.6e-3 * np.sin(2 * np.pi * 1.3 * T)
    model = ResponseModel("second_order", "step", 6)
    theta = np.concatenate([[0.03], np.full(6, 0.08), np.full(6, 0.3)])
    sample_t = 0.5 + np.arange(int(11 * RATE)) / RATE
    blocks = [window_fit(sample_t[w * int(RATE):(w + 1) * int(RATE)], NODES)[0] for w in range(11)]
    proj = sparse.csr_matrix(sparse.block_diag(blocks))
    return SimpleNamespace(model=model, initial=theta, T=T, U=U, proj=proj, sample_t=sample_t, start=None)


def test_the_play_at_a_node_is_the_deadband_at_the_drive_positions_weighed_as_the_controls():
    from platkit.diagnose.stream import stream_direction, stream_play

    term = _stream()
    X = actuator_positions(term.model, term.initial, term.T, term.U, term.sample_t)
    truth = term.proj @ (play_operator(X[:, 0], PLAY, X[0, 0]) - X[:, 0])  # at each node
    node = np.arange(term.proj.shape[0])[::-1]  # in any order
    memory, path, weight = stream_play(term, node)
    assert path.shape[:2] == (len(node), 6) and weight.shape == (len(node), path.shape[2])
    direction = stream_direction(SimpleNamespace(command_t=term.T, commands=term.U), term, get_platform("stewart"),
                                 (term.proj @ term.sample_t)[node])
    poses = PoseSet("stewart", term.proj[node] @ X, np.zeros((len(node), 1, 3)), ["M1"],
                    extras={"node": node, "direction": direction, "play": memory, "play_path": path,
                            "play_weight": weight})
    poses = with_history(poses, get_platform("stewart"))  # the stream's memory kept, not the step's NaN
    b = Backlash().term(0, {"actuator": "L1", "actuator_index": 0, "unit": "m"})
    got = b.control_offset(np.array([-0.5 * PLAY]), poses, 6)[:, 0]
    np.testing.assert_allclose(got, truth[node], atol=1e-9)
    # the step misses by most of the play where the play is being taken up
    assert np.max(np.abs(-0.5 * PLAY * direction[:, 0] - truth[node])) > 0.5 * PLAY
    # a fold keeps each node's own memory and samples
    rows = np.array([4, 9, 20, 31])
    np.testing.assert_allclose(b.control_offset(np.array([-0.5 * PLAY]), poses.subset(rows), 6)[:, 0], got[rows],
                               atol=1e-15)
    # the mirror (a positive half_play), the limit at 0, and the actuators that never moved
    np.testing.assert_allclose(b.control_offset(np.array([0.5 * PLAY]), poses, 6)[:, 0], -got, atol=1e-15)
    np.testing.assert_allclose(b.control_offset(np.zeros(1), poses, 6)[:, 0], 0.0, atol=1e-15)
    other = Backlash().term(3, {"actuator": "L4", "actuator_index": 3, "unit": "m"})
    np.testing.assert_allclose(other.control_offset(np.array([-0.5 * PLAY]), poses, 6)[:, 3], 0.0, atol=1e-15)


def test_a_memory_cut_at_its_depth_is_counted():
    # a decaying oscillation: every swing narrower than the one before, all nested
    x = (0.5 ** np.arange(12) * (-1.0) ** np.arange(12))[:, None]
    at = np.array([3, 11])
    assert not play_cut(play_memory(x, at)).any()
    cut = play_memory(x, at, depth=4)
    np.testing.assert_array_equal(play_cut(cut)[:, 0], [False, True])
    assert cut.shape[2] == 5  # four turning points and the start
