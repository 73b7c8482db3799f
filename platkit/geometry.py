"""Rotations and rigid transforms, numeric (numpy) and symbolic (CasADi).

Quaternions are scalar first, ``(w, x, y, z)``, and unit. ``R = Rz(yaw) Ry(pitch) Rx(roll)``
is the roll-pitch-yaw convention of the spec. Transforms are named ``a_from_b``: a 4x4 matrix
that maps homogeneous coordinates in frame b to frame a.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

# ----------------------------------------------------------------------------- numeric


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) with w >= 0. ``q``: (..., 4)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    sign = np.where(q[..., :1] < 0, -1.0, 1.0)
    return q * sign


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a*b of (..., 4) arrays."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def matrix_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4)."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4), w >= 0, from rotation matrices (..., 3, 3) (scipy's batched
    conversion; a matrix a little off orthonormal is taken as its nearest rotation)."""
    # here, not at the top: scipy.spatial costs every verb's start-up a noticeable share
    from scipy.spatial.transform import Rotation  # type: ignore[import-untyped]

    R = np.asarray(R, float)
    flat = R.reshape(-1, 3, 3)
    if flat.shape[0] == 0:
        return np.zeros(R.shape[:-2] + (4,))
    out = Rotation.from_matrix(flat).as_quat(canonical=True, scalar_first=True)
    return quat_normalize(out.reshape(R.shape[:-2] + (4,)))


def matrix_from_rpy(roll, pitch, yaw) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll); broadcasts over array arguments -> (..., 3, 3)."""
    roll, pitch, yaw = np.broadcast_arrays(*(np.asarray(a, float) for a in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack(
        [
            np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
            np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
            np.stack([-sp, cp * sr, cp * cr], -1),
        ],
        axis=-2,
    )


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) (..., 3) with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    R = np.asarray(R, float)
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    pitch = np.arcsin(np.clip(-R[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def quat_from_rpy(roll, pitch, yaw) -> np.ndarray:
    return quat_from_matrix(matrix_from_rpy(roll, pitch, yaw))


def rpy_from_quat(q: np.ndarray) -> np.ndarray:
    return rpy_from_matrix(matrix_from_quat(q))


def matrix_from_rotvec(v: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrices (..., 3, 3) from rotation vectors (..., 3) in radians."""
    v = np.asarray(v, float)
    theta = np.linalg.norm(v, axis=-1)[..., None, None]
    K = skew(v)
    small = theta < 1e-8
    th = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(th) / th)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(th)) / th**2)
    return np.eye(3) + a * K + b * (K @ K)


def rotvec_from_matrix(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) from rotation matrices (..., 3, 3)."""
    q = quat_from_matrix(R)
    return rotvec_from_quat(q)


def rotvec_from_quat(q: np.ndarray) -> np.ndarray:
    q = quat_normalize(q)
    w = q[..., 0]
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, w)
    scale = np.where(s < 1e-12, 2.0, angle / np.where(s < 1e-12, 1.0, s))
    return v * scale[..., None]


def quat_from_rotvec(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-12
    k = np.where(small, 0.5, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half), v * k], axis=-1)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices (..., 3, 3) of vectors (..., 3)."""
    v = np.asarray(v, float)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(
        [np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], axis=-2
    )


def transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from rotation (3, 3) and translation (3,)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def transform_points(a_from_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to points (..., 3)."""
    pts = np.asarray(points_b, float)
    return pts @ a_from_b[:3, :3].T + a_from_b[:3, 3]


def invert_transform(a_from_b: np.ndarray) -> np.ndarray:
    R = a_from_b[:3, :3]
    return transform(R.T, -R.T @ a_from_b[:3, 3])


def rigid_fit(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None):
    """Least-squares rigid motion (Kabsch): R, t minimising sum w |R s + t - target|^2.

    ``source``, ``target``: (n, 3). Returns (R (3, 3), t (3,)).
    """
    source = np.asarray(source, float)
    target = np.asarray(target, float)
    w = np.ones(len(source)) if weights is None else np.asarray(weights, float)
    w = w / w.sum()
    cs = w @ source
    ct = w @ target
    H = (source - cs).T @ ((target - ct) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d])
    R = Vt.T @ D @ U.T
    return R, ct - R @ cs


# ----------------------------------------------------------------------------- symbolic


def ca_matrix_from_quat(q):
    """CasADi 3x3 rotation matrix from a (possibly non-unit) quaternion (w, x, y, z)."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    n = w * w + x * x + y * y + z * z
    s = 2.0 / n
    return ca.vertcat(
        ca.horzcat(1 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
        ca.horzcat(s * (x * y + w * z), 1 - s * (x * x + z * z), s * (y * z - w * x)),
        ca.horzcat(s * (x * z - w * y), s * (y * z + w * x), 1 - s * (x * x + y * y)),
    )


def ca_quat_from_rpy(roll, pitch, yaw):
    """CasADi quaternion (w, x, y, z) of Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = ca.cos(roll / 2), ca.sin(roll / 2)
    cp, sp = ca.cos(pitch / 2), ca.sin(pitch / 2)
    cy, sy = ca.cos(yaw / 2), ca.sin(yaw / 2)
    return ca.vertcat(
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def ca_quat_multiply(a, b):
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return ca.vertcat(
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def ca_rot_x(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, c, -s), ca.horzcat(0, s, c))


def ca_rot_y(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, 0, s), ca.horzcat(0, 1, 0), ca.horzcat(-s, 0, c))


def ca_rot_z(a):
    c, s = ca.cos(a), ca.sin(a)
    return ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))


def ca_matrix_from_rpy(roll, pitch, yaw):
    return ca.mtimes([ca_rot_z(yaw), ca_rot_y(pitch), ca_rot_x(roll)])


def ca_matrix_from_rotvec(v):
    """Rodrigues formula, smooth at zero (uses the series where the angle is tiny)."""
    theta2 = ca.dot(v, v)
    theta = ca.sqrt(theta2 + 1e-300)
    K = ca.skew(v)
    a = ca.if_else(theta2 < 1e-12, 1 - theta2 / 6, ca.sin(theta) / theta)
    b = ca.if_else(theta2 < 1e-12, 0.5 - theta2 / 24, (1 - ca.cos(theta)) / theta2)
    return ca.DM.eye(3) + a * K + b * ca.mtimes(K, K)


def ca_quat_from_matrix_trace(R):
    """Quaternion from a rotation matrix near identity (trace branch only; for residuals)."""
    w = 0.5 * ca.sqrt(ca.fmax(1 + R[0, 0] + R[1, 1] + R[2, 2], 1e-12))
    return ca.vertcat(w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w))
