"""The outputs of a calibration: calibration.yaml, report.json and report.html (spec section 2).

``write_outputs(cal, poses, out_dir)`` writes the three files atomically (all or nothing), and for
a stand built from a URDF also ``calibrated.urdf`` (the estimate folded into the joint origins).
report.json: ``rms_before``, ``rms_after`` (the session's length unit), ``unit``, ``n_poses``,
``n_markers``, ``converged``, and more (held-out errors, identifiability, per-marker RMS, outliers).
report.html: one self-contained page, plots embedded as base64 PNG (matplotlib figures drawn by
Agg, without pyplot), or none with ``write_outputs(..., with_html=False)`` (``calibrate --no-report``).
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import yaml
from matplotlib.figure import Figure

from platkit.errors import BadInput
from platkit.io import jsonout
from platkit.io.atomic import atomic_output_dir
from platkit.io.calibration import Calibration, heldout_in_unit, write_calibration_yaml
from platkit.io.figures import png_base64
from platkit.io.urdf_export import export_calibrated_urdf
from platkit.kinematics import PlatformModel
from platkit.model import length_scale
from platkit.poses import PoseSet
from platkit.settle import settling_summary


def _finite_or_none(x):
    x = float(x)
    return x if np.isfinite(x) else None


def per_marker_rms(r: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """RMS (m) of the 3-D error per marker over the kept observations; r: (N, M, 3)."""
    d2 = np.sum(r ** 2, axis=2)
    keep = np.isfinite(d2) & (weights > 0 if weights is not None else True)
    out = np.full(r.shape[1], np.nan)
    for i in range(r.shape[1]):
        if keep[:, i].any():
            out[i] = np.sqrt(np.mean(d2[keep[:, i], i]))
    return out


def per_link_rms(residuals: np.ndarray, weights: np.ndarray | None, marker_names: list[str],
                 marker_links: dict[str, str], scale: float = 1.0) -> dict[str, float | None]:
    """{link: RMS of the 3-D marker errors of its markers} over the observations kept by the
    robust loss (weight > 0, finite), in ``residuals``' unit over ``scale``; links in the order
    first named, None for a link without a kept observation. ``residuals`` (N, C, 3): the markers'
    channels first (bodies after them are not counted)."""
    M = len(marker_names)
    r = np.asarray(residuals, float)[:, :M]
    keep = np.isfinite(r).all(axis=2)
    if weights is not None:
        keep &= np.asarray(weights)[:, :M] > 0
    d2 = np.sum(np.nan_to_num(r) ** 2, axis=2)
    out: dict[str, float | None] = {}
    for link in dict.fromkeys(marker_links[m] for m in marker_names if m in marker_links):
        on = np.array([marker_links.get(m) == link for m in marker_names])
        sel = keep[:, on]
        out[link] = _finite_or_none(np.sqrt(np.mean(d2[:, on][sel])) / scale) if sel.any() else None
    return out


def report_dict(cal: Calibration, poses: PoseSet | None = None, description: str | None = None) -> dict:
    """report.json as a dict; lengths in the session's unit (``unit``). ``description``: the
    description as calibration.yaml beside it names it (default the calibration's own)."""
    s = length_scale(cal.length_unit)
    ident = cal.identifiability or {}
    out = {
        "platform": cal.platform,
        "description": cal.description if description is None else description,
        "method": cal.method,
        "unit": cal.length_unit,
        "rms_before": _finite_or_none(cal.rms_before / s),
        "rms_after": _finite_or_none(cal.rms_after / s),
        "n_poses": int(cal.n_poses),
        "n_markers": int(cal.n_markers),
        "converged": bool(cal.converged),
        "iterations": int(cal.iterations),
        "n_observations": int(cal.n_observations),
        "n_rejected_as_outliers": int(cal.n_rejected),
        "noise_sigma_per_axis": _finite_or_none(cal.noise_sigma / s),
        "time_s": float(cal.time_s),
        "n_parameters_estimated": int(sum(1 for st in cal.td_status if st == "estimated")),
        "held_at_nominal": [h["name"] for h in ident.get("held_at_nominal", [])],
        "weakly_identified": list(ident.get("weakly_identified", [])),
        "at_plausible_limit": list(ident.get("at_plausible_limit", [])),
        "gauge": ident.get("gauge"),  # what no pose fixes, the conventions that fix it (docs/calibration.md)
        "model_selection": ident.get("model_selection"),  # which groups were freed, chosen by held-out prediction
        "warnings": list(cal.warnings),  # what to check before trusting the fit
        "rms_definition": "root mean square of the 3-D distance between predicted and measured markers, "
                          "over the observations kept by the robust loss",
    }
    if poses is not None:
        out["settling"] = settling_summary(poses, cal.length_unit)  # every command: kept, extrapolated, or dropped and why
    if cal.motion:  # calibrated from motion: which samples served, the actuators' response fitted
        out["motion"] = cal.motion
    if cal.fit is not None:
        after = cal.fit.residuals_after
        pm = per_marker_rms(after, cal.fit.weights)
        out["rms_after_per_marker"] = {n: _finite_or_none(v / s) for n, v in zip(channel_names(cal), pm)}
        if cal.marker_links:  # a tree: each tracked link's markers together (docs/trees.md)
            out["rms_after_per_link"] = per_link_rms(after, cal.fit.weights, cal.marker_names, cal.marker_links, s)
        d = np.linalg.norm(after, axis=2)
        out["max_error_after"] = _finite_or_none(np.nanmax(d) / s) if np.isfinite(d).any() else None
    if cal.heldout:
        out["heldout"] = heldout_in_unit(cal.heldout, cal.length_unit)
    if cal.paper:
        out["paper"] = cal.paper
    return out


# ---------------------------------------------------------------------------- plots


def _subplots(nrows: int = 1, ncols: int = 1, figsize=(6.4, 4.8), squeeze: bool = True,
              bottom_in: float = 0.55, left_in: float = 0.85, gap_in: float = 0.0):
    """(figure, axes) like pyplot.subplots, without pyplot: a bare Figure (no global figure
    registry, no GUI backend) with fixed margins in inches (``gap_in``: between rows and
    columns, for rotated tick labels), so that saving it draws it once: no layout engine and
    no tight bounding box, each of which costs a second drawing (the report was most
    of a small calibration's time)."""
    w, h = figsize
    fig = Figure(figsize=figsize)
    top_in, right_in = 0.25, 0.2
    axes_h = (h - bottom_in - top_in - (nrows - 1) * gap_in) / nrows
    axes_w = (w - left_in - right_in - (ncols - 1) * max(gap_in, 0.6)) / ncols
    fig.subplots_adjust(left=left_in / w, right=1 - right_in / w, bottom=bottom_in / h, top=1 - top_in / h,
                        hspace=gap_in / axes_h if nrows > 1 else 0.2, wspace=max(gap_in, 0.6) / axes_w)
    return fig, fig.subplots(nrows, ncols, squeeze=squeeze)


def _png(fig) -> str:
    return png_base64(fig, tight=False)


def _finite_row_mean(a: np.ndarray) -> np.ndarray:
    """Mean of each row's finite entries, NaN for a row with none (a pose the model could not
    predict), without numpy's warning about an empty mean."""
    ok = np.isfinite(a)
    n = ok.sum(axis=1)
    total = np.where(ok, a, 0.0).sum(axis=1)
    return np.divide(total, n, out=np.full(len(n), np.nan), where=n > 0)


def _plots(cal: Calibration, poses: PoseSet | None) -> list[tuple[str, str, str]]:
    """(title, caption, base64 png) for every plot the data allow."""
    s = length_scale(cal.length_unit)
    lu = cal.length_unit
    out = []
    if cal.fit is not None:
        before, after, w_after = cal.fit.residuals_before, cal.fit.residuals_after, cal.fit.weights
        fig, ax = _subplots(figsize=(9, 3.2))
        db = np.sqrt(_finite_row_mean(np.sum(before ** 2, axis=2))) / s
        da = np.sqrt(_finite_row_mean(np.sum(after ** 2, axis=2))) / s
        n = np.arange(len(db))
        ax.plot(n, db, ".", ms=3, label=f"before (nominal td), RMS {cal.rms_before / s:.3g} {lu}", color="tab:red")
        ax.plot(n, da, ".", ms=3, label=f"after, RMS {cal.rms_after / s:.3g} {lu}", color="tab:blue")
        rej = np.nonzero(((w_after == 0) & np.isfinite(after).all(axis=2)).any(axis=1))[0]
        if rej.size:
            ax.plot(rej, da[rej], "x", color="k", label="pose with a rejected marker")
        ax.set_xlabel("pose (row)")
        ax.set_ylabel(f"RMS marker error [{lu}]")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        out.append(("Residuals per pose", "RMS over the markers of each pose, before and after calibration.", _png(fig)))

        names = channel_names(cal)
        fig, ax = _subplots(figsize=(max(4, 0.7 * len(names) + 2), 3.2))
        pb = per_marker_rms(before, cal.fit.weights_before) / s
        pa = per_marker_rms(after, w_after) / s
        x = np.arange(len(names))
        ax.bar(x - 0.2, pb, 0.4, label="before", color="tab:red")
        ax.bar(x + 0.2, pa, 0.4, label="after", color="tab:blue")
        ax.set_xticks(x, names)
        ax.set_ylabel(f"RMS error [{lu}]")
        ax.set_yscale("log")
        ax.legend(fontsize=8)
        out.append(("Residuals per marker", "RMS 3-D error of each marker over the poses.", _png(fig)))

    est = [i for i, st in enumerate(cal.td_status) if st == "estimated" and np.isfinite(cal.td_std[i])]
    if est:
        groups = [("m", f"[{lu}]", 1 / s), ("rad", "[mrad]", 1e3)]
        other = [i for i in est if cal.spec.parameters[i].unit not in ("m", "rad")]
        panels = [(u, lab, k, [i for i in est if cal.spec.parameters[i].unit == u]) for u, lab, k in groups]
        if other:
            panels.append(("other", "[relative, x1e3]", None, other))
        panels = [p for p in panels if p[3]]
        fig, axes = _subplots(len(panels), 1, figsize=(max(6, 0.22 * max(len(p[3]) for p in panels) + 2),
                                                       3.4 * len(panels)), squeeze=False, bottom_in=1.2, gap_in=1.2)
        for ax, (_unit, lab, k, idx) in zip(axes[:, 0], panels):
            if k is None:
                nom = np.where(cal.td_nominal[idx] != 0, np.abs(cal.td_nominal[idx]), 1.0)
                dev = (cal.td[idx] - cal.td_nominal[idx]) / nom * 1e3
                err = cal.td_std[idx] / nom * 1e3
            else:
                dev = (cal.td[idx] - cal.td_nominal[idx]) * k
                err = cal.td_std[idx] * k
            x = np.arange(len(idx))
            ax.errorbar(x, dev, yerr=2 * err, fmt="o", ms=3, capsize=2)
            ax.axhline(0, color="0.6", lw=0.8)
            ax.set_xticks(x, [cal.spec.parameters[i].name for i in idx], rotation=90, fontsize=7)
            ax.set_ylabel(f"estimate - nominal {lab}")
        out.append(("Parameter deviations", "Estimated minus nominal, with two-standard-deviation error bars "
                    "(parameters held at nominal are not shown).", _png(fig)))

    ident = cal.identifiability or {}
    sv = ident.get("singular_values")
    if sv:
        fig, ax = _subplots(figsize=(7, 3))
        sv = np.asarray(sv, float)
        floor = 1e-17 * max(float(sv.max()), 1e-300)  # below double precision: zero
        ax.semilogy(np.arange(1, len(sv) + 1), np.maximum(sv, floor), "o-", ms=3)
        n_id = ident.get("n_identifiable", len(sv))
        ax.axvline(n_id + 0.5, color="tab:red", lw=1, label=f"{n_id} identifiable of {len(sv)}")
        ax.set_xlabel("index")
        ax.set_ylabel("singular value (scaled Jacobian)")
        ax.legend(fontsize=8)
        out.append(("Identifiability", "Singular values of the identification Jacobian, each column scaled "
                    "by its parameter's typical correction (1 mm, 1 mrad). Values near zero are "
                    "combinations the data cannot fix; they are held at nominal and listed below.", _png(fig)))

    controls = None if cal.fit is None else cal.fit.controls
    if controls is not None and len(controls):
        try:

            fb = PlatformModel(cal.calibrated_spec()).forward_batch(controls, cal.td, strict=False)
            P = fb.p[fb.converged]
            panels = coverage_panels(cal.spec, lu)
            fig, axes = _subplots(1, len(panels), figsize=(3.7 * len(panels), 3.3), squeeze=False, gap_in=0.9)
            for a, ((i, xlabel, sx), (j, ylabel, sy)) in zip(axes[0], panels):
                a.plot(P[:, i] * sx, P[:, j] * sy, ".", ms=3)
                a.set_xlabel(xlabel), a.set_ylabel(ylabel)
                a.set_aspect("auto")
            out.append(("Coverage of the workspace", "Where the plan took the moving frame (calibrated model), in "
                        "the stand's pose coordinates.", _png(fig)))
            lo, hi = cal.spec.control_bounds()
            span = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, np.ptp(controls, axis=0) + 1e-12)
            base = np.where(np.isfinite(lo), lo, controls.min(axis=0))
            frac = (controls - base) / span
            fig, ax = _subplots(figsize=(max(5, 0.6 * cal.spec.n_u + 2), 3), bottom_in=0.75)
            for j in range(cal.spec.n_u):
                ax.plot(np.full(len(frac), j) + np.random.default_rng(j).uniform(-0.15, 0.15, len(frac)),
                        frac[:, j], ".", ms=2)
            ax.set_xticks(range(cal.spec.n_u), cal.spec.control_names, rotation=45)
            ax.set_ylabel("fraction of the stroke")
            ax.set_ylim(-0.05, 1.05)
            out.append(("Coverage of the controls", "Each control's commanded values across its range.", _png(fig)))
        except Exception:  # a coverage plot must never stop the report from being written
            pass
    return out


