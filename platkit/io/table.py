"""Numeric CSV tables (commands.csv, markers.csv, poses.csv, plan files): the chunked reader.

pandas' C reader parses the body CHUNK_ROWS rows at a time into one array allocated once; where
it stops or disagrees with the file's own count of lines and separators, the rest is read cell
by cell, and that reading names the file, row, line and column of the problem."""
from __future__ import annotations

import contextlib
import csv
import io
import math
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from platkit.errors import BadSession


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
        sep = _separator(path)
        if sep != ",":
            return _read_separated(path, sep)
        header, body_start = read_header(path)
        progress = _Progress(path, quiet)  # says so at once for a large file, before counting its lines
        mid = _split_offset(path, body_start)
        n_lines, n_commas, rows_first = _count_body(path, body_start, mid)
        if n_lines == 0:
            raise BadSession(f"{path}: no data rows after the header")
        progress.total = n_lines
        data = np.empty((n_lines, len(header)))
        done = _parse_halves(path, header, data, progress, body_start, mid, rows_first) if mid is not None else 0
        if done < n_lines:
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


def _separator(path: Path) -> str:
    """The separator of a table: ';' where its header line has one, else a tab where it has one
    and no comma, else ','."""
    with path.open("rb") as fh:
        first = fh.readline()
    if b";" in first:
        return ";"
    if b"\t" in first and b"," not in first:
        return "\t"
    return ","


def _read_separated(path: Path, sep: str) -> Table:
    """A table separated by ';' or a tab (as spreadsheets write CSV in many locales), its decimal
    mark a comma or a point: a comma in a number cell is a decimal comma. Parsed by pandas' C
    reader where the decimal mark of the first data row holds throughout and every row has the
    header's cells; else cell by cell, which names the row, line and column of the first cell
    that is not a finite number or NaN and of a row whose cell count differs from the header's
    (the same errors as a comma-separated table's)."""
    import pandas

    text = path.read_text(encoding="utf-8-sig")
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or not lines[0].strip():
        raise BadSession(f"{path}: the file is empty; expected a header row")
    header = [h.strip() for h in next(csv.reader([lines[0]], delimiter=sep))]
    for j, h in enumerate(header):
        if not h:
            raise BadSession(f"{path}: header column {j + 1} is empty")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise BadSession(f"{path}: header has duplicate columns {dup}")
    if len(lines) < 2:
        raise BadSession(f"{path}: no data rows after the header")
    n = len(header)
    body = "\n".join(lines[1:])
    decimal = "," if "," in lines[1] else "."
    data = None
    if body.count(sep) == (n - 1) * (len(lines) - 1) and '"' not in body:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                data = pandas.read_csv(io.StringIO(body), sep=sep, decimal=decimal, header=None, dtype=np.float64,
                                       engine="c", keep_default_na=False, na_values=NAN_CELLS,
                                       skip_blank_lines=False).to_numpy()
        except (ValueError, pandas.errors.ParserError):
            data = None
        if data is not None and (data.shape != (len(lines) - 1, n) or np.isinf(data).any()):
            data = None
    if data is None:
        data = np.empty((len(lines) - 1, n))
        for r, row in enumerate(csv.reader(lines[1:], delimiter=sep)):
            if len(row) != n:
                raise BadSession(f"{path} row {r + 1} (line {r + 2}): {len(row)} cells, expected {n} like the header")
            for j, cell in enumerate(row):
                cell = cell.strip()
                if cell == "" or cell.lower() == "nan":
                    data[r, j] = math.nan
                    continue
                try:
                    v = float(cell.replace(",", "."))
                except ValueError:
                    raise BadSession(
                        f"{path} row {r + 1} (line {r + 2}) column {header[j]!r}: expected a number, got {cell!r}"
                    ) from None
                if not math.isfinite(v):
                    raise BadSession(
                        f"{path} row {r + 1} (line {r + 2}) column {header[j]!r}: expected a finite number, got {cell!r}"
                    )
                data[r, j] = v
    return Table(path, header, data)


def _check_finite(path: Path, header: list[str], data: np.ndarray, body_start: int) -> None:
    """BadSession for the first infinite cell of ``data`` (the fast reader takes 'inf' and
    1e999 for numbers), worded by the cell-by-cell reading of that row. Looked for in blocks of
    _FINITE_BLOCK rows (the mask of a block stays in the cache; one of the whole table is an
    eighth of its size)."""
    for k in range(0, len(data), _FINITE_BLOCK):
        infinite = np.isinf(data[k:k + _FINITE_BLOCK])
        if infinite.any():
            r = k + int(np.argwhere(infinite)[0][0])
            _parse_exact(path, header, data, r, body_start, _Progress(path, quiet=True), stop=r + 1)


_FINITE_BLOCK = 16_384


#: files at least this large say on stderr how far their reading is (about once a second)
PROGRESS_MIN_BYTES = 32 * 2**20
#: rows the fast reader parses at a time: the peak memory beyond the table itself, and how far
#: back the cell-by-cell reading starts when a chunk holds a cell the fast reader refuses
CHUNK_ROWS = 50_000
#: cells that the fast reader takes for NaN (the cell-by-cell reading: empty or 'nan' in any case)
NAN_CELLS = ["", "nan", "NaN", "NAN", "-nan", "-NaN"]
_BLOCK_BYTES = 16 * 2**20


def read_header(path: Path) -> tuple[list[str], int]:
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


