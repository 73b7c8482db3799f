"""platkit plan: which commands to send in a calibration session (grid or D-optimal)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.commands.common import add_platform_options, platform_from_args
from platkit.errors import BadInput


def add_parser(sub):
    p = sub.add_parser("plan", help="experiment design: a snake-ordered grid or a D-optimal set of commands")
    add_platform_options(p)
    p.add_argument("--out", required=True, help="plan.csv to write (plan.json with the predicted uncertainty beside it)")
    p.add_argument("--grid", type=int, default=None, metavar="N", help="N points per control, visited in snake order")
    p.add_argument("--optimal", type=int, default=None, metavar="N", help="select N poses D-optimally")
    p.add_argument("--candidates", type=int, default=500, metavar="M",
                   help="random feasible candidates for --optimal (default 500; with --grid the grid is the candidate set)")
    p.add_argument("--noise-mm", type=float, default=0.1, help="marker noise per coordinate of a settled pose, mm (default 0.1)")
    p.add_argument("--markers", type=int, default=5, help="markers on the moving part (default 5)")
    p.add_argument("--margin", type=float, default=0.1, help="fraction of each stroke kept clear at both ends (default 0.1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of plan.csv (default mm)")
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
    with atomic_output_dir(out.parent if str(out.parent) else Path(".")) as tmp:
        pl.write_plan_csv(tmp / out.name, spec, plan.controls, args.unit)
        (tmp / (out.stem + ".json")).write_text(jsonout.dumps(report, indent=2, default=float) + "\n", encoding="utf-8")
    _print(plan.info, report.get("baseline"), out, len(plan.controls))
    return 0


def _print(info: dict, baseline: dict | None, out: Path, n: int) -> None:
    def line(name, d):
        if not d.get("identifiable"):
            return (f"{name}: {d['n_poses']} poses do not identify the {d['identifiable_rank']} identifiable "
                    f"directions (rank {d['plan_rank']})")
        return (f"{name}: {d['n_poses']} poses; {d['identifiable_rank']} of {d['n_parameters']} parameter directions "
                f"identifiable ({d['never_identifiable']} never are from markers alone); predicted marker RMS "
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
