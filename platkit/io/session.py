"""Recording sessions: a folder with session.yaml, commands.csv, markers.csv (or poses.csv, or a
C3D file) and optionally imu.csv. See docs/session-format.md.

``platform: none`` (or null) in session.yaml is an IMU-only recording: it has no stand, so nothing
is checked against controls and commands.csv may be absent; imu.csv is then required. imu.csv is
read by :func:`platkit.io.imu.read_imu_csv`, the one IMU reader, which repairs short gaps
(and says so in ``Session.imu_notes``) and names the file, line and column of anything else.

Units are declared in session.yaml, never guessed. Everything is converted to SI on reading:
controls with :func:`platkit.model.controls_to_si`, marker coordinates to metres, times to
seconds. Every problem is one :class:`~platkit.errors.BadSession` line naming the file, the row
(1-based data row, with the file line) or column, and what was expected.
"""
from __future__ import annotations

import csv
import io
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas

from platkit.errors import BadInput, BadSession
from platkit.io.c3d import read_c3d_markers
from platkit.io.description import load_yaml
from platkit.io.imu import DEFAULT_MAX_REPAIR_S, IMU_COLUMNS, ImuStream, read_imu_csv
from platkit.io.shipped import shipped_dir
from platkit.model import LENGTH_UNITS, PlatformSpec, controls_to_si
from platkit.plugins import get_platform

#: session.yaml keys platkit reads; any other key is a typo or a newer format, and an error.
SESSION_KEYS = (
    "platform", "description", "units", "markers", "base_markers", "mocap_rate_hz", "imu",
    "moving_link", "notes", "markers_file", "markers_time_offset", "base_link",
    "date",  # (platkit) when it was recorded, ISO 8601: orders a stand's history (platkit batch --history)
    "rigid_bodies", "rigid_body_noise",  # 6-DOF bodies (spec section 1) and (platkit) their declared noise
)
#: the seven columns of a rigid body T: T_x,T_y,T_z (origin, length unit) and T_qw..T_qz (unit quaternion)
BODY_SUFFIXES = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: a body's quaternion is unit if its norm is within this of 1 (recorders write 4 to 6 decimals); it
#: is normalised after the check
QUAT_NORM_TOL = 1e-3
#: session.yaml ``rigid_body_noise`` keys: each sigma per axis, with its unit in the name
BODY_NOISE_KEYS = {"position_mm": 1e-3, "position_m": 1.0, "rotation_deg": math.pi / 180, "rotation_rad": 1.0}
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
#: keys of session.yaml's ``imu`` mapping: the spec's rate_hz and frame, and (platkit) the
#: sensor's full scale, which flags saturated samples (platkit.io.imu)
IMU_KEYS = ("rate_hz", "frame", "gyr_range_rad_s", "acc_range_m_s2")
#: session.yaml ``platform`` values that mean "no stand" (spec: "none for an IMU-only recording")
NO_PLATFORM = ("none",)
AXES = ("x", "y", "z")


@dataclass
class Table:
    """A numeric CSV table: ``header`` names, ``data`` (rows, columns) floats, NaN for empty
    cells or 'nan'."""

    path: Path
    header: list[str]
    data: np.ndarray

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.header.index(name)]

    def where(self, row: int, column: str | None = None) -> str:
        """'file row r (line l)[ column c]' for messages; ``row`` is 0-based."""
        text = f"{self.path} row {row + 1} (line {row + 2})"
        return text + (f" column {column!r}" if column is not None else "")


@dataclass
class Session:
    """A recording session read from its folder; SI units inside.

    Attributes:
        folder: the session folder. platform: stand name or None (``platform: none`` or null in
            session.yaml, and none given: an IMU-only recording).
        spec: the stand's PlatformSpec built with the session's description, or None.
        description: the description file used (None: the stand's default).
        length_unit, time_unit: as declared in session.yaml.
        marker_names (M,), base_marker_names (B,): as declared. body_names: the rigid bodies
            declared (``rigid_bodies``); body_noise: their declared noise {'position_m',
            'rotation_rad'} (per-axis sigmas) or empty.
        mocap_rate_hz: declared rate or None. imu: the declared imu mapping or None.
        moving_link: URDF link carrying the markers, or None. notes: free text.
        command_t (N,) s; commands (N, n_u) internal units ('m' controls in metres), or None
            without a stand (command_t is still read, and its times checked, if commands.csv
            exists) or without commands.csv.
        marker_t (K,) s and markers (K, M, 3) m (NaN = occluded), base_markers (K, B, 3) m:
            the raw motion-capture stream (from markers.csv or a C3D file), or None.
        bodies: (K, B_body, 7) the rigid bodies' stream from markers.csv (origin m, unit
            quaternion; all seven NaN where occluded), or None.
        poses: the reduced table of poses.csv as a dict (controls (N, n_u), markers (N, M, 3) m,
            n_samples (N, M) or None, t (N,) or None, bodies (N, B_body, 7), n_body_samples
            (N, B_body) or None), or None.
        imu_stream: the inertial stream from imu.csv as read and repaired by
            :func:`platkit.io.imu.read_imu_csv` (times in s), or None.
        imu_t (J,) s, imu_gyr (J, 3) rad/s, imu_acc (J, 3) m/s^2: the same stream's arrays.
        imu_notes: one sentence per repair made while reading imu.csv, and per axis with
            saturated samples (empty: the file was used as it is).
    """

    folder: Path
    platform: str | None
    spec: PlatformSpec | None
    description: Path | None
    length_unit: str
    time_unit: str
    marker_names: list[str]
    base_marker_names: list[str]
    mocap_rate_hz: float | None
    imu: dict | None
    moving_link: str | None
    notes: str
    command_t: np.ndarray | None = None
    commands: np.ndarray | None = None
    marker_t: np.ndarray | None = None
    markers: np.ndarray | None = None
    base_markers: np.ndarray | None = None
    poses: dict | None = None
    imu_t: np.ndarray | None = None
    imu_gyr: np.ndarray | None = None
    imu_acc: np.ndarray | None = None
    imu_stream: ImuStream | None = None
    imu_notes: list[str] = field(default_factory=list)
    markers_source: Path | None = None
    extras: dict = field(default_factory=dict)
    body_names: list[str] = field(default_factory=list)
    body_noise: dict = field(default_factory=dict)
    bodies: np.ndarray | None = None

    @property
    def has_markers(self) -> bool:
        return self.markers is not None or self.poses is not None


