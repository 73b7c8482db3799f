"""platkit plan: which commands to send in a calibration session (grid or D-optimal)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from platkit.commands.common import add_platform_options, parse_vector, platform_from_args
from platkit.errors import BadInput
from platkit.notices import said


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
    p.add_argument("--noise-mm", type=float, default=0.1,
                   help="marker noise per coordinate of a settled pose (with --motion: of each sample), mm (default 0.1)")
    p.add_argument("--markers", type=int, default=None,
                   help="markers on the moving part (default 5; on a tree, --moving-link A,B: 3 on each tracked link, "
                        "marker k on link k mod L)")
    p.add_argument("--margin", type=float, default=0.1, help="fraction of each stroke kept clear at both ends (default 0.1)")
    p.add_argument("--move", default=None, metavar="NAME[,NAME...]",
                   help="the controls the session moves: names or shell-style patterns ('arm_*'), comma separated; "
                        "every other control is held at its home (its neutral, or the middle of its stroke less "
                        "--margin where the neutral lies on or outside it) in every command, and the prediction is "
                        "told at the reference poses with them held there (default: every control that moves a "
                        "tracked link; those that move none are held at neutral)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of plan.csv (default mm)")
    mo = p.add_argument_group("excitation for calibration from motion (--motion): --out is the session's commands.csv")
    mo.add_argument("--motion", action="store_true",
                    help="design a streamed excitation trajectory without holds (--family: via-point sweeps or a Fourier "
                         "series per control), D-optimal for the model calibrate fits, within the strokes (less "
                         "--margin), --max-rate and --max-accel on every command, every command reachable")
    mo.add_argument("--duration-s", type=float, default=None, help="the session's length, s")
    mo.add_argument("--target-mm", type=float, default=None,
                    help="the predicted marker error to reach in 90%% of sessions (3-D RMS over the stand's reference "
                         "poses, mm): the session is made as long as it needs (with --duration-s: that length, checked "
                         "against the target)")
    mo.add_argument("--max-rate", default=None, metavar="V[,V...]",
                    help="the drives' rate limit: one number or one per control, per s in the controls' own unit "
                         "(--unit for length controls); default: what the description declares (a URDF joint's "
                         "velocity)")
    mo.add_argument("--max-accel", default=None, metavar="A[,A...]",
                    help="the drives' acceleration limit, per s^2, as --max-rate")
    mo.add_argument("--family", default=None, metavar="{fourier,via}",
                    help="the trajectory family: 'via', sweeps through D-optimal via points at the drives' full "
                         "rate and acceleration, joined by synchronised trapezoidal moves, passing each at rest "
                         "without holding (the whole stroke covered); 'fourier', a Fourier series per control with "
                         "D-optimal coefficients (--period-s, --harmonics, --evaluations) (default via)")
    mo.add_argument("--period-s", type=float, default=40.0, help="the series' period, s (default 40)")
    mo.add_argument("--harmonics", type=int, default=8, help="harmonics of the base frequency 1/period (default 8)")
    mo.add_argument("--command-rate-hz", type=float, default=20.0, help="commands per second (default 20)")
    mo.add_argument("--rate-hz", type=float, default=100.0, help="the motion capture's rate, samples per s (default 100)")
    mo.add_argument("--evaluations", type=int, default=200,
                    help="trajectories the design evaluates (default 200, about 0.1 s each)")
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


def _markers(args, spec) -> tuple[np.ndarray, dict]:
    """The planned marker layout (--markers, default :func:`platkit.calibrate.plan.default_marker_count`)
    and the report's keys for it: 'markers', 'marker_layout_m' (each in its link's frame) and, on a
    tree, 'marker_links' (marker k on tracked link k mod L)."""
    from platkit.calibrate import plan as pl

    n = pl.default_marker_count(spec) if args.markers is None else args.markers
    links = pl.marker_links(spec, n)
    if len(set(links)) < len(set(pl.marker_links(spec, 64))):
        raise BadInput(f"--markers {n}: a tree of {len(set(pl.marker_links(spec, 64)))} tracked links needs a marker "
                       "on each (marker k rides on link k mod L)")
    markers = pl.default_marker_layout(spec, n, np.random.default_rng(0))
    out: dict = {"markers": n, "marker_layout_m": markers.tolist()}
    if len(set(links)) > 1:
        out["marker_links"] = links
    return markers, out


def moving_controls(spec, text: str | None) -> np.ndarray | None:
    """--move: (n_u,) bool, the controls named or matched (shell-style, case-sensitive) by its
    comma-separated items; None where not given. BadInput naming the option and the item that
    matches no control, or an empty list."""
    from fnmatch import fnmatchcase

    from platkit.calibrate.plan import idle_controls

    if text is None:
        return None
    items = [x.strip() for x in text.split(",")]
    if not any(items):
        raise BadInput("--move: no control named (give names or patterns, comma separated)")
    if "" in items:
        raise BadInput(f"--move {text!r}: an empty name between commas")
    names = list(spec.control_names)
    moving = np.zeros(spec.n_u, bool)
    for item in items:
        hit = np.array([fnmatchcase(n, item) for n in names], bool)
        if not hit.any():
            raise BadInput(f"--move: {item!r} is not a control of the {spec.name} stand (nor matches one); its "
                           f"controls: {', '.join(names)}")
        moving |= hit
    if spec.link_poses is not None and not np.any(moving & ~idle_controls(spec)):
        raise BadInput(f"--move {text!r}: moves no control that moves a tracked link ({', '.join(spec.tracked_links)}); "
                       "the markers would never move on the stand")
    return moving


def _held_report(spec, moving: np.ndarray | None, held) -> dict:
    """plan.json's 'move' (the controls moved) and 'held' (each held control's value, SI) for --move."""
    if moving is None:
        return {}
    names = np.array(spec.control_names)
    return {"move": list(names[moving]), "held": {str(n): float(v) for n, v in zip(names[held[0]], held[1][held[0]])}}


def _print_held(report: dict) -> None:
    """The printed line of --move: how many controls move, which are held (the first few)."""
    if "held" in report:
        held = list(report["held"])
        shown = ", ".join(held[:8]) + (f" and {len(held) - 8} more" if len(held) > 8 else "")
        print(f"moves {len(report['move'])} controls (--move); holds {len(held)} at home: {shown or 'none'}")


def _summary(info: dict) -> dict:
    return {k: v for k, v in info.items() if k != "parameter_std"}


def _check_shared(args) -> None:
    """The options both kinds of plan read: the stroke margin, the noise, the seed."""
    if not 0 <= args.margin < 0.5:
        raise BadInput(f"--margin must be in [0, 0.5), got {args.margin}")
    if not args.noise_mm > 0:
        raise BadInput("--noise-mm must be positive")
    if args.seed < 0:
        raise BadInput(f"--seed: must be 0 or more, got {args.seed}")


def run(args) -> int:
    from platkit.calibrate import plan as pl
    from platkit.io import jsonout
    from platkit.io.atomic import atomic_output_dir, check_output_file

    if args.motion:
        return run_motion(args)
    used = [f"--{k.replace('_', '-')}" for k in MOTION_ONLY if getattr(args, k) is not None]
    if used:
        raise BadInput(f"{', '.join(used)}: only with --motion")
    if args.grid is None and args.optimal is None:
        raise BadInput("give --grid N or --optimal N (or both: the grid is then the candidate set)")
    _check_shared(args)
    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        raise BadInput(f"--out {out}: expected a .csv file name")
    check_output_file(out)
    study = _monte_carlo_inputs(args) if args.monte_carlo is not None or args.compare or args.effect else None
    if study is not None and args.move is not None:
        raise BadInput("--move: not with --monte-carlo (its held-out poses move every control)")
    spec = platform_from_args(args)
    moving = moving_controls(spec, args.move)
    held = None if moving is None else pl.held_at_home(spec, moving, args.margin)
    sigma = args.noise_mm * 1e-3
    rng = np.random.default_rng(args.seed)
    markers, report = _markers(args, spec)
    report = {"platform": spec.name, "noise_mm": args.noise_mm, **report,
              "reference": f"predicted errors are RMS over {pl.REFERENCE_POSES} random reachable poses "
                           f"(seed {pl.REFERENCE_SEED}), the same for every plan of this stand",
              "unit": args.unit, **_held_report(spec, moving, held)}
    if args.optimal is not None:
        cands = pl.grid_plan(spec, args.grid, args.margin, held=held) if args.grid else None
        if args.optimal < 1:
            raise BadInput("--optimal must be at least 1")
        if cands is None and args.candidates < args.optimal:
            raise BadInput(f"--candidates {args.candidates}: must be at least --optimal ({args.optimal})")
        plan, baseline = pl.optimal_plan(spec, args.optimal, args.candidates, rng, sigma, markers=markers,
                                         candidates=cands, margin=args.margin, held=held)
        report["plan"] = plan.info
        report["baseline"] = {"kind": "first N random candidates" if cands is None else "N grid points evenly along the path", **baseline}
    else:
        plan = pl.grid_plan(spec, args.grid, args.margin, held=held)
        plan.info.update(kind="grid")
        plan.info.update(pl.evaluate_plan(spec, plan, sigma, markers=markers, margin=args.margin, held=held))
        report["plan"] = plan.info
    report["n_poses"] = int(len(plan.controls))
    if study is not None:
        report["monte_carlo"] = _monte_carlo(args, spec, plan, markers, out)
    report["warnings"] = said()  # every warning said while the verb ran (platkit.notices), on stderr too
    with atomic_output_dir(out.parent if str(out.parent) else Path(".")) as tmp:
        pl.write_plan_csv(tmp / out.name, spec, plan.controls, args.unit)
        (tmp / (out.stem + ".json")).write_text(jsonout.dumps(report, indent=2, default=float) + "\n", encoding="utf-8")
    _print(plan.info, report.get("baseline"), out, len(plan.controls))
    _print_held(report)
    if study is not None:
        _print_monte_carlo(report["monte_carlo"], report["plan"], out)
    return 0


#: options that apply to --motion alone (their defaults None)
MOTION_ONLY = ("duration_s", "target_mm", "max_rate", "max_accel", "family")


def run_motion(args) -> int:
    """``platkit plan --motion``: the excitation trajectory (platkit.calibrate.excitation) written as
    the session's commands.csv, its report (<out stem>.json) beside it."""
    from platkit.calibrate import excitation as ex
    from platkit.calibrate import sweeps as sw
    from platkit.calibrate import trajectories as tr
    from platkit.io import jsonout
    from platkit.io.atomic import atomic_output_dir, check_output_file
    from platkit.model import controls_to_si, length_scale

    for flag, on in (("--grid", args.grid is not None), ("--optimal", args.optimal is not None),
                     ("--monte-carlo", args.monte_carlo is not None), ("--compare", bool(args.compare)),
                     ("--effect", bool(args.effect))):
        if on:
            raise BadInput(f"{flag}: applies to hold plans, not --motion")
    _check_shared(args)
    if args.target_mm is not None and not args.target_mm > 0:
        raise BadInput(f"--target-mm must be positive, got {args.target_mm:g}")
    if args.family is not None and args.family not in sw.FAMILIES:
        raise BadInput(f"--family: one of {', '.join(sw.FAMILIES)}, got {args.family!r}")
    out = Path(args.out)
    if out.suffix.lower() != ".csv":
        raise BadInput(f"--out {out}: expected a .csv file name (the session's commands.csv)")
    check_output_file(out)
    spec = platform_from_args(args)
    moving = moving_controls(spec, args.move)

    def limit(text, option):
        if text is None:
            return None
        v = parse_vector(text, option)
        if v.size not in (1, spec.n_u):
            raise BadInput(f"{option}: expected 1 or {spec.n_u} numbers (one per control: "
                           f"{', '.join(spec.control_names)}), got {v.size}")
        if not np.all(v > 0):
            raise BadInput(f"{option}: every limit must be positive, got {text}")
        return controls_to_si(spec, np.broadcast_to(v, (spec.n_u,)), args.unit)

    try:
        limits = tr.drive_limits(spec, limit(args.max_rate, "--max-rate"), limit(args.max_accel, "--max-accel"),
                                 args.margin, moving)
    except BadInput as exc:  # a limit the stand does not declare is asked of its option, given or not
        head, colon, rest = str(exc).partition(":")
        if colon and head in ("max_rate", "max_accel"):
            raise BadInput("--" + head.replace("_", "-") + ":" + rest) from None
        raise
    markers, marker_report = _markers(args, spec)
    progress = None if args.quiet else _design_progress()
    target_m = None if args.target_mm is None else args.target_mm * 1e-3
    if (args.family or "via") == "via":
        result = sw.plan_sweep(spec, limits, command_rate_hz=args.command_rate_hz, mocap_rate_hz=args.rate_hz,
                               sigma_m=args.noise_mm * 1e-3, markers=markers, rng=np.random.default_rng(args.seed),
                               duration_s=args.duration_s, target_m=target_m, seen=1.0)
    else:
        result = ex.plan_excitation(spec, limits, period_s=args.period_s, harmonics=args.harmonics,
                                    command_rate_hz=args.command_rate_hz, mocap_rate_hz=args.rate_hz,
                                    sigma_m=args.noise_mm * 1e-3, markers=markers,
                                    rng=np.random.default_rng(args.seed), duration_s=args.duration_s,
                                    target_m=target_m, evaluations=args.evaluations, progress=progress)
    held = None if moving is None else (~moving, limits.lower)
    report = {"platform": spec.name, "unit": args.unit, "noise_mm": args.noise_mm, **marker_report,
              "seed": args.seed, **_held_report(spec, moving, held), **result.report,
              "warnings": said()}  # every warning said while the verb ran (platkit.notices), on stderr too
    with atomic_output_dir(out.parent if str(out.parent) else Path(".")) as tmp:
        ex.write_commands_csv(tmp / out.name, spec, result.t, result.controls, args.unit)
        (tmp / (out.stem + ".json")).write_text(jsonout.dumps(report, indent=2, default=float) + "\n", encoding="utf-8")
    r, p = result.report, result.report["prediction"]
    sc = length_scale("mm")
    print(f"wrote {out} ({r['n_commands']} commands at {r['command_rate_hz']:g} per s, {r['duration_s']:.1f} s, no holds) "
          f"and {out.with_suffix('.json')}")
    _print_held(report)
    fam = r["family"]
    if fam["name"] == "via":
        mine, theirs = ("D-optimal", "random") if fam["choice"] == "d_optimal" else ("random", "D-optimal")
        other = f"a sweep through {theirs} via points"
        if fam["choice"] != "d_optimal":  # the random sweep predicts better: written, the D-optimal one said beside it
            p = {**p, "marker_rms_m_random": p["marker_rms_m_d_optimal"],
                 "marker_rms_p90_m_random": p["marker_rms_p90_m_d_optimal"]}
        print(f"excitation: a sweep through {fam['via_points']} {mine} via points in {fam['box_share']:.0%} of the box "
              f"({fam['tours']:g} tour(s), "
              f"{fam['detours']} move(s) through neutral), {min(v for v in r['stroke_share'] if v is not None):.0%} of each stroke at least; rate "
              f"{r['checked']['rate_share']:.0%} and acceleration {r['checked']['accel_share']:.0%} of the limits at "
              f"most; criterion {r['design']['criterion_random']:.2f} (random via points), "
              f"{r['design']['criterion_d_optimal']:.2f} (D-optimal)")
    else:
        other = "a random multisine"
        print(f"excitation: period {fam['period_s']:g} s, {fam['harmonics']} harmonics; rate "
              f"{r['checked']['rate_share']:.0%} and acceleration {r['checked']['accel_share']:.0%} of the limits at "
              f"most; criterion {r['design']['criterion_random']:.2f} (random multisine) -> "
              f"{r['design']['criterion']:.2f} ({r['design']['evaluations']} evaluations)")
    print(f"predicted marker error (3-D RMS over the reference poses, {p['samples_fitted']} samples of {args.noise_mm:g} mm "
          f"noise): {p['marker_rms_m'] / sc:.4f} mm, 90% of sessions under {p['marker_rms_p90_m'] / sc:.4f} mm ({other} "
          f"of the same duration and limits: {p['marker_rms_m_random'] / sc:.4f} mm, "
          f"{p['marker_rms_p90_m_random'] / sc:.4f} mm)")
    for link, e in (p.get("links") or {}).items():
        print(f"  {link}: {e['markers']} markers; predicted marker error {e['marker_rms_m'] / sc:.4f} mm")
    if "target" in r:
        tg = r["target"]
        print(f"target {tg['target_m'] / sc:g} mm (90% of sessions): {'met' if tg['met'] else 'NOT met'} by a session of "
              f"{tg['duration_s']:.1f} s" + (f" ({tg['samples_needed']} samples needed)" if "samples_needed" in tg else ""))
    return 0


