"""The stages of a calibration by robust least squares, run by :func:`platkit.calibrate.estimate.calibrate`.

0. the problem (:class:`~platkit.calibrate.problem.CalibrationProblem`) and its start: the
   transform and the markers by rigid registration at the starting td, the priors, and the gauge
   freedoms of the transform and markers held (:func:`~platkit.calibrate.identifiability.nuisance_gauge`);
1. registration only (transform and markers, td at its start), robustly: its residuals give
   ``rms_before``, over the observations the final fit keeps (step 3's robust weights), so that
   before and after are RMS over the same observations: the registration's own weights judge
   residuals at a td not yet fitted (a rigid body's declared noise, far below them, rejects most
   of its origins there);
2. identifiability: pivoted orthogonalisation of the scaled Jacobian at the registered start; the
   parameters the data cannot fix are held at nominal and reported by name;
3. Levenberg-Marquardt over everything identifiable, robust (:func:`~platkit.calibrate.solve.robust_fit`),
   with rigid bodies' rotation weight estimated from the residuals where no noise was declared;
4. standard deviations from sigma^2 (J^T W J)^-1, in the gauge's convention;
then the :class:`~platkit.io.calibration.Calibration` and, with ``folds``, k-fold held-out errors.
How it runs is :class:`CalibrationOptions`.

Within a model selection (:func:`~platkit.calibrate.registration.kept_registrations`) the gauge
analysis and stage 1 are kept by everything they read
(:func:`~platkit.calibrate.identifiability.problem_digest`, the masks, the options): the
selection's candidates start from the same poses at the same z, and stage 1 fits only the
transform and markers, so a candidate whose start another has computed takes a copy of it, bit
for bit what computing it again gives. Not where a fit reports its progress (its lines are
told), nor on a stand solved by Newton's method (its solutions start from its last ones).
Within :func:`scored_only` (a selection's scored candidates) what only a written calibration
reports is not computed.
"""
from __future__ import annotations

import copy
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np

from platkit.bodies import estimate_rho
from platkit.calibrate.identifiability import (
    DEFAULT_REL_TOL,
    Gauge,
    Identifiability,
    apply_marker_convention,
    classify_held,
    nuisance_gauge,
    problem_digest,
    select_identifiable,
    singular_values,
    weighted_rows,
)
from platkit.calibrate.plan import reference_poses_for
from platkit.calibrate.problem import PLAUSIBLE_RANGE, CalibrationProblem, FitState, Progress
from platkit.calibrate.registration import digest, kept
from platkit.calibrate.solve import LMResult, _rms, _weighted, kfold, robust_fit, weighted_factor
from platkit.errors import BadInput, NoConvergence, NotIdentifiable
from platkit.io.calibration import Calibration, FitRecord
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm


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


@dataclass(frozen=True, kw_only=True)
class CalibrationOptions:
    """How a calibration fits: each field is the keyword of the same name of
    :func:`platkit.calibrate.estimate.calibrate` (its meaning and default there)."""

    free: Sequence[str] | None = None
    robust: bool = True
    folds: int = 0
    rel_tol: float = DEFAULT_REL_TOL
    max_iter: int = 60
    progress: Progress | None = None
    platform_options: dict | None = None
    td_start: np.ndarray | None = None
    ridge_m: float = 0.0
    plausible: float | None = PLAUSIBLE_RANGE
    row_block: int | None = None


_SCORED = threading.local()


@contextmanager
def scored_only() -> Iterator[None]:
    """Within this block (in this thread), :func:`fit_calibration` leaves out what only a written
    calibration reports and a model selection's scoring of a candidate never reads: the singular
    values (at the start and at the estimate), the chosen columns' condition number, and the
    classification of the held parameters (gauge or not excited) with the gauge's counts and the
    stand parameters' columns on the reference poses, which serve only that (:func:`_start`); its
    ``identifiability`` says so under ``not_computed``. The fit, its active unknowns, weights,
    noise and the names held are a full calibration's."""
    before = getattr(_SCORED, "on", False)
    _SCORED.on = True
    try:
        yield
    finally:
        _SCORED.on = before


