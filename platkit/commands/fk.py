"""platkit fk: pose from controls."""
from __future__ import annotations

import numpy as np

from platkit.commands.common import add_platform_options, add_unit_option, parse_vector, pose_dict, print_json, platform_from_args
from platkit.kinematics import PlatformModel
from platkit.model import controls_to_si, length_scale
from platkit.notices import said
from platkit.plugins import get_platform
from platkit.urdf import link_pose_function


def add_parser(sub):
    p = sub.add_parser("fk", help="forward kinematics: pose from controls")
    add_platform_options(p)
    add_unit_option(p)
    p.add_argument("--u", required=True, help="controls, comma separated ('m' controls in --unit)")
    p.add_argument("--guess", default=None, help="starting pose coordinates, comma separated (lengths in --unit)")
    p.add_argument("--allow-mirror", action="store_true", help="report a mirror solution instead of failing")
    p.add_argument("--link", default=None,
                   help="URDF stands: also the poses of these links (comma separated; a tree's tracked links are "
                        "always given)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def run(args) -> int:
    spec = platform_from_args(args)
    model = PlatformModel(spec, length_unit=args.unit)
    u = controls_to_si(spec, parse_vector(args.u, "--u", spec.n_u, spec.control_names), args.unit)
    guess = None
    if args.guess:
        guess = parse_vector(args.guess, "--guess", spec.n_p)
        s = length_scale(args.unit)
        guess = np.array([g * s if c.unit == "m" else g for g, c in zip(guess, spec.coordinates)])
    res = model.forward(u, guess=guess, allow_mirror=args.allow_mirror)
    out = pose_dict(res.q, res.X, args.unit)
    out.update({"platform": spec.name, "iterations": res.iterations, "residual": res.residual,
                "on_branch": res.on_branch})
    s = length_scale(args.unit)
    out["coordinates"] = {c.name: float(v / s if c.unit == "m" else v) for c, v in zip(spec.coordinates, res.p)}
    misfit = _misfit_rows(spec, res, args.unit)
    if misfit is not None:
        out["misfit"] = misfit
    links = link_poses(spec, u, args)
    if links:
        out["links"] = {name: pose_dict(q, X, args.unit) for name, (q, X) in links.items()}
    out["warnings"] = said()  # every warning said while the verb ran (platkit.notices), on stderr too
    if args.json:
        print_json(out)
        return 0
    print(f"position  x={out['x']:.4f} y={out['y']:.4f} z={out['z']:.4f} {args.unit}")
    print(f"rotation  roll={np.degrees(out['roll']):.5f} pitch={np.degrees(out['pitch']):.5f} yaw={np.degrees(out['yaw']):.5f} deg")
    print(f"quaternion w={out['qw']:.9f} x={out['qx']:.9f} y={out['qy']:.9f} z={out['qz']:.9f}")
    # a stand with more rows than coordinates solves by least squares, its residual the rows' norm
    # each over its plausible misfit
    solve = (f"least-squares iterations {res.iterations}, weighted misfit {res.residual:.2e}" if misfit is not None
             else f"newton iterations {res.iterations}, residual {res.residual:.2e}")
    print(solve + ("" if res.on_branch else "  MIRROR POSE (not on the stand's branch)"))
    if misfit is not None:
        print("misfit    " + ", ".join(f"{name} {row['value']:+.4g} {row['unit']}" for name, row in misfit.items())
              + f" (worst {res.misfit_ratio:.0%} of its plausible misfit)")
    for name, (q, X) in links.items():
        d = pose_dict(q, X, args.unit)
        print(f"link {name}  x={d['x']:.4f} y={d['y']:.4f} z={d['z']:.4f} {args.unit}  "
              f"quaternion w={d['qw']:.9f} x={d['qx']:.9f} y={d['qy']:.9f} z={d['qz']:.9f}")
    return 0


def link_poses(spec, u, args) -> dict:
    """{link: (q (4,), w >= 0; X (3,) m)} in the base frame: a tree's tracked links, then those of --link."""
    names = list(spec.tracked_links)
    if args.link:
        names += [n.strip() for n in args.link.split(",") if n.strip() and n.strip() not in names]
    if not names:
        return {}
    q, X = link_pose_function(spec, names)(u, spec.nominal_td())
    q, X = np.asarray(q).ravel(), np.asarray(X).ravel()
    # each quaternion with w >= 0, as the moving frame's and predict's: one rotation, one way of writing it
    return {n: (q[4 * k:4 * k + 4] * (-1.0 if q[4 * k] < 0 else 1.0), X[3 * k:3 * k + 3]) for k, n in enumerate(names)}


def _misfit_rows(spec, res, unit: str) -> dict | None:
    """Each row's misfit at the least-squares pose of a stand with more rows than pose
    coordinates ('m' rows in ``unit``), with its plausible misfit; None for a square stand."""
    if res.misfit is None:
        return None
    s = length_scale(unit)
    rows = spec.misfit or [None] * len(res.misfit)
    out = {}
    for i, (m, v) in enumerate(zip(rows, res.misfit)):
        name = m.name if m is not None else f"row {i}"
        scale = s if m is not None and m.unit == "m" else 1.0
        out[name] = {"value": float(v / scale), "unit": unit if scale != 1.0 else (m.unit if m is not None else ""),
                     "plausible": float(m.plausible / scale) if m is not None else None}
    return out
