"""CasADi kinematics of a URDF chain or tree: the parameters (td), joint values, link poses, the
stand's PlatformSpec, frame Jacobians. Joint model and td layout: :mod:`platkit.urdf`."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadInput
from platkit.geometry import (
    ca_matrix_from_rpy,
    ca_quat_from_rpy,
    ca_quat_multiply,
    matrix_from_rpy,
    quat_from_matrix,
    quat_normalize,
    rpy_from_quat,
)
from platkit.model import Control, Parameter, PlatformSpec, six_dof_pose
from platkit.urdf._tree import ACTUATED_TYPES, KinematicTree, SerialChain, UrdfJoint

ORIGIN_FIELDS = ("origin_x", "origin_y", "origin_z", "origin_rx", "origin_ry", "origin_rz")
CONTROL_UNIT_FACTORS = {"rad": 1.0, "m": 1.0, "deg": np.pi / 180.0}


# ----------------------------------------------------------------------------- parameters


def chain_parameters(chain, free_groups: tuple[str, ...] = ("offset", "origin")) -> list[Parameter]:
    """The td list of a chain or tree (layout in :mod:`platkit.urdf`). ``free_groups``: which of
    the groups 'offset', 'scale', 'origin', 'mimic' start free (the estimator may fix
    unidentifiable ones)."""
    params = []
    src = str(chain.path)
    for j in chain.calibrated:
        if j.actuated:
            params.append(Parameter(f"{j.name}.offset", j.unit, 0.0, free="offset" in free_groups, group="offset",
                                    source=f"{src}: joint {j.name} zero (nominal: the URDF zero)"))
            params.append(Parameter(f"{j.name}.scale", "1", 1.0, lower=0.0, free="scale" in free_groups, group="scale",
                                    source=f"{src}: joint {j.name} (nominal: one joint unit per control unit)"))
        else:
            master, multiplier, offset = j.mimic
            params.append(Parameter(f"{j.name}.mimic_multiplier", "1", multiplier, free="mimic" in free_groups,
                                    group="mimic", source=f"{src}: joint {j.name} <mimic joint='{master}' multiplier>"))
            params.append(Parameter(f"{j.name}.mimic_offset", j.unit, offset, free="mimic" in free_groups,
                                    group="mimic", source=f"{src}: joint {j.name} <mimic joint='{master}' offset>"))
        xyz = " ".join(format(v + 0.0, ".9g") for v in j.origin[:3, 3])  # + 0.0: no '-0'
        rpy = " ".join(format(v + 0.0, ".9g") for v in urdf_rpy(j.origin[:3, :3]))
        for f in ORIGIN_FIELDS:
            unit = "m" if f in ("origin_x", "origin_y", "origin_z") else "rad"
            params.append(Parameter(f"{j.name}.{f}", unit, 0.0, free="origin" in free_groups, group="origin",
                                    source=f"{src}: error of joint {j.name} <origin xyz='{xyz}' rpy='{rpy}'>, "
                                           "in the joint frame"))
    return params


def joint_origins(chain) -> dict[str, dict]:
    """The URDF's nominal numbers of the chain's joints, plain (for reports):
    {joint: {type, parent, child, xyz (m), rpy (rad), axis, lower, upper}}."""
    return {
        j.name: {"type": j.type, "parent": j.parent, "child": j.child,
                 "xyz": j.origin[:3, 3].tolist(), "rpy": urdf_rpy(j.origin[:3, :3]).tolist(),
                 "axis": j.axis.tolist(), "lower": j.lower, "upper": j.upper}
        for j in chain.joints
    }


# ----------------------------------------------------------------------------- kinematics


def _axis_rotation(axis: np.ndarray, theta):
    """CasADi rotation matrix and quaternion of angle ``theta`` about the unit ``axis``."""
    K = ca.DM(np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]]))
    R = ca.DM.eye(3) + ca.sin(theta) * K + (1 - ca.cos(theta)) * ca.mtimes(K, K)
    q = ca.vertcat(ca.cos(theta / 2), ca.sin(theta / 2) * ca.DM(axis))
    return R, q


def joint_values(calibrated: list[UrdfJoint], control_units: list[str], u, td):
    """(theta {joint: SI value}, td_start {joint: index of its first parameter}) of the actuated and
    mimic joints ``calibrated`` (td laid out as :func:`chain_parameters`), for controls ``u`` in
    ``control_units``: actuated joints take the controls in order, mimic joints follow their master."""
    theta_of: dict[str, object] = {}
    td_start: dict[str, int] = {}
    k = i = 0
    for j in calibrated:
        td_start[j.name] = k
        if j.actuated:
            offset, scale = td[k], td[k + 1]
            theta_of[j.name] = scale * (CONTROL_UNIT_FACTORS[control_units[i]] * u[i] - offset)
            i += 1
        k += 8
    assert k == td.shape[0] and i == u.shape[0], "td or u does not match the chain"
    for j in calibrated:  # a mimic joint may come before its master
        if not j.actuated:
            k = td_start[j.name]
            theta_of[j.name] = td[k] * theta_of[j.mimic[0]] + td[k + 1]
    return theta_of, td_start


def _joint_local(j: UrdfJoint, theta_of: dict, td_start: dict, td):
    """(R, q, X) of parent_from_child of joint ``j``: its origin, origin error and motion. A joint
    without parameters (fixed, or not a control: held at its zero, a mimic at its offset) is its
    origin and that constant motion."""
    R0 = j.origin[:3, :3]
    t0 = j.origin[:3, 3]
    q0 = quat_from_matrix(R0)
    if j.name in td_start:
        theta = theta_of[j.name]
        k = td_start[j.name] + 2
        d = td[k:k + 3]
        rx, ry, rz = td[k + 3], td[k + 4], td[k + 5]
        X_local = ca.DM(t0) + ca.mtimes(ca.DM(R0), d)
        R_local = ca.mtimes(ca.DM(R0), ca_matrix_from_rpy(rx, ry, rz))
        q_local = ca_quat_multiply(ca.DM(q0), ca_quat_from_rpy(rx, ry, rz))
    else:
        theta = 0.0 if j.mimic is None else j.mimic[2]
        X_local, R_local, q_local = ca.DM(t0), ca.DM(R0), ca.DM(q0)
        if j.type not in ACTUATED_TYPES:
            return R_local, q_local, X_local
    # parent_from_child = origin * Trans(d) * R_err * motion(theta)
    if j.type == "prismatic":
        X_local = X_local + ca.mtimes(R_local, ca.DM(j.axis)) * theta
    else:
        R_joint, q_joint = _axis_rotation(j.axis, theta)
        R_local = ca.mtimes(R_local, R_joint)
        q_local = ca_quat_multiply(q_local, q_joint)
    return R_local, q_local, X_local


def _compose(acc, local):
    R_acc, q_acc, X_acc = acc
    R_local, q_local, X_local = local
    return ca.mtimes(R_acc, R_local), ca_quat_multiply(q_acc, q_local), X_acc + ca.mtimes(R_acc, X_local)


_IDENTITY = (ca.DM.eye(3), ca.DM([1.0, 0.0, 0.0, 0.0]), ca.DM.zeros(3))


def chain_kinematics(chain, control_units: list[str], u, td, link: str | None = None):
    """Symbolic forward kinematics of a chain or tree: (R 3x3, q (4,), X (3,)) of ``link`` (default:
    the moving link) in the base link, for controls ``u`` (n_u,) in ``control_units`` and
    parameters ``td`` laid out as :func:`chain_parameters`."""
    return link_kinematics(chain, control_units, u, td, [link or chain.moving_link])[0]


def link_kinematics(chain, control_units: list[str], u, td, links: list[str]):
    """[(R 3x3, q (4,), X (3,)) per link of ``links``] in the base link of a chain or tree; the
    joints shared by several links' paths are composed once."""
    theta_of, td_start = joint_values(chain.calibrated, control_units, u, td)
    tree = chain.tree
    done: dict[str, tuple] = {chain.base_link: _IDENTITY}

    def pose_of(link: str):
        path = []
        while link not in done:
            joint = tree.joints[tree.parent_joint[link]]
            path.append(joint)
            link = joint.parent
        acc = done[link]
        for j in reversed(path):
            acc = done[j.child] = _compose(acc, _joint_local(j, theta_of, td_start, td))
        return acc

    return [pose_of(link) for link in links]


