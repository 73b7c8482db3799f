"""``platkit predict --register SESSION``: the calibration re-registered to that session's set-up,
then predicted as any other (not a verb of its own: predict's option, kept apart from its module)."""
from __future__ import annotations

import tempfile
from pathlib import Path

from platkit.errors import BadInput


def add_arguments(p) -> None:
    """predict's options for re-registration."""
    p.add_argument("--register", default=None, metavar="SESSION",
                   help="a session recorded in the motion-capture set-up to predict in (another day: the cameras "
                        "calibrated again, the robot moved): its poses re-fit the base-to-mocap transform, every "
                        "geometric and effect parameter held, and the markers are predicted in its frame")
    p.add_argument("--register-markers", action="store_true",
                   help="with --register: re-fit the marker places on their links too (a marker body mounted again)")
    p.add_argument("--registered-calibration", default=None, metavar="DIR",
                   help="with --register: also write the re-registered calibration to DIR/calibration.yaml (its "
                        "'registration' says what was re-fitted, on which session), for predict without --register")


def run_registered(args, run, payload: list | None = None) -> int:
    """Re-register ``args.calibration`` on ``args.register``, say the set-up found in one line, then
    ``run`` predict's plain path with the re-registered calibration (written to
    ``--registered-calibration`` whole, or to a folder removed afterwards). ``payload`` (``--payload``,
    parsed): the load the register session was recorded with, so its poses are read and fitted
    with the stand carrying it (through the calibration's compliances)."""
    from platkit.calibrate.predict import read_carrying
    from platkit.calibrate.reregister import reregister
    from platkit.commands.common import read_with_calibration
    from platkit.io.atomic import atomic_output_dir, check_output_dir, check_output_file
    from platkit.model import length_scale

    check_output_file(args.out)
    if args.registered_calibration is not None:
        check_output_dir(args.registered_calibration)
    if not Path(args.calibration).is_file():
        raise BadInput(f"{args.calibration}: calibration file not found")
    cal = read_carrying(args.calibration, payload)
    folder = Path(args.register)
    _, poses = read_with_calibration(folder, cal, args.calibration, quiet=True)
    moved, reg = reregister(cal, poses, markers=args.register_markers)
    s = length_scale(cal.length_unit)
    turn, move = reg.shift(cal)
    print(f"re-registered on {folder} ({reg.n_poses} poses, {reg.n_points} points"
          + (f", {reg.n_rejected} left out as outliers" if reg.n_rejected else "") + "): mocap_from_base turned "
          f"{turn * 1e3:.4g} mrad and moved {move / s:.4g} {cal.length_unit} from the calibration's"
          + (", the marker places re-fitted" if reg.markers else "") + f"; rms on those poses {reg.rms / s:.4g} "
          f"{cal.length_unit}")
    record = {"registration": {"session": str(folder), "calibration": str(args.calibration),
                               "note": "the set-up (mocap_from_base" + (" and the marker places" if reg.markers else "")
                                       + ") re-fitted on the session's poses; every other value is the calibration's",
                               **reg.to_dict(cal)}}
    args.register, args.register_markers, out_dir = None, False, args.registered_calibration
    args.registered_calibration = None
    if out_dir is None:
        with tempfile.TemporaryDirectory(prefix="platkit-registered-") as tmp:
            args.calibration = str(_write(moved, Path(tmp), record))
            return run(args)
    with atomic_output_dir(out_dir) as tmp:
        args.calibration = str(_write(moved, tmp, record))
        code = run(args)
    args.calibration = str(Path(out_dir) / "calibration.yaml")
    print(f"wrote {args.calibration}")
    return code


def _write(cal, folder: Path, record: dict) -> Path:
    """calibration.yaml of ``cal`` in ``folder`` (travelling, as calibrate writes it), ``record`` after it."""
    from platkit.io.calibration import write_calibration_yaml
    from platkit.io.description import dump_yaml

    path = write_calibration_yaml(cal, folder)
    with path.open("a", encoding="utf-8") as fh:
        fh.write(dump_yaml(record, sort_keys=False, default_flow_style=None, width=120))
    return path
