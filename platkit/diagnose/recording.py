"""Recording artefacts in diagnosis: the finding of holds that never settled, read from the raw
stream (extrapolated to rest by the settling search) and named after the library's
``unsettled_holds`` effect; the direction effects such a session would echo; and the calibration
of the stand that leaves the artefacts out (the effects whose ``recording`` is True: a lag left
out, a moved marker at its new place)."""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from platkit.diagnose.fitting import (
    FROM_SETTLED_STREAM,
    FROM_SLOW_APPROACH,
    Finding,
    Fit,
    Options,
    _cv,
    _fit,
    _fmt_rms,
    _rms,
    extrapolated,
)
from platkit.diagnose.naming import _without
from platkit.diagnose.stats import paired_improvement
from platkit.effects import Effect, history
from platkit.io.calibration import Calibration
from platkit.model import PlatformSpec
from platkit.plugins import effect_library
from platkit.poses import PoseSet
from platkit.terms import ModelTerm


def stand_calibration(cal: Calibration, library: Mapping[str, Effect] | None = None) -> Calibration:
    """The calibration of the stand from one fitted with recording artefacts (the terms whose
    effect in ``library``, default every installed effect, has ``recording`` True): their terms
    left out (the stand is predicted where it settles), a marker one of them moved placed where it
    moved to (``Effect.moved_markers``: each offset added to its position, the stds combined).
    Other terms stay."""
    library = effect_library() if library is None else library
    artefact = [t.effect in library and library[t.effect].recording for t in cal.terms]
    keep = [k for k, a in enumerate(artefact) if not a]
    markers = np.array(cal.marker_positions, float, copy=True)
    mstd = np.array(cal.marker_std, float, copy=True)
    for t, theta, std, a in zip(cal.terms, cal.theta, cal.theta_std, artefact):
        for m, offset, sd in (library[t.effect].moved_markers(t, theta, std) if a else []):
            markers[m] = markers[m] + offset
            mstd[m] = np.sqrt(mstd[m] ** 2 + sd**2)
    if len(keep) == len(cal.terms):
        return cal
    return replace(cal, terms=[cal.terms[k] for k in keep], theta=[cal.theta[k] for k in keep],
                   theta_std=[cal.theta_std[k] for k in keep], marker_positions=markers, marker_std=mstd)

def _slow_actuator_echo(effect: Effect, term: ModelTerm, settled: Finding | None, poses: PoseSet) -> bool:
    """True for a term of a direction effect (``Effect.direction``, a backlash) on an actuator the
    finding of unsettled holds named, in a session where holds were extrapolated to rest: what the
    approach model missed lies along that actuator's last move, which is a direction effect's
    signature, so the two cannot be told apart on these data."""
    return effect.direction and _on_slow_actuator(term, settled, poses)


def _on_slow_actuator(term: ModelTerm, settled: Finding | None, poses: PoseSet) -> bool:
    """True for a term placed on an actuator that a ``settling_lag`` finding named, in a session
    where holds were extrapolated to rest."""
    if settled is None:
        return False
    if not extrapolated(poses).any():
        return False
    slow = {a.strip() for a in str(settled.where.get("actuator", "")).split(",")} - {"", "all"}
    return str(term.where.get("actuator", "")).strip() in slow


def extrapolated_weak_echo(settled: Finding | None, poses: PoseSet, p_heldout: float, level: float) -> bool:
    """True for a term whose held-out proof is only weak (paired p above ``level``) in a session
    whose holds were extrapolated to rest (a ``settling_lag`` finding from the stream): what the
    approach model missed is a function of the slow actuator's state, and it reaches every pose
    through the kinematics; even the poses that settled are biased along its last move (the
    settling search's own test stops short of a slow drive's last hundredths). A term on that
    actuator, or on any other, absorbs a slice of it, and a weak proof does not tell the two
    apart."""
    if settled is None or p_heldout <= level:
        return False
    return bool(extrapolated(poses).any())


