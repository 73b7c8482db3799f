"""platkit track: drive links of a URDF chain to targets, or along a trajectory, by the tracking servo."""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from platkit.chains import KinematicChain, ServoOptions, Task, follow_trajectory, parse_selection
from platkit.chains.servo import Servo
from platkit.chains.tasks import SECONDARY_COSTS, failure_message
from platkit.chains.transforms import pose_from_xyz_rpy
from platkit.commands.common import parse_vector, print_json
from platkit.errors import BadInput, OutOfWorkspace
from platkit.io.atomic import atomic_write_text, check_output_file
from platkit.limits import RECORDING_TOLERANCE, ROUNDING
from platkit.model import length_scale
from platkit.notices import said, warn


def add_parser(sub):
    p = sub.add_parser(
        "track", help="drive a link of a URDF chain to a target or along a trajectory (tracking servo)",
        description="Drive one or more links of a URDF robot to their targets (or one link along a "
                    "trajectory) and write the joint path. Lengths in --unit, angles in radians; "
                    "rotations as roll,pitch,yaw (R = Rz Ry Rx) or qw,qx,qy,qz.")
    p.add_argument("--urdf", required=True, help="the robot's URDF file (no meshes are read)")
    p.add_argument("--link", required=True, action="append",
                   help="link to drive; repeat for several links of a tree (one --target each)")
    p.add_argument("--base", default="world",
                   help="link whose frame the targets are given in (default: the URDF root); "
                        "if joints move it, the targets move with it")
    goal = p.add_mutually_exclusive_group(required=True)
    goal.add_argument("--target", action="append",
                      help="x,y,z[,roll,pitch,yaw | ,qw,qx,qy,qz] of the link in --base; repeat per --link; "
                           "x,y,z alone leaves the rotation free")
    goal.add_argument("--trajectory", help="CSV with columns t,x,y,z and optionally roll,pitch,yaw or qw,qx,qy,qz")
    p.add_argument("--out", required=True, help="joint path CSV to write: step (or t), then one column per joint")
    p.add_argument("--q0", default="mid",
                   help="start: 'mid' (middle of each joint's range, default), 'zero', comma-separated values "
                        "for every joint, or name=value pairs (others mid-range)")
    p.add_argument("--select", action="append",
                   help="components to control, of x,y,z,rx,ry,rz (e.g. 'xyz', 'xyzrz'); once for all links or once per link")
    p.add_argument("--weights", action="append",
                   help="six weights for x,y,z,rx,ry,rz (0 leaves one free); once for all links or once per link")
    p.add_argument("--frame-basis", choices=["base", "local"], default="base",
                   help="read --select/--weights components in the --base frame (default) or in the link's own")
    p.add_argument("--lock", default="", help="comma-separated joints that must not move")
    p.add_argument("--solver", choices=["pinv", "lp"], default="pinv",
                   help="inverse velocity by damped pseudo-inverse (default) or linear programming")
    p.add_argument("--secondary", choices=SECONDARY_COSTS, default="none",
                   help="cost minimised in the null space of redundant chains")
    p.add_argument("--unit", choices=["m", "mm"], default="m",
                   help="length unit of targets, trajectory, tolerances, prismatic joints and reported errors (default m)")
    p.add_argument("--tol-pos", type=float, default=1e-6, help="position tolerance in --unit (default 1e-6 m)")
    p.add_argument("--tol-rot", type=float, default=1e-6, help="rotation tolerance in rad (default 1e-6)")
    p.add_argument("--max-iterations", type=int, default=500, help="servo steps per target (default 500)")
    p.add_argument("--max-seconds", type=float, default=30.0, help="time cap per target in s (default 30)")
    p.add_argument("--restarts", type=int, default=0,
                   help="retry a failed target from this many random configurations (the path written is the "
                        "successful attempt's)")
    p.add_argument("--seed", type=int, default=0, help="seed of the restarts")
    p.add_argument("--dt", type=float, default=0.1, help="servo period in s: joints move at most rate limit * dt per step")
    p.add_argument("--no-rate-limits", action="store_true", help="ignore the URDF's velocity limits")
    p.add_argument("--step-pos", type=float, default=None,
                   help="trajectory resampling: largest position step in --unit (default 5 mm)")
    p.add_argument("--step-rot", type=float, default=0.02, help="trajectory resampling: largest rotation step in rad")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def _start(chain: KinematicChain, text: str, unit: str) -> np.ndarray:
    text = text.strip()
    if text == "mid":
        return chain.mid_range()
    if text == "zero":
        return chain.neutral()
    s = length_scale(unit)
    prismatic = np.array([k == "prismatic" for k in chain.kinds])
    if "=" in text:
        theta = chain.mid_range()
        for item in text.split(","):
            if not item.strip():
                continue
            name, _, value = item.partition("=")
            name = name.strip()
            if name not in chain.joint_names:
                raise BadInput(f"--q0: no joint named {name!r}; joints: {', '.join(chain.joint_names)}")
            v = parse_vector(value, f"--q0 {name}", 1)[0]
            i = chain.joint_names.index(name)
            theta[i] = v * s if prismatic[i] else v
    else:
        v = parse_vector(text, "--q0", chain.n)
        theta = np.where(prismatic, v * s, v)
    check_start(chain, theta, unit)
    return theta


