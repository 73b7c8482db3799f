"""Figures for the HTML reports: a matplotlib figure as inline PNG (base64)."""
from __future__ import annotations

import base64
import io


def png_base64(fig, tight: bool = True) -> str:
    """The figure as a base64 PNG (90 dpi), for an ``<img src='data:image/png;base64,...'>``.
    ``tight``: cropped to what is drawn (matplotlib then draws the figure twice); a figure with
    a layout engine of its own (``layout="constrained"``) needs no cropping. A figure made by
    pyplot is closed; a bare ``matplotlib.figure.Figure`` (no pyplot) has nothing to close."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, **({"bbox_inches": "tight"} if tight else {}))
    if getattr(fig.canvas, "manager", None) is not None:  # registered with pyplot
        import matplotlib.pyplot as plt

        plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")
