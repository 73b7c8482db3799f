"""The actuators' response of a stream without holds, chosen again by diagnosis before any effect
is tried (platkit.diagnose.search).

A stream's windowed poses are modelled through the calibrated actuator response, refitted as a
term in every fit (platkit.calibrate.motion.LocalResponseTerm). Where that response follows the
first order at some actuator (a kind the caller named, or calibrate's choice), what a second-order
drive does beyond a first-order lag is left in the residuals as structure in the motion: smooth
in time, a function of each actuator's travel and its rate, and any effect whose signature
follows an actuator's travel (a scale nonlinearity, above all) takes a slice of it and predicts
held-out poses a little better. That slice is the response's, not the effect's.

Rule (:func:`response_again`): the response is fitted again with every actuator in the second
order (each time constant halved and damping 1: the same lag at low frequency, calibrate's own
start for the second order, platkit.calibrate.motion_kind), beside the geometry and the terms the
calibration carries; it replaces the first order where it lowers the BIC and predicts the
windowed poses held out significantly better (one-sided paired Wilcoxon at ``alpha_heldout``).
The effects are then tried and proven beside the response the stream supports (the
findings' held-out figures are that model's), as the geometry is chosen again beside them, and
the calibration diagnosis writes carries it (calibration.yaml's ``actuator_response`` of the second
order, its ``choice`` saying that diagnosis chose it again), with or without an effect named: the
model the findings were judged in is the model written, as for the geometry chosen again. A
response already second order everywhere, or a session that is not a stream, is left as it is.

Rule, after an effect is accepted (:func:`kind_after_effect`; the search calls it through
:func:`again_after`, before the geometry is chosen again): the kind was chosen with the effect
left in the residuals, where either kind can take a slice of it (and the geometry's weakly
determined directions with it), so it is chosen again beside the effect: the response is fitted in
each other kind (every actuator first order, each time constant the lag 2 zeta tau; every actuator
second order, from the lag as above), started at the fitted response and fitted with the geometry
and every term; the one of lower BIC replaces the response where its BIC is lower than the model's
and, the simpler kind, the richer does not predict the K-fold held-out poses significantly better,
or, the richer kind, it predicts them significantly better (one-sided paired Wilcoxon at
``alpha_heldout`` either way: the richer response proves itself). The round's record carries the
choice (``response``), a kept choice is listed among diagnosis.json's rounds, and calibration.yaml
carries the response kept, its ``actuator_response.why`` saying so.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.motion import LocalResponseTerm
from platkit.calibrate.motion_kind import theta_by_name
from platkit.calibrate.motion_start import fd_steps
from platkit.calibrate.response import ResponseModel
from platkit.diagnose.fitting import Fit, Options, _cv, _fit, _fmt_rms, _rms, _swapped
from platkit.diagnose.stats import paired_improvement
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["ROUND_RESPONSE", "first_order_response", "kind_after_effect", "kind_kept", "response_again",
           "second_order_response"]

#: the "round" of diagnosis.json's rounds that records the response chosen again (kept or not)
ROUND_RESPONSE = "response"


def second_order_response(term: ModelTerm, control_names: list[str],
                          theta: np.ndarray | None = None) -> LocalResponseTerm | None:
    """The stream's response ``term`` (at ``theta``, default its start) with every actuator in the
    second order, started where it has the same lag at low frequency (time constant halved,
    damping 1), or None where ``term`` is not a stream's response or already second order at
    every actuator."""
    if not isinstance(term, LocalResponseTerm) or (term.model.kind == "second_order" and not term.model.first):
        return None
    return _in_kind(term, control_names, "second_order", term.initial if theta is None else theta)


def first_order_response(term: ModelTerm, control_names: list[str], theta: np.ndarray) -> LocalResponseTerm | None:
    """The stream's response ``term`` at ``theta`` with every actuator in the first order, each
    time constant the second order's lag at low frequency (2 zeta tau), or None where ``term`` is
    not a stream's response or already first order at every actuator."""
    if not isinstance(term, LocalResponseTerm) or term.model.kind == "first_order":
        return None
    return _in_kind(term, control_names, "first_order", theta)