def check_start(chain: KinematicChain, theta: np.ndarray, length_unit: str) -> None:
    """--q0 against the joint limits under platkit.limits' policy for a reading: past a limit by
    at most RECORDING_TOLERANCE of the joint's range, a warning (the servo starts at the limit);
    further, BadInput naming the joint, its value, its range and how far past it is. Prismatic
    joints are shown in ``length_unit`` (--unit)."""
    s = length_scale(length_unit)
    for name, kind, t, lo, hi in zip(chain.joint_names, chain.kinds, theta, chain.lower, chain.upper):
        rounding = ROUNDING * max([1.0] + [abs(v) for v in (lo, hi) if np.isfinite(v)])
        if lo - rounding <= t <= hi + rounding:
            continue
        k, unit = (s, length_unit) if kind == "prismatic" else (1.0, "rad")
        limit = lo if t < lo else hi
        span = hi - lo
        slack = RECORDING_TOLERANCE * span if np.isfinite(span) and span > 0 else 0.0
        past = abs(t - limit)
        where = (f"--q0 joint {name!r}: {t / k:.6g} is past the limit {limit / k:.6g} {unit} by {past / k:.3g} {unit}; "
                 f"the range is [{lo / k:.6g}, {hi / k:.6g}] {unit}")
        if past > slack:
            raise BadInput(f"{where}; more than the recording tolerance ({slack / k:.3g} {unit}, "
                           f"{RECORDING_TOLERANCE:.0%} of the range)")
        warn(f"{where}; within the recording tolerance ({slack / k:.3g} {unit}, {RECORDING_TOLERANCE:.0%} of the "
             "range: encoder noise or a soft limit): the servo starts at the limit")


def _per_link(values: list[str] | None, n_links: int, option: str) -> list[str | None]:
    if not values:
        return [None] * n_links
    if len(values) == 1:
        return values * n_links
    if len(values) != n_links:
        raise BadInput(f"{option}: give it once for all links or once per --link ({n_links}), got {len(values)}")
    return values


def _weights(select: str | None, weights: str | None, rotation_given: bool) -> np.ndarray:
    w = np.ones(6) if weights is None else parse_vector(weights, "--weights", 6)
    if np.any(w < 0) or not np.any(w > 0):
        raise BadInput("--weights: six non-negative numbers, not all zero")
    if select is not None:
        w = w * parse_selection(select)
    elif not rotation_given:
        w[3:] = 0.0
    if not np.any(w > 0):
        raise BadInput("--select/--weights leave no component to control")
    return w


def _target(text: str, s: float) -> tuple[np.ndarray, bool]:
    v = parse_vector(text, "--target")
    if v.size not in (3, 6, 7):
        raise BadInput(f"--target: expected x,y,z or x,y,z,roll,pitch,yaw or x,y,z,qw,qx,qy,qz, got {v.size} numbers")
    if v.size == 7 and np.linalg.norm(v[3:]) == 0:
        raise BadInput("--target: the quaternion is zero")
    v = v.copy()
    v[:3] *= s
    return pose_from_xyz_rpy(v), v.size > 3


