"""One round of the diagnosis search, step by step: the score test that screens every candidate
term (:func:`screen`), the fit of the best variant of a kind and place (:func:`best_variant`), the
variants of terms accepted earlier chosen again beside a later one (:func:`variants_again`), the
held-out confirmation that accepts one (:func:`confirm`), the effects said beside it
(:func:`equally_good`) and why none was accepted (:func:`not_accepted`). The search that runs
the rounds is platkit.diagnose.search."""
from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

import numpy as np

from platkit.calibrate.problem import CalibrationProblem
from platkit.calibrate.solve import blas_threads
from platkit.diagnose.bodies import screen_system
from platkit.diagnose.fitting import Fit, Options, _cv, _fit, _later, _rms, _swapped, _where_text, body_residuals
from platkit.diagnose.stats import column_basis, outside_basis, paired_improvement, score_test
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["screen", "place", "best_variant", "variants_again", "confirm", "equally_good", "not_accepted"]


def screen(fit: Fit, spec: PlatformSpec, poses: PoseSet,
           candidates: list[ModelTerm]) -> list[tuple[float, float, float, np.ndarray]]:
    """Score test of each candidate at the current fit: [(F, p, separability, J columns (N, M, 3, k))].

    The decompositions run on one BLAS thread, as the estimator's products do
    (platkit.calibrate.solve.blas_threads): a hundred SVDs of thousands of rows by a few columns,
    which worker threads only make spin. The candidates' columns are taken outside the base's
    span (:func:`platkit.diagnose.stats.outside_basis`) SCREEN_COLUMNS at a time, consecutive
    candidates together (a candidate wider than that alone), not candidate by candidate."""
    if not candidates:
        return []
    problem = CalibrationProblem(spec, poses, fit.terms + list(candidates))
    z = np.concatenate([fit.z, np.concatenate([np.asarray(c.initial, float) * 0 for c in candidates])])
    with blas_threads(1):
        st = problem.evaluate(z, with_jac=True)
        n_base = len(fit.z)
        r, J = screen_system(poses, fit.weights, fit.r, st.J)
        Jb = J[:, :n_base][:, fit.active]
        dof = len(r) - int(fit.active.sum())
        basis = column_basis(Jb)
        out, k = [], n_base
        widths = [len(c.initial) for c in candidates]
        for group in _groups(widths, SCREEN_COLUMNS):
            k0 = k
            projected = outside_basis(basis, J[:, k0:k0 + sum(widths[i] for i in group)])
            for i in group:
                K = widths[i]
                F, p, sep = score_test(r, Jb, J[:, k:k + K], dof, basis=basis, projected=projected[:, k - k0:k - k0 + K])
                out.append((F, p, sep, st.J[..., k:k + K]))
                k += K
    return out


#: candidates' columns taken outside the base's span together in :func:`screen` (5,400 rows x 64:
#: 2.8 MB, the size of the tree's basis)
SCREEN_COLUMNS = 64


def _groups(widths: Sequence[int], most: int) -> list[list[int]]:
    """The indices of ``widths`` in order, in runs whose widths sum to at most ``most`` (a width
    over it alone)."""
    groups: list[list[int]] = []
    total = most + 1
    for i, w in enumerate(widths):
        if total + w > most:
            groups.append([])
            total = 0
        groups[-1].append(i)
        total += w
    return groups


def place(term: ModelTerm) -> tuple:
    """(effect, actuator or joint, marker or rigid body): terms of one kind at one place compete, never add up."""
    w = term.where
    actuator = str(w.get("actuator", w.get("joint", "")))
    return term.effect, "" if actuator == "all" else actuator, str(w.get("marker", w.get("rigid_body", "")))

