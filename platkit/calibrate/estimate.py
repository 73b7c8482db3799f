"""Calibration of a stand from settled poses: :func:`calibrate`, the checks of its result, and
prediction with it.

The observation model (unknowns, residuals, exact Jacobians) is
:class:`platkit.calibrate.problem.CalibrationProblem`; the solvers (Levenberg-Marquardt, the
robust fit, k-fold held-out errors) are in :mod:`platkit.calibrate.solve`; which parameter groups
to free is chosen by :mod:`platkit.calibrate.selection` (the default of ``platkit calibrate``).

Procedure (:func:`calibrate`, its stages in :mod:`platkit.calibrate.stages`):
1. poses by nominal forward kinematics; the transform and the markers by rigid alignment
   (Kabsch, with the rotation from the relative motions so that no translation is needed);
2. registration only (transform and markers, td at nominal): gives ``rms_before``;
3. identifiability: pivoted orthogonalisation of the scaled Jacobian (identifiability.py); the
   parameters the data cannot fix are held at nominal and reported by name;
4. Levenberg-Marquardt over everything identifiable, robust: Huber weights on each marker's
   3-D error (scale from the median error), then outliers beyond 4.5 sigma rejected outright;
5. standard deviations from sigma^2 (J^T W J)^-1; optional k-fold held-out prediction error;
6. what a user should check before trusting the fit (:func:`fit_warnings`), and a rigid body
   whose orientations were rejected en masse refused (:func:`check_body_orientations`).
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from platkit.bodies import ROTATION_REJECTED_SHARE, log_so3, rotation_refusal
from platkit.calibrate.identifiability import DEFAULT_REL_TOL
from platkit.calibrate.problem import PLAUSIBLE_RANGE, Progress, link_frames
from platkit.calibrate.robust import REJECT_K
from platkit.calibrate.solve import blas_threads
from platkit.calibrate.stages import CalibrationOptions, fit_calibration
from platkit.errors import BadInput, BadSession
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix, quat_normalize
from platkit.io.calibration import Calibration
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec, length_scale
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

# ---------------------------------------------------------------------------- public


def calibrate(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm] = (), free: Sequence[str] | None = None,
              robust: bool = True, folds: int = 0, rel_tol: float = DEFAULT_REL_TOL, max_iter: int = 60,
              progress: Progress | None = None, platform_options: dict | None = None,
              td_start: np.ndarray | None = None, ridge_m: float = 0.0,
              plausible: float | None = PLAUSIBLE_RANGE, row_block: int | None = None) -> Calibration:
    """Estimate td, the base-to-mocap transform, marker positions and term parameters.

    poses: settled poses (SI); spec: the stand (its nominal td is the starting point and the value
    of every parameter held); terms: extra physics (ModelTerm); free: see
    :func:`platkit.calibrate.stages.free_mask`;
    folds: K > 1 adds K-fold held-out prediction errors to ``Calibration.heldout``.
    ridge_m: optional shrinkage of td towards nominal (see CalibrationProblem.set_ridge); 0 (default)
    is plain (robust) least squares.
    plausible: td is kept within nominal +- this many typical corrections (see
    CalibrationProblem.set_plausible; the names that reach the edge are in
    ``identifiability['at_plausible_limit']``); None lets td go anywhere.
    row_block: None (default) takes the Jacobian of every pose at once; a number of poses takes
    it that many at a time (normal equations summed block by block: memory of one block whatever
    the poses, the sums in another order: the same fit to rounding).
    Raises NotIdentifiable when not even the transform and markers can be fixed, NoConvergence
    when forward kinematics fails on most poses. A final fit that met no per-step stopping rule
    within ``max_iter`` iterations is judged on its last ones (:func:`platkit.calibrate.solve.judge_window`):
    converged where its misfit has (``converged``), and either way its judgement, with the
    parameters still moving and how, is one of ``warnings``.
    """
    opt = CalibrationOptions(free=free, robust=robust, folds=folds, rel_tol=rel_tol, max_iter=max_iter,
                             progress=progress, platform_options=platform_options, td_start=td_start, ridge_m=ridge_m,
                             plausible=plausible, row_block=row_block)
    with blas_threads(1):
        cal = fit_calibration(poses, spec, terms, opt)
    cal.warnings = fit_warnings(cal, poses)
    stop = cal.fit.stop if cal.fit is not None else None
    if stop is not None:  # the final fit's last run met no per-step rule: its judgement said
        cal.warnings.append(stop.sentence(cal.iterations))
    check_body_orientations(cal, poses)
    return cal


#: a fit whose RMS is this many times the markers' own noise does not describe the data
MISFIT_RATIO = 10.0
#: ... nor one above this (m), whatever the noise: a marker error of centimetres is no calibration
#: (and points derived from one tracked rigid body keep their distances exactly: no noise floor)
MISFIT_ABSOLUTE_M = 0.005


def marker_noise_floor(poses: PoseSet) -> float:
    """The markers' own noise per axis (m), from the poses alone, without any model of the stand:
    :func:`pair_noise` over the pairs of markers on one link (``poses.marker_links`` on a tree;
    every pair where all ride one rigid part). On a tree a pair across two links changes its
    distance with the pose, so its spread is motion, not noise. Points computed from one tracked
    rigid body give about 0."""
    if not poses.marker_links:
        return pair_noise(poses.markers)
    return pair_noise(poses.markers, [str(poses.marker_links.get(n)) for n in poses.marker_names])


def pair_noise(Y: np.ndarray, links=None) -> float:
    """The markers' noise per axis (m) from samples or poses Y (K, M, 3): the distance between two
    markers on one rigid part is the same at every sample, so its spread (1.4826 MAD over the
    samples where both were seen) is sqrt(2) sigma for isotropic noise sigma per axis. Median over
    the pairs on one link (``links`` (M,); None: every pair); NaN with no such pair seen together
    at three samples."""
    M = Y.shape[1]
    same = None if links is None else np.equal.outer(np.asarray(links), np.asarray(links))
    vis = np.all(np.isfinite(Y), axis=2)
    per_pair = []
    for i in range(M):
        for j in range(i + 1, M):
            both = vis[:, i] & vis[:, j]
            if (same is not None and not same[i, j]) or both.sum() < 3:
                continue
            d = np.linalg.norm(Y[both, i] - Y[both, j], axis=1)
            per_pair.append(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2))
    return float(np.median(per_pair)) if per_pair else float("nan")


def fit_warnings(cal: Calibration, poses: PoseSet) -> list[str]:
    """One sentence per thing a user should check before trusting ``cal`` (empty: nothing found).

    A fit can converge (the iterations stop) and still not describe the data: an RMS after the fit
    above MISFIT_RATIO times the markers' own 3-D noise (:func:`marker_noise_floor`) and above
    MISFIT_ABSOLUTE_M is said, with what usually causes it.
    """
    out = []
    lu = cal.length_unit
    s = length_scale(lu)
    floor_3d = np.sqrt(3) * marker_noise_floor(poses)
    limit = max(MISFIT_RATIO * floor_3d, MISFIT_ABSOLUTE_M) if np.isfinite(floor_3d) else MISFIT_ABSOLUTE_M
    if np.isfinite(cal.rms_after) and cal.rms_after > limit:
        noise = (f"{cal.rms_after / floor_3d:.0f} times the markers' own noise, {floor_3d / s:.3g} {lu} RMS from how "
                 "much the distances between markers on one link vary over the poses" if limit > MISFIT_ABSOLUTE_M
                 else f"more than {MISFIT_ABSOLUTE_M / s:g} {lu}")
        out.append(f"rms_after {cal.rms_after / s:.4g} {lu} is far above any measurement noise ({noise}): the fit "
                   "stopped, but the model does not describe these data. Check that the session is for this stand "
                   "and description, that the control columns are in the stand's order and units (session.yaml "
                   "units), that no marker columns are swapped, that the command log holds every command sent, then "
                   "run platkit diagnose")
    lost = rejected_by_marker(cal)
    for name, (n_rej, n_seen) in lost.items():
        if n_rej >= max(3, MARKER_LOST_SHARE * n_seen):
            out.append(f"marker {name}: {n_rej} of its {n_seen} observations rejected as outliers (beyond "
                       f"{REJECT_K:g} sigma): a marker that slipped or was relabelled part-way through the session "
                       "looks like this; its place is where most of its observations put it. Run platkit diagnose "
                       "(a marker_slip is corrected in the data)")
    for name, (n_rej, n_rot, n_seen) in rejected_by_body(cal).items():
        if n_rej >= max(3, MARKER_LOST_SHARE * n_seen):
            out.append(f"rigid body {name}: {n_rej} of its {n_seen} observations rejected as outliers (beyond "
                       f"{REJECT_K:g} sigma; {n_rot} by their orientation, {n_rej - n_rot} by their origin alone): the "
                       "fit rests on the rest; a body that slipped, was re-defined in the mocap software part-way, or "
                       "whose orientation is written in another order looks like this. Run platkit diagnose")
    return out


#: a marker with at least this share of its observations rejected is said (a slip, a relabelling)
MARKER_LOST_SHARE = 0.2


def rejected_by_body(cal: Calibration) -> dict[str, tuple[int, int, int]]:
    """{body: (observations rejected as outliers, of them by the orientation, observations seen)}
    for the rigid bodies with any rejected, from the robust fit's final weights: an observation
    (one pose of one body) is rejected where its origin or its orientation channel is."""
    B = len(cal.body_names)
    if cal.fit is None or not B:
        return {}
    w, r = cal.fit.weights, cal.fit.residuals_after
    M = len(cal.marker_names)
    w = np.asarray(w)
    seen = np.isfinite(r[:, M:M + B]).all(axis=2)
    rot = seen & (w[:, M + B:M + 2 * B] <= 0)
    rej = seen & ((w[:, M:M + B] <= 0) | rot)
    return {n: (int(rej[:, k].sum()), int(rot[:, k].sum()), int(seen[:, k].sum()))
            for k, n in enumerate(cal.body_names) if rej[:, k].any()}


def check_body_orientations(cal: Calibration, poses: PoseSet) -> None:
    """BadSession where a rigid body's orientations were rejected en masse (more than
    ROTATION_REJECTED_SHARE of those seen): the fit would rest on its origins alone and look
    perfect; the line names the likely cause (platkit.bodies.rotation_refusal)."""
    for name, (_, n_rot, n_seen) in rejected_by_body(cal).items():
        if n_seen < 4 or n_rot <= ROTATION_REJECTED_SHARE * n_seen:
            continue
        b = cal.body_names.index(name)
        _, q, X, ok = predict_markers(cal, poses.controls, poses)
        predicted = predict_bodies(cal, q, X, poses.controls, poses)[:, b, 3:]
        measured = poses.bodies[:, b, 3:]
        use = ok & np.isfinite(measured).all(axis=1) & np.isfinite(predicted).all(axis=1)
        raise BadSession(rotation_refusal(name, poses.source or "the session", measured[use], predicted[use],
                                          n_rot, n_seen))


def rejected_by_marker(cal: Calibration) -> dict[str, tuple[int, int]]:
    """{marker: (observations rejected as outliers, observations seen)} for the markers with any
    rejected, from the robust fit's final weights; empty without them."""
    if cal.fit is None:
        return {}
    w, r = cal.fit.weights, cal.fit.residuals_after
    M = len(cal.marker_names)
    seen = np.isfinite(r[:, :M]).all(axis=2)
    rej = seen & (np.asarray(w)[:, :M] <= 0)
    return {n: (int(rej[:, m].sum()), int(seen[:, m].sum())) for m, n in enumerate(cal.marker_names) if rej[:, m].any()}