def coverage_panels(spec, length_unit: str) -> list[tuple[tuple[int, str, float], tuple[int, str, float]]]:
    """The panels of the workspace coverage plot: the stand's pose coordinates in pairs (0, 1),
    (2, 3), ..., an odd last one beside the first, each as (index, axis label, factor from SI to the
    label's unit: lengths in ``length_unit``, angles in degrees); every coordinate in some panel
    (a gimbal's yaw and pitch, a planar robot's x, y and yaw, a hexapod's six)."""
    scale = length_scale(length_unit)

    def axis(k: int) -> tuple[int, str, float]:
        c = spec.coordinates[k]
        if c.unit == "m":
            return k, f"{c.name} [{length_unit}]", 1.0 / scale
        if c.unit == "rad":
            return k, f"{c.name} [deg]", 180.0 / np.pi
        return k, f"{c.name} [{c.unit}]", 1.0

    n = spec.n_p
    pairs = [(k, k + 1) for k in range(0, n - 1, 2)] + ([(n - 1, 0)] if n % 2 else [])
    return [(axis(i), axis(j)) for i, j in pairs]


def _table(rows, header) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _settling_html(st: dict) -> str:
    """What became of every command: settled, extrapolated to rest, dropped (counted by reason, then listed)."""
    text = (f"{st['n_commands']} commands: {st['n_poses']} settled poses"
            + (f" ({st['n_extrapolated']} of them extrapolated to rest from their approach)" if st["n_extrapolated"] else "")
            + (f"; {st['n_dropped']} dropped: " + ", ".join(f"{n} {why}" for why, n in st["dropped_by_reason"].items())
               if st["n_dropped"] else "; none dropped") + ".")
    out = f"<h2>Settling</h2><p>{html.escape(text)}</p>"
    if st.get("unsettled"):
        out += f"<p>{html.escape(st['unsettled']['sentence'])}.</p>"
    if st["dropped"]:
        rows = [(d["row"], d["reason"]) for d in st["dropped"][:200]]
        more = len(st["dropped"]) - len(rows)
        out += _table(rows, ["commands.csv row", "why no pose"]) + (f"<p>and {more} more (report.json)</p>" if more > 0 else "")
    return out


