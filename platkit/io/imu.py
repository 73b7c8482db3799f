"""The inertial stream: reading ``imu.csv`` with checks, and writing it.

``imu.csv`` (spec section 1): ``t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z``, seconds, rad/s and m/s^2,
in the sensor's own axes. Extra columns are ignored; a row with more or fewer cells than the
header is an error (a cut line is not a missing sample). This is the one IMU reader:
:func:`platkit.io.session.load_session` reads imu.csv through it. Every problem is either a one-line
:class:`~platkit.errors.BadSession` naming the file, line and column, or a repair that is
stated in :attr:`ImuStream.repairs` (short runs of missing cells and short time gaps are
linearly interpolated; anything longer than ``max_repair_s`` is an error). Saturated samples are
never repaired: they are flagged in :attr:`ImuStream.saturated` and reported. A stream plainly
not in the spec's units (an accelerometer in g, a gyro in deg/s, times in ms) is refused by
:func:`check_units`, naming the file and column and what was expected.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadSession
from platkit.io.atomic import atomic_write_text
from platkit.io.session_checks import MOCAP_RATE_FACTOR, implausible

IMU_COLUMNS = ("t", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")

#: missing cells and time gaps up to this long are interpolated (and reported); longer ones fail
DEFAULT_MAX_REPAIR_S = 0.05

#: a run of at least this many equal samples at a column's extreme value is a clipping plateau
SATURATION_RUN = 3

G_STANDARD = 9.80665  # m/s^2


@dataclass
class ImuStream:
    """An inertial recording on a uniform clock.

    ``t`` (N,) s; ``gyr`` (N, 3) rad/s; ``acc`` (N, 3) m/s^2, sensor axes. ``saturated`` (N, 6)
    bool marks samples at a clipping limit (gyro x, y, z, accel x, y, z). ``repairs``: one
    sentence per repair made while reading (empty when the file was used as it is). ``notes``:
    one sentence per check the stream could not be judged by, or that the user answered
    (:func:`check_units`).
    """

    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    saturated: np.ndarray = None
    repairs: list[str] = field(default_factory=list)
    source: str = ""
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.t = np.asarray(self.t, float)
        self.gyr = np.asarray(self.gyr, float)
        self.acc = np.asarray(self.acc, float)
        if self.saturated is None:
            self.saturated = np.zeros((len(self.t), 6), bool)

    @property
    def n(self) -> int:
        return len(self.t)

    @property
    def dt(self) -> float:
        """The sampling interval, s (median of the time steps)."""
        return float(np.median(np.diff(self.t))) if self.n > 1 else float("nan")

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt

    def warnings(self) -> list[str]:
        """Repairs, saturation and the units checks' notes, as sentences for a report."""
        out = list(self.repairs) + list(self.notes)
        names = IMU_COLUMNS[1:]
        for j in range(6):
            k = int(self.saturated[:, j].sum())
            if k:
                out.append(f"{self.source or 'imu'}: {k} samples of {names[j]} at the sensor's clipping limit "
                           f"({np.abs(self.gyr if j < 3 else self.acc)[:, j % 3].max():.4g}); they are kept as measured")
        return out

    def slice(self, start: int, stop: int) -> ImuStream:
        return ImuStream(self.t[start:stop], self.gyr[start:stop], self.acc[start:stop],
                         self.saturated[start:stop], list(self.repairs), self.source, list(self.notes))


def _line(row_index: int) -> int:
    """File line of data row ``row_index`` (0-based; the header is line 1)."""
    return row_index + 2


def _fast_rows(body: str, n_columns: int, cols: list[int]) -> np.ndarray | None:
    """(N, 7) the IMU columns of a clean file's data rows, parsed by numpy's C reader (np.loadtxt:
    no pandas to import, which would cost the verb's start-up more than the parse), or where a
    cell is empty, by pandas' C reader (empty and 'nan' cells NaN); None where a line has another
    number of cells than the header (or is blank), a cell is not a plain number (NaN only as an
    empty or 'nan' cell outside ``t``), or anything else the cell-by-cell reader must name or
    repair."""
    if not body.strip():
        return None
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", dtype=float, ndmin=2, comments=None, encoding=None)
    except ValueError:  # an empty cell, text, or a row with another number of cells
        import pandas  # here, not at the top: only a file with gaps needs it

        try:
            data = pandas.read_csv(io.StringIO(body), header=None, dtype=float, engine="c", keep_default_na=False,
                                   na_values=["", "nan", "NaN", "NAN"], skip_blank_lines=False).to_numpy()
        except (ValueError, pandas.errors.ParserError):  # a longer row than the first is a ParserError
            return None
    if data.ndim != 2 or data.shape[1] != n_columns:
        return None
    # a shorter row comes back padded with NaN: every row has all its cells only if the commas add up
    if body.count(",") != data.shape[0] * (n_columns - 1):
        return None
    data = data[:, cols]
    if np.isinf(data).any() or np.isnan(data[:, 0]).any():
        return None
    return data