def _design_progress():
    """Progress of the design on stderr: one line about every 2 s, and the last."""
    import time

    last = [time.perf_counter()]

    def show(k: int, n: int, logdet: float) -> None:
        now = time.perf_counter()
        if k == n or now - last[0] >= 2.0:
            last[0] = now
            print(f"plan: excitation design {k}/{n}  criterion {logdet:.2f}", file=sys.stderr, flush=True)

    return show


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


def stand_options(args) -> dict:
    """The stand options given (--base-link, --moving-link) as get_platform takes them: a tree's
    comma-separated links as a mapping (as platform_from_args reads them)."""
    options = {k: getattr(args, k) for k in ("base_link", "moving_link") if getattr(args, k, None) is not None}
    if "," in options.get("moving_link", ""):
        options["moving_link"] = {n.strip(): n.strip() for n in options["moving_link"].split(",") if n.strip()}
    return options


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
    options = stand_options(args)
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
    for link, h in (mc["plans"][names[0]].get("heldout_rms_mm_links") or {}).items():
        pred = (info.get("links") or {}).get(link, {}).get("predicted_marker_rms_m")
        print(f"  {link}: held-out median {h['median']:.4f} mm, p90 {h['p90']:.4f} mm"
              + ("" if pred is None else f"; linear prediction {pred * 1e3 * 3 ** 0.5:.4f} mm"))
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

    def per_link(d):
        for link, e in (d.get("links") or {}).items():
            seen = (f"{e['plan_rank']} of the {e['identifiable_rank']} directions its markers see"
                    + ("" if e["identifiable"] else " (NOT all excited)"))
            rms = ("" if e["predicted_marker_rms_m"] is None else
                   f"; predicted marker RMS {e['predicted_marker_rms_m'] * 1e3:.4f} mm "
                   f"(max {e['predicted_marker_max_m'] * 1e3:.4f} mm)")
            print(f"  {link}: {e['markers']} markers, {e['stand_parameters']} stand parameters move it; {seen}{rms}")

    print(f"wrote {out} ({n} commands) and {out.with_suffix('.json')}")
    print(line(info.get("kind", "plan"), info))
    per_link(info)
    if baseline is not None:
        print(line("baseline", baseline))
        per_link(baseline)
    if info.get("identifiable"):
        worst = sorted(info["parameter_std"].items(), key=lambda kv: -kv[1]["std"] * (1e3 if kv[1]["unit"] in ("m", "rad") else 1))[:3]
        print("largest parameter std (minimum-norm gauge): " + ", ".join(
            f"{k} {v['std'] * 1e3:.4f} {'mm' if v['unit'] == 'm' else 'mrad' if v['unit'] == 'rad' else 'm' + v['unit']}"
            if v["unit"] in ("m", "rad") else f"{k} {v['std']:.4g} {v['unit']}" for k, v in worst))