def best_variant(i0: int, cands: list, scr: list, cur: Fit, spec: PlatformSpec, poses: PoseSet,
                  weights: np.ndarray, opt: Options) -> tuple[int, Fit]:
    """The variant of candidate ``i0``'s kind and place (a cooling time constant, a period, a
    slip's row) that fits best, as (index, fit). The score test ranks them at zero effect; a large
    effect may fit another better. ``opt.max_variants`` spread over them (in the library's order,
    ``i0`` among them) are fitted, then the neighbours of the lowest BIC until it is a minimum.

    An effect that extrapolates in time (``Effect.forecast``) has forms (``where['form']``): the
    best variant of each form by BIC, then the form that predicts the later part of the session
    best (fitting._later, each fit's ``later``; ``cur.later`` is set beside them)."""
    same = [j for j in range(len(cands)) if place(cands[j][1]) == place(cands[i0][1])
            and scr[j][2] >= opt.min_separability]
    if i0 not in same:
        same.append(i0)
    if not cands[i0][0].forecast:
        return _lowest_bic(i0, same, cands, cur, spec, poses, weights, opt)
    forms: dict[str, list[int]] = {}
    for j in same:
        forms.setdefault(str(cands[j][1].where.get("form", "")), []).append(j)
    if cur.later is None:
        cur.later = _later(cur, spec, poses, opt.later_share, opt.lm_iterations)
    best: list[tuple[int, Fit]] = []
    for members in forms.values():
        first = i0 if i0 in members else members[0]
        j, f = _lowest_bic(first, members, cands, cur, spec, poses, weights, opt)
        f.later = _later(f, spec, poses, opt.later_share, opt.lm_iterations)
        best.append((j, f))
    return min(best, key=lambda jf: (np.nan_to_num(jf[1].later, nan=np.inf), jf[1].bic))


def _lowest_bic(i0: int, same: list[int], cands: list, cur: Fit, spec: PlatformSpec, poses: PoseSet,
                weights: np.ndarray, opt: Options) -> tuple[int, Fit]:
    """Of the candidates ``same`` (``i0`` among them), the one of lowest BIC: spread fits, then
    the neighbours of the lowest until it is a minimum (see :func:`best_variant`)."""
    return _descend(i0, same, lambda j: _fit(spec, poses, cur.terms + [cands[j][1]], cur.z, cur.active, weights,
                                             opt.lm_iterations, opt.robust), opt.max_variants, {})


def _descend(i0: int, same: list[int], fit_one, max_variants: int, fits: dict[int, Fit]) -> tuple[int, Fit]:
    """Of ``same`` (``i0`` among them, in the library's order), the one of lowest BIC: ``max_variants``
    spread over them and ``i0`` fitted (``fit_one(j)``, unless in ``fits`` already), then the
    neighbours of the lowest until it is a minimum."""
    pick = {int(same[int(round(x))]) for x in np.linspace(0, len(same) - 1, max(1, min(max_variants, len(same))))}
    pick.add(i0)
    fits = dict(fits)
    while True:
        for j in pick - set(fits):
            fits[j] = fit_one(j)
        best = min(fits, key=lambda j: fits[j].bic)
        b = same.index(best)
        pick = {same[k] for k in (b - 1, b + 1) if 0 <= k < len(same)} - set(fits)
        if not pick:
            return best, fits[best]


