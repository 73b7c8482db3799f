"""Per-actuator delays and rate limits fitted from motion, beside the old response model, on the same sessions.

For each seed (unseen while developing: 2700001 on), on the stewart stand, the physical simulator
streams its random multisine (--duration-s at --mocap-hz, commands at 20 Hz, the nuisances it draws:
latency, clock offset, coloured noise, occlusion bursts) with two explicit drive options: each
leg its own pure delay, drawn uniformly in --delays (s, from the seed), and on --limited legs
(drawn from the seed) a rate limit of --limit-share times the fastest the log asks of that leg
(its largest step over the command interval): a limit that binds on the log's fastest moves.
Each session is calibrated twice (platkit.calibrate.motion): the old response model (one common
shift, second-order response of a step reference) and the new one (delays=True,
rate_limit=True), both second order (named: the kind's choice from the data is not measured
here). Printed per seed and model: the error of --test random reachable commands
against the true stand (geometry, markers, frame from the simulator; RMS over markers, mm; or why
the fit was refused) and the ratio old / new; for the new model each leg's fitted lag (shift +
delay: what the markers fix; the truth is the clock shift plus the leg's delay) and its error,
the delay beyond the fastest leg against the truth's, the fitted rate limit against the truth on
the limited legs, and what was held. --holds N: a session of N random holds instead (a profile
reference: both models fit each leg's rate and acceleration; the limited legs' limit is
--limit-share times their drawn profile rate, so the truth's rate is the smaller of the two).

    .venv/bin/python benchmarks/calibrate_response.py [--seeds 2700001,2700002] [--duration-s 60]
        [--mocap-hz 100] [--delays 0.02,0.12] [--limited 2] [--limit-share 0.8] [--holds N]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from calibrate_motion import truth_error  # benchmarks/, the script's own folder on the path

from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_start import command_speed
from platkit.calibrate.plan import feasible
from platkit.errors import PlatkitError
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session

#: a leg without a rate limit is simulated with this one (m/s): never reached
FREE_RATE = 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="2700001")
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--mocap-hz", type=float, default=100.0)
    ap.add_argument("--delays", default="0.02,0.12", help="the legs' delays drawn uniformly in this range, s")
    ap.add_argument("--limited", type=int, default=2, help="legs with a rate limit that binds")
    ap.add_argument("--limit-share", type=float, default=0.8, help="their limit over the fastest the log asks")
    ap.add_argument("--test", type=int, default=200)
    ap.add_argument("--holds", type=int, default=0, help="instead of the multisine, this many random holds (a profile "
                    "reference); the limited legs' limit --limit-share times their drawn profile rate")
    args = ap.parse_args()
    d_lo, d_hi = (float(x) for x in args.delays.split(","))
    spec = get_platform("stewart")
    names = list(spec.control_names)
    lo, hi = spec.control_bounds()
    summary = []
    for seed in (int(s) for s in args.seeds.split(",")):
        rng = np.random.default_rng([seed, 77])
        delay = rng.uniform(d_lo, d_hi, spec.n_u)
        limited = np.sort(rng.choice(spec.n_u, args.limited, replace=False))
        plan = ({"n_poses": args.holds, "plan": "random"} if args.holds else
                {"motion": "multisine", "duration_s": args.duration_s})
        free = simulate_physics(spec, seed=seed, mocap_rate_hz=args.mocap_hz, **plan)
        rate = np.full(spec.n_u, FREE_RATE)
        asked = free.response.rate if args.holds else command_speed(free.command_t, free.commands)
        rate[limited] = args.limit_share * asked[limited]
        sim = simulate_physics(spec, seed=seed, mocap_rate_hz=args.mocap_hz, actuator_delay_s=delay,
                               actuator_rate_limit=rate, **plan)
        U = spec.neutral_u() + (rng.uniform(size=(4 * args.test, spec.n_u)) - 0.5) * 0.6 * (hi - lo)
        ok, _ = feasible(spec, U, sim.td)
        U = U[ok][:args.test]
        true_lag = sim.nuisances.time_shift_s + delay
        print(f"seed {seed}: {len(sim.commands)} commands, {len(sim.marker_t)} samples; delays "
              + " ".join(f"{n} {1e3 * d:.1f}" for n, d in zip(names, delay)) + " ms; clock shift "
              f"{1e3 * sim.nuisances.time_shift_s:.1f} ms; rate limits "
              + ", ".join(f"{names[j]} {1e3 * rate[j]:.1f} mm/s" for j in limited), flush=True)
        errors = {}
        with tempfile.TemporaryDirectory() as tmp:
            write_physical_session(sim, Path(tmp) / "s")
            s = load_session(Path(tmp) / "s")
            for label, opts in (("old", {"kind": "second_order"}),
                                ("new", {"kind": "second_order", "delays": True, "rate_limit": True})):
                t0 = time.perf_counter()
                try:
                    cal, _ = calibrate_motion(s, s.spec, **opts)
                except PlatkitError as ex:
                    errors[label] = float("nan")
                    print(f"  {label}: refused ({time.perf_counter() - t0:.0f} s): {str(ex)[:160]}", flush=True)
                    continue
                errors[label] = truth_error(cal, sim, U)
                print(f"  {label}: truth {1e3 * errors[label]:.4f} mm, rms after {1e3 * cal.rms_after:.3f} mm, "
                      f"{time.perf_counter() - t0:.0f} s; held {cal.motion['held'] or 'none'}", flush=True)
                if label != "new":
                    continue
                r = cal.motion["response"]
                lag = np.array([r["actuators"][n]["lag_s"]["value"] for n in names])
                fit_rate = np.array([r["actuators"][n]["rate"]["value"] for n in names])
                rel, rel_true = lag - lag.min(), true_lag - true_lag.min()
                print("    leg  lag_ms(true)  err_ms  beyond_fastest_ms(true)  delay_std_ms  tau_ms(true)  tau_std_ms  "
                      "rate_mm/s(true)")
                for j, n in enumerate(names):
                    a = r["actuators"][n]
                    tau = a["tau_s"]["value"]
                    sd = [("held" if a[b]["std"] is None else f"{1e3 * a[b]['std']:.1f}") for b in ("delay_s", "tau_s")]
                    true_rate = min(rate[j], sim.response.rate[j]) if args.holds else rate[j]
                    rtxt = (f"{1e3 * fit_rate[j]:.1f} ({1e3 * true_rate:.1f}) {fit_rate[j] / true_rate:.3f}"
                            if j in limited or args.holds else f"{1e3 * fit_rate[j]:.0f} (none)")
                    print(f"    {n}  {1e3 * lag[j]:.1f} ({1e3 * true_lag[j]:.1f})  {1e3 * (lag[j] - true_lag[j]):+.1f}  "
                          f"{1e3 * rel[j]:.1f} ({1e3 * rel_true[j]:.1f})  {sd[0]}  {1e3 * tau:.1f} "
                          f"({1e3 * sim.response.tau_s[j]:.1f})  {sd[1]}  {rtxt}")
                true_rates = np.minimum(rate, sim.response.rate) if args.holds else rate
                worst_rate = np.abs(fit_rate[limited] / true_rates[limited] - 1).max() if len(limited) else float("nan")
                summary.append([seed, np.abs(lag - true_lag).max(), worst_rate])
        ratio = errors["old"] / errors["new"] if np.isfinite(errors.get("old", np.nan)) else float("nan")
        print(f"  old / new truth error: {ratio:.2f}" + (" (old refused)" if not np.isfinite(ratio) else ""), flush=True)
        if summary and summary[-1][0] == seed:
            summary[-1] += [errors["old"], errors["new"]]
    for seed, dl, dr, e_old, e_new in summary:
        print(f"seed {seed}: truth old {1e3 * e_old:.4f} mm, new {1e3 * e_new:.4f} mm (old / new {e_old / e_new:.2f}); "
              f"worst lag error {1e3 * dl:.1f} ms, worst limited rate error "
              + (f"{100 * dr:.2f}%" if np.isfinite(dr) else "(no leg limited)"))


if __name__ == "__main__":
    main()
