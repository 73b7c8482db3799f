"""platkit stand ``psvr``: the three-motor crank-rod platform of Burlakov et al. (2018).

Three motors i = A, B, C turn cranks of length r in vertical planes through the horizontal
directions e_i; a rod of length R joins each crank tip D_i to a platform joint; a passive
telescopic column on a cardan joint holds the platform's centre C = (0, 0, h) on the base z axis
and blocks yaw. With crank angle a_i = k_i (u_i - u0_i) and R(q) = Rx(alpha) Ry(beta):

    D_i = V_i + r (sin a_i e_i - cos a_i z)            (paper eq. 1, written for any azimuth)
    E_i = C + R(q) S_i                                  (eq. 2)
    F_i = |E_i - D_i| - R                               (eq. 3, as a distance, metres)

td = (k_A, k_B, k_C, A0, B0, C0, V (9), S (9), R, r): the paper's 26 numbers.
Pose coordinates p = (alpha, beta, h): q = quat(Rx(alpha) Ry(beta)), X = (0, 0, h).

Assembly mode (``branch`` g > 0, six numbers):
  g_i     = sin a_i                    the crank points outward (the paper's choice);
  g_{3+i} = (E_i - D_i) . t_i / R      t_i = d D_i / d a_i / r, the crank's direction of travel:
            positive while the rod is on the outward side of the crank, i.e. the crank is between
            its two dead points (in line with the rod). The other root of each rod equation and the
            forward-kinematics mirror poses (the platform reflected below the crank tips, h < 0)
            have it negative. The closed-form inverse picks this root.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import ca_matrix_from_quat
from platkit.hookspecs import hookimpl
from platkit.io.description import check_fields, check_platform, default_description, load_yaml, number, require, vector
from platkit.model import Control, Coordinate, Parameter, PlatformFactory, PlatformSpec, length_scale

MOTORS = ("A", "B", "C")
N_TD = 26
#: slices of td (see the module docstring)
K, U0, V, S, ROD, CRANK = slice(0, 3), slice(3, 6), slice(6, 15), slice(15, 24), 24, 25


def read_description(path: Path) -> dict:
    """Parse and check a psvr description; returns SI values (metres, radians)."""
    data = load_yaml(path)
    check_platform(data, "psvr", path)
    check_fields(data, ("units", "motors", "crank_length", "rod_length", "neutral_pose"), path)
    units = require(data, "units", path, dict)
    check_fields(units, ("length",), path, "units")
    length = units.get("length")
    if length not in ("mm", "m"):
        raise BadDescription(f"{path}: field 'units.length' must be 'mm' or 'm', got {length!r}")
    scale = length_scale(length)
    motors = require(data, "motors", path, list)
    if len(motors) != 3:
        raise BadDescription(f"{path}: field 'motors' must list 3 motors, got {len(motors)}")
    names, azimuth, V_, S_, k, u0, stroke = [], [], [], [], [], [], []
    for i, m in enumerate(motors):
        where = f"motors[{i}]"
        if not isinstance(m, dict):
            raise BadDescription(f"{path}: {where} must be a mapping")
        check_fields(m, ("name", "crank_azimuth_deg", "crank_pivot", "platform_joint", "rad_per_count", "zero_count",
                         "stroke"), path, where)
        names.append(str(require(m, "name", path, str, where)))
        azimuth.append(np.radians(number(m, "crank_azimuth_deg", path, where)))
        V_.append(vector(m, "crank_pivot", path, 3, where) * scale)
        S_.append(vector(m, "platform_joint", path, 3, where) * scale)
        k_i = number(m, "rad_per_count", path, where)
        if k_i == 0:
            raise BadDescription(f"{path}: field '{where}.rad_per_count' must not be zero")
        k.append(k_i)
        u0.append(number(m, "zero_count", path, where))
        s = vector(m, "stroke", path, 2, where)
        if not s[0] < s[1]:
            raise BadDescription(f"{path}: field '{where}.stroke' must be [min, max] with min < max")
        stroke.append(s)
    r = number(data, "crank_length", path) * scale
    R = number(data, "rod_length", path) * scale
    for key, value in (("crank_length", r), ("rod_length", R)):
        if value <= 0:
            raise BadDescription(f"{path}: field {key!r} must be positive")
    neutral = require(data, "neutral_pose", path, dict)
    check_fields(neutral, ("alpha", "beta", "h"), path, "neutral_pose")
    p0 = np.array([number(neutral, "alpha", path, "neutral_pose"), number(neutral, "beta", path, "neutral_pose"),
                   number(neutral, "h", path, "neutral_pose") * scale])
    return dict(names=names, azimuth=np.array(azimuth), V=np.array(V_), S=np.array(S_), k=np.array(k),
                u0=np.array(u0), stroke=np.array(stroke), r=r, R=R, p0=p0, raw=data)


def quat_from_alpha_beta(alpha, beta):
    """CasADi (or numpy) quaternion (w, x, y, z) of Rx(alpha) Ry(beta) (the paper's eq. 2)."""
    ca_, sa, cb, sb = ca.cos(alpha / 2), ca.sin(alpha / 2), ca.cos(beta / 2), ca.sin(beta / 2)
    return ca.vertcat(ca_ * cb, sa * cb, ca_ * sb, sa * sb)


def crank_geometry(u, td, q, X, e):
    """CasADi pieces of the model, each 3x3 with one column per motor (metres).

    ``e``: 3x3 numpy array, column i the horizontal unit vector e_i of crank plane i.
    Returns (a (3,), D crank tips, E platform joints, t crank directions of travel).
    """
    a = td[K] * (u - td[U0])
    r = td[CRANK]
    z = ca.DM([0.0, 0.0, 1.0])
    Vm = ca.reshape(td[V], 3, 3)
    Sm = ca.reshape(td[S], 3, 3)
    D = ca.horzcat(*[Vm[:, i] + r * (ca.sin(a[i]) * e[:, i] - ca.cos(a[i]) * z) for i in range(3)])
    t = ca.horzcat(*[ca.cos(a[i]) * e[:, i] + ca.sin(a[i]) * z for i in range(3)])
    E = ca.repmat(X, 1, 3) + ca.mtimes(ca_matrix_from_quat(q), Sm)
    return a, D, E, t


def closed_form_inverse(td, q, X, e):
    """CasADi crank counts u (3,) from a pose, on the stand's branch; NaN where there is none.

    Per motor, with w = E - V, P = w.e, Q = -w.z: |D - E| = R gives
    P sin a + Q cos a = (r^2 + |w|^2 - R^2) / (2 r) = K, i.e. rho sin(a + phi) = K with
    rho = |(P, Q)|, phi = atan2(Q, P). The root a = asin(K / rho) - phi has (E - D).t = rho cos(a + phi)
    > 0 (the branch); it is NaN when |K| > rho (the rod cannot reach) or when the crank would
    point inward (sin a <= 0).
    """
    r, R = td[CRANK], td[ROD]
    Vm = ca.reshape(td[V], 3, 3)
    Sm = ca.reshape(td[S], 3, 3)
    E = ca.repmat(X, 1, 3) + ca.mtimes(ca_matrix_from_quat(q), Sm)
    u = []
    for i in range(3):
        w = E[:, i] - Vm[:, i]
        P = ca.dot(w, ca.DM(e[:, i]))
        Q = -w[2]
        rho = ca.sqrt(P * P + Q * Q)
        ratio = (r * r + ca.dot(w, w) - R * R) / (2 * r * rho)
        a = ca.asin(ca.fmin(ca.fmax(ratio, -1), 1)) - ca.atan2(Q, P)
        a = ca.atan2(ca.sin(a), ca.cos(a))
        ok = ca.logic_and(ca.fabs(ratio) <= 1, ca.sin(a) > 0)
        u.append(ca.if_else(ok, td[U0][i] + a / td[K][i], np.nan))
    return ca.vertcat(*u)


def pose_functions(p0: np.ndarray) -> tuple[list[Coordinate], ca.Function, ca.Function]:
    """Pose coordinates (alpha, beta, h), p -> (q, X) and (q, X) -> p."""
    coords = [
        Coordinate("alpha", "rad", float(p0[0]), -np.pi / 2, np.pi / 2),
        Coordinate("beta", "rad", float(p0[1]), -np.pi / 2, np.pi / 2),
        Coordinate("h", "m", float(p0[2]), 0.0, np.inf),
    ]
    p = ca.SX.sym("p", 3)
    pose = ca.Function("pose", [p], [quat_from_alpha_beta(p[0], p[1]), ca.vertcat(0, 0, p[2])], ["p"], ["q", "X"])
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    w, x, y, z = q[0], q[1], q[2], q[3]
    # R = Rx(alpha) Ry(beta) has R[0,2] = sin beta, R[0,0] = cos beta, R[2,1] = sin alpha, R[1,1] = cos alpha
    beta = ca.atan2(2 * (x * z + w * y), 1 - 2 * (y * y + z * z))
    alpha = ca.atan2(2 * (y * z + w * x), 1 - 2 * (x * x + z * z))
    from_pose = ca.Function("coordinates_from_pose", [q, X], [ca.vertcat(alpha, beta, X[2])], ["q", "X"], ["p"])
    return coords, pose, from_pose


def build(path: Path | None, options: dict | None = None) -> PlatformSpec:
    if options:
        raise BadInput(f"the psvr stand takes no options, got {sorted(options)}")
    path = path or default_description("psvr.yaml")
    d = read_description(path)
    names = d["names"]
    e = np.stack([np.cos(d["azimuth"]), np.sin(d["azimuth"]), np.zeros(3)])  # column i: e_i
    src = str(path)
    params = [Parameter(f"k_{n}", "rad/count", float(v), group="scales", source=src) for n, v in zip(names, d["k"])]
    params += [Parameter(f"u0_{n}", "count", float(v), group="zeros", source=src) for n, v in zip(names, d["u0"])]
    params += [Parameter(f"V_{n}_{a}", "m", float(d["V"][i, j]), group="crank_pivots", source=src)
               for i, n in enumerate(names) for j, a in enumerate("xyz")]
    params += [Parameter(f"S_{n}_{a}", "m", float(d["S"][i, j]), group="platform_joints", source=src)
               for i, n in enumerate(names) for j, a in enumerate("xyz")]
    params += [Parameter("R_rod", "m", d["R"], 0.0, np.inf, group="lengths", source=src),
               Parameter("r_crank", "m", d["r"], 0.0, np.inf, group="lengths", source=src)]
    assert len(params) == N_TD

    u = ca.SX.sym("u", 3)
    td = ca.SX.sym("td", N_TD)
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    a, D, E, t = crank_geometry(u, td, q, X, e)
    rods = E - D
    lengths = ca.sqrt(ca.sum1(rods**2)).T
    residual = ca.Function("F", [u, td, q, X], [lengths - td[ROD]], ["u", "td", "q", "X"], ["r"])
    g = ca.vertcat(ca.sin(a), ca.sum1(rods * t).T / td[ROD])
    branch = ca.Function("branch", [u, td, q, X], [g], ["u", "td", "q", "X"], ["g"])
    inverse = ca.Function("inverse", [td, q, X], [closed_form_inverse(td, q, X, e)], ["td", "q", "X"], ["u"])

    coords, pose, from_pose = pose_functions(d["p0"])
    td0 = np.concatenate([d["k"], d["u0"], d["V"].ravel(), d["S"].ravel(), [d["R"], d["r"]]])
    u_neutral = np.asarray(inverse(td0, *pose(d["p0"]))).ravel()
    if not np.all(np.isfinite(u_neutral)):
        raise BadDescription(f"{path}: field 'neutral_pose' cannot be reached with the cranks outward")
    controls = []
    for n, s, u_n in zip(names, d["stroke"], u_neutral):
        if not s[0] <= u_n <= s[1]:
            raise BadDescription(
                f"{path}: field 'neutral_pose' needs motor {n} at {u_n:.4f} counts, outside its stroke [{s[0]}, {s[1]}]"
            )
        controls.append(Control(n, "count", float(s[0]), float(s[1]), float(u_n)))
    return PlatformSpec(
        name="psvr",
        title="PSVR three-motor crank-rod platform (Burlakov et al.)",
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
        extras={"crank_planes": e.T.copy(), "crank_pivots_m": d["V"], "platform_joints_m": d["S"]},
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory("psvr", "PSVR three-motor crank-rod platform (Burlakov et al.)", build, (".yaml", ".yml"))]
