"""platkit workspace: corner envelope, true translational envelope, conditioning, plots."""
from __future__ import annotations

from platkit.commands.common import add_platform_options, add_unit_option, print_json, platform_from_args
from platkit.io.atomic import check_output_dir
from platkit.kinematics import PlatformModel
from platkit.workspace import AXES
from platkit.workspace.files import write_workspace


def add_parser(sub):
    p = sub.add_parser("workspace", help="reachable set: control-box corners, true envelope, plots")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--out", required=True, help="output folder (workspace.json, corners.csv, envelope.csv, plots)")
    p.add_argument("--no-plots", action="store_true", help="skip the figures (write the tables and workspace.json only)")
    p.add_argument("--json", action="store_true", help="print workspace.json as one JSON object")
    return p


def run(args) -> int:
    check_output_dir(args.out)
    spec = platform_from_args(args)
    model = PlatformModel(spec, length_unit=args.unit)
    figures = write_workspace(model, args.out, unit=args.unit, plots=not args.no_plots)
    if args.json:
        print_json(figures)
        return 0
    unit = args.unit
    corners = figures["corners"]
    print(f"{spec.name}: origin relative to the neutral pose, {unit}")
    print(f"{'envelope':<34}" + "".join(f"{a + ' min':>11}{a + ' max':>11}" for a in AXES))
    box = "pose-box" if spec.pose_free else "control-box"
    rows = [(f"{corners['count']} {box} corners ({corners['converged']} solved)", corners["relative_to_neutral"])]
    for name, env in figures["true_envelope"].items():
        rows.append((f"true, {name.replace('_', ' ')}", env))
    for label, env in rows:
        print(f"{label:<34}" + "".join(f"{env[a]['min']:>11.1f}{env[a]['max']:>11.1f}" for a in AXES))
    cond = figures["conditioning"]
    print(f"conditioning: neutral condition number {cond['neutral']['condition_number']:.3g}, "
          f"worst corner inverse condition {cond['corners_min_inverse_condition']:.3g}, "
          f"{len(cond['near_singular_corners'])} corners below {cond['threshold']}")
    print(f"written to {args.out}")
    return 0