# ----------------------------------------------------------------------------- CSV


def read_table(path: Path, what: str = "", quiet: bool = False) -> Table:
    """Read a CSV table of numbers with a header row. Empty cells and 'nan' are NaN; anything
    else that is not a finite number is a BadSession naming row and column.

    The body is parsed by pandas' C reader, CHUNK_ROWS rows at a time, into one (rows, columns)
    float64 array allocated once (peak memory: the table plus one chunk), so a stream of
    millions of rows reads in seconds. Where that parse stops (a cell it cannot read) or
    disagrees with the file's own count of lines and separators (a row with too few or too
    many cells, a blank line, quoting), the rest is read cell by cell from the first row it
    had not finished, and that reading names the file, row, line and column of the problem.
    Files of PROGRESS_MIN_BYTES or more say on stderr how far the reading is, from its start
    and about once a second, unless ``quiet``.
    """
    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found{' (' + what + ')' if what else ''}")
    try:
        header, body_start = _read_header(path)
        progress = _Progress(path, quiet)  # says so at once for a large file, before counting its lines
        n_lines, n_commas = _count_body(path, body_start)
        if n_lines == 0:
            raise BadSession(f"{path}: no data rows after the header")
        progress.total = n_lines
        data = np.empty((n_lines, len(header)))
        done = _parse_fast(path, header, body_start, data, progress)
        if done < n_lines:  # the rows the fast reader did fill must have their separators too
            n_commas = _count_commas(path, body_start, _offset_of_row(path, body_start, done))
        if n_commas != (len(header) - 1) * min(done, n_lines):
            done = 0  # some row has too few or too many cells (or quotes): find it cell by cell
        if done < n_lines:
            try:
                n_rows = _parse_exact(path, header, data, done, body_start, progress)
            except BadSession:
                _check_finite(path, header, data[:done], body_start)  # an earlier problem is told first
                raise
            data = data[:n_rows]
        _check_finite(path, header, data, body_start)
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise BadSession(f"{path}: cannot be read as CSV ({exc})") from None
    progress.finish()
    return Table(path, header, data)


def _check_finite(path: Path, header: list[str], data: np.ndarray, body_start: int) -> None:
    """BadSession for the first infinite cell of ``data`` (the fast reader takes 'inf' and
    1e999 for numbers), worded by the cell-by-cell reading of that row."""
    infinite = np.isinf(data)
    if infinite.any():
        r = int(np.argwhere(infinite)[0][0])
        _parse_exact(path, header, data, r, body_start, _Progress(path, quiet=True), stop=r + 1)


#: files at least this large say on stderr how far their reading is (about once a second)
PROGRESS_MIN_BYTES = 32 * 2**20
#: rows the fast reader parses at a time: the peak memory beyond the table itself, and how far
#: back the cell-by-cell reading starts when a chunk holds a cell the fast reader refuses
CHUNK_ROWS = 50_000
#: cells that the fast reader takes for NaN (the cell-by-cell reading: empty or 'nan' in any case)
NAN_CELLS = ["", "nan", "NaN", "NAN", "-nan", "-NaN"]
_BLOCK_BYTES = 16 * 2**20


def _read_header(path: Path) -> tuple[list[str], int]:
    """(header names, byte offset of the first data line); BadSession for an empty file or
    an empty or duplicated column name."""
    with path.open("rb") as fh:
        first = fh.readline()
        start = fh.tell()
        if not first.strip():
            if not fh.read().strip():
                raise BadSession(f"{path}: the file is empty; expected a header row")
            raise BadSession(f"{path}: header column 1 is empty")
    header = [h.strip() for h in next(csv.reader([first.decode("utf-8-sig")]))]
    for j, h in enumerate(header):
        if not h:
            raise BadSession(f"{path}: header column {j + 1} is empty")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise BadSession(f"{path}: header has duplicate columns {dup}")
    return header, start


def _count_body(path: Path, start: int) -> tuple[int, int]:
    """(lines, commas) of the file from byte ``start`` to its last non-blank character."""
    lines = commas = 0
    tail_newlines = 0  # newlines after the last non-blank character seen so far
    any_text = False
    with path.open("rb") as fh:
        fh.seek(start)
        while block := fh.read(_BLOCK_BYTES):
            lines += _count_byte(block, b"\n")
            commas += _count_byte(block, b",")
            stripped = block.rstrip(b" \t\r\n")
            if stripped:
                any_text = True
                tail_newlines = block.count(b"\n", len(stripped))
            else:
                tail_newlines += block.count(b"\n")
    if not any_text:
        return 0, 0
    return lines - tail_newlines + 1, commas


def _count_commas(path: Path, start: int, stop: int) -> int:
    """Commas between byte offsets ``start`` and ``stop``."""
    commas = 0
    with path.open("rb") as fh:
        fh.seek(start)
        while start < stop and (block := fh.read(min(_BLOCK_BYTES, stop - start))):
            commas += _count_byte(block, b",")
            start += len(block)
    return commas


def _count_byte(block: bytes, byte: bytes) -> int:
    """How often ``byte`` occurs in ``block`` (numpy: a few times faster than bytes.count)."""
    return int(np.count_nonzero(np.frombuffer(block, np.uint8) == byte[0]))


