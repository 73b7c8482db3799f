"""Motion-capture markers from C3D files (read with ezc3d).

The point units come from the file's POINT:UNITS parameter (never guessed); labels are mapped
to the session's marker names: an exact match, else the part after the last ':' (Vicon and
Qualisys write ``Subject:M1``). Samples whose residual is negative are occluded (NaN).
:func:`read_c3d_recording` reads every point and the ROTATION group's 6-DOF bodies (platkit
import).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.errors import BadSession
from platkit.geometry import quat_from_matrix
from platkit.io.recording import Recording, name_map

C3D_UNITS = {"mm": 1e-3, "m": 1.0, "cm": 1e-2}
#: the first three entries of a ROTATION transform's bottom row must be within this of 0 (a
#: translation there means the matrix was stored transposed: read as it is, the body's position
#: would be 0 and its rotation inverted)
BOTTOM_TOL = 1e-6


def _ezc3d():
    try:
        import ezc3d
    except ImportError:  # pragma: no cover - ezc3d is in the [mocap] and [dev] extras
        raise BadSession("reading C3D files needs the ezc3d package: pip install 'platkit[mocap]'") from None
    return ezc3d


def _param(c, group: str, name: str, path: Path):
    try:
        return c["parameters"][group][name]["value"]
    except KeyError:
        raise BadSession(f"{path}: C3D parameter {group}:{name} is missing") from None


def match_labels(labels: list[str], names: list[str], path: Path) -> list[int]:
    """Index in ``labels`` of every name in ``names``; BadSession naming a missing or ambiguous one."""
    labels = [str(lb).strip() for lb in labels]
    out = []
    for n in names:
        exact = [i for i, lb in enumerate(labels) if lb == n]
        if not exact:
            exact = [i for i, lb in enumerate(labels) if lb.rsplit(":", 1)[-1] == n]
        if not exact:
            raise BadSession(f"{path}: no point labelled {n!r}; the file has {', '.join(labels) or 'no points'}")
        if len(exact) > 1:
            raise BadSession(f"{path}: marker {n!r} matches several point labels {[labels[i] for i in exact]}")
        out.append(exact[0])
    return out


def _open_c3d(path: Path):
    """The C3D file read by ezc3d, its POINT:UNITS (one of C3D_UNITS) and POINT:RATE (Hz, positive);
    BadSession naming the file and parameter otherwise."""
    ezc3d = _ezc3d()
    try:
        c = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises plain RuntimeError/IOError on a bad file
        raise BadSession(f"{path}: cannot be read as C3D ({exc})") from None
    units = _param(c, "POINT", "UNITS", path)
    unit = str(units[0] if isinstance(units, (list, tuple)) and units else units).strip().lower()
    if unit not in C3D_UNITS:
        raise BadSession(f"{path}: POINT:UNITS is {unit!r}; expected one of {', '.join(C3D_UNITS)}")
    rate = float(np.asarray(_param(c, "POINT", "RATE", path), float).ravel()[0])
    if not rate > 0:
        raise BadSession(f"{path}: POINT:RATE is {rate}; expected a positive frame rate")
    return c, unit, rate


def read_c3d_markers(path: str | Path, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Markers ``names`` from a C3D file.

    Returns ``t`` (K,) seconds from the file's first frame number and point rate, and ``xyz``
    (K, len(names), 3) metres in the motion-capture frame, NaN where occluded.
    """
    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found (the motion-capture markers)")
    c, unit, rate = _open_c3d(path)
    labels = list(_param(c, "POINT", "LABELS", path))
    idx = match_labels(labels, names, path)
    points = np.asarray(c["data"]["points"], float)  # (4, n_points, n_frames)
    xyz = points[:3, idx, :].transpose(2, 1, 0) * C3D_UNITS[unit]
    residuals = c["data"].get("meta_points", {}).get("residuals")
    if residuals is not None:
        res = np.asarray(residuals, float)[0][idx, :].T
        xyz[res < 0] = np.nan
    first = int(c["header"]["points"]["first_frame"])
    t = (first + np.arange(xyz.shape[0])) / rate
    return t, xyz


