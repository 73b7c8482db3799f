"""Calibration of a stand from settled poses: the procedure, and prediction with the result.

The observation model (unknowns, residuals, exact Jacobians) is
:class:`platkit.calibrate.problem.CalibrationProblem`; the solvers (Levenberg-Marquardt, the
robust fit, k-fold held-out errors) are in :mod:`platkit.calibrate.solve`; which parameter groups
to free is chosen by :mod:`platkit.calibrate.selection` (the default of ``platkit calibrate``).

Procedure (:func:`calibrate`):
1. poses by nominal forward kinematics; the transform and the markers by rigid alignment
   (Kabsch, with the rotation from the relative motions so that no translation is needed);
2. registration only (transform and markers, td at nominal): gives ``rms_before``;
3. identifiability: pivoted orthogonalisation of the scaled Jacobian (identifiability.py); the
   parameters the data cannot fix are held at nominal and reported by name;
4. Levenberg-Marquardt over everything identifiable, robust: Huber weights on each marker's
   3-D error (scale from the median error), then outliers beyond 4.5 sigma rejected outright;
5. standard deviations from sigma^2 (J^T W J)^-1; optional k-fold held-out prediction error.
"""
from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from platkit.bodies import ROTATION_REJECTED_SHARE, estimate_rho, log_so3, rotation_refusal
from platkit.calibrate.identifiability import (
    DEFAULT_REL_TOL,
    apply_marker_convention,
    classify_held,
    nuisance_gauge,
    select_identifiable,
    singular_values,
)
from platkit.calibrate.plan import reference_poses_for
from platkit.calibrate.problem import (
    PLAUSIBLE_RANGE,
    CalibrationProblem,
    Progress,
    link_frames,
    parameter_scale,
)
from platkit.calibrate.robust import REJECT_K
from platkit.calibrate.solve import _rms, _weighted, blas_threads, kfold, levenberg_marquardt, robust_fit
from platkit.errors import BadInput, BadSession, NoConvergence, NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix, quat_normalize
from platkit.io.calibration import Calibration
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec, length_scale
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

# ---------------------------------------------------------------------------- public


def free_mask(spec: PlatformSpec, free: Sequence[str] | None) -> np.ndarray:
    """Which td entries to fit: None = every parameter the stand marks free; otherwise names or
    group names (e.g. ['offset', 'origin']). An empty list fits none (registration only)."""
    if free is None:
        return np.array([p.free for p in spec.parameters], bool)
    wanted = set(free)
    known = {p.name for p in spec.parameters} | {p.group for p in spec.parameters}
    unknown = sorted(wanted - known)
    if unknown:
        groups = sorted({p.group for p in spec.parameters if p.group})
        raise BadInput(f"free: {', '.join(unknown)} is neither a parameter nor a group of the {spec.name} stand "
                       f"(groups: {', '.join(groups)})")
    return np.array([(p.name in wanted or p.group in wanted) for p in spec.parameters], bool)


def calibrate(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm] = (), free: Sequence[str] | None = None,
              robust: bool = True, folds: int = 0, rel_tol: float = DEFAULT_REL_TOL, max_iter: int = 60,
              progress: Progress | None = None, platform_options: dict | None = None,
              td_start: np.ndarray | None = None, ridge_m: float = 0.0,
              plausible: float | None = PLAUSIBLE_RANGE) -> Calibration:
    """Estimate td, the base-to-mocap transform, marker positions and term parameters.

    poses: settled poses (SI); spec: the stand (its nominal td is the starting point and the value
    of every parameter held); terms: extra physics (ModelTerm); free: see :func:`free_mask`;
    folds: K > 1 adds K-fold held-out prediction errors to ``Calibration.heldout``.
    ridge_m: optional shrinkage of td towards nominal (see CalibrationProblem.set_ridge); 0 (default)
    is plain (robust) least squares.
    plausible: td is kept within nominal +- this many typical corrections (see
    CalibrationProblem.set_plausible; the names that reach the edge are in
    ``identifiability['at_plausible_limit']``); None lets td go anywhere.
    Raises NotIdentifiable when not even the transform and markers can be fixed, NoConvergence
    when forward kinematics fails on most poses.
    """
    with blas_threads(1):
        cal = _calibrate(poses, spec, terms, free, robust, folds, rel_tol, max_iter, progress, platform_options,
                         td_start, ridge_m, plausible)
    cal.extras["warnings"] = fit_warnings(cal, poses)
    check_body_orientations(cal, poses)
    return cal


#: a fit whose RMS is this many times the markers' own noise does not describe the data
MISFIT_RATIO = 10.0
#: ... nor one above this (m), whatever the noise: a marker error of centimetres is no calibration
#: (and points derived from one tracked rigid body keep their distances exactly: no noise floor)
MISFIT_ABSOLUTE_M = 0.005


