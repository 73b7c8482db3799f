"""The outputs of ``platkit orient``: orientation.csv, report.json, report.html.

orientation.csv: ``t,qw,qx,qy,qz``, the platform frame in the base frame (spec section 2), t in
seconds on the session's clock. report.json: the settings found (bias, alignment, latency), the
warnings, and, when the session holds the truth, the errors in degrees. report.html: the same
with plots (orientation over time; errors over time when the truth is known).
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from platkit.geometry import rpy_from_quat
from platkit.inertial.orient import OrientResult
from platkit.io import jsonout
from platkit.io.atomic import atomic_output_dir
from platkit.io.figures import png_base64 as _png


def orientation_csv(t: np.ndarray, q: np.ndarray) -> str:
    rows = ["t,qw,qx,qy,qz"]
    rows += [f"{ti:.9g},{a:.9f},{b:.9f},{c:.9f},{d:.9f}" for ti, (a, b, c, d) in zip(t, q)]
    return "\n".join(rows) + "\n"


def _plots(result: OrientResult) -> list[tuple[str, str]]:
    """(title, base64 PNG) of each plot; bare matplotlib Figures (no pyplot state, the user's
    backend untouched)."""
    from matplotlib.figure import Figure  # matplotlib only when drawing: the verb's start-up

    out = []
    step = max(1, len(result.t) // 4000)
    rpy = np.degrees(rpy_from_quat(result.q[::step]))
    fig = Figure(figsize=(9, 3.2))
    ax = fig.subplots()
    for j, name in enumerate(("roll", "pitch", "yaw")):
        ax.plot(result.t[::step], rpy[:, j], lw=0.8, label=name)
    if result.truth is not None:
        tt, qt = result.truth
        s2 = max(1, len(tt) // 4000)
        rt = np.degrees(rpy_from_quat(qt[::s2]))
        for j in range(3):
            ax.plot(tt[::s2], rt[:, j], "k:", lw=0.6)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("deg")
    ax.legend(loc="upper right", fontsize=8)
    out.append(("Orientation (roll, pitch, yaw of the platform in the base frame; dotted: truth)", _png(fig)))
    if result.errors:
        e = result.errors
        s2 = max(1, len(e["t"]) // 4000)
        fig = Figure(figsize=(9, 3.2))
        ax = fig.subplots()
        ax.plot(e["t"][::s2], np.degrees(e["inclination"][::s2]), lw=0.8, label="inclination")
        ax.plot(e["t"][::s2], np.degrees(e["total"][::s2]), lw=0.8, label="total")
        ax.plot(e["t"][::s2], np.degrees(e["total_heading_aligned"][::s2]), lw=0.8, label="total, heading aligned")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("error [deg]")
        ax.legend(loc="upper right", fontsize=8)
        out.append(("Error against the truth", _png(fig)))
    return out


def report_html(result: OrientResult) -> str:
    r = result.report
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>platkit orient</title>",
             "<style>body{font-family:sans-serif;max-width:60em;margin:auto}pre{background:#f4f4f4;padding:.5em}</style>",
             "</head><body>", f"<h1>Orientation of {html.escape(r['session'])}</h1>",
             f"<p>Method <b>{html.escape(r['method'])}</b>; {r['n_samples']} samples at {r['rate_hz']:.4g} Hz; "
             f"heading {html.escape(r.get('heading', ''))}.</p>"]
    if "truth" in r:
        t = r["truth"]
        parts.append(f"<p>Against the truth ({t['n_samples']} samples): inclination RMSE "
                     f"<b>{t['inclination_rmse_deg']:.3f} deg</b> (max {t['inclination_max_deg']:.3f}), total RMSE "
                     f"{t['total_rmse_deg']:.3f} deg, with the heading aligned "
                     f"{t['total_rmse_heading_aligned_deg']:.3f} deg.</p>")
    if r.get("warnings"):
        parts.append("<h2>Warnings</h2><ul>" + "".join(f"<li>{html.escape(w)}</li>" for w in r["warnings"]) + "</ul>")
    for title, png in _plots(result):
        parts.append(f"<h2>{html.escape(title)}</h2><img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    parts.append("<h2>report.json</h2><pre>" + html.escape(jsonout.dumps(r, indent=2)) + "</pre>")
    parts.append("</body></html>")
    return "\n".join(parts)


def write_outputs(result: OrientResult, out_dir: str | Path) -> list[Path]:
    """Write orientation.csv, report.json, report.html into ``out_dir`` (whole or not at all)."""
    names = ["orientation.csv", "report.json", "report.html"]
    with atomic_output_dir(out_dir) as tmp:
        (tmp / "orientation.csv").write_text(orientation_csv(result.t, result.q), encoding="utf-8")
        (tmp / "report.json").write_text(jsonout.dumps(result.report, indent=2) + "\n", encoding="utf-8")
        (tmp / "report.html").write_text(report_html(result), encoding="utf-8")
    return [Path(out_dir) / n for n in names]