def read_c3d_recording(path: str | Path) -> Recording:
    """Every labelled point of a C3D file as a marker, and every rotation of its ROTATION group
    (the 6-DOF bodies Qualisys and Vicon can write: a 4x4 transform per body and frame, its
    translation in POINT:UNITS) as a rigid body, in the file's unit (cm read as mm). Samples with
    a negative residual or NaN coordinates, and rotations with NaN entries, are occluded and
    counted. A transform whose bottom row is not 0, 0, 0, (1) or whose rotation is not orthonormal
    is refused, naming the frame. Times are frame numbers over the rate; the rotations must share
    the points' rate."""
    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found")
    c, unit, rate = _open_c3d(path)
    scale, unit_out = (10.0, "mm") if unit == "cm" else (1.0, unit)
    points = np.asarray(c["data"]["points"], float)  # (4, n_points, n_frames)
    first = int(c["header"]["points"]["first_frame"])
    n = points.shape[2]
    rec = Recording(source=path, format="C3D", unit=unit_out, t=(first + np.arange(n)) / rate, rate_hz=rate)
    if unit == "cm":
        rec.notes.append("lengths in cm converted to mm")
    labels = [str(lb).strip() for lb in _param(c, "POINT", "LABELS", path)] if points.shape[1] else []
    residuals = c["data"].get("meta_points", {}).get("residuals")
    res = np.asarray(residuals, float)[0] if residuals is not None else np.zeros(points.shape[1:])
    for k, name in name_map(labels, f"{path}: POINT:LABELS").items():
        i = labels.index(k)
        xyz = points[:3, i, :].T * scale
        gone = (res[i] < 0) | ~np.isfinite(xyz).all(axis=1)
        xyz[gone] = np.nan
        rec.markers[name] = xyz
        rec.occluded[name] = int(gone.sum())
        rec.zeros[name] = 0
    rot = c["data"].get("rotations")
    rot = np.asarray(rot, float) if rot is not None else np.zeros((4, 4, 0, n))
    if rot.ndim == 4 and rot.shape[2] > 0:
        if "ROTATION" not in c["parameters"]:
            raise BadSession(f"{path}: rotations without a ROTATION group")
        rlabels = [str(lb).strip() for lb in c["parameters"]["ROTATION"]["LABELS"]["value"]]
        if len(rlabels) != rot.shape[2]:
            raise BadSession(f"{path}: ROTATION:LABELS names {len(rlabels)} bodies, the data holds {rot.shape[2]}")
        if rot.shape[3] != n:
            raise BadSession(f"{path}: the rotations have {rot.shape[3]} frames, the points {n}; "
                             "only rotations at the points' rate are read")
        for k, name in name_map(rlabels, f"{path}: ROTATION:LABELS").items():
            if name in rec.markers:
                raise BadSession(f"{path}: {name!r} is both a point and a rotation")
            T = rot[:, :, rlabels.index(k), :].transpose(2, 0, 1)  # (n, 4, 4)
            gone = np.asarray(~np.isfinite(T[:, :3, :4]).all(axis=(1, 2)), bool)
            pos = np.where(gone[:, None], np.nan, T[:, :3, 3] * scale)
            q = np.full((n, 4), np.nan)
            if (~gone).any():
                bottom = np.abs(T[~gone, 3, :3]).max(axis=1)
                if bottom.max() > BOTTOM_TOL:
                    f = int(np.nonzero(~gone)[0][np.argmax(bottom)])
                    moved = np.abs(T[~gone, :3, 3]).max() > BOTTOM_TOL
                    why = ("not a rigid transform" if moved else
                           "its translation is in the bottom row: the matrix is stored transposed")
                    raise BadSession(f"{path}: rotation {k!r}, frame {first + f}: the 4x4 transform's bottom row is "
                                     f"{', '.join(f'{v:.6g}' for v in T[f, 3])}, not 0, 0, 0, 1 ({why})")
                R = T[~gone, :3, :3]
                err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
                if err.max() > 1e-3:
                    f = int(np.nonzero(~gone)[0][np.argmax(err)])
                    raise BadSession(f"{path}: rotation {k!r}, frame {first + f}: not a rotation matrix "
                                     f"(R R^T off the identity by {err.max():.3g})")
                q[~gone] = quat_from_matrix(R)
            rec.bodies[name] = (pos, q)
            rec.occluded[name] = int(gone.sum())
            rec.zeros[name] = 0
    return rec


def write_c3d_markers(path: str | Path, t: np.ndarray, xyz: np.ndarray, names: list[str], unit: str = "mm") -> None:
    """Write markers (K, M, 3) metres sampled at a constant rate to a C3D file (for examples and
    tests); occluded samples (NaN) get residual -1."""
    ezc3d = _ezc3d()
    t = np.asarray(t, float)
    rate = 1.0 / float(np.median(np.diff(t)))
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [rate]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(names)
    pts = np.ones((4, len(names), len(t)))
    pts[:3] = np.asarray(xyz, float).transpose(2, 1, 0) / C3D_UNITS[unit]
    c["data"]["points"] = pts
    c.add_parameter("POINT", "UNITS", unit)
    c.write(str(path))
