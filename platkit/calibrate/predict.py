"""Predict markers and poses from a calibration for a file of commands (``platkit predict``).

Input: a commands CSV with one column per control of the stand (named as the stand names them;
an optional ``t`` column and other columns are allowed and used only by time- or history-
dependent model terms). 'm' controls are in the calibration's length unit.
Output: one row per command row: the control columns, every marker's ``<name>_x,_y,_z`` in the
motion-capture frame, every rigid body's ``<T>_x,_y,_z,_qw,_qx,_qy,_qz`` (origin and unit
quaternion, qw >= 0) in the motion-capture frame, then the pose ``x,y,z,qw,qx,qy,qz`` of the moving frame in the base frame
(on a tree then ``<link>_x,...,<link>_qz`` for each other tracked link);
lengths in the calibration's length unit. A command outside its control's stroke, a ``t``
that decreases, or no ``t`` for a model with time-dependent terms, is bad input; rows whose forward kinematics fails inside the strokes are written
with empty cells and counted.

The thermal state (a model whose terms read the time, docs/diagnosis.md "Thermal drift"): the
rows are predicted at a time since power-on, ``at_time`` for the first row and later rows by their
``t`` (``--at-time``), or at the equilibrium (``warm``, ``--warm``); by default the rows' ``t`` are
read on the clock of the session the model was fitted on (its terms' ``where['first_command_t']``;
a later session that continues that clock is predicted as warm as it is), else the first row is at
power-on (cold), later rows by their ``t``. The power-on is the session's (session.yaml's
``power_on_t``; a term's ``where['since_power_on_at_start_s']`` keeps it); where the session did not
say it, the first command of the session the model was fitted on stands for it. Such a model's output has two
more columns after the pose: ``since_power_on_s`` (the time each row is predicted at; ``inf``
warm) and ``thermal_note`` (empty, or why the row is an extrapolation: beyond the recorded span,
or a drift with no equilibrium asked for warm, predicted at the end of the recorded span). A
model with no time-dependent term predicts the same at any time: the options are accepted and
the result says so.
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import predict_bodies, predict_links, predict_markers
from platkit.effects import with_history
from platkit.errors import BadInput
from platkit.io.atomic import atomic_write_text
from platkit.io.calibration import Calibration, read_calibration
from platkit.io.table import read_table
from platkit.limits import check_strokes
from platkit.model import controls_from_si, controls_to_si, length_scale
from platkit.notices import warn
from platkit.poses import PoseSet

#: effects whose terms move with the gravity loads (a payload changes their prediction)
LOADED_EFFECTS = ("compliance", "link_bending")


def read_commands(path: str | Path, cal: Calibration) -> tuple[np.ndarray, np.ndarray | None]:
    """Controls (N, n_u) in internal units and t (N,) or None from a commands CSV."""

    try:
        table = read_table(Path(path), "commands")
    except BadInput as exc:
        raise BadInput(str(exc)) from None
    spec = cal.spec
    missing = [n for n in spec.control_names if n not in table.header]
    if missing:
        raise BadInput(f"{path}: missing control column {missing[0]!r}; the {spec.name} stand's controls are "
                       f"{', '.join(spec.control_names)}")
    U = np.column_stack([table.column(n) for n in spec.control_names])
    bad = np.argwhere(~np.isfinite(U))
    if bad.size:
        r, c = bad[0]
        raise BadInput(f"{table.where(int(r), spec.control_names[c])}: the control is empty or nan; every row needs a number")
    U_si = controls_to_si(spec, U, cal.length_unit)
    _check_strokes(table, spec, U, U_si, cal.length_unit)
    t = table.column("t") if "t" in table.header else None
    if t is not None:
        bad_t = np.nonzero(~np.isfinite(t))[0]
        if bad_t.size:
            raise BadInput(f"{table.where(int(bad_t[0]), 't')}: empty or nan; a t column needs a time in every row")
        back = np.nonzero(np.diff(t) < 0)[0]
        if back.size:
            r = int(back[0]) + 1
            raise BadInput(f"{table.where(r, 't')}: {t[r]:.6g} is earlier than the row before "
                           "(times must not decrease: time- and history-dependent terms read the rows in order)")
    return U_si, t


def _check_strokes(table, spec, U_file: np.ndarray, U_si: np.ndarray, length_unit: str) -> None:
    """Commands against the strokes under platkit.limits' policy, as a session's commands.csv: a
    reading past a limit within the recording tolerance is kept with a warning, further out is
    bad input (with a hint when the number is in the other length unit)."""
    check_strokes(spec, U_si, U_file, length_unit, table.where, BadInput,
                  f"the calibration's lengths are in {length_unit}", warn)


def prediction_table(cal: Calibration, U: np.ndarray, t: np.ndarray | None = None,
                     since_power_on: np.ndarray | None = None):
    """(header, rows (N, cols), ok (N,)) of the predict output for controls U (N, n_u) SI.
    ``since_power_on`` (N,) s: the thermal state of each row (``inf`` warm; see the module's
    docstring), or None: the first row at power-on, later rows by ``t``."""
    N = U.shape[0]
    poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                    marker_names=list(cal.marker_names), t=t, length_unit=cal.length_unit,
                    marker_links=dict(cal.marker_links))  # on a tree, terms move each marker with its link
    if cal.terms:  # history- and time-dependent terms read the rows' order and times

        poses = with_history(poses, cal.spec)
        if since_power_on is not None:  # the terms read the time since their session's first command
            state = np.asarray(since_power_on, float)
            poses.extras = dict(poses.extras, elapsed=state - power_on_offset(cal),
                                thermal_start_s=np.full(N, state[0] if N else 0.0))
    markers, q, X, ok = predict_markers(cal, U, poses)
    s = length_scale(cal.length_unit)
    header = list(cal.spec.control_names)
    header += [f"{m}_{a}" for m in cal.marker_names for a in "xyz"]
    header += [f"{b}_{a}" for b in cal.body_names for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    header += ["x", "y", "z", "qw", "qx", "qy", "qz"]
    bodies = predict_bodies(cal, q, X, U, poses)
    bodies[..., :3] /= s
    cols = [controls_from_si(cal.spec, U, cal.length_unit), markers.reshape(N, -1) / s, bodies.reshape(N, -1), X / s, q]
    others = cal.spec.tracked_links[1:] if cal.marker_links else []
    if others:  # a tree: each other tracked link's pose after the moving frame's
        q_links, X_links = predict_links(cal, U, poses)
        for k, link in enumerate(others, start=1):
            header += [f"{link}_{a}" for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
            cols += [X_links[:, k] / s, q_links[:, k]]
    rows = np.column_stack(cols)
    rows[~ok, cal.spec.n_u:] = np.nan
    return header, rows, ok


def terms_reading_time(cal: Calibration, U: np.ndarray) -> list[str]:
    """Effects of ``cal``'s model terms whose offsets at controls U (N, n_u) SI change with the
    time since the first command (thermal drift, a marker slip): asked of each term through
    ModelTerm's offsets under two different clocks (the second with a thermal state at its first
    row), so any effect plugin is covered. The rows are U's, repeated in turn to at least three,
    so that a heat that cools between moves shows its clock."""
    if not cal.terms:
        return []

    U = U[np.arange(max(len(U), 3)) % len(U)] if len(U) else U
    N, n_u = U.shape
    blank = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                    marker_names=list(cal.marker_names), length_unit=cal.length_unit)
    clocks = []
    for elapsed, state in ((np.arange(N, dtype=float), {}),
                           (3.7 * np.arange(N, dtype=float) + 11.0, {"thermal_start_s": np.full(N, 11.0)})):
        poses = with_history(blank, cal.spec)
        poses.extras = dict(poses.extras, elapsed=elapsed, **state)
        clocks.append(poses)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
    X = np.zeros((N, 3))
    names = []
    for term, theta in zip(cal.terms, cal.theta):
        theta = np.asarray(theta, float)
        offsets = [(term.control_offset(theta, p, n_u), term.marker_offset(theta, p), term.pose_offset(theta, p, q, X))
                   for p in clocks]
        if any(not np.allclose(np.asarray(a, float), np.asarray(b, float), equal_nan=True)
               for a, b in zip(*offsets)):
            names.append(term.effect)
    return names


def _term_offsets(cal: Calibration, U: np.ndarray, elapsed: float) -> np.ndarray:
    """Every term's offsets (control, pose, marker; flattened) at controls U (N, n_u) SI, every
    row at ``elapsed`` s since power-on (``inf``: warm)."""
    N, n_u = U.shape
    blank = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                    marker_names=list(cal.marker_names), length_unit=cal.length_unit)
    poses = with_history(blank, cal.spec)
    poses.extras = dict(poses.extras, elapsed=np.full(N, elapsed), thermal_start_s=np.full(N, elapsed))
    q = np.tile([1.0, 0.0, 0.0, 0.0], (N, 1))
    X = np.zeros((N, 3))
    parts = []
    with np.errstate(invalid="ignore", over="ignore"):  # a term that cannot take inf says so by a nan
        for term, theta in zip(cal.terms, cal.theta):
            theta = np.asarray(theta, float)
            parts += [np.ravel(term.control_offset(theta, poses, n_u)), np.ravel(term.marker_offset(theta, poses)),
                      np.ravel(term.pose_offset(theta, poses, q, X))]
    return np.concatenate(parts) if parts else np.zeros(0)


def power_on_offset(cal: Calibration) -> float:
    """Seconds from power-on to the first command of the session the model was fitted on (its
    terms' ``where['since_power_on_at_start_s']``); 0 where none says it (the first command stands
    for the power-on)."""
    found = [t.where.get("since_power_on_at_start_s") for t in cal.terms]
    found = [float(v) for v in found if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return max(found) if found else 0.0


def session_clock_start(cal: Calibration) -> float | None:
    """The time t (s, on its own clock) of the first command of the session the model was fitted
    on (its terms' ``where['first_command_t']``), or None where no term says it."""
    found = [t.where.get("first_command_t") for t in cal.terms]
    found = [float(v) for v in found if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return min(found) if found else None


def recorded_span(cal: Calibration) -> tuple[float, float] | None:
    """(first, last) s since the first command of the session the model's time-dependent terms
    were fitted on (their ``where['recorded_s']``), or None where no term says it."""
    spans = [t.where.get("recorded_s") for t in cal.terms]
    spans = [s for s in spans if isinstance(s, (list, tuple)) and len(s) == 2]
    if not spans:
        return None
    return float(min(s[0] for s in spans)), float(max(s[1] for s in spans))


def thermal_state(cal: Calibration, U: np.ndarray, t: np.ndarray | None, at_time: float | None = None,
                  warm: bool = False, commands: str | Path = "commands") -> dict:
    """The thermal state ``predict`` predicts for (see the module's docstring): {'timed': the
    effects whose terms read the time, 'since_power_on' (N,) s or None, 'notes' (N,) str,
    'state': one sentence, 'warnings': [sentences]}. BadInput where the state cannot be given."""
    N = len(U)
    timed = terms_reading_time(cal, U)
    if not timed:
        state = "the model has no time-dependent term: the prediction is the same at any time"
        if at_time is not None or warm:
            state += f" (--{'warm' if warm else 'at-time'} changes nothing)"
        return {"timed": [], "since_power_on": None, "notes": [""] * N, "state": state, "warnings": []}
    if at_time is not None and not (np.isfinite(at_time) and at_time >= 0):
        raise BadInput(f"--at-time must be a time since power-on in seconds (>= 0), got {at_time:g}")
    if t is None and not warm and at_time is None:
        raise BadInput(f"{commands}: no 't' column, but the calibration's model has time-dependent terms "
                       f"({', '.join(timed)}); give t in seconds on the session's clock, or --at-time or --warm")
    span = recorded_span(cal)  # since the session's first command
    on = power_on_offset(cal)
    rel = np.zeros(N) if t is None else np.asarray(t, float) - float(t[0])
    notes = [""] * N
    warnings: list[str] = []
    span_text = ("unknown (the calibration does not say it)" if span is None
                 else f"{span[0] + on:.6g} to {span[1] + on:.6g} s")
    if warm:
        if not np.allclose(_term_offsets(cal, U[:1], 1e8), _term_offsets(cal, U[:1], 1e9), rtol=1e-9, atol=1e-15):
            if span is None:
                raise BadInput(f"--warm: the model's {', '.join(timed)} has no equilibrium (it drifts without end) and "
                               "the calibration does not say the span it was fitted on; give --at-time")
            since = np.full(N, span[1] + on)
            note = (f"{', '.join(timed)} has no equilibrium (it drifts without end): predicted at the end of the "
                    f"recorded span, {span[1] + on:.6g} s since power-on")
            notes = [note] * N
            warnings.append(note)
            state = f"warm asked; {note}"
        else:
            if not np.all(np.isfinite(_term_offsets(cal, np.vstack([U[:1], U[:1]]), np.inf))):
                raise BadInput(f"--warm: the model's {', '.join(timed)} cannot say its equilibrium (a calibration "
                               "written before its terms kept the recorded work rate); give --at-time")
            since = np.full(N, np.inf)
            state = "warm: the equilibrium the thermal terms reach (t since power-on -> inf)"
            if span is not None:
                end, far = _term_offsets(cal, U[:1], span[1]), _term_offsets(cal, U[:1], np.inf)
                if np.max(np.abs(far - end), initial=0.0) > 0.05 * max(np.max(np.abs(far), initial=0.0), 1e-15):
                    note = (f"the equilibrium lies beyond the recorded span ({span_text} since power-on): "
                            "extrapolated by the model's thermal terms")
                    notes = [note] * N
                    warnings.append(note)
        return {"timed": timed, "since_power_on": since, "notes": notes, "state": state, "warnings": warnings}
    t0 = session_clock_start(cal)
    if at_time is None and t is not None and t0 is not None:  # the rows' t on the session's clock
        since = np.asarray(t, float) - t0 + on
        state = (f"{since[0]:.6g} s since power-on at the first row, the rows' t read on the clock of the session "
                 "the model was fitted on (the default; give --at-time or --warm for another state)")
    else:
        since = (0.0 if at_time is None else float(at_time)) + rel
        state = (f"{since[0]:.6g} s since power-on at the first row" + ("" if t is None else ", later rows by their t")
                 + ("" if at_time is not None else " (the default: cold at the first row; give --at-time or --warm)"))
    if span is not None:
        first, last = span[0] + on, span[1] + on
        out = (since > last * (1 + 1e-9) + 1e-9) | (since < first - 0.01 * (last - first) - 1e-9)
        if np.any(out):
            note = (f"{since[out].min():.6g} to {since[out].max():.6g} s since power-on is beyond the recorded span "
                    f"({span_text}): extrapolated by the model's thermal terms")
            notes = [note if o else "" for o in out]
            warnings.append(f"{int(out.sum())} of {N} rows: {note}")
    return {"timed": timed, "since_power_on": since, "notes": notes, "state": state, "warnings": warnings}


def read_carrying(calibration, payload: list | None):
    """The calibration at ``calibration`` with its stand carrying ``payload`` (a list of {link,
    mass_kg, com_m}, empty for none; None: the load it was calibrated with). Only URDF stands carry
    one; BadInput otherwise."""
    cal = read_calibration(calibration)
    if payload is None:
        return cal
    if cal.spec.name != "urdf":
        raise BadInput(f"--payload: the {cal.spec.name} stand of {calibration} carries no payload (URDF stands do)")
    return read_calibration(calibration, {"payload": payload})


def predict_file(calibration: str | Path, commands: str | Path, out: str | Path, at_time: float | None = None,
                 warm: bool = False, payload: list | None = None) -> dict:
    """Read a calibration.yaml and a commands CSV, write the prediction CSV atomically, at the
    thermal state ``at_time`` (s since power-on at the first row) or ``warm`` (see the module's
    docstring); ``payload`` (a list of {link, mass_kg, com_m}, empty for none) the load the stand
    carries in place of its calibration session's (URDF stands: it changes the loads of the
    compliance terms).

    Returns {'rows': N, 'failed': number of rows without a solution, 'out': path, 'thermal': the
    state said in one sentence, 'timed': the effects whose terms read the time, 'warnings': [sentences],
    'loaded': whether a term moves with the loads (LOADED_EFFECTS)}.
    """
    if at_time is not None and warm:
        raise BadInput("--at-time and --warm ask for two thermal states; give one")
    cal = read_carrying(calibration, payload)
    U, t = read_commands(commands, cal)
    thermal = thermal_state(cal, U, t, at_time, warm, commands)
    header, rows, ok = prediction_table(cal, U, t, thermal["since_power_on"])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    timed = thermal["since_power_on"] is not None
    w.writerow(header + (["since_power_on_s", "thermal_note"] if timed else []))
    for k, r in enumerate(rows):
        cells = ["" if not np.isfinite(v) else format(float(v), ".10g") for v in r]
        if timed:
            cells += [format(float(thermal["since_power_on"][k]), ".10g"), thermal["notes"][k]]
        w.writerow(cells)
    atomic_write_text(out, buf.getvalue())
    return {"rows": int(len(rows)), "failed": int(np.sum(~ok)), "out": str(out), "thermal": thermal["state"],
            "timed": list(thermal["timed"]), "warnings": list(thermal["warnings"]),
            "loaded": any(term.effect in LOADED_EFFECTS for term in cal.terms)}
