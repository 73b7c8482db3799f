"""The non-rigid probe: each marker its own offset with the pose (issue 10)."""
import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.problem import CalibrationProblem
from platkit.diagnose.probes import marker_probe, space_probe, time_probe
from platkit.effects import with_history
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate import simulate


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


def test_its_jacobian_is_known_and_matches_finite_differences():
    # the estimator takes a term's columns from offset_jacobians when the term knows them (the
    # probe's 4 x 3 x 7 parameters by finite differences cost half of a TIAGo diagnosis)
    spec = get_platform("stewart")
    poses = with_history(simulate(spec, seed=3, n_poses=32, raw=False, plan="random").poses, spec)
    cal = calibrate(poses, spec)
    z0 = cal.fit.z
    fk_X = CalibrationProblem(spec, poses, []).kinematics(cal.td, poses.controls)[1]
    rng = np.random.default_rng(1)
    for probe in (marker_probe(poses), time_probe(poses), space_probe(fk_X)):
        theta = rng.normal(0, 1e-4, len(probe.initial))
        z = np.concatenate([z0, theta])

        class ByDifferences(type(probe)):
            def offset_jacobians(self, *args):
                return None

        slow = ByDifferences(**{f: getattr(probe, f) for f in probe.__dataclass_fields__})
        known = CalibrationProblem(spec, poses, [probe]).evaluate(z)
        fd = CalibrationProblem(spec, poses, [slow]).evaluate(z)
        np.testing.assert_allclose(known.r, fd.r, rtol=0, atol=1e-15)
        cols = known.J.shape[-1] - len(theta)
        np.testing.assert_allclose(known.J[..., :cols], fd.J[..., :cols], rtol=0, atol=0)
        np.testing.assert_allclose(known.J[..., cols:], fd.J[..., cols:], rtol=1e-5, atol=1e-9)
        assert np.abs(known.J[..., cols:]).max() > 0.01  # the columns are there, not zeros