def fit_calibration(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm],
                    opt: CalibrationOptions) -> Calibration:
    """The procedure of the module docstring, one stage a line (no warnings: see
    :func:`platkit.calibrate.estimate.calibrate`)."""
    t0 = time.perf_counter()
    report = not getattr(_SCORED, "on", False)  # the figures only a written calibration reports
    start = _start(poses, spec, terms, opt, report)
    problem = start.problem
    # stage 1: registration only (td held at its nominal), robustly
    reg = _registration_only(start, opt)
    residuals_before = reg.state.r.copy()
    # stage 2: identifiability at the registered start
    ident, active = _identifiable(problem, reg.z, start, opt, report)
    # stage 3: the full robust fit
    fit = robust_fit(problem, reg.z, active, opt.robust, opt.max_iter, opt.progress, "iteration")
    fit = refit_body_rho(problem, fit, active, opt.robust, opt.max_iter, opt.progress)
    # stage 4: the uncertainty of the estimate, in the stated gauge
    est = _uncertainty(problem, fit, active, start.gauge, report)
    rms_before = _rms(reg.state, est.weights)  # over the observations the fit kept (module docstring, 1.)
    cal = _calibration(poses, spec, terms, problem, ident, start.gauge, est, rms_before, opt)
    cal.fit = FitRecord(residuals_before=residuals_before, residuals_after=est.state.r.copy(),
                        weights_before=reg.weights.copy(), weights=est.weights.copy(), controls=poses.controls.copy(),
                        problem=problem, z=est.z.copy(), active=active, cov=est.cov, identifiability=ident,
                        stop=fit.window)
    if problem.B:
        set_body_placements(cal, problem, est.z, est.std)
    if opt.folds and opt.folds > 1:
        cal.heldout = kfold(problem, est.z, active, opt.folds, opt.robust, opt.max_iter, opt.progress)
    cal.time_s = time.perf_counter() - t0
    if opt.progress is not None:
        opt.progress("done", {"rms_before": rms_before, "rms_after": est.rms_after, "time_s": cal.time_s})
    return cal


@dataclass(frozen=True)
class _Start:
    """The problem at its start: ``z`` registered at the starting td, the nuisance unknowns
    (transform, markers, rigid bodies' placements) and the candidates to free (nuisance, the free
    td, the terms' parameters), the gauge freedoms held in both."""

    problem: CalibrationProblem
    z: np.ndarray
    nuisance: np.ndarray
    candidates: np.ndarray
    gauge: Gauge


def _start(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm], opt: CalibrationOptions,
           report: bool = True) -> _Start:
    """Stage 0: the problem, its start by rigid registration, its priors, and the gauge freedoms
    (what no set of poses fixes, told apart from what these poses do not excite on the stand's
    reference poses): the transform and marker coordinates that are gauges are held, and fixed by
    the stated convention after the fit. Without ``report`` (:func:`scored_only`) the gauge is
    analysed on the transform and marker columns alone, which decide what it holds (the other
    candidates' columns serve only to classify what is held): one analysis for every candidate
    set. NoConvergence where forward kinematics fails on most poses."""
    free_td = free_mask(spec, opt.free)  # bad names are bad input before any work
    problem = CalibrationProblem(spec, poses, terms)
    problem.row_block = opt.row_block
    td0 = spec.nominal_td() if opt.td_start is None else np.asarray(opt.td_start, float)
    z = problem.initial_registration(td0)
    problem.set_ridge(opt.ridge_m, z)
    problem.set_plausible(opt.plausible)
    nuisance = np.zeros(problem.n_z, bool)
    nuisance[problem.i_w] = nuisance[problem.i_t] = nuisance[problem.i_m] = True
    nuisance[problem.i_body_pos] = nuisance[problem.i_body_rot] = True  # rigid bodies' placements
    st = problem.evaluate(z, with_jac=False)
    if np.mean(st.converged) < 0.5:
        raise NoConvergence(f"{spec.name} forward kinematics at the nominal parameters", 0, float("nan"),
                            f"{int(np.sum(~st.converged))} of {poses.n_poses} poses have no solution; "
                            "check the platform and the control units")
    candidates = nuisance.copy()
    candidates[problem.i_td] = free_td
    candidates[problem.i_theta] = True
    reference = reference_poses_for(spec, problem.model)
    key = problem_digest(problem, z)
    analysed = candidates if report else nuisance.copy()  # the columns the gauge analysis reads
    if key is None:
        gauge = nuisance_gauge(problem, z, analysed, nuisance, reference, opt.rel_tol)
    else:
        gauge = kept("gauge", digest(key, analysed, nuisance, *reference, opt.rel_tol),
                     lambda: (spec, tuple(terms), nuisance_gauge(problem, z, analysed, nuisance, reference, opt.rel_tol)),
                     lambda got: (got[0], got[1], copy.deepcopy(got[2])))[2]
    nuisance[gauge.held] = False
    candidates[gauge.held] = False
    return _Start(problem, z, nuisance, candidates, gauge)


