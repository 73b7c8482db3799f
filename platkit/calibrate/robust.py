"""Robust statistics of 3-D point errors, shared by the registration and the solvers.

An error is the norm of a predicted minus a measured point; for isotropic Gaussian noise of sigma
per axis it follows a Maxwell distribution, whose median is MAXWELL_MEDIAN sigma.
"""
from __future__ import annotations

import numpy as np

#: Median of the 3-D error norm of isotropic Gaussian noise, in units of the per-axis sigma.
MAXWELL_MEDIAN = 1.5381722
HUBER_K = 3.0  # Huber threshold on the 3-D error, in sigma
REJECT_K = 4.5  # errors beyond this many sigma are outliers (P < 1e-3 for clean 3-D noise)


def robust_sigma(d: np.ndarray) -> float:
    """Per-axis noise sigma from 3-D error norms, robustly (median)."""
    d = d[np.isfinite(d)]
    return float(np.median(d) / MAXWELL_MEDIAN) if d.size else float("nan")
