"""Scalar quaternion arithmetic on plain floats, for the sample-by-sample filters.

The estimators run one sample at a time; numpy calls on 4-element arrays cost more than the
arithmetic, so the inner loops use tuples of floats. Quaternions are (w, x, y, z), Hamilton
product, ``rotate(q, v)`` = q v q*.
"""
from __future__ import annotations

import math


def mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def normalize(q):
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def conj(q):
    return (q[0], -q[1], -q[2], -q[3])


def rotate(q, v):
    """q v q* for a unit quaternion q and a 3-vector v."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 (q_vec x v)
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return (vx + w * tx + y * tz - z * ty,
            vy + w * ty + z * tx - x * tz,
            vz + w * tz + x * ty - y * tx)


def from_rotvec(wx, wy, wz):
    """exp of a rotation vector (rad)."""
    angle = math.sqrt(wx * wx + wy * wy + wz * wz)
    if angle < 1e-12:
        return (1.0, 0.5 * wx, 0.5 * wy, 0.5 * wz)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), s * wx, s * wy, s * wz)


def from_two_vectors(a, b):
    """The shortest rotation that turns the direction of ``a`` into that of ``b``."""
    ax, ay, az = a
    bx, by, bz = b
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    ax, ay, az = ax / na, ay / na, az / na
    bx, by, bz = bx / nb, by / nb, bz / nb
    d = ax * bx + ay * by + az * bz
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    if d < -1.0 + 1e-12:  # opposite: any perpendicular axis
        px, py, pz = (1.0, 0.0, 0.0) if abs(ax) < 0.9 else (0.0, 1.0, 0.0)
        cx, cy, cz = ay * pz - az * py, az * px - ax * pz, ax * py - ay * px
        n = math.sqrt(cx * cx + cy * cy + cz * cz)
        return (0.0, cx / n, cy / n, cz / n)
    return normalize((1.0 + d, cx, cy, cz))


def matrix(q):
    """Row-major rotation matrix of a unit quaternion, as a 9-tuple."""
    w, x, y, z = q
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))
