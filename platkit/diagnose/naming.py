"""Checks on a name before and after it is given: a generic probe (probes.py) that predicts
held-out poses better than the named model takes its place as ``unexplained``; a name proven only
weakly beside a lack of fit, one that proves nothing beside the probe that still beats the named
model at the end, or one that proves nothing beside a model of the structure in time the
location tests still find beside a lack of fit, is not named. ``_without`` refits a model with
some of its terms left out, ``_unnamed`` takes their findings back (used by the search and
the recording rules), and ``_take_back`` does so for a round of the search, said."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from platkit.diagnose.fitting import Finding, Fit, Options, _cv, _fit, _fmt_rms, _rms, _where_text
from platkit.diagnose.locate import locate, located
from platkit.diagnose.probes import marker_probe, space_probe, time_probe
from platkit.diagnose.stats import paired_improvement
from platkit.model import PlatformSpec
from platkit.poses import PoseSet


def _probe_beats(spec, poses, cur: Fit, best: Fit | None, opt: Options, best_p: float = 0.0) -> Finding | None:
    """The ``unexplained`` finding of :func:`_best_probe`, or None."""
    beaten = _best_probe(spec, poses, cur, best, opt, best_p)
    return None if beaten is None else beaten[0]


def _best_probe(spec, poses, cur: Fit, best: Fit | None, opt: Options,
                best_p: float = 0.0) -> tuple[Finding, Fit] | None:
    """A generic probe that predicts held-out poses significantly better than ``best`` (or, with
    best None, than the current model): (its ``unexplained`` finding, the model with it); else None.

    A named candidate whose own held-out proof is weak (``best_p``, its paired p against the
    current model, above ``alpha_heldout * weak_separability_factor``) also yields to a probe
    that is proven against the current model and predicts better than it with a lower BIC, even
    when the two cannot be told apart significantly."""
    ref = best if best is not None else cur
    fk_X = cur.problem.kinematics(cur.problem.split(cur.z)[0], poses.controls)[1]
    probes = [p for p in (time_probe(poses), space_probe(fk_X), marker_probe(poses, spec)) if p is not None]
    results = []
    for probe in probes:
        f = _fit(spec, poses, cur.terms + [probe], cur.z, cur.active, cur.weights, opt.lm_iterations, opt.robust)
        f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
        p = paired_improvement(ref.cv, f.cv)
        p0 = paired_improvement(cur.cv, f.cv)
        results.append((probe, f, p, p0))
    for probe, f, p, p0 in sorted(results, key=lambda x: x[1].cv_rms):
        gain_vs_ref = f.cv_rms < (1 - 2 * opt.min_relative_gain) * ref.cv_rms
        proven = p < opt.alpha_heldout / max(len(probes), 1) and p0 < opt.alpha_heldout and f.bic < cur.bic
        weak_name = (best is not None and best_p > opt.weak_alpha
                     and p0 < opt.alpha_heldout / max(len(probes), 1) and f.bic < best.bic)
        if (proven or weak_name) and gain_vs_ref:
            unit = poses.length_unit
            what = ("changes with time" if "time" in probe.where else
                    "moves each marker on its own with the pose" if "markers" in probe.where else
                    "varies smoothly over the workspace")
            named = "" if best is None else f" better than the best named effect ({best.terms[-1].effect}, " \
                f"{_fmt_rms(best.cv_rms, unit)})"
            return (Finding(
                effect="unexplained", where=dict(probe.where), parameters={}, heldout_rms_before=cur.cv_rms,
                heldout_rms_after=f.cv_rms, p_heldout=p0, bic_change=float(f.bic - cur.bic),
                evidence=(f"a generic model in which the pose error {what} predicts held-out poses at "
                          f"{_fmt_rms(f.cv_rms, unit)} against {_fmt_rms(cur.cv_rms, unit)}{named} "
                          f"(paired Wilcoxon p = {p:.2g}); no effect in the library matches it")), f)
    return None

def _without(spec: PlatformSpec, poses: PoseSet, cur: Fit, drop: set[int], opt: Options) -> Fit:
    """``cur`` refitted without its terms at the indices ``drop``, with its K-fold held-out errors."""
    thetas = cur.problem.split(cur.z)[4]
    start = cur.problem.i_theta.start
    keep = [k for k in range(len(cur.terms)) if k not in drop]
    z = np.concatenate([cur.z[:start]] + [np.asarray(thetas[k], float) for k in keep])
    active = np.concatenate([cur.active[:start]] + [np.ones(len(thetas[k]), bool) for k in keep])
    f = _fit(spec, poses, [cur.terms[k] for k in keep], z, active, cur.weights, opt.lm_iterations, opt.robust)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    return f


def _unnamed(findings: list[Finding], accepted_info: list[dict], gone: set[int]) -> tuple[list[Finding], list[dict]]:
    """The findings, and the accepted terms' fit records (one per modelled finding, in order),
    without those whose term's id is in ``gone``."""
    modelled = [f for f in findings if f.term is not None]
    info = [x for f, x in zip(modelled, accepted_info) if id(f.term) not in gone]
    return [f for f in findings if f.term is None or id(f.term) not in gone], info


