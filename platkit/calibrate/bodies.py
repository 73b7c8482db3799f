"""Rigid bodies measured in 6 DOF: rotation algebra, averaging, and the weight of rotation against position.

A body T is measured as its frame's origin (m) and orientation (unit quaternion qw, qx, qy, qz),
both in the motion-capture frame. Its placement on the moving part (origin p_T, m, and rotation
vector phi_T, rad, in the moving frame) is unknown and calibrated like a marker's position.
The estimator (:class:`platkit.calibrate.problem.CalibrationProblem`) gives each body two
residual channels of three numbers: the origin's error (m, like a marker), and the rotation vector
of R_meas^T R_pred scaled by rho = sigma_position / sigma_rotation (m/rad), so that both channels
are metres of equal noise. rho is declared in session.yaml (``rigid_body_noise: {position_mm,
rotation_deg}``) or estimated from the residuals after a first fit (:func:`estimate_rho`).
"""
from __future__ import annotations

import numpy as np

from platkit.geometry import matrix_from_quat, quat_from_matrix, skew

#: rho (m/rad) before anything is known: a mocap body's 0.1 mm per 1 mrad (0.057 deg)
DEFAULT_RHO_M_PER_RAD = 0.1
#: length (m) of the virtual axes that give a body's frame three points for the initial registration
AXIS_LENGTH_M = 0.1
#: Median of the 3-D error norm of isotropic Gaussian noise, in units of the per-axis sigma.
_MAXWELL_MEDIAN = 1.5381722


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad, angle in [0, pi], of rotation matrices (..., 3, 3)."""
    q = quat_from_matrix(R)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    k = np.where(s < 1e-12, 2.0, angle / np.where(s < 1e-12, 1.0, s))
    return q[..., 1:] * k[..., None]


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3) (..., 3, 3): exp(phi + d) = exp(phi) exp(J_r(phi) d) to first order."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th ** 2 / 24.0, (1.0 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0 - th ** 2 / 120.0, (t - np.sin(t)) / t ** 3)
    return np.eye(3) - a * K + b * (K @ K)


def right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`right_jacobian` (..., 3, 3): log(exp(phi) exp(d)) = phi + J_r^-1(phi) d."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th ** 2 / 720.0, 1.0 / t ** 2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) + 0.5 * K + c * (K @ K)


def quat_mean(q: np.ndarray) -> np.ndarray:
    """Mean orientation (4,) of unit quaternions q (K, 4) (qw, qx, qy, qz): the principal eigenvector of
    sum q q^T (Markley's mean, blind to each sample's sign), returned with qw >= 0."""
    q = np.asarray(q, float)
    _, V = np.linalg.eigh(q.T @ q)
    m = V[:, -1]
    return m if m[0] >= 0 else -m


def average_body(samples: np.ndarray) -> tuple[np.ndarray, int]:
    """Settled body pose (7,) from samples (K, 7) (x, y, z m; qw, qx, qy, qz): positions averaged
    like a marker's, orientations by :func:`quat_mean`; rows with any NaN (occluded) are left out.
    Returns (pose, number of samples averaged); all NaN and 0 when none was seen."""
    samples = np.asarray(samples, float)
    seen = np.all(np.isfinite(samples), axis=1)
    if not seen.any():
        return np.full(7, np.nan), 0
    s = samples[seen]
    return np.concatenate([s[:, :3].mean(axis=0), quat_mean(s[:, 3:])]), int(seen.sum())


def declared_rho(body_noise: dict) -> float | None:
    """rho (m/rad) from a PoseSet's declared body noise ({'position_m', 'rotation_rad'}), or None."""
    if not body_noise:
        return None
    return float(body_noise["position_m"]) / float(body_noise["rotation_rad"])


def estimate_rho(pos_residuals: np.ndarray, rot_residuals: np.ndarray) -> float | None:
    """rho = sigma_position / sigma_rotation (m/rad) from the residuals of a fit: each sigma robustly
    (median of the 3-D norms over the Maxwell median), over the rows given.

    pos_residuals (K, 3) m, rot_residuals (K, 3) rad (unscaled). None when either is too small to
    say anything (fewer than 3 rows, or a zero scale).
    """
    p = np.linalg.norm(pos_residuals, axis=-1)
    r = np.linalg.norm(rot_residuals, axis=-1)
    p, r = p[np.isfinite(p)], r[np.isfinite(r)]
    if p.size < 3 or r.size < 3:
        return None
    sp, sr = np.median(p) / _MAXWELL_MEDIAN, np.median(r) / _MAXWELL_MEDIAN
    if not (sp > 0 and sr > 0):
        return None
    return float(sp / sr)


def body_frame_points(bodies: np.ndarray) -> np.ndarray:
    """Three points of each body's frame (N, 3 B, 3) m: its origin and the tips of its x and y axes at
    AXIS_LENGTH_M, for a registration that only knows points. bodies (N, B, 7); NaN stays NaN."""
    N, B, _ = bodies.shape
    seen = np.all(np.isfinite(bodies), axis=2)
    R = matrix_from_quat(np.where(seen[..., None], bodies[..., 3:], np.array([1.0, 0, 0, 0])))
    o = bodies[..., :3]
    pts = np.stack([o, o + AXIS_LENGTH_M * R[..., :, 0], o + AXIS_LENGTH_M * R[..., :, 1]], axis=2)
    pts[~seen] = np.nan
    return pts.reshape(N, 3 * B, 3)


def placement_from_frame_points(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body placements from the fitted frame points (B, 3, 3) of :func:`body_frame_points`:
    origins (B, 3) m and rotations (B, 3, 3) (Gram-Schmidt of the two axes)."""
    o = points[:, 0]
    x = points[:, 1] - o
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = points[:, 2] - o
    y -= np.sum(x * y, axis=1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return o, np.stack([x, y, np.cross(x, y)], axis=2)
