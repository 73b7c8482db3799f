"""OptiTrack Motive CSV exports (format version 1.2x).

    Format Version,1.23,Take Name,...,Export Frame Rate,120.000000,...,Rotation Type,Quaternion,
        Length Units,Millimeters,Coordinate Space,Global      (one line)
    <blank>
    ,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker
    ,Name,T,T,T,T,T,T,T,T,M1,M1,M1
    ,ID,1,1,1,1,1,1,1,1,2,2,2
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,Position,Position,Position
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z
    0,0.000000,0.0123,-0.4567,0.0011,0.8895,1193.014,3071.078,-1725.361,0.00012,...

Rigid bodies (Type "Rigid Body"): Position X,Y,Z in the Length Units, Rotation as a quaternion in
x,y,z,w order (mapped to the spec's w,x,y,z); a Rotation Type other than Quaternion is refused.
Labelled markers (Type "Marker"): Position X,Y,Z. Rigid body markers, bones, bone markers and
unlabelled markers are left out, and said. Times: the Time column. An empty cell is an occluded
sample, and so is a marker at 0,0,0 or a body whose quaternion is all zero (which some exports
write for a frame the body was not tracked).
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from platkit.errors import BadInput
from platkit.io.recording import Recording, checked_quaternions, name_map, number, occlude_points

UNITS = {"Millimeters": ("mm", 1.0), "Meters": ("m", 1.0), "Centimeters": ("mm", 10.0)}


def read_motive_csv(path: str | Path) -> Recording:
    """A Motive CSV export's rigid bodies and labelled markers."""
    path = Path(path)
    try:
        rows = list(csv.reader(path.read_text(encoding="utf-8-sig").splitlines()))
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{path}: cannot be read as text ({exc})") from None
    meta_row = rows[0] if rows else []
    meta = {meta_row[k].strip(): meta_row[k + 1].strip() for k in range(0, len(meta_row) - 1, 2)}
    if "Format Version" not in meta:
        raise BadInput(f"{path}: line 1 does not start with 'Format Version' (is this a Motive CSV export?)")
    if "Length Units" not in meta or meta["Length Units"] not in UNITS:
        raise BadInput(f"{path}: line 1: Length Units is {meta.get('Length Units')!r}; expected one of "
                       f"{', '.join(UNITS)} (units are declared, never guessed)")
    unit, scale = UNITS[meta["Length Units"]]
    rate_s = meta.get("Export Frame Rate") or meta.get("Capture Frame Rate")
    rate = number(rate_s, f"{path}: line 1, Export Frame Rate") if rate_s else None
    # the labelled rows: 'Type', 'Name', 'ID' in the first or second cell; the components' row starts 'Frame'
    find: dict[str, int] = {}
    frame_row = None
    for r, row in enumerate(rows[1:40], start=1):
        lead = [c.strip() for c in row[:2]]
        for key in ("Type", "Name", "ID"):
            if key in lead and key not in find:
                find[key] = r
        if lead and lead[0] == "Frame":
            frame_row = r
            break
    if frame_row is None or "Type" not in find or "Name" not in find:
        raise BadInput(f"{path}: no 'Type', 'Name' and 'Frame,Time' header rows in the first 40 lines")
    types, names, comps = rows[find["Type"]], rows[find["Name"]], rows[frame_row]
    cats = rows[frame_row - 1]
    width = len(comps)
    if width < 3 or comps[1].strip() not in ("Time", "Time (Seconds)"):
        raise BadInput(f"{path}: line {frame_row + 1}: expected 'Frame,Time (Seconds),...', got {','.join(comps[:3])!r}")

    def cell(row, c):
        return row[c].strip() if c < len(row) else ""

    groups: dict[tuple[str, str], dict[str, int]] = {}
    for c in range(2, width):
        typ, nm = cell(types, c), cell(names, c)
        key = f"{cell(cats, c)} {cell(comps, c)}".strip()
        groups.setdefault((typ, nm), {})[key] = c
    data = [(r + 1, row) for r, row in enumerate(rows[frame_row + 1:], start=frame_row + 1) if any(x.strip() for x in row)]
    if not data:
        raise BadInput(f"{path}: no frames after the header")
    values = np.full((len(data), width), np.nan)
    for i, (line, row) in enumerate(data):
        if len(row) < width:
            raise BadInput(f"{path}: line {line}: {len(row)} cells, expected {width} like line {frame_row + 1}")
        for c in range(width):
            values[i, c] = number(row[c], f"{path}: line {line}, column {c + 1} "
                                          f"({cell(names, c) or cell(comps, c)} {cell(cats, c)} {cell(comps, c)})".rstrip())
    t = values[:, 1]
    if np.isnan(t).any():
        i = int(np.nonzero(np.isnan(t))[0][0])
        raise BadInput(f"{path}: line {data[i][0]}, column 2 (Time): missing time")
    rec = Recording(source=path, format=f"OptiTrack Motive CSV (format {meta['Format Version']})", unit=unit, t=t,
                    rate_hz=rate)
    if scale != 1.0:
        rec.notes.append(f"lengths in {meta['Length Units']} converted to mm")
    kept = [(typ, nm) for typ, nm in groups if typ in ("Rigid Body", "Marker")]
    left = sorted({typ for typ, _ in groups if typ not in ("Rigid Body", "Marker")})
    if left:
        rec.notes.append(f"columns of type {', '.join(left)} left out (only rigid bodies and labelled markers are read)")
    unlabelled = [nm for typ, nm in kept if typ == "Marker" and nm.lower().startswith("unlabeled")]
    if unlabelled:
        rec.notes.append(f"{len(unlabelled)} unlabelled marker(s) left out")
    kept = [(typ, nm) for typ, nm in kept if not (typ == "Marker" and nm in unlabelled)]
    lmap = name_map([nm for _, nm in kept], f"{path}: line {find['Name'] + 1}")
    for typ, nm in kept:
        cols = groups[(typ, nm)]
        name = lmap[nm]
        pos_keys = ["Position X", "Position Y", "Position Z"]
        missing = [k for k in pos_keys if k not in cols]
        if missing:
            raise BadInput(f"{path}: line {frame_row + 1}: {typ.lower()} {nm!r} has no {missing[0]} column")
        pos = values[:, [cols[k] for k in pos_keys]] * scale
        if typ == "Marker":
            rec.markers[name] = occlude_points(rec, name, pos, zeros_missing=True)
            continue
        if meta.get("Rotation Type", "Quaternion") != "Quaternion" or "Rotation W" not in cols:
            raise BadInput(f"{path}: line 1: Rotation Type is {meta.get('Rotation Type')!r}; export rigid bodies "
                           "with Rotation Type Quaternion (Euler angles depend on an order the file does not say)")
        # Motive writes the quaternion x,y,z,w; the spec's order is w,x,y,z
        q = values[:, [cols["Rotation W"], cols["Rotation X"], cols["Rotation Y"], cols["Rotation Z"]]]
        empty = ~np.isfinite(q).all(axis=1) | ~np.isfinite(pos).all(axis=1)
        zero = ~empty & np.all(q == 0.0, axis=1)
        gone = empty | zero
        q[gone] = np.nan
        pos[gone] = np.nan
        where = f"rigid body {nm!r} (columns {cols['Rotation X'] + 1}-{cols['Rotation W'] + 1})"
        q = checked_quaternions(q, lambda i, where=where: f"{path}: line {data[i][0]}, {where}")
        rec.bodies[name] = (pos, q)
        rec.occluded[name] = int(gone.sum())
        rec.zeros[name] = int(zero.sum())
    if not rec.markers and not rec.bodies:
        raise BadInput(f"{path}: no rigid bodies and no labelled markers")
    return rec