def channel_names(cal: Calibration) -> list[str]:
    """Names of the residual channels: the markers, each body's origin, each body's rotation (times rho)."""
    return (list(cal.marker_names) + [f"{b} origin" for b in cal.body_names]
            + [f"{b} rotation" for b in cal.body_names])


def report_html(cal: Calibration, poses: PoseSet | None = None, description: str | None = None) -> str:
    rep = report_dict(cal, poses, description)
    s = length_scale(cal.length_unit)
    lu = cal.length_unit
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>platkit calibration: {html.escape(cal.platform)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
        "th{background:#eee}td:first-child{text-align:left}img{max-width:100%}</style></head><body>",
        f"<h1>Calibration of the {html.escape(cal.platform)} stand</h1>",
        f"<p>Method <b>{html.escape(cal.method)}</b>; description {html.escape(str(rep['description']))}; "
        f"{cal.n_poses} poses, {cal.n_markers} markers, {cal.n_observations} marker observations kept, "
        f"{cal.n_rejected} rejected as outliers; {'converged' if cal.converged else '<b>NOT converged</b>'} "
        f"after {cal.iterations} iterations in {cal.time_s:.2f} s.</p>",
        f"<p>RMS marker error: <b>{cal.rms_before / s:.4g} {lu}</b> before (nominal parameters, only the "
        f"base-to-mocap transform and the markers fitted), <b>{cal.rms_after / s:.4g} {lu}</b> after. "
        f"Estimated noise per axis {cal.noise_sigma / s:.3g} {lu}.</p>",
    ]
    h = rep.get("heldout") or {}
    if h.get("folds"):
        parts.append(f"<p>Held-out ({h['folds']}-fold) prediction RMS: <b>{h['rms']:.4g} {lu}</b> "
                     f"(inliers {h['rms_inliers']:.4g} {lu}).</p>")
    if h.get("second_session"):
        v = h["second_session"]
        parts.append(f"<p>Prediction of a second session ({html.escape(str(v['source']))}, {v['n_poses']} poses): "
                     f"RMS <b>{v['rms']:.4g} {lu}</b>.</p>")
    for w in cal.warnings:
        parts.append(f"<p><b>Warning:</b> {html.escape(w)}</p>")
    if rep.get("rms_after_per_link"):  # a tree: each tracked link's markers together (docs/trees.md)
        rows = [(link, ", ".join(m for m in cal.marker_names if cal.marker_links.get(m) == link),
                 "" if v is None else f"{v:.4g}") for link, v in rep["rms_after_per_link"].items()]
        parts.append("<h2>Tracked links</h2>" + _table(rows, ["link", "markers", f"RMS after ({lu})"]))
    if poses is not None:
        parts.append(_settling_html(rep["settling"]))
    sel = (cal.identifiability or {}).get("model_selection") or {}
    if sel:
        parts.append("<h2>Which parameters were freed</h2><p>" + html.escape(sel.get("reason", "")) + ".</p>")
        if sel.get("candidates"):
            rows = [(", ".join(c["free"]) or "none", str(c["n_parameters_estimated"]), f"{c['heldout_median']:.4g}",
                     f"{c['heldout_rms']:.4g}", f"{c['fit_rms']:.4g}", "chosen" if c["free"] == sel["chosen"] else "")
                    for c in sel["candidates"]]
            parts.append(f"<p>Candidates, scored by the {html.escape(sel['criterion'])} ({lu}):</p>"
                         + _table(rows, ["free groups", "estimated", "held-out median", "held-out RMS", "fit RMS", ""]))
    for title, caption, png in _plots(cal, poses):
        parts.append(f"<h2>{html.escape(title)}</h2><p>{html.escape(caption)}</p>"
                     f"<img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    ident = cal.identifiability or {}
    held = ident.get("held_at_nominal", [])
    parts.append("<h2>Parameters the data cannot fix</h2>")
    if held:
        rows = [(h["name"], ", ".join(f"{v:+.3g} {k}" for k, v in h["combination"].items()), h["reason"]) for h in held]
        parts.append("<p>Held at their nominal values (the combination shown, in scaled units, is invisible "
                     "in the markers):</p>" + _table(rows, ["parameter", "unseen combination", "why"]))
    else:
        parts.append("<p>None: every free parameter is identifiable from these poses.</p>")
    gauge = ident.get("gauge") or {}
    if gauge.get("conventions"):  # what no pose fixes, and how it is fixed (docs/calibration.md)
        parts.append(f"<p>Gauge freedoms ({gauge.get('dimensions')} directions no set of poses can fix, "
                     f"{gauge.get('not_excited')} these poses do not excite), fixed by convention:</p><ul>"
                     + "".join(f"<li>{html.escape(c)}</li>" for c in gauge["conventions"]) + "</ul>")
    if ident.get("weakly_identified"):
        parts.append("<p>Weakly identified (standard deviation over ten typical corrections): "
                     + html.escape(", ".join(ident["weakly_identified"])) + "</p>")
    if ident.get("at_plausible_limit"):
        parts.append("<p><b>At the edge of the plausible range</b> (nominal &plusmn; 100 typical corrections: 10 cm, "
                     "0.1 rad, 10%): " + html.escape(", ".join(ident["at_plausible_limit"]))
                     + ". The fit pushed these far from the drawing: the geometric model is absorbing something "
                     "it does not describe; run <code>platkit diagnose</code>.</p>")
    rows = []
    for p, v, sd, nom, st in zip(cal.spec.parameters, cal.td, cal.td_std, cal.td_nominal, cal.td_status):
        k, unit = (1 / s, lu) if p.unit == "m" else (1.0, p.unit)
        rows.append((p.name, f"{v * k:.6g}", "" if not np.isfinite(sd) else f"{sd * k:.3g}", f"{nom * k:.6g}",
                     f"{(v - nom) * k:+.4g}", unit, st))
    parts.append("<h2>Parameters</h2>" + _table(rows, ["name", "value", "std", "nominal", "deviation", "unit", "status"]))
    rows = [(n, *(f"{x / s:.4f}" for x in pos), *("" if not np.isfinite(x) else f"{x / s:.3g}" for x in sd))
            for n, pos, sd in zip(cal.marker_names, cal.marker_positions, cal.marker_std)]
    if cal.marker_links:  # a tree: each marker sits in its own link's frame
        rows = [(r[0], cal.marker_links.get(r[0], ""), *r[1:]) for r in rows]
        parts.append(f"<h2>Markers on the tracked links ({lu}, each in its link's frame)</h2>"
                     + _table(rows, ["marker", "link", "x", "y", "z", "std x", "std y", "std z"]))
    else:
        parts.append(f"<h2>Markers on the moving part ({lu}, moving frame)</h2>"
                     + _table(rows, ["marker", "x", "y", "z", "std x", "std y", "std z"]))
    if cal.body_names:
        rows = [(n, *(f"{x / s:.4f}" for x in pos), *(f"{x:.6f}" for x in rv),
                 *("" if not np.isfinite(x) else f"{x / s:.3g}" for x in sd[:3]),
                 *("" if not np.isfinite(x) else f"{x:.3g}" for x in sd[3:]))
                for n, pos, rv, sd in zip(cal.body_names, cal.body_positions, cal.body_rotvecs, cal.body_std)]
        head = ["body", "x", "y", "z", "rx", "ry", "rz", "std x", "std y", "std z", "std rx", "std ry", "std rz"]
        where = "moving part", "moving frame"
        if cal.marker_links:  # a tree: each body sits in its own link's frame
            rows = [(r[0], cal.marker_links.get(r[0], ""), *r[1:]) for r in rows]
            head.insert(1, "link")
            where = "tracked links", "each in its link's frame"
        parts.append(f"<h2>Rigid bodies on the {where[0]} (origin {lu}, rotation vector rad, {where[1]})</h2>"
                     + _table(rows, head)
                     + f"<p>Rotation errors weigh as position errors through rho = {cal.body_rho / s:.4g} {lu}/rad "
                       f"({html.escape(cal.body_rho_source)}).</p>")
    T = cal.mocap_from_base
    parts.append(f"<h2>Base to motion capture</h2><pre>{html.escape(np.array2string(T[:3, :3], precision=6))}\n"
                 f"translation {html.escape(np.array2string(T[:3, 3] / s, precision=4))} {lu}</pre>")
    if cal.terms:
        rows = []
        for term, th, sd in zip(cal.terms, cal.theta, cal.theta_std):
            for n, v, e, u in zip(term.parameter_names, th, sd if sd is not None else th, term.units or [""] * len(th)):
                rows.append((f"{term.effect}.{n}", f"{v:.6g}", f"{e:.3g}", u))
        parts.append("<h2>Model terms</h2>" + _table(rows, ["parameter", "value", "std", "unit"]))
    parts.append("</body></html>")
    return "\n".join(parts)


def write_outputs(cal: Calibration, out_dir: str | Path, poses: PoseSet | None = None, with_html: bool = True) -> list[Path]:
    """Write calibration.yaml, report.json, report.html (and calibrated.urdf for URDF stands) into
    ``out_dir`` atomically. Returns the paths written. ``with_html=False``: no report.html (its
    figures take longer than a small calibration; ``platkit calibrate --no-report``). A URDF stand's
    calibrated.urdf that cannot be written (a joint scale other than 1) is a warning of ``cal``
    (appended, so calibration.yaml and the reports list it; the caller says it)."""
    out_dir = Path(out_dir)
    names = []
    with atomic_output_dir(out_dir) as tmp:
        names = ["calibration.yaml", "report.json"] + (["report.html"] if with_html else [])
        urdf = None  # what report.json says of calibrated.urdf (URDF stands only)
        if cal.spec.extras.get("chain") is not None:
            try:
                export_calibrated_urdf(cal.spec, cal.td, tmp / "calibrated.urdf")
                names.append("calibrated.urdf")
                urdf = "calibrated.urdf"
            except BadInput as exc:  # e.g. a joint scale other than 1 has no place in a URDF
                urdf = f"not written: {exc}"
                cal.warnings = [*cal.warnings, f"calibrated.urdf {urdf}"]  # said where the files list it
        write_calibration_yaml(cal, tmp)  # with its description beside it: the folder travels
        # the reports name the description as calibration.yaml does (relative to the folder, or shipped:);
        # read through libyaml's safe loader where PyYAML has it (a tree's 57 kB file: 0.7 s in Python's)
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        described = (yaml.load((tmp / "calibration.yaml").read_text(encoding="utf-8"), Loader=loader) or {}).get(
            "description")
        rep = report_dict(cal, poses, described)
        if urdf is not None:
            rep["calibrated_urdf"] = urdf
        (tmp / "report.json").write_text(jsonout.dumps(rep, indent=2) + "\n", encoding="utf-8")
        if with_html:
            (tmp / "report.html").write_text(report_html(cal, poses, described), encoding="utf-8")
    return [out_dir / n for n in names]