# ---------------------------------------------------------------------------- prediction


def predict_markers(cal: Calibration, controls: np.ndarray, poses: PoseSet | None = None):
    """Model prediction for controls (N, n_u), SI: (markers (N, M, 3) in the mocap frame, q (N, 4)
    and X (N, 3), the moving frame's pose in the base frame, converged (N,)).

    ``poses`` supplies what history- or time-dependent terms need (t, row order, extras) and, on a
    tree, each marker's link; by default a PoseSet of the controls alone with the calibration's
    marker-to-link mapping (as ``platkit predict`` reads it).
    """
    spec = cal.calibrated_spec()
    model = PlatformModel(spec)
    U = np.atleast_2d(np.asarray(controls, float))
    N, M = U.shape[0], len(cal.marker_names)
    if poses is None:  # on a tree, the terms move each marker with its own link
        poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, M, 3), np.nan),
                        marker_names=list(cal.marker_names), length_unit=cal.length_unit,
                        marker_links=dict(cal.marker_links))
    R_all, X_all, dm, ok = _predicted_frames(cal, spec, model, U, poses)
    A = matrix_from_rotvec(cal.mocap_rotvec)
    k = np.array(calibration_links(cal)[:M], int)
    pts = X_all[:, k] + np.einsum("nmab,nmb->nma", R_all[:, k], cal.marker_positions[None] + dm)
    markers = pts @ A.T + cal.mocap_translation
    R, X = R_all[:, 0], X_all[:, 0]
    q = quat_normalize(quat_from_matrix(R))
    markers[~ok] = np.nan
    return markers, q, X, ok