def variants_again(cur: Fit, first: int, library: dict, spec: PlatformSpec, poses: PoseSet, weights: np.ndarray,
                   judged: np.ndarray, opt: Options, margin: float) -> tuple[Fit, list[dict[str, Any]]]:
    """The variant (a cooling time constant, a period, a slip's row) of each term accepted before
    the last one, ``cur.terms[first:-1]``, chosen again beside the terms accepted after it. A
    term's variant was chosen in its own round (:func:`best_variant`), with the effects named
    later still in the residual, which can pull it far from where the data put it once they are
    modelled. Each term's variants of its kind, place and form (the library's candidates, at the
    current fit) are fitted in its place, every other term kept, spread then the neighbours of the
    lowest BIC (as best_variant); the lowest replaces the term where its BIC is lower by ``margin``
    (a tie would trade a variant for one the data do not tell from it) and its K-fold held-out
    errors on the ``judged`` poses are not worse than the model's (paired Wilcoxon at
    ``alpha_heldout``: held-out prediction decides). A term whose own variant is not among the
    candidates (a form told apart since) is left as it is.

    Returns the model (``cur`` itself where nothing changed; the new model with its ``cv``) and,
    per term replaced, {"term": its index, "before", "after": the two terms, "bic_change",
    "heldout_rms_before", "heldout_rms_after", "p_worse", "J": the new term's Jacobian columns
    (N, M, 3, K) at the new fit}."""
    notes: list[dict[str, Any]] = []
    for k in range(first, len(cur.terms) - 1):
        term = cur.terms[k]
        eff = library.get(term.effect)
        if eff is None:
            continue
        variants = [c for c in eff.candidates(spec, poses, body_residuals(cur, poses))
                    if place(c) == place(term) and c.where.get("form") == term.where.get("form")]
        own = [j for j, c in enumerate(variants) if repr(c.where) == repr(term.where)]  # arrays in a where
        if len(variants) < 2 or not own:
            continue
        fit_one = partial(_in_place, cur, k, variants, spec, poses, weights, opt)
        j, f = _descend(own[0], list(range(len(variants))), fit_one, opt.max_variants, {own[0]: cur})
        if j == own[0] or f.bic >= cur.bic - margin:
            continue
        if cur.cv is None:
            cur.cv = _cv(cur, spec, poses, opt.folds, opt.lm_iterations)
        f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
        p_worse = paired_improvement(f.cv[judged], cur.cv[judged])
        if p_worse < opt.alpha_heldout:
            continue
        J = f.problem.evaluate(f.z, with_jac=True).J
        assert J is not None
        notes.append({"term": k, "before": term, "after": variants[j], "bic_change": float(f.bic - cur.bic),
                      "heldout_rms_before": cur.cv_rms, "heldout_rms_after": f.cv_rms, "p_worse": float(p_worse),
                      "J": J[..., f.term_columns(k)]})
        cur = f
    return cur, notes


def _in_place(cur: Fit, k: int, variants: list[ModelTerm], spec: PlatformSpec, poses: PoseSet, weights: np.ndarray,
              opt: Options, j: int) -> Fit:
    """``cur`` refitted with ``variants[j]`` in place of its term ``k`` (that term's parameters
    started from the variant's initial values, every other unknown from ``cur``)."""
    terms, z, active = _swapped(cur, k, variants[j])
    return _fit(spec, poses, terms, z, active, weights, opt.lm_iterations, opt.robust)


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
    geometry as it is fitted, and its gain rests on the small part left), and a term whose held-out
    gain is under ``small_gain``. The latter is what a slice of structure the term does not
    describe gives: any term takes a little of an unmodelled lack of fit, and the candidate tested
    is the winner of the screening and of the refits."""
    for k, (i, f, p_h) in enumerate(sorted(trials, key=lambda x: x[1].bic)):
        if _failed(f, p_h, separability[i], cur, judged, opt, share=len(trials) if k > 0 else 1) is None:
            return i, f, p_h
    return None


def equally_good(i: int, best: Fit, trials: list[tuple[int, Fit, float]], cands: list,
                  separability: Sequence[float], cur: Fit, judged: np.ndarray, opt: Options) -> list[dict[str, Any]]:
    """The other effects of the round at the accepted candidate ``i``'s actuator or marker that
    :func:`confirm` would accept on their own and that predict the held-out ``judged`` poses as
    well: the accepted one is not significantly better (paired Wilcoxon at ``alpha_heldout``).
    On this plan the name is one of them."""
    where = place(cands[i][1])[1:]
    out = []
    for j, f, p_h in trials:
        eff, term = cands[j]
        if j == i or eff.name == cands[i][0].name or place(term)[1:] != where or not any(where):
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
    if f.later is not None and cur.later is not None and np.isfinite(cur.later) and not f.later <= cur.later:
        return (f"it predicts the later {100 * opt.later_share:g}% of the session, held out, "
                f"{f.later / cur.later:.2f} times as far off as the model without it")
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


def not_accepted(trials: list[tuple[int, Fit, float]], cands: list, separability: Sequence[float], cur: Fit,
                  judged: np.ndarray, opt: Options) -> str:
    """Why the candidate the information criterion prefers was not accepted, in a sentence."""
    i, f, p_h = min(trials, key=lambda x: x[1].bic)
    return f"{cands[i][0].name} ({_where_text(cands[i][1].where)}): not accepted, " + \
        str(_failed(f, p_h, separability[i], cur, judged, opt))