def settled_stream_weak_lag(effect: Effect, settled: Finding | None, poses: PoseSet, p_heldout: float,
                            level: float) -> bool:
    """True for a fitted term of the ``unsettled_holds`` effect (a lag: a fraction of the last
    move, added to the poses) proven only weakly (paired p above ``level``) in a session whose raw
    stream the settling search read and found settled (no lag read from it): the direct evidence
    of a lag, markers still moving at the end of a hold, is not there, and the term only takes a
    slice of some other structure."""
    if not effect.unsettled_holds or settled is not None or p_heldout <= level:
        return False
    return (poses.settling or {}).get("sigma_m") is not None


def weak_beside_the_recording(effect: Effect, settled: Finding | None, poses: PoseSet, p_heldout: float,
                              level: float) -> tuple[str, str] | None:
    """(where it comes from, for not_separable; the sentence said) for a weakly proven term the
    recording does not let be named (:func:`extrapolated_weak_echo`, :func:`settled_stream_weak_lag`),
    else None."""
    p = f"paired p = {p_heldout:.2g}"
    if extrapolated_weak_echo(settled, poses, p_heldout, level):
        return (f"{FROM_SLOW_APPROACH} (held-out {p}, a weak proof: what the approach model "
                "missed reaches every pose)",
                f"proven only weakly ({p}) in a session whose holds were extrapolated to rest: not told apart from "
                "the approach's remnant")
    if settled_stream_weak_lag(effect, settled, poses, p_heldout, level):
        return (f"{FROM_SETTLED_STREAM} (held-out {p}, a weak proof of a lag the stream does "
                "not show)",
                f"proven only weakly ({p}), and the stream shows the holds settled")
    return None


def unsettled_effect(library: Mapping[str, Effect]) -> Effect | None:
    """The effect that holds which never settled are (``Effect.unsettled_holds``): the first of
    ``library``'s, else of the installed effects' (a library given without it still names what
    the stream shows), None when no effect is."""
    for candidates in (library, effect_library()):
        for effect in candidates.values():
            if effect.unsettled_holds:
                return effect
    return None


def _settling_finding(spec: PlatformSpec, poses: PoseSet, cur: Fit, weights: np.ndarray, opt: Options,
                      say: Callable[[str], None], name: str) -> Finding | None:
    """The finding of holds that never settled and were extrapolated to rest by the settling
    search, named ``name`` (the ``unsettled_holds`` effect's), or None.

    It is made from the raw stream: the settling search extrapolated many holds (more than its
    ``max_unsettled_fraction``) and read from the direction the markers still moved which
    actuators lag, with what time constant. Where enough held-out *settled* poses exist, it is
    tested there: the model fitted to the poses as extrapolated (``cur``) and one fitted with those
    holds where the stream was at their end ('held_markers') predict them (the same data in both);
    it stands when the extrapolated one predicts them significantly better, or, with the lagging
    actuators named from the stream, when it does not predict them significantly worse (paired
    Wilcoxon the other way at ``alpha_heldout``). The correction is the settling search's own:
    diagnosis changes nothing in the calibration. With too few settled poses to test on, the
    stream's evidence stands alone when it names the actuators."""
    info = poses.settling or {}
    un = info.get("unsettled") or {}
    if not un or not info.get("n_extrapolated") or "held_markers" not in poses.extras or cur.cv is None:
        return None
    ex = extrapolated(poses)
    named = list(un.get("actuators") or [])
    unit = poses.length_unit
    if ex.sum() == 0:
        return None
    if (~ex).sum() < 2 * opt.folds:
        if not named:
            say(f"{un['sentence']}; too few held-out settled poses ({int((~ex).sum())}) to test the extrapolation")
            return None
        rms = float(np.sqrt(np.nanmean(cur.cv)))
        say(f"{name} (from the stream): {un['sentence']}; only {int((~ex).sum())} settled poses, too few to "
            "test the extrapolation on held-out ones: the stream's evidence stands alone")
        return _settling_lag(name, un, int(info.get("n_commands", poses.n_poses)), rms, rms, float("nan"),
                             f"{un['sentence']}; the {int(info['n_extrapolated'])} extrapolated to rest from their "
                             f"fitted approach (only {int((~ex).sum())} holds settled: too few to test the "
                             "extrapolation on held-out settled poses)")
    naive = poses.subset(np.arange(poses.n_poses))
    naive.markers = np.where(ex[:, None, None], np.asarray(poses.extras["held_markers"], float), poses.markers)
    if naive.n_samples is not None:
        n = np.array(naive.n_samples, float, copy=True)
        n[ex] = np.median(n[~ex])  # a window of the stream, as a plain search would have averaged
        naive.n_samples = n
    w = np.all(np.isfinite(naive.markers), axis=2).astype(float)
    base = _fit(spec, naive, cur.terms, cur.z, cur.active, w, opt.lm_iterations, opt.robust)
    base.cv = _cv(base, spec, naive, opt.folds, opt.lm_iterations)
    before = float(np.sqrt(np.nanmean(base.cv[~ex])))
    after = float(np.sqrt(np.nanmean(cur.cv[~ex])))
    p = paired_improvement(base.cv[~ex], cur.cv[~ex])
    p_worse = paired_improvement(cur.cv[~ex], base.cv[~ex])
    say(f"{name} (from the stream): held-out settled poses {_fmt_rms(before, unit)} -> {_fmt_rms(after, unit)} "
        f"(paired p = {p:.2g}; worse: p = {p_worse:.2g})")
    better = after < before and p < opt.alpha_heldout
    worse = after > before and p_worse < opt.alpha_heldout
    if not better and not (named and not worse):
        return None
    return _settling_lag(name, un, int(info.get("n_commands", poses.n_poses)), before, after, float(p),
                         f"{un['sentence']}; the {int(info['n_extrapolated'])} extrapolated to rest from their fitted "
                         f"approach, instead of taken where the stream was at the end of the hold, predict the "
                         f"{int((~ex).sum())} held-out settled poses at {_fmt_rms(after, unit)} against "
                         f"{_fmt_rms(before, unit)} ({opt.folds}-fold, paired Wilcoxon p = {p:.2g}"
                         + (")" if better else f"; no better, not significantly worse, p = {p_worse:.2g}: the actuators named "
                            "from the stream)"))

