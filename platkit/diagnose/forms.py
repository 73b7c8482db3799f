"""The forms of an accepted term's physics told apart (a term's ``alternatives(theta, poses,
others)``: a joint's compliance or the bending of the link before it, as many parameters): each
form is fitted in the term's place, one at a time, and one whose BIC is lower by FORM_BIC_MARGIN
is kept (:func:`tell_apart`). The search that accepts the terms is platkit.diagnose.search."""
from __future__ import annotations

from typing import TYPE_CHECKING

from platkit.diagnose.fitting import Finding, Fit, _cv, _fit
from platkit.diagnose.rounds import screen

if TYPE_CHECKING:
    from platkit.diagnose.search import Search

__all__ = ["FORM_BIC_MARGIN", "tell_apart"]

#: a form of an accepted term is kept where its BIC is lower by this much (a tie is chance)
FORM_BIC_MARGIN = 2.0


def tell_apart(search: Search, finding: Finding, before: Fit) -> None:
    """The term ``search`` just accepted fitted in each other form of its physics it offers (a term's
    ``alternatives(theta, poses, others)``: a joint's compliance or the bending of the link
    before it, as many parameters), one at a time, each tried once; a form whose BIC is lower by
    FORM_BIC_MARGIN is kept (a tie would trade a place for one the data do not tell from it).
    ``before``: the model without it (the finding's signature columns are taken again there)."""
    opt, k = search.opt, len(search.cur.terms) - 1
    term = search.cur.terms[k]
    offered = getattr(term, "alternatives", None)
    tried: set[str] = set()
    notes: list[dict] = []
    while offered is not None:
        theta = search.cur.theta(k)
        forms = [(what, t) for what, t in offered(theta, search.poses, search.cur.terms[:k]) if what not in tried]
        if not forms:
            break
        what, alt = forms[0]
        tried.add(what)
        K = len(theta)
        f = _fit(search.spec, search.poses, search.cur.terms[:k] + [alt], search.cur.z[:-K], search.cur.active[:-K],
                 search.weights, opt.lm_iterations, opt.robust)
        kept = bool(f.bic < search.cur.bic - FORM_BIC_MARGIN)
        notes.append({"change": what, "bic_change": float(f.bic - search.cur.bic), "kept": kept})
        search.say(f"  {what}: BIC {f.bic - search.cur.bic:+.1f}{', kept' if kept else ''}")
        if kept:
            search.cur, term, offered = f, alt, getattr(alt, "alternatives", None)
    if notes:
        search.rounds[-1]["told_apart"] = notes
    if term is finding.term:
        return
    search.cur.cv = _cv(search.cur, search.spec, search.poses, opt.folds, opt.lm_iterations)
    finding.term, finding.where = term, dict(term.where)
    finding.heldout_rms_after = search.cur.cv_rms
    finding.bic_change = float(search.cur.bic - before.bic)
    search.accepted[-1] = {"fit": search.cur, "J": screen(before, search.spec, search.poses, [term])[0][3]}
