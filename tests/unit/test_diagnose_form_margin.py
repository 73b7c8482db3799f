"""Diagnosis keeps another form of an accepted term (a joint's compliance told apart as its
parent's bending, and back) only where its BIC is lower by FORM_BIC_MARGIN
(platkit/diagnose/forms.py: tell_apart): a tie is chance, and on a humanoid's spherical
shoulder (iCub) a tie kept swapped the shoulder's named compliances for a bend the data could not
tell from them."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import platkit.diagnose.forms as forms


class _Term:
    def __init__(self, forms):
        self.forms, self.where = forms, {"joint": "every loaded joint (2)"}

    def alternatives(self, theta, poses, others):
        return self.forms


def _told(monkeypatch, bic_change: float):
    alt = SimpleNamespace(where={"joint": "every loaded joint (2)", "bends": ["l1"]})
    term = _Term([("l2's compliance told apart as link bending at l1", alt)])
    cur = SimpleNamespace(terms=[term], theta=lambda k: np.zeros(2), z=np.zeros(5), active=np.ones(5, bool),
                          bic=100.0, cv_rms=1.0)
    fit = SimpleNamespace(terms=[alt], bic=100.0 + bic_change, cv_rms=0.9)
    monkeypatch.setattr(forms, "_fit", lambda *a, **k: fit)
    monkeypatch.setattr(forms, "_cv", lambda *a, **k: None)
    monkeypatch.setattr(forms, "screen", lambda *a, **k: [(0.0, 1.0, 1.0, "J")])
    me = SimpleNamespace(opt=SimpleNamespace(lm_iterations=1, robust=False, folds=2), cur=cur, poses=None, spec=None,
                         weights=None, say=lambda m: None, rounds=[{}], accepted=[None])
    finding = SimpleNamespace(term=term, where=dict(term.where), heldout_rms_after=1.0, bic_change=0.0)
    forms.tell_apart(me, finding, cur)
    return me, finding, fit, alt


@pytest.mark.parametrize("change", [-0.04, -1.9])
def test_a_form_no_better_than_chance_is_not_kept(monkeypatch, change):
    me, finding, _, _ = _told(monkeypatch, change)
    assert me.rounds[-1]["told_apart"] == [{"change": "l2's compliance told apart as link bending at l1",
                                            "bic_change": pytest.approx(change), "kept": False}]
    assert "bends" not in finding.where


def test_a_form_the_data_choose_is_kept(monkeypatch):
    me, finding, fit, alt = _told(monkeypatch, -2.5)
    assert me.rounds[-1]["told_apart"][0]["kept"] and me.cur is fit and finding.term is alt
    assert finding.where["bends"] == ["l1"] and finding.heldout_rms_after == 0.9
