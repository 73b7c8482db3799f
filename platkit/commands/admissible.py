"""platkit admissible: the set of poses a stand can take (controls in their strokes, on its branch).

Writes to --out (whole or not at all):
    admissible.json         summary: grid, counts, extent and volume of the set, slices drawn
    admissible.csv          the admissible grid poses and their controls
    admissible_slices.png   2-D slices of the first two coordinates at values of the third
    admissible_boundary.png 3-D scatter of the set's boundary (three swept coordinates)
Lengths in --unit, angles in radians in the files; the plots use mm and degrees.
"""
from __future__ import annotations

import csv

import numpy as np

from platkit.admissible import admissible_grid, check_not_degenerate, default_axes, plot_boundary, plot_slices
from platkit.commands.common import add_platform_options, add_unit_option, platform_from_args
from platkit.errors import BadInput
from platkit.io.atomic import atomic_output_dir, check_output_dir
from platkit.kinematics import PlatformModel
from platkit.model import length_scale
from platkit.plugins import get_platform
from platkit.io import jsonout


def add_parser(sub):
    p = sub.add_parser("admissible", help="the admissible set of poses: slices, boundary, volume")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--axes", default=None,
                   help="pose coordinates to sweep, comma separated (default: all, for stands with up to 3); "
                        "the others stay at their neutral values")
    p.add_argument("--n", type=int, default=41, help="grid values per swept coordinate (default 41)")
    p.add_argument("--slices", type=int, default=6, help="number of slices to draw (default 6)")
    return p


def _unit_product(units: list[str]) -> str:
    """['rad', 'rad', 'mm'] -> 'rad^2 mm'."""
    out = []
    for u in dict.fromkeys(units):
        k = units.count(u)
        out.append(u if k == 1 else f"{u}^{k}")
    return " ".join(out)


def run(args) -> int:
    check_output_dir(args.out)
    spec = platform_from_args(args)
    if args.axes:
        names = [a.strip() for a in args.axes.split(",") if a.strip()]
    elif spec.n_p <= 3:
        names = spec.coordinate_names
    else:
        raise BadInput(f"--axes: {spec.name} has {spec.n_p} pose coordinates ({', '.join(spec.coordinate_names)}); name 2 or 3 to sweep")
    if not 2 <= len(names) <= 3:
        raise BadInput(f"--axes: name 2 or 3 pose coordinates, got {len(names)}")
    if not 3 <= args.n <= 201:
        raise BadInput(f"--n: expected 3 to 201 grid values per coordinate, got {args.n}")
    if not 1 <= args.slices <= 24:
        raise BadInput(f"--slices: expected 1 to 24, got {args.slices}")
    model = PlatformModel(spec)
    axes = default_axes(spec, names, args.n, model=model)
    grid = admissible_grid(spec, axes, model=model)
    check_not_degenerate(grid)
    s = length_scale(args.unit)

    def shown(value, unit):
        return float(value) / s if unit == "m" else float(value)

    extent = {n: [shown(v, u) for v in grid.extent()[n]] for n, u in zip(grid.names, grid.units)}
    units = {n: (args.unit if u == "m" else u) for n, u in zip(grid.names, grid.units)}
    length_power = sum(u == "m" for u in grid.units)
    summary = {
        "platform": spec.name,
        "coordinates": list(grid.names),
        "units": units,
        "fixed": {n: shown(v, spec.coordinates[spec.coordinate_names.index(n)].unit) for n, v in grid.fixed.items()},
        "grid": {n: {"min": shown(a[0], u), "max": shown(a[-1], u), "n": len(a)} for n, a, u in zip(grid.names, grid.axes, grid.units)},
        "n_grid": int(grid.inside.size),
        "n_admissible": int(grid.inside.sum()),
        "n_no_solution": int(grid.no_solution.sum()),
        "n_outside_stroke": int(grid.outside_stroke.sum()),
        "n_off_branch": int(grid.off_branch.sum()),
        "extent": extent,
        "volume": grid.volume / s**length_power,
        "volume_unit": _unit_product([units[n] for n in grid.names]),
    }
    with atomic_output_dir(args.out) as tmp:
        pts = grid.points()
        U = grid.controls[grid.inside]
        with open(tmp / "admissible.csv", "w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(list(grid.names) + list(grid.control_names))
            for p, u in zip(pts, U):
                w.writerow([repr(shown(v, un)) for v, un in zip(p, grid.units)] + [repr(float(x)) for x in u])
        sliced = plot_slices(grid, tmp / "admissible_slices.png", args.slices)  # fails if nothing is admissible
        if len(names) == 3:
            summary["slices"] = {grid.names[-1]: [shown(v, grid.units[-1]) for v in sliced]}
            summary["n_boundary_drawn"] = plot_boundary(grid, tmp / "admissible_boundary.png")
        (tmp / "admissible.json").write_text(jsonout.dumps(summary, indent=2) + "\n", encoding="utf-8")
    print(f"{spec.name}: {summary['n_admissible']} of {summary['n_grid']} grid poses admissible; "
          f"volume {summary['volume']:.6g} {summary['volume_unit']}")
    for n in grid.names:
        lo, hi = extent[n]
        shown_unit = "deg" if grid.units[grid.names.index(n)] == "rad" else units[n]
        if shown_unit == "deg":
            lo, hi = np.degrees(lo), np.degrees(hi)
        print(f"  {n}: {lo:.4g} .. {hi:.4g} {shown_unit}")
    print(f"written to {args.out}")
    return 0
