"""platkit ik: controls from a pose."""
from __future__ import annotations

import numpy as np

from platkit.commands.common import (add_platform_options, add_unit_option, parse_vector, platform_from_args, print_json,
                                     unit_quaternion)
from platkit.errors import BadInput, OutOfWorkspace
from platkit.geometry import quat_conjugate, quat_from_rpy, quat_multiply, rpy_from_quat
from platkit.kinematics import PlatformModel
from platkit.model import controls_from_si, length_scale
from platkit.notices import said, warn
from platkit.plugins import get_platform


def add_parser(sub):
    p = sub.add_parser("ik", help="inverse kinematics: controls from a pose")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--pose", required=True,
                   help="x,y,z,roll,pitch,yaw (lengths in --unit, angles rad) or x,y,z,qw,qx,qy,qz; "
                        "or the stand's own pose coordinates with --coordinates")
    p.add_argument("--coordinates", action="store_true", help="--pose gives the stand's pose coordinates (see describe)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def run(args) -> int:
    spec = platform_from_args(args)
    model = PlatformModel(spec, length_unit=args.unit)
    s = length_scale(args.unit)
    if args.coordinates:
        p = parse_vector(args.pose, "--pose", spec.n_p)
        p = np.array([v * s if c.unit == "m" else v for v, c in zip(p, spec.coordinates)])
        q, X = model.pose(p)
    else:
        v = parse_vector(args.pose, "--pose")
        if v.size == 6:
            q = quat_from_rpy(*v[3:6])
        elif v.size == 7:
            q = unit_quaternion(v[3:], "--pose")
        else:
            raise BadInput(f"--pose: expected 6 (x,y,z,roll,pitch,yaw) or 7 (x,y,z,qw,qx,qy,qz) numbers, got {v.size}")
        X = v[:3] * s
        _check_pose_is_the_stands(model, q, X, args.unit)
    u = _off_the_moving_link_at_neutral(spec, model.inverse(q, X))
    if _controls_left_free(spec, model, u, q, X):
        warn(f"{spec.name}: {spec.n_u} controls for {spec.n_p} pose coordinates: these controls are one solution of "
             "many that give the pose")
    u_out = controls_from_si(spec, u, args.unit)
    names = spec.control_names
    units = [args.unit if c.unit == "m" else c.unit for c in spec.controls]
    if args.json:
        print_json({"platform": spec.name, "controls": dict(zip(names, u_out.tolist())), "units": dict(zip(names, units)),
                    "warnings": said()})  # every warning said while the verb ran, on stderr too
        return 0
    width = max([10] + [len(n) for n in names])
    for n, v, un in zip(names, u_out, units):
        print(f"{n:<{width}} {v:.6f} {un}")
    return 0


def _controls_left_free(spec, model: PlatformModel, u: np.ndarray, q: np.ndarray, X: np.ndarray) -> bool:
    """True when the pose leaves some control free: F_u, the residual's Jacobian in the controls at
    the pose, has rank below n_u (a redundantly actuated stand, a joint that does not move the
    tracked link). A stand with one row per control fixes every control, however many more controls
    than pose coordinates it has (a cable robot: each cable's length is that of the pose)."""
    if spec.n_u <= spec.n_p:
        return False
    if spec.coordinates_from_pose is None:
        return True
    J_u = np.asarray(model.F_jac(u, spec.nominal_td(), model.coordinates(q, X))[2], float)
    return bool(np.linalg.matrix_rank(J_u) < spec.n_u)


def _off_the_moving_link_at_neutral(spec, u: np.ndarray) -> np.ndarray:
    """On a URDF tree the pose asked is the moving link's (the first tracked): the joints that do
    not move it (the other arm, the head) are given at their neutral (within their strokes), not
    where the solver left them, and said."""
    chain = spec.extras.get("chain")
    if chain is None or len(spec.tracked_links) < 2 or not hasattr(chain, "required"):
        return u
    moving = {n for n, link in chain.required().items() if link == chain.moving_link}
    off = [i for i, n in enumerate(spec.control_names) if n not in moving]
    if not off:
        return u
    u = np.array(u, float)
    for i in off:
        c = spec.controls[i]
        u[i] = min(max(c.neutral, c.lower), c.upper)
    shown = ", ".join(spec.control_names[i] for i in off[:12]) + (f" and {len(off) - 12} more" if len(off) > 12 else "")
    warn(f"{spec.name}: the pose is that of the moving link {chain.moving_link!r}; the {len(off)} joints that do not "
         f"move it ({shown}) are given at their neutral")
    return u


def _check_pose_is_the_stands(model: PlatformModel, q, X, unit: str) -> None:
    """A stand with fewer than six pose coordinates (psvr: alpha, beta, h) can take only some
    poses; its residual may still be solvable at others (the rods reach a yawed platform), so
    ik would print controls for a pose the stand never takes. Refuse such a pose, saying the
    nearest one it can take."""
    spec = model.spec
    if spec.coordinates_from_pose is None:
        return
    q_near, X_near = model.pose(model.coordinates(q, X))
    d = quat_multiply(quat_conjugate(q_near), q)
    angle = 2.0 * np.arctan2(np.linalg.norm(d[1:]), abs(d[0]))
    s = length_scale(unit)
    # tolerances a pose typed back from printed numbers (9 significant digits) passes
    if np.linalg.norm(X_near - X) <= 1e-7 * max(1.0, np.linalg.norm(X)) and angle <= 1e-7:
        return
    rpy = rpy_from_quat(q_near)
    raise OutOfWorkspace(
        f"{spec.name} cannot take this pose: its pose coordinates are only {', '.join(spec.coordinate_names)}; "
        f"the nearest pose it takes is x,y,z = {', '.join(f'{v / s:.9g}' for v in X_near)} {unit}, "
        f"roll,pitch,yaw = {', '.join(f'{v:.9g}' for v in rpy)} rad (or give --coordinates)")
