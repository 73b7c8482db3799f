"""The outputs of ``platkit orient``: orientation.csv, report.json, report.html.

orientation.csv: ``t,qw,qx,qy,qz``, the platform frame in the base frame (spec section 2), t in
seconds on the session's clock. report.json: the settings found (bias, alignment, latency), the
warnings, and, when the session holds the truth, the errors in degrees. report.html: the same
with plots, inline SVG (orientation over time; errors over time when the truth is known).
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from platkit.geometry import rpy_from_quat
from platkit.inertial.orient import OrientResult
from platkit.io import jsonout
from platkit.io.atomic import atomic_output_dir
from platkit.io.svgplot import line_plot


def orientation_csv(t: np.ndarray, q: np.ndarray) -> str:
    # one %-format over every row at once: the same text as a row-by-row f-string, in a third of the time
    data = np.column_stack([t, q]).ravel().tolist()
    return "t,qw,qx,qy,qz\n" + ("%.9g,%.9f,%.9f,%.9f,%.9f\n" * len(t)) % tuple(data)


def _plots(result: OrientResult) -> list[tuple[str, str]]:
    """(title, inline SVG) of each plot (platkit.io.svgplot: no matplotlib to import, which
    alone would cost the verb more than its estimate); at most about 4000 points per line."""
    out = []
    step = max(1, len(result.t) // 4000)
    rpy = np.degrees(rpy_from_quat(result.q[::step]))
    series = [(result.t[::step], rpy[:, j], name, "") for j, name in enumerate(("roll", "pitch", "yaw"))]
    if result.truth is not None:
        tt, qt = result.truth
        s2 = max(1, len(tt) // 4000)
        rt = np.degrees(rpy_from_quat(qt[::s2]))
        series += [(tt[::s2], rt[:, j], "truth", "dotted") for j in range(3)]
    out.append(("Orientation (roll, pitch, yaw of the platform in the base frame; dotted: truth)",
                line_plot(series, "t [s]", "deg")))
    if result.errors:
        e = result.errors
        s2 = max(1, len(e["t"]) // 4000)
        series = [(e["t"][::s2], np.degrees(e[k][::s2]), label, "") for k, label in
                  (("inclination", "inclination"), ("total", "total"), ("total_heading_aligned", "total, heading aligned"))]
        out.append(("Error against the truth", line_plot(series, "t [s]", "error [deg]")))
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
    for title, svg in _plots(result):
        parts.append(f"<h2>{html.escape(title)}</h2>{svg}")
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