def predict_links(cal: Calibration, controls: np.ndarray, poses: PoseSet | None = None):
    """Every tracked link's pose under ``cal`` (model terms included): q (N, L, 4) and X (N, L, 3) m in
    the base frame, for controls (N, n_u) SI; L = 1 (the moving frame) but on a tree."""
    spec = cal.calibrated_spec()
    U = np.atleast_2d(np.asarray(controls, float))
    if poses is None:  # on a tree, the terms move each marker with its own link
        poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((len(U), len(cal.marker_names), 3), np.nan),
                        marker_names=list(cal.marker_names), length_unit=cal.length_unit,
                        marker_links=dict(cal.marker_links))
    R_all, X_all, _, ok = _predicted_frames(cal, spec, PlatformModel(spec), U, poses)
    q = quat_normalize(quat_from_matrix(R_all))
    q[~ok], X_all[~ok] = np.nan, np.nan
    return q, X_all


def calibration_links(cal: Calibration) -> list[int]:
    """Index in the stand's tracked links of the link each marker, then each body, of ``cal``
    rides on (all 0 where they ride on the moving frame)."""
    names = list(cal.marker_names) + list(cal.body_names)
    if not cal.marker_links:
        return [0] * len(names)
    tracked = cal.spec.tracked_links or [cal.spec.moving_frame]
    return [tracked.index(cal.marker_links[n]) for n in names]


