"""The fleet summary of a batch: one row per session (fit and held-out errors, findings, the
parameters that moved), read back from each session's usual outputs, written as summary.csv,
summary.json and summary.html (with plots).

A parameter *moved* in a session when its estimate differs from the description's nominal by
more than its own standard deviation (the calibration's) explains: |z| = |value - nominal| / std
above the two-sided Bonferroni level for ``MOVED_ALPHA`` over the parameters the session
estimated (so a session of 30 parameters at the noise has a 1% chance of any flag, not 8%).
Only estimated parameters are judged: one the session held at nominal (its poses did not
identify it) is *not identified* there and has no value, and a fixed one (a gauge of the batch,
or not asked for) neither. The fleet's medians are over the sessions that identified the
parameter. A batch calibrates every session in one parameterisation (platkit.batch.gauge), so
these compare across sessions.
"""
from __future__ import annotations

import csv
import html
import io
import json
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import norm

from platkit.batch.store import BatchFolder, SessionRef
from platkit.io.atomic import atomic_output_dir
from platkit.io.figures import png_base64
from platkit.io.jsonout import dumps

__all__ = ["MOVED_ALPHA", "moved_level", "moved_parameters", "session_row", "summarise", "write_summary",
           "parameter_table"]

#: family-wise level of the "moved" test over one session's estimated parameters
MOVED_ALPHA = 0.01
#: summary.csv columns, in order (a verb fills those it has)
COLUMNS = ["session", "status", "error", "unit", "n_poses", "n_markers", "rms_before", "rms_after", "heldout_rms",
           "converged", "findings", "heldout_rms_before_findings", "heldout_rms_after_findings", "moved",
           "not_identified",
           "n_samples", "method", "inclination_rmse_deg", "total_rmse_deg", "seconds", "worker", "path"]


def _read_json(path: Path) -> dict:
    return json.loads(path.read_text(encoding="utf-8"))


def parameter_table(calibration_yaml: Path) -> dict[str, dict]:
    """``{name: {value, std, nominal, unit, status}}`` from a calibration.yaml (its units)."""
    data = yaml.safe_load(calibration_yaml.read_text(encoding="utf-8"))
    return {name: {k: p.get(k) for k in ("value", "std", "nominal", "unit", "status")}
            for name, p in (data.get("parameters") or {}).items()}


def _estimated(p: dict) -> bool:
    return p.get("status", "estimated") == "estimated" and p.get("std") is not None and p["std"] > 0


def moved_level(params: dict[str, dict], alpha: float = MOVED_ALPHA) -> float:
    """|z| beyond which a parameter of this session moved: two-sided Bonferroni at ``alpha`` over
    its estimated parameters."""
    n = sum(1 for p in params.values() if _estimated(p))
    return float(norm.isf(alpha / 2 / max(n, 1)))


def moved_parameters(params: dict[str, dict], alpha: float = MOVED_ALPHA) -> list[dict]:
    """The parameters that moved (see the module docstring), largest first: name, change
    (value - nominal, in its unit), std, z."""
    out = []
    level = moved_level(params, alpha)
    for name, p in params.items():
        if not _estimated(p):
            continue
        change = p["value"] - p["nominal"]
        z = change / p["std"]
        if abs(z) > level:
            out.append({"name": name, "change": change, "std": p["std"], "z": z, "unit": p["unit"]})
    return sorted(out, key=lambda m: -abs(m["z"]))


def session_row(verb: str, ref: SessionRef, batch: BatchFolder) -> dict:
    """The summary row of one session: status 'ok' (its outputs read back), 'failed' (the
    error), or 'missing' (not run yet: a batch that was stopped)."""
    record = batch.record(ref.name)
    row: dict = {"session": ref.name, "path": str(ref.path)}
    if record is None:
        return {**row, "status": "missing", "error": "not run (the batch was stopped before it)"}
    row.update(seconds=record.get("seconds"), worker=record.get("worker"))
    if not record.get("ok"):
        return {**row, "status": "failed", "error": record.get("error", "")}
    folder = batch.sessions / ref.name
    row["status"] = "ok"
    if verb in ("calibrate", "diagnose"):
        params = parameter_table(folder / "calibration.yaml")
        # a parameter the session did not identify is said so, with no value (calibration.yaml holds its nominal)
        row["parameters"] = {n: ({**p, "value": None, "std": None} if p.get("status") == "held_at_nominal" else p)
                             for n, p in params.items()}
        row["moved_detail"] = moved_parameters(params)
        row["moved"] = " ".join(m["name"] for m in row["moved_detail"])
        row["moved_level"] = moved_level(params)
        row["not_identified"] = " ".join(n for n, p in params.items() if p.get("status") == "held_at_nominal")
    if verb == "calibrate":
        rep = _read_json(folder / "report.json")
        row.update(unit=rep["unit"], n_poses=rep["n_poses"], n_markers=rep["n_markers"], rms_before=rep["rms_before"],
                   rms_after=rep["rms_after"], converged=rep["converged"],
                   heldout_rms=(rep.get("heldout") or {}).get("rms"))
    elif verb == "diagnose":
        d = _read_json(folder / "diagnosis.json")
        found = [f for f in d["findings"] if "heldout_rms_before" in f]
        row.update(unit=d["unit"], n_poses=d["n_poses"], n_markers=d["n_markers"], rms_before=d["rms_geometric"],
                   rms_after=d["rms_final"], findings=" ".join(f["effect"] for f in d["findings"]),
                   verdict=d["verdict"])
        if found:
            row.update(heldout_rms_before_findings=found[0]["heldout_rms_before"],
                       heldout_rms_after_findings=found[-1]["heldout_rms_after"])
    elif verb == "orient":
        rep = _read_json(folder / "report.json")
        truth = rep.get("truth") or {}
        n = sum(1 for _ in (folder / "orientation.csv").open(encoding="utf-8")) - 1
        row.update(n_samples=n, method=rep.get("method"), inclination_rmse_deg=truth.get("inclination_rmse_deg"),
                   total_rmse_deg=truth.get("total_rmse_deg"))
    return row


