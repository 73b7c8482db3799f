"""The history of one stand: its calibrations over time, each parameter's trend with its
uncertainty, and the changes larger than the uncertainties explain (wear, a knock, a part).

Sessions are ordered by the ``date`` of their session.yaml where every session has one, else by
the batch's (natural) folder order. For each parameter estimated in a session (value v_i, std
s_i from its calibration.yaml), the test walks the sessions in order, keeping a *segment* of
sessions that agree: the next session is compared with the segment's weighted mean m (variance
1 / sum 1/s_j^2),

    z_i = (v_i - m) / (k sqrt(s_i^2 + var m)),

and a change is flagged when |z_i| exceeds the two-sided Bonferroni level for ``alpha`` over all
parameters and sessions tested; a flagged session starts a new segment (so a knock is flagged
once, and a drift each time it has moved more than the noise explains again). ``k`` >= 1 is
the dispersion of the calibrations: 1.4826 x the median of |v_i - v_{i-1}| / sqrt(s_i^2 + s_{i-1}^2)
over every parameter, so stds that understate the month-to-month scatter do not raise false
flags (the median ignores the few real changes). The trend is the weighted least-squares slope
of v over time, with its std (scaled by k).
"""
from __future__ import annotations

import csv
import datetime as dt
import html
import io
from pathlib import Path

import numpy as np
from scipy.stats import norm

from platkit.batch.fleet import parameter_table
from platkit.batch.store import BatchFolder, SessionRef
from platkit.errors import BadInput
from platkit.io.atomic import atomic_output_dir
from platkit.io.description import load_yaml
from platkit.io.figures import png_base64
from platkit.io.jsonout import dumps

__all__ = ["ALPHA", "session_date", "stand_history", "write_history"]

#: family-wise level of the change tests (over every parameter and session)
ALPHA = 0.01
#: a robust (MAD) sigma from a median absolute value
MAD_TO_SIGMA = 1.4826


def session_date(folder: Path) -> dt.date | None:
    """The ``date`` of a session's session.yaml (an ISO date or date-time), or None."""
    data = load_yaml(Path(folder) / "session.yaml")
    value = data.get("date") if isinstance(data, dict) else None
    if value is None:
        return None
    if isinstance(value, dt.datetime):
        return value.date()
    if isinstance(value, dt.date):
        return value
    try:
        return dt.date.fromisoformat(str(value)[:10])
    except ValueError:
        raise BadInput(f"{Path(folder) / 'session.yaml'}: field 'date': expected an ISO date such as 2026-03-01, "
                       f"got {value!r}") from None


