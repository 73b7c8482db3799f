"""The backlash term is a play over the session's commands in order (platkit_effects.drive.BacklashTerm,
platkit.play.play_memory): a reversal shorter than the play leaves the output where it was, the
history is the whole session's (a subset of rows, a command that gave no pose), and the estimator fits
the half play of a drive whose short reversals a sign of the last move cannot give."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.diagnose import effect_library
from platkit.effects import with_history
from platkit.play import play_memory as PLAY_MEMORY
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.physics import simulate_physics

#: B's commands (counts) and, by hand, the offset of a play of half width 2 (y = clamp(y, u - 2, u + 2))
B_COMMANDS = [1000.0, 1010.0, 1004.0, 1006.0, 990.0, 992.0, 1020.0]
B_OFFSETS = [0.0, -2.0, 2.0, 0.0, 2.0, 0.0, -2.0]


def _poses(spec, b, **extras):
    U = np.tile(np.array([2000.0, 0.0, 2000.0]), (len(b), 1))
    U[:, 1] = b
    return PoseSet(spec.name, U, np.zeros((len(b), 1, 3)), ["m1"], extras=extras)


def _backlash(spec, poses):
    return next(t for t in effect_library()["backlash"].candidates(spec, poses) if t.where["actuator"] == "B")


def test_a_reversal_shorter_than_the_play_keeps_the_output():
    spec = get_platform("psvr")
    poses = with_history(_poses(spec, B_COMMANDS), spec)
    term = _backlash(spec, poses)
    off = term.control_offset(np.array([-2.0]), poses, spec.n_u)
    np.testing.assert_allclose(off[:, 1], B_OFFSETS, atol=1e-12)
    assert not off[:, [0, 2]].any()
    # a subset (a fold, held-out rows) keeps the whole session's history
    rows = np.array([3, 5, 6])
    np.testing.assert_allclose(term.control_offset(np.array([-2.0]), poses.subset(rows), spec.n_u)[:, 1],
                               np.array(B_OFFSETS)[rows], atol=1e-12)
    # a long move reads as before: half_play times the direction; the offset is odd in half_play
    np.testing.assert_allclose(term.control_offset(np.array([2.0]), poses, spec.n_u)[:, 1], -np.array(B_OFFSETS))


def test_a_command_that_gave_no_pose_is_in_the_history():
    # rows 2 (B at 1004) gave no pose: the settled session carries each row's command row and the
    # step that led to it from the full log, and the play still sees the reversal to 1004
    spec = get_platform("psvr")
    full = _poses(spec, B_COMMANDS)
    steps = np.diff(np.vstack([full.controls[:1], full.controls]), axis=0)
    kept = np.array([0, 1, 3, 4, 5, 6])
    poses = with_history(_poses(spec, np.array(B_COMMANDS)[kept], row=kept, last_step=steps[kept]), spec)
    off = _backlash(spec, poses).control_offset(np.array([-2.0]), poses, spec.n_u)
    np.testing.assert_allclose(off[:, 1], np.array(B_OFFSETS)[kept], atol=1e-12)


@pytest.fixture(scope="module")
def short_reversals():
    """A psvr in the time-domain simulator with a play of 60 counts on one actuator, every command
    followed by one that reverses every actuator by 20 counts (a third of the play): settled poses,
    0.02 mm noise."""
    spec = get_platform("psvr")
    base = simulate_physics(spec, seed=5400911, n_poses=40, plan="random").commands
    back = base - 20.0 * np.sign(np.diff(np.vstack([base[:1], base]), axis=0))
    U = np.empty((2 * len(base), spec.n_u))
    U[0::2], U[1::2] = base, back
    sim = simulate_physics(spec, seed=5400911, plan=U, effects=[("backlash", 60.0)])
    noisy = sim.settled_markers + np.random.default_rng(2).normal(0, 2e-5, sim.settled_markers.shape)
    poses = with_history(PoseSet(spec.name, U, noisy, list(sim.marker_names), t=sim.command_t,
                                 length_unit=sim.length_unit, source="test"), spec)
    return spec, poses, dict(sim.physics)["backlash"].parameters()


def test_the_estimator_recovers_the_half_play_a_sign_cannot_give(short_reversals):
    spec, poses, truth = short_reversals
    term = next(t for t in effect_library()["backlash"].candidates(spec, poses)
                if t.where["actuator"] == truth["actuator"])
    cal = calibrate(poses, spec, terms=[term])
    assert cal.theta[0][0] == pytest.approx(truth["model_half_play"], rel=0.01)
    assert cal.rms_after < 4e-5  # the noise (0.02 mm a coordinate: 0.035 mm a point); a sign of the last move leaves 0.25 mm


def test_the_play_memory_is_built_once_for_poses_without_history(monkeypatch):
    # a caller of the estimator that gives poses without with_history: the problem builds the
    # history once, and every evaluation (the forward differences in half_play included) reads it
    import platkit.effects as effects
    from platkit.calibrate.problem import CalibrationProblem

    spec = get_platform("psvr")
    bare = _poses(spec, B_COMMANDS)
    term = _backlash(spec, with_history(bare, spec))
    built = []
    monkeypatch.setattr(effects, "play_memory", lambda *a, **k: built.append(1) or PLAY_MEMORY(*a, **k))
    problem = CalibrationProblem(spec, bare, [term])
    z = problem.nominal.copy()
    states = []
    for h in (-2.0, -1.0, 3.0):
        z[problem.i_theta] = h
        states.append(problem.evaluate(z))
    assert len(built) == 1
    given = CalibrationProblem(spec, with_history(bare, spec), [term])
    for h, state in zip((-2.0, -1.0, 3.0), states):
        z[problem.i_theta] = h
        np.testing.assert_array_equal(given.evaluate(z).r, state.r)