def _count_body(path: Path, start: int, split: int | None = None) -> tuple[int, int, int]:
    """(lines, commas) of the file from byte ``start`` to its last non-blank character, and the
    lines before byte ``split`` (0 without one). One pass, read in _COUNT_BYTES blocks into one
    buffer (counted in the cache: 65 -> 36 ms for 291 MB, 2026-11-25)."""
    lines = commas = before = 0
    buf = bytearray(_COUNT_BYTES)
    view = np.frombuffer(buf, np.uint8)
    hit = np.empty(_COUNT_BYTES, bool)
    pos = start
    with path.open("rb", buffering=0) as fh:
        fh.seek(start)
        while n := fh.readinto(buf):
            v, h = view[:n], hit[:n]
            np.equal(v, 10, out=h)  # b"\n"
            lines += int(np.count_nonzero(h))
            if split is not None and pos < split <= pos + n:
                before = lines - int(np.count_nonzero(h[split - pos:]))
            np.equal(v, 44, out=h)  # b","
            commas += int(np.count_nonzero(h))
            pos += n
    tail_newlines, any_text = _blank_tail(path, start)
    if not any_text:
        return 0, 0, 0
    return lines - tail_newlines + 1, commas, before


def _blank_tail(path: Path, start: int) -> tuple[int, bool]:
    """(newlines after the last non-blank character of the file from byte ``start``, whether
    there is one), read backwards from the end."""
    newlines = 0
    with path.open("rb") as fh:
        end = fh.seek(0, io.SEEK_END)
        while end > start:
            begin = max(start, end - _COUNT_BYTES)
            fh.seek(begin)
            block = fh.read(end - begin)
            stripped = block.rstrip(b" \t\r\n")
            if stripped:
                return newlines + block.count(b"\n", len(stripped)), True
            newlines += block.count(b"\n")
            end = begin
    return newlines, False


_COUNT_BYTES = 2**20


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


class _Range(io.RawIOBase):
    """The bytes of a file from ``start`` to ``stop``, as a file pandas can read from."""

    def __init__(self, path: Path, start: int, stop: int | None):
        self._fh = path.open("rb")
        self._fh.seek(start)
        self._left = None if stop is None else stop - start

    def readable(self) -> bool:
        return True

    def readinto(self, buffer) -> int:
        view = memoryview(buffer)
        if self._left is not None:
            view = view[: self._left]
        n = self._fh.readinto(view)
        if self._left is not None:
            self._left -= n
        return n

    def close(self) -> None:
        self._fh.close()
        super().close()


#: files at least this large are parsed as two halves at once (pandas' tokenizer releases the
#: GIL): about 1.6x faster on two cores; any half that does not read cleanly falls back to one pass
PARALLEL_MIN_BYTES = 16 * 2**20


def _split_offset(path: Path, body_start: int) -> int | None:
    """The byte offset of the line at which a body of PARALLEL_MIN_BYTES or more is split in two
    halves (the first line that starts after its middle), or None (too small to split)."""
    size = path.stat().st_size
    if size - body_start < PARALLEL_MIN_BYTES:
        return None
    with path.open("rb") as fh:
        fh.seek(body_start + (size - body_start) // 2)
        fh.readline()
        return fh.tell()


def _parse_halves(path: Path, header: list[str], data: np.ndarray, progress: _Progress, body_start: int, mid: int,
                  rows_first: int) -> int:
    """Fill ``data`` from two halves of the body, split at byte ``mid`` (the start of a line;
    ``rows_first`` lines before it), in two threads; ``len(data)`` when both read cleanly, else
    0 (the caller reads it in one pass, which finds the problem)."""
    if len(data) < 2 * CHUNK_ROWS or not 0 < rows_first < len(data):
        return 0
    parts = [(body_start, mid, data[:rows_first]), (mid, None, data[rows_first:])]
    counts = [0, 0]
    lock = threading.Lock()

    def read(k: int) -> None:
        start, stop, rows = parts[k]

        def update(done: int) -> None:
            with lock:
                counts[k] = done
                progress.update(sum(counts))

        counts[k] = _parse_fast(path, header, start, rows, progress, stop=stop, update=update, quiet_warnings=False)

    threads = [threading.Thread(target=read, args=(k,), daemon=True) for k in (0, 1)]
    # the halves' warnings are left out here, once, by this thread: warnings.catch_warnings saves and
    # restores the process's one filter list, so one entered in each thread (each restoring what the
    # other had set) could leave 'ignore' in force after the read and every later warning unsaid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a row with extra cells: the separator count finds it
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    return len(data) if counts == [rows_first, len(data) - rows_first] else 0


def _parse_fast(path: Path, header: list[str], body_start: int, data: np.ndarray, progress: _Progress,
                stop: int | None = None, update=None, quiet_warnings: bool = True) -> int:
    """Fill ``data`` chunk by chunk with pandas' C reader, one row per line (a blank line is a
    row of NaN here, which the separator count catches); the number of rows filled before the
    first chunk it could not read (all of them: ``len(data)``). Blank lines after the last row
    are not rows. ``stop``: read the file only up to this byte offset; ``update(rows)``: the
    progress callback (default ``progress.update``). ``quiet_warnings``: pandas' warnings left
    out here (False in a thread of :func:`_parse_halves`, which leaves them out for both)."""
    import pandas  # here, not at the top: a verb that reads no table (platkit orient) need not import it

    done = 0
    update = progress.update if update is None else update
    with io.BufferedReader(_Range(path, body_start, stop), 1 << 20) as fh, contextlib.ExitStack() as quiet:
        if quiet_warnings:
            quiet.enter_context(warnings.catch_warnings())
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
                update(done)
        except (ValueError, pandas.errors.ParserError, UnicodeDecodeError):
            pass
    return done


def _parse_exact(path: Path, header: list[str], data: np.ndarray, first: int, body_start: int,
                 progress: _Progress, stop: int | None = None) -> int:
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