def _unproven_beside_probe(spec: PlatformSpec, poses: PoseSet, probed: Fit, first: int, last: int,
                           judged: np.ndarray, opt: Options) -> dict[int, float]:
    """{index: paired p} of the named terms ``probed.terms[first:last]`` that do not predict the
    held-out settled poses significantly better (paired Wilcoxon at ``alpha_heldout``) in the
    model that also holds the generic probe which still beats the named model (``probed``, the
    probe last): each was a slice of that structure, not an effect of its own."""
    loose = {}
    for k in range(first, last):
        wo = _without(spec, poses, probed, {k}, opt)
        rows = judged & np.isfinite(wo.cv) & np.isfinite(probed.cv)
        p = paired_improvement(wo.cv[rows], probed.cv[rows])
        if not (_rms(probed.cv, rows) < _rms(wo.cv, rows) and p < opt.alpha_heldout):
            loose[k] = float(p)
    return loose


def _unproven_beside_time(spec: PlatformSpec, poses: PoseSet, cur: Fit, first: int, floor: float,
                          judged: np.ndarray, weights: np.ndarray, opt: Options) -> tuple[dict[int, float], dict]:
    """({index: paired p} of the named terms ``cur.terms[first:]`` that do not predict held-out
    settled poses significantly better beside a model of the structure in time, that model's
    description) when the named model still predicts held-out poses at more than
    ``lack_of_fit_factor`` times the noise floor and the location tests find its residuals
    structured along time (autocorrelation or runs, at ``alpha * 0.1`` after adjustment); else
    ({}, {}).

    The location tests, not held-out prediction, prove the structure is there: a weak sway needs
    a time resolution the probe cannot afford on few poses and predicts no better than a chance
    slice of it. The model of it is the time probe whose resolution (6 bins up to a quarter of the
    poses) predicts held-out poses best. A named term that proves nothing beside it was a slice of
    that structure."""
    if not _rms(cur.cv, judged) > opt.lack_of_fit_factor * floor:
        return {}, {}
    left = located(locate(cur.r, poses, spec, weights, opt.alpha), opt.alpha * 0.1)
    in_time = [x for x in left if x.detail.get("order") == "time"]
    if not in_time:
        return {}, {}
    best = None
    for bins in range(6, poses.n_poses // 4 + 1, 2):
        probe = time_probe(poses, bins)
        if probe is None:
            break
        f = _fit(spec, poses, cur.terms + [probe], cur.z, cur.active, cur.weights, opt.lm_iterations, opt.robust)
        f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
        if best is None or _rms(f.cv, judged) < _rms(best[1].cv, judged):
            best = (bins, f)
    if best is None:
        return {}, {}
    loose = _unproven_beside_probe(spec, poses, best[1], first, len(cur.terms), judged, opt)
    return loose, {"located": f"{in_time[0].test} ({', '.join(f'{k} {v}' for k, v in in_time[0].where.items())}), "
                              f"adjusted p = {in_time[0].p_adjusted:.2g}",
                   "time_bins": best[0], "heldout_rms_with_it": _rms(best[1].cv, judged)}


def _weak_beside_lack_of_fit(cur: Fit, poses: PoseSet, spec: PlatformSpec, findings: list[Finding], floor: float,
                             judged: np.ndarray, weights: np.ndarray, n_prior: int, opt: Options) -> set[int]:
    """The indices (into ``cur.terms``) of the named terms proven only weakly (held-out paired p
    above ``alpha_heldout * weak_separability_factor``) in a model that still predicts held-out
    poses at more than ``lack_of_fit_factor`` times the noise floor with structure located in its
    residuals: each explains a slice of something the library does not hold. Empty otherwise."""
    if not _rms(cur.cv, judged) > opt.lack_of_fit_factor * floor:
        return set()
    level = opt.weak_alpha
    p_of = {id(f.term): f.p_heldout for f in findings if f.term is not None}
    weak = {k for k in range(n_prior, len(cur.terms)) if p_of.get(id(cur.terms[k]), 0.0) > level}
    if not weak or not located(locate(cur.r, poses, spec, weights, opt.alpha), opt.alpha * 0.1):
        return set()
    return weak


def _take_back(cur: Fit, taken: dict[int, float | None], round_name: str, about: dict[str, Any],
               why: Callable[[float | None], str], findings: list[Finding], accepted_info: list[dict],
               rounds: list[dict], say: Callable[[str], None],
               tail: str = "a slice of physics the library does not hold") -> tuple[list[Finding], list[dict]]:
    """Takes back the names of the terms ``cur.terms[k]`` for k in ``taken`` (k -> the paired p of
    the test that took it back, or None): a round ``round_name`` in ``rounds`` (their names, the
    paired p-values if any, then ``about``), one progress line each (``why(p)``, then ``tail``: what
    the term had taken), and the findings and fit records without them (the caller refits the model
    without the terms)."""
    ks = sorted(taken)
    names = [f"{cur.terms[k].effect} ({_where_text(cur.terms[k].where)})" for k in ks]
    entry: dict[str, Any] = {"round": round_name, "not_named": names}
    if any(taken[k] is not None for k in ks):
        entry["paired_p"] = {n: taken[k] for n, k in zip(names, ks)}
    rounds.append({**entry, **about})
    for n, k in zip(names, ks):
        say(f"{n}: {why(taken[k])}: {tail}; not named")
    return _unnamed(findings, accepted_info, {id(cur.terms[k]) for k in ks})