def _parse_fast(path: Path, header: list[str], body_start: int, data: np.ndarray, progress: "_Progress") -> int:
    """Fill ``data`` chunk by chunk with pandas' C reader, one row per line (a blank line is a
    row of NaN here, which the separator count catches); the number of rows filled before the
    first chunk it could not read (all of them: ``len(data)``). Blank lines after the last row
    are not rows."""
    done = 0
    with path.open("rb") as fh, warnings.catch_warnings():
        fh.seek(body_start)
        warnings.simplefilter("ignore")  # a row with extra cells: the separator count finds it
        try:
            chunks = pandas.read_csv(
                fh, header=None, names=header, index_col=False, dtype=np.float64, engine="c",
                keep_default_na=False, na_values=NAN_CELLS, chunksize=CHUNK_ROWS, encoding="utf-8",
                skip_blank_lines=False,
            )
            for chunk in chunks:
                rows = chunk.to_numpy(dtype=np.float64)
                if rows.shape[1] != data.shape[1]:
                    return done
                fit = min(len(rows), len(data) - done)
                if fit < len(rows) and not np.isnan(rows[fit:]).all():
                    return done
                data[done:done + fit] = rows[:fit]
                done += fit
                progress.update(done)
        except (ValueError, pandas.errors.ParserError, UnicodeDecodeError):
            pass
    return done


def _parse_exact(path: Path, header: list[str], data: np.ndarray, first: int, body_start: int,
                 progress: "_Progress", stop: int | None = None) -> int:
    """Read rows ``first``.. (0-based data rows) cell by cell into ``data``; the number of rows
    of the table (trailing blank lines are not rows). BadSession naming the row, line and
    column of the first cell that is not a finite number or NaN, and of a row whose cell count
    differs from the header's. ``stop``: read no further than this row."""
    n = len(header)
    with path.open("rb") as raw:
        raw.seek(_offset_of_row(path, body_start, first))
        text = io.TextIOWrapper(raw, encoding="utf-8", newline="")
        r = first
        blank = None  # the first of a run of blank rows: an error only if a row follows
        for row in csv.reader(text):
            if stop is not None and r >= stop:
                break
            if not row or (len(row) == 1 and not row[0].strip()):  # a blank line
                blank = (r, len(row)) if blank is None else blank
                r += 1
                continue
            if blank is not None:
                br, cells = blank
                raise BadSession(f"{path} row {br + 1} (line {br + 2}): {cells} cells, expected {n} like the header")
            if len(row) != n:
                raise BadSession(f"{path} row {r + 1} (line {r + 2}): {len(row)} cells, expected {n} like the header")
            if r >= len(data):  # more rows than lines counted: a quoted cell spans lines
                raise BadSession(f"{path} row {r + 1} (line {r + 2}): a cell spans lines; expected one row per line")
            values = data[r]
            for j, cell in enumerate(row):
                cell = cell.strip()
                if cell == "" or cell.lower() == "nan":
                    values[j] = math.nan
                    continue
                try:
                    v = float(cell)
                except ValueError:
                    raise BadSession(
                        f"{path} row {r + 1} (line {r + 2}) column {header[j]!r}: expected a number, got {cell!r}"
                    ) from None
                if not math.isfinite(v):
                    raise BadSession(
                        f"{path} row {r + 1} (line {r + 2}) column {header[j]!r}: expected a finite number, got {cell!r}"
                    )
                values[j] = v
            r += 1
            if r % CHUNK_ROWS == 0:
                progress.update(r)
        text.detach()
    if blank is not None:
        r = blank[0]
    if r == 0:
        raise BadSession(f"{path}: no data rows after the header")
    return r


def _offset_of_row(path: Path, body_start: int, row: int) -> int:
    """Byte offset of data row ``row`` (0-based), counting one row per line."""
    offset, need = body_start, row
    with path.open("rb") as fh:
        fh.seek(body_start)
        while need:
            block = fh.read(_BLOCK_BYTES)
            if not block:
                break
            k = block.count(b"\n")
            if k < need:
                need -= k
                offset += len(block)
                continue
            pos = -1
            for _ in range(need):
                pos = block.index(b"\n", pos + 1)
            return offset + pos + 1
    return offset


class _Progress:
    """'reading FILE: N% (rows of total)' on stderr for large files, at the start and about
    once a second; nothing for small files or when quiet."""

    def __init__(self, path: Path, quiet: bool, total_rows: int = 0):
        self.path, self.total = path, total_rows
        size = path.stat().st_size
        self.on = not quiet and size >= PROGRESS_MIN_BYTES
        self.t0 = self.last = time.monotonic()
        if self.on:
            print(f"reading {path}: {size / 1e6:.0f} MB", file=sys.stderr, flush=True)

    def update(self, done: int) -> None:
        now = time.monotonic()
        if self.on and now - self.last >= 1.0:
            self.last = now
            print(f"reading {self.path.name}: {100 * done / max(self.total, 1):.0f}% ({done:,} of {self.total:,} rows, "
                  f"{now - self.t0:.0f} s)", file=sys.stderr, flush=True)

    def finish(self) -> None:
        if self.on and time.monotonic() - self.t0 >= 1.0:
            print(f"reading {self.path.name}: done in {time.monotonic() - self.t0:.1f} s", file=sys.stderr, flush=True)


def check_times(table: Table, t: np.ndarray, column: str = "t") -> None:
    """Times must be present and strictly increasing: BadSession naming the row otherwise."""
    bad = np.nonzero(~np.isfinite(t))[0]
    if bad.size:
        raise BadSession(f"{table.where(int(bad[0]), column)}: the time is empty; every row needs one")
    d = np.diff(t)
    if np.any(d <= 0):
        r = int(np.nonzero(d <= 0)[0][0]) + 1
        kind = "duplicated" if d[r - 1] == 0 else "earlier than the row before (times must increase)"
        raise BadSession(f"{table.where(r, column)}: timestamp {t[r]:.9g} is {kind}")


def marker_columns(name: str) -> list[str]:
    return [f"{name}_{a}" for a in AXES]


def body_columns(name: str) -> list[str]:
    return [f"{name}_{a}" for a in BODY_SUFFIXES]


