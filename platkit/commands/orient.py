"""platkit orient: the platform's orientation from a session's inertial stream."""
from __future__ import annotations

from platkit.errors import BadInput
from platkit.notices import said, warn

#: the estimators of platkit.inertial.orient.METHODS (a test keeps the two equal): importing that
#: module to build the parser would load every filter and scipy.signal (seconds)
METHODS = ("platkit", "platkit-causal", "paper", "command-aided")


def add_parser(sub):
    p = sub.add_parser("orient", help="orientation of the platform from the session's IMU (orientation.csv, report)")
    p.add_argument("session", help="session folder with session.yaml and imu.csv")
    p.add_argument("--calibration", default=None,
                   help="calibration.yaml of the stand (for the command-predicted poses; default: nominal model)")
    p.add_argument("--imu-calibration", default=None,
                   help="YAML with the IMU's gyr_bias_rad_s, gyr_scale, acc_bias_m_s2, acc_scale, sensor_from_platform "
                        "(default: found from the session)")
    p.add_argument("--method", default="platkit", choices=METHODS,
                   help="platkit (offline: forward-backward bias, zero-phase filter), platkit-causal, paper (Burlakov et al. 2018), "
                        "command-aided (gyro fused with the calibrated model's poses)")
    p.add_argument("--platform", default=None, help="stand name (default: session.yaml's)")
    p.add_argument("--description", default=None, help="description file (default: session.yaml's or the stand's)")
    p.add_argument("--max-repair-s", type=float, default=0.05,
                   help="missing IMU data and time gaps up to this long are interpolated (and reported); longer ones are errors")
    p.add_argument("--level-base", action="store_true",
                   help="command-aided: the base frame's z is vertical and the accelerometer calibrated, so the "
                        "tilt comes from the accelerometer alone (default: its constant offset to the model is removed)")
    p.add_argument("--out", required=True, help="output folder")
    return p


def run(args) -> int:
    from platkit.inertial.orient import orient_session
    from platkit.inertial.report import write_outputs
    from platkit.io.atomic import check_output_dir

    check_output_dir(args.out)
    if not args.max_repair_s >= 0:
        raise BadInput(f"--max-repair-s: must be 0 or more seconds, got {args.max_repair_s}")
    result = orient_session(args.session, args.method, args.calibration, args.imu_calibration,
                            args.platform, args.description, args.max_repair_s, args.level_base)
    for w in result.warnings:  # said before writing (platkit.notices): the report lists every warning
        warn(w)
    result.report["warnings"] = list(dict.fromkeys(list(result.warnings) + said()))
    write_outputs(result, args.out)
    r = result.report
    line = f"orientation of {len(result.t)} samples ({r['method']}) -> {args.out}/orientation.csv"
    if "truth" in r:
        line += (f"; against the truth: inclination RMSE {r['truth']['inclination_rmse_deg']:.3f} deg, "
                 f"total RMSE {r['truth']['total_rmse_deg']:.3f} deg")
    print(line)
    return 0
