"""platkit plan: which commands to send in a calibration session (grid or D-optimal)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from platkit.commands.common import add_platform_options, platform_from_args
from platkit.errors import BadInput


def add_parser(sub):
    p = sub.add_parser("plan", help="experiment design: a snake-ordered grid or a D-optimal set of commands")
    add_platform_options(p)
    p.add_argument("--out", required=True, help="plan.csv to write (plan.json with the predicted uncertainty beside it)")
    p.add_argument("--grid", type=int, default=None, metavar="N",
                   help="N points per control, visited in snake order (a stand whose pose space is free, "
                        "'free_space: pose' like a cable robot: N values per pose coordinate, mapped to commands "
                        "through IK)")
    p.add_argument("--optimal", type=int, default=None, metavar="N", help="select N poses D-optimally")
    p.add_argument("--candidates", type=int, default=500, metavar="M",
                   help="random feasible candidates for --optimal (default 500; with --grid the grid is the candidate set)")
    p.add_argument("--noise-mm", type=float, default=0.1, help="marker noise per coordinate of a settled pose, mm (default 0.1)")
    p.add_argument("--markers", type=int, default=5, help="markers on the moving part (default 5)")
    p.add_argument("--margin", type=float, default=0.1, help="fraction of each stroke kept clear at both ends (default 0.1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of plan.csv (default mm)")
    mc = p.add_argument_group("Monte-Carlo evaluation (needs platkit[batch]: dask.distributed)")
    mc.add_argument("--monte-carlo", type=int, default=None, metavar="N",
                    help="also score the plan on N true stands drawn around the description: each simulated, "
                         "calibrated and scored on the stand's held-out reference poses (<out>.montecarlo.json)")
    mc.add_argument("--compare", action="append", default=[], metavar="PLAN.csv",
                    help="another plan (a plan.csv) scored on the same N true stands, side by side (repeatable)")
    mc.add_argument("--effect", action="append", default=[], metavar="NAME[:SIZE]",
                    help="a hidden effect in every true stand, as platkit simulate --effect (repeatable)")
    mc.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="an existing Dask scheduler (default: $PLATKIT_DASK_SCHEDULER, else a local cluster)")
    mc.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster (default: one per core)")
    mc.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return p


def _summary(info: dict) -> dict:
    return {k: v for k, v in info.items() if k != "parameter_std"}


def run(args) -> int:
    from platkit.calibrate import plan as pl
    from platkit.io import jsonout
    from platkit.io.atomic import atomic_output_dir, check_output_file

    if args.grid is None and args.optimal is None:
        raise BadInput("give --grid N or --optimal N (or both: the grid is then the candidate set)")
    if not 0 <= args.margin < 0.5:
        raise BadInput(f"--margin must be in [0, 0.5), got {args.margin}")
    if not args.noise_mm > 0:
        raise BadInput("--noise-mm must be positive")
    if args.seed < 0:
        raise BadInput(f"--seed: must be 0 or more, got {args.seed}")
    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        raise BadInput(f"--out {out}: expected a .csv file name")
    check_output_file(out)
    study = _monte_carlo_inputs(args) if args.monte_carlo is not None or args.compare or args.effect else None
    spec = platform_from_args(args)
    sigma = args.noise_mm * 1e-3
    rng = np.random.default_rng(args.seed)
    markers = pl.default_marker_layout(spec, args.markers, np.random.default_rng(0))
    report: dict = {"platform": spec.name, "noise_mm": args.noise_mm, "markers": args.markers,
                    "reference": f"predicted errors are RMS over {pl.REFERENCE_POSES} random reachable poses "
                                 f"(seed {pl.REFERENCE_SEED}), the same for every plan of this stand",
                    "marker_layout_m": markers.tolist(), "unit": args.unit}
    if args.optimal is not None:
        cands = pl.grid_plan(spec, args.grid, args.margin) if args.grid else None
        if args.optimal < 1:
            raise BadInput("--optimal must be at least 1")
        if cands is None and args.candidates < args.optimal:
            raise BadInput(f"--candidates {args.candidates}: must be at least --optimal ({args.optimal})")
        plan, baseline = pl.optimal_plan(spec, args.optimal, args.candidates, rng, sigma, markers=markers,
                                         candidates=cands, margin=args.margin)
        report["plan"] = plan.info
        report["baseline"] = {"kind": "first N random candidates" if cands is None else "N grid points evenly along the path", **baseline}
    else:
        plan = pl.grid_plan(spec, args.grid, args.margin)
        plan.info.update(kind="grid")
        plan.info.update(pl.evaluate_plan(spec, plan, sigma, markers=markers, margin=args.margin))
        report["plan"] = plan.info
    report["n_poses"] = int(len(plan.controls))
    if study is not None:
        report["monte_carlo"] = _monte_carlo(args, spec, plan, markers, out)
    with atomic_output_dir(out.parent if str(out.parent) else Path(".")) as tmp:
        pl.write_plan_csv(tmp / out.name, spec, plan.controls, args.unit)
        (tmp / (out.stem + ".json")).write_text(jsonout.dumps(report, indent=2, default=float) + "\n", encoding="utf-8")
    _print(plan.info, report.get("baseline"), out, len(plan.controls))
    if study is not None:
        _print_monte_carlo(report["monte_carlo"], report["plan"], out)
    return 0


def _monte_carlo_inputs(args) -> bool:
    """Check the Monte-Carlo options before any work (bad input, exit 2)."""
    from platkit.batch.engine import require_dask

    if args.monte_carlo is None:
        raise BadInput("--compare and --effect apply to a Monte-Carlo study: add --monte-carlo N")
    if args.monte_carlo < 2:
        raise BadInput(f"--monte-carlo {args.monte_carlo}: use 2 or more draws")
    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers {args.workers}: use 1 or more")
    for c in args.compare:
        if not Path(c).is_file():
            raise BadInput(f"--compare {c}: plan file not found")
    require_dask("platkit plan --monte-carlo")
    return True


def _monte_carlo(args, spec, plan, markers, out: Path) -> dict:
    """Score the plan (and the --compare plans) on the same --monte-carlo true stands; the draws
    are kept in <out stem>.montecarlo/ (a re-run skips them). Returns plan.json's monte_carlo."""
    from platkit.batch.engine import progress_line
    from platkit.batch.montecarlo import evaluate_plans
    from platkit.calibrate import plan as pl
    from platkit.simulate.effects import parse_effect

    plans = {out.stem: plan.controls}
    for c in args.compare:
        name = Path(c).stem
        if name in plans:
            raise BadInput(f"--compare {c}: two plans are named {name!r}; give the files different names")
        plans[name] = pl.read_plan_csv(Path(c), spec, args.unit)
    effects = tuple(parse_effect(e) for e in args.effect)
    options = {k: getattr(args, k) for k in ("base_link", "moving_link") if getattr(args, k, None) is not None}
    description = None if args.description is None else str(Path(args.description).resolve())
    folder = out.parent / f"{out.stem}.montecarlo"
    if not args.quiet:
        print(f"plan: {args.monte_carlo} Monte-Carlo draws of {len(plans)} plans ({folder})", file=sys.stderr)
    result = evaluate_plans(spec.name, description, options, plans, markers, args.monte_carlo, args.noise_mm, effects,
                            args.seed, folder, args.scheduler, args.workers,
                            None if args.quiet else progress_line("plan"))
    return {"n_draws": args.monte_carlo, "folder": str(folder), "effects": [list(e) for e in effects],
            "definition": "held-out error: RMS of the 3-D distance between the calibrated model's and the true "
                          "marker positions over the stand's reference poses (noise-free), per draw; parameter error: "
                          "estimate - truth where estimated; every plan sees the same true stands",
            "plans": result}


