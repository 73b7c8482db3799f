"""Checks of a session's streams, shared by its readers: times, the marker and rigid-body
columns and their values, the plausibility of the declared length unit, the controls against
the strokes. Every problem is one BadSession line naming the file, row and column."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.errors import BadSession
from platkit.io.table import Table
from platkit.limits import RECORDING_TOLERANCE, check_strokes
from platkit.model import LENGTH_UNITS, PlatformSpec, controls_to_si
from platkit.notices import units_are_checked, warn

#: the seven columns of a rigid body T: T_x,T_y,T_z (origin, length unit) and T_qw..T_qz (unit quaternion)
BODY_SUFFIXES = ("x", "y", "z", "qw", "qx", "qy", "qz")
#: a body's quaternion is unit if its norm is within this of 1 (recorders write 4 to 6 decimals); it
#: is normalised after the check
QUAT_NORM_TOL = 1e-3
#: the columns of a marker M: M_x, M_y, M_z
AXES = ("x", "y", "z")


#: how a refusal by a plausibility check says it can be answered
UNITS_CHECKED_ANSWER = "if the file is right as written, run again with --units-checked"


def implausible(message: str, notes: list[str] | None = None) -> None:
    """A plausibility check of units failed: a BadSession of ``message`` that says how to answer
    it, or, where the user answered (platkit.notices.units_checked), a note (appended to ``notes``, default
    a PlatkitWarning) and the data kept as written."""
    if units_are_checked():
        note = f"{message} (kept as written: --units-checked)"
        if notes is None:
            warn(note)
        else:
            notes.append(note)
        return
    raise BadSession(f"{message}; {UNITS_CHECKED_ANSWER}")


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


def _check_plausible_unit(table: Table, markers: np.ndarray, length_unit: str, names: list[str],
                          extremes: tuple[float, float] | None = None) -> None:
    """Marker coordinates that cannot be in the declared unit: BadSession naming the column.
    Declared m but beyond 100 m: the file is in mm. Declared mm but every coordinate within
    20 mm of the origin and the whole stream within 20 mm: the file is in m. ``extremes``: the
    largest and smallest finite coordinate, where the caller has them (NaN: none is finite)."""
    if extremes is None:
        if not markers.size or not np.isfinite(markers).any():
            return
        # fmax/fmin reductions skip NaN without copying the stream (millions of rows)
        hi, lo = float(np.fmax.reduce(markers, axis=None)), float(np.fmin.reduce(markers, axis=None))
    else:
        hi, lo = extremes
        if not markers.size or np.isnan(hi):
            return
    if max(hi, -lo) > LARGEST_VOLUME_M:
        with np.errstate(invalid="ignore"):
            r, k, a = np.argwhere(np.abs(markers) > LARGEST_VOLUME_M)[0]
        implausible(
            f"{table.where(int(r), f'{names[k]}_{AXES[a]}')}: {markers[r, k, a] / LENGTH_UNITS[length_unit]:.6g} "
            f"{length_unit} is beyond any motion-capture volume; is the file in mm? session.yaml declares {length_unit}"
        )
        return
    if length_unit == "mm" and markers.shape[0] > 1:
        hi, lo = hi / LENGTH_UNITS["mm"], lo / LENGTH_UNITS["mm"]
        if max(hi, -lo) < 20.0 and hi - lo < 20.0:
            implausible(
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


#: rows per block of :func:`checked_marker_block`'s one pass (a block and its masks stay in the cache)
CHECK_BLOCK = 16_384


def checked_marker_block(table: Table, names: list[str], scale: float, length_unit: str) -> np.ndarray:
    """(rows, M, 3) metres from the x,y,z columns of ``names``, checked: what
    :func:`_marker_block` (in place), :func:`_check_seen` and :func:`_check_plausible_unit` do, in
    one pass over the rows in blocks of CHECK_BLOCK instead of one pass (and a stream-sized mask)
    each: scaled, seen, whole samples, extremes. The same result and the same errors in the same
    order (a marker never seen, then the first sample with some of x,y,z empty, then an
    implausible unit). The table's columns are scaled in place: it is not to be used after."""
    idx = np.array([[table.header.index(c) for c in marker_columns(m)] for m in names], dtype=int).reshape(-1, 3)
    first = int(idx[0, 0]) if idx.size else 0
    if not idx.size or not np.array_equal(idx.ravel(), np.arange(first, first + idx.size)):
        xyz = _marker_block(table, names, scale, in_place=True)
        _check_seen(xyz, names, table.path)
        _check_plausible_unit(table, xyz, length_unit, names)
        return xyz
    data = table.data[:, first:first + idx.size]
    n, M = len(data), len(names)
    seen = np.zeros(M, bool)
    partial_at: tuple[int, int] | None = None
    hi, lo = np.nan, np.nan
    for k in range(0, n, CHECK_BLOCK):
        block = data[k:k + CHECK_BLOCK]
        block *= scale
        finite = np.isfinite(block)
        n_finite = np.count_nonzero(finite)
        finite = finite.reshape(len(block), M, 3)
        fx, fy, fz = finite[..., 0], finite[..., 1], finite[..., 2]
        whole = fx & fy
        whole &= fz
        if not seen.all():
            seen |= whole.any(axis=0)
        # a sample with some of x,y,z empty: fewer finite coordinates than three per whole sample
        if partial_at is None and n_finite != 3 * np.count_nonzero(whole):
            r, m = np.argwhere((fx | fy | fz) & ~whole)[0]
            partial_at = (k + int(r), int(m))
        hi = np.fmax(hi, np.fmax.reduce(block, axis=None))  # NaN-skipping, as _check_plausible_unit
        lo = np.fmin(lo, np.fmin.reduce(block, axis=None))
    xyz = data.reshape(n, M, 3)
    for m, ok in zip(names, seen):
        if not ok:
            raise BadSession(f"{table.path}: marker {m!r} is never seen (every sample empty); remove it from session.yaml")
    if partial_at is not None:
        r, m = partial_at
        raise BadSession(
            f"{table.path} row {r + 1} (line {r + 2}): marker {names[m]!r} has some of x,y,z empty; an occluded "
            f"sample leaves all three empty"
        )
    _check_plausible_unit(table, xyz, length_unit, names, (float(hi), float(lo)))
    return xyz


