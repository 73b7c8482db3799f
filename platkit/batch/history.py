"""The history of one stand: its calibrations over time, each parameter's trend with its
uncertainty, and the changes larger than the uncertainties explain (wear, a knock, a part).

Sessions are ordered by the ``date`` of their session.yaml (an ISO date or date-time) where every
session has one, else by the batch's (natural) folder order; sessions of one day are in the order
of their times, and by folder name where no time is given. Every date is read and checked before
any work (a bad one is a BadSession naming the file and the field). A history follows one stand:
sessions of different stands (platform, or description where none is given on the command line)
are refused in one line.

The sessions' calibrations are in one parameterisation (platkit.batch.gauge): the same free
parameters, the same gauge. A parameter a session did not identify (held at nominal there: its
poses do not excite it) has no value in that session; it is tested only between sessions that
identify it, and history.json says, per parameter, the sessions that did not.

Maintenance events (``maintenance.yaml`` beside the sessions, or ``--maintenance FILE``: a list of
``{date: ..., note: ...}``) are shown on the history, and each starts a new run of agreeing
sessions: the first session after it is not tested against those before (the stand was worked
on; a change there is explained), and the event is said instead. An event dated on a session's
day without a time comes before that session. For each parameter estimated in a session (value v_i, std
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
from platkit.batch.store import BatchFolder, SessionRef, natural_key
from platkit.errors import BadInput, BadSession
from platkit.io.atomic import atomic_output_dir
from platkit.io.description import load_yaml
from platkit.io.figures import png_base64
from platkit.io.jsonout import dumps
from platkit.io.session_yaml import iso_when

__all__ = ["ALPHA", "session_date", "session_when", "history_order", "check_one_stand", "read_maintenance",
           "stand_history", "write_history", "MAINTENANCE_FILE"]

#: the maintenance log beside the sessions (their common folder), read where present
MAINTENANCE_FILE = "maintenance.yaml"

#: family-wise level of the change tests (over every parameter and session)
ALPHA = 0.01
#: a robust (MAD) sigma from a median absolute value
MAD_TO_SIGMA = 1.4826


def session_when(folder: Path) -> dt.datetime | dt.date | None:
    """The ``date`` of a session's session.yaml: a date, a date-time (naive, UTC where a zone is
    given), or None. A value that is neither is a BadSession naming the file and the field."""
    path = Path(folder) / "session.yaml"
    data = load_yaml(path, error=BadSession)  # a date YAML cannot build (2026-02-30) is refused there
    value = data.get("date") if isinstance(data, dict) else None
    return None if value is None else iso_when(value, path, "date")


def session_date(folder: Path) -> dt.date | None:
    """The day of a session's ``date`` (see :func:`session_when`), or None."""
    when = session_when(folder)
    return when.date() if isinstance(when, dt.datetime) else when


def _sort_key(when, name: str) -> tuple:
    day = when.date() if isinstance(when, dt.datetime) else when
    clock = when.time() if isinstance(when, dt.datetime) else None
    # within a day: timed sessions by their time, untimed ones by folder name after... the folder name decides
    # between two sessions without a time, and a session without a time is placed by its name among the others
    return (day, clock is None, clock or dt.time(), natural_key(name))


def history_order(names: list[str], whens: list) -> tuple[list[int], str]:
    """The sessions' order in the history: by ``whens`` (session_when of each) where every
    session has one, within a day by time and else by folder name; by folder name where none has
    one. Returns the indices and what the time axis is. Some dated and some not is bad input
    naming a session without."""
    if all(w is None for w in whens):
        return list(range(len(names))), "session (folder order)"
    if any(w is None for w in whens):
        missing = next(n for n, w in zip(names, whens) if w is None)
        raise BadInput(f"{missing}: session.yaml has no 'date' while other sessions have one; date all or none")
    order = sorted(range(len(names)), key=lambda i: _sort_key(whens[i], names[i]))
    return order, "days since the first session"


def _days(whens: list) -> np.ndarray:
    """Days since the first of ``whens`` (dates at midnight), fractional for date-times."""
    ts = [w if isinstance(w, dt.datetime) else dt.datetime.combine(w, dt.time()) for w in whens]
    return np.array([(t - ts[0]).total_seconds() / 86400.0 for t in ts], float)


