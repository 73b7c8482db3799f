"""Diagnosis outputs: diagnosis.json, calibration.yaml (the model with the accepted effects) and
report.html (each located mismatch shown as the residual against the regressor that exposed it,
before and after), written whole or not at all."""
from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from platkit.calibrate.report import per_link_rms
from platkit.diagnose.fitting import Diagnosis, Finding
from platkit.diagnose.registered import registered_in_unit
from platkit.io.atomic import atomic_output_dir
from platkit.io.calibration import portable_descriptions, with_portable_descriptions, write_calibration_yaml
from platkit.io.figures import png_base64 as _png
from platkit.io.jsonout import strict
from platkit.model import length_scale
from platkit.notices import said
from platkit.settle import settling_summary

FORMAT = "platkit-diagnosis/1"


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def _length_unit(si_unit: str | None, unit: str) -> tuple[float, str | None]:
    """(metres per shown unit, shown unit) for a parameter unit: lengths ('m', 'm/s', 'm/N', ...)
    are shown in the session's length unit; anything else as it is."""
    if si_unit == "m" or (si_unit or "").startswith("m/"):
        return length_scale(unit), unit + si_unit[1:]
    return 1.0, si_unit


def _where_dict(where: Any) -> Any:
    """A finding's ``where`` for diagnosis.json: "unit" (the unit the term's parameters are stored
    in, SI; the shown parameters carry theirs) becomes "stored_unit"."""
    out = dict(strict(where)) if isinstance(where, dict) else strict(where)
    if isinstance(out, dict) and "unit" in out:
        out["stored_unit"] = out.pop("unit")
    return out


def finding_dict(f: Finding, unit: str) -> dict[str, Any]:
    s = length_scale(unit)
    params = {}
    for name, v in f.parameters.items():
        k, shown = _length_unit(v.get("unit"), unit)
        params[name] = {"value": _num(v["value"] / k), "std": None if v["std"] is None else _num(v["std"] / k),
                        "unit": shown}
    where = _where_dict(f.where)
    out = {
        "effect": f.effect,
        "where": where,
        "parameters": params,
        "heldout_rms_before": _num(f.heldout_rms_before / s),
        "heldout_rms_after": _num(f.heldout_rms_after / s),
        "unit": unit,
        "evidence": f.evidence,
        "p_heldout": _num(f.p_heldout),
        "p_screen": _num(f.p_screen),
        "bic_change": _num(f.bic_change),
        "separability": _num(f.separability),
        "warnings": list(f.warnings),
    }
    if f.corrected:  # a recording artefact: how calibration.yaml leaves it out
        out["corrected"] = f.corrected
    if f.alternatives:  # other effects at the same place, not told apart from it on this plan
        out["alternatives"] = [{"effect": a["effect"], "where": _where_dict(a["where"]),
                                "heldout_rms": _num(a["heldout_rms"] / s), "p_named_better": _num(a["p_named_better"])}
                               for a in f.alternatives]
    if f.heldout_session_rms_before is not None:
        out["heldout_session_rms_before"] = _num(f.heldout_session_rms_before / s)
        out["heldout_session_rms_after"] = _num(f.heldout_session_rms_after / s)
    return out


def rms_per_link(d: Diagnosis) -> dict[str, dict[str, float | None]]:
    """On a tree, {link: {"geometric": RMS, "final": RMS}} of its markers' fit errors (the
    session's unit) under the geometric model and the final one; {} on a single moving link."""
    links = d.calibration.marker_links or d.poses.marker_links
    if not links:
        return {}
    s = length_scale(d.unit)
    names = list(d.poses.marker_names)
    before = per_link_rms(d.base.fit.residuals_after, d.base.fit.weights, names, links, s) \
        if d.base.fit is not None else {}
    fin = d.final_fit.fit
    after = per_link_rms(fin.residuals_after, fin.weights, names, links, s) if fin is not None else {}
    return {link: {"geometric": before.get(link), "final": after.get(link)}
            for link in dict.fromkeys(links[m] for m in names if m in links)}


