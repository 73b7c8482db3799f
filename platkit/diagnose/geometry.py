"""The geometry chosen again during the search: the groups a calibration held freed again before a
term mostly inside the geometry is named (:func:`_reopened`), and the model selection made again
beside an accepted effect, the stand's or a recording artefact's (:func:`_reselected`)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.selection import parameter_groups, reselect_geometry
from platkit.diagnose.fitting import Fit, Options, _cv, _cv_channels, _fit, _fmt_rms, _kept_channels, _per_pose, _rms
from platkit.diagnose.stats import paired_improvement
from platkit.model import PlatformSpec
from platkit.poses import PoseSet


def _reopened(spec: PlatformSpec, poses: PoseSet, cur: Fit, free: Sequence[str] | None, judged: np.ndarray,
              opt: Options, platform_options: dict | None) -> tuple[Fit, list[str], dict] | None:
    """The model with the parameter groups held by the calibration freed again, as (fit, free
    names, note), when it predicts the held-out ``judged`` poses better than ``cur`` (lower BIC, a
    held-out gain of ``min_relative_gain``, paired p < ``alpha_heldout``); else None.

    A calibration's model selection scores the groups with every effect still in the residual:
    a large one (a gear's cyclic error) hides what a held group (the rod lengths) would explain,
    and an effect mostly inside the geometry (a scale nonlinearity) would be named in its place.
    Tried once, when such a term (separability under ``warn_separability``) is about to be
    accepted: where none is, the search costs nothing more."""
    if free is None:
        return None
    groups = parameter_groups(spec)
    held = [g for g, names in groups.items() if not set(names) & set(free)]
    if not held:
        return None
    trial = list(free) + [n for g in held for n in groups[g]]
    td_now = cur.problem.split(cur.z)[0]
    cal = calibrate(poses, spec, terms=cur.terms, free=trial, td_start=td_now, robust=opt.robust,
                    platform_options=platform_options)
    f = _fit(spec, poses, cur.terms, cal.fit.z, cal.fit.active, cur.weights, opt.lm_iterations, opt.robust)
    f.cv = _cv(f, spec, poses, opt.folds, opt.lm_iterations)
    p = paired_improvement(cur.cv[judged], f.cv[judged])
    before, after = _rms(cur.cv, judged), _rms(f.cv, judged)
    if not (f.bic < cur.bic and after < (1 - opt.min_relative_gain) * before and p < opt.alpha_heldout):
        return None
    unit = poses.length_unit
    text = (f"geometry: {', '.join(held)} freed again (held by the calibration, chosen with the effect still in the "
            f"residual): held-out RMS {_fmt_rms(before, unit)} -> {_fmt_rms(after, unit)} (paired p = {p:.2g}); "
            "--keep-geometry keeps the calibration's free set")
    return f, trial, {"groups": held, "heldout_rms_before": before, "heldout_rms_after": after, "p_heldout": float(p),
                      "text": text}

def _reselected(spec: PlatformSpec, poses: PoseSet, cur: Fit, free: Sequence[str] | None, judged: np.ndarray,
                opt: Options, platform_options: dict | None, after: str) -> tuple[Fit | None, list[str], dict] | None:
    """After an effect (``after``, as the note names it) is accepted, the stand's or a recording
    artefact corrected in the data, the geometry's model selection made again beside the accepted terms
    (platkit.calibrate.selection.reselect_geometry), as (fit, free names, note), when it chooses
    another free set that predicts the held-out ``judged`` poses no worse than ``cur``, in all and
    on every tracked link; (None, ``free``, note) when it predicts a tracked link worse (the free
    set in force kept); else None. A group chosen with the physics still in the residual
    may stand in for it (a torso joint's scale for its gravity sag): beside the physics it no longer
    earns its place. A group held while an artefact's residual swamped it (a rigid body's slip of
    millimetres) is freed beside the artefact's term. But a group shared by the branches may stand
    in for physics the accepted terms do not model (the torso's sag seen from the other arm):
    holding it then predicts that branch's link worse, and the new free set is not taken."""
    if free is None:
        return None
    cal = reselect_geometry(poses, spec, cur.terms, robust=opt.robust, platform_options=platform_options)
    chosen = [n for n, st in zip(spec.parameter_names, cal.td_status) if st == "estimated"]
    if set(chosen) == set(free):
        return None
    f = _fit(spec, poses, cur.terms, cal.fit.z, cal.fit.active, cur.weights, opt.lm_iterations, opt.robust)
    ch = _cv_channels(f, spec, poses, opt.folds, opt.lm_iterations)
    f.cv = _per_pose(ch)
    before, now = _rms(cur.cv, judged), _rms(f.cv, judged)
    if not now <= before:
        return None
    sel = cal.identifiability.get("model_selection") or {}
    unit = poses.length_unit
    groups = (f"free {', '.join(sel.get('chosen', [])) or 'none'} (held {', '.join(sel.get('held', [])) or 'none'})")
    note = {"after": after, "chosen": list(sel.get("chosen", [])), "held": list(sel.get("held", [])),
            "heldout_rms_before": before, "heldout_rms_after": now}
    ch_cur = _kept_channels(cur, poses, opt.folds, opt.lm_iterations)  # what cur.cv was computed from
    if ch_cur is None:
        ch_cur = _cv_channels(cur, spec, poses, opt.folds, opt.lm_iterations)
    worse = [w for w in per_link_change(ch_cur, ch, poses, judged) if w["heldout_rms_after"] > w["heldout_rms_before"]]
    if worse:
        said = ", ".join(f"{w['link']} {_fmt_rms(w['heldout_rms_before'], unit)} -> "
                         f"{_fmt_rms(w['heldout_rms_after'], unit)}" for w in worse)
        note.update(links_worse=worse, text=f"geometry chosen again beside {after}: {groups} not taken: it predicts "
                    f"a tracked link worse held out ({said}); the free set in force kept")
        return None, list(free), note
    note["text"] = (f"geometry chosen again beside {after}: {groups}, held-out RMS {_fmt_rms(before, unit)} -> "
                    f"{_fmt_rms(now, unit)}; --keep-geometry keeps the calibration's free set")
    return f, chosen, note

def _channel_links(poses: PoseSet) -> list[str]:
    """The tracked link of each positional channel of a fit's residuals: the markers, then the
    rigid bodies' positions (their rotations, in another unit, follow them and are not counted)."""
    return [poses.marker_links[m] for m in poses.marker_names] + [poses.marker_links[b] for b in poses.body_names]

def per_link_change(before: np.ndarray, after: np.ndarray, poses: PoseSet, judged: np.ndarray) -> list[dict]:
    """On a tree, each tracked link's held-out RMS (m) over the ``judged`` poses under two models, from
    their (N, C) held-out squared errors per channel (fitting._cv_channels), as {link,
    heldout_rms_before, heldout_rms_after}; [] where every marker rides on one moving link (the
    pooled error is then that link's)."""
    if not poses.marker_links:
        return []
    links = _channel_links(poses)
    out = []
    for link in dict.fromkeys(links):
        on = np.array([x == link for x in links] + [False] * (before.shape[1] - len(links)))
        with np.errstate(invalid="ignore"):
            rms = [_rms(_per_pose(d2[:, on]), judged) for d2 in (before, after)]
        out.append({"link": link, "heldout_rms_before": rms[0], "heldout_rms_after": rms[1]})
    return out
