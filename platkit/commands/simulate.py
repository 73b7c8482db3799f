"""platkit simulate: write a simulated session folder (with its truth) for any stand."""
from __future__ import annotations

import sys
from pathlib import Path

from platkit.commands.common import add_platform_options, parse_vector, platform_from_args
from platkit.errors import BadInput, NotIdentifiable
from platkit.notices import said

#: the additive simulator's defaults for the nuisances --physics draws per session
ADDITIVE_DEFAULTS = {"noise_mm": 0.2, "occlusion": 0.02, "hold_s": 1.5}
#: options only the physical simulator reads
PHYSICS_ONLY = ("latency_s", "clock_offset_s", "white_noise", "overshoot", "motion", "duration_s", "command_rate_hz",
                "warmup")

#: IMU rate when --imu is given without --imu-rate-hz
DEFAULT_IMU_RATE_HZ = 200.0
DEFAULT_IMU_NOISE = (0.002, 0.02)


def effect_help() -> str:
    """The --effect help: what SIZE means for every installed effect, in both simulators (from
    the effects' ``size_help``: the plugins are loaded, so only when help is shown)."""
    from platkit.simulate.effects import size_help

    sizes = "; ".join(f"{n}: {what}" for n, what in sorted(size_help().items()))
    physics_sizes = "; ".join(f"{n}: {what}" for n, what in sorted(size_help(physics=True).items()))
    return (f"hidden effect, repeatable (NAME:SIZE or NAME=SIZE). Sizes: {sizes}. With --physics: "
            f"{physics_sizes}. A base_tilt turns the whole stand in the level world: the motion capture cannot see "
            "it, an --imu's accelerometer can (its truth also goes to truth_imu.yaml)")


