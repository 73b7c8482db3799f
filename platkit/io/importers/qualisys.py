"""Qualisys Track Manager (QTM) TSV exports, 3D (markers) and 6D (rigid bodies).

A header block of tab-separated keys and values, then the data:

    NO_OF_FRAMES	1000
    NO_OF_CAMERAS	8
    NO_OF_MARKERS	4               (6D: NO_OF_BODIES)
    FREQUENCY	100
    NO_OF_ANALOG	0
    ANALOG_FREQUENCY	0
    DESCRIPTION	--
    TIME_STAMP	2026-03-01, 10:15:33.456	12345.678
    DATA_INCLUDED	3D                  (6D: 6D)
    MARKER_NAMES	M1	M2	M3	M4      (6D: BODY_NAMES	T)
    TRAJECTORY_TYPES	Measured	...   (3D, optional)
    Frame	Time	M1 X	M1 Y	M1 Z	...  (optional: older exports start the data here)
    1	0.00000	1650.549	864.247	3553.671	...

3D data: X, Y, Z per marker in mm. 6D data, per body: X, Y, Z (mm), Roll, Pitch, Yaw (deg),
Residual, Rot[0]..Rot[8] (the rotation matrix). The matrix is read column by column (Rot[0..2]
its first column), checked against Roll, Pitch, Yaw taken as R = Rx(roll) Ry(pitch) Rz(yaw)
(QTM's default "Qualisys standard" angles): where the file's angles match the matrix read row by
row instead, that reading is used and said; where they match neither (angles defined otherwise
in QTM's settings), the column reading is kept and said. Times: the Time column, else the frame
index over FREQUENCY. Cells are separated by tabs, so a decimal comma is read as a decimal point.
A marker at 0,0,0, or an empty or NaN cell, is an occluded sample (QTM
writes zeros for a gap), and a body whose cells are empty, NaN or all zero.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import quat_from_matrix
from platkit.io.recording import Recording, name_map, number, occlude_points

#: a rotation matrix must be orthonormal within this
ORTHO_TOL = 1e-3


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def read_qualisys_tsv(path: str | Path) -> Recording:
    """A QTM TSV export: markers (3D) or rigid bodies (6D)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{path}: cannot be read as text ({exc})") from None
    header: dict[str, list[str]] = {}
    k = 0
    while k < len(lines):
        cells = lines[k].split("\t")
        key = cells[0].strip()
        if not key or not key.replace("_", "").isupper():
            break
        header[key] = [c.strip() for c in cells[1:]]
        k += 1
    for key in ("NO_OF_FRAMES", "FREQUENCY"):
        if key not in header or not header[key]:
            raise BadInput(f"{path}: the header has no {key} (is this a QTM TSV export?)")
    rate = number(header["FREQUENCY"][0], f"{path}: FREQUENCY")
    if not rate > 0:
        raise BadInput(f"{path}: FREQUENCY is {header['FREQUENCY'][0]!r}; expected Hz > 0")
    six = "BODY_NAMES" in header
    names_key = "BODY_NAMES" if six else "MARKER_NAMES"
    if names_key not in header:
        raise BadInput(f"{path}: the header has neither MARKER_NAMES nor BODY_NAMES")
    labels = [c for c in header[names_key] if c]
    if not labels:
        raise BadInput(f"{path}: {names_key} lists no names")
    rec = Recording(source=path, format=f"Qualisys TSV ({'6D' if six else '3D'})", unit="mm", t=np.zeros(0),
                    rate_hz=rate)
    per = 16 if six else 3
    has_frame = k < len(lines) and lines[k].split("\t")[0].strip() == "Frame"
    lead = 0
    if has_frame:
        cols = [c.strip() for c in lines[k].split("\t")]
        lead = 2 if len(cols) > 1 and cols[1] == "Time" else 1
        k += 1
    width = lead + per * len(labels)
    body = [(n + 1, ln) for n, ln in enumerate(lines[k:], start=k) if ln.strip()]
    if not body:
        raise BadInput(f"{path}: no data rows after the header")
    values = np.full((len(body), width), np.nan)
    for r, (line, ln) in enumerate(body):
        cells = ln.split("\t")
        if len(cells) > width and any(c.strip() for c in cells[width:]):
            raise BadInput(f"{path}: line {line}: {len(cells)} cells, expected {width}")
        if len(cells) < width:
            raise BadInput(f"{path}: line {line}: {len(cells)} cells, expected {width} "
                           f"({lead} leading and {per} per name of {names_key})")
        for c in range(width):
            values[r, c] = number(cells[c], f"{path}: line {line}, column {c + 1}", decimal_comma=True)
    n_frames = number(header["NO_OF_FRAMES"][0], f"{path}: NO_OF_FRAMES")
    if n_frames != len(body):
        raise BadInput(f"{path}: NO_OF_FRAMES says {n_frames:g}, the file has {len(body)} data rows (cut short?)")
    rec.t = values[:, 1] if lead == 2 else np.arange(len(body)) / rate
    lmap = name_map(labels, f"{path}: {names_key}")
    for m, label in enumerate(labels):
        block = values[:, lead + per * m: lead + per * (m + 1)]
        name = lmap[label]
        if not six:
            rec.markers[name] = occlude_points(rec, name, block, zeros_missing=True)
            continue
        pos, rpy, rot = block[:, 0:3], np.radians(block[:, 3:6]), block[:, 7:16]
        empty = ~np.isfinite(rot).all(axis=1) | ~np.isfinite(pos).all(axis=1)
        zero = ~empty & np.all(rot == 0.0, axis=1)
        gone = empty | zero
        R = np.full((len(body), 3, 3), np.nan)
        R[~gone] = rot[~gone].reshape(-1, 3, 3).transpose(0, 2, 1)  # Rot[0..2] the first column
        if (~gone).any():
            Rg = R[~gone]
            err = np.abs(Rg @ Rg.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
            if err.max() > ORTHO_TOL:
                r = int(np.nonzero(~gone)[0][np.argmax(err)])
                raise BadInput(f"{path}: line {body[r][0]}, body {label!r}: Rot[0..8] is not a rotation matrix "
                               f"(R R^T off the identity by {err.max():.3g})")
            ok = np.isfinite(rpy[~gone]).all(axis=1)
            if ok.any():
                a = rpy[~gone][ok]
                from_angles = _rx(a[:, 0]) @ _ry(a[:, 1]) @ _rz(a[:, 2])
                col = np.abs(Rg[ok] - from_angles).max()
                row = np.abs(Rg[ok].transpose(0, 2, 1) - from_angles).max()
                if col > 1e-3 and row <= 1e-3:
                    R[~gone] = Rg.transpose(0, 2, 1)
                    rec.notes.append(f"body {label!r}: Rot[0..8] read row by row (the file's Roll, Pitch, Yaw "
                                     "agree with that order)")
                elif col > 1e-3:
                    rec.notes.append(f"body {label!r}: Roll, Pitch, Yaw do not match Rot[0..8] as R = Rx Ry Rz "
                                     "(other angles in QTM's settings); the matrix is read column by column")
        q = np.full((len(body), 4), np.nan)
        if (~gone).any():
            q[~gone] = quat_from_matrix(R[~gone])
        pos = np.where(gone[:, None], np.nan, pos)
        rec.bodies[name] = (pos, q)
        rec.occluded[name] = int(gone.sum())
        rec.zeros[name] = int(zero.sum())
    return rec
