"""Forward selection of effects: screen, refit with the shared estimator, accept on held-out proof.

One round (repeated until nothing passes or the cap on the effects named is reached,
:func:`effect_cap`: ``max_effects`` where given, else three on a stand or a chain and three for
each tracked link of a tree; a search the cap ended says so in its rounds and verdict):

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
   (naming._unproven_beside_time). Before those, with two or more named, each is tested again by
   removal: the model without it must predict the held-out settled poses worse, or the later names
   describe what it took, and it is not named (taking_back.take_back_unneeded).

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
an effect of any shape the geometry absorbs on this plan leaves nothing to find. Likewise nothing
more is named once the model named so far predicts them at the floor (:meth:`Search.select`). With nothing
found, a geometric model more than ``lack_of_fit_factor`` times the floor is a lack of fit
(``unexplained``); below that, where held-out prediction cannot tell a weak effect from noise,
residuals alike at poses next in time or with near commands are (locate.neighbour_tests); both
rules are in lack_of_fit.py.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from platkit._threads import blas_threads
from platkit.calibrate.estimate import calibrate
from platkit.diagnose.fitting import FROM_NO_MARKER, FROM_SLOW_APPROACH, Diagnosis, Finding, Fit, Options, _cv, _fit
from platkit.diagnose.fitting import _fmt_rms, _rms
from platkit.diagnose.fitting import _where_text, body_residuals, extrapolated
from platkit.diagnose.floor import noise_floor
from platkit.diagnose.lack_of_fit import lack_of_fit
from platkit.diagnose.locate import locate, located
from platkit.diagnose.forms import FORM_BIC_MARGIN, tell_apart
from platkit.diagnose.naming import _probe_beats
from platkit.diagnose.response_kind import again_after, response_again
from platkit.diagnose.stream import nodes_share_noise
from platkit.diagnose.recording import (
    _settling_finding,
    _slip_not_kept,
    _slow_actuator_echo,
    stand_calibration,
    unsettled_effect,
    weak_beside_the_recording,
)
from platkit.diagnose.rounds import best_variant, confirm, equally_good, not_accepted, place, screen, variants_again
from platkit.diagnose.stats import holm, paired_improvement
from platkit.diagnose.evidence import _evidence, _offset_sign, _params, _score_heldout, _signature
from platkit.diagnose.geometry import _reopened, _reselected
from platkit.diagnose.taking_back import (
    take_back_beside_probe,
    take_back_beside_time,
    take_back_unneeded,
    take_back_weak,
)
from platkit.diagnose.verdict import verdict
from platkit.effects import Effect, with_history
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec
from platkit.plugins import effect_library
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["diagnose", "Search", "SETTLED_PER_FOLD", "settled_needed", "effect_cap", "CHAIN_EFFECTS"]

#: the cap on the effects named on a stand or a chain (one moving part), where none is given
CHAIN_EFFECTS = 3


def effect_cap(spec: PlatformSpec, given: int | None = None) -> int:
    """The most effects the search names: ``given`` (``--max-effects``) where set; else
    CHAIN_EFFECTS for each tracked link of a tree, CHAIN_EFFECTS on a stand or a chain (one moving
    part). Each branch the markers follow can hold effects of its own (a bend where it hangs on
    the trunk) beside those the branches share (the every-joint compliance, the trunk's bend): the
    cap is a bound on a search the held-out tests end, not a guess at the truth's size."""
    if given is not None:
        return int(given)
    return CHAIN_EFFECTS * max(len(spec.tracked_links), 1)

#: the stand's physics is proven on settled poses, at least this many per fold of the held-out
#: test; with fewer (the rest extrapolated to rest), nothing of the stand is named
SETTLED_PER_FOLD = 4


def settled_needed(folds: int | None = None) -> int:
    """The settled poses the search needs to judge the stand's physics on, with ``folds`` folds
    (default: the CLI's, Options().folds)."""
    return SETTLED_PER_FOLD * (Options().folds if folds is None else folds)


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

    The stages, each a method of :class:`Search`: the geometric model and its noise floor
    (``Search(...)``), the finding the stream shows (:meth:`Search.settling`), the rounds of
    forward selection (:meth:`Search.select`, each accepted term's forms told apart in forms.py), each
    name tested again by removal beside the others and the other take-back steps (taking_back.py:
    take_back_unneeded, take_back_weak, take_back_beside_probe, take_back_beside_time), the final model
    (:meth:`Search.final_model`), what structure is left (:meth:`Search.structure_left`) and what
    is written (:meth:`Search.written`, :meth:`Search.diagnosis`).
    """
    with blas_threads(1):  # a library call computes on one BLAS thread, as every verb does (platkit._threads)
        search = Search(spec, poses, options, library, progress, start)
        search.settling()
        search.select()
        take_back_unneeded(search)
        take_back_weak(search)
        take_back_beside_probe(search)
        take_back_beside_time(search)
        search.final_model()
        search.structure_left()
        return search.diagnosis(search.written(), heldout)


class Search:
    """The state of one diagnosis search: the model so far (``cur``), the findings and the
    records of each (``accepted``: its fit and Jacobian columns), the rounds diagnosis.json
    lists, the terms set aside (``not_separable``), and what ends the search (``stop``: at the
    noise floor or too few settled poses; ``stop_unexplained``: a probe beat the named model)."""

    def __init__(self, spec: PlatformSpec, poses: PoseSet, options: Options | None = None,
                 library: dict[str, Effect] | None = None, progress: Callable[[str], None] | None = None,
                 start: Calibration | None = None):
        """The geometric model of the session (the calibration ``start`` as given: its stand, its
        estimated parameters free, its td the start, its terms kept), its K-fold held-out errors and
        the noise floor they are judged against."""
        self.opt = opt = options or Options()
        self.cap = effect_cap(start.spec if start is not None else spec, opt.max_effects)
        self.library = effect_library() if library is None else library
        self.say = progress or (lambda s: None)
        self.poses = poses = with_history(poses, spec)
        self.unit = poses.length_unit
        self.start = start
        self.free, self.td_start, self.prior = opt.free, None, []
        if start is not None:
            spec = start.spec
            if self.free is None:
                self.free = [n for n, st in zip(spec.parameter_names, start.td_status) if st == "estimated"]
            self.td_start, self.prior = start.td, list(start.terms)
        self.spec = spec
        self.free_given = self.free
        self.platform_options = None if start is None else start.platform_options
        self.base_cal = calibrate(poses, spec, terms=self.prior, free=self.free, td_start=self.td_start,
                                  robust=opt.robust, platform_options=self.platform_options)
        self.weights = np.all(np.isfinite(poses.markers), axis=2).astype(float)
        cur = _fit(spec, poses, self.prior, self.base_cal.fit.z, self.base_cal.fit.active, self.weights,
                   opt.lm_iterations, opt.robust)
        cur.cv = _cv(cur, spec, poses, opt.folds, opt.lm_iterations)
        # a stream's response in the first order leaves a second-order drive's motion in the residuals,
        # which a term along an actuator's travel takes a slice of: the response is chosen again first
        again = response_again(spec, poses, self.prior, cur, self.free, self.td_start, self.platform_options,
                               self.weights, opt)
        self.response_note = None if again is None else again[3]
        self.response_cal: Calibration | None = None  # the estimator's fit with the response chosen again
        self.response_after: list[dict] = []  # the response's kind chosen again beside an effect (kept)
        if again is not None and again[1] is not None:  # the model judged, named beside and written
            self.prior, self.response_cal, cur = list(again[0]), again[1], again[2]
        if self.response_note is not None:
            self.say(self.response_note["text"])
        self.cur = cur
        self.say(f"geometric model: fit RMS {_fmt_rms(np.sqrt(cur.rss * 3 / cur.n_obs), self.unit)}, "
                 f"held-out RMS {_fmt_rms(cur.cv_rms, self.unit)}")
        self.locations_before = locate(cur.r, poses, spec, self.weights, opt.alpha)
        self.findings: list[Finding] = []
        self.accepted: list[dict] = []
        self.rounds: list[dict] = []
        self.not_separable: dict[tuple, dict] = {}
        self.stop_unexplained: Finding | None = None
        self.end_probe: tuple | None = None
        self.first_cv = cur.cv_rms
        self.floor = noise_floor(poses, int(cur.active.sum()))
        n_seen = int(np.all(np.isfinite(poses.markers), axis=2).sum())
        factor = max(opt.noise_floor_factor, 1.0 + 1.5 * np.sqrt(2.0 / (3.0 * max(n_seen, 1))))
        self.floor_factor = factor
        self.at_floor = self.floor is not None and cur.cv_rms <= factor * self.floor
        if self.floor is not None:
            self.say(f"noise floor of held-out prediction: {_fmt_rms(self.floor, self.unit)}"
                     + (" (the geometric model is at it: nothing left to find)" if self.at_floor else ""))
        self.settled: Finding | None = None
        self.judged = np.ones(poses.n_poses, bool)
        self.too_few_settled = False
        self.stop = self.at_floor
        self.reopened_once = False  # the held geometry is tried once, before the first term mostly inside it
        self.echoes: set[tuple] = set()  # weak terms on a slow actuator: the approach's remnant, not named
        self.unwritten: dict[int, str] = {}  # id(term) -> why its model change is not written

    @property
    def naming(self) -> bool:
        """Whether names still stand: the search neither stopped nor ended at a probe."""
        return not self.stop and self.stop_unexplained is None

    def refit(self, terms: list[ModelTerm]) -> tuple[Calibration, bool]:
        """The estimator's full fit (robust weights, covariance) of ``terms`` with the current free
        set, and whether it is the model as given (no term added, the free set unchanged: then
        the geometric fit itself). The geometry freed again counts as a change of the model, with
        or without a term beside it (its note in the rounds says calibration.yaml estimates it), and
        so does a stream's response chosen again (response_kind.response_again): the model the names
        were judged in is the model written."""
        if len(terms) == len(self.prior) and self.free == self.free_given:
            return (self.base_cal, True) if self.response_cal is None else (self.response_cal, False)
        return calibrate(self.poses, self.spec, terms=terms, free=self.free, td_start=self.td_start,
                         robust=self.opt.robust, platform_options=self.platform_options), False

    # ------------------------------------------------------------------------ the recording
    def settling(self) -> None:
        """The finding of holds that never settled, read from the stream, and the poses held-out
        proof is judged on: where the stand settled. An extrapolated pose carries what its approach
        model missed, along the last move (a backlash's signature); with too few settled poses to
        judge on, the stand's physics is not named (a recording that never settles)."""
        lag_effect = unsettled_effect(self.library)
        self.settled = None if lag_effect is None else _settling_finding(
            self.spec, self.poses, self.cur, self.weights, self.opt, self.say, lag_effect.name)
        if self.settled is not None:
            self.findings.append(self.settled)
        judged = ~extrapolated(self.poses)
        need = settled_needed(self.opt.folds)
        self.too_few_settled = bool(judged.sum() < need and not judged.all())
        if self.too_few_settled:
            self.say(f"only {int(judged.sum())} holds settled: too few to prove an effect of the stand on")
        if judged.sum() < need:
            judged = np.ones(self.poses.n_poses, bool)
        self.judged = judged
        self.stop = self.at_floor or self.too_few_settled

    # ------------------------------------------------------------------------ the rounds
    def select(self) -> None:
        """Rounds of forward selection until one accepts nothing, a probe beats the named model,
        the model named so far predicts held-out poses at the noise floor (the geometric model's
        rule: what is left there is noise, or a remnant of the physics named that any further term
        would only take a slice of), or the cap (:func:`effect_cap`) is reached: then the search
        did not end at a test, and a round ``at_cap`` says so (the verdict too)."""
        while not self.stop:
            if len(self.findings) >= self.cap:
                links = len(self.spec.tracked_links)
                why = ("--max-effects" if self.opt.max_effects is not None else
                       f"{CHAIN_EFFECTS} for each of the tree's {links} tracked links" if links > 1 else
                       f"{CHAIN_EFFECTS} on one moving part")
                text = (f"stopped at the cap of {self.cap} effect{'s' if self.cap != 1 else ''} ({why}), not at a "
                        "test: a further effect was not tried")
                self.rounds.append({"round": len(self.rounds) + 1, "at_cap": text, "cap": self.cap})
                self.say(text)
                break
            if not self.round():
                break
            if self.floor is not None and self.findings and self.naming \
                    and self.cur.cv_rms <= self.floor_factor * self.floor:
                text = (f"the model predicts held-out poses at {_fmt_rms(self.cur.cv_rms, self.unit)}, at the noise "
                        f"floor ({_fmt_rms(self.floor, self.unit)}): nothing left to find")
                self.rounds.append({"round": len(self.rounds) + 1, "at_noise_floor": text})
                self.say(text)
                break

    def candidates(self) -> list[tuple[Effect, ModelTerm]]:
        """Every effect's candidate terms at places no term of its kind holds yet; a direction
        effect on a slow actuator is set aside (its approach's remnant looks the same)."""
        cands: list[tuple[Effect, ModelTerm]] = []
        taken = {place(t) for t in self.cur.terms}
        body_r = body_residuals(self.cur, self.poses)
        for eff in self.library.values():
            if eff.unsettled_holds and self.settled is not None:
                continue  # the lag is already read from the stream and corrected in the data
            for term in eff.candidates(self.spec, self.poses, body_r):
                if place(term) in taken or place(term) in self.echoes:  # one term of a kind per actuator / marker
                    continue
                if _slow_actuator_echo(eff, term, self.settled, self.poses):
                    self.not_separable[(eff.name, _where_text(term.where))] = {
                        "effect": eff.name, "where": term.where, "separability": 0.0,
                        "from": f"{FROM_SLOW_APPROACH} (an unfinished approach along the last "
                                "move looks like play in that actuator)"}
                    continue
                cands.append((eff, term))
        return cands

    def screened(self, cands: list[tuple[Effect, ModelTerm]]) -> tuple[list, np.ndarray, list[int]]:
        """The round's score tests (Holm-adjusted), the candidates to refit (the best of each kind
        and place, at most ``max_refits``), and the round's entry in ``rounds``."""
        opt = self.opt
        scr = screen(self.cur, self.spec, self.poses, [t for _, t in cands])
        p_adj = holm(np.array([s[1] for s in scr])) if scr else np.zeros(0)
        table = []
        for (eff, term), (F, p, sep, J), pa in zip(cands, scr, p_adj):
            table.append({"effect": eff.name, "where": _where_text(term.where), "F": F, "p_adjusted": float(pa),
                          "separability": sep})
            if sep < opt.min_separability:
                key = (eff.name, _where_text(term.where))
                moves_none = not np.any(np.nan_to_num(np.asarray(J, float)))
                self.not_separable[key] = {"effect": eff.name, "where": term.where, "separability": sep,
                                           "from": FROM_NO_MARKER if moves_none else "motion capture"}
        order = [i for i in np.argsort([s[1] for s in scr])
                 if p_adj[i] < opt.alpha and scr[i][2] >= opt.min_separability]
        # the best candidate of each kind and place (one split per marker, one period per
        # actuator), so that neighbours of one located step do not crowd out the others
        chosen: list[int] = []
        seen: set[tuple] = set()
        for i in order:
            if place(cands[i][1]) not in seen and len(chosen) < opt.max_refits:
                chosen.append(i)
                seen.add(place(cands[i][1]))
        self.rounds.append({"round": len(self.rounds) + 1, "screened": len(cands), "passed_screening": len(order),
                            "refit": [f"{cands[i][0].name} ({_where_text(cands[i][1].where)})" for i in chosen],
                            "top": sorted(table, key=lambda x: x["p_adjusted"])[:8]})
        return scr, p_adj, chosen

    def trials(self, cands: list, scr: list, chosen: list[int]) -> list[tuple[int, Fit, float]]:
        """Each chosen candidate's best variant, fitted with its held-out errors: (index, fit,
        paired held-out p against the current model)."""
        opt, cur = self.opt, self.cur
        trials = []
        for i0 in chosen:
            i, f = best_variant(i0, cands, scr, cur, self.spec, self.poses, self.weights, opt)
            eff, term = cands[i]
            f.cv = _cv(f, self.spec, self.poses, opt.folds, opt.lm_iterations)
            trials.append((i, f, paired_improvement(cur.cv[self.judged], f.cv[self.judged])))
            self.say(f"  {eff.name} ({_where_text(term.where)}): held-out RMS {_fmt_rms(f.cv_rms, self.unit)} "
                     f"(paired p = {trials[-1][2]:.2g}), BIC {f.bic - cur.bic:+.1f}")
        return trials

    def round(self) -> bool:
        """One round: screen, refit, confirm, then the checks on the candidate confirmed (the
        recording's, the held geometry's, the probes') before it is accepted. True: search on."""
        opt = self.opt
        cands = self.candidates()
        scr, p_adj, chosen = self.screened(cands)
        if not chosen:
            return False
        trials = self.trials(cands, scr, chosen)
        separability = [sc[2] for sc in scr]
        good = confirm(trials, separability, self.cur, self.judged, opt)
        if good is None:
            self.rounds[-1]["not_accepted"] = not_accepted(trials, cands, separability, self.cur, self.judged, opt)
            self.say(self.rounds[-1]["not_accepted"])
            return False
        i, best, ph = good
        eff, term = cands[i]
        if self.contradicted_by_the_recording(eff, term, float(scr[i][2]), ph):
            return True
        if opt.reopen_geometry and scr[i][2] < opt.warn_separability and not self.reopened_once:
            # a term mostly inside the geometry's span competes with the geometry the calibration
            # held (its selection scored the groups with every effect still in the residual): the
            # held groups are tried first, and the round is screened again if they predict better
            self.reopened_once = True
            reopened = _reopened(self.spec, self.poses, self.cur, self.free, self.judged, opt, self.platform_options)
            if reopened is not None:
                self.cur, self.free, note = reopened
                self.rounds[-1]["geometry_reopened"] = note
                self.say(note["text"])
                return True
        # naming check: a generic model of the same structure must not predict clearly better
        if opt.probes:
            probe_better = _probe_beats(self.spec, self.poses, self.cur, best, opt, ph)
            if probe_better is not None:
                self.stop_unexplained = probe_better
                return False
        self.accept(i, cands, scr, p_adj, trials, best, ph)
        return True

    def contradicted_by_the_recording(self, eff: Effect, term: ModelTerm, separability: float, ph: float) -> bool:
        """A weak proof the recording contradicts (an extrapolated approach, settled holds): the
        term is set aside, never tried again at its place."""
        weak = weak_beside_the_recording(eff, self.settled, self.poses, ph, self.opt.weak_alpha)
        if weak is None:
            return False
        self.echoes.add(place(term))
        self.not_separable[(eff.name, _where_text(term.where))] = {
            "effect": eff.name, "where": term.where, "separability": separability, "from": weak[0]}
        self.say(f"{eff.name} ({_where_text(term.where)}): {weak[1]}; not named")
        return True

    def accept(self, i: int, cands: list, scr: list, p_adj: np.ndarray, trials: list, best: Fit, ph: float) -> None:
        """Name candidate ``i`` (its fit ``best``, held-out p ``ph``): its finding, then the
        geometry chosen again beside the accepted terms, a recording artefact's as a physics' (the
        calibration chose it with the artefact in the data; fitted, it no longer hides what a held
        group explains)."""
        opt, cur = self.opt, self.cur
        eff, term = cands[i]
        F, p_s, sep, Jc = scr[i]
        k = len(best.terms) - 1
        theta = best.theta(k)
        warn = []
        if sep < opt.warn_separability:
            warn.append(f"only {100 * sep:.0f}% of its signature lies outside the geometry's Jacobian: "
                        "part of it is absorbed by the geometric parameters on this design")
        reg = eff.regressor(term, self.spec, self.poses)
        finding = Finding(
            effect=eff.name, where=dict(term.where), parameters={}, heldout_rms_before=cur.cv_rms,
            heldout_rms_after=best.cv_rms, evidence="", p_heldout=float(ph), p_screen=float(p_adj[i]),
            bic_change=float(best.bic - cur.bic), separability=float(sep), warnings=warn, term=term,
            regressor=reg, regressor_label=eff.regressor_label(term),
            signature_before=_signature(Jc, cur.r, theta, _offset_sign(term, theta, best, self.poses)))
        finding.alternatives = equally_good(i, best, trials, cands, [sc[2] for sc in scr], cur, self.judged, opt)
        self.findings.append(finding)
        self.accepted.append({"fit": best, "J": Jc})
        self.say(f"accepted {eff.name} ({_where_text(term.where)})")
        self.cur = best
        tell_apart(self, finding, cur)
        again_after(self, f"{eff.name} ({_where_text(term.where)})")  # the response's kind chosen again beside it
        sel = (self.start.identifiability.get("model_selection") or {}) if self.start is not None else {}
        chosen_free = bool(sel) and not str(sel.get("reason", "")).startswith("no selection")  # not the user's --free
        if opt.reopen_geometry and chosen_free:  # the geometry chosen again beside the accepted terms
            again = _reselected(self.spec, self.poses, self.cur, self.free, self.judged, opt, self.platform_options,
                                f"{eff.name} ({_where_text(term.where)})")
            if again is not None:
                self.say(again[2]["text"])
                self.rounds[-1]["geometry_reselected" if again[0] is not None else "geometry_kept"] = again[2]
            if again is not None and again[0] is not None:
                self.cur, self.free = again[0], again[1]
                # the final refit starts where the selection left the geometry: a group it holds is
                # held at nominal, not at the value it took standing in for the physics
                self.td_start = self.cur.problem.split(self.cur.z)[0].copy()
        self.variants_again()

    def variants_again(self) -> None:
        """The variants of the terms accepted before the last chosen again beside it
        (rounds.variants_again): each finding keeps its place and takes the new variant."""
        cur, notes = variants_again(self.cur, len(self.prior), self.library, self.spec, self.poses, self.weights,
                                    self.judged, self.opt, FORM_BIC_MARGIN)
        if not notes:
            return
        self.cur = cur
        for note in notes:
            finding = next(f for f in self.findings if f.term is note["before"])
            eff, term = self.library[note["after"].effect], note["after"]
            finding.term, finding.where = term, dict(term.where)
            finding.regressor, finding.regressor_label = eff.regressor(term, self.spec, self.poses), \
                eff.regressor_label(term)
            self.accepted[note["term"] - len(self.prior)] = {"fit": cur, "J": note["J"]}
            self.say(f"{eff.name} ({_where_text(term.where)}): its variant chosen again beside the later terms, "
                     f"BIC {note['bic_change']:+.1f}")
        self.rounds[-1]["variants_again"] = [
            {"effect": n["after"].effect, "where": _where_text(n["after"].where), "bic_change": n["bic_change"],
             "heldout_rms_before": n["heldout_rms_before"], "heldout_rms_after": n["heldout_rms_after"],
             "p_worse": n["p_worse"],
             "changed": {k: [n["before"].where.get(k), v] for k, v in n["after"].where.items()
                         if repr(v) != repr(n["before"].where.get(k))}} for n in notes]

    # ------------------------------------------------------------------------ the final model
    def final_model(self) -> None:
        """The final model through the estimator's full procedure (robust weights, covariance),
        each finding's parameters, signature and evidence from it, and the location tests of its
        residuals. A recording artefact with an onset whose model change does not predict the
        poses from then on better is named and corrected in the data (the fitted model keeps it),
        but not written into calibration.yaml (``unwritten``)."""
        if self.naming:
            for k in range(len(self.prior), len(self.cur.terms)):
                term = self.cur.terms[k]
                eff = self.library.get(term.effect)
                onset = eff.onset(term) if eff is not None and eff.recording else None
                if eff is not None and onset is not None:
                    note = _slip_not_kept(self.spec, self.poses, self.cur, k, eff, onset, self.judged, self.opt)
                    if note is not None:
                        self.unwritten[id(term)] = note
                        self.say(f"{eff.name} ({_where_text(term.where)}): {note}")
        self.final_cal, self.unchanged = self.refit(self.cur.terms)
        self.modelled = [f for f in self.findings if f.term is not None]
        for k, (finding, info) in enumerate(zip(self.modelled, self.accepted), start=len(self.prior)):
            theta, std = self.final_cal.theta[k], self.final_cal.theta_std[k]
            finding.parameters = _params(finding.term, theta, std)
            finding.signature_after = _signature(info["J"], self.final_cal.fit.residuals_after, theta,
                                                 _offset_sign(finding.term, theta, info["fit"], self.poses))
            finding.evidence = _evidence(finding, self.poses, self.unit, folds=self.opt.folds)
        self.locations = locate(self.final_cal.fit.residuals_after, self.poses, self.spec, None, self.opt.alpha)

    def structure_left(self) -> None:
        """What the final model leaves: the probe that beat it (``unexplained``), structure the
        location tests find that held-out prediction sees, or, with nothing modelled, a lack of fit
        (lack_of_fit.py). Held-out prediction is judged where the stand settled (an extrapolated
        pose carries what its approach model missed: the noise floor does not hold for it)."""
        opt, unit = self.opt, self.unit
        if self.end_probe is not None:
            self.stop_unexplained = self.end_probe[0]
        if self.stop_unexplained is not None:
            self.findings.append(self.stop_unexplained)
        held = _rms(self.cur.cv, self.judged) if self.cur.cv is not None else float("nan")
        if not self.stop:
            left = located(self.locations, opt.alpha * 0.1) if self.stop_unexplained is None else []
            if left and (self.modelled or nodes_share_noise(self.poses)) and self.floor is not None \
                    and held <= opt.lack_of_fit_factor * self.floor:
                # beside a modelled effect, or on a stream's windowed poses (their nodes share coloured noise), structure the
                # tests still see but held-out prediction does not (within the factor) is a remnant or noise: said, not named
                self.say(f"structure remains ({left[0].test}, adjusted p = {left[0].p_adjusted:.2g}) but the model "
                         f"predicts held-out poses at {_fmt_rms(held, unit)}, within {opt.lack_of_fit_factor:g} times "
                         "the noise floor: not reported as unexplained")
                left = []
            if left:
                top = left[0]
                self.findings.append(Finding(
                    effect="unexplained", where=dict(top.where), parameters={}, heldout_rms_before=self.cur.cv_rms,
                    heldout_rms_after=self.cur.cv_rms,
                    evidence=(f"{top.test} of the residual ({', '.join(f'{k} {v}' for k, v in top.where.items())}) "
                              f"survives correction for {len(self.locations)} tests (adjusted p = "
                              f"{top.p_adjusted:.2g}); no effect in the library predicts held-out poses better"),
                    p_screen=float(top.p_adjusted)))
        if not self.stop and not self.modelled and self.floor is not None \
                and not any(f.effect == "unexplained" for f in self.findings):
            lack, near = lack_of_fit(self.cur, self.poses, self.floor, held, opt, self.say)
            if near is not None:
                self.rounds.append(near)
            if lack is not None:
                self.findings.append(lack)

    # ------------------------------------------------------------------------ what is written
    def written(self) -> Calibration:
        """The findings in order of their held-out gain, each recording artefact's correction
        said, and the calibration diagnosis writes: the stand's (recording artefacts left out),
        refit without the terms whose model change is not written; the calibration given,
        unchanged, where nothing changed the model."""
        self.findings.sort(key=lambda f: -(f.heldout_rms_before - f.heldout_rms_after) if f.effect != "unexplained"
                           else 0)
        written, as_given = self.refit([t for t in self.cur.terms if id(t) not in self.unwritten]) if self.unwritten \
            else (self.final_cal, self.unchanged)
        stand = stand_calibration(written, self.library)
        if self.start is not None and as_given:
            # nothing modelled and the geometry's free set as given: the calibration given is what
            # diagnosis writes, unchanged (a refit from it can wander within the estimate's own
            # uncertainty where the geometry is poorly determined)
            stand = self.start
        for f in self.findings:  # a recording artefact's term is corrected in the data
            eff = self.library.get(f.effect)
            if f.term is not None and eff is not None and eff.recording:
                f.corrected = self.unwritten.get(id(f.term)) or eff.correction(f.where)
        return stand

    def diagnosis(self, stand: Calibration, heldout: PoseSet | None = None) -> Diagnosis:
        """The :class:`Diagnosis` whose calibration is ``stand``, ``heldout`` (another recording)
        scored before and after, and its verdict."""
        library = self.library
        if self.response_note is not None:  # chosen before the search's rounds, recorded beside them
            self.rounds.append(self.response_note)
        self.rounds.extend(self.response_after)
        heldout_info = None
        if heldout is not None:
            heldout_info = _score_heldout(self.base_cal, stand, heldout, self.spec, self.findings)
        diag = Diagnosis(findings=self.findings, verdict="", calibration=stand, base=self.base_cal,
                         locations=self.locations, locations_before=self.locations_before, rounds=self.rounds,
                         not_separable=list(self.not_separable.values()), unit=self.unit, poses=self.poses,
                         heldout_session=heldout_info, fitted=self.final_cal, noise_floor=self.floor,
                         heldout_geometric=self.first_cv, at_noise_floor=self.at_floor,
                         too_few_settled=bool(self.too_few_settled), options=self.opt,
                         advice={n: e.not_separable_advice for n, e in library.items() if e.not_separable_advice},
                         untried={n: r for n, e in library.items() if (r := e.untried(self.spec, self.poses))})
        diag.verdict = verdict(diag)
        return diag

