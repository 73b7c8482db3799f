"""platkit workspace: corner envelope, true translational envelope, conditioning, plots."""
from __future__ import annotations

import math

from platkit.commands.common import add_platform_options, add_unit_option, print_json, platform_from_args
from platkit.io.atomic import check_output_dir
from platkit.kinematics import PlatformModel
from platkit.model import length_scale
from platkit.workspace import AXES, DEGENERATE_SPAN
from platkit.workspace.files import write_workspace


def add_parser(sub):
    p = sub.add_parser("workspace", help="reachable set: control-box corners, true envelope, plots")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--out", required=True, help="output folder (workspace.json, corners.csv, envelope.csv, "
                                                "coordinates.csv, plots)")
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
    box = "pose-box" if spec.pose_free else "control-box"
    rows = [(f"{corners['count']} {box} corners ({corners['converged']} solved)", corners["relative_to_neutral"])]
    for name, env in figures["true_envelope"].items():
        rows.append((f"true, {name.replace('_', ' ')}", env))
    if max(env[a]["range"] for _, env in rows for a in AXES) * length_scale(unit) <= DEGENERATE_SPAN:
        at = ", ".join(f"{v:.1f}" for v in figures["neutral_position"])
        print(f"{spec.name}: the origin does not move (x, y, z = {at} {unit} at every corner and in both envelopes)")
    else:
        print(f"{spec.name}: origin relative to the neutral pose, {unit}")
        print(f"{'envelope':<34}" + "".join(f"{a + ' min':>11}{a + ' max':>11}" for a in AXES))
        for label, env in rows:
            print(f"{label:<34}" + "".join(f"{env[a]['min']:>11.1f}{env[a]['max']:>11.1f}" for a in AXES))
    _print_coordinates(figures["coordinates"], unit)
    cond = figures["conditioning"]
    print(f"conditioning: neutral condition number {cond['neutral']['condition_number']:.3g}, "
          f"worst corner inverse condition {cond['corners_min_inverse_condition']:.3g}, "
          f"{len(cond['near_singular_corners'])} corners below {cond['threshold']}")
    print(f"written to {args.out}")
    return 0


def _print_coordinates(coordinates: dict, unit: str) -> None:
    """The pose coordinates' ranges (workspace.json's, lengths in ``unit``, angles in rad) as a
    table in ``unit`` and degrees; the coordinates that do not move (a range of at most
    DEGENERATE_SPAN, m or rad) in one line after it."""
    moved, held = [], []
    for name, c in coordinates.items():
        angle = c["unit"] == "rad"
        k = 180.0 / math.pi if angle else 1.0
        si = 1.0 if angle else length_scale(unit)
        row = (name, "deg" if angle else c["unit"], c["neutral"] * k, c["min"] * k, c["max"] * k)
        (moved if c["range"] * si > DEGENERATE_SPAN else held).append(row)
    if moved:
        print("pose coordinates over the poses it takes (strokes, branch, coordinates' bounds)")
        print(f"{'coordinate':<34}{'neutral':>11}{'min':>11}{'max':>11}")
        for name, shown, *values in moved:
            print(f"{name + ' (' + shown + ')':<34}" + "".join(f"{v:>11.1f}" for v in values))
    if held:
        print("not moved: " + ", ".join(f"{name} = {neutral:.1f} {shown}" for name, shown, neutral, _, _ in held))
