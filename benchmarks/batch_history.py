"""A stand's history, calibrated in one parameterisation (the batch's) against each session's own
gauge: false changes on a static stand, and a knock found, over unseen seeds.

    .venv/bin/python benchmarks/batch_history.py [--stands stewart,psvr,rotary] [--seeds 3]
                                                 [--seed-base 5100] [--months 8] [--poses 20]

For each stand and seed: a true stand off its drawing (2 mm, 2 mrad per parameter, drawn from the
seed), unchanged over ``--months`` monthly sessions, each simulated with its own seed (noise 0.05 mm,
a random plan, a motion-capture frame and markers of its own), calibrated with the drawing

- *own gauge*: each session with the stand's default free parameters, the held set chosen from
  its own data (what ``platkit calibrate --no-selection`` does one session at a time, and what a
  batch did before issue 27);
- *batch gauge*: each session with the batch's parameterisation (platkit.batch.gauge: the same free
  list less the gauge, chosen once on the stand's reference poses);

then the history test (platkit.batch.history.stand_history) and the fleet's "moved" over the months.
Printed per stand: changes flagged on the static stand (every one is false), parameters whose
held set differed between months, and the dispersion k. Then, on the stewart with the leg offsets
free (a stand whose joints are as drawn), a 0.5 mm knock of leg 3 in month 5: the times it is
flagged alone, there, and its estimated size.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from platkit.batch.gauge import common_parameterisation
from platkit.batch.history import stand_history
from platkit.calibrate.estimate import calibrate
from platkit.plugins import get_platform
from platkit.simulate import perturb_parameters, simulate

TABLE_KEYS = ("value", "std", "nominal", "unit", "status")


def table(cal) -> dict[str, dict]:
    return {n: {k: p[k] for k in TABLE_KEYS} for n, p in cal.to_dict()["parameters"].items()}


def months(spec, truths, free, seed, poses) -> list:
    out = []
    for m, truth in enumerate(truths):
        sim = simulate(spec.with_td(truth), seed=seed * 100 + m, n_poses=poses, raw=False, perturbation=0.0,
                       plan="random", noise_mm=0.05, n_markers=4)
        out.append(calibrate(sim.poses, spec, free=free))
    return out


def history(cals, spec) -> dict:
    names = [f"month{m + 1:02d}" for m in range(len(cals))]
    return stand_history(names, [table(c) for c in cals], [None] * len(cals))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stands", default="stewart,psvr,rotary")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seed-base", type=int, default=5100)
    ap.add_argument("--months", type=int, default=8)
    ap.add_argument("--poses", type=int, default=20)
    args = ap.parse_args()
    t0 = time.perf_counter()
    seeds = range(args.seed_base, args.seed_base + args.seeds)
    print(f"static stands, {args.months} months of {args.poses} poses, seeds {seeds.start}..{seeds.stop - 1}")
    print(f"{'stand':8s} {'seed':>5s}  {'own gauge: changes':>18s} {'held sets':>9s} {'k':>5s}   "
          f"{'batch gauge: changes':>20s} {'held sets':>9s} {'k':>5s}")
    totals: dict[str, list[int]] = {}
    for stand in args.stands.split(","):
        spec = get_platform(stand)
        param = common_parameterisation(spec)
        for seed in seeds:
            truth = perturb_parameters(spec, np.random.default_rng(seed))
            row = []
            for free in (None, param.free):
                cals = months(spec, [truth] * args.months, free, seed, args.poses)
                h = history(cals, spec)
                held = {tuple(s != "estimated" for s in c.td_status) for c in cals}
                row.append((len(h["changes"]), len(held), h["dispersion_k"]))
            totals.setdefault(stand, [0, 0, 0])
            totals[stand][0] += row[0][0]
            totals[stand][1] += row[1][0]
            totals[stand][2] += 1
            print(f"{stand:8s} {seed:5d}  {row[0][0]:18d} {row[0][1]:9d} {row[0][2]:5.2f}   {row[1][0]:20d} "
                  f"{row[1][1]:9d} {row[1][2]:5.2f}", flush=True)
    print("false changes in all:", ", ".join(f"{s} {own} own gauge, {batch} batch gauge ({n} histories)"
                                             for s, (own, batch, n) in totals.items()))
    spec = get_platform("stewart")
    legs = [p.name for p in spec.parameters if p.group == "leg_offsets"]
    param = common_parameterisation(spec, ["leg_offsets"])
    hits, sizes = 0, []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        drawing = spec.nominal_td() + np.array([rng.normal(0, 1e-3) if n in legs else 0.0 for n in spec.parameter_names])
        knock = np.array([5e-4 if n == legs[2] else 0.0 for n in spec.parameter_names])
        truths = [drawing + (knock if m >= 4 else 0.0) for m in range(args.months)]
        h = history(months(spec, truths, param.free, seed, args.poses + 4), spec)
        flags = [(f["parameter"], f["session"]) for f in h["changes"]]
        alone = flags == [(legs[2], "month05")]
        hits += alone
        if alone:
            sizes.append(h["changes"][0]["change"])
        print(f"knock, seed {seed}: flagged {flags}" + (f", size {h['changes'][0]['change']:+.3f} mm" if alone else ""),
              flush=True)
    print(f"knock of 0.5 mm on {legs[2]} in month05: flagged alone, there, in {hits} of {len(seeds)}; sizes "
          + ", ".join(f"{x:.3f}" for x in sizes) + f" mm; {time.perf_counter() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
