"""Homogeneous transforms H_ij and twists, after Sorokin (2017), section 3 and eqs. 15-18.

The paper treats the transform between two frames as one geometric object whose components may
be a 4x4 matrix, a quaternion plus a vector, or a dual quaternion: they are interchangeable, and
this module converts between the three and composes in each.

Twists are 6-vectors ``(v, omega)``: linear velocity of a reference point, then angular velocity
(the paper's eq. 3 order; its eqs. 12 and 18 list ``(omega, v)``, the same object permuted).
The pose error ``(r, rho)`` is ordered the same way: translation, then rotation vector.

Shapes: transforms (4, 4); quaternions (4,) scalar first ``(w, x, y, z)``; dual quaternions
(8,) = real part (4,) then dual part (4,); twists (6,). Lengths in metres, angles in radians.
"""
from __future__ import annotations

import numpy as np

from platkit.geometry import (
    matrix_from_quat,
    matrix_from_rpy,
    quat_conjugate,
    quat_from_matrix,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    rotvec_from_matrix,
    rotvec_from_quat,
    skew,
)

# ----------------------------------------------------------------------------- three components


def quat_vec_from_transform(a_from_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(q (4,), t (3,)) of a 4x4 transform: rotate by q, then translate by t."""
    a_from_b = np.asarray(a_from_b, float)
    return quat_from_matrix(a_from_b[:3, :3]), a_from_b[:3, 3].copy()


def transform_from_quat_vec(q: np.ndarray, t: np.ndarray) -> np.ndarray:
    """4x4 transform from a unit quaternion (4,) and a translation (3,)."""
    H = np.eye(4)
    H[:3, :3] = matrix_from_quat(q)
    H[:3, 3] = np.asarray(t, float)
    return H


def compose_quat_vec(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]):
    """(q, t) of a*b: the quaternion + vector form of H_a @ H_b."""
    qa, ta = a
    qb, tb = b
    return quat_normalize(quat_multiply(qa, qb)), ta + matrix_from_quat(qa) @ np.asarray(tb, float)


def _pure(v: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.asarray(v, float)])


def dual_quat_from_transform(a_from_b: np.ndarray) -> np.ndarray:
    """Unit dual quaternion (8,) = (q_r, q_d) with q_d = 1/2 t q_r, of a 4x4 transform."""
    q, t = quat_vec_from_transform(a_from_b)
    return np.concatenate([q, 0.5 * quat_multiply(_pure(t), q)])


def transform_from_dual_quat(dq: np.ndarray) -> np.ndarray:
    """4x4 transform of a unit dual quaternion (8,): t = 2 q_d q_r*."""
    dq = np.asarray(dq, float)
    n = np.linalg.norm(dq[:4])
    qr, qd = dq[:4] / n, dq[4:] / n
    t = 2.0 * quat_multiply(qd, quat_conjugate(qr))[1:]
    return transform_from_quat_vec(qr, t)


def dual_quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Product a*b of dual quaternions (8,): the dual-quaternion form of H_a @ H_b."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    return np.concatenate([
        quat_multiply(a[:4], b[:4]),
        quat_multiply(a[:4], b[4:]) + quat_multiply(a[4:], b[:4]),
    ])


def invert(a_from_b: np.ndarray) -> np.ndarray:
    """b_from_a of a 4x4 rigid transform."""
    R = a_from_b[:3, :3]
    H = np.eye(4)
    H[:3, :3] = R.T
    H[:3, 3] = -R.T @ a_from_b[:3, 3]
    return H


def make_transform(R: np.ndarray | None = None, t: np.ndarray | None = None) -> np.ndarray:
    """4x4 transform from a rotation (3, 3) and a translation (3,) (identity where omitted)."""
    H = np.eye(4)
    if R is not None:
        H[:3, :3] = R
    if t is not None:
        H[:3, 3] = t
    return H


# ----------------------------------------------------------------------------- twists (eqs. 15-18)


def unit_twist(kind: str, axis: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """W_i: the joint's unit twist (6,) ``(v, omega)`` in its own frame (eqs. 15, 16).

    ``kind``: 'revolute' or 'continuous' (omega = s a, v = 0) or 'prismatic' (v = s a,
    omega = 0); ``axis``: the joint axis (3,) in the joint frame; ``scale``: the paper's s
    (e.g. a gear ratio between the joint coordinate and the motion; 1 for SI joint values).
    """
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    W = np.zeros(6)
    if kind in ("revolute", "continuous"):
        W[3:] = scale * a
    elif kind == "prismatic":
        W[:3] = scale * a
    else:
        raise ValueError(f"unit twist: unknown joint kind {kind!r} (revolute, continuous, prismatic)")
    return W


def transport_matrix(r: np.ndarray) -> np.ndarray:
    """R_i^j (6, 6): moves a twist's reference point by ``r`` (eq. 18), (v, omega) order.

    ``r`` (3,) goes from the old point to the new one, in the basis the twist is written in:
    omega' = omega, v' = v + omega x r.
    """
    T = np.eye(6)
    T[:3, 3:] = -skew(np.asarray(r, float))
    return T


def rotation_action(a_from_b_rotation: np.ndarray) -> np.ndarray:
    """The action of H on a twist (6, 6): both 3-vectors rotated, no translation (eq. 19)."""
    A = np.zeros((6, 6))
    A[:3, :3] = a_from_b_rotation
    A[3:, 3:] = a_from_b_rotation
    return A


# ----------------------------------------------------------------------------- errors, interpolation


def pose_error(current: np.ndarray, target: np.ndarray, basis: str = "reference") -> np.ndarray:
    """E = P^-1 U as the 6-vector (r, rho) (m, rad) of the paper's tracking servo.

    ``current`` P and ``target`` U are 4x4 placements in one reference frame. With
    ``basis='local'`` (the paper's recommendation: the controlled link's own basis) r and rho are
    the translation and rotation vector of P^-1 U; with ``basis='reference'`` the same
    6-vector rotated into the reference basis: r = t_U - t_P, rho = rotvec(R_U R_P^T).
    """
    R_p = current[:3, :3]
    r = target[:3, 3] - current[:3, 3]
    rho = rotvec_from_matrix(target[:3, :3] @ R_p.T)
    E = np.concatenate([r, rho])
    if basis == "local":
        return rotation_action(R_p.T) @ E
    if basis != "reference":
        raise ValueError(f"pose_error: basis must be 'reference' or 'local', got {basis!r}")
    return E


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (4,), s in [0, 1], shortest arc."""
    rel = quat_normalize(quat_multiply(quat_conjugate(q0), q1))
    return quat_normalize(quat_multiply(q0, quat_from_rotvec(s * rotvec_from_quat(rel))))


def interpolate_pose(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """4x4 pose at fraction s between poses a and b: linear in position, SLERP in rotation."""
    qa = quat_from_matrix(a[:3, :3])
    qb = quat_from_matrix(b[:3, :3])
    return transform_from_quat_vec(slerp(qa, qb, s), (1.0 - s) * a[:3, 3] + s * b[:3, 3])


def pose_from_xyz_rpy(values: np.ndarray) -> np.ndarray:
    """4x4 pose from x, y, z (m) and optionally roll, pitch, yaw (rad); R = Rz Ry Rx."""

    v = np.asarray(values, float)
    H = np.eye(4)
    H[:3, 3] = v[:3]
    if v.size == 6:
        H[:3, :3] = matrix_from_rpy(v[3], v[4], v[5])
    elif v.size == 7:
        H[:3, :3] = matrix_from_quat(v[3:7])
    elif v.size != 3:
        raise ValueError(f"pose: expected 3, 6 or 7 numbers, got {v.size}")
    return H
