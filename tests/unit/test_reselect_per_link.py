"""The geometry's model selection made again after an effect is accepted is taken only where it
predicts no tracked link worse in K-fold: on a tree, a group shared by the branches (a torso
joint's scale) may stand in for physics the accepted term does not model, and holding it trades
one hand for the other while the pooled error still falls (issue 24, iCub seed 25101)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from platkit.diagnose import geometry
from platkit.diagnose.fitting import Diagnosis, Options
from platkit.diagnose.verdict import verdict
from platkit.poses import PoseSet

N = 20
NAMES = ["L1", "L2", "R1", "R2"]


def _poses(tree: bool) -> PoseSet:
    links = {"L1": "l_hand", "L2": "l_hand", "R1": "r_hand", "R2": "r_hand"} if tree else {}
    return PoseSet("urdf", np.zeros((N, 2)), np.zeros((N, 4, 3)), list(NAMES), marker_links=links)


def _run(monkeypatch: pytest.MonkeyPatch, poses: PoseSet, left: float, right: float):
    """_reselected with the selection and the fits replaced: the calibration's model errs 1e-4 m on
    every marker held out; the reselected one ``left`` and ``right`` m on each hand's markers."""
    spec = SimpleNamespace(parameter_names=["a.scale", "a.origin"])
    cal = SimpleNamespace(td_status=["held", "estimated"], fit=SimpleNamespace(z=np.zeros(2), active=np.ones(2, bool)),
                          identifiability={"model_selection": {"chosen": ["origin"], "held": ["scale"]}})
    cur = SimpleNamespace(terms=[], weights=np.ones((N, 4)), cv=np.full(N, 1e-8), name="cur")
    new = SimpleNamespace(cv=None, name="new")
    errs = {"cur": np.full((N, 4), 1e-8),
            "new": np.concatenate([np.full((N, 2), left**2), np.full((N, 2), right**2)], axis=1)}
    monkeypatch.setattr(geometry, "reselect_geometry", lambda *a, **k: cal)
    monkeypatch.setattr(geometry, "_fit", lambda *a, **k: new)
    monkeypatch.setattr(geometry, "_cv_channels", lambda fit, *a, **k: errs[fit.name])
    out = geometry._reselected(spec, poses, cur, ["a.scale", "a.origin"], np.ones(N, bool), Options(), None,
                               "compliance (joint j)")
    return out, new


def test_a_reselection_that_predicts_one_hand_worse_is_not_taken(monkeypatch):
    out, _ = _run(monkeypatch, _poses(tree=True), left=1.05e-4, right=0.85e-4)  # pooled error falls
    assert out is not None
    fit, free, note = out
    assert fit is None and free == ["a.scale", "a.origin"]
    assert [w["link"] for w in note["links_worse"]] == ["l_hand"]
    assert note["links_worse"][0]["heldout_rms_after"] == pytest.approx(1.05e-4)
    assert "l_hand" in note["text"] and "kept" in note["text"]


def test_a_reselection_that_predicts_every_hand_no_worse_is_taken(monkeypatch):
    out, new = _run(monkeypatch, _poses(tree=True), left=0.99e-4, right=0.85e-4)
    assert out is not None and out[0] is new and out[1] == ["a.origin"]
    assert "links_worse" not in out[2]


def test_one_moving_link_is_judged_on_the_pooled_error(monkeypatch):
    out, new = _run(monkeypatch, _poses(tree=False), left=1.05e-4, right=0.85e-4)
    assert out is not None and out[0] is new


def test_per_link_change_counts_each_links_markers():
    poses = _poses(tree=True)
    a = np.full((N, 4), 4e-8)
    b = a.copy()
    b[:, 2:] = 1e-8
    b[0, 0] = np.nan  # an unseen marker is left out, not counted as zero
    got = {w["link"]: (w["heldout_rms_before"], w["heldout_rms_after"])
           for w in geometry.per_link_change(a, b, poses, np.ones(N, bool))}
    assert got == {"l_hand": pytest.approx((2e-4, 2e-4)), "r_hand": pytest.approx((2e-4, 1e-4))}


def test_the_verdict_says_the_free_set_was_kept(monkeypatch):
    poses = _poses(tree=True)
    note = _run(monkeypatch, poses, left=1.05e-4, right=0.85e-4)[0][2]
    d = Diagnosis(findings=[], verdict="", calibration=None, base=None, locations=[], locations_before=[],
                  rounds=[{"round": 1, "geometry_kept": note}], not_separable=[], unit="mm", poses=poses)
    assert ("After compliance (joint j) was accepted, the geometry's model selection made again would free origin "
            "and hold scale, but it predicts l_hand worse held out: the free set in force is kept.") in verdict(d)