def add_parser(sub):
    p = sub.add_parser(
        "simulate", help="simulate a calibration session with a known true stand (truth.yaml)",
        description="Two simulators. Default (additive; with --poses-only the fastest): the stand moves smoothly to "
                    "each command, and hidden effects are added as the model terms diagnosis fits. --physics: a "
                    "time-domain stand (each "
                    "actuator follows its command through rate and acceleration limits and its own damped "
                    "second-order response; effects act where their physics acts; hold, noise colour, occlusion, "
                    "latency and clock offset drawn per session from the seed) with the true settled pose of every "
                    "command in truth_settled.csv. See docs/simulation.md.")
    add_platform_options(p)
    p.add_argument("--out", required=True, help="session folder to write (refused if it already holds files, "
                                                "unless --force)")
    p.add_argument("--force", action="store_true",
                   help="write into an --out folder that already holds files (the session's files are replaced; "
                        "other files there are left, and counted on stderr)")
    effect = p.add_argument("--effect", action="append", default=[], metavar="NAME[:SIZE]",
                            help="hidden effect, repeatable (NAME:SIZE or NAME=SIZE); the sizes are listed by "
                                 "platkit simulate --help")
    plain_help = p.format_help

    def format_help() -> str:  # building the parser must not import the simulator
        effect.help = effect_help()
        return plain_help()

    p.format_help = format_help
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--perturbation", type=float, default=1.0, metavar="SCALE",
                   help="how far the true stand lies from the description: SCALE times 2 mm, 2 mrad (0.1%% of other "
                        "values) per parameter, drawn from the seed (default 1); 0: the description is the true stand")
    p.add_argument("--poses", type=int, default=80, help="number of commands (default 80)")
    p.add_argument("--plan", default=None,
                   help="grid (snake-ordered grid), random, or a plan.csv file (default grid; random poses, said, "
                        "where the stand has no grid of --poses reachable poses, as with a tree's many joints)")
    p.add_argument("--physics", action="store_true",
                   help="simulate the stand's physics in time (platkit.simulate.physics) instead of adding model "
                        "terms; writes truth_settled.csv, the true settled pose of every command")
    p.add_argument("--noise-mm", type=float, default=None,
                   help=f"white marker noise per coordinate and sample, mm (default {ADDITIVE_DEFAULTS['noise_mm']:g}; "
                        "with --physics drawn per session)")
    p.add_argument("--occlusion", type=float, default=None,
                   help=f"fraction of marker samples occluded (default {ADDITIVE_DEFAULTS['occlusion']:g}; with "
                        "--physics drawn per session, in bursts)")
    p.add_argument("--markers", type=int, default=None,
                   help="markers on the moving part (default 5; on a tree 3 on each tracked link, as plan places them)")
    p.add_argument("--base-markers", type=int, default=0, help="markers fixed on the base (default 0)")
    p.add_argument("--rigid-bodies", type=int, default=0,
                   help="rigid bodies measured in 6 DOF on the moving part, T1, T2, ... (on a tree, body b on "
                        "tracked link b mod L, as the markers; default 0; 0.1 mm and 0.05 deg noise per sample; with "
                        "--physics the markers' noise on the origin, the same over 0.1 m on the orientation)")
    p.add_argument("--imu", action="store_true",
                   help="also simulate an IMU on the moving part: imu.csv, session.yaml's imu entry, and the truth "
                        "files platkit orient scores against (truth_orientation.csv, truth_imu.yaml); any --imu-* "
                        "option implies it")
    p.add_argument("--imu-rate-hz", type=float, default=None,
                   help=f"IMU sampling rate (default {DEFAULT_IMU_RATE_HZ:g})")
    p.add_argument("--imu-bias", default=None, metavar="GX,GY,GZ,AX,AY,AZ",
                   help="IMU biases: gyro rad/s, then accelerometer m/s^2 (one number for all six; default 0)")
    p.add_argument("--imu-noise", default=None, metavar="GYR,ACC",
                   help=f"IMU white noise per sample: gyro rad/s, accelerometer m/s^2 "
                        f"(default {DEFAULT_IMU_NOISE[0]:g},{DEFAULT_IMU_NOISE[1]:g})")
    p.add_argument("--rate-hz", type=float, default=100.0, help="motion-capture rate (default 100)")
    p.add_argument("--hold-s", type=float, default=None,
                   help=f"time each command is held after arriving (default {ADDITIVE_DEFAULTS['hold_s']:g}; with "
                        "--physics drawn per session, 2 to 3 s)")
    p.add_argument("--latency-s", type=float, default=None,
                   help="--physics: the motion capture's latency, s (default drawn, 0 to 0.02)")
    p.add_argument("--clock-offset-s", type=float, default=None,
                   help="--physics: markers.csv's clock minus commands.csv's, s (default drawn, -0.15 to 0.15)")
    p.add_argument("--white-noise", action="store_true",
                   help="--physics: white marker noise only (default: white plus a correlated part)")
    p.add_argument("--overshoot", action="store_true",
                   help="--physics: drives tuned below critical damping, so they overshoot their commands")
    p.add_argument("--motion", default=None, metavar="multisine|path|cue|FILE",
                   help="--physics: commands streamed at a steady rate without holds (a multi-sine per actuator, a "
                        "smooth random path, or motion-cue-like smoothed steps; or a commands.csv streamed as it is, "
                        "e.g. platkit plan --motion's), instead of --poses held commands")
    p.add_argument("--duration-s", type=float, default=None,
                   help="--physics --motion: the session's length, s (default 200)")
    p.add_argument("--command-rate-hz", type=float, default=None,
                   help="--physics --motion: commands per second (default 20)")
    p.add_argument("--warmup", default=None, choices=["visible", "warm"],
                   help="--physics: the stand warms up with time since power-on (its size and time constant drawn "
                        "from the seed): visible (switched on just before the first command) or warm (long before); "
                        "session.yaml says power_on_t")
    p.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of the session files (default mm)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--raw", dest="poses_only", action="store_false", help="write the raw markers.csv stream (default)")
    mode.add_argument("--poses-only", dest="poses_only", action="store_true", help="write settled poses.csv instead")
    p.set_defaults(poses_only=False)
    return p


