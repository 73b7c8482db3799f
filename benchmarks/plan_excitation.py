"""Designed excitation against a random multisine: predicted and reached accuracy of calibration from motion.

On the stewart stand: `plan --motion`'s design (platkit.calibrate.excitation: its criterion, log det
of the information plus the response's part told apart from the geometry, over the Fourier family
within the given rate, acceleration and stroke limits, from --design-seed) and the
random multisine it starts from (the same family, duration and limits) are each streamed to the
physical simulator (platkit.simulate.physics: the true stand drawn from the seed, its drives'
responses, latency, clock offset, occlusion bursts; white marker noise of --noise-mm, or the
drawn white + correlated noise with --drawn-noise) on seeds not used while developing, then
calibrated from motion (platkit.calibrate.motion, as `platkit calibrate` does on a session without
holds). The error is that of the calibration's predicted markers against the true stand's at the
stand's reference poses (the poses the prediction is told on), 3-D RMS in mm. Prints per seed the
predicted and reached error of each trajectory, reached / predicted (at most 1: the prediction
holds), and random / designed (over 1: the design is better).

    .venv/bin/python benchmarks/plan_excitation.py [--seeds 2700001,2700002] [--duration-s 60] [--family via]

With ``--family via``: `plan --motion --family via`'s sweep (platkit.calibrate.via_points: D-optimal
via points joined by time-optimal moves) against a sweep through random candidates, the same
duration and limits.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from calibrate_motion import truth_error  # benchmarks/, the script's own folder on the path

from platkit.calibrate.excitation import MotionInformation, design_excitation, predict_trajectory
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.plan import default_marker_layout, reference_poses_for
from platkit.calibrate.trajectories import FourierFamily, drive_limits, limit_violations, trajectory
from platkit.calibrate.via_points import design_via, via_trajectory
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="2700001")
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--period-s", type=float, default=40.0)
    ap.add_argument("--harmonics", type=int, default=8)
    ap.add_argument("--evaluations", type=int, default=200)
    ap.add_argument("--design-seed", type=int, default=0)
    ap.add_argument("--max-rate", type=float, default=250.0, help="mm/s")
    ap.add_argument("--max-accel", type=float, default=500.0, help="mm/s^2")
    ap.add_argument("--noise-mm", type=float, default=0.2)
    ap.add_argument("--drawn-noise", action="store_true", help="the simulator's drawn white + correlated noise")
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--family", default="fourier", choices=["fourier", "via"])
    args = ap.parse_args()
    spec = get_platform("stewart")
    command_rate_hz = 20.0
    limits = drive_limits(spec, args.max_rate * 1e-3, args.max_accel * 1e-3, 0.1)
    markers = default_marker_layout(spec, 5, np.random.default_rng(0))
    t0 = time.perf_counter()
    info = MotionInformation(spec, markers)
    commands = {}
    if args.family == "via":
        for name, choice in (("designed", True), ("random", False)):
            sweep = design_via(spec, limits, markers, args.duration_s, command_rate_hz,
                               np.random.default_rng(args.design_seed), d_optimal_choice=choice)
            commands[name] = via_trajectory(sweep.path, limits, command_rate_hz)[0]
        print(f"design: via points in {time.perf_counter() - t0:.0f} s")
    else:
        family = FourierFamily(args.period_s, args.harmonics, spec.n_u)
        design = design_excitation(spec, family, limits, info, command_rate_hz, np.random.default_rng(args.design_seed),
                                   evaluations=args.evaluations)
        print(f"design: {args.evaluations} evaluations in {time.perf_counter() - t0:.0f} s; criterion "
              f"{design.criterion_start:.2f} (random multisine) -> {design.criterion:.2f} (designed)")
        for name, coef in (("designed", design.coef), ("random", design.start)):
            commands[name] = trajectory(spec, family, coef, limits, args.duration_s, command_rate_hz)[0]
    sigma = args.noise_mm * 1e-3
    plans = {}
    for name, U in commands.items():
        v = limit_violations(U, command_rate_hz, limits)
        p, n_fit = predict_trajectory(info, U, command_rate_hz, len(U) / command_rate_hz, args.rate_hz, 1.0, sigma)
        pred, p90 = p["marker_rms_m"], p["marker_rms_p90_m"]
        plans[name] = (U, pred, p90)
        print(f"{name}: {len(U)} commands, rate {v['rate_share']:.3f} and acceleration {v['accel_share']:.3f} of the "
              f"limits, {v['box'] + v['rate'] + v['accel']} samples past them; predicted {pred * 1e3:.4f} mm, 90% of "
              f"sessions under {p90 * 1e3:.4f} mm "
              f"({n_fit} samples of {args.noise_mm:g} mm white noise)")
    U_ref, _ = reference_poses_for(spec)
    print("errors in mm; /pred, /p90: reached over the predicted expectation and 90th percentile; shift: the fitted clock "
          "shift minus the truth, ms")
    print(f"{'seed':>8} {'designed':>9} {'/pred':>6} {'/p90':>6} {'shift':>6} {'random':>9} {'/pred':>6} {'/p90':>6} "
          f"{'shift':>6} {'random/designed':>16}")
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        out, shift = {}, {}
        for name, (U, _pred, _p90) in plans.items():
            noise = {} if args.drawn_noise else {"noise_mm": args.noise_mm, "coloured": False}
            sim = simulate_physics(spec, seed=seed, motion=U, command_rate_hz=command_rate_hz,
                                   mocap_rate_hz=args.rate_hz, **noise)
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp) / name
                write_physical_session(sim, folder)
                s = load_session(folder)
                cal, _ = calibrate_motion(s, s.spec)
            out[name] = truth_error(cal, sim, U_ref)
            shift[name] = cal.motion["response"]["shift_s"]["value"] - sim.nuisances.time_shift_s
        d, r = out["designed"], out["random"]
        _, pd, qd = plans["designed"]
        _, pr, qr = plans["random"]
        print(f"{seed:>8} {d * 1e3:>9.4f} {d / pd:>6.2f} {d / qd:>6.2f} {shift['designed'] * 1e3:>6.1f} {r * 1e3:>9.4f} "
              f"{r / pr:>6.2f} {r / qr:>6.2f} {shift['random'] * 1e3:>6.1f} {r / d:>16.2f}", flush=True)
        rows.append((d / qd, r / qr, r / d))
    a = np.array(rows)
    print(f"over {len(a)} seeds: designed within its 90th percentile {int(np.sum(a[:, 0] <= 1))}/{len(a)}, random "
          f"{int(np.sum(a[:, 1] <= 1))}/{len(a)}; random/designed median {np.median(a[:, 2]):.2f} "
          f"(min {a[:, 2].min():.2f}), better on {int(np.sum(a[:, 2] > 1))}/{len(a)}")


if __name__ == "__main__":
    main()
