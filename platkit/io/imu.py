"""The inertial stream: reading ``imu.csv`` with checks, writing it, and reading BROAD trials.

``imu.csv`` (spec section 1): ``t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z``, seconds, rad/s and m/s^2,
in the sensor's own axes. Extra columns are ignored; a row with more or fewer cells than the
header is an error (a cut line is not a missing sample). This is the one IMU reader:
:func:`platkit.io.session.load_session` reads imu.csv through it. Every problem is either a one-line
:class:`~platkit.errors.BadSession` naming the file, line and column, or a repair that is
stated in :attr:`ImuStream.repairs` (short runs of missing cells and short time gaps are
linearly interpolated; anything longer than ``max_repair_s`` is an error). Saturated samples are
never repaired: they are flagged in :attr:`ImuStream.saturated` and reported.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadSession
from platkit.io.atomic import atomic_write_text

IMU_COLUMNS = ("t", "gyr_x", "gyr_y", "gyr_z", "acc_x", "acc_y", "acc_z")

#: missing cells and time gaps up to this long are interpolated (and reported); longer ones fail
DEFAULT_MAX_REPAIR_S = 0.05

#: a run of at least this many equal samples at a column's extreme value is a clipping plateau
SATURATION_RUN = 3


@dataclass
class ImuStream:
    """An inertial recording on a uniform clock.

    ``t`` (N,) s; ``gyr`` (N, 3) rad/s; ``acc`` (N, 3) m/s^2, sensor axes. ``saturated`` (N, 6)
    bool marks samples at a clipping limit (gyro x, y, z, accel x, y, z). ``repairs``: one
    sentence per repair made while reading (empty when the file was used as it is).
    """

    t: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    saturated: np.ndarray = None
    repairs: list[str] = field(default_factory=list)
    source: str = ""

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
        """Repairs and saturation, as sentences for a report."""
        out = list(self.repairs)
        names = IMU_COLUMNS[1:]
        for j in range(6):
            k = int(self.saturated[:, j].sum())
            if k:
                out.append(f"{self.source or 'imu'}: {k} samples of {names[j]} at the sensor's clipping limit "
                           f"({np.abs(self.gyr if j < 3 else self.acc)[:, j % 3].max():.4g}); they are kept as measured")
        return out

    def slice(self, start: int, stop: int) -> "ImuStream":
        return ImuStream(self.t[start:stop], self.gyr[start:stop], self.acc[start:stop],
                         self.saturated[start:stop], list(self.repairs), self.source)


def _line(row_index: int) -> int:
    """File line of data row ``row_index`` (0-based; the header is line 1)."""
    return row_index + 2


def read_imu_csv(path: str | Path, max_repair_s: float = DEFAULT_MAX_REPAIR_S,
                 gyr_range: float | None = None, acc_range: float | None = None,
                 time_scale: float = 1.0) -> ImuStream:
    """Read and check ``imu.csv``.

    ``time_scale``: seconds per unit of the file's ``t`` (1e-3 for a session in ms); the stream,
    ``max_repair_s`` and the messages about times are in seconds.

    ``gyr_range`` (rad/s) and ``acc_range`` (m/s^2): the sensor's full scale, if known; samples at
    99.9 % of it or beyond are flagged saturated. Without them, a run of SATURATION_RUN or more
    equal samples at a column's largest magnitude is flagged.
    Raises BadSession (file, line, column) for a missing file or column, text that is not a
    number, time that does not increase, or missing data / gaps longer than ``max_repair_s``.
    """
    path = Path(path)
    try:  # utf-8-sig: a byte-order mark (spreadsheet exports) is not part of the first column's name
        with path.open(newline="", encoding="utf-8-sig") as fh:
            lines = list(csv.reader(fh))
    except FileNotFoundError:
        raise BadSession(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise BadSession(f"{path}: cannot be read as CSV ({exc})") from None
    if not lines:
        raise BadSession(f"{path}: empty file, expected the header {','.join(IMU_COLUMNS)}")
    header = [h.strip() for h in lines[0]]
    index = {}
    for name in IMU_COLUMNS:
        if name not in header:
            raise BadSession(f"{path}: line 1: missing column {name!r} (expected {','.join(IMU_COLUMNS)})")
        if header.count(name) > 1:
            raise BadSession(f"{path}: line 1: column {name!r} appears {header.count(name)} times")
        index[name] = header.index(name)
    cols = [index[n] for n in IMU_COLUMNS]
    rows = []
    for i, row in enumerate(lines[1:]):
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
    if len(rows) < 2:
        raise BadSession(f"{path}: fewer than 2 data rows")
    data = np.array(rows, float)
    return check_stream(data[:, 0] * time_scale, data[:, 1:4], data[:, 4:7], str(path), max_repair_s, gyr_range, acc_range)


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


@dataclass
class BroadTrial:
    """One BROAD trial: the IMU stream, the optical truth and the scoring mask.

    ``q_earth_from_imu`` (N, 4) w x y z in ENU, NaN where the optical system lost the body;
    ``movement`` (N,) bool: the samples the benchmark scores.
    """

    name: str
    imu: ImuStream
    q_earth_from_imu: np.ndarray
    movement: np.ndarray
    rate_hz: float


def read_broad(path: str | Path) -> BroadTrial:
    """Read a BROAD HDF5 trial (fields imu_gyr, imu_acc, opt_quat, movement, attribute sampling_rate)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise BadSession(f"{path}: not an HDF5 file ({exc})") from None
    with f:
        for key in ("imu_gyr", "imu_acc", "opt_quat", "movement"):
            if key not in f:
                raise BadSession(f"{path}: missing dataset {key!r}")
        if "sampling_rate" not in f.attrs:
            raise BadSession(f"{path}: missing attribute 'sampling_rate'")
        rate = float(f.attrs["sampling_rate"])
        gyr = np.asarray(f["imu_gyr"], float)
        acc = np.asarray(f["imu_acc"], float)
        quat = np.asarray(f["opt_quat"], float)
        movement = np.asarray(f["movement"]).astype(bool)
    n = len(gyr)
    if not (acc.shape == gyr.shape == (n, 3) and quat.shape == (n, 4) and movement.shape == (n,)):
        raise BadSession(f"{path}: datasets have inconsistent shapes")
    for key, arr in (("imu_gyr", gyr), ("imu_acc", acc)):
        bad = np.argwhere(~np.isfinite(arr))
        if bad.size:
            raise BadSession(f"{path}: dataset {key!r}, sample {bad[0][0]}, axis {bad[0][1]}: not a finite number")
    t = np.arange(n) / rate
    imu = ImuStream(t, gyr, acc, saturation_mask(np.column_stack([gyr, acc])), [], str(path))
    return BroadTrial(path.stem, imu, quat, movement, rate)
