"""platkit stand ``hexapod-rss``: a 6-RSS hexapod driven by rotary servos.

Leg i: a servo at pivot B_i turns a horn of length a in the vertical plane through the horizontal
direction d_i; a rod of length l joins the horn tip H_i to the platform joint P_i:

    H_i = B_i + a (cos theta_i d_i + sin theta_i z),   theta_i = u_i + o_i
    F_i = |X + R(q) P_i - H_i| - l

td = (B_1..B_6, P_1..P_6, o_1..o_6, a, l): 44 numbers, metres and radians.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import ca_matrix_from_quat
from platkit.hookspecs import hookimpl
from platkit.io.description import load_yaml, number, require, vector
from platkit.model import Control, Parameter, PlatformFactory, PlatformSpec, length_scale, six_dof_pose

NAME = "hexapod-rss"
N_LEGS = 6
DEFAULT_DESCRIPTION = Path(__file__).with_name("hexapod_rss.yaml")


def read_description(path: Path) -> dict:
    """Parse and check a description; return SI arrays. Every error names the file and field."""
    data = load_yaml(path)
    units = require(data, "units", path, dict)
    scale = length_scale(str(units.get("length", "")))
    servos = require(data, "servos", path, list)
    if len(servos) != N_LEGS:
        raise BadDescription(f"{path}: field 'servos' must list {N_LEGS} servos, got {len(servos)}")
    names, B, P, d, offset, ranges = [], [], [], [], [], []
    for i, s in enumerate(servos):
        where = f"servos[{i}]"
        if not isinstance(s, dict):
            raise BadDescription(f"{path}: {where} must be a mapping")
        names.append(require(s, "name", path, str, where))
        B.append(vector(s, "pivot", path, 3, where) * scale)
        P.append(vector(s, "platform_joint", path, 3, where) * scale)
        azimuth = np.radians(number(s, "horn_azimuth_deg", path, where))
        d.append([np.cos(azimuth), np.sin(azimuth), 0.0])
        offset.append(number(s, "zero_offset", path, where))
        r = vector(s, "range", path, 2, where)
        if not r[0] < r[1]:
            raise BadDescription(f"{path}: field '{where}.range' must be [min, max] with min < max")
        ranges.append(r)
    a = number(data, "horn_length", path) * scale
    l = number(data, "rod_length", path) * scale
    if not 0 < a < l:
        raise BadDescription(f"{path}: fields 'horn_length' and 'rod_length' must satisfy 0 < horn < rod")
    neutral = require(data, "neutral_pose", path, dict)
    X0 = vector(neutral, "position", path, 3, "neutral_pose") * scale
    rpy0 = vector(neutral, "rpy", path, 3, "neutral_pose")
    return dict(names=names, B=np.array(B), P=np.array(P), d=np.array(d).T, offset=np.array(offset),
                ranges=np.array(ranges), a=a, l=l, X0=X0, rpy0=rpy0, raw=data)


def leg_geometry(u, td, q, X, d):
    """CasADi 3x6 arrays, one column per leg: rods (platform joint - horn tip) and the horn tips'
    directions of travel t_i = d H_i / d theta_i / a. ``d``: 3x6 horn-plane directions."""
    B = ca.reshape(td[0:18], 3, 6)
    P = ca.reshape(td[18:36], 3, 6)
    theta = u + td[36:42]
    a = td[42]
    z = ca.DM([0.0, 0.0, 1.0])
    H = ca.horzcat(*[B[:, i] + a * (ca.cos(theta[i]) * d[:, i] + ca.sin(theta[i]) * z) for i in range(N_LEGS)])
    t = ca.horzcat(*[-ca.sin(theta[i]) * d[:, i] + ca.cos(theta[i]) * z for i in range(N_LEGS)])
    joints = ca.repmat(X, 1, N_LEGS) + ca.mtimes(ca_matrix_from_quat(q), P)
    return joints - H, t


def servo_angles(td, q, X, d):
    """Closed-form inverse kinematics: commands u (6,) for a pose; NaN where a rod cannot reach.

    With w = E_i - B_i (E_i the platform joint), |w - a (cos theta d + sin theta z)| = l reads
    (w.d) cos theta + w_z sin theta = (|w|^2 + a^2 - l^2) / (2 a) = K, i.e. rho sin(theta + phi) = K
    with rho = |(w_z, w.d)|, phi = atan2(w.d, w_z). Of its two roots we keep
    theta = asin(K / rho) - phi, the one with the rod on the upper side of the horn's travel
    (the branch below).
    """
    B = ca.reshape(td[0:18], 3, 6)
    P = ca.reshape(td[18:36], 3, 6)
    a, l = td[42], td[43]
    E = ca.repmat(X, 1, N_LEGS) + ca.mtimes(ca_matrix_from_quat(q), P)
    u = []
    for i in range(N_LEGS):
        w = E[:, i] - B[:, i]
        wd = ca.dot(w, ca.DM(d[:, i]))
        rho = ca.sqrt(wd * wd + w[2] * w[2])
        ratio = (ca.dot(w, w) + a * a - l * l) / (2 * a * rho)
        theta = ca.asin(ca.fmin(ca.fmax(ratio, -1), 1)) - ca.atan2(wd, w[2])
        theta = ca.atan2(ca.sin(theta), ca.cos(theta))  # into (-pi, pi]
        u.append(ca.if_else(ca.fabs(ratio) <= 1, theta - td[36 + i], np.nan))
    return ca.vertcat(*u)


def build(path: Path | None, options: dict) -> PlatformSpec:
    """Build the stand from a description file (None: the one shipped in this package)."""
    if options:
        raise BadInput(f"the {NAME} stand takes no options, got {sorted(options)}")
    path = path or DEFAULT_DESCRIPTION
    desc = read_description(path)
    src = str(path)
    params = [Parameter(f"B{i + 1}_{c}", "m", float(v), group="servo_pivots", source=src)
              for i in range(N_LEGS) for c, v in zip("xyz", desc["B"][i])]
    params += [Parameter(f"P{i + 1}_{c}", "m", float(v), group="platform_joints", source=src)
               for i in range(N_LEGS) for c, v in zip("xyz", desc["P"][i])]
    params += [Parameter(f"o{i + 1}", "rad", float(v), group="zero_offsets", source=src)
               for i, v in enumerate(desc["offset"])]
    params += [Parameter("horn_a", "m", desc["a"], 0.0, np.inf, group="lengths", source=src),
               Parameter("rod_l", "m", desc["l"], 0.0, np.inf, group="lengths", source=src)]

    u = ca.SX.sym("u", N_LEGS)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    rods, t = leg_geometry(u, td, q, X, desc["d"])
    lengths = ca.sqrt(ca.sum1(rods**2)).T
    residual = ca.Function("F", [u, td, q, X], [lengths - td[43]], ["u", "td", "q", "X"], ["r"])
    # Assembly mode: the rod on the upper side of the horn's travel, (E - H).t > 0. The other root
    # of each rod equation, and the mirror poses with the platform below the horns, have it < 0.
    branch = ca.Function("branch", [u, td, q, X], [ca.sum1(rods * t).T / td[43]], ["u", "td", "q", "X"], ["g"])
    inverse = ca.Function("inverse", [td, q, X], [servo_angles(td, q, X, desc["d"])], ["td", "q", "X"], ["u"])

    coords, pose, from_pose = six_dof_pose(desc["X0"], desc["rpy0"], angle_max=0.6)
    td0 = np.array([p.nominal for p in params])
    u0 = np.asarray(inverse(td0, *pose(np.concatenate([desc["X0"], desc["rpy0"]])))).ravel()
    controls = []
    for name, (lo, hi), neutral in zip(desc["names"], desc["ranges"], u0):
        if not lo <= neutral <= hi:
            raise BadDescription(f"{path}: field 'neutral_pose' needs servo {name} at {neutral:.4f} rad, outside its range")
        controls.append(Control(name, "rad", float(lo), float(hi), float(neutral)))
    return PlatformSpec(
        name=NAME, title="6-RSS hexapod with rotary servos", controls=controls, parameters=params,
        coordinates=coords, residual=residual, pose=pose, coordinates_from_pose=from_pose,
        inverse=inverse, branch=branch, description=desc["raw"], description_path=path,
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory(NAME, "6-RSS hexapod with rotary servos", build, (".yaml", ".yml"))]