def read_trajectory(path: str, s: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """(times (k,), poses (k, 4, 4), rotation given) from a trajectory CSV; BadInput naming the
    file, row and column on anything malformed (the numbers are read by the session reader,
    :func:`platkit.io.table.read_table`, so every CSV of platkit words its errors alike)."""
    from platkit.io.table import read_table

    table = read_table(Path(path), "trajectory")
    p, header = table.path, table.header
    for col in ("t", "x", "y", "z"):
        if col not in header:
            raise BadInput(f"{p}: missing column {col!r}; expected t,x,y,z[,roll,pitch,yaw | qw,qx,qy,qz]")
    rpy = all(c in header for c in ("roll", "pitch", "yaw"))
    quat = all(c in header for c in ("qw", "qx", "qy", "qz"))
    if rpy and quat:
        raise BadInput(f"{p}: give the rotation as roll,pitch,yaw or as qw,qx,qy,qz, not both")
    for group, whole in ((("roll", "pitch", "yaw"), rpy), (("qw", "qx", "qy", "qz"), quat)):
        partial = [c for c in group if c in header]
        if partial and not whole:  # a rotation half given would be silently dropped
            missing = [c for c in group if c not in header]
            raise BadInput(f"{p}: column {partial[0]!r} without {', '.join(repr(c) for c in missing)}; "
                           f"a rotation needs all of {','.join(group)}")
    cols = ["t", "x", "y", "z"] + (["roll", "pitch", "yaw"] if rpy else ["qw", "qx", "qy", "qz"] if quat else [])
    data = table.data[:, [header.index(c) for c in cols]]
    bad = np.argwhere(~np.isfinite(data))
    if bad.size:
        r, j = bad[0]
        raise BadInput(f"{table.where(int(r), cols[j])}: empty or nan; a trajectory needs every value")
    times, poses = data[:, 0], []
    for r, values in enumerate(data):
        v = values[1:].copy()
        v[:3] *= s
        if quat and np.linalg.norm(v[3:]) == 0:
            raise BadInput(f"{p} row {r + 1} (line {r + 2}): the quaternion is zero")
        if r and times[r] < times[r - 1]:
            raise BadInput(f"{table.where(r, 't')}: times must not decrease "
                           f"({times[r]} after {times[r - 1]})")
        poses.append(pose_from_xyz_rpy(v))
    return times.copy(), np.array(poses), rpy or quat


def _csv(first: str, keys: np.ndarray, thetas: np.ndarray, chain: KinematicChain, s: float) -> str:
    prismatic = np.array([k == "prismatic" for k in chain.kinds])
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([first] + chain.joint_names)
    for key, theta in zip(keys, thetas):
        vals = np.where(prismatic, theta / s, theta)
        w.writerow([key if first == "step" else repr(float(key))] + [repr(float(v)) for v in vals])
    return out.getvalue()


def run(args) -> int:
    s = length_scale(args.unit)
    check_output_file(args.out)
    chain = KinematicChain.from_urdf(args.urdf)
    links = args.link
    for name in links + [args.base]:
        chain.frame_id(name)
    theta0 = _start(chain, args.q0, args.unit)
    for name, value in (("--tol-pos", args.tol_pos), ("--tol-rot", args.tol_rot), ("--max-seconds", args.max_seconds), ("--dt", args.dt)):
        if not value > 0:
            raise BadInput(f"{name}: must be positive, got {value}")
    if args.restarts < 0:
        raise BadInput(f"--restarts: must be 0 or more, got {args.restarts}")
    if args.seed < 0:
        raise BadInput(f"--seed: must be 0 or more, got {args.seed}")
    if args.max_iterations < 1:
        raise BadInput(f"--max-iterations: must be 1 or more, got {args.max_iterations}")
    options = ServoOptions(
        tol_position=args.tol_pos * s, tol_rotation=args.tol_rot, max_iterations=args.max_iterations,
        max_seconds=args.max_seconds, dt=args.dt, use_rate_limits=not args.no_rate_limits, solver=args.solver,
        secondary=args.secondary, locked=[n.strip() for n in args.lock.split(",") if n.strip()],
        restarts=args.restarts, seed=args.seed)
    basis = "local" if args.frame_basis == "local" else "reference"
    selects = _per_link(args.select, len(links), "--select")
    weights = _per_link(args.weights, len(links), "--weights")
    report: dict = {"urdf": str(args.urdf), "links": links, "base": args.base, "unit": args.unit, "out": str(args.out)}

    if args.trajectory is not None:
        if len(links) != 1:
            raise BadInput("--trajectory drives one --link")
        times, poses, rotation_given = read_trajectory(args.trajectory, s)
        w = _weights(selects[0], weights[0], rotation_given)
        step_pos = 0.005 if args.step_pos is None else args.step_pos * s
        if not (step_pos > 0 and args.step_rot > 0):
            raise BadInput("--step-pos and --step-rot must be positive")
        result = follow_trajectory(chain, links[0], times, poses, frame=args.base, theta0=theta0, weights=w,
                                   basis=basis, options=options, max_linear_step=step_pos,
                                   max_angular_step=args.step_rot)
        atomic_write_text(args.out, _csv("t", result.times, result.thetas, chain, s))
        report.update({
            "converged": True, "samples": int(result.times.size), "waypoints": int(times.size),
            "iterations": int(result.iterations),
            "max_position_error": float(result.position_errors.max() / s),
            "max_rotation_error": float(result.rotation_errors.max()),
            "final_joints": _joints_dict(chain, result.thetas[-1], s),
            "warnings": said(),  # every warning said while the verb ran (platkit.notices), on stderr too
        })
        if args.json:
            print_json(report)
            return 0
        print(f"followed {links[0]} through {times.size} waypoints ({result.times.size} samples, {result.iterations} servo steps)")
        print(f"largest error at a sample: position {report['max_position_error']:.3g} {args.unit}, "
              f"rotation {report['max_rotation_error']:.3g} rad")
        print(f"joint path written to {args.out}")
        return 0

    targets = args.target
    if len(targets) != len(links):
        raise BadInput(f"--target: one per --link ({len(links)}), got {len(targets)}")
    tasks = []
    for link, text, sel, wt in zip(links, targets, selects, weights):
        T, rotation_given = _target(text, s)
        tasks.append(Task(link, T, frame=args.base, weights=_weights(sel, wt, rotation_given), basis=basis))
    servo = Servo(chain, tasks, options)
    result = servo.run(theta0)
    if not result.converged:
        raise OutOfWorkspace(failure_message(tasks, result, args.unit, s))
    atomic_write_text(args.out, _csv("step", np.arange(len(result.path)), result.path, chain, s))
    report.update({
        "converged": True, "iterations": int(result.iterations), "restarts": int(result.restarts),
        "iterations_total": int(result.iterations_total), "refine_iterations": int(result.refine_iterations),
        "secondary": args.secondary, "secondary_cost_before": result.secondary_cost_before,
        "secondary_cost": result.secondary_cost,
        "position_errors": [e / s for e in result.position_errors], "rotation_errors": result.rotation_errors,
        "final_joints": _joints_dict(chain, result.theta, s),
        "warnings": said(),  # every warning said while the verb ran (platkit.notices), on stderr too
    })
    if args.json:
        print_json(report)
        return 0
    for task, pe, re in zip(tasks, result.position_errors, result.rotation_errors):
        parts = []
        if np.any(task.weights[:3] > 0):
            parts.append(f"position error {pe / s:.3g} {args.unit}")
        if np.any(task.weights[3:] > 0):
            parts.append(f"rotation error {re:.3g} rad")
        print(f"reached {task.link}: " + ", ".join(parts))
    line = f"{result.iterations} iterations"
    if result.restarts:
        line += f" after {result.restarts} restarts ({result.iterations_total} in all)"
    if result.refine_iterations and args.secondary == "manipulability":
        line += (f"; then {result.refine_iterations} null-space steps raised the manipulability "
                 f"from {-result.secondary_cost_before:.6g} to {-result.secondary_cost:.6g}")
    elif result.refine_iterations:
        line += (f"; then {result.refine_iterations} null-space steps lowered the {args.secondary} cost "
                 f"from {result.secondary_cost_before:.6g} to {result.secondary_cost:.6g}")
    print(line)
    print(f"joint path ({len(result.path)} rows) written to {args.out}")
    return 0


def _joints_dict(chain: KinematicChain, theta: np.ndarray, s: float) -> dict:
    return {n: float(v / s if k == "prismatic" else v) for n, k, v in zip(chain.joint_names, chain.kinds, theta)}
