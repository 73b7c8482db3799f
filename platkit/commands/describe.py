"""platkit describe: controls, parameters (name, unit, nominal) and pose coordinates of a stand."""
from __future__ import annotations

import numpy as np

from platkit.commands.common import add_platform_options, add_unit_option, print_json, platform_from_args
from platkit.model import length_scale
from platkit.plugins import get_platform


def add_parser(sub):
    p = sub.add_parser("describe", help="controls, parameters and pose coordinates of a stand")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def _shown(value: float, unit: str, length_unit: str) -> tuple[float, str]:
    if unit == "m":
        return value / length_scale(length_unit), length_unit
    return value, unit


def run(args) -> int:
    spec = platform_from_args(args)
    controls = []
    for c in spec.controls:
        lo, unit = _shown(c.lower, c.unit, args.unit)
        hi, _ = _shown(c.upper, c.unit, args.unit)
        neutral, _ = _shown(c.neutral, c.unit, args.unit)
        controls.append({"name": c.name, "unit": unit, "lower": lo, "upper": hi, "neutral": neutral})
    params = []
    for p in spec.parameters:
        nominal, unit = _shown(p.nominal, p.unit, args.unit)
        params.append({"name": p.name, "unit": unit, "nominal": nominal, "free": p.free, "group": p.group})
    coords = []
    for c in spec.coordinates:
        neutral, unit = _shown(c.neutral, c.unit, args.unit)
        coords.append({"name": c.name, "unit": unit, "neutral": neutral})
    out = {
        "platform": spec.name, "title": spec.title,
        "description": str(spec.description_path) if spec.description_path else None,
        "controls": controls, "parameters": params, "coordinates": coords,
        "n_parameters": len(params),
        "closed_form_inverse": spec.inverse is not None, "closed_form_forward": spec.forward is not None,
    }
    chain = spec.extras.get("chain")
    if chain is not None:  # a URDF stand: the links it tracks, and the joints that follow a control
        out["tracked_links"] = list(spec.tracked_links or [chain.moving_link])
        out["mimic_joints"] = [{"joint": j.name, "master": j.mimic[0], "multiplier": j.mimic[1], "offset": j.mimic[2]}
                               for j in chain.calibrated if j.mimic is not None]
    if args.json:
        print_json(out)
        return 0
    print(f"{spec.name}: {spec.title}")
    print(f"description: {out['description']}")
    print(f"controls ({len(controls)}):")
    wc = max([12] + [len(c["name"]) for c in controls])  # columns as wide as the longest name (a URDF's joints)
    for c in controls:
        print(f"  {c['name']:<{wc}} [{c['lower']:.6g}, {c['upper']:.6g}] {c['unit']}  neutral {c['neutral']:.6g}")
    if chain is not None:
        links = out["tracked_links"]
        print(f"tracked links: {', '.join(links)} (the pose is the first's)" if len(links) > 1
              else f"moving link: {links[0]}")
        for m in out["mimic_joints"]:
            print(f"  mimic joint {m['joint']} = {m['multiplier']:.6g} * {m['master']} + {m['offset']:.6g}")
    print(f"pose coordinates ({len(coords)}): " + ", ".join(f"{c['name']} [{c['unit']}]" for c in coords))
    print(f"parameters ({len(params)}):")
    wp = max([16] + [len(p["name"]) for p in params])
    for p in params:
        flag = "" if p["free"] else "  (fixed)"
        print(f"  {p['name']:<{wp}} {p['nominal']:>14.6g} {p['unit']:<10} {p['group']}{flag}")
    return 0
