"""How well held-out poses could be predicted at best: the noise floor of settled poses (what
marker noise alone leaves) and, for a lack of fit, the marker whose residuals stand out."""
from __future__ import annotations

import numpy as np

from platkit.poses import PoseSet


def noise_floor(poses: PoseSet, n_params: int) -> float | None:
    """The held-out RMS (m, of the 3-D marker error) that marker noise alone gives: each settled
    marker averages n samples of noise sigma per coordinate (sigma from the settling search; a
    point standing for a rigid body, platkit.diagnose.bodies, its own from
    ``settling['point_sigma_m']``), and a refit on the other folds adds its own error (about
    n_params / n_observations of it); a coloured noise averages less (its slow part,
    ``slow_noise_inflation`` of settle). None when a seen marker has no sigma (poses not from a
    stream, no declared body noise) or the poses carry no sample counts."""
    settling = poses.settling or {}
    sigma, own = settling.get("sigma_m"), settling.get("point_sigma_m") or {}
    if poses.n_samples is None:
        return None
    col = np.array([own.get(name, np.nan if sigma is None else sigma) for name in poses.marker_names], float)
    col = col * np.sqrt(settling.get("slow_noise_inflation", 1.0))  # coloured noise averages less
    n = np.asarray(poses.n_samples, float)
    seen = np.all(np.isfinite(poses.markers), axis=2) & (n > 0)
    if not seen.any() or not np.all(np.isfinite(col[seen.any(axis=0)])):
        return None
    ms = float(np.mean((3.0 * col[None, :] ** 2 / np.where(seen, n, 1.0))[seen]))
    return float(np.sqrt(ms * (1.0 + n_params / (3.0 * seen.sum()))))


def pose_words(poses: PoseSet) -> str:
    """What the poses are, said in a sentence: 'windowed poses' for a stream without holds read
    through its response (its nodes in ``extras['node']``: platkit.calibrate.motion.motion_stream),
    else 'settled poses'."""
    return "windowed poses" if "node" in poses.extras else "settled poses"


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