def _in_kind(term: LocalResponseTerm, control_names: list[str], kind: str, theta: np.ndarray) -> LocalResponseTerm:
    """``term`` at ``theta`` with every actuator in ``kind``, each started at the same lag at low
    frequency (a first order's tau is a critically damped second order's 2 tau)."""
    old = term.model
    new = ResponseModel(kind, old.reference, old.n_u, delays=old.delays, rate_limit=old.rate_limit)
    by_name = dict(zip(old.names(control_names), np.asarray(theta, float)))
    split = old.split(theta)
    for j, c in enumerate(control_names):
        tau, second = float(split["tau_s"][j]), old.is_second(j)
        lag = 2.0 * float(split["damping"][j]) * tau if second else tau
        by_name[f"tau_s.{c}"] = lag if kind == "first_order" else (tau if second else 0.5 * lag)
        by_name[f"damping.{c}"] = float(split["damping"][j]) if second else 1.0
    start = theta_by_name(new, control_names, by_name)
    out = LocalResponseTerm(new, term.T, term.U, control_names, start, fd_steps(new, start), term.start, term.proj,
                            term.sample_t)
    out.start_transient = term.start_transient
    return out


def response_again(spec: PlatformSpec, poses: PoseSet, prior: list[ModelTerm], cur: Fit, free: list[str] | None,
                   td_start: np.ndarray | None, platform_options: Any, weights: np.ndarray,
                   opt: Options) -> tuple[list[ModelTerm], Calibration | None, Fit | None, dict[str, Any]] | None:
    """The stream's response tried in the second order beside the geometry and the calibration's
    other terms ``prior`` (the module docstring's rule), against ``cur``, the model as given with
    its K-fold held-out errors: (the terms with it, the estimator's fit of them, their fit with its
    K-fold held-out errors, the round's record) where it is kept; ``(prior, None, None, record)``
    where it is not (the record says why); None where there is nothing to try (no stream's
    response among ``prior``, or one already second order at every actuator)."""
    k = next((i for i, t in enumerate(prior) if isinstance(t, LocalResponseTerm)), None)
    freer = None if k is None else second_order_response(prior[k], list(spec.control_names))
    if freer is None:
        return None
    terms = [*prior[:k], freer, *prior[k + 1:]]
    cal = calibrate(poses, spec, terms=terms, free=free, td_start=td_start, robust=opt.robust,
                    platform_options=platform_options)
    f = _fit(spec, poses, terms, cal.fit.z, cal.fit.active, weights, opt.lm_iterations, opt.robust)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    kept, p = kind_kept(f, cur, np.ones(len(cur.cv), bool), opt, simpler=False)
    unit = poses.length_unit
    record = {"round": ROUND_RESPONSE, "tried": "second order at every actuator", "kept": kept,
              "heldout_rms_before": cur.cv_rms, "heldout_rms_after": f.cv_rms, "paired_p": float(p),
              "bic_change": float(f.bic - cur.bic),
              "text": (f"the stream's actuator response in the second order at every actuator "
                       f"{'replaces' if kept else 'does not replace'} the calibration's first order: held-out "
                       f"{_fmt_rms(cur.cv_rms, unit)} -> {_fmt_rms(f.cv_rms, unit)} (paired p = {p:.2g}), "
                       f"BIC {f.bic - cur.bic:+.1f}"
                       + ("; effects are judged beside it, and calibration.yaml carries it" if kept else ""))}
    return (terms, cal, f, record) if kept else (prior, None, None, record)