def summarise(verb: str, sessions: list[SessionRef], batch: BatchFolder) -> dict:
    """The summary.json mapping: counts, one row per session (in the batch's order) and, for
    calibrations, one row per parameter over the fleet (how many sessions it moved in, the
    median and spread of its change)."""
    rows = [session_row(verb, ref, batch) for ref in sessions]
    counts = {s: sum(1 for r in rows if r["status"] == s) for s in ("ok", "failed", "missing")}
    fleet: dict[str, dict] = {}
    for r in rows:
        for name, p in (r.get("parameters") or {}).items():
            f = fleet.setdefault(name, {"unit": p["unit"], "changes": [], "z": [], "moved_in": [], "not_identified_in": []})
            if _estimated(p):
                f["changes"].append(p["value"] - p["nominal"])
                f["z"].append((p["value"] - p["nominal"]) / p["std"])
            elif p.get("status") == "held_at_nominal":
                f["not_identified_in"].append(r["session"])
        for m in r.get("moved_detail", []):
            fleet[m["name"]]["moved_in"].append(r["session"])
    parameters = {name: {"unit": f["unit"], "n_sessions": len(f["changes"]),
                         "median_change": float(np.median(f["changes"])) if f["changes"] else None,
                         "spread_change": float(np.std(f["changes"], ddof=1)) if len(f["changes"]) > 1 else None,
                         "median_z": float(np.median(f["z"])) if f["z"] else None,
                         "moved_in": f["moved_in"], "not_identified_in": f["not_identified_in"]}
                  for name, f in fleet.items() if f["changes"] or f["not_identified_in"]}
    return {"verb": verb, "counts": counts, "moved_alpha": MOVED_ALPHA,
            "moved_definition": f"|value - nominal| / std beyond the two-sided Bonferroni level for {MOVED_ALPHA:g} over "
                                "the session's estimated parameters (its moved_level); parameters a session did not "
                                "identify are not judged there",
            "sessions": rows, "parameters": parameters}


def _csv(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in COLUMNS})
    return buf.getvalue()


