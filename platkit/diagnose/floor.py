"""How well held-out poses could be predicted at best: the noise floor of settled poses (what
marker noise alone leaves) and, for a lack of fit, the marker whose residuals stand out."""
from __future__ import annotations

import numpy as np

from platkit.poses import PoseSet


def noise_floor(poses: PoseSet, n_params: int) -> float | None:
    """The held-out RMS (m, of the 3-D marker error) that marker noise alone gives: each settled
    marker averages n samples of noise sigma per coordinate (sigma from the settling search), and
    a refit on the other folds adds its own error (about n_params / n_observations of it); a
    coloured noise averages less (its slow part, ``slow_noise_inflation`` of settle). None
    when the poses did not come from a stream (no sigma) or carry no sample counts."""
    sigma = (poses.settling or {}).get("sigma_m")
    if sigma is None or poses.n_samples is None:
        return None
    sigma = sigma * np.sqrt((poses.settling or {}).get("slow_noise_inflation", 1.0))  # coloured noise averages less
    n = np.asarray(poses.n_samples, float)
    seen = np.all(np.isfinite(poses.markers), axis=2) & (n > 0)
    if not seen.any():
        return None
    ms = float(np.mean(3.0 * sigma**2 / n[seen]))
    return float(np.sqrt(ms * (1.0 + n_params / (3.0 * seen.sum()))))


def worst_marker(residuals: np.ndarray, poses: PoseSet) -> str | None:
    """The marker whose fit residuals (N, M, 3) are largest (RMS over the poses that saw it), when
    it stands out (1.5 times the median marker's): a marker moving against the others; else None."""
    r = np.asarray(residuals, float)
    seen = np.isfinite(r).all(axis=2)
    per = np.array([np.sqrt(np.mean(np.sum(r[seen[:, m], m] ** 2, axis=1))) if seen[:, m].any() else 0.0
                    for m in range(r.shape[1])])
    if per.size < 2 or not np.median(per) > 0:
        return None
    k = int(np.argmax(per))
    return poses.marker_names[k] if per[k] > 1.5 * np.median(per) else None
