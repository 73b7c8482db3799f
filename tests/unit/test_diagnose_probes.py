"""The non-rigid probe: each marker its own offset with the pose (issue 10)."""
import numpy as np

from platkit.diagnose.probes import marker_probe
from platkit.poses import PoseSet


def _poses(n, n_u=3, m=4, seed=0):
    rng = np.random.default_rng(seed)
    return PoseSet("x", rng.uniform(-1, 2, (n, n_u)), np.zeros((n, m, 3)), list("abcdefgh"[:m]), t=np.arange(n) * 4.0)


def test_it_holds_a_plate_bending_with_the_reach_of_the_command():
    poses = _poses(50)
    probe = marker_probe(poses)
    assert probe is not None and len(probe.initial) == 4 * 3 * 4
    lo, hi = poses.controls.min(axis=0), poses.controls.max(axis=0)
    reach = np.mean(((poses.controls - 0.5 * (lo + hi)) / (0.5 * (hi - lo))) ** 2, axis=1)
    share = np.array([1.0, -0.7, 0.5, -1.0])
    bend = np.zeros((50, 4, 3))
    bend[:, :, 2] = 1e-3 * reach[:, None] * share[None]  # markers against each other, along z
    f = probe.features(poses)
    A = np.linalg.lstsq(f, bend.reshape(50, -1), rcond=None)[0]  # (n_f, M*3)
    theta = A.T.reshape(4, 3, -1).ravel()
    assert np.allclose(probe.marker_offset(theta, poses), bend, atol=1e-12)
    # a subset (a fold) keeps the full session's scaling
    sub = poses.subset(np.arange(0, 50, 2))
    assert np.allclose(probe.marker_offset(theta, sub), bend[::2], atol=1e-12)


def test_too_few_poses_or_one_marker_give_no_probe():
    assert marker_probe(_poses(20)) is None
    assert marker_probe(_poses(50, m=1)) is None
    assert marker_probe(_poses(40, n_u=12)) is None  # fewer than 4 poses per parameter of a marker