def _settling_lag(name: str, un: dict, n_commands: int, before: float, after: float, p: float,
                  evidence: str) -> Finding:
    """The finding ``name`` of the settling search's ``unsettled`` summary ``un`` (of ``n_commands``)."""
    tau = un.get("time_constant_s")
    q = un.get("time_constant_quartiles_s") or [np.nan, np.nan]
    spread = (q[1] - q[0]) / 1.349 if np.all(np.isfinite(q)) else None
    where = {"actuator": ", ".join(un.get("actuators") or []) or "all", "markers": list(un.get("markers") or []),
             "holds": int(un.get("n", 0)), "of_commands": int(n_commands)}
    return Finding(
        effect=name, where=where,
        parameters={"time_constant": {"value": tau, "std": spread, "unit": "s"},
                    "hold": {"value": un.get("hold_s"), "std": None, "unit": "s"}},
        heldout_rms_before=before, heldout_rms_after=after, p_heldout=p, evidence=evidence,
        corrected=("in the data: those holds enter as the rest position of their approach, weighted by its "
                   "uncertainty; calibration.yaml predicts where the stand settles"))


#: where a ``settling_lag`` finding read from a refusal's settle summary comes from (its ``where['from']``)
FROM_SETTLE_SUMMARY = "settle summary of a session calibrated from motion"


def _response_said(response: Mapping | None, named: list[str]) -> str:
    """'; the calibration from motion's fitted response agrees: B tau 0.65 s, the slowest (A 0.1 s,
    ...)' or the clause that says it does not; '' without a response."""
    acts = (response or {}).get("actuators") or {}
    taus = {c: float(e["tau_s"]["value"]) for c, e in acts.items()
            if (e.get("tau_s") or {}).get("value") is not None and e["tau_s"].get("status") == "estimated"}
    if not taus:
        return ""
    slow = max(taus, key=lambda c: taus[c])
    each = ", ".join(f"{c} {taus[c]:.3g} s" for c in taus)
    agrees = "agrees" if slow in named else "reads another actuator as the slowest"
    return f"; the calibration from motion's fitted response {agrees}: slowest {slow} (time constants {each})"