def check_one_stand(stands: list[tuple[str, str]], names: list[str]) -> None:
    """A history follows one stand: ``stands`` (one (platform, description identity) per
    session) must all be equal, else bad input in one line naming the first two that differ."""
    first = stands[0]
    for name, st in zip(names, stands):
        if st != first:
            what = "stand" if st[0] != first[0] else "description"
            raise BadInput(f"a history follows one stand: {names[0]} is {first[0]} ({first[1]}), {name} is {st[0]} "
                           f"({st[1]}); a different {what}. Run one history per stand (or give --description)")


def read_maintenance(path: str | Path) -> list[dict]:
    """The maintenance events of ``path`` (YAML: a list of {date, note}), in time order: each
    ``{"date": ISO text, "when": date or datetime, "note": text}``. An entry without a valid date or
    a note is bad input naming the file and the entry."""
    import yaml

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{p}: cannot be read ({exc})") from None
    except (yaml.YAMLError, ValueError) as exc:
        raise BadInput(f"{p}: not valid YAML, or a date in it is not a date ({str(exc).splitlines()[0]})") from None
    if data is None:
        return []
    if not isinstance(data, list):
        raise BadInput(f"{p}: expected a list of events, each {{date: 2026-05-01, note: what was done}}")
    out = []
    for k, e in enumerate(data, 1):
        if not isinstance(e, dict) or "date" not in e or not str(e.get("note") or "").strip():
            raise BadInput(f"{p}: event {k}: needs a 'date' and a 'note', got {e!r}")
        unknown = sorted(set(e) - {"date", "note"})
        if unknown:
            raise BadInput(f"{p}: event {k}: unknown field {unknown[0]!r} (fields: date, note)")
        when = iso_when(e["date"], p, f"date' of event '{k}", error=BadInput)
        out.append({"date": when.isoformat(), "when": when, "note": str(e["note"]).strip()})
    return sorted(out, key=lambda e: _sort_key(e["when"], ""))


def _event_before(event_when, session_when) -> bool:
    """The event happened before the session (a date-only event on the session's day: before it)."""
    a = event_when if isinstance(event_when, dt.datetime) else dt.datetime.combine(event_when, dt.time.min)
    b = session_when if isinstance(session_when, dt.datetime) else dt.datetime.combine(session_when, dt.time.max)
    return a <= b


