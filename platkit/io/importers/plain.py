"""Plain tables in the spec's columns (``t``, ``<name>_x,_y,_z``, a body's seven columns) written
with another separator or decimal mark, as spreadsheets in many locales write them.

The separator is the header's: a semicolon or a tab where the header has one, else a comma.
With a semicolon or tab separator a decimal comma is read as a decimal point (``1650,549``);
with a comma separator it cannot be, and a cell like that is an error. The length unit is not in
the file and must be given.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from platkit.errors import BadInput
from platkit.io.recording import Recording, checked_quaternions, number, occlude_points

BODY = ("x", "y", "z", "qw", "qx", "qy", "qz")


def separator(header_line: str) -> str:
    """The separator a table's header line uses: ';', a tab, else ','."""
    if ";" in header_line:
        return ";"
    if "\t" in header_line:
        return "\t"
    return ","


def read_table_export(path: str | Path, unit: str) -> Recording:
    """A plain table of markers and bodies, with its separator and decimal mark recognised."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{path}: cannot be read as text ({exc})") from None
    lines = text.splitlines()
    if not lines:
        raise BadInput(f"{path}: empty file")
    sep = separator(lines[0])
    decimal_comma = sep != ","
    rows = list(csv.reader(lines, delimiter=sep))
    header = [h.strip() for h in rows[0]]
    if not header or header[0] != "t":
        raise BadInput(f"{path}: line 1: the first column must be 't', got {header[0] if header else ''!r}")
    index = {h: k for k, h in enumerate(header)}
    if len(index) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise BadInput(f"{path}: line 1: column {dup!r} appears twice")
    bodies = [h[:-3] for h in header if h.endswith("_qw")]
    used = {"t"} | {f"{b}_{c}" for b in bodies for c in BODY}
    for b in bodies:
        for c in BODY:
            if f"{b}_{c}" not in index:
                raise BadInput(f"{path}: line 1: rigid body {b!r} has no column '{b}_{c}'")
    markers = []
    for h in header:
        if h in used:
            continue
        if h[-2:] not in ("_x", "_y", "_z"):
            raise BadInput(f"{path}: line 1: column {h!r} is neither 't', '<marker>_x/_y/_z' nor a rigid body's")
        m = h[:-2]
        if m not in markers:
            markers.append(m)
            for c in "xyz":
                if f"{m}_{c}" not in index:
                    raise BadInput(f"{path}: line 1: marker {m!r} has no column '{m}_{c}'")
    data = [(k + 1, row) for k, row in enumerate(rows) if k > 0 and any(c.strip() for c in row)]
    if len(data) < 2:
        raise BadInput(f"{path}: fewer than 2 data rows")
    values = np.full((len(data), len(header)), np.nan)
    for i, (line, row) in enumerate(data):
        if len(row) != len(header):
            raise BadInput(f"{path}: line {line}: {len(row)} cells, expected {len(header)} like the header "
                           + ("(a decimal comma in a comma-separated file?)" if sep == "," and len(row) > len(header) else ""))
        for j, h in enumerate(header):
            values[i, j] = number(row[j], f"{path}: line {line}, column {h!r}", decimal_comma)
    t = values[:, 0]
    if np.isnan(t).any():
        i = int(np.nonzero(np.isnan(t))[0][0])
        raise BadInput(f"{path}: line {data[i][0]}, column 't': missing time")
    rec = Recording(source=path, format=f"table ({ {',': 'comma', ';': 'semicolon', chr(9): 'tab'}[sep] }-separated"
                    + (", decimal comma" if decimal_comma else "") + ")", unit=unit, t=t)
    for m in markers:
        xyz = values[:, [index[f"{m}_{c}"] for c in "xyz"]]
        rec.markers[m] = occlude_points(rec, m, xyz, zeros_missing=False)
    for b in bodies:
        block = values[:, [index[f"{b}_{c}"] for c in BODY]]
        empty = ~np.isfinite(block).all(axis=1)
        partial = empty & np.isfinite(block).any(axis=1)
        if partial.any():
            i = int(np.nonzero(partial)[0][0])
            col = next(f"{b}_{c}" for k, c in enumerate(BODY) if not np.isfinite(block[i, k]))
            raise BadInput(f"{path}: line {data[i][0]}, column {col!r}: empty while the body's other cells are given")
        pos = np.where(empty[:, None], np.nan, block[:, :3])
        q = checked_quaternions(np.where(empty[:, None], np.nan, block[:, 3:]),
                                lambda i, b=b: f"{path}: line {data[i][0]}, column '{b}_qw'")
        rec.bodies[b] = (pos, q)
        rec.occluded[b] = int(empty.sum())
        rec.zeros[b] = 0
    if len(t) > 1:
        dt = np.diff(t)
        if (dt > 0).all():
            rec.rate_hz = float(1.0 / np.median(dt))
    return rec