def _predicted_frames(cal: Calibration, spec: PlatformSpec, model: PlatformModel, U: np.ndarray, poses: PoseSet):
    """The tracked links' frames under ``cal``'s model terms: R (N, L, 3, 3), X (N, L, 3) m in the
    base frame (L = 1 but on a tree), the markers' offsets dm (N, M, 3) and converged (N,)."""
    N, M = U.shape[0], len(cal.marker_names)
    td = cal.td
    du = np.zeros((N, spec.n_u))
    dpose = np.zeros((N, 6))
    dm = np.zeros((N, M, 3))
    if cal.terms:
        fb = model.forward_batch(U, td, strict=False)
        for term, th in zip(cal.terms, cal.theta):
            du += term.control_offset(th, poses, spec.n_u)
            dpose += term.pose_offset(th, poses, fb.q, fb.X)
            dm += term.marker_offset(th, poses)
    fb = model.forward_batch(U + du, td, strict=False)
    if cal.marker_links and spec.link_poses is not None:
        R_all, X_all = link_frames(spec, td, U + du)
    else:
        R_all, X_all = matrix_from_quat(fb.q)[:, None], fb.X[:, None]
    R_all = np.einsum("nab,nkbc->nkac", matrix_from_rotvec(dpose[:, 3:]), R_all)
    X_all = X_all + dpose[:, None, :3]
    return R_all, X_all, dm, fb.converged & fb.on_branch


def point_errors(cal: Calibration, poses: PoseSet) -> np.ndarray:
    """|predicted - measured| (N, M) in metres for a pose set in the same mocap frame (NaN unseen)."""
    pred, _, _, _ = predict_markers(cal, poses.controls, poses)
    return np.linalg.norm(pred - poses.markers, axis=2)