def _check_marker_header(table: Table, declared: list[str], leading: list[str], optional_suffixes=(),
                         bodies: tuple[str, ...] | list[str] = ()) -> None:
    """The header must be ``leading`` + x,y,z columns of every declared marker (+ optional
    per-marker columns) + the seven columns of every declared rigid body (+ the same optional
    columns); name the first column that is missing or undeclared."""
    allowed = set(leading)
    for m in declared:
        allowed.update(marker_columns(m))
        allowed.update(f"{m}_{s}" for s in optional_suffixes)
    for b in bodies:
        allowed.update(body_columns(b))
        allowed.update(f"{b}_{s}" for s in optional_suffixes)
    for col in table.header:
        if col not in allowed:
            stem = col.rsplit("_", 1)[0]
            if (col.endswith(("_qw", "_qx", "_qy", "_qz")) or f"{stem}_qw" in table.header) and stem not in bodies:
                raise BadSession(
                    f"{table.path}: column {col!r} is for a rigid body {stem!r} that session.yaml does not declare "
                    f"(rigid_bodies: {', '.join(bodies) or 'none'})")
            stem = col.rsplit("_", 1)[0]
            if col.endswith(("_x", "_y", "_z")) and stem not in declared:
                raise BadSession(
                    f"{table.path}: column {col!r} is for a marker {stem!r} that session.yaml does not declare "
                    f"(declared: {', '.join(declared) or 'none'})"
                )
            raise BadSession(
                f"{table.path}: unexpected column {col!r}; expected {', '.join(leading)} then "
                f"<marker>_x,_y,_z for {', '.join(declared)}"
            )
    for col in list(leading) + [c for m in declared for c in marker_columns(m)] + [c for b in bodies
                                                                                   for c in body_columns(b)]:
        if col not in table.header:
            raise BadSession(f"{table.path}: missing column {col!r}")


def _body_block(table: Table, names: list[str], scale: float) -> np.ndarray:
    """(rows, B, 7) from the seven columns of each rigid body: origin in metres, unit quaternion.

    Occluded: all seven empty. Some empty, a never-seen body, or a quaternion whose norm is not
    within QUAT_NORM_TOL of 1 is a BadSession naming the file, row and column; quaternions are
    then normalised (their sign is kept: q and -q are the same orientation)."""
    idx = np.array([[table.header.index(c) for c in body_columns(b)] for b in names], dtype=int).reshape(-1, 7)
    out = table.data[:, idx] if idx.size else np.zeros((table.data.shape[0], 0, 7))
    out = np.array(out, float)
    finite = np.isfinite(out)
    whole = np.all(finite, axis=2)
    partial = finite.any(axis=2) & ~whole
    if partial.any():
        r, k = np.argwhere(partial)[0]
        col = body_columns(names[k])[int(np.argmin(finite[r, k]))]
        raise BadSession(f"{table.where(int(r), col)}: empty while other columns of body {names[k]!r} are given; "
                         "an occluded body leaves all seven empty")
    for k, b in enumerate(names):
        if not whole[:, k].any():
            raise BadSession(f"{table.path}: rigid body {b!r} is never seen (every row empty); remove it from "
                             "session.yaml's rigid_bodies")
    norm = np.linalg.norm(np.where(whole[..., None], out[..., 3:], 1.0), axis=2)
    with np.errstate(invalid="ignore"):
        bad = np.argwhere(whole & (np.abs(norm - 1.0) > QUAT_NORM_TOL))
    if bad.size:
        r, k = bad[0]
        raise BadSession(f"{table.where(int(r), names[k] + '_qw')}: the quaternion of body {names[k]!r} has norm "
                         f"{norm[r, k]:.6g}; expected a unit quaternion (qw,qx,qy,qz, norm within {QUAT_NORM_TOL:g} "
                         "of 1)")
    out[..., :3] *= scale
    out[..., 3:] /= norm[..., None]
    return out


def _marker_block(table: Table, names: list[str], scale: float, in_place: bool = False) -> np.ndarray:
    """(rows, M, 3) metres from the x,y,z columns of ``names``. ``in_place``: where those
    columns stand side by side in that order (as a recorder writes them), the result is a view
    of ``table.data`` scaled in place, so a stream of millions of rows is not copied."""
    idx = np.array([[table.header.index(c) for c in marker_columns(m)] for m in names], dtype=int).reshape(-1, 3)
    if not idx.size:
        return np.zeros((table.data.shape[0], 0, 3))
    first = int(idx[0, 0])
    if in_place and np.array_equal(idx.ravel(), np.arange(first, first + idx.size)):
        block = table.data[:, first:first + idx.size]
        block *= scale
        return block.reshape(len(block), len(names), 3)
    return table.data[:, idx] * scale


#: no motion-capture volume is this large (m): coordinates beyond it are in another unit
LARGEST_VOLUME_M = 100.0


def _check_plausible_unit(table: Table, markers: np.ndarray, length_unit: str, names: list[str]) -> None:
    """Marker coordinates that cannot be in the declared unit: BadSession naming the column.
    Declared m but beyond 100 m: the file is in mm. Declared mm but every coordinate within
    20 mm of the origin and the whole stream within 20 mm: the file is in m."""
    if not markers.size or not np.isfinite(markers).any():
        return
    # fmax/fmin reductions skip NaN without copying the stream (millions of rows)
    hi, lo = float(np.fmax.reduce(markers, axis=None)), float(np.fmin.reduce(markers, axis=None))
    if max(hi, -lo) > LARGEST_VOLUME_M:
        with np.errstate(invalid="ignore"):
            r, k, a = np.argwhere(np.abs(markers) > LARGEST_VOLUME_M)[0]
        raise BadSession(
            f"{table.where(int(r), f'{names[k]}_{AXES[a]}')}: {markers[r, k, a] / LENGTH_UNITS[length_unit]:.6g} "
            f"{length_unit} is beyond any motion-capture volume; is the file in mm? session.yaml declares {length_unit}"
        )
    if length_unit == "mm" and markers.shape[0] > 1:
        hi, lo = hi / LENGTH_UNITS["mm"], lo / LENGTH_UNITS["mm"]
        if max(hi, -lo) < 20.0 and hi - lo < 20.0:
            raise BadSession(
                f"{table.path}: every marker coordinate is within 20 mm of the origin; the values look like "
                f"metres but session.yaml declares mm"
            )


