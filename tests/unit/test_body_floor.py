"""The noise floor of a rigid body's points (platkit.diagnose.floor): a body pose is one 6-DOF
measurement (6 observations, its three points' errors correlated) in the floor and in the BIC,
and the floor with the geometric fit's design is the K-fold held-out error that the simulated noise
alone gives.

A Stewart on its nominal geometry carries one body T1 (noise SP, SR per axis); its points
(platkit.diagnose.bodies.as_points) are fitted as diagnosis fits them (platkit.diagnose.fitting._fit,
the geometry free as calibrate frees it), and the K-fold of that linearised fit is drawn again and
again with the body's own noise (a position error and a turn per pose, moving its three points
together), each fold refitted by least squares with the fit's weights as platkit.diagnose.fitting._cv
refits it. The floor from the fit's design (kfold_refit) is that K-fold's RMS; the rule from the
count of observations is about 15 % below it on this design (the refit's error is 0.6 of the noise,
not n_params / n_observations).
"""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.diagnose.bodies import as_points
from platkit.diagnose.fitting import _fit
from platkit.diagnose.floor import kfold_refit, noise_floor
from platkit.diagnose.stats import bic
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.poses import PoseSet

SP, SR = 1e-4, 1e-3  # m, rad per axis: the body's noise per sample
FOLDS = 5


def _body_poses(n: int, seed: int = 5, marker: bool = False) -> PoseSet:
    """n poses of one body (and, with ``marker``, one marker M1 beside it) on the nominal Stewart,
    noiseless, one sample each, the body's noise declared (SP, SR); the marker's sigma 2e-4 m."""
    spec = get_platform("stewart")
    rng = np.random.default_rng(seed)
    lo, hi = spec.control_bounds()
    U = spec.neutral_u() + rng.uniform(-0.25, 0.25, (n, spec.n_u)) * (hi - lo)
    fb = PlatformModel(spec).forward_batch(U, spec.nominal_td(), strict=False)
    R = matrix_from_quat(fb.q)
    o = fb.X + np.einsum("nab,b->na", R, np.array([0.02, -0.05, 0.03]))
    Rw = np.einsum("nab,bc->nac", R, matrix_from_rotvec(np.array([0.4, -0.3, 1.1])))
    bodies = np.concatenate([o, quat_from_matrix(Rw)], axis=1)[:, None, :]
    markers = (fb.X + np.einsum("nab,b->na", R, np.array([0.1, 0.05, 0.0])))[:, None, :] if marker \
        else np.zeros((n, 0, 3))
    return PoseSet("stewart", U, markers, ["M1"] if marker else [], n_samples=np.ones((n, markers.shape[1])),
                   bodies=bodies, body_names=["T1"], n_body_samples=np.ones((n, 1)),
                   body_noise={"position_m": SP, "rotation_rad": SR}, settling={"sigma_m": 2e-4})


def test_a_body_pose_counts_six_observations():
    pts = as_points(_body_poses(10, marker=True))
    assert pts.marker_names == ["M1", "T1.o", "T1.x", "T1.y"]
    s = pts.settling["point_sigma_m"]
    ms = np.mean([3 * 2e-4**2, 3 * s["T1.o"] ** 2, 3 * s["T1.x"] ** 2, 3 * s["T1.y"] ** 2])
    # 10 poses: the marker's 3 numbers and the body's 6 (its position and turn), not its points' 9
    assert noise_floor(pts, 6) == pytest.approx(np.sqrt(ms * (1 + 6 / (10 * (3 + 6)))))
    markers = _body_poses(10, marker=True)  # the marker alone: 3 numbers a pose, as before
    markers.bodies, markers.body_names, markers.n_body_samples = None, [], None
    assert noise_floor(markers, 6) == pytest.approx(np.sqrt(3 * 2e-4**2 * (1 + 6 / 30)))


def _kfold_of_noise(J: np.ndarray, w: np.ndarray, pts: np.ndarray, draws: int, seed: int = 11) -> float:
    """RMS of the linearised K-fold (platkit.diagnose.fitting._cv's folds and score: each pose's
    mean over its points of the 3-D squared error) over ``draws`` draws of the body's noise:
    residuals r = J theta - e, each fold's theta by least squares with the weights ``w`` (N, 3)."""
    N, P = J.shape[0], J.shape[-1]
    rng = np.random.default_rng(seed)
    lever = pts[:, 1:] - pts[:, :1]  # (N, 2, 3) the tips from the origin
    fold = np.arange(N) % FOLDS
    Jf = J.reshape(N, 9, P)
    sw = np.repeat(np.sqrt(w), 3, axis=1)  # (N, 9)
    total = 0.0
    for _ in range(draws):
        d, turn = rng.normal(0, SP, (N, 3)), rng.normal(0, SR, (N, 3))
        e = np.concatenate([d[:, None], d[:, None] + np.cross(turn[:, None], lever)], axis=1).reshape(N, 9)
        ms = np.zeros(N)
        for k in range(FOLDS):
            tr, te = fold != k, fold == k
            theta = np.linalg.lstsq((sw[tr, :, None] * Jf[tr]).reshape(-1, P), (sw[tr] * e[tr]).reshape(-1),
                                    rcond=None)[0]
            r = (Jf[te] @ theta - e[te]).reshape(-1, 3, 3)
            ms[te] = np.mean(np.sum(r**2, axis=2), axis=1)
        total += np.mean(ms)
    return float(np.sqrt(total / draws))


@pytest.fixture(scope="module")
def body_fit():
    """(the body's points over 30 poses, their geometric fit as diagnosis fits them: joints free)."""
    spec = get_platform("stewart")
    pts = as_points(_body_poses(30))
    cal = calibrate(pts, spec, free=[n for n in spec.parameter_names if n.startswith(("B", "P"))], robust=False)
    weights = np.ones((pts.n_poses, pts.n_markers))
    return pts, _fit(spec, pts, [], cal.fit.z, cal.fit.active, weights, 5, robust=False)


def test_the_bic_counts_a_body_pose_as_six_numbers(body_fit):
    pts, fit = body_fit
    assert fit.n_obs == 9 * 30  # the points' coordinates, as the fit's RMS reads them
    assert fit.bic == pytest.approx(bic(fit.rss, 6 * 30, fit.n_params))


def test_the_floor_of_a_body_is_the_kfold_error_of_its_noise(body_fit):
    pts, fit = body_fit
    refit = kfold_refit(fit, FOLDS)
    J = refit[0]
    assert J.shape[:3] == (30, 3, 3) and J.shape[3] == int(fit.active.sum())
    floor = noise_floor(pts, J.shape[3], refit)
    simulated = _kfold_of_noise(J, refit[1], np.asarray(pts.markers), draws=300)
    assert floor == pytest.approx(simulated, rel=0.03)
    # the rule from the count of observations is well below what the K-fold's refit makes of the noise
    assert noise_floor(pts, J.shape[3]) < 0.9 * simulated