def kind_kept(f: Fit, cur: Fit, judged: np.ndarray, opt: Options, simpler: bool) -> tuple[bool, float]:
    """Whether the response of the other kind (fit ``f``) replaces ``cur``'s, and the one-sided
    paired held-out p (Wilcoxon on the K-fold errors of the ``judged`` poses) of the richer model
    (more unknowns) predicting better than the simpler: each judged by what predicts, the richer
    response kept only where it proves itself. ``f`` the simpler: kept where its BIC is lower and
    ``cur`` does not predict significantly better (p at or above ``alpha_heldout``); ``f`` the
    richer: kept where its BIC is lower and it predicts significantly better (p under
    ``alpha_heldout``, its RMS lower), as before any effect (:func:`response_again`)."""
    if simpler:
        p = float(paired_improvement(f.cv[judged], cur.cv[judged]))
        return bool(f.bic < cur.bic and p >= opt.alpha_heldout), p
    p = float(paired_improvement(cur.cv[judged], f.cv[judged]))
    return bool(f.bic < cur.bic and p < opt.alpha_heldout and _rms(f.cv, judged) < _rms(cur.cv, judged)), p


def kind_after_effect(spec: PlatformSpec, poses: PoseSet, cur: Fit, judged: np.ndarray, opt: Options,
                      after: str) -> tuple[Fit | None, dict[str, Any]] | None:
    """After an effect (``after``, as the record names it) is accepted, the stream's response's kind
    chosen again beside it (the module docstring's rule, second part): each other kind (every
    actuator first order, every actuator second order) started at the fitted response's lag and
    fitted with the geometry and every term of ``cur``; the one of lowest BIC judged by
    :func:`kind_kept`. Returns (its fit with K-fold held-out errors, the record) where it is kept,
    (None, the record) where it is not, None where ``cur`` has no stream's response."""
    k = next((i for i, t in enumerate(cur.terms) if isinstance(t, LocalResponseTerm)), None)
    if k is None:
        return None
    term, theta, names = cur.terms[k], cur.theta(k), list(spec.control_names)
    fits = []
    for alt in (first_order_response(term, names, theta), second_order_response(term, names, theta)):
        if alt is not None:
            terms, z, active = _swapped(cur, k, alt)
            fits.append((alt, _fit(spec, poses, terms, z, active, cur.weights, opt.lm_iterations, opt.robust)))
    alt, f = min(fits, key=lambda af: af[1].bic)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    kept, p = kind_kept(f, cur, judged, opt, simpler=f.n_params < cur.n_params)
    alt.initial = np.asarray(f.theta(k), float).copy()  # the final refit starts where this fit left it
    kind = alt.model.kind.replace("_", " ")
    before, now, unit = _rms(cur.cv, judged), _rms(f.cv, judged), poses.length_unit
    record = {"round": ROUND_RESPONSE, "after": after, "tried": f"{kind} at every actuator, beside {after}",
              "kept": kept, "heldout_rms_before": before, "heldout_rms_after": now, "paired_p_richer_better": p,
              "bic_change": float(f.bic - cur.bic),
              "text": (f"the stream's actuator response in the {kind} at every actuator beside {after} "
                       f"{'replaces' if kept else 'does not replace'} the {term.model.kind.replace('_', ' ')}: "
                       f"held-out {_fmt_rms(before, unit)} -> {_fmt_rms(now, unit)} (paired p of the richer "
                       f"predicting better = {p:.2g}), "
                       f"BIC {f.bic - cur.bic:+.1f}" + ("; calibration.yaml carries it" if kept else ""))}
    return (f if kept else None), record


def again_after(search: Any, after: str) -> None:
    """:func:`kind_after_effect` in a diagnosis search (platkit.diagnose.search.Search) just after
    it accepted ``after``: the model searched on (``search.cur``) takes the response kept, the
    round's record carries the choice (``response``), and a kept choice is listed among the rounds
    diagnosis.json writes (``search.response_after``), for calibration.yaml's ``why``."""
    again = kind_after_effect(search.spec, search.poses, search.cur, search.judged, search.opt, after)
    if again is None:
        return
    fit, record = again
    search.say(record["text"])
    search.rounds[-1]["response"] = record
    if fit is not None:
        search.cur = fit
        search.response_after.append(record)