def predict_bodies(cal: Calibration, q: np.ndarray, X: np.ndarray, controls: np.ndarray | None = None,
                   poses: PoseSet | None = None) -> np.ndarray:
    """The calibration's rigid bodies (N, B, 7) in the motion-capture frame: origin (m) and unit quaternion
    (qw >= 0), from the moving frame's pose in the base frame, q (N, 4) and X (N, 3) m (as
    :func:`predict_markers` returns them). On a tree whose bodies ride on other links, from the
    ``controls`` (N, n_u) (and ``poses``, for the model terms) instead."""
    N, B = len(q), len(cal.body_names)
    if B == 0:
        return np.zeros((N, 0, 7))
    A = matrix_from_rotvec(cal.mocap_rotvec)
    links = calibration_links(cal)[len(cal.marker_names):]
    if any(links):
        if controls is None:
            raise ValueError("predict_bodies: a tree's bodies need the controls")
        spec = cal.calibrated_spec()
        U = np.atleast_2d(np.asarray(controls, float))
        if poses is None:
            poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                            marker_names=list(cal.marker_names), length_unit=cal.length_unit)
        R_all, X_all, _, _ = _predicted_frames(cal, spec, PlatformModel(spec), U, poses)
        Rk, Xk = R_all[:, links], X_all[:, links]  # (N, B, 3, 3), (N, B, 3)
    else:
        Rk = np.broadcast_to(matrix_from_quat(q)[:, None], (N, B, 3, 3))
        Xk = np.broadcast_to(X[:, None], (N, B, 3))
    R = np.einsum("ab,nkbc->nkac", A, Rk)  # each body's mocap_from_link rotation
    origin = Xk @ A.T + cal.mocap_translation + np.einsum("nkab,kb->nka", R, cal.body_positions)
    quat = quat_from_matrix(np.einsum("nkab,kbc->nkac", R, matrix_from_rotvec(cal.body_rotvecs)))
    quat = np.where(quat[..., :1] < 0, -quat, quat)
    return np.concatenate([origin, quat], axis=2)


def second_session_errors(cal: Calibration, poses: PoseSet) -> dict:
    """Held-out prediction of another session recorded in the same mocap frame: {'source',
    'n_poses', 'rms' (m, over every marker and rigid body origin), 'rms_per_marker' {name: m}, and
    with bodies 'rms_per_body' {name: m} (origins) and 'rotation_rms_per_body_rad' {name: rad}}.
    Markers and bodies are matched by name."""
    missing = [m for m in cal.marker_names if m not in poses.marker_names]
    missing += [b for b in cal.body_names if b not in poses.body_names]
    if missing:
        raise BadInput(f"{poses.source or 'validation session'}: has no marker or rigid body {missing[0]!r} of the "
                       "calibration")
    order = [poses.marker_names.index(m) for m in cal.marker_names]
    sub = PoseSet(poses.platform, poses.controls, poses.markers[:, order], list(cal.marker_names), t=poses.t,
                  length_unit=poses.length_unit, source=poses.source, extras=dict(poses.extras))
    pred, q, X, ok = predict_markers(cal, sub.controls, sub)
    d = np.linalg.norm(pred - sub.markers, axis=2)
    per = {m: float(np.sqrt(np.nanmean(d[:, i] ** 2))) for i, m in enumerate(cal.marker_names)}
    out = {"source": poses.source, "n_poses": int(poses.n_poses), "rms_per_marker": per}
    if cal.body_names:
        measured = poses.bodies[:, [poses.body_names.index(b) for b in cal.body_names]]
        body = predict_bodies(cal, q, X, sub.controls, sub)
        body[~ok] = np.nan
        d_body = np.linalg.norm(body[..., :3] - measured[..., :3], axis=2)
        turn = np.einsum("nkba,nkbc->nkac", matrix_from_quat(np.nan_to_num(measured[..., 3:], nan=1.0)),
                         matrix_from_quat(np.nan_to_num(body[..., 3:], nan=1.0)))
        angle = np.where(np.isfinite(measured[..., 3:]).all(axis=2) & np.isfinite(body[..., 3:]).all(axis=2),
                         np.linalg.norm(log_so3(turn), axis=2), np.nan)
        out["rms_per_body"] = {b: float(np.sqrt(np.nanmean(d_body[:, k] ** 2))) for k, b in enumerate(cal.body_names)}
        out["rotation_rms_per_body_rad"] = {b: float(np.sqrt(np.nanmean(angle[:, k] ** 2)))
                                            for k, b in enumerate(cal.body_names)}
        d = np.concatenate([d, d_body], axis=1)
    out["rms"] = float(np.sqrt(np.nanmean(d ** 2))) if np.isfinite(d).any() else float("nan")
    return out


__all__ = ["calibrate", "fit_warnings", "marker_noise_floor", "pair_noise", "check_body_orientations", "rejected_by_body",
           "rejected_by_marker", "predict_markers", "predict_bodies", "predict_links", "calibration_links", "point_errors",
           "second_session_errors"]
