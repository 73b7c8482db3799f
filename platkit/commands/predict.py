"""platkit predict: markers (mocap frame) and poses (base frame) from a calibration, per command row."""
from __future__ import annotations

import sys


def add_parser(sub):
    p = sub.add_parser("predict", help="predict markers and poses for a commands file from a calibration")
    p.add_argument("--calibration", required=True, help="calibration.yaml written by calibrate or diagnose")
    p.add_argument("--commands", required=True, help="CSV with one column per control (and optionally t)")
    p.add_argument("--out", required=True, help="CSV to write")
    return p


def run(args) -> int:
    from platkit.calibrate.predict import predict_file
    from platkit.io.atomic import check_output_file

    check_output_file(args.out)
    res = predict_file(args.calibration, args.commands, args.out)
    if res["failed"]:
        print(f"platkit: warning: {res['failed']} of {res['rows']} rows have no forward-kinematics solution; "
              "their predicted cells are empty", file=sys.stderr)
    print(f"wrote {res['rows']} rows to {res['out']}")
    return 0