def marker_noise_floor(poses: PoseSet) -> float:
    """The markers' own noise per axis (m), from the poses alone, without any model of the stand.

    The markers ride one rigid part, so the distance between two of them is the same in every
    pose; its spread (1.4826 MAD over the poses where both were seen) is sqrt(2) sigma for
    isotropic noise sigma per axis. Median over the marker pairs; NaN with fewer than two markers
    or three poses seen together. Points computed from one tracked rigid body give about 0.
    """
    Y = poses.markers
    vis = np.all(np.isfinite(Y), axis=2)
    per_pair = []
    for i in range(poses.n_markers):
        for j in range(i + 1, poses.n_markers):
            both = vis[:, i] & vis[:, j]
            if both.sum() < 3:
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
                 "much the distances between markers vary over the poses" if limit > MISFIT_ABSOLUTE_M
                 else f"more than {MISFIT_ABSOLUTE_M / s:g} {lu}")
        out.append(f"rms_after {cal.rms_after / s:.4g} {lu} is far above any measurement noise ({noise}): the fit "
                   "stopped, but the model does not describe these data. Check that the session is for this stand "
                   "and description, that the control columns are in the stand's order and units (session.yaml "
                   "units), that no marker columns are swapped, then run platkit diagnose")
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
    w = cal.extras.get("weights")
    r = cal.extras.get("residuals_after")
    B = len(cal.body_names)
    if w is None or r is None or not B:
        return {}
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
    w = cal.extras.get("weights")
    r = cal.extras.get("residuals_after")
    if w is None or r is None:
        return {}
    M = len(cal.marker_names)
    seen = np.isfinite(r[:, :M]).all(axis=2)
    rej = seen & (np.asarray(w)[:, :M] <= 0)
    return {n: (int(rej[:, m].sum()), int(seen[:, m].sum())) for m, n in enumerate(cal.marker_names) if rej[:, m].any()}