def _plots(summary: dict) -> list[tuple[str, str, str]]:
    from matplotlib.figure import Figure  # bare Figures: no pyplot state, the user's backend untouched

    rows = [r for r in summary["sessions"] if r["status"] == "ok"]
    out = []
    if not rows:
        return out
    names = [r["session"] for r in rows]
    x = np.arange(len(rows))
    if any(r.get("rms_after") is not None for r in rows):
        unit = rows[0].get("unit", "")
        fig = Figure(figsize=(max(6, 0.25 * len(rows) + 3), 3.2))
        ax = fig.subplots()
        w = 0.4
        ax.bar(x - w / 2, [r.get("rms_before") or 0 for r in rows], w, label="before (nominal)", color="#bbb")
        ax.bar(x + w / 2, [r.get("rms_after") or 0 for r in rows], w, label="after", color="#1f77b4")
        held = [r.get("heldout_rms") for r in rows]
        if any(h is not None for h in held):
            ax.plot(x, [np.nan if h is None else h for h in held], "k_", ms=12, mew=2, label="held-out")
        ax.set_yscale("log")
        ax.set_ylabel(f"marker RMS ({unit})")
        ax.set_xticks(x, names, rotation=90, fontsize=7)
        ax.legend(fontsize=8)
        out.append(("Fit error per session", "RMS marker error with the nominal description and after the fit "
                    "(log scale); a session far above the others is the one to look at.", png_base64(fig)))
    pnames = sorted({n for r in rows for n in (r.get("parameters") or {})},
                    key=lambda n: list(rows[0].get("parameters", {})).index(n) if n in rows[0].get("parameters", {}) else 0)
    if pnames:
        Z = np.full((len(rows), len(pnames)), np.nan)
        for i, r in enumerate(rows):
            for j, n in enumerate(pnames):
                p = (r.get("parameters") or {}).get(n)
                if p and _estimated(p):
                    Z[i, j] = (p["value"] - p["nominal"]) / p["std"]
        fig = Figure(figsize=(max(6, 0.22 * len(pnames) + 2), max(2.5, 0.22 * len(rows) + 1.5)))
        ax = fig.subplots()
        im = ax.imshow(np.clip(Z, -10, 10), cmap="coolwarm", vmin=-10, vmax=10, aspect="auto", interpolation="nearest")
        moved = np.abs(Z) > np.array([[r.get("moved_level") or np.inf] for r in rows])
        for i, j in zip(*np.nonzero(moved)):
            ax.text(j, i, "*", ha="center", va="center", fontsize=8)
        ax.set_xticks(np.arange(len(pnames)), pnames, rotation=90, fontsize=6)
        ax.set_yticks(np.arange(len(rows)), names, fontsize=7)
        fig.colorbar(im, ax=ax, label="(value - nominal) / std, clipped at 10")
        out.append(("Parameters that moved", "Each cell is one parameter of one session, its change from the "
                    "nominal description in units of its own std; * marks a parameter that moved (beyond the "
                    "session's Bonferroni level). White: not estimated in that session (not identified, or "
                    "fixed).", png_base64(fig)))
    effects: dict[str, int] = {}
    for r in rows:
        for e in (r.get("findings") or "").split():
            effects[e] = effects.get(e, 0) + 1
    if effects:
        fig = Figure(figsize=(6, 3))
        ax = fig.subplots()
        ax.barh(list(effects), list(effects.values()), color="#d62728")
        ax.set_xlabel("sessions")
        out.append(("Findings over the fleet", "How many sessions each effect was found in (held-out proven).",
                    png_base64(fig)))
    if any(r.get("total_rmse_deg") is not None for r in rows):
        fig = Figure(figsize=(max(6, 0.25 * len(rows) + 3), 3))
        ax = fig.subplots()
        ax.bar(x, [r.get("total_rmse_deg") or 0 for r in rows])
        ax.set_ylabel("orientation RMSE against the truth (deg)")
        ax.set_xticks(x, names, rotation=90, fontsize=7)
        out.append(("Orientation error per session", "Only sessions with a truth file.", png_base64(fig)))
    return out


def _html(summary: dict) -> str:
    c = summary["counts"]
    rows = summary["sessions"]
    head = [k for k in COLUMNS if k not in ("path", "worker") and any(r.get(k) not in (None, "") for r in rows)]
    table = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(r.get(k)))}</td>" for k in head) + "</tr>" for r in rows)
    parts = ["<!doctype html><html><head><meta charset='utf-8'>",
             f"<title>platkit batch {html.escape(summary['verb'])}</title>",
             "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px}"
             "th{background:#eee}img{max-width:100%}</style></head><body>",
             f"<h1>Fleet summary: platkit batch {html.escape(summary['verb'])}</h1>",
             f"<p>{len(rows)} sessions: <b>{c['ok']} done</b>, <b>{c['failed']} failed</b>, {c['missing']} not run. "
             f"A parameter moved when {html.escape(summary['moved_definition'])}.</p>"]
    for title, caption, png in _plots(summary):
        parts.append(f"<h2>{html.escape(title)}</h2><p>{html.escape(caption)}</p>"
                     f"<img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    parts.append("<h2>Sessions</h2><table><tr>" + "".join(f"<th>{html.escape(k)}</th>" for k in head) + "</tr>"
                 + table + "</table>")
    if summary["parameters"]:
        prow = "".join(f"<tr><td>{html.escape(n)}</td><td>{p['n_sessions']}</td><td>{len(p['moved_in'])}</td>"
                       f"<td>{_fmt(p['median_change'])}</td><td>{_fmt(p['median_z'])}</td>"
                       f"<td>{_fmt(p['spread_change'])}</td><td>{html.escape(p['unit'])}</td>"
                       f"<td>{html.escape(' '.join(p['not_identified_in']))}</td></tr>"
                       for n, p in summary["parameters"].items())
        parts.append("<h2>Parameters over the fleet</h2><table><tr><th>parameter</th><th>sessions estimated</th>"
                     "<th>sessions moved</th><th>median change</th><th>median z</th><th>spread of the change</th>"
                     "<th>unit</th><th>not identified in</th></tr>" + prow + "</table>")
    parts.append("</body></html>")
    return "\n".join(parts)


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def write_summary(verb: str, sessions: list[SessionRef], batch: BatchFolder) -> tuple[dict, list[Path]]:
    """Write summary.csv, summary.json and summary.html into the batch folder (whole or not at
    all); return the summary and the paths."""
    summary = summarise(verb, sessions, batch)
    names = ["summary.csv", "summary.json", "summary.html"]
    with atomic_output_dir(batch.out) as tmp:
        (tmp / "summary.csv").write_text(_csv(summary["sessions"]), encoding="utf-8")
        (tmp / "summary.json").write_text(dumps(summary, indent=2) + "\n", encoding="utf-8")
        (tmp / "summary.html").write_text(_html(summary), encoding="utf-8")
    return summary, [batch.out / n for n in names]