def stand_history(names: list[str], tables: list[dict[str, dict]], dates: list[dt.date | None],
                  alpha: float = ALPHA) -> dict:
    """The history mapping (history.json) of sessions ``names`` in time order, with their
    calibrations' parameter tables (fleet.parameter_table) and dates (all or none given)."""
    n = len(names)
    if n < 2:
        raise BadInput(f"a history needs 2 or more sessions of the stand, got {n}")
    dated = all(d is not None for d in dates)
    if dated:
        time = np.array([(d - dates[0]).days for d in dates], float)
        axis = "days since the first session"
    else:
        time = np.arange(n, dtype=float)
        axis = "session (folder order)"
    pnames = list(dict.fromkeys(p for t in tables for p in t))
    V = np.full((n, len(pnames)), np.nan)
    S = np.full((n, len(pnames)), np.nan)
    units = {}
    for i, t in enumerate(tables):
        for j, p in enumerate(pnames):
            e = t.get(p)
            if e and e.get("status") == "estimated" and e.get("std") and e["std"] > 0:
                V[i, j], S[i, j] = e["value"], e["std"]
            if e:
                units[p] = e["unit"]
    # dispersion of the calibrations, from consecutive sessions (robust: real changes are few)
    dz = (V[1:] - V[:-1]) / np.sqrt(S[1:] ** 2 + S[:-1] ** 2)
    dz = np.abs(dz[np.isfinite(dz)])
    k = max(1.0, MAD_TO_SIGMA * float(np.median(dz))) if dz.size else 1.0
    n_tests = int(np.sum(np.isfinite(V[1:]).sum(axis=0)))
    z_crit = float(norm.isf(alpha / 2 / max(n_tests, 1)))
    parameters, changes = {}, []
    Z = np.full_like(V, np.nan)
    for j, p in enumerate(pnames):
        idx = [i for i in range(n) if np.isfinite(V[i, j])]
        entry = {"unit": units.get(p), "value": [None if not np.isfinite(v) else float(v) for v in V[:, j]],
                 "std": [None if not np.isfinite(s) else float(s) for s in S[:, j]], "changes": []}
        segment: list[int] = []
        for i in idx:
            if segment:
                w = 1 / S[segment, j] ** 2
                m = float(np.sum(w * V[segment, j]) / np.sum(w))
                var_m = float(1 / np.sum(w))
                z = (V[i, j] - m) / (k * np.sqrt(S[i, j] ** 2 + var_m))
                Z[i, j] = z
                if abs(z) > z_crit:
                    flag = {"parameter": p, "session": names[i], "index": i,
                            "date": None if dates[i] is None else dates[i].isoformat(), "change": float(V[i, j] - m),
                            "std": float(k * np.sqrt(S[i, j] ** 2 + var_m)), "z": float(z), "unit": units.get(p),
                            "before": float(m), "after": float(V[i, j])}
                    entry["changes"].append(flag)
                    changes.append(flag)
                    segment = []
            segment.append(i)
        if len(idx) >= 3:
            t, v, w = time[idx], V[idx, j], 1 / S[idx, j] ** 2
            A = np.stack([np.ones_like(t), t], axis=1)
            cov = np.linalg.inv(A.T @ (w[:, None] * A))
            coef = cov @ A.T @ (w * v)
            entry["trend_per_step"] = float(coef[1])
            entry["trend_std"] = float(k * np.sqrt(cov[1, 1]))
        parameters[p] = entry
    changes.sort(key=lambda f: (f["index"], -abs(f["z"])))
    return {"sessions": names, "dates": [None if d is None else d.isoformat() for d in dates], "time": time.tolist(),
            "time_axis": axis, "trend_unit": f"parameter unit per {'day' if dated else 'session'}",
            "alpha": alpha, "n_tests": n_tests, "z_critical": z_crit, "dispersion_k": k,
            "method": "sequential segment test (see platkit.batch.history): each session against the weighted mean "
                      "of the agreeing sessions before it, Bonferroni over every parameter and session",
            "changes": changes, "parameters": parameters, "z": [[None if not np.isfinite(x) else float(x) for x in row]
                                                                for row in Z], "parameter_names": pnames}


def _plots(h: dict) -> list[tuple[str, str, str]]:
    from matplotlib.figure import Figure  # bare Figures: no pyplot state, the user's backend untouched

    out = []
    names, t = h["sessions"], np.array(h["time"])
    flagged = list(dict.fromkeys(f["parameter"] for f in h["changes"]))
    ranked = sorted((p for p, e in h["parameters"].items() if e.get("trend_std")),
                    key=lambda p: -abs(h["parameters"][p]["trend_per_step"]) / h["parameters"][p]["trend_std"])
    shown = (flagged + [p for p in ranked if p not in flagged])[:6]
    if shown:
        fig = Figure(figsize=(8, 1.9 * len(shown) + 0.6))
        axes = fig.subplots(len(shown), 1, sharex=True, squeeze=False)
        for ax, p in zip(axes[:, 0], shown):
            e = h["parameters"][p]
            v = np.array([np.nan if x is None else x for x in e["value"]])
            s = np.array([np.nan if x is None else x for x in e["std"]])
            ax.errorbar(t, v, yerr=2 * h["dispersion_k"] * s, fmt="o-", ms=4, color="#1f77b4", lw=1, capsize=2)
            for f in e["changes"]:
                ax.plot(t[f["index"]], f["after"], "o", ms=11, mfc="none", mec="#d62728", mew=2)
                ax.annotate(f"{f['change']:+.3g} {f['unit']}", (t[f["index"]], f["after"]), textcoords="offset points",
                            xytext=(6, 6), color="#d62728", fontsize=8)
            ax.ticklabel_format(axis="y", useOffset=False)
            ax.set_ylabel(f"{p} ({e['unit']})", fontsize=8)
        axes[-1, 0].set_xticks(t, names if len(names) <= 24 else None, rotation=60, fontsize=7)
        axes[-1, 0].set_xlabel(h["time_axis"])
        out.append(("Parameters over time", "Each calibration's estimate with +- 2 std (scaled by the dispersion k); "
                    "a red ring is a change larger than the uncertainties explain. Flagged parameters first, then "
                    "the steepest trends.", png_base64(fig)))
    Z = np.array([[np.nan if x is None else x for x in row] for row in h["z"]], float)
    if Z.size and np.isfinite(Z).any():
        fig = Figure(figsize=(max(6, 0.2 * Z.shape[1] + 2), max(2.5, 0.25 * Z.shape[0] + 1.2)))
        ax = fig.subplots()
        im = ax.imshow(np.abs(Z), cmap="Reds", vmin=0, vmax=max(h["z_critical"] * 1.5, 1), aspect="auto",
                       interpolation="nearest")
        for i, j in zip(*np.nonzero(np.abs(np.nan_to_num(Z)) > h["z_critical"])):
            ax.text(j, i, "x", ha="center", va="center", fontsize=8)
        ax.set_xticks(np.arange(Z.shape[1]), h["parameter_names"], rotation=90, fontsize=6)
        ax.set_yticks(np.arange(Z.shape[0]), names, fontsize=7)
        fig.colorbar(im, ax=ax, label="|z| against the sessions before")
        out.append(("Every parameter, every session", f"|z| of each session against the agreeing sessions before "
                    f"it; x marks a change (|z| > {h['z_critical']:.2f}).", png_base64(fig)))
    return out


