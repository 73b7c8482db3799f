"""Forward selection of effects: screen, refit with the shared estimator, accept on held-out proof.

One round (repeated until nothing passes or ``max_effects`` are in):

1. screen every candidate term of every effect (one per actuator, marker, period, ...) with a
   score test on the current fit's residuals: the part of the term's Jacobian columns outside
   the identification Jacobian's column space against the residual (Holm over all candidates).
   A term with almost nothing outside that space (separability < ``min_separability``) cannot
   be told from the geometry on this design: it is set aside with a warning, never accepted;
2. refit the best few, each added to the model, together with td, the mocap transform and
   the markers (the estimator's robust fit); every model is scored on every seen observation;
3. take the refit candidate with the lowest BIC; accept it if its BIC is below the current
   model's AND its K-fold held-out prediction improves significantly (one-sided Wilcoxon on the
   per-pose held-out errors at ``alpha_heldout``; one confirmatory test per round, in the order
   BIC fixes: a fixed-sequence procedure, so no multiplicity correction is needed); unless a
   generic probe (probes.py) predicts significantly better still, in which case the structure
   is reported ``unexplained`` and not named. When a probe still beats the named model after the
   last round, each named term is tested again beside it, and one that no longer predicts better
   is not named (naming._unproven_beside_probe; the other checks on a name live there too); where
   none does but the model is left above twice the noise floor with its residuals structured in
   time, each is tested beside a time probe fine enough to follow that structure
   (naming._unproven_beside_time).

Held-out errors: poses are split into K interleaved folds (pose n in fold n mod K); each fold's
poses are predicted from a refit on the others, started from the full fit.

Effects whose ``recording`` is True describe the recording, not the stand (a lag, a slipped
marker): they are fitted like the others, so that the geometry is estimated from corrected data,
but the calibration diagnosis writes predicts where the stand settles: without the lag, with a
moved marker at its new place (:func:`stand_calibration`). Holds that never settled are found in
the raw stream by the settling search (platkit.settle); when it extrapolated them to rest, the
finding of the ``unsettled_holds`` effect says which actuators lag and with what time constant,
and is accepted only if the calibration from the extrapolated poses predicts the held-out *settled*
poses better than one from where the stream was at the end of those holds.

Nothing is named when the geometric model already predicts held-out poses at the noise floor
(the averaging noise of the settled poses, from the stream's noise and the samples averaged):
an effect of any shape the geometry absorbs on this plan leaves nothing to find. With nothing
found, a geometric model more than ``lack_of_fit_factor`` times the floor is a lack of fit
(``unexplained``); below that, where held-out prediction cannot tell a weak effect from noise,
residuals alike at poses next in time or with near commands are (locate.neighbour_tests); both
rules are in lack_of_fit.py.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from platkit.calibrate.estimate import CalibrationProblem, calibrate, point_errors
from platkit.calibrate.selection import parameter_groups, reselect_geometry
from platkit.diagnose.floor import noise_floor
from platkit.diagnose.locate import locate, located
from platkit.diagnose.stats import column_basis, holm, paired_improvement, score_test
from platkit.effects import Effect, with_history
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec, length_scale
from platkit.plugins import effect_library
from platkit.poses import PoseSet
from platkit.terms import ModelTerm
from platkit.diagnose.fitting import (FROM_SLOW_APPROACH, ROUND_BESIDE_PROBE, ROUND_BESIDE_TIME, ROUND_WEAK_NAMES,
                                       Diagnosis, Finding, Fit, Options, _cv, _fit, _fmt_rms, _obs, _rms, _where_text,
                                       body_residuals, extrapolated)
from platkit.diagnose.lack_of_fit import lack_of_fit
from platkit.diagnose.naming import (
    _best_probe,
    _probe_beats,
    _unnamed,
    _unproven_beside_probe,
    _unproven_beside_time,
    _weak_beside_lack_of_fit,
    _without,
)
from platkit.diagnose.recording import (
    _settling_finding,
    _slip_not_kept,
    _slow_actuator_echo,
    stand_calibration,
    unsettled_effect,
    weak_beside_the_recording,
)
from platkit.diagnose.verdict import verdict

__all__ = ["diagnose", "screen", "confirm"]


def _weighted_system(fit: Fit, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keep = _obs(fit.weights, fit.r)
    sw = np.sqrt(fit.weights)[:, :, None] * keep[:, :, None]
    r = (np.nan_to_num(fit.r) * sw).reshape(-1)
    Jw = (np.nan_to_num(J) * sw[..., None]).reshape(-1, J.shape[-1])
    rows = np.repeat(keep.reshape(-1), 3)
    return r[rows], Jw[rows]

def screen(fit: Fit, spec: PlatformSpec, poses: PoseSet, candidates: list[ModelTerm]) -> list[tuple[float, float, float, np.ndarray]]:
    """Score test of each candidate at the current fit: [(F, p, separability, J columns (N, M, 3, k))]."""
    if not candidates:
        return []
    problem = CalibrationProblem(spec, poses, fit.terms + list(candidates))
    z = np.concatenate([fit.z, np.concatenate([np.asarray(c.initial, float) * 0 for c in candidates])])
    st = problem.evaluate(z, with_jac=True)
    n_base = len(fit.z)
    r, J = _weighted_system(fit, st.J)
    Jb = J[:, :n_base][:, fit.active]
    dof = len(r) - int(fit.active.sum())
    basis = column_basis(Jb)
    out, k = [], n_base
    for c in candidates:
        K = len(c.initial)
        F, p, sep = score_test(r, Jb, J[:, k:k + K], dof, basis=basis)
        out.append((F, p, sep, st.J[..., k:k + K]))
        k += K
    return out

def _signature(J: np.ndarray, r: np.ndarray, theta: np.ndarray | None, sign: np.ndarray) -> np.ndarray:
    """(N,) each pose's measured-minus-model error along the term's signature (m): r_n (M*3)
    projected on J_n theta_hat, signed by the term's own offset at that pose (``sign``), so that
    it follows the regressor (a backlash's two directions fall on two sides of zero)."""
    N = J.shape[0]
    Jn = np.nan_to_num(J.reshape(N, -1, J.shape[-1]))
    d = Jn @ (theta if theta is not None and np.linalg.norm(theta) > 0 else np.ones(J.shape[-1]))
    rn = np.nan_to_num(r.reshape(N, -1))
    size = np.linalg.norm(d, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(size > 0, -np.sum(rn * d, axis=1) / size * sign, np.nan)

def _offset_sign(term: ModelTerm, theta: np.ndarray, fit: "Fit", poses: PoseSet) -> np.ndarray:
    """(N,) sign of the term's offset at each pose, in its most varying component."""
    q, X = fit.problem.kinematics(fit.problem.split(fit.z)[0], poses.controls)[:2]
    parts = [term.control_offset(theta, poses, poses.controls.shape[1]), term.pose_offset(theta, poses, q, X),
             term.marker_offset(theta, poses).reshape(poses.n_poses, -1)]
    off = np.concatenate([np.nan_to_num(p) for p in parts], axis=1)
    return np.sign(off[:, int(np.argmax(np.var(off, axis=0)))])

def _place(term: ModelTerm) -> tuple:
    """(effect, actuator or marker): terms of one kind at one place compete, never add up."""
    w = term.where
    actuator = str(w.get("actuator", ""))
    return term.effect, "" if actuator == "all" else actuator, str(w.get("marker", ""))

def _params(term: ModelTerm, theta: np.ndarray, std: np.ndarray | None) -> dict[str, dict[str, Any]]:
    d = term.to_dict(theta, std)["parameters"]
    for v in d.values():
        if v["std"] is not None and not np.isfinite(v["std"]):
            v["std"] = None
    return d

# ---------------------------------------------------------------------------- the search
def diagnose(spec: PlatformSpec, poses: PoseSet, options: Options | None = None,
             library: dict[str, Effect] | None = None, heldout: PoseSet | None = None,
             progress: Callable[[str], None] | None = None, start: Calibration | None = None) -> Diagnosis:
    """Find, name and model what the geometric calibration of ``poses`` leaves structured.

    spec: the stand; poses: the session (SI); library: effect name -> Effect (default: every
    installed effect); heldout: optionally another recording of the same stand in the same
    mocap frame, scored before and after (never used to choose); start: the calibration being
    diagnosed (its stand, its estimated parameters as the free set, its td as the start, its
    terms kept). Returns a :class:`Diagnosis` whose ``calibration`` is the final model.
    """
    opt = options or Options()
    library = effect_library() if library is None else library
    say = progress or (lambda s: None)
    poses = with_history(poses, spec)
    unit = poses.length_unit
    free, td_start, prior = opt.free, None, []
    if start is not None:
        spec = start.spec
        if free is None:
            free = [n for n, st in zip(spec.parameter_names, start.td_status) if st == "estimated"]
        td_start, prior = start.td, list(start.terms)
    free_given = free
    platform_options = None if start is None else start.platform_options
    base_cal = calibrate(poses, spec, terms=prior, free=free, td_start=td_start, robust=opt.robust,
                         platform_options=platform_options)

    def refit(terms: list[ModelTerm]) -> tuple[Calibration, bool]:
        """The estimator's full fit (robust weights, covariance) of ``terms`` with the current free
        set, and whether it is the model as given (no term added, the free set unchanged: then
        the geometric fit itself). The geometry freed again counts as a change of the model, with
        or without a term beside it (its note in the rounds says calibration.yaml estimates it)."""
        if len(terms) == len(prior) and free == free_given:
            return base_cal, True
        return calibrate(poses, spec, terms=terms, free=free, td_start=td_start, robust=opt.robust,
                         platform_options=platform_options), False
    z0, active0 = base_cal.extras["z"], base_cal.extras["active"]
    weights = np.all(np.isfinite(poses.markers), axis=2).astype(float)
    cur = _fit(spec, poses, prior, z0, active0, weights, opt.lm_iterations, opt.robust)
    cur.cv = _cv(cur, spec, poses, opt.folds, opt.lm_iterations)
    say(f"geometric model: fit RMS {_fmt_rms(np.sqrt(cur.rss * 3 / cur.n_obs), unit)}, "
        f"held-out RMS {_fmt_rms(cur.cv_rms, unit)}")
    locations_before = locate(cur.r, poses, spec, weights, opt.alpha)
    findings: list[Finding] = []
    accepted_info: list[dict] = []
    rounds: list[dict] = []
    not_separable: dict[tuple, dict] = {}
    stop_unexplained: Finding | None = None
    first_cv = cur.cv_rms
    floor = noise_floor(poses, int(cur.active.sum()))
    n_seen = int(np.all(np.isfinite(poses.markers), axis=2).sum())
    factor = max(opt.noise_floor_factor, 1.0 + 1.5 * np.sqrt(2.0 / (3.0 * max(n_seen, 1))))
    at_floor = floor is not None and cur.cv_rms <= factor * floor
    if floor is not None:
        say(f"noise floor of held-out prediction: {_fmt_rms(floor, unit)}"
            + (" (the geometric model is at it: nothing left to find)" if at_floor else ""))
    lag_effect = unsettled_effect(library)
    settled = None if lag_effect is None else _settling_finding(spec, poses, cur, weights, opt, say, lag_effect.name)
    if settled is not None:
        findings.append(settled)
    # held-out proof on poses where the stand settled: an extrapolated pose carries what its
    # approach model missed, along the last move (a backlash's signature); with too few settled
    # poses to judge on, the stand's physics is not named (a recording that never settles)
    judged = ~extrapolated(poses)
    too_few_settled = judged.sum() < 4 * opt.folds and not judged.all()
    if too_few_settled:
        say(f"only {int(judged.sum())} holds settled: too few to prove an effect of the stand on")
    if judged.sum() < 4 * opt.folds:
        judged = np.ones(poses.n_poses, bool)
    stop = at_floor or too_few_settled
    reopened_once = False  # the held geometry is tried once, before the first term mostly inside it
    echoes: set[tuple] = set()  # weak terms on a slow actuator: the approach's remnant, not named
    while len(findings) < opt.max_effects and not stop:
        cands: list[tuple[Effect, ModelTerm]] = []
        taken = {_place(t) for t in cur.terms}
        body_r = body_residuals(cur, poses)
        for eff in library.values():
            if eff.unsettled_holds and settled is not None:
                continue  # the lag is already read from the stream and corrected in the data
            for term in eff.candidates(spec, poses, body_r):
                if _place(term) in taken or _place(term) in echoes:  # one term of a kind per actuator / marker
                    continue
                if _slow_actuator_echo(eff, term, settled, poses):
                    not_separable[(eff.name, _where_text(term.where))] = {
                        "effect": eff.name, "where": term.where, "separability": 0.0,
                        "from": f"{FROM_SLOW_APPROACH} (an unfinished approach along the last "
                                "move looks like play in that actuator)"}
                    continue
                cands.append((eff, term))
        scr = screen(cur, spec, poses, [t for _, t in cands])
        p_adj = holm(np.array([s[1] for s in scr])) if scr else np.zeros(0)
        table = []
        for (eff, term), (F, p, sep, _), pa in zip(cands, scr, p_adj):
            table.append({"effect": eff.name, "where": _where_text(term.where), "F": F, "p_adjusted": float(pa),
                          "separability": sep})
            if sep < opt.min_separability:
                key = (eff.name, _where_text(term.where))
                not_separable[key] = {"effect": eff.name, "where": term.where, "separability": sep,
                                      "from": "motion capture"}
        order = [i for i in np.argsort([s[1] for s in scr])
                 if p_adj[i] < opt.alpha and scr[i][2] >= opt.min_separability]
        # the best candidate of each kind and place (one split per marker, one period per
        # actuator), so that neighbours of one located step do not crowd out the others
        chosen, seen = [], set()
        for i in order:
            if _place(cands[i][1]) not in seen and len(chosen) < opt.max_refits:
                chosen.append(i)
                seen.add(_place(cands[i][1]))
        rounds.append({"round": len(rounds) + 1, "screened": len(cands), "passed_screening": len(order),
                       "refit": [f"{cands[i][0].name} ({_where_text(cands[i][1].where)})" for i in chosen],
                       "top": sorted(table, key=lambda x: x["p_adjusted"])[:8]})
        if not chosen:
            break
        trials = []
        for i0 in chosen:
            i, f = _best_variant(i0, cands, scr, cur, spec, poses, weights, opt)
            eff, term = cands[i]
            f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
            trials.append((i, f, paired_improvement(cur.cv[judged], f.cv[judged])))
            say(f"  {eff.name} ({_where_text(term.where)}): held-out RMS {_fmt_rms(f.cv_rms, unit)} "
                f"(paired p = {trials[-1][2]:.2g}), BIC {f.bic - cur.bic:+.1f}")
        good = confirm(trials, [sc[2] for sc in scr], cur, judged, opt)
        if good is None:
            rounds[-1]["not_accepted"] = _not_accepted(trials, cands, [sc[2] for sc in scr], cur, judged, opt)
            say(rounds[-1]["not_accepted"])
            break
        i, best, ph = good
        eff, term = cands[i]
        weak = weak_beside_the_recording(eff, settled, poses, ph, opt.weak_alpha)
        if weak is not None:  # a weak proof the recording (an extrapolated approach, settled holds) contradicts
            echoes.add(_place(term))
            not_separable[(eff.name, _where_text(term.where))] = {
                "effect": eff.name, "where": term.where, "separability": float(scr[i][2]), "from": weak[0]}
            say(f"{eff.name} ({_where_text(term.where)}): {weak[1]}; not named")
            continue
        if opt.reopen_geometry and scr[i][2] < opt.warn_separability and not reopened_once:
            # a term mostly inside the geometry's span competes with the geometry the calibration
            # held (its selection scored the groups with every effect still in the residual): the
            # held groups are tried first, and the round is screened again if they predict better
            reopened_once = True
            reopened = _reopened(spec, poses, cur, free, judged, opt, platform_options)
            if reopened is not None:
                cur, free, note = reopened
                rounds[-1]["geometry_reopened"] = note
                say(note["text"])
                continue
        # naming check: a generic model of the same structure must not predict clearly better
        if opt.probes:
            probe_better = _probe_beats(spec, poses, cur, best, opt, ph)
            if probe_better is not None:
                stop_unexplained = probe_better
                break
        F, p_s, sep, Jc = scr[i]
        k = len(best.terms) - 1
        theta = best.theta(k)
        warn = []
        if sep < opt.warn_separability:
            warn.append(f"only {100 * sep:.0f}% of its signature lies outside the geometry's Jacobian: "
                        "part of it is absorbed by the geometric parameters on this design")
        reg = eff.regressor(term, spec, poses)
        finding = Finding(
            effect=eff.name, where=dict(term.where), parameters={}, heldout_rms_before=cur.cv_rms,
            heldout_rms_after=best.cv_rms, evidence="", p_heldout=float(ph), p_screen=float(p_adj[i]),
            bic_change=float(best.bic - cur.bic), separability=float(sep), warnings=warn, term=term,
            regressor=reg, regressor_label=eff.regressor_label(term),
            signature_before=_signature(Jc, cur.r, theta, _offset_sign(term, theta, best, poses)))
        finding.alternatives = _equally_good(i, best, trials, cands, [sc[2] for sc in scr], cur, judged, opt)
        findings.append(finding)
        accepted_info.append({"fit": best, "J": Jc})
        say(f"accepted {eff.name} ({_where_text(term.where)})")
        cur = best
        if opt.reopen_geometry and not eff.recording:  # the geometry chosen again beside the physics
            again = _reselected(spec, poses, cur, free, judged, opt, platform_options)
            if again is not None:
                again[2]["after"] = f"{eff.name} ({_where_text(term.where)})"
                cur, free, rounds[-1]["geometry_reselected"] = again
                say(again[2]["text"])
    if not stop and stop_unexplained is None and floor is not None and len(cur.terms) > len(prior):
        weak = _weak_beside_lack_of_fit(cur, poses, spec, findings, floor, judged, weights, len(prior), opt)
        if weak:
            findings, accepted_info = _take_back(
                cur, dict.fromkeys(weak), ROUND_WEAK_NAMES, {}, lambda p: (
                    f"proven only weakly, and the model still predicts held-out poses at more than "
                    f"{opt.lack_of_fit_factor:g} times the noise floor with structure located"),
                findings, accepted_info, rounds, say)
            cur = _without(spec, poses, cur, weak, opt)
    # structure a generic probe still predicts better at the end: a named term that no longer
    # proves itself beside the probe was a slice of that structure (tested before the final fit)
    end_probe = _best_probe(spec, poses, cur, None, opt) if not stop and stop_unexplained is None and opt.probes \
        else None
    if end_probe is not None and len(cur.terms) > len(prior):
        loose = _unproven_beside_probe(spec, poses, end_probe[1], len(prior), len(cur.terms), judged, opt)
        reduced = _without(spec, poses, cur, set(loose), opt) if loose else None
        again = _best_probe(spec, poses, reduced, None, opt) if reduced is not None else None
        if again is not None:
            findings, accepted_info = _take_back(
                cur, loose, ROUND_BESIDE_PROBE, {}, lambda p: (
                    f"no longer predicts held-out poses better beside the generic model that still beats the named "
                    f"ones (paired p = {p:.2g})"),
                findings, accepted_info, rounds, say)
            cur, end_probe = reduced, again
    if end_probe is None and not stop and stop_unexplained is None and opt.probes and floor is not None \
            and len(cur.terms) > len(prior):
        # no probe beats the named model, but the location tests still find structure in time
        # beside a lack of fit: each name is tested beside a model of it
        loose, about = _unproven_beside_time(spec, poses, cur, len(prior), floor, judged, weights, opt)
        if loose:
            findings, accepted_info = _take_back(
                cur, loose, ROUND_BESIDE_TIME, about, lambda p: (
                    f"no longer predicts held-out poses better (paired p = {p:.2g}) beside a model of the structure "
                    f"in time the location tests still find ({about['located']})"),
                findings, accepted_info, rounds, say)
            cur = _without(spec, poses, cur, set(loose), opt)
            end_probe = _best_probe(spec, poses, cur, None, opt)
    # the final model through the estimator's full procedure (robust weights, covariance)
    # a slip whose model change does not predict the poses from the slip on better: named and
    # corrected in the data (the fitted model keeps it), but not written into calibration.yaml
    slip_notes: dict[int, str] = {}
    if not stop and stop_unexplained is None:
        for k in range(len(prior), len(cur.terms)):
            eff = library.get(cur.terms[k].effect)
            onset = eff.onset(cur.terms[k]) if eff is not None and eff.recording else None
            if eff is not None and onset is not None:
                note = _slip_not_kept(spec, poses, cur, k, eff, onset, judged, opt)
                if note is not None:
                    slip_notes[id(cur.terms[k])] = note
                    say(f"{eff.name} ({_where_text(cur.terms[k].where)}): {note}")
    final_cal, unchanged = refit(cur.terms)
    modelled = [f for f in findings if f.term is not None]
    for k, (finding, info) in enumerate(zip(modelled, accepted_info), start=len(prior)):
        theta, std = final_cal.theta[k], final_cal.theta_std[k]
        finding.parameters = _params(finding.term, theta, std)
        finding.signature_after = _signature(info["J"], final_cal.extras["residuals_after"], theta,
                                             _offset_sign(finding.term, theta, info["fit"], poses))
        finding.evidence = _evidence(finding, poses, unit, folds=opt.folds)
    locations = locate(final_cal.extras["residuals_after"], poses, spec, None, opt.alpha)
    if end_probe is not None:
        stop_unexplained = end_probe[0]
    if stop_unexplained is not None:
        findings.append(stop_unexplained)
    # held-out prediction where the stand settled (an extrapolated pose carries what its approach
    # model missed: the noise floor does not hold for it)
    held = _rms(cur.cv, judged) if cur.cv is not None else float("nan")
    if not stop:
        left = located(locations, opt.alpha * 0.1) if stop_unexplained is None else []
        if left and modelled and floor is not None and held <= opt.lack_of_fit_factor * floor:
            # beside a modelled effect, structure the location tests still see but held-out
            # prediction does not (within the factor clean sessions reach of the noise floor) is
            # what the effect's model leaves of its physics, not another effect: said, not named
            say(f"structure remains ({left[0].test}, adjusted p = {left[0].p_adjusted:.2g}) but the model predicts "
                f"held-out poses at {_fmt_rms(held, unit)}, within {opt.lack_of_fit_factor:g} times the noise "
                "floor: not reported as unexplained")
            left = []
        if left:
            top = left[0]
            findings.append(Finding(
                effect="unexplained", where=dict(top.where), parameters={}, heldout_rms_before=cur.cv_rms,
                heldout_rms_after=cur.cv_rms,
                evidence=(f"{top.test} of the residual ({', '.join(f'{k} {v}' for k, v in top.where.items())}) "
                          f"survives correction for {len(locations)} tests (adjusted p = {top.p_adjusted:.2g}); "
                          "no effect in the library predicts held-out poses better"),
                p_screen=float(top.p_adjusted)))
    if not stop and not modelled and floor is not None and not any(f.effect == "unexplained" for f in findings):
        lack, near = lack_of_fit(cur, poses, floor, held, opt, say)
        if near is not None:
            rounds.append(near)
        if lack is not None:
            findings.append(lack)
    findings.sort(key=lambda f: -(f.heldout_rms_before - f.heldout_rms_after) if f.effect != "unexplained" else 0)
    # calibration.yaml without the slips whose model change predicts no better
    written, as_given = refit([t for t in cur.terms if id(t) not in slip_notes]) if slip_notes else (final_cal, unchanged)
    stand = stand_calibration(written, library)
    if start is not None and as_given:
        # nothing modelled and the geometry's free set as given: the calibration given is what
        # diagnosis writes, unchanged (a refit from it can wander within the estimate's own
        # uncertainty where the geometry is poorly determined: a slow psvr actuator's session,
        # proof seed 931112, moved u0_B by one standard error and the settled poses' held-out
        # prediction 0.121 -> 0.125 mm, with no finding that changes the model)
        stand = start
    for f in findings:  # a recording artefact's term is corrected in the data
        eff = library.get(f.effect)
        if f.term is not None and eff is not None and eff.recording:
            f.corrected = slip_notes.get(id(f.term)) or eff.correction(f.where)
    heldout_info = None
    if heldout is not None:
        heldout_info = _score_heldout(base_cal, stand, heldout, spec, findings)
    diag = Diagnosis(findings=findings, verdict="", calibration=stand, base=base_cal, locations=locations,
                     locations_before=locations_before, rounds=rounds, not_separable=list(not_separable.values()),
                     unit=unit, poses=poses, heldout_session=heldout_info, fitted=final_cal, noise_floor=floor,
                     heldout_geometric=first_cv, at_noise_floor=at_floor, too_few_settled=bool(too_few_settled),
                     options=opt, advice={n: e.not_separable_advice for n, e in library.items() if e.not_separable_advice},
                     untried={n: r for n, e in library.items() if (r := e.untried(spec, poses))})
    diag.verdict = verdict(diag)
    return diag

def _take_back(cur: Fit, taken: dict[int, float | None], round_name: str, about: dict[str, Any],
               why: Callable[[float | None], str], findings: list[Finding], accepted_info: list[dict],
               rounds: list[dict], say: Callable[[str], None]) -> tuple[list[Finding], list[dict]]:
    """Takes back the names of the terms ``cur.terms[k]`` for k in ``taken`` (k -> the paired p of
    the test that took it back, or None): a round ``round_name`` in ``rounds`` (their names, the
    paired p-values if any, then ``about``), one progress line each (``why(p)``), and the findings
    and fit records without them (the caller refits the model without the terms)."""
    ks = sorted(taken)
    names = [f"{cur.terms[k].effect} ({_where_text(cur.terms[k].where)})" for k in ks]
    entry: dict[str, Any] = {"round": round_name, "not_named": names}
    if any(taken[k] is not None for k in ks):
        entry["paired_p"] = {n: taken[k] for n, k in zip(names, ks)}
    rounds.append({**entry, **about})
    for n, k in zip(names, ks):
        say(f"{n}: {why(taken[k])}: a slice of physics the library does not hold; not named")
    return _unnamed(findings, accepted_info, {id(cur.terms[k]) for k in ks})


def _reopened(spec: PlatformSpec, poses: PoseSet, cur: Fit, free: Sequence[str] | None, judged: np.ndarray,
              opt: Options, platform_options: dict | None) -> tuple[Fit, list[str], dict] | None:
    """The model with the parameter groups held by the calibration freed again, as (fit, free
    names, note), when it predicts the held-out ``judged`` poses better than ``cur`` (lower BIC, a
    held-out gain of ``min_relative_gain``, paired p < ``alpha_heldout``); else None.

    A calibration's model selection scores the groups with every effect still in the residual:
    a large one (a gear's cyclic error) hides what a held group (the rod lengths) would explain,
    and an effect mostly inside the geometry (a scale nonlinearity) would be named in its place.
    Tried once, when such a term (separability under ``warn_separability``) is about to be
    accepted: where none is, the search costs nothing more."""
    if free is None:
        return None
    groups = parameter_groups(spec)
    held = [g for g, names in groups.items() if not set(names) & set(free)]
    if not held:
        return None
    trial = list(free) + [n for g in held for n in groups[g]]
    td_now = cur.problem.split(cur.z)[0]
    cal = calibrate(poses, spec, terms=cur.terms, free=trial, td_start=td_now, robust=opt.robust,
                    platform_options=platform_options)
    f = _fit(spec, poses, cur.terms, cal.extras["z"], cal.extras["active"], cur.weights, opt.lm_iterations, opt.robust)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    p = paired_improvement(cur.cv[judged], f.cv[judged])
    before, after = _rms(cur.cv, judged), _rms(f.cv, judged)
    if not (f.bic < cur.bic and after < (1 - opt.min_relative_gain) * before and p < opt.alpha_heldout):
        return None
    unit = poses.length_unit
    text = (f"geometry: {', '.join(held)} freed again (held by the calibration, chosen with the effect still in the "
            f"residual): held-out RMS {_fmt_rms(before, unit)} -> {_fmt_rms(after, unit)} (paired p = {p:.2g}); "
            "--keep-geometry keeps the calibration's free set")
    return f, trial, {"groups": held, "heldout_rms_before": before, "heldout_rms_after": after, "p_heldout": float(p),
                      "text": text}

def _reselected(spec: PlatformSpec, poses: PoseSet, cur: Fit, free: Sequence[str] | None, judged: np.ndarray,
                opt: Options, platform_options: dict | None) -> tuple[Fit, list[str], dict] | None:
    """After an effect of the stand is accepted, the geometry's model selection made again beside
    the accepted terms (platkit.calibrate.selection.reselect_geometry), as (fit, free names, note),
    when it chooses another free set that predicts the held-out ``judged`` poses no worse than
    ``cur``; else None. A group chosen with the physics still in the residual may stand in for it
    (a torso joint's scale for its gravity sag): beside the physics it no longer earns its place."""
    if free is None:
        return None
    cal = reselect_geometry(poses, spec, cur.terms, robust=opt.robust, platform_options=platform_options)
    chosen = [n for n, st in zip(spec.parameter_names, cal.td_status) if st == "estimated"]
    if set(chosen) == set(free):
        return None
    f = _fit(spec, poses, cur.terms, cal.extras["z"], cal.extras["active"], cur.weights, opt.lm_iterations, opt.robust)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    before, after = _rms(cur.cv, judged), _rms(f.cv, judged)
    if not after <= before:
        return None
    sel = cal.identifiability.get("model_selection") or {}
    unit = poses.length_unit
    text = (f"geometry chosen again beside {', '.join(t.effect for t in cur.terms)}: free "
            f"{', '.join(sel.get('chosen', [])) or 'none'} (held {', '.join(sel.get('held', [])) or 'none'}), held-out "
            f"RMS {_fmt_rms(before, unit)} -> {_fmt_rms(after, unit)}; --keep-geometry keeps the calibration's free set")
    return f, chosen, {"chosen": list(sel.get("chosen", [])), "held": list(sel.get("held", [])),
                       "heldout_rms_before": before, "heldout_rms_after": after, "text": text}

def _best_variant(i0: int, cands: list, scr: list, cur: Fit, spec: PlatformSpec, poses: PoseSet,
                  weights: np.ndarray, opt: Options) -> tuple[int, Fit]:
    """The variant of candidate ``i0``'s kind and place (a cooling time constant, a period, a
    slip's row) that fits best, as (index, fit). The score test ranks them at zero effect; a large
    effect may fit another better. ``opt.max_variants`` spread over them (in the library's order,
    ``i0`` among them) are fitted, then the neighbours of the lowest BIC until it is a minimum."""
    same = [j for j in range(len(cands)) if _place(cands[j][1]) == _place(cands[i0][1])
            and scr[j][2] >= opt.min_separability]
    if i0 not in same:
        same.append(i0)
    pick = {int(same[int(round(x))]) for x in np.linspace(0, len(same) - 1, max(1, min(opt.max_variants, len(same))))}
    pick.add(i0)
    fits: dict[int, Fit] = {}
    while True:
        for j in pick - set(fits):
            fits[j] = _fit(spec, poses, cur.terms + [cands[j][1]], cur.z, cur.active, weights, opt.lm_iterations,
                           opt.robust)
        best = min(fits, key=lambda j: fits[j].bic)
        b = same.index(best)
        pick = {same[k] for k in (b - 1, b + 1) if 0 <= k < len(same)} - set(fits)
        if not pick:
            return best, fits[best]

def confirm(trials: list[tuple[int, Fit, float]], separability: Sequence[float], cur: Fit, judged: np.ndarray,
            opt: Options) -> tuple[int, Fit, float] | None:
    """The candidate a round accepts, as (index, fit, held-out p), or None. ``trials``: (candidate
    index, its fit with cv, paired held-out p against ``cur``); ``separability`` per candidate.

    Fixed-sequence confirmation: in the order the information criterion prefers, the first must
    lower BIC, cut the held-out RMS of the ``judged`` poses by ``min_relative_gain`` and prove
    itself held out at ``alpha_heldout``. When it fails, the others follow in that order, each at
    the level shared among the candidates refit (Bonferroni): of two large effects, the one that
    fits best alone may be the one that cannot predict without the other (a backlash beside a
    thermal drift on the psvr: BIC -464 but held-out p = 0.17, the drift p = 0.00017).

    Two kinds of candidate prove themselves at the stricter level ``alpha_heldout`` times
    ``weak_separability_factor``: a term mostly inside the geometry's column space (it moves the
    geometry as it is fitted, and its gain rests on the small part left; real ones pass at
    p < 1e-4 in the proof benchmark, chance ones at 0.02), and a term whose held-out gain is
    under ``small_gain``. The latter is what a slice of structure the term does not describe
    gives: any term takes a little of an unmodelled lack of fit, and the candidate tested is
    the winner of the screening and of the refits. On the physical simulator a stewart plate flex
    (out of the library) was named a scale nonlinearity at a 4% gain, p = 0.019, and held-out
    prediction of the settled poses went 0.068 -> 0.072 mm (seed 1010211); right names with gains
    that small passed at p = 0.0024-0.0048."""
    for k, (i, f, p_h) in enumerate(sorted(trials, key=lambda x: x[1].bic)):
        if _failed(f, p_h, separability[i], cur, judged, opt, share=len(trials) if k > 0 else 1) is None:
            return i, f, p_h
    return None


def _equally_good(i: int, best: Fit, trials: list[tuple[int, Fit, float]], cands: list,
                  separability: Sequence[float], cur: Fit, judged: np.ndarray, opt: Options) -> list[dict[str, Any]]:
    """The other effects of the round at the accepted candidate ``i``'s actuator or marker that
    :func:`confirm` would accept on their own and that predict the held-out ``judged`` poses as
    well: the accepted one is not significantly better (paired Wilcoxon at ``alpha_heldout``).
    On this plan the name is one of them (psvr proof seed 1151103: a weak scale nonlinearity of
    actuator C, mostly absorbed by the geometry, and a cyclic error of C with a period of 1024
    counts, 1.6 periods over C's travel, predict held-out poses at 0.0472 and 0.0471 mm; the
    cyclic error was named)."""
    place = _place(cands[i][1])[1:]
    out = []
    for j, f, p_h in trials:
        eff, term = cands[j]
        if j == i or eff.name == cands[i][0].name or _place(term)[1:] != place or not any(place):
            continue
        if _failed(f, p_h, separability[j], cur, judged, opt) is not None:
            continue
        p = paired_improvement(f.cv[judged], best.cv[judged])
        if p >= opt.alpha_heldout:
            out.append({"effect": eff.name, "where": dict(term.where), "heldout_rms": f.cv_rms,
                        "p_named_better": float(p)})
    return out


def _failed(f: Fit, p_h: float, separability: float, cur: Fit, judged: np.ndarray, opt: Options,
            share: int = 1) -> str | None:
    """Why :func:`confirm` does not accept candidate ``f`` (held-out paired p ``p_h``, tested at
    its level divided by ``share``), in words; None when it does."""
    if f.bic >= cur.bic:
        return f"BIC {f.bic - cur.bic:+.1f}"
    before, after = _rms(cur.cv, judged), _rms(f.cv, judged)
    if after >= (1 - opt.min_relative_gain) * before:
        return f"held-out gain {100 * (1 - after / before):.1f}% (under {100 * opt.min_relative_gain:g}%)"
    level, why = _level(f, separability, cur, judged, opt)
    if p_h < level / share:
        return None
    return f"held-out paired p = {p_h:.2g}, not under {level / share:.2g}" + (f" (the stricter level: {why})" if why else "")


def _level(f: Fit, separability: float, cur: Fit, judged: np.ndarray, opt: Options) -> tuple[float, str]:
    """The held-out level a candidate ``f`` proves itself at (before the Bonferroni share of a
    later candidate) and why it is the stricter one ('' for ``alpha_heldout``); see :func:`confirm`."""
    before, after = _rms(cur.cv, judged), _rms(f.cv, judged)
    if separability < opt.warn_separability:
        why = f"only {100 * separability:.0f}% of its signature lies outside the geometry's Jacobian"
    elif after >= (1 - opt.small_gain) * before:
        why = f"its held-out gain, {100 * (1 - after / before):.1f}%, is under {100 * opt.small_gain:g}%"
    else:
        return opt.alpha_heldout, ""
    return opt.weak_alpha, why


def _not_accepted(trials: list[tuple[int, Fit, float]], cands: list, separability: Sequence[float], cur: Fit,
                  judged: np.ndarray, opt: Options) -> str:
    """Why the candidate the information criterion prefers was not accepted, in a sentence."""
    i, f, p_h = min(trials, key=lambda x: x[1].bic)
    return f"{cands[i][0].name} ({_where_text(cands[i][1].where)}): not accepted, " + \
        str(_failed(f, p_h, separability[i], cur, judged, opt))

def _evidence(f: Finding, poses: PoseSet, unit: str, folds: int) -> str:
    first = next(iter(f.parameters.items()), None)
    par = ""
    if first is not None:
        name, v = first
        scale = length_scale(unit) if v["unit"] == "m" else 1.0
        shown_unit = unit if v["unit"] == "m" else v["unit"]
        std = "" if v["std"] is None else f" +- {v['std'] / scale:.2g}"
        par = f"; fitted {name} = {v['value'] / scale:.3g}{std} {shown_unit}"
    return (f"adding {f.effect} ({_where_text(f.where)}) cut the {folds}-fold held-out RMS from "
            f"{_fmt_rms(f.heldout_rms_before, unit)} to {_fmt_rms(f.heldout_rms_after, unit)} over "
            f"{poses.n_poses} poses (paired Wilcoxon p = {f.p_heldout:.2g}, BIC {f.bic_change:+.0f}; "
            f"score test against the residual: Holm p = {f.p_screen:.2g}){par}")

def _score_heldout(base: Calibration, final: Calibration, heldout: PoseSet, spec: PlatformSpec,
                   findings: list[Finding]) -> dict[str, float]:
    ho = with_history(heldout, spec)
    e0 = point_errors(base, ho)
    e1 = point_errors(final, ho)
    before = float(np.sqrt(np.nanmean(e0**2)))
    after = float(np.sqrt(np.nanmean(e1**2)))
    for f in findings:
        f.heldout_session_rms_before, f.heldout_session_rms_after = before, after
    per_marker = {n: (float(np.sqrt(np.nanmean(e0[:, m] ** 2))), float(np.sqrt(np.nanmean(e1[:, m] ** 2))))
                  for m, n in enumerate(base.marker_names)}
    return {"rms_before": before, "rms_after": after, "per_marker": per_marker,
            "p_improvement": paired_improvement(np.nanmean(e0**2, axis=1), np.nanmean(e1**2, axis=1)),
            "n_poses": heldout.n_poses}
