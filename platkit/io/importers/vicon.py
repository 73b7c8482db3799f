"""Vicon Nexus / Tracker CSV exports.

The file is a list of sections, each:

    <section name>                      Trajectories, Segments (Nexus) or Objects (Tracker)
    <rate in Hz>
    ,,Subject:M1,,,Subject:M2,,,        a name at the first column of each group
    Frame,Sub Frame,X,Y,Z,X,Y,Z         the components of each group
    ,,mm,mm,mm,mm,mm,mm                 the unit of each component
    1,0,1650.549,864.247,3553.671,...   one row per frame
    <a blank line ends the section>

Trajectories groups are markers (X,Y,Z). Segments / Objects groups are rigid bodies
(RX,RY,RZ,TX,TY,TZ): the translation TX,TY,TZ and the rotation as a helical (rotation-vector)
angle RX,RY,RZ in the unit its units row gives (deg or rad). Other sections (Devices, Model
Outputs, Joints) are left out, and said. Section names are read whatever their letter case; the
older layout (a 'Field #' column, no Sub Frame column, no units row) is refused: it does not say
its length unit. Times are frame numbers over the rate. An empty cell is an occluded sample, and
so is a marker at exactly 0,0,0 or a body with all six cells 0, which some exports write for a
gap.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import quat_from_rotvec
from platkit.io.recording import Recording, name_map, number, occlude_points

LENGTHS = {"mm": 1.0, "m": 1.0, "cm": 10.0}  # cm is read as mm (x10)
ANGLES = {"deg": np.pi / 180.0, "rad": 1.0}
BODY_SECTIONS = ("Segments", "Objects")
MARKER_SECTIONS = ("Trajectories",)
#: every section name a Vicon CSV export starts a section with (read whatever its letter case:
#: older exports write them in capitals, TRAJECTORIES)
SECTIONS = MARKER_SECTIONS + BODY_SECTIONS + ("Devices", "Model Outputs", "Joints")
_CANONICAL = {s.upper(): s for s in SECTIONS}


def section_name(cell: str) -> str | None:
    """The section a first cell starts (its canonical spelling), or None."""
    return _CANONICAL.get(cell.strip().upper())


def _blank(row: list[str]) -> bool:
    return not any(c.strip() for c in row)


def read_vicon_csv(path: str | Path) -> Recording:
    """A Vicon CSV export's Trajectories (markers) and Segments / Objects (rigid bodies)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{path}: cannot be read as text ({exc})") from None
    rows = list(csv.reader(text.splitlines()))
    rec = Recording(source=path, format="Vicon CSV", unit="mm", t=np.zeros(0))
    units: set[str] = set()
    t_ref: np.ndarray | None = None
    i = 0
    seen_section = False
    while i < len(rows):
        if _blank(rows[i]):
            i += 1
            continue
        section = section_name(rows[i][0]) or rows[i][0].strip()
        line = i + 1
        if len(rows) < i + 5:
            raise BadInput(f"{path}: line {line}: section {section!r} ends before its rate, name, component and "
                           "units rows")
        rate_cell = rows[i + 1][0] if rows[i + 1] else ""
        rate = number(rate_cell, f"{path}: line {line + 1} (the rate of section {section!r})")
        if not rate > 0:
            raise BadInput(f"{path}: line {line + 1}: the rate of section {section!r} is {rate_cell!r}; expected Hz > 0")
        names, comps, unit_row = rows[i + 2], rows[i + 3], rows[i + 4]
        j = i + 5
        while j < len(rows) and not _blank(rows[j]):
            j += 1
        data = rows[i + 5:j]
        i = j
        if section not in MARKER_SECTIONS + BODY_SECTIONS:
            rec.notes.append(f"section {section!r} (line {line}) left out: only Trajectories, Segments and Objects "
                             "are motion capture")
            continue
        seen_section = True
        if comps and comps[0].strip() == "Field #":
            raise BadInput(f"{path}: line {line + 3}: an older Vicon CSV layout (a 'Field #' column, no Sub Frame "
                           "column and no units row): it does not say its length unit; export the trial again "
                           "with a units row (Vicon Nexus 2 or later), or write it as a plain table and import "
                           "that with --unit")
        if [c.strip() for c in comps[:2]] != ["Frame", "Sub Frame"]:
            raise BadInput(f"{path}: line {line + 3}: expected 'Frame,Sub Frame,...' (the component row of section "
                           f"{section!r}), got {','.join(comps[:3])!r}")
        if not data:
            raise BadInput(f"{path}: section {section!r} (line {line}) has no data rows")
        width = max(c for c in range(len(comps)) if comps[c].strip()) + 1  # trailing empty cells are no columns
        starts = [c for c in range(2, max(len(names), 2)) if names[c].strip()]
        if not starts:
            raise BadInput(f"{path}: line {line + 2}: no names in section {section!r}")
        groups = [(names[c].strip(), c, (starts[k + 1] if k + 1 < len(starts) else width)) for k, c in enumerate(starts)]
        values = np.full((len(data), width), np.nan)
        for r, row in enumerate(data):
            if len(row) < width:
                raise BadInput(f"{path}: line {i - len(data) + r + 1}: {len(row)} cells, expected {width} like "
                               f"the component row (line {line + 3})")
            for c in range(width):
                label = comps[c].strip()
                values[r, c] = number(row[c], f"{path}: line {i - len(data) + r + 1}, column {c + 1} ({label})")
        frames = values[:, 0]
        if np.isnan(frames).any():
            r = int(np.nonzero(np.isnan(frames))[0][0])
            raise BadInput(f"{path}: line {i - len(data) + r + 1}, column 1 (Frame): missing frame number")
        t = frames / rate
        if t_ref is None:
            t_ref, rec.rate_hz = t, rate
        elif len(t) != len(t_ref) or not np.allclose(t, t_ref, rtol=0, atol=1e-9):
            raise BadInput(f"{path}: section {section!r} (line {line}) has other frames than the first section")
        label_map = name_map([g[0] for g in groups], f"{path}: line {line + 2}")
        for label, c0, c1 in groups:
            want = ["X", "Y", "Z"] if section in MARKER_SECTIONS else ["RX", "RY", "RZ", "TX", "TY", "TZ"]
            got = [comps[c].strip() for c in range(c0, c1)]
            if sorted(got) != sorted(want):
                raise BadInput(f"{path}: line {line + 3}, columns {c0 + 1}-{c1}: {label!r} has components "
                               f"{','.join(got)}; expected {','.join(want)}")
            col = {g: c0 + k for k, g in enumerate(got)}
            for g in want:
                u = unit_row[col[g]].strip() if col[g] < len(unit_row) else ""
                table = ANGLES if g.startswith("R") else LENGTHS
                if u not in table:
                    raise BadInput(f"{path}: line {line + 4}, column {col[g] + 1}: unit {u!r} for {label} {g}; "
                                   f"expected one of {', '.join(table)}")
                if not g.startswith("R"):
                    units.add(u)
            name = label_map[label]
            if section in MARKER_SECTIONS:
                xyz = values[:, [col["X"], col["Y"], col["Z"]]] * LENGTHS[unit_row[col["X"]].strip()]
                rec.markers[name] = occlude_points(rec, name, xyz, zeros_missing=True)
            else:
                rv = values[:, [col["RX"], col["RY"], col["RZ"]]] * ANGLES[unit_row[col["RX"]].strip()]
                pos = values[:, [col["TX"], col["TY"], col["TZ"]]] * LENGTHS[unit_row[col["TX"]].strip()]
                six = np.column_stack([rv, pos])
                empty = ~np.isfinite(six).all(axis=1)
                zero = np.all(six == 0.0, axis=1)
                pos[empty | zero] = np.nan
                q = np.full((len(t), 4), np.nan)
                q[~(empty | zero)] = quat_from_rotvec(rv[~(empty | zero)])
                rec.bodies[name] = (pos, q)
                rec.occluded[name] = int(np.sum(empty | zero))
                rec.zeros[name] = int(np.sum(zero))
    if not seen_section or t_ref is None:
        raise BadInput(f"{path}: no Trajectories, Segments or Objects section (is this a Vicon CSV export?)")
    lengths = {"m" if u == "m" else "mm" for u in units}
    if len(lengths) > 1:
        raise BadInput(f"{path}: lengths in both mm and m; export them in one unit")
    rec.unit = lengths.pop() if lengths else "mm"
    if "cm" in units:
        rec.notes.append("lengths in cm converted to mm")
    rec.t = t_ref
    return rec
