"""Helpers shared by the CLI verbs: platform options, pose formatting, JSON printing."""
from __future__ import annotations

import sys

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import rpy_from_quat
from platkit.model import length_scale


def add_platform_options(parser, required: bool = True) -> None:
    parser.add_argument("--platform", required=required, help="stand name (see `platkit plugins`)")
    parser.add_argument("--description", default=None, help="description file (default: the stand's own)")
    parser.add_argument("--base-link", default=None, help="serial-chain stands: the link the chain starts from")
    parser.add_argument("--moving-link", default=None,
                        help="serial-chain stands: the link that moves (carries the markers); a tree: the tracked "
                             "links, comma separated")


def platform_from_args(args):
    """The PlatformSpec named by --platform/--description and the stand options
    (--base-link, --moving-link) where given."""
    from platkit.plugins import get_platform

    options = {k: getattr(args, k, None) for k in ("base_link", "moving_link")}
    if options["moving_link"] and "," in options["moving_link"]:  # a tree: several tracked links
        options["moving_link"] = {n.strip(): n.strip() for n in options["moving_link"].split(",") if n.strip()}
    return get_platform(args.platform, args.description, **{k: v for k, v in options.items() if v is not None})


def add_unit_option(parser) -> None:
    parser.add_argument("--unit", default="mm", choices=["mm", "m"], help="length unit of lengths in and out (default mm)")


def parse_vector(text: str, what: str, size: int | None = None, names: list[str] | None = None) -> np.ndarray:
    """'1,2,3' -> array; BadInput naming the option on anything else (and, given ``names``, the
    ``size`` values expected in their order: a URDF tree's controls are many)."""
    try:
        values = np.array([float(v) for v in text.replace(";", ",").split(",") if v.strip() != ""])
    except ValueError:
        raise BadInput(f"{what}: expected comma-separated numbers, got {text!r}") from None
    if size is not None and values.size != size:
        raise BadInput(f"{what}: expected {size} numbers, got {values.size}"
                       + (f" ({', '.join(names)}, in this order)" if names else ""))
    if not np.all(np.isfinite(values)):
        raise BadInput(f"{what}: numbers must be finite")
    return values


#: a quaternion typed or written by a person is unit if its norm is within this of 1 (4 to 6 decimals
#: pass); further off it is refused rather than normalised (a scaled or mistyped rotation), as the
#: session readers and importers do
QUATERNION_NORM_TOL = 1e-3


def unit_quaternion(q, what: str) -> np.ndarray:
    """``q`` (4,) w,x,y,z normalised; BadInput naming ``what`` (the option or file place) if it is
    zero or its norm is further than QUATERNION_NORM_TOL from 1."""
    q = np.asarray(q, float)
    n = float(np.linalg.norm(q))
    if n == 0:
        raise BadInput(f"{what}: the quaternion is zero")
    if abs(n - 1.0) > QUATERNION_NORM_TOL:
        raise BadInput(f"{what}: the quaternion qw,qx,qy,qz has norm {n:.6g}, expected 1 (within "
                       f"{QUATERNION_NORM_TOL:g}); give a unit quaternion, or the rotation as roll,pitch,yaw")
    return q / n


def pose_dict(q, X, unit: str) -> dict:
    """A pose as the spec's JSON: x, y, z (unit), qw..qz, roll, pitch, yaw (rad)."""
    s = length_scale(unit)
    q = np.asarray(q, float)
    rpy = rpy_from_quat(q)
    return {
        "x": float(X[0] / s), "y": float(X[1] / s), "z": float(X[2] / s),
        "qw": float(q[0]), "qx": float(q[1]), "qy": float(q[2]), "qz": float(q[3]),
        "roll": float(rpy[0]), "pitch": float(rpy[1]), "yaw": float(rpy[2]),
        "unit": unit,
    }


def print_json(obj) -> None:
    from platkit.io.jsonout import dumps

    sys.stdout.write(dumps(obj, indent=2) + "\n")


def read_with_calibration(folder, cal, calibration, quiet: bool = False, read: dict | None = None):
    """(session, settled poses) of the session ``folder`` read with the stand of ``cal`` (read from
    ``calibration``): its platform must be the calibration's, a tree's markers on the links the
    calibration has them on (:func:`same_links`); the control readings kept beside a limit are said.
    Its streams are read once: ``read``, where given, gets the session under ``folder`` before it
    is settled (a caller whose settling fails reads the stream otherwise, not from the files again)."""
    from pathlib import Path

    from platkit.io.session import load_session
    from platkit.io.session_yaml import read_session_yaml
    from platkit.notices import warn
    from platkit.settle import load_poses

    platform = read_session_yaml(Path(folder)).get("platform")
    if platform is not None and platform != cal.platform:
        raise BadInput(f"{folder}: the session is of the {platform} stand, the calibration of {cal.platform}")
    session = load_session(folder, spec=cal.spec, quiet=quiet)
    same_links(session.moving_link, cal.marker_links, folder, calibration)
    if read is not None:
        read[folder] = session
    for note in session.extras.get("control_notes", []):  # readings kept (platkit.limits)
        warn(note)
    return session, load_poses(folder, spec=cal.spec, session=session)


def same_links(session_links, cal_links: dict, folder, calibration) -> None:
    """A tree session's markers on the links the calibration has them on: a marker that
    session.yaml maps to another link than the calibration is bad input (the calibration's link
    would be used, the session's mapping ignored, with nothing said)."""
    from pathlib import Path

    if not isinstance(session_links, dict) or not cal_links:
        return
    for name, link in session_links.items():
        if name in cal_links and cal_links[name] != link:
            raise BadInput(f"{Path(folder) / 'session.yaml'}: field 'moving_link' maps {name!r} to {link!r}, the "
                           f"calibration {calibration} to {cal_links[name]!r}; a diagnosis keeps the calibration's "
                           "markers where they are")
