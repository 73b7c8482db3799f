"""platkit stand ``stewart``: the 6-UPS flight-simulator motion base of Liu, Ma and Lin.

Residual, one row per leg i (metres):
    F_i = | X + R(q) P_i - B_i | - (L_i + dL_i)
with base joints B_i (base frame), platform joints P_i (platform frame) and leg-length offsets
dL_i: td = (B_1..B_6, P_1..P_6, dL_1..dL_6), 42 numbers.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import ca_matrix_from_quat, matrix_from_quat, matrix_from_rpy
from platkit.hookspecs import hookimpl
from platkit.io.description import check_fields, check_platform, default_description, load_yaml, number, require, vector
from platkit.model import Control, Parameter, PlatformFactory, PlatformSpec, length_scale, six_dof_pose

N_LEGS = 6


def read_description(path: Path) -> dict:
    """Parse and check a stewart description; returns SI arrays (metres, radians)."""
    data = load_yaml(path)
    check_platform(data, "stewart", path)
    check_fields(data, ("units", "legs", "neutral_pose", "workspace_limits"), path)
    units = require(data, "units", path, dict)
    check_fields(units, ("length",), path, "units")
    unit = require(units, "length", path, str, "units")
    if unit not in ("mm", "m"):
        raise BadDescription(f"{path}: field 'units.length' must be 'mm' or 'm', got {unit!r}")
    scale = length_scale(unit)
    legs = require(data, "legs", path, list)
    if len(legs) != N_LEGS:
        raise BadDescription(f"{path}: field 'legs' must list {N_LEGS} legs, got {len(legs)}")
    names, B, P, off, stroke = [], [], [], [], []
    for i, leg in enumerate(legs):
        where = f"legs[{i}]"
        if not isinstance(leg, dict):
            raise BadDescription(f"{path}: {where} must be a mapping")
        check_fields(leg, ("name", "base_joint", "platform_joint", "offset", "stroke"), path, where)
        names.append(str(require(leg, "name", path, str, where)))
        B.append(vector(leg, "base_joint", path, 3, where) * scale)
        P.append(vector(leg, "platform_joint", path, 3, where) * scale)
        off.append(number(leg, "offset", path, where) * scale if "offset" in leg else 0.0)
        s = vector(leg, "stroke", path, 2, where) * scale
        if not s[0] < s[1]:
            raise BadDescription(f"{path}: {where}.stroke must be [min, max] with min < max")
        stroke.append(s)
    for i in range(N_LEGS):
        for j in range(i):
            if np.allclose(B[i], B[j]) and np.allclose(P[i], P[j]):
                raise BadDescription(f"{path}: legs {names[j]} and {names[i]} have the same base and platform joints")
    if len(set(names)) != N_LEGS:
        raise BadDescription(f"{path}: leg names must differ, got {names}")
    neutral = require(data, "neutral_pose", path, dict)
    check_fields(neutral, ("position", "rpy"), path, "neutral_pose")
    X0 = vector(neutral, "position", path, 3, "neutral_pose") * scale
    rpy0 = vector(neutral, "rpy", path, 3, "neutral_pose") if "rpy" in neutral else np.zeros(3)
    limits = data.get("workspace_limits") or {}
    if not isinstance(limits, dict):
        raise BadDescription(f"{path}: field 'workspace_limits' must be a mapping")
    check_fields(limits, ("position_min", "position_max", "angle_max"), path, "workspace_limits")
    pmin = vector(limits, "position_min", path, 3, "workspace_limits") * scale if "position_min" in limits else None
    pmax = vector(limits, "position_max", path, 3, "workspace_limits") * scale if "position_max" in limits else None
    amax = number(limits, "angle_max", path, "workspace_limits") if "angle_max" in limits else np.pi / 2
    R0 = matrix_from_rpy(*rpy0)
    L0 = np.linalg.norm(X0 + np.array(P) @ R0.T - np.array(B), axis=1) - np.array(off)
    for name, L, (lo, hi) in zip(names, L0, stroke):
        if not lo <= L <= hi:
            raise BadDescription(
                f"{path}: leg {name} is {L / scale:.6g} {unit} long at the neutral pose, outside its stroke "
                f"[{lo / scale:.6g}, {hi / scale:.6g}] {unit}"
            )
    return dict(names=names, B=np.array(B), P=np.array(P), offset=np.array(off), stroke=np.array(stroke),
                X0=X0, rpy0=rpy0, position_min=pmin, position_max=pmax, angle_max=amax, raw=data)


def leg_vectors(td, q, X):
    """CasADi 3x6 leg vectors X + R P_i - B_i (base frame) for td laid out as in this module."""
    B = ca.reshape(td[0:18], 3, 6)
    P = ca.reshape(td[18:36], 3, 6)
    R = ca_matrix_from_quat(q)
    return ca.repmat(X, 1, 6) + ca.mtimes(R, P) - B


def build(path: Path | None, options: dict | None = None) -> PlatformSpec:
    if options:
        raise BadInput(f"the stewart stand takes no options, got {sorted(options)}")
    path = path or default_description("stewart.yaml")
    d = read_description(path)
    params = []
    for i in range(N_LEGS):
        for a, v in zip("xyz", d["B"][i]):
            params.append(Parameter(f"B{i + 1}_{a}", "m", float(v), group="base_joints", source=str(path)))
    for i in range(N_LEGS):
        for a, v in zip("xyz", d["P"][i]):
            params.append(Parameter(f"P{i + 1}_{a}", "m", float(v), group="platform_joints", source=str(path)))
    for i in range(N_LEGS):
        params.append(Parameter(f"dL{i + 1}", "m", float(d["offset"][i]), group="leg_offsets", source=str(path)))

    u = ca.SX.sym("u", N_LEGS)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    legs = leg_vectors(td, q, X)
    lengths = ca.sqrt(ca.sum1(legs**2)).T
    offsets = td[36:42]
    residual = ca.Function("F", [u, td, q, X], [lengths - (u + offsets)], ["u", "td", "q", "X"], ["r"])
    inverse = ca.Function("inverse", [td, q, X], [lengths - offsets], ["td", "q", "X"], ["u"])
    # assembly mode: every platform joint above the base plane (the mirror solutions are below)
    Pw = ca.repmat(X, 1, 6) + ca.mtimes(ca_matrix_from_quat(q), ca.reshape(td[18:36], 3, 6))
    branch = ca.Function("branch", [u, td, q, X], [Pw[2, :].T], ["u", "td", "q", "X"], ["g"])

    coords, pose, from_pose = six_dof_pose(d["X0"], d["rpy0"], d["position_min"], d["position_max"], d["angle_max"])
    R0 = matrix_from_rpy(*d["rpy0"])
    neutral_L = np.linalg.norm(d["X0"] + d["P"] @ R0.T - d["B"], axis=1) - d["offset"]
    controls = [Control(n, "m", float(s[0]), float(s[1]), float(L0)) for n, s, L0 in zip(d["names"], d["stroke"], neutral_L)]
    return PlatformSpec(
        name="stewart",
        title="6-UPS Stewart motion base (Liu, Ma, Lin)",
        controls=controls,
        parameters=params,
        coordinates=coords,
        residual=residual,
        pose=pose,
        coordinates_from_pose=from_pose,
        inverse=inverse,
        branch=branch,
        description=d["raw"],
        description_path=path,
        extras={"base_joints_m": d["B"], "platform_joints_m": d["P"]},
    )


def leg_kinematics(spec: PlatformSpec, q, X, v=None, omega=None, a=None, alpha=None, td=None) -> dict:
    """The paper's leg relations (Liu, Ma, Lin, eqs. 3-8), numerically, for one platform state.

    ``q`` (4,), ``X`` (3,) m: the pose; ``v``, ``omega`` (3,): velocity of the platform origin
    and angular velocity, ``a``, ``alpha`` (3,): their rates; all in the base frame (m, s, rad).
    Returns a dict of arrays, legs along the last axis (6):
        legs (3, 6)          eq. 3: leg vectors X + R P_i - B_i
        lengths (6,)         |legs|, commanded lengths are these minus the offsets dL_i
        directions (3, 6)    unit leg vectors n_i
    and when a twist is given:
        joint_velocities (3, 6)   eq. 4: V_i = v + omega x (R P_i)
        rates (6,)                eq. 5: leg extension rate V_i . n_i
        leg_angular_velocities (3, 6)  eq. 7: l_i x V_i / |l_i|^2 (the leg's spin about its own
                                  axis is left out; the paper's printed V x l / |l| has the
                                  wrong dimension and sign)
    and when (a, alpha) are given too:
        joint_accelerations (3, 6)  eq. 6: A_i = a + alpha x (R P_i) + omega x (omega x R P_i)
        accelerations (6,)         eq. 8: A_i . n_i + |l_i| |omega_leg_i|^2. The paper prints a
                                  minus sign before the last term; differentiating |l_i| twice
                                  gives a plus (the centripetal part of eq. 2 points inward).
    The paper writes omega x P_i with P_i in the platform frame; the joint lever is R P_i.
    """

    td = spec.nominal_td() if td is None else np.asarray(td, float)
    B = td[0:18].reshape(6, 3).T
    P = td[18:36].reshape(6, 3).T
    R = matrix_from_quat(np.asarray(q, float))
    lever = R @ P  # (3, 6)
    legs = np.asarray(X, float)[:, None] + lever - B
    lengths = np.linalg.norm(legs, axis=0)
    n = legs / lengths
    out = {"legs": legs, "lengths": lengths, "directions": n}
    if v is None or omega is None:
        return out
    v, omega = np.asarray(v, float), np.asarray(omega, float)
    V = v[:, None] + np.cross(omega, lever.T).T
    w_leg = np.cross(legs.T, V.T).T / lengths**2
    out.update(joint_velocities=V, rates=np.sum(V * n, axis=0), leg_angular_velocities=w_leg)
    if a is None or alpha is None:
        return out
    a, alpha = np.asarray(a, float), np.asarray(alpha, float)
    A = a[:, None] + np.cross(alpha, lever.T).T + np.cross(omega, np.cross(omega, lever.T)).T
    out.update(joint_accelerations=A, accelerations=np.sum(A * n, axis=0) + lengths * np.sum(w_leg**2, axis=0))
    return out


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory("stewart", "6-UPS Stewart motion base (Liu, Ma, Lin)", build, (".yaml", ".yml"))]
