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
"""
from __future__ import annotations

from typing import Any

import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.motion import LocalResponseTerm
from platkit.calibrate.motion_kind import theta_by_name
from platkit.calibrate.motion_start import fd_steps
from platkit.calibrate.response import ResponseModel
from platkit.diagnose.fitting import Fit, Options, _cv, _fit, _fmt_rms
from platkit.diagnose.stats import paired_improvement
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["ROUND_RESPONSE", "second_order_response", "response_again"]

#: the "round" of diagnosis.json's rounds that records the response chosen again (kept or not)
ROUND_RESPONSE = "response"


def second_order_response(term: ModelTerm, control_names: list[str]) -> LocalResponseTerm | None:
    """The stream's response ``term`` with every actuator in the second order, started where it
    has the same lag at low frequency (time constant halved, damping 1), or None where ``term`` is
    not a stream's response or already second order at every actuator."""
    if not isinstance(term, LocalResponseTerm):
        return None
    old = term.model
    if old.kind == "second_order" and not old.first:
        return None
    new = ResponseModel("second_order", old.reference, old.n_u, delays=old.delays, rate_limit=old.rate_limit)
    by_name = dict(zip(old.names(control_names), np.asarray(term.initial, float)))
    split = old.split(term.initial)
    for j, c in enumerate(control_names):
        second = old.is_second(j)
        by_name[f"tau_s.{c}"] = float(split["tau_s"][j]) if second else 0.5 * float(split["tau_s"][j])
        by_name[f"damping.{c}"] = float(split["damping"][j]) if second else 1.0
    theta = theta_by_name(new, control_names, by_name)
    out = LocalResponseTerm(new, term.T, term.U, control_names, theta, fd_steps(new, theta), term.start, term.proj,
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
    p = paired_improvement(cur.cv, f.cv)
    kept = bool(f.bic < cur.bic and p < opt.alpha_heldout and f.cv_rms < cur.cv_rms)
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
