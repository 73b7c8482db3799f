"""platkit stand ``delta``: a Clavel delta robot (three rotary arms, parallelogram forearms).

Arm i: a motor at B_i turns an upper arm of length a_i in the vertical plane through the
horizontal direction d_i = (cos psi_i, sin psi_i, 0), the angle theta_i measured downwards from
the horizontal; a parallelogram forearm of length b_i joins the elbow E_i to the platform joint
P_i. The parallelograms keep the platform parallel to the base: it translates and never rotates,
so its pose is p = (x, y, z) and q = (1, 0, 0, 0) always.

    E_i = B_i + a_i (cos theta_i d_i - sin theta_i z),   theta_i = u_i + o_i
    F_i = |X + P_i - E_i| - b_i

td = (B_1..B_3, P_1..P_3, o_1..o_3, a_1..a_3, b_1..b_3, psi_1..psi_3): 30 numbers, metres and
radians. Whatever markers cannot tell apart on a stand that never rotates (a common shift of the
P_i against the markers, of the B_i against the motion-capture frame, a turn of the whole base
about z) the core fixes by a stated convention: the stand need not.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.hookspecs import hookimpl
from platkit.io.description import check_fields, check_platform, load_yaml, number, require, vector
from platkit.model import Control, Coordinate, Parameter, PlatformFactory, PlatformSpec, length_scale

NAME = "delta"
N_ARMS = 3
DEFAULT_DESCRIPTION = Path(__file__).with_name("delta.yaml")
TOP_FIELDS = ("units", "arms", "neutral_pose", "workspace")
ARM_FIELDS = ("name", "base_joint", "azimuth_deg", "platform_joint", "upper_arm", "forearm", "zero_offset", "range")


def read_description(path: Path) -> dict:
    """Parse and check a description; return SI arrays. Every error names the file and field."""
    data = load_yaml(path)
    check_platform(data, NAME, path)
    check_fields(data, TOP_FIELDS, path)
    units = require(data, "units", path, dict)
    scale = length_scale(str(units.get("length", "")))
    arms = require(data, "arms", path, list)
    if len(arms) != N_ARMS:
        raise BadDescription(f"{path}: field 'arms' must list {N_ARMS} arms, got {len(arms)}")
    out = {k: [] for k in ("names", "B", "P", "psi", "a", "b", "offset", "ranges")}
    for i, arm in enumerate(arms):
        where = f"arms[{i}]"
        if not isinstance(arm, dict):
            raise BadDescription(f"{path}: {where} must be a mapping")
        check_fields(arm, ARM_FIELDS, path, where)
        out["names"].append(require(arm, "name", path, str, where))
        out["B"].append(vector(arm, "base_joint", path, 3, where) * scale)
        out["P"].append(vector(arm, "platform_joint", path, 3, where) * scale)
        out["psi"].append(np.radians(number(arm, "azimuth_deg", path, where)))
        a = number(arm, "upper_arm", path, where) * scale
        b = number(arm, "forearm", path, where) * scale
        if not 0 < a < b:
            raise BadDescription(f"{path}: fields '{where}.upper_arm' and '{where}.forearm' must satisfy "
                                 "0 < upper_arm < forearm")
        out["a"].append(a)
        out["b"].append(b)
        out["offset"].append(number(arm, "zero_offset", path, where))
        r = vector(arm, "range", path, 2, where)
        if not r[0] < r[1]:
            raise BadDescription(f"{path}: field '{where}.range' must be [min, max] with min < max")
        out["ranges"].append(r)
    neutral = require(data, "neutral_pose", path, dict)
    check_fields(neutral, ("position",), path, "neutral_pose")
    X0 = vector(neutral, "position", path, 3, "neutral_pose") * scale
    box = require(data, "workspace", path, dict)
    check_fields(box, ("min", "max"), path, "workspace")
    lo = vector(box, "min", path, 3, "workspace") * scale
    hi = vector(box, "max", path, 3, "workspace") * scale
    if not np.all(lo < X0) or not np.all(X0 < hi):
        raise BadDescription(f"{path}: field 'neutral_pose.position' must lie inside 'workspace' (min < position < max)")
    arrays = {k: np.array(v, float) for k, v in out.items() if k != "names"}
    return dict(names=out["names"], X0=X0, lo=lo, hi=hi, raw=data, **arrays)


def arm_geometry(u, td, X):
    """CasADi 3x3 arrays, one column per arm: forearms (platform joint - elbow) and the elbows'
    directions of travel t_i = d E_i / d theta_i / a_i."""
    B = ca.reshape(td[0:9], 3, 3)
    P = ca.reshape(td[9:18], 3, 3)
    theta = u + td[18:21]
    a, psi = td[21:24], td[27:30]
    z = ca.DM([0.0, 0.0, 1.0])
    forearms, t = [], []
    for i in range(N_ARMS):
        d = ca.vertcat(ca.cos(psi[i]), ca.sin(psi[i]), 0)
        E = B[:, i] + a[i] * (ca.cos(theta[i]) * d - ca.sin(theta[i]) * z)
        forearms.append(X + P[:, i] - E)
        t.append(-ca.sin(theta[i]) * d - ca.cos(theta[i]) * z)
    return ca.horzcat(*forearms), ca.horzcat(*t)


def arm_angles(td, X):
    """Closed-form inverse kinematics: commands u (3,) for a platform position; NaN where a
    forearm cannot reach.

    With w = X + P_i - B_i, |w - a (cos theta d - sin theta z)| = b reads
    (w.d) cos theta - w_z sin theta = (|w|^2 + a^2 - b^2) / (2 a) = K, i.e. rho cos(theta + phi) = K
    with rho = |(w.d, w_z)|, phi = atan2(w_z, w.d). Of its two roots we keep
    theta = -acos(K / rho) - phi, the elbow outside (the stand's branch).
    """
    B = ca.reshape(td[0:9], 3, 3)
    P = ca.reshape(td[9:18], 3, 3)
    a, b, psi = td[21:24], td[24:27], td[27:30]
    u = []
    for i in range(N_ARMS):
        d = ca.vertcat(ca.cos(psi[i]), ca.sin(psi[i]), 0)
        w = X + P[:, i] - B[:, i]
        wd = ca.dot(w, d)
        rho = ca.sqrt(wd * wd + w[2] * w[2])
        ratio = (ca.dot(w, w) + a[i] * a[i] - b[i] * b[i]) / (2 * a[i] * rho)
        theta = -ca.acos(ca.fmin(ca.fmax(ratio, -1), 1)) - ca.atan2(w[2], wd)
        theta = ca.atan2(ca.sin(theta), ca.cos(theta))  # into (-pi, pi]
        u.append(ca.if_else(ca.fabs(ratio) <= 1, theta - td[18 + i], np.nan))
    return ca.vertcat(*u)


def build(path: Path | None, options: dict) -> PlatformSpec:
    """Build the stand from a description file (None: the one shipped in this package)."""
    if options:
        raise BadInput(f"the {NAME} stand takes no options, got {sorted(options)}")
    path = path or DEFAULT_DESCRIPTION
    desc = read_description(path)
    src = str(path)
    params = [Parameter(f"B{i + 1}_{c}", "m", float(v), group="base_joints", source=src)
              for i in range(N_ARMS) for c, v in zip("xyz", desc["B"][i])]
    params += [Parameter(f"P{i + 1}_{c}", "m", float(v), group="platform_joints", source=src)
               for i in range(N_ARMS) for c, v in zip("xyz", desc["P"][i])]
    params += [Parameter(f"o{i + 1}", "rad", float(v), group="zero_offsets", source=src)
               for i, v in enumerate(desc["offset"])]
    params += [Parameter(f"a{i + 1}", "m", float(v), 0.0, np.inf, group="upper_arms", source=src)
               for i, v in enumerate(desc["a"])]
    params += [Parameter(f"b{i + 1}", "m", float(v), 0.0, np.inf, group="forearms", source=src)
               for i, v in enumerate(desc["b"])]
    params += [Parameter(f"psi{i + 1}", "rad", float(v), group="azimuths", source=src)
               for i, v in enumerate(desc["psi"])]

    u = ca.SX.sym("u", N_ARMS)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    forearms, t = arm_geometry(u, td, X)
    lengths = ca.sqrt(ca.sum1(forearms**2)).T
    residual = ca.Function("F", [u, td, q, X], [lengths - td[24:27]], ["u", "td", "q", "X"], ["r"])
    # Assembly mode: every elbow outside, (J - E).t > 0 with t the elbow's direction of travel.
    # The other root of each arm's equation (elbow in) and the mirror pose with the platform
    # above the elbows have it < 0.
    branch = ca.Function("branch", [u, td, q, X], [ca.sum1(forearms * t).T / td[24:27]], ["u", "td", "q", "X"], ["g"])
    inverse = ca.Function("inverse", [td, q, X], [arm_angles(td, X)], ["td", "q", "X"], ["u"])

    p = ca.SX.sym("p", 3)
    pose = ca.Function("pose", [p], [ca.DM([1.0, 0.0, 0.0, 0.0]), p], ["p"], ["q", "X"])
    from_pose = ca.Function("coordinates_from_pose", [q, X], [X], ["q", "X"], ["p"])
    coords = [Coordinate(n, "m", float(v), float(lo), float(hi))
              for n, v, lo, hi in zip("xyz", desc["X0"], desc["lo"], desc["hi"])]

    td0 = np.array([prm.nominal for prm in params])
    u0 = np.asarray(inverse(td0, [1.0, 0.0, 0.0, 0.0], desc["X0"])).ravel()
    controls = []
    for name, (lo, hi), neutral in zip(desc["names"], desc["ranges"], u0):
        if not lo <= neutral <= hi:
            raise BadDescription(f"{path}: field 'neutral_pose' needs arm {name} at {neutral:.4f} rad, outside its range")
        controls.append(Control(name, "rad", float(lo), float(hi), float(neutral)))
    return PlatformSpec(
        name=NAME, title="Clavel delta robot (three rotary arms, translation only)", controls=controls,
        parameters=params, coordinates=coords, residual=residual, pose=pose, coordinates_from_pose=from_pose,
        inverse=inverse, branch=branch, description=desc["raw"], description_path=path,
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory(NAME, "Clavel delta robot (three rotary arms, translation only)", build, (".yaml", ".yml"))]