def orientation_error(q_model, q):
    """Rotation vector (small-angle) taking q_model to q, sign-safe: 2 * vec(q_model^-1 q) * sign(w).

    Zero exactly when q = +-q_model; ``q`` need not be unit."""
    conj = ca.vertcat(q_model[0], -q_model[1], -q_model[2], -q_model[3])
    d = ca_quat_multiply(conj, q)
    return 2 * ca.if_else(d[0] < 0, -1, 1) * d[1:]


def chain_spec(
    chain: SerialChain | KinematicTree,
    *,
    name: str,
    title: str,
    control_names: list[str] | None = None,
    control_units: list[str] | None = None,
    free_groups: tuple[str, ...] = ("offset", "origin"),
    description: dict | None = None,
    description_path: Path | None = None,
) -> PlatformSpec:
    """A PlatformSpec for a serial chain or a tree: closed-form forward, 6-row residual, six-dof
    pose of the moving link; on a tree also ``tracked_links`` and ``link_poses`` (every tracked
    link's pose, the moving link first).

    Residual (6 rows): ``[X - X_fk(u, td); orientation_error(q_fk(u, td), q)]`` in metres and
    radians. Controls default to the actuated joints' names in their URDF units (rad, m);
    ``control_units`` may say 'deg' for revolute joints. Bounds are the URDF limits in the
    control's unit at nominal scale; neutral controls are 0 clipped into the limits.
    """
    actuated = chain.actuated
    n_u = len(actuated)
    names = control_names or [j.name for j in actuated]
    units = control_units or [j.unit for j in actuated]
    if len(names) != n_u or len(units) != n_u:
        raise BadInput(f"{chain.path}: {n_u} actuated joints on the chain but {len(names)} control names / {len(units)} units")
    for j, unit in zip(actuated, units):
        if unit not in (("m",) if j.type == "prismatic" else ("rad", "deg")):
            raise BadInput(f"{chain.path}: joint {j.name!r} ({j.type}) cannot take controls in {unit!r}")
    params = chain_parameters(chain, free_groups)
    u = ca.SX.sym("u", n_u)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    tracked = list(chain.links) if isinstance(chain, KinematicTree) else []
    frames = link_kinematics(chain, units, u, td, tracked or [chain.moving_link])
    _, q_fk, X_fk = frames[0]
    forward = ca.Function("forward", [u, td], [q_fk, X_fk], ["u", "td"], ["q", "X"])
    link_poses = None
    if tracked:
        link_poses = ca.Function("link_poses", [u, td], [ca.vertcat(*[f[1] for f in frames]),
                                                         ca.vertcat(*[f[2] for f in frames])],
                                 ["u", "td"], ["q", "X"])
    residual = ca.Function("F", [u, td, q, X], [ca.vertcat(X - X_fk, orientation_error(q_fk, q))],
                           ["u", "td", "q", "X"], ["r"])
    controls = []
    for j, n, unit in zip(actuated, names, units):
        c = CONTROL_UNIT_FACTORS[unit]
        lo, hi = j.lower / c, j.upper / c
        controls.append(Control(n, unit, lo, hi, float(np.clip(0.0, lo, hi))))
    u0 = np.array([c.neutral for c in controls])
    td0 = np.array([p.nominal for p in params])
    q0, X0 = (np.asarray(a).ravel() for a in forward(u0, td0))
    coords, pose, from_pose = six_dof_pose(X0, rpy_from_quat(quat_normalize(q0)))
    return PlatformSpec(
        name=name,
        title=title,
        controls=controls,
        parameters=params,
        coordinates=coords,
        residual=residual,
        pose=pose,
        coordinates_from_pose=from_pose,
        forward=forward,
        description=description if description is not None else {
            "urdf": str(chain.path), "base_link": chain.base_link, "moving_link": chain.moving_link},
        description_path=description_path if description_path is not None else chain.path,
        moving_frame=chain.moving_link,
        base_frame=chain.base_link,
        extras={"chain": chain, "control_units": units, "urdf_path": chain.path,
                "joint_origins": joint_origins(chain)},
        tracked_links=tracked,
        link_poses=link_poses,
    )