def _calibrate(poses, spec, terms, free, robust, folds, rel_tol, max_iter, progress, platform_options, td_start,
               ridge_m, plausible) -> Calibration:
    t0 = time.perf_counter()
    free_td = free_mask(spec, free)  # bad names are bad input before any work
    problem = CalibrationProblem(spec, poses, terms)
    td0 = spec.nominal_td() if td_start is None else np.asarray(td_start, float)
    z = problem.initial_registration(td0)
    problem.set_ridge(ridge_m, z)
    problem.set_plausible(plausible)
    n_z = problem.n_z
    nuisance = np.zeros(n_z, bool)
    nuisance[problem.i_w] = nuisance[problem.i_t] = nuisance[problem.i_m] = True
    nuisance[problem.i_body_pos] = nuisance[problem.i_body_rot] = True  # rigid bodies' placements
    st = problem.evaluate(z, with_jac=False)
    if np.mean(st.converged) < 0.5:
        raise NoConvergence(f"{spec.name} forward kinematics at the nominal parameters", 0, float("nan"),
                            f"{int(np.sum(~st.converged))} of {poses.n_poses} poses have no solution; "
                            "check the platform and the control units")
    candidates = nuisance.copy()
    candidates[problem.i_td] = free_mask(spec, free)
    candidates[problem.i_theta] = True
    # stage 0: gauge freedoms (what no set of poses fixes, told apart from what these poses do not
    # excite on the stand's reference poses); the transform and marker coordinates that are gauges
    # are held, and fixed by the stated convention after the fit
    gauge = nuisance_gauge(problem, z, candidates, nuisance, reference_poses_for(spec, problem.model), rel_tol)
    nuisance[gauge.held] = False
    candidates[gauge.held] = False
    # stage 1: registration only (td held at its nominal), robustly
    reg = robust_fit(problem, z, nuisance, robust, max_iter, progress, "registration")
    rms_before = _rms(reg.state, reg.weights)
    residuals_before = reg.state.r.copy()
    # stage 2: identifiability at the registered start
    st = problem.evaluate(reg.z)
    cand_idx = np.nonzero(candidates)[0]
    # seen and solved; what the registration rejected counts too: the model terms may be what
    # explains it (a slipped marker's later half is an outlier only to the geometry), and a
    # Jacobian column does not depend on the measured value
    used = (problem.base_weights > 0) & np.isfinite(st.r).all(axis=2)
    Jc = (np.take(st.J, cand_idx, axis=-1) * np.sqrt(np.where(used, problem.base_weights, 0.0))[:, :, None, None])[used]
    Jc = Jc.reshape(-1, len(cand_idx))
    ident = select_identifiable(Jc, [problem.names[i] for i in cand_idx], problem.scale[cand_idx],
                                problem.tiers[cand_idx].tolist(), rel_tol)
    chosen = cand_idx[ident.chosen]
    lost_nuisance = [h.name for h in ident.held if not h.name.startswith(("term.",)) and
                     (h.name.startswith(("mocap.", "marker.", "body.")))]
    if lost_nuisance:
        raise NotIdentifiable(f"the poses cannot fix {', '.join(lost_nuisance)}: the platform must rotate about "
                              "two axes or translate, and each marker be seen in several poses")
    classify_held(ident, gauge, cand_idx, problem, rel_tol)
    if progress is not None:
        progress("identifiability", {"n_identifiable": len(chosen), "held": [h.name for h in ident.held]})
    active = np.zeros(n_z, bool)
    active[chosen] = True
    # stage 3: the full robust fit
    fit = robust_fit(problem, reg.z, active, robust, max_iter, progress, "iteration")
    fit = refit_body_rho(problem, fit, active, robust, max_iter, progress)
    z = fit.z
    st = problem.evaluate(z)
    weights = fit.weights
    keep = (weights > 0) & np.isfinite(st.r).all(axis=2)
    rms_after = _rms(st, weights)
    # covariance over the active unknowns
    rw, Jw = _weighted(st, weights, active)
    n_obs = 3 * int(keep.sum())
    dof = max(1, n_obs - int(active.sum()))
    s2 = float(rw @ rw) / dof
    JtJ = Jw.T @ Jw
    if problem.prior_rows(z) is not None:  # posterior covariance: the prior rows count as data
        _, Jp = _weighted(st, weights, active, problem.prior_rows(z))
        JtJ = Jp.T @ Jp
    try:
        cov = s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov = s2 * np.linalg.pinv(JtJ)
    std_full = np.full(n_z, np.nan)
    std_full[active] = np.sqrt(np.clip(np.diag(cov), 0, None))
    z, gauge_map = apply_marker_convention(problem, z, gauge)
    if gauge.held and not np.array_equal(gauge_map, np.eye(n_z)):  # the covariance in the convention's gauge
        cov_full = np.zeros((n_z, n_z))
        cov_full[np.ix_(active, active)] = cov
        cov_full = gauge_map @ cov_full @ gauge_map.T
        cov = cov_full[np.ix_(active, active)]
        moved = active | np.any(gauge_map != np.eye(n_z), axis=1)
        std_full[moved] = np.sqrt(np.clip(np.diag(cov_full)[moved], 0, None))
    sv = singular_values(Jw * problem.scale[active][None, :], blocked=True)  # reported only
    # report
    free_td = free_mask(spec, free)
    held_names = {h.name for h in ident.held}
    status = []
    for p, f in zip(spec.parameters, free_td):
        status.append("held_at_nominal" if p.name in held_names else ("estimated" if f else "fixed"))
    td_std = std_full[problem.i_td].copy()
    weak = [problem.names[i] for i in np.nonzero(active)[0]
            if i < spec.n_td and std_full[i] > 10 * problem.scale[i]]
    identifiability = ident.to_dict()
    identifiability.update({
        "singular_values_at_estimate": [float(x) for x in sv],
        "scaled_by": "each parameter's typical correction: 1 mm for lengths, 1 mrad for angles, 1e-3 relative otherwise",
        "weakly_identified": weak,
        "at_plausible_limit": [n for n in problem.beyond_plausible(z) if active[problem.names.index(n)]],
        "plausible_range": None if plausible is None else f"nominal +- {plausible:g} typical corrections",
        "rel_tol": rel_tol,
        "gauge": gauge.to_dict(),
    })
    td, w, t, m, theta = problem.split(z)
    theta_std, k = [], problem.i_theta.start
    for size in problem.theta_sizes:
        theta_std.append(std_full[k:k + size])
        k += size
    cal = Calibration(
        platform=spec.name, description=None if spec.description_path is None else str(spec.description_path),
        spec=spec, td=td.copy(), td_std=td_std, td_nominal=spec.nominal_td(), td_status=status,
        mocap_rotvec=w.copy(), mocap_translation=t.copy(),
        mocap_std=np.concatenate([std_full[problem.i_w], std_full[problem.i_t]]),
        marker_names=list(poses.marker_names), marker_positions=m.copy(),
        marker_std=std_full[problem.i_m].reshape(-1, 3), rms_before=rms_before, rms_after=rms_after,
        length_unit=poses.length_unit, platform_options=dict(spec.extras.get("platform_options") or platform_options or {}),
        method="lsq",
        converged=bool(fit.converged), iterations=int(fit.iterations), n_poses=poses.n_poses,
        n_markers=poses.n_markers, n_observations=int(keep.sum()),
        n_rejected=int(np.sum(problem.visible & ~keep)), noise_sigma=float(np.sqrt(s2)),
        identifiability=identifiability, terms=list(terms), theta=[np.array(x) for x in theta], theta_std=theta_std,
        marker_links=dict(poses.marker_links) if problem.point_links is not None else {},
    )
    cal.extras.update({
        "residuals_before": residuals_before, "residuals_after": st.r.copy(), "weights": weights.copy(),
        "weights_before": reg.weights.copy(), "singular_values": sv, "identifiability": ident,
        "controls": poses.controls.copy(), "active": active, "z": z.copy(), "names": list(problem.names),
        "cov": cov, "problem": problem, "ridge_m": ridge_m,
    })
    if problem.B:
        set_body_placements(cal, problem, z, std_full)
    if folds and folds > 1:
        cal.heldout = kfold(problem, z, active, folds, robust, max_iter, progress)
    cal.time_s = time.perf_counter() - t0
    if progress is not None:
        progress("done", {"rms_before": rms_before, "rms_after": rms_after, "time_s": cal.time_s})
    return cal


