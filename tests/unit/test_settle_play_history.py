"""Settled poses carry a play's memory over the whole command log (platkit.settle, extras 'play'):
commands that gave no pose are in it, however many in a row, so the backlash term's play
(platkit_effects.drive.BacklashTerm) sees a reversal made while the markers were hidden."""
from __future__ import annotations

import numpy as np

from platkit.effects import command_order, play_memory, with_history
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.settle import settle
from platkit.simulate.physics import simulate_physics, write_physical_session


def test_commands_without_a_pose_are_in_the_play(tmp_path):
    spec = get_platform("psvr")
    sim = simulate_physics(spec, seed=5620001, n_poses=40, plan="random")
    session = load_session(write_physical_session(sim, tmp_path / "s"), quiet=True)
    T = session.command_t
    hidden = (session.marker_t >= T[5]) & (session.marker_t < T[8])  # commands 5, 6 and 7: no markers
    session.markers[hidden] = np.nan
    poses, _ = settle(session)
    rows = poses.extras["row"]
    assert not np.isin([5, 6, 7], rows).any() and 8 in rows
    U = session.commands  # the whole log, in the controls' internal units
    np.testing.assert_allclose(U[rows], poses.controls)
    np.testing.assert_array_equal(poses.extras["play"], play_memory(U, rows))
    # what the poses alone give (one command put back before the gap) is not the whole log
    assert not np.array_equal(play_memory(*command_order(poses)), poses.extras["play"])
    # the history keeps the settled memory, and a subset of the poses keeps it row by row
    kept = with_history(poses, spec)
    np.testing.assert_array_equal(kept.extras["play"], poses.extras["play"])
    np.testing.assert_array_equal(kept.subset([2, 5]).extras["play"], poses.extras["play"][[2, 5]])
