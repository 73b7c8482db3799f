"""The take-back steps of the diagnosis search, after its rounds: names the final model does not
need, tested again by removal (:func:`take_back_unneeded`), names weakly proven beside a
lack of fit the model still leaves (:func:`take_back_weak`), names that no longer prove themselves
beside a generic probe that still beats the named model (:func:`take_back_beside_probe`) or beside
a model of the structure in time the location tests still find (:func:`take_back_beside_time`).
Each takes the names back from a :class:`platkit.diagnose.search.Search`, said in its rounds
(naming._take_back); the tests themselves live in naming.py."""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from platkit.diagnose.fitting import ROUND_BESIDE_PROBE, ROUND_BESIDE_TIME, ROUND_BY_REMOVAL, ROUND_WEAK_NAMES, Fit, _rms
from platkit.diagnose.naming import (
    _best_probe,
    _take_back,
    _unproven_beside_probe,
    _unproven_beside_time,
    _weak_beside_lack_of_fit,
    _without,
)
from platkit.diagnose.stats import paired_improvement

if TYPE_CHECKING:
    from platkit.diagnose.search import Search

__all__ = ["take_back", "unneeded", "take_back_unneeded", "take_back_weak", "take_back_beside_probe",
           "take_back_beside_time"]


def take_back(search: Search, taken: dict[int, float | None], round_name: str, about: dict[str, Any],
              why: Callable[[float | None], str], tail: str | None = None) -> None:
    """Take back the names of ``search.cur.terms[k]`` for k in ``taken`` (naming._take_back;
    ``tail``: what the terms had taken, said after ``why``, default naming's)."""
    more = {} if tail is None else {"tail": tail}
    search.findings, search.accepted = _take_back(search.cur, taken, round_name, about, why, search.findings,
                                                  search.accepted, search.rounds, search.say, **more)


def unneeded(search: Search) -> tuple[int, float, Fit] | None:
    """The named term of ``search.cur`` (those the search added) that the final model needs least,
    as (its index, the paired p of the model with it against the model without it, that model), if
    the model with it does not predict the held-out ``judged`` poses better, significantly (paired
    Wilcoxon at ``alpha_heldout``, the level it was accepted at) and in RMS; else None."""
    cur, opt = search.cur, search.opt
    worst: tuple[int, float, Fit] | None = None
    for k in range(len(search.prior), len(cur.terms)):
        wo = _without(search.spec, search.poses, cur, {k}, opt)
        rows = search.judged & np.isfinite(wo.cv) & np.isfinite(cur.cv)
        p = paired_improvement(wo.cv[rows], cur.cv[rows])
        if _rms(cur.cv, rows) < _rms(wo.cv, rows) and p < opt.alpha_heldout:
            continue
        if worst is None or p > worst[1]:
            worst = (k, float(p), wo)
    return worst


def take_back_unneeded(search: Search) -> None:
    """Each name tested again by removal, after the rounds: a term accepted in an early round was
    proven against the model of its round, with the effects named later still in the residual, and
    one of those can describe what it took better (two shapes along one actuator's travel: a
    periodic error of a period near the stroke and a smooth travel error). While two or more terms
    are named and one is not needed by the model (:func:`unneeded`), the one needed least is taken
    back (a round ROUND_BY_REMOVAL with its paired p) and the model refitted without it; the others
    are then tested again beside the smaller model. A term named alone was proven against the model
    without it in its own round."""
    while search.naming and len(search.cur.terms) - len(search.prior) >= 2:
        loose = unneeded(search)
        if loose is None:
            return
        k, p, wo = loose
        take_back(search, {k: p}, ROUND_BY_REMOVAL, {}, lambda p: (
            f"the model without it predicts held-out poses as well (paired p = {p:.2g})"),
            tail="what it took is described by the other effects named")
        search.cur = wo


def take_back_weak(search: Search) -> None:
    """Weakly proven names beside a lack of fit the model still leaves (naming._weak_beside_lack_of_fit)."""
    opt = search.opt
    if not search.naming or search.floor is None or len(search.cur.terms) <= len(search.prior):
        return
    weak = _weak_beside_lack_of_fit(search.cur, search.poses, search.spec, search.findings, search.floor,
                                    search.judged, search.weights, len(search.prior), opt)
    if weak:
        take_back(search, dict.fromkeys(weak), ROUND_WEAK_NAMES, {}, lambda p: (
            f"proven only weakly, and the model still predicts held-out poses at more than "
            f"{opt.lack_of_fit_factor:g} times the noise floor with structure located"))
        search.cur = _without(search.spec, search.poses, search.cur, weak, search.opt)


def take_back_beside_probe(search: Search) -> None:
    """Structure a generic probe still predicts better at the end: a named term that no longer
    proves itself beside the probe was a slice of that structure (tested before the final fit)."""
    opt = search.opt
    search.end_probe = _best_probe(search.spec, search.poses, search.cur, None, opt) \
        if search.naming and opt.probes else None
    if search.end_probe is None or len(search.cur.terms) <= len(search.prior):
        return
    loose = _unproven_beside_probe(search.spec, search.poses, search.end_probe[1], len(search.prior),
                                   len(search.cur.terms), search.judged, opt)
    reduced = _without(search.spec, search.poses, search.cur, set(loose), opt) if loose else None
    again = _best_probe(search.spec, search.poses, reduced, None, opt) if reduced is not None else None
    if again is not None:
        take_back(search, loose, ROUND_BESIDE_PROBE, {}, lambda p: (
            f"no longer predicts held-out poses better beside the generic model that still beats the named "
            f"ones (paired p = {p:.2g})"))
        search.cur, search.end_probe = reduced, again


def take_back_beside_time(search: Search) -> None:
    """No probe beats the named model, but the location tests still find structure in time
    beside a lack of fit: each name is tested beside a model of it."""
    opt = search.opt
    if search.end_probe is not None or not search.naming or not opt.probes or search.floor is None \
            or len(search.cur.terms) <= len(search.prior):
        return
    loose, about = _unproven_beside_time(search.spec, search.poses, search.cur, len(search.prior), search.floor,
                                         search.judged, search.weights, opt)
    if loose:
        take_back(search, loose, ROUND_BESIDE_TIME, about, lambda p: (
            f"no longer predicts held-out poses better (paired p = {p:.2g}) beside a model of the structure "
            f"in time the location tests still find ({about['located']})"))
        search.cur = _without(search.spec, search.poses, search.cur, set(loose), opt)
        search.end_probe = _best_probe(search.spec, search.poses, search.cur, None, opt)