def _registration_only(start: _Start, opt: CalibrationOptions) -> LMResult:
    """Stage 1: the robust fit of the nuisance unknowns from ``start.z``; within a selection, a
    copy of the one kept for the same problem, start and options (the module docstring)."""
    problem = start.problem
    key = None if opt.progress is not None else problem_digest(problem, start.z)

    def fit():
        return robust_fit(problem, start.z, start.nuisance, opt.robust, opt.max_iter, opt.progress, "registration")

    if key is None:
        return fit()

    def copied(got: tuple) -> tuple:
        reg = got[2]
        state = FitState(reg.state.r.copy(), None if reg.state.J is None else reg.state.J.copy(),
                         reg.state.converged.copy(), reg.state.structure)
        return got[0], got[1], replace(reg, z=reg.z.copy(), state=state, weights=reg.weights.copy())

    return kept("registration_only", digest(key, start.nuisance, bool(opt.robust), int(opt.max_iter)),
                lambda: (problem.spec, tuple(problem.terms), fit()), copied)[2]


def _identifiable(problem: CalibrationProblem, z: np.ndarray, start: _Start,
                  opt: CalibrationOptions, classify: bool = True) -> tuple[Identifiability, np.ndarray]:
    """Stage 2: which candidates the poses fix, by pivoted orthogonalisation of the scaled Jacobian
    at ``z`` (the registered start); returns the analysis and the active unknowns (n_z,) bool, the
    held parameters classified with ``classify``. NotIdentifiable where not even the transform and
    the markers are fixed."""
    st = problem.evaluate(z, with_jac=problem.row_block is None)
    cand_idx = np.nonzero(start.candidates)[0]
    # seen and solved; what the registration rejected counts too: the model terms may be what
    # explains it (a slipped marker's later half is an outlier only to the geometry), and a
    # Jacobian column does not depend on the measured value
    used = (problem.base_weights > 0) & np.isfinite(st.r).all(axis=2)
    if st.J is None:  # solved block by block: an R with the Jacobian's column inner products
        Jc = weighted_factor(problem, z, st, np.where(used, problem.base_weights, 0.0), start.candidates)
    else:
        Jc = weighted_rows(problem, st, cand_idx)
    ident = select_identifiable(Jc, [problem.names[i] for i in cand_idx], problem.scale[cand_idx],
                                problem.tiers[cand_idx].tolist(), opt.rel_tol)
    chosen = cand_idx[ident.chosen]
    lost_nuisance = [h.name for h in ident.held if not h.name.startswith(("term.",)) and
                     (h.name.startswith(("mocap.", "marker.", "body.")))]
    if lost_nuisance:
        raise NotIdentifiable(f"the poses cannot fix {', '.join(lost_nuisance)}: the platform must rotate about "
                              "two axes or translate, and each marker be seen in several poses")
    if classify:
        classify_held(ident, start.gauge, cand_idx, problem, opt.rel_tol)
    if opt.progress is not None:
        opt.progress("identifiability", {"n_identifiable": len(chosen), "held": [h.name for h in ident.held]})
    active = np.zeros(problem.n_z, bool)
    active[chosen] = True
    return ident, active


@dataclass(frozen=True)
class _Estimate:
    """The fit's end: ``z`` in the stated gauge, the active unknowns (n_z,) bool, whether the fit
    converged and in how many iterations, the state and robust weights at the fit's own z,
    the observations kept, rms_after (m), the noise variance s2 (m^2 per axis), the covariance
    over the active unknowns, every unknown's std (NaN: not estimated) and the scaled Jacobian's
    singular values (reported only)."""

    z: np.ndarray
    active: np.ndarray
    converged: bool
    iterations: int
    state: FitState
    weights: np.ndarray
    keep: np.ndarray
    rms_after: float
    s2: float
    cov: np.ndarray
    std: np.ndarray
    singular_values: np.ndarray | None


def _uncertainty(problem: CalibrationProblem, fit, active: np.ndarray, gauge: Gauge, report: bool = True) -> _Estimate:
    """Stage 4: sigma^2 (J^T W J)^-1 over the active unknowns (the prior rows counted as data:
    the posterior covariance), then the gauge's convention applied to z and carried into the
    covariance; the singular values (reported only) with ``report``, else None."""
    n_z = problem.n_z
    z = fit.z
    st = problem.evaluate(z, with_jac=problem.row_block is None)
    weights = fit.weights
    keep = (weights > 0) & np.isfinite(st.r).all(axis=2)
    rms_after = _rms(st, weights)
    rw, Jw = _weighted(st, weights, active)
    if Jw is None:  # solved block by block: an R with R^T R = Jw^T Jw stands in for Jw
        Jw = weighted_factor(problem, z, st, weights, active)
    n_obs = 3 * int(keep.sum())
    dof = max(1, n_obs - int(active.sum()))
    s2 = float(rw @ rw) / dof
    JtJ = Jw.T @ Jw
    if problem.prior_rows(z) is not None:  # posterior covariance: the prior rows count as data
        _, Jp = _weighted(st, weights, active, problem.prior_rows(z))
        if Jp is None:
            Jp = weighted_factor(problem, z, st, weights, active, problem.prior_rows(z))
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
    sv = singular_values(Jw * problem.scale[active][None, :], blocked=True) if report else None  # reported only
    return _Estimate(z, active, bool(fit.converged), int(fit.iterations), st, weights, keep, rms_after, s2, cov,
                     std_full, sv)