def stand_history(names: list[str], tables: list[dict[str, dict]], dates: list,
                  alpha: float = ALPHA, events: list[dict] | None = None) -> dict:
    """The history mapping (history.json) of sessions ``names`` in time order, with their
    calibrations' parameter tables (fleet.parameter_table), dates or date-times (all or none
    given) and maintenance ``events`` (read_maintenance; they need the dates)."""
    n = len(names)
    if n < 2:
        raise BadInput(f"a history needs 2 or more sessions of the stand, got {n}")
    events = list(events or [])
    dated = all(d is not None for d in dates)
    if events and not dated:
        raise BadInput("maintenance events are placed by date: give every session a 'date' in session.yaml")
    # the events between each session and the one before it (each starts a new run of agreeing sessions)
    between: dict[int, list[dict]] = {}
    for e in events:
        after = [i for i in range(n) if _event_before(e["when"], dates[i])]
        if after and after[0] > 0:
            between.setdefault(after[0], []).append(e)
    if dated:
        time = _days(dates)
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
            if segment and any(k in between for k in range(segment[-1] + 1, i + 1)):
                segment = []  # worked on since: a new run of agreeing sessions starts here, untested
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
        if len(idx) >= 3 and np.ptp(time[idx]) > 0:  # sessions all at one time have no trend
            t, v, w = time[idx], V[idx, j], 1 / S[idx, j] ** 2
            A = np.stack([np.ones_like(t), t - t.mean()], axis=1)
            cov = np.linalg.inv(A.T @ (w[:, None] * A))
            coef = cov @ A.T @ (w * v)
            entry["trend_per_step"] = float(coef[1])
            entry["trend_std"] = float(k * np.sqrt(cov[1, 1]))
        entry["not_identified_in"] = [names[i] for i in range(n)
                                      if (tables[i].get(p) or {}).get("status") == "held_at_nominal"]
        parameters[p] = entry
    changes.sort(key=lambda f: (f["index"], -abs(f["z"])))
    tested = [p for j, p in enumerate(pnames) if np.isfinite(V[:, j]).sum() >= 2]
    partly = {p: e["not_identified_in"] for p, e in parameters.items() if e["not_identified_in"] and p in tested}
    nowhere = [p for j, p in enumerate(pnames) if not np.isfinite(V[:, j]).any()]
    shown_events = [{"date": e["date"], "note": e["note"],
                     "before_session": next((names[i] for i in range(n) if _event_before(e["when"], dates[i])), None)}
                    for e in events]
    return {"sessions": names, "dates": [None if d is None else d.isoformat() for d in dates], "time": time.tolist(),
            "events": shown_events,
            "tested_on": {"parameters": tested, "not_identified_in": partly, "never_estimated": nowhere,
                          "rule": "a parameter is tested between sessions that both identify it (estimated there); "
                                  "a session that held it at nominal has no value for it"},
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
            for ev in h.get("events", []):
                if ev["before_session"] is not None:
                    x_ev = t[names.index(ev["before_session"])] - 0.5 * (np.min(np.diff(t)) if len(t) > 1 and
                                                                           np.min(np.diff(t)) > 0 else 0.5)
                    ax.axvline(x_ev, color="#2ca02c", ls="--", lw=1)
            ax.ticklabel_format(axis="y", useOffset=False)
            ax.set_ylabel(f"{p} ({e['unit']})", fontsize=8)
        axes[-1, 0].set_xticks(t, names if len(names) <= 24 else None, rotation=60, fontsize=7)
        axes[-1, 0].set_xlabel(h["time_axis"])
        out.append(("Parameters over time", "Each calibration's estimate with +- 2 std (scaled by the dispersion k); "
                    "a red ring is a change larger than the uncertainties explain; a green dashed line a maintenance "
                    "event (the session after it starts a new run, untested). Flagged parameters first, then "
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
    if h.get("events"):
        ev = "".join(f"<tr><td>{html.escape(e['date'])}</td><td>{html.escape(e['note'])}</td>"
                     f"<td>{html.escape(e['before_session'] or '(after the last session)')}</td></tr>" for e in h["events"])
        parts.append("<h2>Maintenance</h2><p>Each event starts a new run of agreeing sessions: the session after it is "
                     "not tested against those before.</p><table><tr><th>date</th><th>note</th><th>before session"
                     "</th></tr>" + ev + "</table>")
    t_on = h.get("tested_on") or {}
    if t_on:
        partly = t_on.get("not_identified_in") or {}
        text = (f"Tested on {len(t_on['parameters'])} parameters, each between the sessions that identify it. ")
        if partly:
            text += "Not identified (held at nominal) in some sessions, so not tested there: " + "; ".join(
                f"{p} in {', '.join(v)}" for p, v in partly.items()) + ". "
        if t_on.get("never_estimated"):
            text += f"Never estimated (held in every session: a gauge, or not asked for): {len(t_on['never_estimated'])}."
        parts.append(f"<p>{html.escape(text)}</p>")
    for title, caption, png in _plots(h):
        parts.append(f"<h2>{html.escape(title)}</h2><p>{html.escape(caption)}</p>"
                     f"<img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_history(sessions: list[SessionRef], batch: BatchFolder, alpha: float = ALPHA,
                  events: list[dict] | None = None) -> tuple[dict, list[Path]]:
    """history.csv, history.json and history.html of the batch's calibrated sessions (a failed
    or missing session is left out, and said so in history.json's ``left_out``), with the
    maintenance ``events`` (read_maintenance)."""
    ok = [r for r in sessions if (batch.sessions / r.name / "calibration.yaml").is_file()]
    left_out = [r.name for r in sessions if r not in ok]
    whens = [session_when(r.path) for r in ok]
    order, _ = history_order([r.name for r in ok], whens)
    ok, whens = [ok[i] for i in order], [whens[i] for i in order]
    h = stand_history([r.name for r in ok], [parameter_table(batch.sessions / r.name / "calibration.yaml") for r in ok],
                      whens, alpha, events)
    h["left_out"] = left_out
    with atomic_output_dir(batch.out) as tmp:
        (tmp / "history.csv").write_text(_csv(h), encoding="utf-8")
        (tmp / "history.json").write_text(dumps(h, indent=2) + "\n", encoding="utf-8")
        (tmp / "history.html").write_text(_html(h), encoding="utf-8")
    return h, [batch.out / n for n in ("history.csv", "history.json", "history.html")]