def _check_seen(markers: np.ndarray, names: list[str], path: Path) -> None:
    finite = np.isfinite(markers)
    fx, fy, fz = finite[..., 0], finite[..., 1], finite[..., 2]  # (reductions over an axis of 3 are slow)
    whole = fx & fy & fz
    seen = whole.any(axis=0)
    for m, ok in zip(names, seen):
        if not ok:
            raise BadSession(f"{path}: marker {m!r} is never seen (every sample empty); remove it from session.yaml")
    partial = (fx | fy | fz) & ~whole
    if np.any(partial):
        r, k = np.argwhere(partial)[0]
        raise BadSession(
            f"{path} row {r + 1} (line {r + 2}): marker {names[k]!r} has some of x,y,z empty; an occluded "
            f"sample leaves all three empty"
        )


# ----------------------------------------------------------------------------- session.yaml


def _names(value, key: str, path: Path) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise BadSession(f"{path}: field {key!r} must be a list of marker names")
    names = [v.strip() for v in value]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadSession(f"{path}: field {key!r} names {dup} more than once")
    for n in names:
        if not all(ch.isalnum() or ch in "-." or ch == "_" for ch in n):
            raise BadSession(f"{path}: field {key!r}: marker name {n!r} may hold only letters, digits, '_', '-', '.'")
    return names


def _body_noise(value, path: Path) -> dict:
    """session.yaml ``rigid_body_noise`` (e.g. {position_mm: 0.1, rotation_deg: 0.05}, per-axis
    sigmas) -> {'position_m', 'rotation_rad'}, or {} when not given."""
    if value is None:
        return {}
    form = "a mapping like {position_mm: 0.1, rotation_deg: 0.05} (per-axis sigmas)"
    if not isinstance(value, dict):
        raise BadSession(f"{path}: field 'rigid_body_noise' must be {form}")
    unknown = sorted(set(value) - set(BODY_NOISE_KEYS), key=str)
    if unknown:
        raise BadSession(f"{path}: field 'rigid_body_noise' has unknown key {unknown[0]!r}; known keys: "
                         f"{', '.join(BODY_NOISE_KEYS)}")
    out = {}
    for kind in ("position", "rotation"):
        keys = [k for k in value if k.startswith(kind)]
        if len(keys) != 1:
            raise BadSession(f"{path}: field 'rigid_body_noise' needs one {kind} sigma; it must be {form}")
        v = value[keys[0]]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or not math.isfinite(v):
            raise BadSession(f"{path}: field 'rigid_body_noise.{keys[0]}' must be a positive number, got {v!r}")
        out[f"{kind}_{'m' if kind == 'position' else 'rad'}"] = float(v) * BODY_NOISE_KEYS[keys[0]]
    return out


def read_session_yaml(folder: Path) -> dict:
    """session.yaml checked field by field; returns a dict of clean values."""
    path = folder / "session.yaml"
    if folder.is_file():
        raise BadSession(f"{folder}: is a file; a session is a folder holding session.yaml")
    if not folder.is_dir():
        raise BadSession(f"{folder}: session folder not found")
    if not path.is_file():
        raise BadSession(f"{path}: file not found; a session folder needs session.yaml")
    data = load_yaml(path, error=BadSession)
    unknown = sorted(set(data) - set(SESSION_KEYS))
    if unknown:
        raise BadSession(f"{path}: unknown field {unknown[0]!r}; known fields: {', '.join(SESSION_KEYS)}")
    out: dict = {}
    platform = data.get("platform")
    if platform is not None and (not isinstance(platform, str) or not platform.strip()):
        raise BadSession(f"{path}: field 'platform' must be a stand name, or none for an IMU-only recording")
    if isinstance(platform, str) and platform.strip().lower() in NO_PLATFORM:
        platform = None  # YAML reads `none` as text; the spec means no stand
    out["platform"] = platform.strip() if isinstance(platform, str) else None
    desc = data.get("description")
    if desc is not None and not isinstance(desc, str):
        raise BadSession(f"{path}: field 'description' must be a file path relative to the folder, or null")
    out["description"] = None
    if desc:
        dpath = (folder / desc) if not Path(desc).is_absolute() else Path(desc)
        if not dpath.is_file():
            raise BadSession(f"{path}: field 'description': file {dpath} not found")
        out["description"] = dpath
    units = data.get("units")
    if units is None:
        raise BadSession(f"{path}: missing field 'units'; declare e.g. units: {{length: mm, time: s}}")
    if not isinstance(units, dict):
        raise BadSession(f"{path}: field 'units' must be a mapping like {{length: mm, time: s}}")
    extra = sorted(set(units) - {"length", "time"})
    if extra:
        raise BadSession(f"{path}: field 'units' has unknown key {extra[0]!r}; expected length and time")
    length = units.get("length")
    if length not in LENGTH_UNITS:
        raise BadSession(
            f"{path}: field 'units.length' must be one of {', '.join(sorted(LENGTH_UNITS))}, got {length!r}"
        )
    time = units.get("time")
    if time not in TIME_UNITS:
        raise BadSession(f"{path}: field 'units.time' must be one of {', '.join(TIME_UNITS)}, got {time!r}")
    out["length_unit"], out["time_unit"] = length, time
    out["markers"] = _names(data.get("markers"), "markers", path)
    out["base_markers"] = _names(data.get("base_markers"), "base_markers", path)
    both = sorted(set(out["markers"]) & set(out["base_markers"]))
    if both:
        raise BadSession(f"{path}: marker {both[0]!r} is listed in both 'markers' and 'base_markers'")
    out["rigid_bodies"] = _names(data.get("rigid_bodies"), "rigid_bodies", path)
    both = sorted(set(out["rigid_bodies"]) & set(out["markers"] + out["base_markers"]))
    if both:
        raise BadSession(f"{path}: {both[0]!r} is listed both as a marker and in 'rigid_bodies'")
    out["rigid_body_noise"] = _body_noise(data.get("rigid_body_noise"), path)
    rate = data.get("mocap_rate_hz")
    if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0 or not math.isfinite(rate)):
        raise BadSession(f"{path}: field 'mocap_rate_hz' must be a positive number, got {rate!r}")
    out["mocap_rate_hz"] = None if rate is None else float(rate)
    imu = data.get("imu")
    if imu is not None:
        if not isinstance(imu, dict):
            raise BadSession(f"{path}: field 'imu' must be null or a mapping like {{rate_hz: 200, frame: imu}}")
        unknown = sorted(set(imu) - set(IMU_KEYS), key=str)
        if unknown:
            raise BadSession(f"{path}: field 'imu' has unknown key {unknown[0]!r}; known keys: {', '.join(IMU_KEYS)}")
        for key in ("rate_hz", "gyr_range_rad_s", "acc_range_m_s2"):
            r = imu.get(key)
            if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float)) or not r > 0
                                  or not math.isfinite(r)):
                raise BadSession(f"{path}: field 'imu.{key}' must be a positive number, got {r!r}")
        if "frame" in imu and not isinstance(imu["frame"], str):
            raise BadSession(f"{path}: field 'imu.frame' must be a frame name")
    out["imu"] = imu
    for key in ("moving_link", "base_link"):
        link = data.get(key)
        if link is not None and (not isinstance(link, str) or not link.strip()):
            raise BadSession(f"{path}: field {key!r} must be a link name or null")
        out[key] = link
    notes = data.get("notes")
    out["notes"] = "" if notes is None else str(notes)
    mfile = data.get("markers_file")
    if mfile is not None and (not isinstance(mfile, str) or not mfile):
        raise BadSession(f"{path}: field 'markers_file' must be a file name in the folder, e.g. markers.c3d")
    out["markers_file"] = mfile
    off = data.get("markers_time_offset", 0.0)
    if isinstance(off, bool) or not isinstance(off, (int, float)) or not math.isfinite(off):
        raise BadSession(f"{path}: field 'markers_time_offset' must be a number of seconds, got {off!r}")
    out["markers_time_offset"] = float(off)
    return out