def run(args) -> int:
    from platkit.simulate.effects import parse_effect

    if args.physics and args.poses_only:
        raise BadInput("--physics simulates the raw stream: leave out --poses-only")
    if not args.physics:
        used = [f"--{k.replace('_', '-')}" for k in PHYSICS_ONLY if getattr(args, k) not in (None, False)]
        if used:
            raise BadInput(f"{', '.join(used)}: only with --physics")

    if args.poses < 3:
        raise BadInput(f"--poses must be at least 3, got {args.poses}")
    check_out_folder(Path(args.out), args.force)
    if args.base_markers < 0:
        raise BadInput(f"--base-markers must be 0 or more, got {args.base_markers}")
    if args.rigid_bodies < 0:
        raise BadInput(f"--rigid-bodies must be 0 or more, got {args.rigid_bodies}")
    if args.markers is not None and args.markers < 3:
        raise BadInput(f"--markers must be at least 3, got {args.markers}")
    if args.seed < 0:
        raise BadInput(f"--seed must be 0 or more, got {args.seed}")
    if not args.perturbation >= 0:
        raise BadInput(f"--perturbation must be 0 or more, got {args.perturbation:g}")
    if args.noise_mm is not None and not args.noise_mm >= 0:
        raise BadInput(f"--noise-mm must be 0 or more, got {args.noise_mm:g}")
    if args.occlusion is not None and not 0 <= args.occlusion < 0.5:
        raise BadInput(f"--occlusion must be a fraction in [0, 0.5), got {args.occlusion:g}")
    if not args.rate_hz > 0:
        raise BadInput(f"--rate-hz must be positive, got {args.rate_hz:g}")
    if args.hold_s is not None and not args.hold_s > 0:
        raise BadInput(f"--hold-s must be positive, got {args.hold_s:g}")
    for name in ("latency_s", "clock_offset_s"):
        v = getattr(args, name)
        if v is not None and not abs(v) < 60:
            raise BadInput(f"--{name.replace('_', '-')} must be a finite number of seconds, got {v:g}")
    if args.latency_s is not None and args.latency_s < 0:
        raise BadInput(f"--latency-s must be 0 or more, got {args.latency_s:g}")
    spec = platform_from_args(args)
    if args.markers is None:
        from platkit.calibrate.plan import default_marker_count

        args.markers = default_marker_count(spec)
    plan = args.plan
    if plan not in (None, "grid", "random"):
        if not Path(plan).exists():
            raise BadInput(f"--plan: {plan}: file not found (give grid, random or a plan CSV file)")
        if not Path(plan).is_file():
            raise BadInput(f"--plan: {plan} is a folder, expected grid, random or a plan CSV file")
    effects = [parse_effect(e) for e in args.effect]
    if args.physics:
        return run_physics(args, spec, plan, effects)
    from platkit.inertial.simulate import split_imu_effects
    from platkit.simulate import simulate, write_session

    for key, value in ADDITIVE_DEFAULTS.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    # IMU effects act on the IMU's samples through their own sensor model, not as model terms
    imu_effects, effects = split_imu_effects(effects, args.seed)
    if imu_effects and not args.imu:
        raise BadInput(f"--effect {imu_effects[0][0].name}: an IMU effect needs --imu")
    imu = imu_hook(args, imu_effects)
    sim = planned(plan, lambda plan: simulate(
        spec, seed=args.seed, n_poses=args.poses, plan=plan, noise_mm=args.noise_mm, occlusion=args.occlusion,
        n_markers=args.markers, raw=not args.poses_only, effects=effects, mocap_rate_hz=args.rate_hz,
        hold_s=args.hold_s, length_unit=args.unit,
        description=None if args.description is None else Path(args.description).name,
        n_base_markers=args.base_markers, imu=imu, perturbation=args.perturbation, n_bodies=args.rigid_bodies))
    out = write_session(sim, args.out, poses_only=args.poses_only, description=args.description,
                        moving_link=getattr(args, "moving_link", None), base_link=getattr(args, "base_link", None),
                        notes=notes_with_warnings(f"simulated by platkit (seed {sim.truth.seed}); the true stand is in "
                                                  "truth.yaml"))
    kind = "settled poses" if args.poses_only else f"{len(sim.marker_t)} motion-capture samples"
    if sim.imu is not None:
        kind += f", {len(sim.imu['t'])} IMU samples"
    print(f"wrote {out}: {spec.name}, {len(sim.commands)} commands, {kind}, "
          f"{sim.poses.n_poses} settled poses; truth in {Path(out) / 'truth.yaml'}")
    say_dropped(sim.plan_info, len(sim.commands))
    for term, theta in sim.truth.terms:
        values = ", ".join(f"{n}={v:.4g}" for n, v in zip(term.parameter_names, theta))
        print(f"  hidden effect {term.effect} at {term.where}: {values}")
    for e, theta in imu_effects:
        print(f"  hidden IMU effect {e.name}: " + ", ".join(f"{n}={v:.4g}" for n, v in zip(e.parameter_names, theta)))
    return 0


