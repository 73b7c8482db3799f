"""Time per target of platkit's tracking servo beside pinocchio's damped least squares.

    .venv/bin/python benchmarks/track_speed.py [--n 50] [--seed 0] [--repeat 1] [--robots ur5,panda] [--profile]

What `platkit track` does for one target (a Servo with the default ServoOptions: tolerance
1e-6 m and 1e-6 rad, joint limits kept, rate limits over dt = 0.1 s), on random reachable
targets (forward kinematics of uniformly random configurations within the limits) from the
middle of the joint ranges, beside pinocchio's documented damped-least-squares IK at the same
tolerance (benchmarks/track_convergence.py: dt = 1, damping 1e-6, at most 1000 iterations),
which ignores the joint limits, and the same with q clipped to the limits after each step; and
platkit without the rate limits (``platkit track --no-rate-limits``: longer steps, fewer of them). The
solvers run in turns, target by target, so that a busy machine slows them alike (the order
rotating from one target to the next); the table
gives the mean time per target, the success rate (and for the references how many of their
solutions are within the limits), the median iterations and the ratio of mean times to the
plain reference. Goal (issue 13): platkit at or below the reference per target.

``--repeat k``: each solver solves each target k times in a row and the fastest counts (on a
shared machine a single pause of a few milliseconds otherwise moves a 0.3 ms mean).

``--profile``: where platkit's time goes (cProfile, the ten largest own times).

The one-target servo runs compiled (platkit.chains.native_servo: the whole loop in C, built
once per machine into the cache directory); the benchmark compiles it into a fresh temporary
cache before timing and prints how long that took, so the rows are warm. The row "Python loop"
is the same servo with the compiled loop switched off (``Servo.compile = False``: what runs
without a C compiler or with PLATKIT_COMPILE=0, and what ran before).

History (2026-11-25, the 2-core machine): the Python loop took 1.95-2.31x the reference on UR5
and 6.47-8.15x on Panda, 40-76 us an iteration in numpy calls against the reference's 17-25.
Compiled (2026-11-25, 23:04 UTC, load 3.8-4.4): UR5 0.25-0.31x, Panda 0.50-0.67x over four
runs of one solve per target, 0.15x and 0.46x with --repeat 3; docs/chains.md section 6 has the
table.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reference_robots import example_robot_urdf  # noqa: E402  (tests/, put on the path by track_convergence)
from track_convergence import ROBOTS, reference_dls  # noqa: E402

from platkit.chains import KinematicChain, Servo, ServoOptions, Task  # noqa: E402
from platkit.chains.native_servo import compiled_servo_reason  # noqa: E402


def platkit_solve(chain, link, target, theta0, compiled=True, **options):
    servo = Servo(chain, [Task(link, target)], ServoOptions(**options))
    servo.compile = compiled
    r = servo.run(theta0)
    within = bool(np.all(r.theta >= chain.lower - 1e-9) and np.all(r.theta <= chain.upper + 1e-9))
    return r.converged, within, r.iterations_total


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="random targets per robot")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=1,
                    help="solve each target this many times per solver and keep the fastest (default 1)")
    ap.add_argument("--robots", default="ur5,panda")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args(argv)
    # compile the servo's loop now, into an empty cache, so that the timed rows are warm
    cache = tempfile.mkdtemp(prefix="platkit-track-speed-")
    os.environ["PLATKIT_CACHE_DIR"] = cache
    try:
        _run(args)
    finally:
        shutil.rmtree(cache, ignore_errors=True)  # the loaded library stays mapped


def _run(args) -> None:
    t0 = time.perf_counter()
    why = compiled_servo_reason()
    took = time.perf_counter() - t0
    print(f"compiled servo loop: {'NOT AVAILABLE (' + why + '); the rows run the Python loop' if why else 'built'} "
          f"in {took:.2f} s (C compiler and load, once per machine; the timed rows are warm)\n")
    for robot in args.robots.split(","):
        urdf, link = ROBOTS[robot]
        chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
        fid = chain.frame_id(link)
        rng = np.random.default_rng(args.seed)
        targets = [chain.placement(chain.random(rng), link) for _ in range(args.n)]
        theta0 = chain.mid_range()
        solvers = {
            "platkit servo (platkit track)": lambda T: platkit_solve(chain, link, T, theta0),
            "platkit servo, --no-rate-limits": lambda T: platkit_solve(chain, link, T, theta0, use_rate_limits=False),
            "platkit servo, Python loop": lambda T: platkit_solve(chain, link, T, theta0, compiled=False),
            "pinocchio DLS (reference)": lambda T: reference_dls(chain, fid, T, theta0)[:3],
            "pinocchio DLS, clipped to limits": lambda T: reference_dls(chain, fid, T, theta0, clip=True)[:3],
        }
        for solve in solvers.values():  # warm up
            solve(targets[0])
        stats = {name: {"s": [], "ok": [], "within": [], "it": []} for name in solvers}
        names = list(solvers)
        for i, T in enumerate(targets):
            # the order rotates from target to target: whichever solver runs right after the
            # clipped reference's thousand iterations finds the caches cold, so none always does
            for name in names[i % len(names):] + names[:i % len(names)]:
                solve = solvers[name]
                best = np.inf
                for _ in range(args.repeat):  # the fastest of the repeats: a busy machine's pauses left out
                    t0 = time.perf_counter()
                    ok, within, it = solve(T)
                    best = min(best, time.perf_counter() - t0)
                stats[name]["s"].append(best)
                stats[name]["ok"].append(ok)
                stats[name]["within"].append(ok and within)
                stats[name]["it"].append(it)
        ref = np.mean(stats["pinocchio DLS (reference)"]["s"])
        print(f"{robot} ({link}, {chain.n} joints), {args.n} random reachable targets from mid-range, tolerance 1e-6 m / 1e-6 rad:")
        width = max(len(n) for n in solvers)
        print(f"  {'solver':<{width}}  {'ms/target':>9}  {'x ref':>6}  {'median ms':>9}  {'success':>7}  {'within limits':>13}  "
              f"{'iterations (median)':>19}  {'us/iteration':>12}")
        for name, st in stats.items():
            mean = np.mean(st["s"])
            per_it = np.sum(st["s"]) / max(np.sum(st["it"]), 1) * 1e6
            print(f"  {name:<{width}}  {mean * 1e3:>9.2f}  {mean / ref:>6.2f}  {np.median(st['s']) * 1e3:>9.2f}  "
                  f"{np.mean(st['ok']) * 100:>6.0f}%  {np.mean(st['within']) * 100:>12.0f}%  {np.median(st['it']):>19.0f}  "
                  f"{per_it:>12.0f}")
        mine = np.mean(stats["platkit servo (platkit track)"]["s"])
        print(f"  goal, platkit at or below the reference per target: {'met' if mine <= ref else 'NOT MET'} "
              f"({mine / ref:.2f}x)")
        if args.profile:
            prof = cProfile.Profile()
            prof.enable()
            for T in targets[:20]:
                platkit_solve(chain, link, T, theta0)
            prof.disable()
            buf = io.StringIO()
            pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(10)
            print("  profile of platkit on 20 targets (own time):")
            for line in buf.getvalue().splitlines():
                if line.strip() and ("/" in line or "{" in line):
                    print("   ", line.strip()[:150])
        print()


if __name__ == "__main__":
    main()