# ----------------------------------------------------------------------------- controls


#: a recorded control this fraction of its stroke past a limit is a reading (encoder noise, a soft
#: limit), kept with a note; further out it is an error
STROKE_TOLERANCE = 0.01


def check_controls(table: Table, spec: PlatformSpec, leading: list[str], length_unit: str,
                   notes: list[str] | None = None) -> np.ndarray:
    """Control columns of ``table`` -> (N, n_u) internal units, checked against the strokes.

    A value past a limit by at most STROKE_TOLERANCE of the stroke (a torso reading 0.350181 m
    against 0.35) is kept, and one sentence per control naming the value and the limit is
    appended to ``notes`` (default: a Python warning); further out is a BadSession.
    """
    names = spec.control_names
    expected = leading + names
    missing = [c for c in expected if c not in table.header]
    if missing:
        raise BadSession(
            f"{table.path}: missing column {missing[0]!r}; the {spec.name} stand expects columns "
            f"{', '.join(expected)} (is this a session for another stand?)"
        )
    raw = table.data[:, [table.header.index(n) for n in names]]
    for j, n in enumerate(names):
        bad = np.nonzero(~np.isfinite(raw[:, j]))[0]
        if bad.size:
            raise BadSession(f"{table.where(int(bad[0]), n)}: empty or nan; every command needs every control")
    u = controls_to_si(spec, raw, length_unit)
    for j, c in enumerate(spec.controls):
        rounding_lo, rounding_hi = 1e-9 * max(1.0, abs(c.lower)), 1e-9 * max(1.0, abs(c.upper))
        stroke = c.upper - c.lower
        slack = STROKE_TOLERANCE * stroke if np.isfinite(stroke) and stroke > 0 else 0.0
        past = (u[:, j] < c.lower - rounding_lo) | (u[:, j] > c.upper + rounding_hi)
        out = np.nonzero((u[:, j] < c.lower - rounding_lo - slack) | (u[:, j] > c.upper + rounding_hi + slack))[0]
        unit = length_unit if c.unit == "m" else c.unit
        s_file = LENGTH_UNITS[length_unit] if c.unit == "m" else 1.0
        lo, hi = c.lower / s_file, c.upper / s_file
        if out.size:
            r = int(out[0])
            hint = ""
            if c.unit == "m":
                for other, s in LENGTH_UNITS.items():
                    if other != length_unit and c.lower <= raw[r, j] * s <= c.upper:
                        hint = f"; the value fits the stroke in {other}, but session.yaml declares {length_unit}"
            raise BadSession(
                f"{table.where(r, c.name)}: {raw[r, j]:.6g} is outside the stroke [{lo:.6g}, {hi:.6g}] {unit}{hint}"
            )
        if past.any():
            rows = np.nonzero(past)[0]
            r = int(rows[np.argmax(np.maximum(c.lower - u[rows, j], u[rows, j] - c.upper))])
            limit = c.lower if u[r, j] < c.lower else c.upper
            note = (f"{table.where(r, c.name)}: {raw[r, j]:.9g} is past the limit {limit / s_file:.9g} {unit}"
                    + (f" ({rows.size} rows past a limit, this one the furthest)" if rows.size > 1 else "")
                    + f"; kept as recorded: within {STROKE_TOLERANCE:.0%} of the stroke [{lo:.6g}, {hi:.6g}] "
                    "(encoder noise or a soft limit)")
            if notes is None:
                warnings.warn(note, stacklevel=2)
            else:
                notes.append(note)
    return u


# ----------------------------------------------------------------------------- loading