#: a recorded control this fraction of its stroke past a limit is a reading (encoder noise, a soft
#: limit), kept with a note; further out it is an error (the one policy of platkit.limits)
STROKE_TOLERANCE = RECORDING_TOLERANCE


def check_controls(table: Table, spec: PlatformSpec, leading: list[str], length_unit: str,
                   notes: list[str] | None = None) -> np.ndarray:
    """Control columns of ``table`` -> (N, n_u) internal units, checked against the strokes under
    platkit.limits' policy: a value past a limit by at most RECORDING_TOLERANCE of the stroke (a
    torso reading 0.350181 m against 0.35) is kept, and one sentence per control naming the
    value and the limit is appended to ``notes`` (default: a PlatkitWarning); further out is a
    BadSession.
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
    return check_strokes(spec, u, raw, length_unit, table.where, BadSession, f"session.yaml declares {length_unit}",
                         warn if notes is None else notes.append)


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


#: motion-capture rates (Hz) outside which a marker stream's times are implausible in the declared unit
MOCAP_RATE_RANGE_HZ = (2.0, 20_000.0)
#: a declared mocap_rate_hz the stream's median step contradicts by more than this factor is refused
MOCAP_RATE_FACTOR = 2.0
#: a command log whose span and the marker stream's differ by more than this factor are in other time units
SPAN_FACTOR = 30.0


def _unit_hint(ratio: float, time_unit: str) -> str:
    """The likely time unit of a file whose times are ``ratio`` times too large (seconds taken for them)."""
    if 300 <= ratio <= 3000 and time_unit == "s":
        return "; the times look like milliseconds: write seconds, or declare units: {time: ms} in session.yaml"
    if 1 / 3000 <= ratio <= 1 / 300 and time_unit == "ms":
        return "; the times look like seconds in a session declared in milliseconds (units: {time: s})"
    return ""


def check_stream_times(stream_t: np.ndarray, stream_path: Path, time_unit: str, declared_rate_hz: float | None,
                       command_t: np.ndarray | None = None, commands_path: Path | None = None) -> None:
    """The marker stream's times (s, after session.yaml's time unit) against what they must agree
    with: session.yaml's ``mocap_rate_hz`` (its median step within MOCAP_RATE_FACTOR of the
    declared rate), a motion-capture rate at all (MOCAP_RATE_RANGE_HZ, where no rate is
    declared), and the command log (the two spans within SPAN_FACTOR of each other). A mismatch is
    one line naming the file and field, with the time unit the numbers look like; a plausibility
    check the user can answer (``--units-checked``)."""
    if len(stream_t) < 2:
        return
    dt = float(np.median(np.diff(stream_t)))
    if not dt > 0:
        return
    rate = 1.0 / dt
    where = f"{stream_path}: column 't'"
    if declared_rate_hz is not None and declared_rate_hz > 0:
        ratio = declared_rate_hz / rate  # > 1: the steps are longer than the declared rate's
        if not 1 / MOCAP_RATE_FACTOR <= ratio <= MOCAP_RATE_FACTOR:
            implausible(f"{where}: the median time step is {dt:.4g} s ({rate:.4g} Hz), but session.yaml's field "
                        f"'mocap_rate_hz' declares {declared_rate_hz:g} Hz (units: time: {time_unit})"
                        + (_unit_hint(ratio, time_unit) or "; correct mocap_rate_hz or the times"))
    elif not MOCAP_RATE_RANGE_HZ[0] <= rate <= MOCAP_RATE_RANGE_HZ[1]:
        slow = rate < MOCAP_RATE_RANGE_HZ[0]
        implausible(f"{where}: the median time step is {dt:.4g} s ({rate:.4g} Hz), "
                    + (f"slower than a motion-capture system records (at least {MOCAP_RATE_RANGE_HZ[0]:g} Hz)" if slow
                       else f"faster than a motion-capture system records (at most {MOCAP_RATE_RANGE_HZ[1]:g} Hz)")
                    + f" in session.yaml's units (time: {time_unit})"
                    + _unit_hint(1000.0 if slow else 1e-3, time_unit))
    if command_t is None or len(command_t) < 2:
        return
    span_m = float(stream_t[-1] - stream_t[0])
    span_c = float(command_t[-1] - command_t[0])
    if span_m > 0 and span_c > 0 and not 1 / SPAN_FACTOR <= span_c / span_m <= SPAN_FACTOR:
        implausible(f"{commands_path}: column 't' spans {span_c:.4g} s, {stream_path.name}'s {span_m:.4g} s "
                    f"({span_c / span_m:.3g} times as long): the two files' times are not in the same unit "
                    f"(session.yaml: units: time: {time_unit}); write both in it")
    if stream_t[-1] < command_t[0] or command_t[-1] < stream_t[0]:  # one clock shared by the files (spec 1)
        raise BadSession(f"{stream_path}: column 't' runs from {stream_t[0]:.6g} to {stream_t[-1]:.6g} s and "
                         f"{Path(commands_path).name if commands_path else 'the command log'}'s from {command_t[0]:.6g} "
                         f"to {command_t[-1]:.6g} s: the two clocks do not overlap, and the files must share one; "
                         "shift one file's times onto the other's clock")
