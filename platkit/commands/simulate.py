"""platkit simulate: write a simulated session folder (with its truth) for any stand."""
from __future__ import annotations

from pathlib import Path

from platkit.commands.common import add_platform_options, platform_from_args
from platkit.errors import BadInput


def add_parser(sub):
    from platkit.simulate.effects import size_help

    sizes = "; ".join(f"{n}: {what}" for n, what in sorted(size_help().items()))
    p = sub.add_parser("simulate", help="simulate a calibration session with a known true stand (truth.yaml)")
    add_platform_options(p)
    p.add_argument("--out", required=True, help="session folder to write")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:SIZE]",
                   help=f"hidden effect, repeatable. Sizes: {sizes}")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--poses", type=int, default=80, help="number of commands (default 80)")
    p.add_argument("--plan", default="grid", help="grid (snake-ordered grid), random, or a plan.csv file (default grid)")
    p.add_argument("--noise-mm", type=float, default=0.2, help="marker noise per coordinate, mm (default 0.2)")
    p.add_argument("--occlusion", type=float, default=0.02, help="fraction of marker samples occluded (default 0.02)")
    p.add_argument("--markers", type=int, default=5, help="markers on the moving part (default 5)")
    p.add_argument("--base-markers", type=int, default=0, help="markers fixed on the base (default 0)")
    p.add_argument("--imu-rate-hz", type=float, default=None,
                   help="also simulate an IMU on the moving part at this rate (imu.csv; platkit.inertial)")
    p.add_argument("--rate-hz", type=float, default=100.0, help="motion-capture rate (default 100)")
    p.add_argument("--hold-s", type=float, default=1.5, help="time each command is held after arriving (default 1.5)")
    p.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of the session files (default mm)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--raw", dest="poses_only", action="store_false", help="write the raw markers.csv stream (default)")
    mode.add_argument("--poses-only", dest="poses_only", action="store_true", help="write settled poses.csv instead")
    p.set_defaults(poses_only=False)
    return p


def run(args) -> int:
    from platkit.simulate import simulate, write_session
    from platkit.simulate.effects import parse_effect

    if args.poses < 3:
        raise BadInput(f"--poses must be at least 3, got {args.poses}")
    if args.base_markers < 0:
        raise BadInput(f"--base-markers must be 0 or more, got {args.base_markers}")
    if args.markers < 3:
        raise BadInput(f"--markers must be at least 3, got {args.markers}")
    if not args.rate_hz > 0 or not args.hold_s > 0:
        raise BadInput("--rate-hz and --hold-s must be positive")
    spec = platform_from_args(args)
    plan = args.plan
    if plan not in ("grid", "random"):
        if not Path(plan).is_file():
            raise BadInput(f"--plan: {plan!r} is neither grid, random nor a plan file")
    effects = [parse_effect(e) for e in args.effect]
    imu = None
    if args.imu_rate_hz is not None:
        if not args.imu_rate_hz > 0 or args.poses_only:
            raise BadInput("--imu-rate-hz must be positive and needs the raw stream (not --poses-only)")
        from platkit.inertial.simulate import imu_for_trajectory

        imu = imu_for_trajectory(rate_hz=args.imu_rate_hz)
    sim = simulate(spec, seed=args.seed, n_poses=args.poses, plan=plan, noise_mm=args.noise_mm,
                   occlusion=args.occlusion, n_markers=args.markers, raw=not args.poses_only, effects=effects,
                   mocap_rate_hz=args.rate_hz, hold_s=args.hold_s, length_unit=args.unit,
                   description=None if args.description is None else Path(args.description).name,
                   n_base_markers=args.base_markers, imu=imu)
    out = write_session(sim, args.out, poses_only=args.poses_only, description=args.description,
                        moving_link=getattr(args, "moving_link", None), base_link=getattr(args, "base_link", None))
    kind = "settled poses" if args.poses_only else f"{len(sim.marker_t)} motion-capture samples"
    print(f"wrote {out}: {spec.name}, {len(sim.commands)} commands, {kind}, "
          f"{sim.poses.n_poses} settled poses; truth in {Path(out) / 'truth.yaml'}")
    for term, theta in sim.truth.terms:
        print(f"  hidden effect {term.effect} at {term.where}: " + ", ".join(f"{n}={v:.4g}" for n, v in zip(term.parameter_names, theta)))
    return 0