def load_session(folder: str | Path, platform: str | None = None, description: str | Path | None = None,
                 spec: PlatformSpec | None = None, imu_max_repair_s: float = DEFAULT_MAX_REPAIR_S,
                 quiet: bool = False) -> Session:
    """Read and check a session folder.

    ``platform``: the stand to read it for (default: session.yaml's); a different name from
    session.yaml's is an error. ``description``: overrides session.yaml's description file.
    ``spec``: an already built stand (skips the plugin lookup; tests and simulation).
    ``imu_max_repair_s``: missing IMU cells and time gaps up to this long (s) are interpolated
    and stated in ``imu_notes``; longer ones are errors. ``quiet``: no progress on stderr while a
    large motion-capture stream is read (:func:`read_table`).
    A session without a stand (``platform: none`` and none given) needs no commands.csv, and
    nothing in it is checked against controls; it needs imu.csv.
    Raises BadSession (one line: file, row or column, what was expected).
    """
    folder = Path(folder)
    y = read_session_yaml(folder)
    ypath = folder / "session.yaml"
    name = y["platform"]
    if spec is not None:
        platform = platform or spec.name
    if platform is not None and name is not None and platform != name:
        raise BadSession(f"{ypath}: the session is for the {name!r} stand, not {platform!r}")
    name = name or platform
    desc_path = Path(description) if description is not None else y["description"]
    if spec is None and name is not None:

        options = {k: y[k] for k in ("moving_link", "base_link") if y[k]}
        try:
            spec = get_platform(name, desc_path, **options)
        except BadInput as exc:
            raise BadSession(f"{ypath}: {exc}") from None
    s = Session(
        folder=folder, platform=name, spec=spec, description=desc_path, length_unit=y["length_unit"],
        time_unit=y["time_unit"], marker_names=y["markers"], base_marker_names=y["base_markers"],
        mocap_rate_hz=y["mocap_rate_hz"], imu=y["imu"], moving_link=y["moving_link"], notes=y["notes"],
        body_names=y["rigid_bodies"], body_noise=y["rigid_body_noise"],
    )
    tscale = TIME_UNITS[s.time_unit]
    lscale = LENGTH_UNITS[s.length_unit]

    # commands
    cpath = folder / "commands.csv"
    poses_path = folder / "poses.csv"
    if spec is not None and y["platform"] is None and not cpath.is_file() and not poses_path.is_file():
        raise BadSession(
            f"{cpath}: file not found; session.yaml declares no platform (an IMU-only recording), and reading "
            f"it for the {spec.name} stand needs its command log"
        )
    if spec is None and cpath.is_file():
        _read_commands_without_stand(s, cpath, tscale)
    elif spec is not None and (cpath.is_file() or not poses_path.is_file()):
        table = read_table(cpath, "the command log")
        extra = [c for c in table.header if c not in ["t"] + spec.control_names]
        if extra:
            raise BadSession(
                f"{cpath}: column {extra[0]!r} is not a control of the {spec.name} stand; expected columns "
                f"t, {', '.join(spec.control_names)} (is this a session for another stand?)"
            )
        s.commands = check_controls(table, spec, ["t"], s.length_unit, s.extras.setdefault("control_notes", []))
        t = table.column("t") * tscale
        check_times(table, t)
        s.command_t = t

    # motion-capture markers: markers.csv, a C3D file, or the reduced poses.csv
    if y["markers_file"]:
        mpath = folder / y["markers_file"]
        if mpath.suffix.lower() == ".c3d":
            if s.body_names:
                raise BadSession(f"{ypath}: rigid bodies are not read from C3D files ({mpath.name}); give them as "
                                 "the seven columns of each body in markers.csv (or poses.csv)")

            t, xyz = read_c3d_markers(mpath, s.marker_names + s.base_marker_names)
            t = t + y["markers_time_offset"]
            s.marker_t, s.markers_source = t, mpath
            M = len(s.marker_names)
            s.markers, s.base_markers = xyz[:, :M], xyz[:, M:]
            _check_seen(xyz, s.marker_names + s.base_marker_names, mpath)
        elif mpath.suffix.lower() == ".csv":
            _read_markers_csv(s, mpath, lscale, tscale, y["markers_time_offset"], quiet)
        else:
            raise BadSession(f"{ypath}: field 'markers_file' must name a .csv or .c3d file, got {y['markers_file']!r}")
    elif (folder / "markers.csv").is_file():
        _read_markers_csv(s, folder / "markers.csv", lscale, tscale, y["markers_time_offset"], quiet)
    elif poses_path.is_file():
        _read_poses_csv(s, poses_path, lscale, tscale)
    if s.markers is not None and poses_path.is_file():  # said, so that nobody believes the other file was used
        name = s.markers_source.name if s.markers_source is not None else "the marker stream"
        s.extras.setdefault("control_notes", []).append(
            f"{folder} holds both {name} and poses.csv: {name} (the raw stream, settled by platkit) is used, "
            "poses.csv is ignored; move one out to choose")
    if s.has_markers and not s.marker_names and not s.body_names:
        raise BadSession(f"{ypath}: field 'markers' must name the markers on the moving part (or 'rigid_bodies' "
                         "the bodies measured in 6 DOF)")

    imu_path = folder / "imu.csv"
    if imu_path.is_file():
        _read_imu(s, imu_path, tscale, imu_max_repair_s)
    elif s.imu is not None:
        raise BadSession(f"{ypath}: field 'imu' declares an inertial stream but {imu_path} is missing")
    elif spec is None:
        raise BadSession(
            f"{imu_path}: file not found; session.yaml declares no platform, so this is an IMU-only recording and "
            f"needs its inertial stream (or name the stand in session.yaml's field 'platform')"
        )
    if s.commands is None and s.poses is None and s.imu_t is None:
        raise BadSession(f"{cpath}: file not found; a session needs commands.csv (or poses.csv)")
    return s


def _read_imu(s: Session, path: Path, tscale: float, max_repair_s: float) -> None:
    """imu.csv through the inertial reader (repairs stated, errors naming line and column);
    times scaled to seconds. The declared full scale, if any, flags saturated samples."""
    declared = s.imu or {}
    stream = read_imu_csv(path, max_repair_s=max_repair_s, gyr_range=declared.get("gyr_range_rad_s"),
                          acc_range=declared.get("acc_range_m_s2"), time_scale=tscale,
                          declared_rate_hz=declared.get("rate_hz"))
    s.imu_stream, s.imu_notes = stream, stream.warnings()
    s.imu_t, s.imu_gyr, s.imu_acc = stream.t, stream.gyr, stream.acc


def _read_commands_without_stand(s: Session, path: Path, tscale: float) -> None:
    """commands.csv of a session without a stand: its times are read and checked (the IMU's
    tools may use them); the control columns cannot be interpreted, only required to be
    present and numeric."""
    table = read_table(path, "the command log")
    if "t" not in table.header:
        raise BadSession(f"{path}: missing column 't'; the command log starts with the command times")
    t = table.column("t") * tscale
    check_times(table, t)
    for j, name in enumerate(table.header):
        bad = np.nonzero(~np.isfinite(table.data[:, j]))[0]
        if bad.size:
            raise BadSession(f"{table.where(int(bad[0]), name)}: empty or nan; every command needs every control")
    s.command_t = t