def _csv(h: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["session", "date", "parameter", "unit", "value", "std", "z", "change"])
    flags = {(f["parameter"], f["index"]): f for f in h["changes"]}
    for j, p in enumerate(h["parameter_names"]):
        e = h["parameters"][p]
        for i, name in enumerate(h["sessions"]):
            f = flags.get((p, i))
            z = h["z"][i][j]
            w.writerow([name, h["dates"][i] or "", p, e["unit"], "" if e["value"][i] is None else e["value"][i],
                        "" if e["std"][i] is None else e["std"][i], "" if z is None else f"{z:.4g}",
                        "" if f is None else f"{f['change']:.6g}"])
    return buf.getvalue()


def _html(h: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(f['session'])}</td><td>{html.escape(f['date'] or '')}</td>"
                   f"<td>{html.escape(f['parameter'])}</td><td>{f['before']:.5g}</td><td>{f['after']:.5g}</td>"
                   f"<td>{f['change']:+.4g} {html.escape(str(f['unit']))}</td><td>{f['z']:+.1f}</td></tr>"
                   for f in h["changes"])
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>platkit: history of a stand</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}table{border-collapse:"
             "collapse;font-size:13px}td,th{border:1px solid #ccc;padding:2px 6px}th{background:#eee}img{max-width:100%}"
             "</style></head><body>",
             f"<h1>History of the stand over {len(h['sessions'])} sessions</h1>",
             f"<p>{len(h['changes'])} changes larger than the uncertainties explain (family-wise level {h['alpha']:g} "
             f"over {h['n_tests']} tests: |z| &gt; {h['z_critical']:.2f}; calibrations' stds scaled by the observed "
             f"dispersion k = {h['dispersion_k']:.2f}). Time: {html.escape(h['time_axis'])}.</p>"]
    if rows:
        parts.append("<table><tr><th>session</th><th>date</th><th>parameter</th><th>before</th><th>after</th>"
                     "<th>change</th><th>z</th></tr>" + rows + "</table>")
    for title, caption, png in _plots(h):
        parts.append(f"<h2>{html.escape(title)}</h2><p>{html.escape(caption)}</p>"
                     f"<img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_history(sessions: list[SessionRef], batch: BatchFolder, alpha: float = ALPHA) -> tuple[dict, list[Path]]:
    """history.csv, history.json and history.html of the batch's calibrated sessions (a failed
    or missing session is left out, and said so in history.json's ``left_out``)."""
    ok = [r for r in sessions if (batch.sessions / r.name / "calibration.yaml").is_file()]
    left_out = [r.name for r in sessions if r not in ok]
    dates = [session_date(r.path) for r in ok]
    if any(d is not None for d in dates) and not all(d is not None for d in dates):
        missing = next(r.name for r, d in zip(ok, dates) if d is None)
        raise BadInput(f"{missing}: session.yaml has no 'date' while other sessions have one; date all or none")
    if all(d is not None for d in dates):
        order = sorted(range(len(ok)), key=lambda i: dates[i])
        ok, dates = [ok[i] for i in order], [dates[i] for i in order]
    h = stand_history([r.name for r in ok], [parameter_table(batch.sessions / r.name / "calibration.yaml") for r in ok],
                      dates, alpha)
    h["left_out"] = left_out
    with atomic_output_dir(batch.out) as tmp:
        (tmp / "history.csv").write_text(_csv(h), encoding="utf-8")
        (tmp / "history.json").write_text(dumps(h, indent=2) + "\n", encoding="utf-8")
        (tmp / "history.html").write_text(_html(h), encoding="utf-8")
    return h, [batch.out / n for n in ("history.csv", "history.json", "history.html")]