def lag_from_settle_summary(settling: Mapping, response: Mapping | None, heldout_rms: float, name: str,
                            max_unsettled_fraction: float) -> Finding | None:
    """The finding ``name`` (the ``unsettled_holds`` effect's) of a session calibrated from motion
    because its holds never settled, read from the settling search's own summary (``settling``:
    platkit.settle.HoldsNeverSettle's), or None.

    The summary is evidence of a slow actuator where the session has holds (more than one settled:
    a stream's last command's hold alone may settle), more
    than ``max_unsettled_fraction`` of its commands never settled, and the search named the
    actuators still moving (their markers' late motion along the actuators' own Jacobian columns,
    or a contrast with the holds that settled) and fitted their time constant: the finding carries
    those actuators (where) and that time constant (size), as :func:`_settling_finding` does for
    holds extrapolated to rest. A stream without holds, or a summary that names no
    actuator, names nothing. Nothing is fitted or changed: the calibration from motion carries the
    actuators' response, the lag's correction, so ``heldout_rms`` (the geometric model's on the
    stream) is the finding's before and after. ``response`` (the calibration's ``motion.response``):
    its fitted time constants are said beside the summary's, a second reading from the whole stream."""
    un = dict(settling.get("unsettled") or {})
    n_commands = int(settling.get("n_commands") or un.get("n_commands") or 0)
    named = [str(a) for a in (un.get("actuators") or []) if str(a).strip()]
    tau = un.get("time_constant_s")
    if (int(settling.get("n_settled") or 0) <= 1 or not named or tau is None or not np.isfinite(float(tau))
            or n_commands <= 0 or int(un.get("n", 0)) <= max_unsettled_fraction * n_commands):
        return None
    f = _settling_lag(name, un, n_commands, heldout_rms, heldout_rms, float("nan"),
                      f"from the {FROM_SETTLE_SUMMARY}: {un['sentence']}; {settling.get('reason', 'refused')}, so the "
                      "session was calibrated from its stream" + _response_said(response, named))
    f.where["from"] = FROM_SETTLE_SUMMARY
    f.corrected = ("by the calibration from motion: its fitted actuator response carries the lag, and calibration.yaml "
                   "predicts where the stand settles")
    return f


def _slip_not_kept(spec: PlatformSpec, poses: PoseSet, cur: Fit, k: int, effect: Effect, onset: float,
                   judged: np.ndarray, opt: Options) -> str | None:
    """For the recording artefact at ``cur.terms[k]`` that acts from ``onset`` on
    (``Effect.onset``, a marker slip): when the model without it predicts the held-out settled
    poses from the onset on as well as the model with it (not significantly worse), the model
    change is not written: the sentence saying so (``effect.correction``) is returned (None
    otherwise, or with too few poses after the onset to tell). The artefact stays a finding and in
    the fitted model (it is in the recording, and the location tests see the data corrected), but
    calibration.yaml predicts where the stand settles now, which the geometric fit already did:
    for a slip, its robust weights had put the marker at its new place and left its earlier half
    out. Fitting both places brings that half back and moves the geometry within its own
    uncertainty, better or worse by chance, so only a change that predicts better is written, by
    the gain every other term must show (``min_relative_gain``)."""
    term = cur.terms[k]
    after = judged & (np.asarray(history(poses, "elapsed"), float) >= onset) & np.isfinite(cur.cv)
    if after.sum() < 2 * opt.folds:
        return None
    wo = _without(spec, poses, cur, {k}, opt)
    rows = after & np.isfinite(wo.cv)
    with_rms, without_rms = _rms(cur.cv, rows), _rms(wo.cv, rows)
    p = paired_improvement(wo.cv[rows], cur.cv[rows])
    if with_rms < (1 - opt.min_relative_gain) * without_rms and p < opt.alpha_heldout:
        return None
    unit = poses.length_unit
    return effect.correction(term.where, f"{_fmt_rms(with_rms, unit)} against {_fmt_rms(without_rms, unit)} "
                                         f"(paired p = {p:.2g}), not {100 * opt.min_relative_gain:g}% better")