def _read_markers_csv(s: Session, path: Path, lscale: float, tscale: float, offset: float, quiet: bool = False) -> None:
    names = s.marker_names + s.base_marker_names
    if not s.marker_names and not s.body_names:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'markers' must name the markers of {path.name}")
    table = read_table(path, "the motion-capture stream", quiet=quiet)
    _check_marker_header(table, names, ["t"], bodies=s.body_names)
    t = table.column("t") * tscale + offset
    check_times(table, t)
    if s.body_names:  # before the markers are scaled in place
        s.bodies = _body_block(table, s.body_names, lscale)
        _check_plausible_unit(table, s.bodies[..., :3], s.length_unit, s.body_names)
    xyz = _marker_block(table, names, lscale, in_place=True)  # the table is not used after this
    _check_seen(xyz, names, path)
    _check_plausible_unit(table, xyz, s.length_unit, names)
    M = len(s.marker_names)
    s.marker_t, s.markers, s.base_markers, s.markers_source = t, xyz[:, :M], xyz[:, M:], path


def _read_poses_csv(s: Session, path: Path, lscale: float, tscale: float) -> None:
    if s.spec is None:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'platform' must name the stand that {path.name} is for")
    if not s.marker_names and not s.body_names:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'markers' must name the markers of {path.name}")
    table = read_table(path, "the settled poses")
    leading = (["t"] if "t" in table.header else []) + s.spec.control_names
    names = s.marker_names + s.base_marker_names
    _check_marker_header(table, names, leading, optional_suffixes=("n",), bodies=s.body_names)
    controls = check_controls(table, s.spec, leading[:1] if leading[:1] == ["t"] else [], s.length_unit,
                              s.extras.setdefault("control_notes", []))
    t = None
    if "t" in table.header:
        t = table.column("t") * tscale
        check_times(table, t)
    xyz = _marker_block(table, names, lscale)
    _check_seen(xyz, names, path)
    _check_plausible_unit(table, xyz, s.length_unit, names)
    n = None
    if any(f"{m}_n" in table.header for m in s.marker_names):
        n = np.zeros((len(table.data), len(s.marker_names)))
        for k, m in enumerate(s.marker_names):
            col = f"{m}_n"
            if col not in table.header:
                raise BadSession(f"{path}: missing column {col!r}; give <marker>_n for every marker or none")
            v = table.column(col)
            bad = np.nonzero(~np.isfinite(v) | (v < 0) | (v != np.round(v)))[0]
            if bad.size:
                raise BadSession(f"{table.where(int(bad[0]), col)}: expected a whole number of samples >= 0")
            n[:, k] = v
        seen = np.isfinite(xyz[:, : len(s.marker_names)]).all(axis=2)
        clash = np.argwhere(seen != (n > 0))
        if clash.size:
            r, k = clash[0]
            raise BadSession(
                f"{table.where(int(r), s.marker_names[k] + '_n')}: {int(n[r, k])} samples but the position is "
                f"{'given' if seen[r, k] else 'empty'}"
            )
    bodies = _body_block(table, s.body_names, lscale)
    _check_plausible_unit(table, bodies[..., :3], s.length_unit, s.body_names)
    M = len(s.marker_names)
    base = xyz[:, M:]
    s.poses = {"controls": controls, "markers": xyz[:, :M], "n_samples": n, "t": t, "bodies": bodies,
               "n_body_samples": _body_counts(table, s.body_names, bodies, path)}
    s.base_markers = base if base.shape[1] else None
    s.markers_source = path
    if s.command_t is not None and len(s.command_t) != len(controls):
        raise BadSession(
            f"{path}: {len(controls)} poses but commands.csv has {len(s.command_t)} rows; poses.csv has one row per command"
        )
    if t is None and s.command_t is not None:
        s.poses["t"] = s.command_t


def _body_counts(table: Table, names: list[str], bodies: np.ndarray, path: Path) -> np.ndarray | None:
    """poses.csv's optional <body>_n columns (N, B): samples averaged per body, or None when none is given."""
    if not any(f"{b}_n" in table.header for b in names):
        return None
    n = np.zeros((len(table.data), len(names)))
    seen = np.isfinite(bodies).all(axis=2)
    for k, b in enumerate(names):
        col = f"{b}_n"
        if col not in table.header:
            raise BadSession(f"{path}: missing column {col!r}; give <body>_n for every rigid body or none")
        v = table.column(col)
        bad = np.nonzero(~np.isfinite(v) | (v < 0) | (v != np.round(v)) | ((v > 0) != seen[:, k]))[0]
        if bad.size:
            r = int(bad[0])
            raise BadSession(f"{table.where(r, col)}: expected a whole number of samples, > 0 exactly where the "
                             f"body's pose is given (here {'given' if seen[r, k] else 'empty'})")
        n[:, k] = v
    return n


#: directories (os.pathsep separated) searched first for examples/sessions/<platform>/ folders
EXAMPLES_ENV = "PLATKIT_EXAMPLES"


def example_session(platform: str) -> Path:
    """The example session shipped for ``platform``: ``<platform>/`` under the directories of the
    ``PLATKIT_EXAMPLES`` variable, else under the example sessions installed with platkit (the
    repository's examples/sessions/, the package ``platkit_data.sessions``). BadSession if none."""
    searched = [Path(d) for d in os.environ.get(EXAMPLES_ENV, "").split(os.pathsep) if d]
    for folder in searched:
        if (folder / platform / "session.yaml").is_file():
            return folder / platform
    searched.append(shipped_dir("sessions"))
    if (searched[-1] / platform / "session.yaml").is_file():
        return searched[-1] / platform
    raise BadSession(
        f"no example session for the {platform!r} stand (looked for {platform}/session.yaml in "
        f"{', '.join(str(d) for d in searched)})"
    )
