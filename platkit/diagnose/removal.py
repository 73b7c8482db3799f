"""Each name tested again by removal, after the search's rounds: a term accepted in an early round
was proven against the model of its round, with the effects named later still in the residual. One
of those can describe what it took better (two shapes along one actuator's travel: a periodic error
of a period near the stroke and a smooth travel error), so each named term must still predict the
held-out settled poses better than the final model without it (:func:`take_back_unneeded`)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from platkit.diagnose.fitting import Fit, _rms, _where_text
from platkit.diagnose.naming import _unnamed, _without
from platkit.diagnose.stats import paired_improvement

if TYPE_CHECKING:
    from platkit.diagnose.search import Search

__all__ = ["ROUND_BY_REMOVAL", "unneeded", "take_back_unneeded"]

#: the round of diagnosis.json that lists the names taken back by removal
ROUND_BY_REMOVAL = "by removal"


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
    """Backward steps after the rounds: while two or more terms are named and one is not needed by
    the model (:func:`unneeded`), the one needed least is taken back and the model refitted without
    it (a round of diagnosis.json says which, with its paired p); the others are then tested again
    beside the smaller model. A term named alone was proven against the model without it in its
    own round."""
    while search.naming and len(search.cur.terms) - len(search.prior) >= 2:
        loose = unneeded(search)
        if loose is None:
            return
        k, p, wo = loose
        name = f"{search.cur.terms[k].effect} ({_where_text(search.cur.terms[k].where)})"
        search.rounds.append({"round": ROUND_BY_REMOVAL, "not_named": [name], "paired_p": {name: p}})
        search.say(f"{name}: the model without it predicts held-out poses as well (paired p = {p:.2g}): "
                   "what it took is described by the other effects named; not named")
        search.findings, search.accepted = _unnamed(search.findings, search.accepted, {id(search.cur.terms[k])})
        search.cur = wo
