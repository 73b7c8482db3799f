"""Line plots as inline SVG, for HTML reports drawn without matplotlib (whose import alone costs
a short verb more than its computation): axes with round ticks, one polyline per series, a legend.
"""
from __future__ import annotations

import html
import math

import numpy as np

#: colours of the series, in order (matplotlib's first four, so the reports look alike)
COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


def _ticks(lo: float, hi: float, n: int = 6) -> list[float]:
    """Round tick values (steps of 1, 2 or 5 times a power of ten) covering [lo, hi]."""
    if not hi > lo:
        return [lo]
    raw = (hi - lo) / n
    p = 10.0 ** math.floor(math.log10(raw))
    step = next(m * p for m in (1, 2, 5, 10) if m * p >= raw)
    first = math.ceil(lo / step) * step
    return [first + k * step for k in range(int((hi - first) / step + 1e-9) + 1)]


def line_plot(series: list[tuple[np.ndarray, np.ndarray, str, str]], xlabel: str, ylabel: str,
              width: int = 810, height: int = 290) -> str:
    """An ``<svg>`` element: ``series`` of (x, y, label, style) with style "" (a solid line in the
    next colour) or "dotted" (a thin black dotted line, not in the legend). Non-finite points
    break a line."""
    left, right, top, bottom = 60, 10, 10, 40
    pw, ph = width - left - right, height - top - bottom
    xs = [np.asarray(x, float) for x, *_ in series]
    ys = [np.asarray(y, float) for _, y, *_ in series]
    fx = np.concatenate([x[np.isfinite(x)] for x in xs]) if xs else np.zeros(1)
    fy = np.concatenate([y[np.isfinite(y)] for y in ys]) if ys else np.zeros(1)
    x0, x1 = (float(fx.min()), float(fx.max())) if fx.size else (0.0, 1.0)
    y0, y1 = (float(fy.min()), float(fy.max())) if fy.size else (0.0, 1.0)
    if x1 <= x0:
        x0, x1 = x0 - 0.5, x0 + 0.5
    pad = 0.05 * (y1 - y0) if y1 > y0 else 0.5
    y0, y1 = y0 - pad, y1 + pad

    def px(x):
        return left + (np.asarray(x) - x0) / (x1 - x0) * pw

    def py(y):
        return top + (y1 - np.asarray(y)) / (y1 - y0) * ph

    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' "
           f"viewBox='0 0 {width} {height}' font-family='sans-serif' font-size='11'>",
           f"<rect x='{left}' y='{top}' width='{pw}' height='{ph}' fill='none' stroke='#000'/>"]
    for v in _ticks(x0, x1):
        X = float(px(v))
        out.append(f"<line x1='{X:.1f}' y1='{top + ph}' x2='{X:.1f}' y2='{top + ph + 4}' stroke='#000'/>"
                   f"<text x='{X:.1f}' y='{top + ph + 16}' text-anchor='middle'>{v:g}</text>")
    for v in _ticks(y0, y1):
        Y = float(py(v))
        out.append(f"<line x1='{left - 4}' y1='{Y:.1f}' x2='{left}' y2='{Y:.1f}' stroke='#000'/>"
                   f"<text x='{left - 6}' y='{Y + 4:.1f}' text-anchor='end'>{v:g}</text>")
    out.append(f"<text x='{left + pw / 2}' y='{height - 6}' text-anchor='middle'>{html.escape(xlabel)}</text>")
    out.append(f"<text x='14' y='{top + ph / 2}' text-anchor='middle' "
               f"transform='rotate(-90 14 {top + ph / 2})'>{html.escape(ylabel)}</text>")
    legend = []
    colour = iter(COLOURS * 4)
    for x, y, (_, _, label, style) in zip(xs, ys, series):
        stroke = "stroke='#000' stroke-width='0.6' stroke-dasharray='1,2'" if style == "dotted" else \
            f"stroke='{(c := next(colour))}' stroke-width='0.9'"
        if style != "dotted":
            legend.append((label, c))
        ok = np.isfinite(x) & np.isfinite(y)
        # one polyline per finite run
        edges = np.flatnonzero(np.diff(np.r_[0, ok.astype(np.int8), 0]))
        P = np.column_stack([px(np.where(ok, x, x0)), py(np.where(ok, y, y0))])
        for a, b in zip(edges[::2], edges[1::2]):
            pts = " ".join(f"{u:.1f},{v:.1f}" for u, v in P[a:b])
            out.append(f"<polyline fill='none' {stroke} points='{pts}'/>")
    for k, (label, c) in enumerate(legend):
        Y = top + 14 + 14 * k
        out.append(f"<line x1='{left + pw - 120}' y1='{Y - 4}' x2='{left + pw - 100}' y2='{Y - 4}' stroke='{c}' "
                   f"stroke-width='2'/><text x='{left + pw - 95}' y='{Y}'>{html.escape(label)}</text>")
    out.append("</svg>")
    return "".join(out)
