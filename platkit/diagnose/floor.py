"""How well held-out poses could be predicted at best: the noise floor of settled poses (what
marker noise alone leaves) and, for a lack of fit, the marker whose residuals stand out.

The floor is the K-fold held-out error (platkit.diagnose.fitting._cv: each pose's mean over its
points of the 3-D squared error, averaged over the poses) that the noise of the settled poses alone
gives: each point's own noise, and the error the refit on the other folds makes from that noise.

- A marker's noise per coordinate is sigma^2 / n (n samples averaged; sigma from the settling
  search, or the point's own in ``settling['point_sigma_m']``; a coloured noise averages less:
  ``slow_noise_inflation`` of settle), independent between markers.
- A rigid body's three points (platkit.diagnose.bodies.as_points) are one 6-DOF measurement: their
  errors are e_o = d, e_x = d + L w x u_x, e_y = d + L w x u_y (d the position noise, sigma_p per
  coordinate; w the turn, sigma_r per axis; u the body's axes at the pose), correlated and of rank
  6 (as platkit.diagnose.bodies.screen_system reads them): a body pose counts 6 observations, not 9,
  and its noise covariance is A S A' / n (:func:`pose_noise`).
- The refit: given the geometric fit and its folds (:func:`kfold_refit`), its own error to first
  order, fold by fold: cov(theta) = H^+ (sum_i J_i' W_i C_i W_i J_i) H^+ over the training poses
  (H = sum_i J_i' W_i J_i, W the folds' fit weights, C_i the pose's noise covariance), and each
  held-out point's expected 3-D squared error its noise plus tr(J_m cov J_m'). Without them,
  n_params / n_observations of the noise, an underestimate where the parameters are many against
  the training folds' observations or the observations correlated (a body's points). Diagnosis's
  search (platkit.diagnose.search) passes no refit: its floor, and the thresholds set against it
  (Options.noise_floor_factor, lack_of_fit_factor, noted_lack_of_fit), are the count rule's.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from platkit._threads import blas_threads
from platkit.diagnose.bodies import _body_triples, n_measured, point_map
from platkit.poses import PoseSet

if TYPE_CHECKING:
    from platkit.diagnose.fitting import Fit

__all__ = ["kfold_refit", "noise_floor", "pose_noise", "pose_words", "worst_marker"]


def kfold_refit(fit: Fit, folds: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """What the K-fold refit of ``fit`` (platkit.diagnose.fitting._cv) is made of, for
    :func:`noise_floor`: (J (N, M, 3, P) of its free parameters at the fit, the weights (N, M) the
    folds' refits use, the weights (N, M) that score them, folds)."""
    J = np.asarray(fit.problem.evaluate(fit.z, with_jac=True).J)
    M = fit.weights.shape[1]
    trained = fit.weights if fit.fit_weights is None else fit.fit_weights
    return (J[:, :M][..., np.asarray(fit.active, bool)], np.asarray(trained, float), np.asarray(fit.weights, float),
            int(folds))


def pose_noise(poses: PoseSet) -> tuple[np.ndarray, list[tuple[list[int], np.ndarray, np.ndarray]]] | None:
    """The noise of the settled poses' points (module docstring): (var (N, M, 3) m^2, each seen
    coordinate's variance, 0 where unseen; and for each rigid body whose noise is known
    (platkit.diagnose.bodies._body_triples): (its points' indices [o, x, y], the poses (n,) where
    all three are seen, their covariance (n, 9, 9) A S A' / n_samples, A (9, 6) the map from its
    position and turn to its points' errors at the pose, S = diag(sigma_p^2 (3), sigma_r^2 (3))),
    whose diagonal is in var). None without sample counts or where a seen point has no sigma."""
    settling = poses.settling or {}
    if poses.n_samples is None:
        return None
    sigma, own = settling.get("sigma_m"), settling.get("point_sigma_m") or {}
    infl = float(settling.get("slow_noise_inflation", 1.0))  # coloured noise averages less
    col = np.array([own.get(name, np.nan if sigma is None else sigma) for name in poses.marker_names], float)
    n = np.asarray(poses.n_samples, float)
    seen = np.all(np.isfinite(poses.markers), axis=2) & (n > 0)
    if not np.all(np.isfinite(col[seen.any(axis=0)])):
        return None
    var = np.repeat(np.where(seen, infl * np.nan_to_num(col)[None, :] ** 2 / np.where(seen, n, 1.0), 0.0)[..., None],
                    3, axis=2)
    pts = np.asarray(poses.markers, float)
    bodies = []
    for io, ix, iy, sp, sr in _body_triples(poses):
        whole = np.flatnonzero(seen[:, io] & seen[:, ix] & seen[:, iy])
        A = point_map(pts[whole][:, [io, ix, iy]])  # screen_system's map
        S = infl * np.array([sp ** 2] * 3 + [sr ** 2] * 3)
        cov = np.einsum("nia,a,nja->nij", A, S, A) / n[whole, io][:, None, None]
        var[whole[:, None], [io, ix, iy]] = np.einsum("nii->ni", cov).reshape(-1, 3, 3)
        bodies.append(([io, ix, iy], whole, cov))
    return var, bodies


def noise_floor(poses: PoseSet, n_params: int,
                refit: tuple[np.ndarray, np.ndarray, np.ndarray, int] | None = None) -> float | None:
    """The K-fold held-out RMS (m, of the 3-D marker error) that the noise of the settled poses
    alone gives (module docstring): each point's noise, and the refit's error from it. ``refit``
    (:func:`kfold_refit` of the geometric fit) gives the K-fold refit's own error (first order);
    without it, n_params / n_observations of the noise, a rigid body's pose counting 6
    observations. None when a seen marker has no sigma (poses not from a stream, no declared body
    noise) or the poses carry no sample counts."""
    noise = pose_noise(poses)
    if noise is None:
        return None
    var, bodies = noise
    seen = np.all(np.isfinite(poses.markers), axis=2) & (np.asarray(poses.n_samples, float) > 0)
    if not seen.any():
        return None
    own = var.sum(axis=2)  # (N, M) each point's 3-D variance
    if refit is None:
        return float(np.sqrt(np.mean(own[seen]) * (1.0 + n_params / n_measured(poses.marker_names, seen))))
    with blas_threads(1):  # products of thousands by tens: worker threads only spin (platkit._threads)
        per_pose = _refit_floor(var, bodies, own, seen, refit)
    return float(np.sqrt(np.nanmean(per_pose))) if np.isfinite(per_pose).any() else None


def _refit_floor(var: np.ndarray, bodies: list, own: np.ndarray, seen: np.ndarray,
                 refit: tuple[np.ndarray, np.ndarray, np.ndarray, int]) -> np.ndarray:
    """Each pose's expected held-out 3-D squared error (N,) under the K-fold refit (module
    docstring), NaN where no scored point is seen; ``own`` (N, M) each point's 3-D variance."""
    J, trained, scored, folds = refit
    N = len(seen)
    J = np.nan_to_num(J) * seen[:, :, None, None]  # (N, M, 3, P)
    WJ = J * np.where(seen, trained, 0.0)[:, :, None, None]
    keep = seen & (scored > 0)
    P = J.shape[-1]
    fold = np.arange(N) % folds
    per_pose = np.full(N, np.nan)
    for k in range(folds):
        train, test = fold != k, fold == k
        X = WJ[train].reshape(-1, P)  # the training rows, weighted
        H_inv = np.linalg.pinv(X.T @ J[train].reshape(-1, P))
        mid = (X * var[train].reshape(-1, 1)).T @ X
        for rows, whole, cov in bodies:  # a body's correlations beside its points' variances
            at = train[whole]
            B = WJ[whole[at]][:, rows].reshape(int(at.sum()), 9, P)
            off = cov[at] * (1.0 - np.eye(9))
            mid += np.einsum("nap,nab,nbq->pq", B, off, B, optimize=True)
        Jt = J[test].reshape(-1, P)
        err = own[test] + np.sum((Jt @ (H_inv @ mid @ H_inv)) * Jt, axis=1).reshape(int(test.sum()), -1, 3).sum(axis=2)
        ok = keep[test]
        per_pose[test] = np.where(ok.any(axis=1), np.sum(np.where(ok, err, 0.0), axis=1) / np.maximum(ok.sum(axis=1), 1),
                                  np.nan)
    return per_pose


def pose_words(poses: PoseSet) -> str:
    """What the poses are, said in a sentence: 'windowed poses' for a stream without holds read
    through its response (its nodes in ``extras['node']``: platkit.calibrate.motion.motion_stream),
    else 'settled poses'."""
    return "windowed poses" if "node" in poses.extras else "settled poses"


def worst_marker(residuals: np.ndarray, poses: PoseSet) -> str | None:
    """The marker whose fit residuals (N, M, 3) are largest (RMS over the poses that saw it), when
    it stands out (1.5 times the median marker's): a marker moving against the others; else None."""
    r = np.asarray(residuals, float)
    seen = np.isfinite(r).all(axis=2)
    per = np.array([np.sqrt(np.mean(np.sum(r[seen[:, m], m] ** 2, axis=1))) if seen[:, m].any() else 0.0
                    for m in range(r.shape[1])])
    if per.size < 2 or not np.median(per) > 0:
        return None
    k = int(np.argmax(per))
    return poses.marker_names[k] if per[k] > 1.5 * np.median(per) else None
