"""Figures for the HTML reports: a matplotlib figure as inline PNG (base64)."""
from __future__ import annotations

import base64
import io


def png_base64(fig) -> str:
    """The figure as a base64 PNG (90 dpi, tight), for an ``<img src='data:image/png;base64,...'>``;
    closes the figure."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")