def planned(plan, simulate_with):
    """``simulate_with(plan)`` with the --plan given; without one, the grid, or, where the stand
    has no grid of enough reachable poses (a tree's many joints: even two values per joint are
    too many points), random poses, said on stderr."""
    if plan is not None:
        return simulate_with(plan)
    try:
        return simulate_with("grid")
    except NotIdentifiable as exc:
        if "grid" not in str(exc):
            raise
        print(f"simulate: {exc}: random poses instead (--plan random)", file=sys.stderr, flush=True)
        return simulate_with("random")


def notes_with_warnings(notes: str) -> str:
    """session.yaml's ``notes``: ``notes``, then every warning said while the session was simulated
    (platkit.notices: a --plan control past a limit within the recording tolerance, ...), each as
    "warning: <text>", so that the session's own file keeps what stderr said. (The writers append
    the dropped-commands sentence themselves.)"""
    return "; ".join([notes] + [f"warning: {w}" for w in said()])


def say_dropped(plan_info: dict, n_kept: int) -> None:
    """Planned commands the true stand does not reach are never dropped silently: one line on
    stderr (the same sentence is in session.yaml's notes and the count in truth.yaml's plan)."""
    from platkit.simulate.files import dropped_note

    note = dropped_note(plan_info, n_kept)
    if note is not None:
        print(f"simulate: {note}", file=sys.stderr)


def check_out_folder(out: Path, force: bool) -> None:
    """A session is never simulated over another silently: an --out that is a file, or a folder
    that already holds files, is refused unless --force (then said on stderr)."""
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out}: is a file, not a session folder")
    held = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if not held:
        return
    if not force:
        shown = ", ".join(held[:4]) + (f" and {len(held) - 4} more" if len(held) > 4 else "")
        raise BadInput(f"--out {out}: already holds {len(held)} file(s) ({shown}); choose a new folder, "
                       "or give --force to write the session over it")
    print(f"simulate: --force: writing over {out}, which held {len(held)} file(s); the session's files are "
          "replaced, any others are left as they were", file=sys.stderr)


def run_physics(args, spec, plan, effects) -> int:
    """``platkit simulate --physics``: the time-domain stand, written with its truth."""
    from platkit.simulate.physics import simulate_physics, write_physical_session

    motion = motion_options(args, spec)
    sim = planned(plan, lambda plan: simulate_physics(
        spec, seed=args.seed, n_poses=args.poses, plan=plan, effects=effects, n_markers=args.markers,
        n_base_markers=args.base_markers, mocap_rate_hz=args.rate_hz, length_unit=args.unit, hold_s=args.hold_s,
        noise_mm=args.noise_mm, occlusion=args.occlusion, latency_s=args.latency_s,
        clock_offset_s=args.clock_offset_s, coloured=not args.white_noise, overshoot=args.overshoot,
        imu=imu_options(args), perturbation=args.perturbation, warmup=args.warmup,
        description=None if args.description is None else Path(args.description).name, n_bodies=args.rigid_bodies,
        **motion))
    out = write_physical_session(sim, args.out, description=args.description,
                                 moving_link=getattr(args, "moving_link", None),
                                 base_link=getattr(args, "base_link", None),
                                 notes=notes_with_warnings(f"simulated in the time domain by platkit (seed {sim.seed}); "
                                                           "the truth is in truth.yaml and truth_settled.csv"))
    kind = f"{len(sim.marker_t)} motion-capture samples"
    if sim.imu is not None:
        kind += f", {len(sim.imu['t'])} IMU samples"
    n = sim.nuisances
    print(f"wrote {out}: {spec.name} simulated in time, {len(sim.commands)} commands over "
          f"{sim.hold_end_t[-1]:.0f} s, {kind}; truth in {Path(out) / 'truth.yaml'} and "
          f"{Path(out) / 'truth_settled.csv'}")
    print(f"  nuisances: hold {n.hold_s:.2f} s, noise {n.noise_m * 1e3:.3f} mm white + {n.coloured_m * 1e3:.3f} mm "
          f"correlated ({n.correlation_s:.2f} s), occlusion {100 * n.occlusion:.1f}%, latency {n.latency_s * 1e3:.0f} ms, "
          f"clock offset {n.clock_offset_s * 1e3:+.0f} ms")
    say_dropped(sim.plan_info, len(sim.commands))
    for name, physics in sim.physics:
        print(f"  hidden effect {name}: " + ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                                   for k, v in physics.parameters().items()))
    return 0