def _checked_rows(path: Path, lines: list[list[str]], header: list[str], cols: list[int]) -> list[list[float]]:
    """The IMU columns of every data row (``lines``: the rows after the header), cell by cell: a
    BadSession names the line and column of the first cell that is not a number."""
    rows = []
    for i, row in enumerate(lines):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):  # a cut or merged line, not a missing sample: never repaired
            raise BadSession(f"{path}: line {_line(i)}: {len(row)} cells, expected {len(header)} like the header")
        values = []
        for name, c in zip(IMU_COLUMNS, cols):
            cell = row[c].strip()
            if cell == "" or cell.lower() == "nan":
                if name == "t":
                    raise BadSession(f"{path}: line {_line(i)}, column 't': missing time")
                values.append(np.nan)
                continue
            try:
                v = float(cell)
            except ValueError:
                raise BadSession(f"{path}: line {_line(i)}, column {name!r}: expected a number, got {cell!r}") from None
            if not np.isfinite(v):
                raise BadSession(f"{path}: line {_line(i)}, column {name!r}: {cell!r} is not a finite number")
            values.append(v)
        rows.append(values)
    return rows


def read_imu_csv(path: str | Path, max_repair_s: float = DEFAULT_MAX_REPAIR_S,
                 gyr_range: float | None = None, acc_range: float | None = None,
                 time_scale: float = 1.0, declared_rate_hz: float | None = None) -> ImuStream:
    """Read and check ``imu.csv``.

    ``time_scale``: seconds per unit of the file's ``t`` (1e-3 for a session in ms); the stream,
    ``max_repair_s`` and the messages about times are in seconds.

    ``gyr_range`` (rad/s) and ``acc_range`` (m/s^2): the sensor's full scale, if known; samples at
    99.9 % of it or beyond are flagged saturated. Without them, a run of SATURATION_RUN or more
    equal samples at a column's largest magnitude is flagged.
    Raises BadSession (file, line, column) for a missing file or column, text that is not a
    number, time that does not increase, or missing data / gaps longer than ``max_repair_s``,
    and (:func:`check_units`) for a stream plainly not in s, rad/s and m/s^2; ``declared_rate_hz``:
    the rate session.yaml declares for the IMU, if any.
    """
    path = Path(path)
    try:  # utf-8-sig: a byte-order mark (spreadsheet exports) is not part of the first column's name
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise BadSession(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise BadSession(f"{path}: cannot be read as CSV ({exc})") from None
    first, _, body = text.partition("\n")
    try:
        header = [h.strip() for h in next(csv.reader([first]), [])]
    except csv.Error as exc:
        raise BadSession(f"{path}: cannot be read as CSV ({exc})") from None
    if not text.strip():
        raise BadSession(f"{path}: empty file, expected the header {','.join(IMU_COLUMNS)}")
    index = {}
    for name in IMU_COLUMNS:
        if name not in header:
            raise BadSession(f"{path}: line 1: missing column {name!r} (expected {','.join(IMU_COLUMNS)})")
        if header.count(name) > 1:
            raise BadSession(f"{path}: line 1: column {name!r} appears {header.count(name)} times")
        index[name] = header.index(name)
    cols = [index[n] for n in IMU_COLUMNS]
    rows: np.ndarray | list[list[float]] | None = _fast_rows(body, len(header), cols)
    if rows is None:  # something to name or repair: the cell-by-cell reader says where
        try:
            lines = list(csv.reader(io.StringIO(body, newline="")))
        except csv.Error as exc:
            raise BadSession(f"{path}: cannot be read as CSV ({exc})") from None
        rows = _checked_rows(path, lines, header, cols)
    if len(rows) < 2:
        raise BadSession(f"{path}: fewer than 2 data rows")
    data = np.asarray(rows, float)
    stream = check_stream(data[:, 0] * time_scale, data[:, 1:4], data[:, 4:7], str(path), max_repair_s, gyr_range,
                          acc_range)
    check_units(stream, str(path), declared_rate_hz)
    return stream


def check_stream(t, gyr, acc, source: str = "imu", max_repair_s: float = DEFAULT_MAX_REPAIR_S,
                 gyr_range: float | None = None, acc_range: float | None = None) -> ImuStream:
    """Check and repair arrays as :func:`read_imu_csv` does (NaN marks a missing cell).

    Lines in messages count a header line, as in the file.
    """
    t = np.asarray(t, float)
    data = np.column_stack([gyr, acc]).astype(float)
    repairs: list[str] = []
    dts = np.diff(t)
    bad = np.nonzero(dts <= 0)[0]
    if bad.size:
        i = bad[0] + 1
        what = "repeats" if dts[bad[0]] == 0 else "goes back"
        raise BadSession(f"{source}: line {_line(i)}, column 't': time {what} ({t[i]:.6g} s after {t[i - 1]:.6g} s); "
                         "expected strictly increasing time")
    dt = float(np.median(dts))
    # missing cells: interpolate short runs, fail on long ones
    names = IMU_COLUMNS[1:]
    for j in range(6):
        miss = np.isnan(data[:, j])
        if not miss.any():
            continue
        starts = np.nonzero(miss & ~np.r_[False, miss[:-1]])[0]
        ends = np.nonzero(miss & ~np.r_[miss[1:], False])[0]
        for s, e in zip(starts, ends):
            if s == 0 or e == len(t) - 1:
                raise BadSession(f"{source}: line {_line(s)}, column {names[j]!r}: missing value at the "
                                 "start or end of the recording (cannot be interpolated)")
            span = t[e + 1] - t[s - 1]
            if span > max_repair_s + dt:
                raise BadSession(f"{source}: line {_line(s)}, column {names[j]!r}: {e - s + 1} missing values "
                                 f"({span:.3g} s), more than the {max_repair_s:g} s that may be interpolated")
        good = ~miss
        data[miss, j] = np.interp(t[miss], t[good], data[good, j])
        repairs.append(f"{source}: column {names[j]!r}: {int(miss.sum())} missing values in {len(starts)} short "
                       f"runs interpolated linearly (first at line {_line(starts[0])})")
    # time gaps: fill short ones on the sampling grid, fail on long ones
    gaps = np.nonzero(dts > 1.5 * dt)[0]
    if gaps.size:
        big = [g for g in gaps if dts[g] > max_repair_s + dt]
        if big:
            g = big[0]
            raise BadSession(f"{source}: line {_line(g + 1)}, column 't': a gap of {dts[g]:.4g} s in time "
                             f"(sampling interval {dt:.4g} s), more than the {max_repair_s:g} s that may be interpolated")
        pieces = []
        prev = 0
        for g in gaps:
            n_fill = int(round(dts[g] / dt)) - 1
            pieces.append(t[prev:g + 1])
            if n_fill > 0:
                pieces.append(t[g] + dts[g] * np.arange(1, n_fill + 1) / (n_fill + 1))
            prev = g + 1
        pieces.append(t[prev:])
        new_t = pieces
        t_full = np.concatenate(new_t)
        data = np.column_stack([np.interp(t_full, t, data[:, j]) for j in range(6)])
        repairs.append(f"{source}: {len(gaps)} short time gaps (longest {dts[gaps].max():.4g} s, first at line "
                       f"{_line(gaps[0] + 1)}) filled with {len(t_full) - len(t)} linearly interpolated samples")
        t = t_full
    saturated = saturation_mask(data, gyr_range, acc_range)
    return ImuStream(t, data[:, :3], data[:, 3:], saturated, repairs, source)


def saturation_mask(data: np.ndarray, gyr_range: float | None = None, acc_range: float | None = None) -> np.ndarray:
    """(N, 6) bool: samples at the clipping limit. ``data`` (N, 6): gyro then accel columns."""
    out = np.zeros(data.shape, bool)
    for j in range(6):
        col = data[:, j]
        full_scale = gyr_range if j < 3 else acc_range
        if full_scale is not None:
            out[:, j] = np.abs(col) >= 0.999 * full_scale
            continue
        peak = np.abs(col).max()
        if peak == 0:
            continue
        at_peak = np.abs(col) == peak
        if at_peak.sum() < SATURATION_RUN:
            continue
        # only a plateau counts: a run of equal extreme samples, which noise alone does not make
        run = np.convolve(at_peak.astype(int), np.ones(SATURATION_RUN, int), mode="valid") == SATURATION_RUN
        if run.any():
            out[:, j] = at_peak
    return out


def format_imu_csv(t, gyr, acc) -> str:
    """imu.csv text. ``t`` (N,) s, ``gyr`` (N, 3) rad/s, ``acc`` (N, 3) m/s^2."""
    arr = np.column_stack([t, gyr, acc])
    lines = [",".join(IMU_COLUMNS)]
    lines += [",".join(f"{v:.9g}" for v in row) for row in arr]
    return "\n".join(lines) + "\n"


def write_imu_csv(path: str | Path, t, gyr, acc) -> None:
    """Write ``imu.csv`` atomically (see :func:`format_imu_csv`)."""

    atomic_write_text(path, format_imu_csv(t, gyr, acc))


# ---------------------------------------------------------------------------- units
#: the accelerometer's median magnitude (m/s^2) an IMU on earth reads: about g (9.81) at rest, and
#: the specific force of a platform's motion averages out around it
ACC_NORM_RANGE = (0.5 * G_STANDARD, 2.0 * G_STANDARD)
#: fastest rotation a gyro's full scale reaches (rad/s): 2000 deg/s, the largest common range
GYRO_MAX_RAD_S = math.radians(2000.0)
#: a gyro in deg/s turns the accelerometer's gravity pi/180 as fast as the rad/s it claims: the
#: fitted ratio within this factor of pi/180 is taken for deg/s
DEG_RATIO_TOLERANCE = 2.0
#: the rotation (rad, in the file's gyro units) the tilting needs to sum to before the ratio is judged
MIN_TILT_FOR_RATIO = 0.3
#: ... and the share of the gravity direction's changes the gyro's rotations must explain (R^2 of
#: the fitted ratio): at rest, or where the accelerometer reads mostly the motion's own
#: acceleration (translations, fast turns), the ratio means nothing and is not judged
MIN_R2_FOR_RATIO = 0.3
#: sampling rates (Hz) outside which an IMU's times are implausible
MIN_RATE_HZ = 1.0
MAX_RATE_HZ = 1e5


def gravity_turn_fit(t: np.ndarray, gyr: np.ndarray, acc: np.ndarray,
                     window_s: float = 0.5) -> tuple[float, float, float]:
    """(k, tilt, r2): how fast the gyro turns the accelerometer's gravity direction, as a ratio.

    The stream is cut into windows of ``window_s``; between consecutive windows the mean
    accelerometer direction u changes by du ~ -k r x u, r the rotation the gyro integrated
    between the windows' middles (sensor axes). k is 1 for a gyro in rad/s (pi/180 for one in
    deg/s); ``tilt`` (rad in the gyro's units) is the rotation that could turn gravity; ``r2``
    the share of the changes du the fit explains. k means something only where both are large
    enough (:data:`MIN_TILT_FOR_RATIO`, :data:`MIN_R2_FOR_RATIO`); nan where the stream is
    shorter than three windows.
    """
    n = len(t)
    dt = float(np.median(np.diff(t)))
    k = max(2, int(round(window_s / dt)))
    m = n // k
    if m < 3:
        return float("nan"), 0.0, 0.0
    u = acc[:m * k].reshape(m, k, 3).mean(axis=1)
    u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-300)
    cum = np.concatenate([np.zeros((1, 3)), np.cumsum(gyr[1:m * k] * np.diff(t[:m * k])[:, None], axis=0)])
    mid = cum[np.arange(m) * k + k // 2]
    r = np.diff(mid, axis=0)
    a = np.cross(r, u[:-1])
    du = np.diff(u, axis=0)
    s = float(np.sum(a * a))
    tilt = math.sqrt(s)
    if s <= 0:
        return float("nan"), 0.0, 0.0
    ratio = float(-np.sum(du * a) / s)
    total = float(np.sum(du * du))
    r2 = 1.0 - float(np.sum((du + ratio * a) ** 2)) / total if total > 0 else 0.0
    return ratio, tilt, r2


def gravity_turn_ratio(t: np.ndarray, gyr: np.ndarray, acc: np.ndarray, window_s: float = 0.5) -> tuple[float, float]:
    """(k, tilt) of :func:`gravity_turn_fit`, k nan where the tilt is too small to judge."""
    k, tilt, _ = gravity_turn_fit(t, gyr, acc, window_s)
    return (k if tilt >= MIN_TILT_FOR_RATIO else float("nan")), tilt


def check_units(stream: ImuStream, source: str, declared_rate_hz: float | None = None) -> None:
    """Stop with one line naming the file and column where the stream is plainly not in the
    spec's units (seconds, rad/s, m/s^2): an accelerometer in g (median magnitude about 1), a gyro
    in deg/s (faster than any gyro's full scale, or turning gravity pi/180 as fast as it claims),
    times in ms (steps 1000 times the declared ``rate_hz``, or an implausibly slow rate).

    Each is a plausibility check the user can answer (``--units-checked``: the stream is kept
    as written, with a note; the refusal says so). The gravity ratio is judged only where the
    stream can tell (:func:`gravity_turn_fit`: enough rotation, and rotations that explain the
    gravity direction's turning); where the ratio would say deg/s but the stream cannot tell (at
    rest, translations, fast turns) it passes with a note in ``stream.notes``."""
    dt = stream.dt
    rate = 1.0 / dt
    if declared_rate_hz is not None and declared_rate_hz > 0:
        ratio = declared_rate_hz / rate
        if not 1 / MOCAP_RATE_FACTOR <= ratio <= MOCAP_RATE_FACTOR:  # the same rule as mocap_rate_hz's
            hint = ""
            if 300 <= ratio <= 3000:
                hint = "; the times look like milliseconds: write seconds, or declare units: {time: ms} in session.yaml"
            elif 1 / 3000 <= ratio <= 1 / 300:
                hint = "; the times look like seconds in a session declared in milliseconds"
            else:
                hint = "; correct the imu entry's rate_hz or the times"
            implausible(f"{source}: column 't': the median time step is {dt:.4g} s ({rate:.4g} Hz) but session.yaml "
                        f"declares the IMU at rate_hz {declared_rate_hz:g}; expected times in seconds at that "
                        f"rate{hint}", stream.notes)
    elif rate < MIN_RATE_HZ:
        implausible(f"{source}: column 't': the median time step is {dt:.4g} s ({rate:.3g} Hz), expected seconds "
                    f"at an IMU's rate (at least {MIN_RATE_HZ:g} Hz); times in milliseconds? write seconds, or "
                    "declare units: {time: ms} in session.yaml", stream.notes)
    elif rate > MAX_RATE_HZ:
        implausible(f"{source}: column 't': the median time step is {dt:.4g} s ({rate:.3g} Hz), faster than an "
                    f"IMU samples (at most {MAX_RATE_HZ:g} Hz); seconds in a session declared in milliseconds?",
                    stream.notes)
    norm = float(np.median(np.linalg.norm(stream.acc, axis=1)))
    if not ACC_NORM_RANGE[0] <= norm <= ACC_NORM_RANGE[1]:
        what = " (that is g: multiply by 9.80665)" if 0.5 <= norm <= 2.0 else ""
        implausible(f"{source}: columns 'acc_x', 'acc_y', 'acc_z': the accelerometer's median magnitude is "
                    f"{norm:.4g}{what}; expected m/s^2, about 9.81 at rest", stream.notes)
    # the 99th percentile: a few samples of a step in a synthetic stream are not a gyro's range
    peak = float(np.percentile(np.linalg.norm(stream.gyr, axis=1), 99.0))
    if peak > GYRO_MAX_RAD_S:
        implausible(f"{source}: columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro reads up to {peak:.4g}, faster than "
                    f"any gyro's range in rad/s ({GYRO_MAX_RAD_S:.3g} rad/s = 2000 deg/s); expected rad/s (deg/s? "
                    "multiply by pi/180)", stream.notes)
        return
    k, tilt, r2 = gravity_turn_fit(stream.t, stream.gyr, stream.acc)
    deg = math.pi / 180.0
    looks_deg = bool(np.isfinite(k) and deg / DEG_RATIO_TOLERANCE <= k <= deg * DEG_RATIO_TOLERANCE)
    if not looks_deg:
        return
    if not (tilt >= MIN_TILT_FOR_RATIO and r2 >= MIN_R2_FOR_RATIO):
        why = (f"it turns {tilt:.2g} rad in all (at least {MIN_TILT_FOR_RATIO:g} needed)" if tilt < MIN_TILT_FOR_RATIO
               else f"its rotations explain {max(r2, 0.0):.0%} of the gravity direction's changes (at least "
                    f"{MIN_R2_FOR_RATIO:.0%} needed: at rest, or where the accelerometer reads mostly the "
                    "motion's own acceleration, the ratio means nothing)")
        stream.notes.append(f"{source}: columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro's unit is taken as rad/s, as "
                            f"the spec says: the ratio of its rotations to the gravity direction's turning ({1 / k:.3g}) "
                            f"would say deg/s, but the stream cannot tell: {why}")
    else:
        implausible(f"{source}: columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro turns the accelerometer's gravity "
                    f"{1 / k:.3g} times too fast for rad/s (that is deg/s: multiply by pi/180); expected rad/s",
                    stream.notes)