def diagnosis_dict(d: Diagnosis) -> dict[str, Any]:
    s = length_scale(d.unit)
    out = {
        "format": FORMAT,
        "platform": d.calibration.platform,
        "unit": d.unit,
        "n_poses": d.poses.n_poses,
        "n_markers": d.poses.n_markers,
        "findings": [finding_dict(f, d.unit) for f in d.findings],
        "verdict": d.verdict,
        "warnings": said(),  # every warning said while the verb ran (platkit.notices)
        "rms_geometric": _num(d.base.rms_after / s),
        "rms_final": _num(d.final_fit.rms_after / s),
        "heldout_rms_geometric": None if d.heldout_geometric is None else _num(d.heldout_geometric / s),
        "noise_floor": None if d.noise_floor is None else _num(d.noise_floor / s),  # held-out RMS from marker noise alone
        "at_noise_floor": bool(d.at_noise_floor),  # then nothing is named: no effect can predict better
        "located_before": [{"test": x.test, "where": strict(x.where), "statistic": _num(x.statistic),
                            "p_adjusted": _num(x.p_adjusted)} for x in d.locations_before if x.p_adjusted < 0.05][:20],
        "located_after": [{"test": x.test, "where": strict(x.where), "statistic": _num(x.statistic),
                           "p_adjusted": _num(x.p_adjusted)} for x in d.locations if x.p_adjusted < 0.05][:20],
        "settling": strict(settling_summary(d.poses, d.unit)),  # every command: kept, extrapolated, dropped and why
        "not_separable": strict(d.not_separable),
        "untried": dict(d.untried),
        "rounds": strict(d.rounds),
        "method": ("forward selection: score-test screening (Holm), refit with the shared estimator, accepted when "
                   "the K-fold held-out error falls significantly (one-sided Wilcoxon, Holm) and BIC falls, unless a "
                   "generic probe predicts significantly better (then: unexplained)"),
    }
    per_link = rms_per_link(d)
    if per_link:  # a tree: each tracked link's markers together (docs/trees.md)
        out["rms_per_link"] = per_link
    if d.imu is not None:
        # IMU findings (platkit.diagnose.imu): gyro in deg/s, accelerometer in m/s^2, each finding says its unit
        out["findings"] += strict(list(d.imu.get("findings", [])))
        out["not_separable"] += strict(list(d.imu.get("not_separable", [])))
        out["imu"] = strict({k: v for k, v in d.imu.items() if k != "findings"})
        out["verdict"] = (out["verdict"] + " " + d.imu.get("verdict", "")).strip()
    if d.heldout_session is not None:
        h = d.heldout_session
        out["heldout_session"] = {"rms_before": _num(h["rms_before"] / s), "rms_after": _num(h["rms_after"] / s),
                                  "p_improvement": _num(h["p_improvement"]), "n_poses": h["n_poses"],
                                  "per_marker": {k: [_num(a / s), _num(b / s)] for k, (a, b) in h["per_marker"].items()}}
        if "registered" in h:  # --heldout-register: the same session, each model re-registered to its set-up
            out["heldout_session"]["registered"] = registered_in_unit(h["registered"], s)
    return out


def _plots(d: Diagnosis) -> list[tuple[str, str]]:
    """(title, base64 PNG) of each plot; bare matplotlib Figures (no pyplot state, the user's
    backend untouched)."""
    from matplotlib.figure import Figure  # matplotlib only when drawing: start-up of the other verbs

    s = length_scale(d.unit)
    out = []
    for f in d.findings:
        if isinstance(f.where, dict) and "alike" in f.where and f.regressor is not None:
            out.append(_neighbour_plot(d, f))
            continue
        if f.regressor is None or f.signature_before is None:
            continue
        fig = Figure(figsize=(10, 3.6))
        ax = fig.subplots(1, 2, sharey=True)
        for a, sig, title in ((ax[0], f.signature_before, "geometric model"), (ax[1], f.signature_after, f"with {f.effect}")):
            if sig is None:
                continue
            a.plot(f.regressor, sig / s, "o", ms=4, alpha=0.7)
            a.axhline(0, color="k", lw=0.5)
            a.set_xlabel(f.regressor_label)
            a.set_title(title)
        ax[0].set_ylabel(f"measured - model, along the effect ({d.unit})")
        out.append((f"{f.effect}: {html.escape(json.dumps(strict(f.where)))}", _png(fig)))
    # residual norm in time order, before and after
    r0 = np.linalg.norm(d.base.fit.residuals_after, axis=2)
    r1 = np.linalg.norm(d.final_fit.fit.residuals_after, axis=2)
    t = d.poses.extras.get("elapsed", np.arange(d.poses.n_poses))
    fig = Figure(figsize=(10, 3.2))
    ax = fig.subplots()
    for m, name in enumerate(d.poses.marker_names):
        ax.plot(t, r0[:, m] / s, ".", alpha=0.4, label=f"{name} geometric")
        ax.plot(t, r1[:, m] / s, "x", alpha=0.6, label=f"{name} final")
    ax.set_xlabel("time since the first command (s)")
    ax.set_ylabel(f"marker error ({d.unit})")
    ax.legend(fontsize=7, ncol=4)
    out.append(("marker errors along time, geometric model and final model", _png(fig)))
    return out


def _neighbour_plot(d: Diagnosis, f: Finding) -> tuple[str, str]:
    """An ``unexplained`` of the neighbour tests: each settled pose's error against its
    neighbour's (next in time, or near in the commands), along the residuals' main direction
    (locate.along_main_direction, kept in the finding's regressor and signature): alike neighbours
    line up on the diagonal, independent ones make a round cloud."""
    from matplotlib.figure import Figure

    s = length_scale(d.unit)
    x, y = np.asarray(f.regressor) / s, np.asarray(f.signature_before) / s
    fig = Figure(figsize=(5.2, 4.6))
    ax = fig.subplots()
    ax.plot(x, y, "o", ms=4, alpha=0.6)
    lim = 1.05 * max(np.max(np.abs(x)), np.max(np.abs(y)), 1e-12)
    ax.plot([-lim, lim], [-lim, lim], color="k", lw=0.5)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_xlabel(f"{f.regressor_label} ({d.unit})")
    ax.set_ylabel(f"at its neighbour ({d.unit})")
    frame = f" (in the {f.where['frame']} frame)" if f.where.get("frame", "motion capture") != "motion capture" else ""
    return (f"unexplained: errors of the geometric model at {html.escape(f.where['alike'])}{html.escape(frame)}",
            _png(fig))


