"""Orientation errors against a truth, with the definitions of Laidig et al. 2021 (BROAD; reading
and scoring that data set is tests/real_data/broad.py).

For an estimate q and a truth q_true (scalar first, both "frame in the earth frame"), the error
is taken in the earth frame, e = q * conj(q_true) = (w, x, y, z):
total 2 acos|w|, heading 2 atan(|z| / |w|), inclination 2 acos(sqrt(w^2 + z^2)). Inclination
does not change when the estimate is turned about the vertical, so estimators without a
magnetometer are scored by it. Radians inside; the ``*_deg`` helpers are for reports.
"""
from __future__ import annotations

import numpy as np

from platkit.geometry import quat_conjugate, quat_multiply


def earth_error(q_est: np.ndarray, q_true: np.ndarray) -> np.ndarray:
    """e = q_est * conj(q_true), (N, 4)."""
    e = quat_multiply(np.asarray(q_est, float), quat_conjugate(np.asarray(q_true, float)))
    return e / np.linalg.norm(e, axis=-1, keepdims=True)


def inclination_error(q_est, q_true) -> np.ndarray:
    """Inclination (roll and pitch) error per sample, rad (N,); NaN where the truth is NaN."""
    e = earth_error(q_est, q_true)
    return 2.0 * np.arccos(np.clip(np.sqrt(e[..., 0] ** 2 + e[..., 3] ** 2), 0.0, 1.0))


def heading_error(q_est, q_true) -> np.ndarray:
    """Heading error per sample, rad (N,)."""
    e = earth_error(q_est, q_true)
    return 2.0 * np.arctan(np.abs(e[..., 3]) / np.abs(e[..., 0]))


def total_error(q_est, q_true) -> np.ndarray:
    """Total rotation angle between estimate and truth per sample, rad (N,)."""
    e = earth_error(q_est, q_true)
    return 2.0 * np.arccos(np.clip(np.abs(e[..., 0]), 0.0, 1.0))


def rmse(err: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root mean square over ``mask`` (all samples if None), ignoring NaN (lost truth)."""
    err = np.asarray(err, float)
    if mask is not None:
        err = err[np.asarray(mask, bool)]
    err = err[np.isfinite(err)]
    if err.size == 0:
        return float("nan")
    return float(np.sqrt(np.mean(err**2)))


def inclination_rmse_deg(q_est, q_true, mask=None) -> float:
    """Inclination RMSE over ``mask`` (all samples if None; BROAD scores movement == 1), degrees."""
    return float(np.degrees(rmse(inclination_error(q_est, q_true), mask)))


def heading_aligned_total_error(q_est, q_true, mask=None) -> np.ndarray:
    """Total error after removing the best constant heading offset (fitted over ``mask``), rad (N,).

    For estimators whose heading is relative (no magnetometer, no command aiding) this is the
    error that remains once the unobservable starting heading is fixed.
    """
    e = earth_error(q_est, q_true)
    sel = np.isfinite(e[:, 0]) if mask is None else (np.asarray(mask, bool) & np.isfinite(e[:, 0]))
    # heading angle of each error's vertical component; average it on the circle
    psi = 2.0 * np.arctan2(e[sel, 3], e[sel, 0])
    psi0 = np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi)))
    rot = np.array([np.cos(psi0 / 2), 0.0, 0.0, -np.sin(psi0 / 2)])
    return total_error(quat_multiply(rot, q_est), q_true)
