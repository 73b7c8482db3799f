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


def prediction_table(cal: Calibration, U: np.ndarray, t: np.ndarray | None = None):
    """(header, rows (N, cols), ok (N,)) of the predict output for controls U (N, n_u) SI."""
    N = U.shape[0]
    poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                    marker_names=list(cal.marker_names), t=t, length_unit=cal.length_unit,
                    marker_links=dict(cal.marker_links))  # on a tree, terms move each marker with its link
    if cal.terms:  # history- and time-dependent terms read the rows' order and times

        poses = with_history(poses, cal.spec)
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
    ModelTerm's offsets under two different clocks, so any effect plugin is covered."""
    if not cal.terms:
        return []

    N, n_u = U.shape
    blank = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, len(cal.marker_names), 3), np.nan),
                    marker_names=list(cal.marker_names), length_unit=cal.length_unit)
    clocks = []
    for elapsed in (np.arange(N, dtype=float), 3.7 * np.arange(N, dtype=float) + 11.0):
        poses = with_history(blank, cal.spec)
        poses.extras = dict(poses.extras, elapsed=elapsed)
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


def predict_file(calibration: str | Path, commands: str | Path, out: str | Path) -> dict:
    """Read a calibration.yaml and a commands CSV, write the prediction CSV atomically.

    Returns {'rows': N, 'failed': number of rows without a solution, 'out': path}.
    """
    cal = read_calibration(calibration)
    U, t = read_commands(commands, cal)
    if t is None:
        timed = terms_reading_time(cal, U)
        if timed:
            raise BadInput(f"{commands}: no 't' column, but the calibration's model has time-dependent terms "
                           f"({', '.join(timed)}); give t in seconds on the session's clock")
    header, rows, ok = prediction_table(cal, U, t)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow(["" if not np.isfinite(v) else format(float(v), ".10g") for v in r])
    atomic_write_text(out, buf.getvalue())
    return {"rows": int(len(rows)), "failed": int(np.sum(~ok)), "out": str(out)}