def _calibration(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm], problem: CalibrationProblem,
                 ident: Identifiability, gauge: Gauge, est: _Estimate, rms_before: float,
                 opt: CalibrationOptions) -> Calibration:
    """The Calibration of the estimate: values, stds and statuses ('held_at_nominal' where the data
    cannot fix a parameter, 'estimated', 'fixed' where it was not free), the identifiability report."""
    z, std_full = est.z, est.std
    free_td = free_mask(spec, opt.free)
    held_names = {h.name for h in ident.held}
    status = []
    for p, f in zip(spec.parameters, free_td):
        status.append("held_at_nominal" if p.name in held_names else ("estimated" if f else "fixed"))
    td_std = std_full[problem.i_td].copy()
    td, w, t, m, theta = problem.split(z)
    theta_std, k = [], problem.i_theta.start
    for size in problem.theta_sizes:
        theta_std.append(std_full[k:k + size])
        k += size
    return Calibration(
        platform=spec.name, description=None if spec.description_path is None else str(spec.description_path),
        spec=spec, td=td.copy(), td_std=td_std, td_nominal=spec.nominal_td(), td_status=status,
        mocap_rotvec=w.copy(), mocap_translation=t.copy(),
        mocap_std=np.concatenate([std_full[problem.i_w], std_full[problem.i_t]]),
        marker_names=list(poses.marker_names), marker_positions=m.copy(),
        marker_std=std_full[problem.i_m].reshape(-1, 3), rms_before=rms_before, rms_after=est.rms_after,
        length_unit=poses.length_unit,
        platform_options=dict(spec.extras.get("platform_options") or opt.platform_options or {}),
        method="lsq",
        converged=est.converged, iterations=est.iterations, n_poses=poses.n_poses,
        n_markers=poses.n_markers, n_observations=int(est.keep.sum()),
        n_rejected=int(np.sum(problem.visible & ~est.keep)), noise_sigma=float(np.sqrt(est.s2)),
        identifiability=_identifiability_report(problem, ident, gauge, est, opt), terms=list(terms),
        theta=[np.array(x) for x in theta], theta_std=theta_std,
        marker_links=dict(poses.marker_links) if problem.point_links is not None else {},
    )


def _identifiability_report(problem: CalibrationProblem, ident: Identifiability, gauge: Gauge, est: _Estimate,
                            opt: CalibrationOptions) -> dict:
    """calibration.yaml's ``identifiability``: the analysis, the singular values at the estimate,
    the parameters weakly identified (std above 10 typical corrections) and those at the edge of
    their plausible range, the tolerance and the gauge."""
    active, std_full = est.active, est.std
    if est.singular_values is None:  # a selection's scored candidate (scored_only)
        return {"n_candidates": len(ident.names), "n_identifiable": len(ident.chosen),
                "held_at_nominal": [h.to_dict() for h in ident.held], "rel_tol": opt.rel_tol,
                "not_computed": "a model selection's scored candidate: the singular values, the condition number "
                                "and the classification of what is held, which only a written calibration reports"}
    weak = [problem.names[i] for i in np.nonzero(active)[0]
            if i < problem.spec.n_td and std_full[i] > 10 * problem.scale[i]]
    identifiability = ident.to_dict()
    identifiability.update({
        "singular_values_at_estimate": [float(x) for x in est.singular_values],
        "scaled_by": "each parameter's typical correction: 1 mm for lengths, 1 mrad for angles, 1e-3 relative otherwise",
        "weakly_identified": weak,
        "at_plausible_limit": [n for n in problem.beyond_plausible(est.z) if active[problem.names.index(n)]],
        "plausible_range": None if opt.plausible is None else f"nominal +- {opt.plausible:g} typical corrections",
        "rel_tol": opt.rel_tol,
        "gauge": gauge.to_dict(),
    })
    return identifiability


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
        st = fit.state if fit.state.has_jacobian else problem.evaluate(fit.z)
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