def report_html(d: Diagnosis) -> str:
    rows = []
    for f in d.findings:
        fd = finding_dict(f, d.unit)
        params = "; ".join(f"{k} = {v['value']:.4g}" + ("" if v["std"] is None else f" +- {v['std']:.2g}") + f" {v['unit']}"
                           for k, v in fd["parameters"].items())
        rows.append(f"<tr><td>{html.escape(f.effect)}</td><td>{html.escape(json.dumps(fd['where']))}</td>"
                    f"<td>{html.escape(params)}</td><td>{fd['heldout_rms_before']:.4g}</td>"
                    f"<td>{fd['heldout_rms_after']:.4g}</td><td>{html.escape(f.evidence)}</td></tr>")
    for fd in (d.imu or {}).get("findings", []):
        params = "; ".join(f"{k} = {v['value']:.4g} +- {v['std']:.2g} {v['unit']}" for k, v in fd["parameters"].items())
        rows.append(f"<tr><td>{html.escape(fd['effect'])}</td><td>{html.escape(json.dumps(fd['where']))}</td>"
                    f"<td>{html.escape(params)}</td><td>{fd['heldout_rms_before']:.4g} {html.escape(fd['unit'])}</td>"
                    f"<td>{fd['heldout_rms_after']:.4g} {html.escape(fd['unit'])}</td><td>{html.escape(fd['evidence'])}</td></tr>")
    table = ("<table border=1 cellpadding=4><tr><th>effect</th><th>where</th><th>parameters</th>"
             f"<th>held-out RMS before ({d.unit})</th><th>after</th><th>evidence</th></tr>" + "".join(rows) + "</table>"
             if rows else "<p>No findings.</p>")
    imgs = "".join(f"<h3>{title}</h3><img alt=\"{html.escape(html.unescape(title))}\" src='data:image/png;base64,{png}'>"
                   for title, png in _plots(d))
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>platkit diagnosis</title></head><body>"
            f"<h1>Diagnosis of the {html.escape(d.calibration.platform)} stand</h1>"
            f"<p>{html.escape(d.verdict)}</p>" + (f"<p>{html.escape(d.imu.get('verdict', ''))}</p>" if d.imu else "")
            + "".join(f"<p><b>Warning:</b> {html.escape(w)}</p>" for w in said())
            + _links_html(d, table) + f"<h2>Where the residual was structured</h2>"
            f"{imgs}</body></html>")


def _links_html(d: Diagnosis, table: str) -> str:
    """The findings' table, then on a tree each tracked link's fit RMS before and after."""
    out = f"<h2>Findings</h2>{table}"
    per_link = rms_per_link(d)
    if per_link:
        def cell(v):
            return "" if v is None else f"{v:.4g}"
        rows = "".join(f"<tr><td>{html.escape(link)}</td><td>{cell(v['geometric'])}</td><td>{cell(v['final'])}</td></tr>"
                       for link, v in per_link.items())
        out += ("<h2>Tracked links</h2><table border=1 cellpadding=4><tr><th>link</th>"
                f"<th>fit RMS, geometric model ({d.unit})</th><th>final model</th></tr>{rows}</table>")
    return out


def write_outputs(d: Diagnosis, out_dir: str | Path, with_html: bool = True) -> list[Path]:
    """Write diagnosis.json, calibration.yaml and (``with_html``) report.html into ``out_dir``,
    all or none (:func:`platkit.io.atomic.atomic_output_dir`). calibration.yaml is
    ``d.calibration``, the stand's: recording artefacts left out (``d.fitted`` holds the model
    fitted to the data), its description copied beside it unless shipped
    (:func:`platkit.io.calibration.write_calibration_yaml`), and diagnosis.json names it as
    calibration.yaml does. Returns the paths written."""
    names = ["diagnosis.json", "calibration.yaml"] + (["report.html"] if with_html else [])
    with atomic_output_dir(out_dir) as tmp:
        renamed = portable_descriptions(d.calibration, tmp)  # its description beside it: the folder travels
        (tmp / "diagnosis.json").write_text(json.dumps(with_portable_descriptions(diagnosis_dict(d), renamed), indent=2)
                                            + "\n", encoding="utf-8")
        write_calibration_yaml(d.calibration, tmp, renamed)
        if with_html:
            (tmp / "report.html").write_text(report_html(d), encoding="utf-8")
    return [Path(out_dir) / n for n in names]