def motion_options(args, spec=None) -> dict:
    """simulate_physics's continuous-motion keywords from --motion (a kind, or a commands file:
    its commands and rate), --duration-s, --command-rate-hz."""
    from platkit.simulate.continuous import KINDS, read_streamed_commands

    if args.motion is None:
        if args.duration_s is not None or args.command_rate_hz is not None:
            raise BadInput("--duration-s and --command-rate-hz apply to --motion")
        return {}
    if args.motion not in KINDS:
        if not Path(args.motion).is_file():
            raise BadInput(f"--motion {args.motion}: neither {', '.join(KINDS)} nor a commands file")
        if args.duration_s is not None or args.command_rate_hz is not None:
            raise BadInput("--duration-s and --command-rate-hz: a --motion file sets both")
        U, rate_hz = read_streamed_commands(Path(args.motion), spec, args.unit)
        return {"motion": U, "command_rate_hz": rate_hz}
    out: dict = {"motion": args.motion}
    if args.duration_s is not None:
        out["duration_s"] = args.duration_s
    if args.command_rate_hz is not None:
        out["command_rate_hz"] = args.command_rate_hz
    return out


def imu_options(args) -> dict | None:
    """The IMU options of platkit.inertial.simulate.imu_for_trajectory from the --imu options, or None."""
    hook = imu_hook(args)
    if hook is None:
        return None
    rate = DEFAULT_IMU_RATE_HZ if args.imu_rate_hz is None else args.imu_rate_hz
    bias = None if args.imu_bias is None else parse_vector(args.imu_bias, "--imu-bias")
    noise = DEFAULT_IMU_NOISE if args.imu_noise is None else tuple(parse_vector(args.imu_noise, "--imu-noise", size=2))
    return {"rate_hz": rate, "bias": bias, "noise": tuple(noise)}


def imu_hook(args, imu_effects=()):
    """The ``imu=`` hook of platkit.simulate from the --imu options (and the IMU effects of
    --effect, as (effect, theta)), or None without them."""
    wanted = args.imu or any(v is not None for v in (args.imu_rate_hz, args.imu_bias, args.imu_noise))
    if not wanted:
        return None
    if args.poses_only:
        raise BadInput("--imu needs the simulated motion: leave out --poses-only")
    rate = DEFAULT_IMU_RATE_HZ if args.imu_rate_hz is None else args.imu_rate_hz
    if not (rate > 0 and rate < float("inf")):
        raise BadInput(f"--imu-rate-hz must be a positive number, got {rate:g}")
    bias = None
    if args.imu_bias is not None:
        bias = parse_vector(args.imu_bias, "--imu-bias")
        if bias.size not in (1, 6):
            raise BadInput(f"--imu-bias: expected 1 or 6 numbers (gyro x, y, z rad/s, accelerometer x, y, z m/s^2), "
                           f"got {bias.size}")
    noise = DEFAULT_IMU_NOISE
    if args.imu_noise is not None:
        noise = parse_vector(args.imu_noise, "--imu-noise", size=2)
        if (noise < 0).any():
            raise BadInput(f"--imu-noise: standard deviations must be 0 or more, got {args.imu_noise!r}")
    from platkit.inertial.simulate import imu_for_trajectory

    return imu_for_trajectory(rate_hz=rate, bias=bias, noise=tuple(noise), effects=list(imu_effects))
