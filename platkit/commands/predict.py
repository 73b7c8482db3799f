"""platkit predict: markers (mocap frame) and poses (base frame) from a calibration, per command row,
at a thermal state (``--at-time`` seconds since power-on, or ``--warm``) where the model has
time-dependent terms."""
from __future__ import annotations

from platkit.commands.reregister import add_arguments as add_register_arguments
from platkit.notices import warn


def add_parser(sub):
    p = sub.add_parser("predict", help="predict markers and poses for a commands file from a calibration")
    p.add_argument("--calibration", required=True, help="calibration.yaml written by calibrate or diagnose")
    p.add_argument("--commands", required=True, help="CSV with one column per control (and optionally t)")
    p.add_argument("--out", required=True, help="CSV to write")
    add_register_arguments(p)
    state = p.add_mutually_exclusive_group()
    state.add_argument("--at-time", type=float, default=None, metavar="SECONDS",
                       help="thermal state: the first row SECONDS after power-on, later rows by their t (where the "
                            "calibration does not know its power-on, its session's first command stands for it); "
                            "default: the first row at power-on")
    state.add_argument("--warm", action="store_true",
                       help="thermal state: the equilibrium the model's thermal terms reach (a drift with none: the "
                            "end of the recorded span, with a warning)")
    p.add_argument("--payload", action="append", default=None, metavar="LINK:KG[:X,Y,Z]",
                   help="the load the stand carries, in place of its calibration session's (URDF stands): MASS kg at "
                        "LINK, its centre of mass X,Y,Z m in the link's frame (default the link's origin); once per "
                        "load; 'none' for none. It moves the prediction through the model's compliance terms")
    return p


def parse_payload_args(values: list[str]) -> list[dict]:
    """``--payload`` values (LINK:KG[:X,Y,Z], or none) as session.yaml's payload list; BadInput naming the value."""
    import math

    from platkit.errors import BadInput
    from platkit.tree_loads import MAX_LINK_MASS

    if values == ["none"]:
        return []
    out = []
    for v in values:
        parts = v.split(":")
        try:
            if v == "none" or len(parts) not in (2, 3) or not parts[0]:
                raise ValueError
            com = [float(x) for x in parts[2].split(",")] if len(parts) == 3 else [0.0, 0.0, 0.0]
            if len(com) != 3:
                raise ValueError
            out.append({"link": parts[0], "mass_kg": float(parts[1]), "com_m": com})
        except ValueError:
            raise BadInput(f"--payload {v!r}: give LINK:KG or LINK:KG:X,Y,Z (kg, m in the link's frame), or none "
                           "alone") from None
        if not (math.isfinite(out[-1]["mass_kg"]) and 0 <= out[-1]["mass_kg"] <= MAX_LINK_MASS) or not all(
                math.isfinite(c) for c in out[-1]["com_m"]):
            raise BadInput(f"--payload {v!r}: the mass must lie in [0, {MAX_LINK_MASS:g}] kg and the centre of mass "
                           "be finite")
    return out


def run(args) -> int:
    payload = None if args.payload is None else parse_payload_args(args.payload)
    if getattr(args, "register", None) is not None:  # the calibration re-registered, then this path
        from platkit.commands.reregister import run_registered

        return run_registered(args, run, payload)
    if getattr(args, "register_markers", False) or getattr(args, "registered_calibration", None) is not None:
        from platkit.errors import BadInput

        raise BadInput(f"--{'register-markers' if args.register_markers else 'registered-calibration'}: give "
                       "--register SESSION (the session whose set-up to fit)")
    from platkit.calibrate.predict import predict_file
    from platkit.io.atomic import check_output_file

    check_output_file(args.out)
    res = predict_file(args.calibration, args.commands, args.out, at_time=args.at_time, warm=args.warm,
                       payload=payload)
    if payload is not None and not res["loaded"]:
        warn(f"--payload: the model of {args.calibration} has no compliance term: the payload changes no prediction")
    say_joint_columns_ignored(args.calibration, args.commands)
    if res["failed"]:
        warn(f"{res['failed']} of {res['rows']} rows have no forward-kinematics solution; "
             "their predicted cells are empty")
    for w in res["warnings"]:
        warn(f"{w} (said in the column thermal_note)")
    if res["timed"] or args.at_time is not None or args.warm:
        print(f"thermal state: {res['thermal']}")
    print(f"wrote {res['rows']} rows to {res['out']}")
    return 0


def say_joint_columns_ignored(calibration, commands) -> None:
    """A URDF stand's commands file may carry other columns (predict reads the controls and t),
    but a column naming a moving joint of the URDF that is not a control is read by nobody: a
    mimic joint (it follows its master) or a joint the calibration does not record (held at
    zero, as in the fit). Said, one warning per kind, so that no one believes the value was used."""
    from pathlib import Path

    from platkit.io.calibration import read_calibration
    from platkit.io.table import read_header

    spec = read_calibration(calibration).spec  # the stand is cached: read again, not rebuilt
    chain = spec.extras.get("chain")
    if chain is None:
        return
    joints = chain.tree.joints
    controls = set(spec.control_names)
    header, _ = read_header(Path(commands))
    odd = [c for c in header if c in joints and c not in controls and joints[c].type != "fixed"]
    mimic = [c for c in odd if joints[c].mimic is not None]
    held = [c for c in odd if joints[c].mimic is None]
    if mimic:
        warn(f"{commands}: column{'s' if len(mimic) > 1 else ''} "
             + ", ".join(f"{c!r} (a mimic joint of {joints[c].mimic[0]!r})" for c in mimic)
             + ": ignored, a mimic joint follows its master through the calibration's multiplier and offset")
    if held:
        warn(f"{commands}: column{'s' if len(held) > 1 else ''} {', '.join(repr(c) for c in held)}: "
             f"{'joints' if len(held) > 1 else 'a joint'} of the URDF that the calibration does not record: ignored, "
             "held at zero as in the fit")
