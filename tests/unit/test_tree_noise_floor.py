"""The markers' own noise on a tree (platkit.calibrate.estimate.marker_noise_floor) and the rule it
serves in a calibration from motion (platkit.calibrate.motion, the command log that does not explain
the motion).

On a tree the markers ride several links: a pair across two links changes its distance with the
pose, so the floor is taken over the pairs on one link. Taken over every pair it read the motion
(~90 mm against 0.17 mm of noise on the stream below), and a stream calibrated against another
recording's command log, its markers off by centimetres, was calibrated without a word. The tree
is tests/unit/test_tree_stream.py's (a torso yaw, a head that moves no marker, two 2-joint arms,
both tool links tracked), streamed by the physical simulator (multisine, 0.1 mm white noise)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from platkit.calibrate.estimate import fit_warnings, marker_noise_floor, pair_noise
from platkit.calibrate.motion import calibrate_motion
from platkit.errors import BadSession
from platkit.io.session import load_session
from platkit.poses import PoseSet
from platkit.simulate.physics import simulate_physics, write_physical_session
from tests.unit.test_tree_stream import URDF, stand

NOISE_M = 1e-4  # per axis


@pytest.fixture(scope="module")
def streams(tmp_path_factory):
    """Two seeds' streams of the tree (seed 41 and 42: each its own true stand and command log)."""
    tmp = tmp_path_factory.mktemp("floor")
    urdf = tmp / "small_tree.urdf"
    urdf.write_text(URDF)
    spec = stand(urdf)
    out = {}
    for seed in (41, 42):
        sim = simulate_physics(spec, seed=seed, motion="multisine", duration_s=12.0, n_markers=6, noise_mm=1e3 * NOISE_M,
                               coloured=False)
        write_physical_session(sim, tmp / f"s{seed}", description=urdf)
        out[seed] = load_session(tmp / f"s{seed}")
    return out


def test_the_floor_of_a_tree_is_its_markers_noise_not_the_motion_between_links():
    """Markers on two links moving apart: the floor is the per-axis noise (pairs on one link), the
    pairs across links would read the motion; one link's markers alone give the same noise."""
    rng = np.random.default_rng(3)
    n = 400
    place = rng.normal(0, 0.05, (6, 3))
    shift = np.zeros((n, 6, 3))
    shift[:, 3:, 0] = rng.uniform(-0.2, 0.2, n)[:, None]  # the second link slides 0.2 m against the first
    Y = place + shift + rng.normal(0, NOISE_M, (n, 6, 3))
    names = [f"M{k}" for k in range(6)]
    links = {m: ("a" if k < 3 else "b") for k, m in enumerate(names)}
    tree = PoseSet("urdf", np.zeros((n, 1)), Y, names, moving_link=links)
    assert tree.marker_links == links
    assert abs(marker_noise_floor(tree) / NOISE_M - 1) < 0.15
    assert pair_noise(Y) > 100 * NOISE_M  # every pair: the motion
    one = PoseSet("urdf", np.zeros((n, 1)), Y[:, :3], names[:3])  # one rigid part, no mapping
    assert abs(marker_noise_floor(one) / marker_noise_floor(tree) - 1) < 0.3


def test_a_tree_stream_against_another_recordings_log_is_refused(streams):
    """The stream of seed 41 with its own log is calibrated (its misfit about its noise, the floor
    its noise, not the motion); against seed 42's log (the same rate and length: every check before
    the fit passes) the markers are left off by centimetres: refused in one line naming
    commands.csv."""
    own = streams[41]
    cal, poses = calibrate_motion(own, own.spec, kind="first_order")
    floor = np.sqrt(3) * marker_noise_floor(poses)
    assert 0.5 * np.sqrt(3) * NOISE_M < floor < 2 * np.sqrt(3) * NOISE_M
    assert cal.rms_after < 3 * floor
    # the misfit warning of estimate.fit_warnings reads the same floor: centimetres off are said
    assert fit_warnings(cal, poses) == []
    (warning,) = fit_warnings(dataclasses.replace(cal, rms_after=0.02), poses)
    assert warning.startswith("rms_after 20 mm is far above any measurement noise (more than 5 mm)")
    other = streams[42]
    n = min(len(own.command_t), len(other.command_t))
    wrong = dataclasses.replace(own, command_t=own.command_t[:n], commands=other.commands[:n])
    with pytest.raises(BadSession, match=r"commands.csv: the command log does not explain the motion .* off by "
                                         r"\d+(\.\d+)? mm RMS.* or the log is another recording's"):
        calibrate_motion(wrong, wrong.spec, kind="first_order")