def frame_jacobian(spec: PlatformSpec, link: str | None = None) -> ca.Function:
    """CasADi ``J(u, td) -> (J_lin (3, n_u), J_ang (3, n_u))``: the origin velocity and angular
    velocity of ``link`` (default: the moving frame; on a tree any link of it), both in base-frame
    axes, per unit control rate (control units). Mimic joints move with their master."""
    chain = spec.extras["chain"]
    if link is not None:
        link_pose_function(spec, [link])  # BadInput for a link not in the URDF or not below the base
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    R, _, X = chain_kinematics(chain, spec.extras["control_units"], u, td, link)
    J_lin = ca.jacobian(X, u)
    cols = []
    for i in range(spec.n_u):
        W = ca.mtimes(ca.jacobian(ca.vec(R), u[i]).reshape((3, 3)), R.T)  # dR/du_i R^T = skew(w_i)
        cols.append(ca.vertcat(W[2, 1], W[0, 2], W[1, 0]))
    J_ang = ca.horzcat(*cols)
    return ca.Function("frame_jacobian", [u, td], [J_lin, J_ang], ["u", "td"], ["J_lin", "J_ang"])


def link_pose_function(spec: PlatformSpec, links: list[str]) -> ca.Function:
    """CasADi ``(u, td) -> (q (4 L), X (3 L))``: the poses of any ``links`` of a URDF-route stand's
    tree (below its base link) in the base frame, stacked in that order. BadInput naming a link
    that is not in the URDF or not below the base."""
    chain = spec.extras.get("chain")
    if chain is None:
        raise BadInput(f"stand {spec.name!r} is not described by a URDF; it has no links to ask for")
    tree = chain.tree
    for link in links:
        if link not in tree.links:
            raise BadInput(f"{chain.path}: link {link!r} is not a link of the URDF")
        walk = link
        while walk != chain.base_link:
            if walk not in tree.parent_joint:
                raise BadInput(f"{chain.path}: link {link!r} is not below base_link {chain.base_link!r}")
            walk = tree.joints[tree.parent_joint[walk]].parent
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    frames = link_kinematics(chain, spec.extras["control_units"], u, td, list(links))
    return ca.Function("link_poses", [u, td], [ca.vertcat(*[f[1] for f in frames]), ca.vertcat(*[f[2] for f in frames])],
                       ["u", "td"], ["q", "X"])


def urdf_rpy(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of a URDF <origin rpy> (R = Rz(yaw) Ry(pitch) Rx(roll)), accurate to
    rounding also near pitch = +-pi/2: yaw is taken from what roll and pitch leave, so an error
    of roll along the gimbal-lock direction is absorbed."""
    R = np.asarray(R, float)
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    roll = np.arctan2(R[2, 1], R[2, 2]) if np.hypot(R[2, 1], R[2, 2]) > 1e-12 else 0.0
    rest = R @ matrix_from_rpy(roll, pitch, 0.0).T  # = Rz(yaw)
    yaw = np.arctan2(rest[1, 0], rest[0, 0])
    return np.array([roll, pitch, yaw])