def _print_monte_carlo(mc: dict, info: dict, out: Path) -> None:
    print(f"Monte Carlo, {mc['n_draws']} true stands (the same for every plan): held-out marker RMS (3-D), mm")
    names = list(mc["plans"])
    width = max(len(n) for n in names) + 2
    print(f"{'plan':<{width}}{'poses':>6}{'median':>9}{'p90':>9}{'p95':>9}{'max':>9}  " +
          "".join(f"beats {o[:10]:<11}" for o in names[1:]))
    for name, r in mc["plans"].items():
        h = r["heldout_rms_mm"]
        beats = "".join(f"{'' if o == name else format(r['beats'][o], '.0%'):<17}" for o in names[1:])
        print(f"{name:<{width}}{r['n_poses']:>6}{h['median']:>9.4f}{h['p90']:>9.4f}{h['p95']:>9.4f}{h['max']:>9.4f}  {beats}")
    if info.get("predicted_marker_rms_m"):
        print(f"linear prediction for {names[0]}: {info['predicted_marker_rms_m'] * 1e3 * 3 ** 0.5:.4f} mm (3-D, "
              f"sqrt(3) x the per-coordinate {info['predicted_marker_rms_m'] * 1e3:.4f} mm)")
    worst = sorted(((k, v) for k, v in mc["plans"][names[0]]["parameter_error"].items() if v["p95_abs"] is not None),
                   key=lambda kv: -kv[1]["p95_abs"])[:4]
    if worst:
        print(f"largest parameter errors of {names[0]} (95th percentile of |estimate - truth|): "
              + ", ".join(f"{k} {v['p95_abs']:.3g} {v['unit']}" for k, v in worst))
    print(f"wrote {out.with_suffix('.json')} (monte_carlo) and the draws in {mc['folder']}")


def _print(info: dict, baseline: dict | None, out: Path, n: int) -> None:
    def line(name, d):
        if not d.get("identifiable"):
            return (f"{name}: {d['n_poses']} poses do not identify the {d['identifiable_rank']} identifiable "
                    f"directions (rank {d['plan_rank']}; calibrate would find {d.get('not_excited', '?')} not excited: "
                    "a stand parameter is then held at nominal, a marker or the mocap frame is an error)")
        return (f"{name}: {d['n_poses']} poses; {d['identifiable_rank']} of {d['n_parameters']} parameter directions "
                f"identifiable ({d['never_identifiable']} never are from markers alone: gauges, which calibrate fixes "
                f"by its stated conventions); predicted marker RMS "
                f"{d['predicted_marker_rms_m'] * 1e3:.4f} mm (max {d['predicted_marker_max_m'] * 1e3:.4f} mm); "
                f"log det {d['logdet']:.2f}")

    print(f"wrote {out} ({n} commands) and {out.with_suffix('.json')}")
    print(line(info.get("kind", "plan"), info))
    if baseline is not None:
        print(line("baseline", baseline))
    if info.get("identifiable"):
        worst = sorted(info["parameter_std"].items(), key=lambda kv: -kv[1]["std"] * (1e3 if kv[1]["unit"] in ("m", "rad") else 1))[:3]
        print("largest parameter std (minimum-norm gauge): " + ", ".join(
            f"{k} {v['std'] * 1e3:.4f} {'mm' if v['unit'] == 'm' else 'mrad' if v['unit'] == 'rad' else 'm' + v['unit']}"
            if v["unit"] in ("m", "rad") else f"{k} {v['std']:.4g} {v['unit']}" for k, v in worst))
