"""Convergence of platkit's tracking servo against a plain pinocchio damped-least-squares IK.

Targets: forward kinematics of uniformly random configurations within the joint limits (so
every target is reachable within the limits); every solver starts from the middle of the
joint ranges. Success: position error <= 1e-6 m and rotation error <= 1e-6 rad; for the
reference also "within limits" (pinocchio's example IK ignores them).

    .venv/bin/python benchmarks/track_convergence.py [--n 100] [--seed 0] [--robots ur5,panda]

The reference is pinocchio's documented IK example (log6 error in the frame, Jlog6 chain rule,
v = -J^T (J J^T + damp I)^-1 err, q <- integrate(q, v dt)) with dt = 1 (Gauss-Newton steps,
faster than the example's dt = 0.1) and damp = 1e-6, at most 1000 iterations; a second run
clips q to the joint limits after every step (the simplest way to make it respect them).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from platkit.chains import KinematicChain, Servo, ServoOptions, Task

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the reference robots' finder
from reference_robots import example_robot_urdf  # noqa: E402

ROBOTS = {
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0"),
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand"),
}
TOL = 1e-6


def reference_dls(chain: KinematicChain, fid: int, target: np.ndarray, theta0: np.ndarray,
                  dt: float = 1.0, damp: float = 1e-6, it_max: int = 1000, clip: bool = False):
    model, data = chain.model, chain.model.createData()
    oMdes = pin.SE3(target)
    q = chain.pin_configuration(theta0)
    for i in range(it_max + 1):
        pin.framesForwardKinematics(model, data, q)
        iMd = data.oMf[fid].actInv(oMdes)
        pos = float(np.linalg.norm(oMdes.translation - data.oMf[fid].translation))
        rot = float(np.linalg.norm(pin.log3(iMd.rotation)))
        if pos <= TOL and rot <= TOL:
            break
        if i == it_max:
            break
        err = pin.log(iMd).vector
        J = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
        J = -pin.Jlog6(iMd.inverse()) @ J
        v = -J.T @ np.linalg.solve(J @ J.T + damp * np.eye(6), err)
        q = pin.integrate(model, q, v * dt)
        if clip:
            q = np.clip(q, model.lowerPositionLimit, model.upperPositionLimit)
    within = bool(np.all(q >= model.lowerPositionLimit - 1e-9) and np.all(q <= model.upperPositionLimit + 1e-9))
    return pos <= TOL and rot <= TOL, within, i, pos, rot


def summarize(name: str, ok, its, pos, rot, secs, extra: str = "") -> None:
    ok = np.asarray(ok, bool)
    its = np.asarray(its)
    pos = np.asarray(pos)
    rot = np.asarray(rot)
    good = ok if ok.any() else np.ones_like(ok)
    print(f"  {name:<34} success {ok.mean() * 100:5.1f}%  iterations median {np.median(its[good]):5.0f} "
          f"p95 {np.percentile(its[good], 95):5.0f} max {its.max():5d}  "
          f"final error (converged) median {np.median(pos[good]):.1e} m / {np.median(rot[good]):.1e} rad, "
          f"worst {pos[good].max():.1e} m / {rot[good].max():.1e} rad  "
          f"{np.mean(secs) * 1e3:6.1f} ms/target{extra}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100, help="random targets per robot")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--robots", default="ur5,panda")
    ap.add_argument("--lp", type=int, default=30, help="targets also solved with the LP solver (slower)")
    ap.add_argument("--trees", type=int, default=20, help="target sets for the tree-shaped chains (0: skip)")
    args = ap.parse_args()
    for robot in args.robots.split(","):
        urdf, link = ROBOTS[robot]
        chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
        fid = chain.frame_id(link)
        rng = np.random.default_rng(args.seed)
        targets = [chain.placement(chain.random(rng), link) for _ in range(args.n)]
        theta0 = chain.mid_range()
        print(f"{robot} ({link}, {chain.n} joints), {args.n} random reachable targets, start at mid-range:")
        variants = [
            ("platkit servo, pinv", ServoOptions(), args.n),
            ("platkit servo, pinv, 10 restarts", ServoOptions(restarts=10), args.n),
            ("platkit servo, LP", ServoOptions(solver="lp"), min(args.lp, args.n)),
        ]
        for name, options, n in variants:
            ok, its, pos, rot, secs, restarts = [], [], [], [], [], []
            for k, T in enumerate(targets[:n]):
                options.seed = k
                t0 = time.perf_counter()
                r = Servo(chain, [Task(link, T)], options).run(theta0)
                secs.append(time.perf_counter() - t0)
                ok.append(r.converged)
                its.append(r.iterations_total)
                pos.append(r.position_error)
                rot.append(r.rotation_error)
                restarts.append(r.restarts)
            summarize(name + (f" [{n}]" if n != args.n else ""), ok, its, pos, rot, secs,
                      f"  restarts used max {max(restarts)}" if options.restarts else "")
        for name, clip in (("pinocchio DLS (reference)", False), ("pinocchio DLS, clipped to limits", True)):
            ok, within, its, pos, rot, secs = [], [], [], [], [], []
            for T in targets:
                t0 = time.perf_counter()
                o, w, i, p, r = reference_dls(chain, fid, T, theta0, clip=clip)
                secs.append(time.perf_counter() - t0)
                ok.append(o)
                within.append(o and w)
                its.append(i)
                pos.append(p)
                rot.append(r)
            summarize(name, ok, its, pos, rot, secs,
                      f"  converged within the joint limits {np.mean(within) * 100:.1f}%")
    if args.trees:
        trees(args.trees, args.seed)


def trees(n: int, seed: int) -> None:
    """Tree-shaped chains: both Talos grippers (6-D each, torso shared, legs and head locked) and
    the four Allegro fingertips (positions), targets from FK of random configurations."""
    cases = [
        ("talos both grippers", "talos_data/robots/talos_reduced.urdf",
         ["gripper_left_base_link", "gripper_right_base_link"], np.ones(6), ("arm", "torso")),
        ("allegro 4 fingertips", "allegro_hand_description/urdf/allegro_right_hand.urdf",
         ["link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip"], np.array([1, 1, 1, 0, 0, 0.0]), ("joint",)),
    ]
    for name, urdf, links, weights, movable in cases:
        chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
        locked = [j for j in chain.joint_names if not j.startswith(movable)]
        free = np.array([j not in locked for j in chain.joint_names])
        rng = np.random.default_rng(seed)
        ok, its, pos, rot, secs = [], [], [], [], []
        for k in range(n):
            theta = np.where(free, chain.random(rng, margin=0.05), chain.mid_range())
            tasks = [Task(link, chain.placement(theta, link), weights=weights) for link in links]
            t0 = time.perf_counter()
            r = Servo(chain, tasks, ServoOptions(locked=locked, restarts=10, seed=k)).run(chain.mid_range())
            secs.append(time.perf_counter() - t0)
            ok.append(r.converged)
            its.append(r.iterations_total)
            pos.append(r.position_error)
            rot.append(r.rotation_error)
        print(f"{name} ({int(free.sum())} joints move), {n} random reachable target sets, start at mid-range:")
        summarize("platkit servo, pinv, 10 restarts", ok, its, pos, rot, secs)


if __name__ == "__main__":
    main()
