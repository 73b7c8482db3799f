"""How much of the geometry to free, chosen by held-out prediction (the default of ``platkit calibrate``).

A stand's parameters come in groups (the urdf stand: ``offset``, ``scale``, ``origin``; stewart:
``base_joints``, ``platform_joints``, ``leg_offsets``; ...). Freeing a group the data fix only
weakly costs accuracy on new poses: its estimate absorbs noise and whatever physics the model
leaves out. Holding a group the stand really needs costs more. :func:`select_model` chooses by
what a user wants from a calibration, prediction of poses it was not fitted on:

1. the most general model (every group, including those a stand holds by default, such as the
   urdf stand's joint scales) is fitted with the robust loss; the observations it rejects as
   outliers are left out of every later comparison, so that all candidates are judged on the same
   observations;
2. backward elimination over the groups: each candidate (the current set less one group) is
   fitted and its leave-one-pose-out prediction errors (:func:`heldout_errors`) compared with the
   current model's, pose by pose (:func:`heldout_evidence`). A group is kept when prediction is
   clearly worse without it (the RMS or the median, by more than Z_CLEAR standard errors); where
   held-out prediction cannot tell (the measurement noise of the held-out marker hides what a few
   parameters change), it is kept if the fit without it is worse beyond the noise (likelihood
   ratio at FIT_LEVEL, :func:`group_significance`), and dropped otherwise. A group that the others
   make redundant (same held-out errors) is dropped, after the others. One group per round, the
   least supported;
3. the chosen groups are fitted once more on the whole session with the user's loss.

The candidates of 2. are scored, never written: their fits leave out what only a written calibration
reports (:func:`~platkit.calibrate.stages.scored_only`).

Model terms (physics a diagnosis accepted) may be fitted with every candidate
(:func:`reselect_geometry`): the geometry is then chosen beside the physics, and a group that only
stood in for it (a torso joint's scale for gravity sag) is held.

Scores: the median and the RMS of the held-out 3-D marker errors (every kept observation of every
pose, each predicted from a fit without its pose). The median is the typical error of a new pose;
the RMS weighs every pose. On real data a few poses that no other pose resembles dominate the RMS
(each is predicted by extrapolation, badly by every model): on the TIAGo training day the RMS
favours holding the joint scales, the median freeing them, neither clearly (docs/calibration.md).

Leave-one-pose-out errors come from one fit per candidate: at the least-squares solution, the
solution without pose n's rows is the Gauss-Newton step ``dz = (A - J_n^T W_n J_n)^-1 J_n^T W_n r_n``
(A = J^T W J plus the priors), exact for a linear model; on the TIAGo arm (plain least squares,
37 refits) each pose's error is within 0.1 mm of refitting and the RMS and median within 0.01 mm.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.identifiability import keep_one_side_of_a_lost_marker
from platkit.calibrate.problem import Progress
from platkit.calibrate.registration import kept_registrations
from platkit.calibrate.solve import blas_threads
from platkit.calibrate.stages import scored_only
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec, length_scale
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: two candidates whose held-out median and RMS agree to this fraction describe the same (a joint
#: offset beside its origin's rotation): the group between them is redundant
TOLERANCE = 1e-6
#: held-out prediction says clearly that a group helps beyond this many standard errors
Z_CLEAR = 2.0
#: where held-out prediction cannot tell, a group is kept if the fit without it is worse at this level
FIT_LEVEL = 0.01
#: fewer poses than this: nothing is selected (the stand's default free set is fitted)
MIN_POSES = 8
#: poses whose leave-one-out systems are solved in one stacked call
CHUNK_POSES = 512
#: beyond this condition number of I - P_n a pose's leave-one-out error is solved by lstsq
WOODBURY_COND = 1e8
UNGROUPED = "(ungrouped)"


def parameter_groups(spec: PlatformSpec) -> dict[str, list[str]]:
    """The stand's parameter groups in description order: {group: [parameter names]}.

    Parameters without a group are gathered under ``(ungrouped)``."""
    groups: dict[str, list[str]] = {}
    for p in spec.parameters:
        groups.setdefault(p.group or UNGROUPED, []).append(p.name)
    return groups


def heldout_errors(cal: Calibration) -> np.ndarray:
    """Leave-one-pose-out prediction errors (N, M) in metres of a least-squares calibration.

    For every pose n, the fit without pose n's observations is taken as the Gauss-Newton step
    from the full solution (A - B_n) dz = J_n^T W_n r_n, A = J^T W J + priors, B_n the pose's share;
    the error is |r_n + J_n dz| per marker. Every unknown the calibration estimated moves (the
    stand's parameters, the base-to-mocap transform, the markers). NaN where the marker was not
    seen or the fit's loss rejected it (weight 0).
    """
    with blas_threads(1):  # stacked products of small matrices: BLAS threads only spin
        return _heldout_errors(cal)


def _ill_conditioned(X: np.ndarray) -> np.ndarray:
    """Where the 2-norm condition number of X[k] (K, m, m) exceeds WOODBURY_COND: decided by the
    bound cond <= |X|_F |X^-1|_F (an LU each), and by singular values where the bound passes half
    the limit (the computed inverse's rounding, at most cond * eps relative, stays far inside it)
    or where a matrix is singular; the same decision as singular values alone."""
    try:
        inv = np.linalg.inv(X)
        check = ~(np.linalg.norm(X, axis=(1, 2)) * np.linalg.norm(inv, axis=(1, 2)) <= WOODBURY_COND / 2)
    except np.linalg.LinAlgError:
        check = np.ones(len(X), bool)
    ill = np.zeros(len(X), bool)
    if check.any():
        ill[check] = np.linalg.cond(X[check]) > WOODBURY_COND
    return ill


def _heldout_errors(cal: Calibration) -> np.ndarray:
    problem, z, active, weights = cal.fit.problem, cal.fit.z, cal.fit.active, cal.fit.weights
    st = problem.evaluate(z)
    N, M = st.r.shape[:2]
    seen = np.isfinite(st.r).all(axis=2) & (weights > 0)
    w = np.where(seen, weights, 0.0)
    r = np.where(seen[..., None], st.r, 0.0)
    J = np.take(st.J, np.flatnonzero(active), axis=3)  # (N, M, 3, n_a)
    J[~seen] = 0.0
    n_a = J.shape[-1]
    Jw = (J * np.sqrt(w)[:, :, None, None]).reshape(-1, n_a)
    A = Jw.T @ Jw
    prior = problem.prior_rows(z)
    if prior is not None:  # the priors stay when a pose leaves: they are no observation
        _, idx, slope = prior
        cols = np.cumsum(active) - 1
        for i, s in zip(idx, slope):
            if active[i]:
                A[cols[i], cols[i]] += s * s
    E = np.full((N, M), np.nan)
    Jr = J.reshape(N, 3 * M, n_a)
    wr = np.repeat(w, 3, axis=1)  # (N, 3 M)
    rr = r.reshape(N, 3 * M)
    # r_n + J_n dz = (I - P_n)^-1 r_n with P_n = J_n A^-1 J_n^T W_n (Woodbury): one 3M x 3M solve
    # per pose, all poses stacked, instead of an n_a x n_a least-squares solve each; where I - P_n
    # is near singular (the pose alone fixes some unknown) the pose is solved as before (lstsq)
    A_inv = np.linalg.inv(A) if np.linalg.cond(A) < WOODBURY_COND * 100 else None  # else every pose by lstsq
    lstsq_poses = np.ones(N, bool) if A_inv is None else np.zeros(N, bool)
    for start in range(0, 0 if A_inv is None else N, CHUNK_POSES):
        k = slice(start, min(N, start + CHUNK_POSES))
        JA = (Jr[k].reshape(-1, n_a) @ A_inv).reshape(-1, 3 * M, n_a)  # one product for the chunk
        I_P = np.eye(3 * M)[None] - JA @ np.swapaxes(Jr[k] * wr[k][:, :, None], 1, 2)
        ill = _ill_conditioned(I_P)
        I_P[ill] = np.eye(3 * M)
        E[k] = np.linalg.norm(np.linalg.solve(I_P, rr[k][:, :, None])[:, :, 0].reshape(-1, M, 3), axis=2)
        lstsq_poses[k] = ill
    for n in np.nonzero(lstsq_poses & seen.any(axis=1))[0]:
        Jn = Jr[n]
        dz = np.linalg.lstsq(A - Jn.T @ (wr[n][:, None] * Jn), Jn.T @ (wr[n] * rr[n]), rcond=None)[0]
        E[n] = np.linalg.norm((rr[n] + Jn @ dz).reshape(M, 3), axis=1)
    E[~seen] = np.nan
    return E


@dataclass
class Candidate:
    """One model the selection scored: the groups it frees and its held-out errors (m)."""

    groups: tuple[str, ...]
    n_estimated: int
    fit_rms: float
    heldout_median: float
    heldout_rms: float
    n_heldout: int
    errors: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 0)))  # (N, M) m, NaN unseen

    def as_dict(self, unit: str) -> dict:
        s = length_scale(unit)
        return {"free": list(self.groups), "n_parameters_estimated": self.n_estimated,
                "heldout_median": self.heldout_median / s, "heldout_rms": self.heldout_rms / s,
                "fit_rms": self.fit_rms / s, "n_heldout_observations": self.n_heldout}


@dataclass
class Selection:
    """What :func:`select_model` chose and why; ``to_dict`` is what calibration.yaml and report.json
    carry under ``model_selection`` (lengths in the session's unit)."""

    groups: list[str]
    chosen: list[str]
    candidates: list[Candidate] = field(default_factory=list)
    reason: str = ""
    n_left_out: int = 0
    time_s: float = 0.0

    def to_dict(self, unit: str) -> dict:
        return {
            "method": "backward elimination over parameter groups, scored by leave-one-pose-out prediction",
            "criterion": "median and RMS of the held-out 3-D marker errors (each pose predicted by a fit without it)",
            "rule": (f"a group is kept when held-out prediction is clearly worse without it (median or RMS, more than "
                     f"{Z_CLEAR:g} standard errors), or, where held-out prediction cannot tell, when the fit without "
                     f"it is worse beyond the noise (likelihood ratio, p < {FIT_LEVEL:g}); otherwise it is held"),
            "unit": unit,
            "groups": list(self.groups),
            "chosen": list(self.chosen),
            "held": [g for g in self.groups if g not in self.chosen],
            "reason": self.reason,
            "observations_left_out": self.n_left_out,
            "candidates": [c.as_dict(unit) for c in self.candidates],
            "time_s": round(float(self.time_s), 3),
            "override": "--free GROUPS (fit these, no selection), --no-selection (the stand's default free set)",
        }


def _names(groups: dict[str, list[str]], chosen: Sequence[str]) -> list[str]:
    return [n for g in chosen for n in groups[g]]


def _score(cal: Calibration, groups: tuple[str, ...]) -> Candidate:
    E = heldout_errors(cal)
    d = E[np.isfinite(E)]
    return Candidate(groups, int(sum(st == "estimated" for st in cal.td_status)), float(cal.rms_after),
                     float(np.median(d)) if d.size else float("inf"),
                     float(np.sqrt(np.mean(d ** 2))) if d.size else float("inf"), int(d.size), E)


def heldout_evidence(with_g: Candidate, without_g: Candidate) -> tuple[float, float]:
    """How clearly a group helps held-out prediction: (z of the RMS, z of the median), positive
    when the model without the group predicts worse.

    RMS: the per-pose mean of (error without)^2 - (error with)^2, its mean over the poses in
    standard errors (a pose's markers share its errors, so poses are the independent units).
    Median: the sign test, observations predicted worse without the group against half of them.
    """
    a, b = without_g.errors, with_g.errors
    both = np.isfinite(a) & np.isfinite(b)
    per_pose = np.array([np.mean(a[n, both[n]] ** 2 - b[n, both[n]] ** 2) for n in range(len(a)) if both[n].any()])
    z_rms = 0.0
    if per_pose.size > 1 and np.std(per_pose) > 0:
        z_rms = float(np.mean(per_pose) / (np.std(per_pose, ddof=1) / np.sqrt(per_pose.size)))
    n = int(both.sum())
    z_median = float((np.sum(a[both] > b[both]) - n / 2) / np.sqrt(n / 4)) if n else 0.0
    return z_rms, z_median


def group_significance(with_g: Calibration, without_g: Calibration) -> tuple[float, int]:
    """(p-value, dof) of the likelihood-ratio test that a group's parameters are not needed: the fit
    without it against the fit with it, on the same observations.

    chi^2 = (RSS without - RSS with) / sigma^2 (sigma^2 per axis from the fit with it), with as many
    degrees of freedom as the fit with it estimates more unknowns; what the other groups describe
    as well (a joint offset beside its origin's rotation) adds none. (1.0, 0) when it adds none.
    """
    from scipy.stats import chi2

    def rss_dof(cal):
        n_active = int(np.sum(cal.fit.active))
        dof = max(1, 3 * int(cal.n_observations) - n_active)
        return cal.noise_sigma ** 2 * dof, dof, n_active

    rss1, dof1, n1 = rss_dof(with_g)
    rss0, _, n0 = rss_dof(without_g)
    k = n1 - n0
    if k <= 0 or not rss1 > 0:
        return 1.0, max(k, 0)
    stat = max(0.0, (rss0 - rss1) / (rss1 / dof1))
    return float(chi2.sf(stat, k)), k


def select_model(poses: PoseSet, spec: PlatformSpec, robust: bool = True, progress: Progress | None = None,
                 platform_options: dict | None = None, ridge_m: float = 0.0, folds: int = 0,
                 tolerance: float = TOLERANCE, terms: Sequence[ModelTerm] = ()) -> Calibration:
    """Calibrate with the parameter groups chosen by held-out prediction (module docstring).

    Returns the final :class:`Calibration`, its ``identifiability['model_selection']`` saying what
    was chosen, what each candidate scored and why (lengths in the session's unit).
    ``folds``: K-fold held-out errors of the chosen model, as :func:`calibrate`.
    ``terms``: model terms (accepted physics) fitted with every candidate, so that the geometry is
    chosen beside them (:func:`reselect_geometry`). Its candidates start from the same rigid
    registrations: they are kept while it runs (:func:`~platkit.calibrate.registration.kept_registrations`).
    """
    with kept_registrations():
        return _select_model(poses, spec, robust, progress, platform_options, ridge_m, folds, tolerance, terms)


def _select_model(poses: PoseSet, spec: PlatformSpec, robust: bool, progress: Progress | None,
                  platform_options: dict | None, ridge_m: float, folds: int, tolerance: float,
                  terms: Sequence[ModelTerm]) -> Calibration:
    """:func:`select_model`'s procedure."""
    t0 = time.perf_counter()
    groups = parameter_groups(spec)
    labels = list(groups)
    unit = poses.length_unit
    s = length_scale(unit)
    common = dict(platform_options=platform_options, ridge_m=ridge_m, terms=list(terms))

    def note(text: str) -> None:
        if progress is not None:
            progress("selection", {"text": text})

    if len(labels) < 2 or poses.n_poses < MIN_POSES:
        why = (f"the {spec.name} stand has {len(labels)} parameter group{'s' if len(labels) != 1 else ''}: nothing to choose"
               if len(labels) < 2 else f"{poses.n_poses} poses are too few to hold any out (at least {MIN_POSES})")
        cal = calibrate(poses, spec, robust=robust, progress=progress, folds=folds, **common)
        default = [g for g in labels if any(p.free for p in spec.parameters if (p.group or UNGROUPED) == g)]
        sel = Selection(labels, default, reason=f"no selection: {why}; the stand's default free parameters are fitted",
                        time_s=time.perf_counter() - t0)
        cal.identifiability["model_selection"] = sel.to_dict(unit)
        return cal
    note(f"the most general model: every group free ({', '.join(labels)})")
    reference = calibrate(poses, spec, free=_names(groups, labels), robust=robust, progress=progress, **common)
    fit = reference.fit
    kept = fit.weights > 0
    # a marker the robust fit rejected wholly (one that slipped) keeps one side of its step
    kept = keep_one_side_of_a_lost_marker(kept, fit.residuals_after, fit.problem, fit.z)[0]
    M, B = poses.n_markers, poses.n_bodies  # channels: markers, then each body's origin and rotation
    left_out = int(np.sum(fit.problem.visible & ~kept))
    clean = poses.subset(np.ones(poses.n_poses, bool))
    clean.markers = np.where(kept[:, :M, None], poses.markers, np.nan)
    if B:
        clean.bodies = np.where((kept[:, M:M + B] & kept[:, M + B:])[..., None], poses.bodies, np.nan)
    fits: dict[tuple[str, ...], Calibration] = {tuple(labels): reference}
    scores: dict[tuple[str, ...], Candidate] = {tuple(labels): _score(reference, tuple(labels))}
    current = tuple(labels)
    note(f"every group: held-out median {scores[current].heldout_median / s:.4g} {unit}, "
         f"RMS {scores[current].heldout_rms / s:.4g} {unit}")
    dropped: list[tuple[str, str]] = []  # (group, why)
    kept_why: dict[str, str] = {}
    while len(current) > 1:
        cur = scores[current]
        trials = []
        for g in current:
            trial = tuple(x for x in current if x != g)
            if trial not in scores:  # scored, never written: without what only a written calibration reports
                with scored_only():
                    cal = calibrate(clean, spec, free=_names(groups, trial), robust=False, **common)
                fits[trial], scores[trial] = cal, _score(cal, trial)
                note(f"without {g}: held-out median {scores[trial].heldout_median / s:.4g} {unit}, "
                     f"RMS {scores[trial].heldout_rms / s:.4g} {unit}")
            c = scores[trial]
            numbers = (f"held-out median / RMS {c.heldout_median / s:.3g} / {c.heldout_rms / s:.3g} {unit} without it, "
                       f"{cur.heldout_median / s:.3g} / {cur.heldout_rms / s:.3g} with it")
            if (abs(c.heldout_median - cur.heldout_median) <= tolerance * cur.heldout_median
                    and abs(c.heldout_rms - cur.heldout_rms) <= tolerance * cur.heldout_rms):
                # last in line: of two groups that describe the same, the other may be dropped instead
                trials.append(((1, 0.0), g, trial, f"{g} held: the other groups describe the same ({numbers})"))
                continue
            z_rms, z_med = heldout_evidence(cur, c)
            if max(z_rms, z_med) > Z_CLEAR:
                kept_why[g] = (f"{g} kept: held-out prediction is clearly worse without it ({numbers}; "
                               f"z {z_rms:.1f} for the RMS, {z_med:.1f} for the median)")
                continue
            p, dof = group_significance(fits[current], fits[trial])
            if p < FIT_LEVEL:
                kept_why[g] = (f"{g} kept: held-out prediction cannot tell ({numbers}; z {z_rms:.1f}, {z_med:.1f}), "
                               f"and the fit without it is worse beyond the noise (likelihood ratio, {dof} unknowns, "
                               f"p = {p:.2g})")
                continue
            trials.append(((0, max(z_rms, z_med)), g, trial,
                           f"{g} held: held-out prediction is no clearly better with it ({numbers}; z {z_rms:.1f}, "
                           f"{z_med:.1f}), nor the fit beyond the noise (likelihood ratio, {dof} unknowns, p = {p:.2g})"))
        if not trials:
            break
        _, g, trial, why = min(trials, key=lambda x: x[0])
        dropped.append((g, why))
        kept_why.pop(g, None)
        current = trial
    chosen = list(current)
    held = [g for g in labels if g not in chosen]
    cur = scores[current]
    parts = [f"free {', '.join(chosen)} (held-out median {cur.heldout_median / s:.3g} {unit}, "
             f"RMS {cur.heldout_rms / s:.3g} {unit})"]
    parts += [why for _, why in dropped]
    parts += [kept_why[g] for g in chosen if g in kept_why]
    reason = "; ".join(parts)
    if current == tuple(labels):
        cal = reference
        if folds and folds > 1:
            cal = calibrate(poses, spec, free=_names(groups, labels), robust=robust, folds=folds, **common)
    else:
        cal = calibrate(poses, spec, free=_names(groups, chosen), robust=robust, progress=progress, folds=folds,
                        **common)
    order = sorted(scores.values(), key=lambda c: (c.heldout_median, len(c.groups)))
    sel = Selection(labels, chosen, order, reason, left_out, time.perf_counter() - t0)
    cal.identifiability["model_selection"] = sel.to_dict(unit)
    if terms:
        cal.identifiability["model_selection"]["beside_terms"] = [t.effect for t in terms]
    note(f"chose {', '.join(chosen)}" + (f"; held {', '.join(held)}" if held else ""))
    return cal


def reselect_geometry(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm], robust: bool = True,
                      progress: Progress | None = None, platform_options: dict | None = None,
                      ridge_m: float = 0.0) -> Calibration:
    """The geometry's model selection made again on a model augmented by ``terms`` (effects a
    diagnosis accepted): every candidate set of parameter groups is fitted with the terms, and the
    groups are chosen by held-out prediction as :func:`select_model` does.

    Why: a group chosen without the physics may have stood in for it (on a humanoid the torso
    joints' scales, freed at 1.05, take the place of gravity sag); once the physics is modelled, a
    group that no longer predicts held-out poses better is held. Returns the Calibration of the
    chosen groups with the terms fitted; ``identifiability['model_selection']`` says what was chosen
    and ``beside_terms`` which effects it was chosen beside."""
    return select_model(poses, spec, robust=robust, progress=progress, platform_options=platform_options,
                        ridge_m=ridge_m, terms=terms)


__all__ = ["select_model", "reselect_geometry", "heldout_errors", "parameter_groups", "Selection", "Candidate", "TOLERANCE"]