def refit_body_rho(problem: CalibrationProblem, fit, active, robust: bool, max_iter: int, progress: Progress | None):
    """With rigid bodies and no declared noise: rho = sigma_position / sigma_rotation (m/rad) from the
    bodies' residuals of ``fit`` (:func:`platkit.bodies.estimate_rho`), and the fit repeated
    with it; twice, as rho moves little after the first. Each channel's scale is corrected for
    what the fit absorbed of it (its rows' leverage: the stand's parameters take more of the
    position noise than of the rotation noise). Returns the last fit (``fit`` unchanged without
    bodies, with declared noise, or when the residuals say nothing)."""
    if not problem.B or problem.rho_source == "declared":
        return fit
    M, B = problem.M, problem.B
    for _ in range(2):
        st = fit.state if fit.state.J is not None else problem.evaluate(fit.z)
        keep = (fit.weights > 0) & np.isfinite(st.r).all(axis=2)
        _, Jw = _weighted(st, fit.weights, active)
        lev = np.einsum("ij,ij->i", Jw @ np.linalg.pinv(Jw.T @ Jw), Jw).reshape(st.r.shape).sum(axis=2)
        dof = []
        for ch in (slice(M, M + B), slice(M + B, M + 2 * B)):  # the bodies' origins, then their rotations
            n = 3.0 * keep[:, ch].sum()
            dof.append(np.sqrt(n / max(n - lev[:, ch][keep[:, ch]].sum(), 1.0)))
        r = st.r * np.sqrt(problem.base_weights)[:, :, None]  # in units of a typical pose's noise
        rho = estimate_rho(r[:, M:M + B][keep[:, M:M + B]] * dof[0],
                           r[:, M + B:][keep[:, M + B:]] / problem.body_rho * dof[1])
        if rho is None:
            break
        problem.body_rho, problem.rho_source = rho, "estimated"
        fit = robust_fit(problem, fit.z, active, robust, max_iter, progress, "iteration")
    return fit


def set_body_placements(cal: Calibration, problem: CalibrationProblem, z: np.ndarray, std_full: np.ndarray) -> None:
    """The rigid bodies' placements on the moving part (origin m, rotation vector rad), their std
    (B, 6) and the weight rho (m/rad) of their rotation channel, from ``z`` into ``cal``."""
    pos, rot = problem.split_bodies(z)
    cal.body_names = list(problem.poses.body_names)
    cal.body_positions, cal.body_rotvecs = pos.copy(), rot.copy()
    cal.body_std = np.concatenate([std_full[problem.i_body_pos].reshape(-1, 3),
                                   std_full[problem.i_body_rot].reshape(-1, 3)], axis=1)
    cal.body_rho, cal.body_rho_source = float(problem.body_rho), problem.rho_source


# ---------------------------------------------------------------------------- prediction


def predict_markers(cal: Calibration, controls: np.ndarray, poses: PoseSet | None = None):
    """Model prediction for controls (N, n_u), SI: markers (N, M, 3) in the mocap frame, pose
    (q (N, 4), X (N, 3)) in the base frame and a converged flag (N,).

    ``poses`` supplies what history- or time-dependent terms need (t, row order, extras); by
    default a PoseSet of the controls alone.
    """
    spec = cal.calibrated_spec()
    model = PlatformModel(spec)
    U = np.atleast_2d(np.asarray(controls, float))
    N, M = U.shape[0], len(cal.marker_names)
    if poses is None:
        poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, M, 3), np.nan),
                        marker_names=list(cal.marker_names), length_unit=cal.length_unit)
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
    if poses is None:
        poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((len(U), len(cal.marker_names), 3), np.nan),
                        marker_names=list(cal.marker_names), length_unit=cal.length_unit)
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


__all__ = ["calibrate", "kfold", "predict_markers", "predict_bodies", "predict_links", "point_errors",
           "second_session_errors",
           "free_mask", "CalibrationProblem", "levenberg_marquardt", "robust_fit", "parameter_scale", "Progress"]
