"""Real data: the PAL TIAGo arm recorded by Qualisys (FIGAROH's example data, Apache-2.0,
Thanh Nguyen, CNRS and Toward), turned into platkit sessions and scored like FIGAROH.

A dataset converter, not the core (../shared/STYLE.md): a user's own robot gets no special
case in platkit, and this one needs none; the golden tests and the benchmarks share it. The URDF
is copied into the session byte for byte; the torso's recorded 0.350181 m against the URDF's
0.35 m limit is a reading the session reader keeps with a warning
(platkit.io.session_checks.check_controls).

Source: ``shared/data/real/tiago/`` (README.md there). Each row of a ``qualisys_*_static_postures``
CSV is a settled pose: four points BL, BR, TR, TL of one rigid body on the hand (metres, in the
frame of a rigid body fixed to the robot base) and the joints ``torso_lift_joint`` (m),
``arm_1_joint .. arm_7_joint`` (rad).

:func:`convert` writes a session folder (session.yaml for the ``urdf`` stand with the URDF copied
beside it unchanged, moving link ``wrist_ft_tool_link``, units m; commands.csv; poses.csv).
:func:`bl_rmse_mm` scores point BL as FIGAROH 1.0.2 reports it (norm RMSE, mm; its published
figures in :data:`FIGAROH`); benchmarks/calibration_tiago.py fits the model levels beside them.

Command line::

    .venv/bin/python tests/real_data/tiago.py convert CSV OUT_SESSION [--urdf FILE]
"""
from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import point_errors
from platkit.errors import BadInput, BadSession
from platkit.io.atomic import atomic_output_dir

MARKERS = ["BL", "BR", "TR", "TL"]
JOINTS = ["torso_lift_joint"] + [f"arm_{k}_joint" for k in range(1, 8)]
MOVING_LINK = "wrist_ft_tool_link"
URDF_NAME = "tiago_48_schunk.urdf"
TRAINING = "qualisys_2021-11-30_static_postures.csv"
VALIDATION = "qualisys_2021-11-26_static_postures.csv"

#: FIGAROH 1.0.2 on these files: norm RMSE of point BL, mm (shared/data/real/tiago/README.md)
FIGAROH = {
    "registration": {"parameters": 9, "training_mm": 3.37, "validation_mm": 4.87},
    "joint_offsets": {"parameters": 14, "training_mm": 2.88, "validation_mm": 4.23},
    "full_geometric": {"parameters": 30, "training_mm": 1.68, "validation_mm": 3.22},
}
#: which td groups each level fits (the urdf stand's groups)
LEVELS = {"registration": [], "joint_offsets": ["offset"], "full_geometric": ["offset", "origin"]}


def default_data_dir() -> Path:
    """shared/data/real/tiago beside the checkout (walking up from this file)."""
    for parent in Path(__file__).resolve().parents:
        cand = parent / "shared" / "data" / "real" / "tiago"
        if cand.is_dir():
            return cand
        cand = parent.parent / "shared" / "data" / "real" / "tiago"
        if cand.is_dir():
            return cand
    raise BadInput("shared/data/real/tiago not found beside the checkout; pass --data DIR")


def read_postures(path: str | Path) -> dict:
    """The static-postures CSV: {'markers': (N, 4, 3) m, 'joints': (N, 8), 't': (N,) s from the first
    row (window start, robot clock), 'std_mm': (N,)}. BadSession names row and column."""
    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found")
    with path.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise BadSession(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    need = [f"{a}{k}" for k in range(1, 5) for a in "xyz"] + JOINTS + ["t_start_robot"]
    for c in need:
        if c not in header:
            raise BadSession(f"{path}: missing column {c!r}")
    data = np.empty((len(rows) - 1, len(header)))
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise BadSession(f"{path} row {r + 1}: {len(row)} cells, expected {len(header)}")
        for j, cell in enumerate(row):
            try:
                data[r, j] = float(cell)
            except ValueError:
                raise BadSession(f"{path} row {r + 1} column {header[j]!r}: expected a number, got {cell!r}") from None
    col = {h: data[:, j] for j, h in enumerate(header)}
    markers = np.stack([np.column_stack([col[f"x{k}"], col[f"y{k}"], col[f"z{k}"]]) for k in range(1, 5)], axis=1)
    joints = np.column_stack([col[j] for j in JOINTS])
    t = col["t_start_robot"] - col["t_start_robot"][0]
    std = col.get("marker_std_mm", np.full(len(t), np.nan))
    return {"markers": markers, "joints": joints, "t": t, "std_mm": std}


def convert(csv_path: str | Path, out_session: str | Path, urdf: str | Path | None = None) -> Path:
    """Write a platkit session folder for one static-postures CSV (atomically).

    session.yaml: platform urdf, description the URDF (copied into the folder), moving_link
    wrist_ft_tool_link, units m and s, markers BL, BR, TR, TL. commands.csv: t and the 8 joints;
    poses.csv: t, the joints and the markers (the rows are already settled plateaus).
    """
    csv_path = Path(csv_path)
    if not csv_path.is_file():
        raise BadInput(f"{csv_path}: static-postures CSV not found")
    urdf = Path(urdf) if urdf is not None else csv_path.parent / URDF_NAME
    if not urdf.is_file():
        raise BadInput(f"{urdf}: URDF not found (it is looked for beside the CSV; give another with --urdf, "
                       "or urdf= from Python)")
    d = read_postures(csv_path)
    order = np.argsort(d["t"], kind="stable")
    t = d["t"][order]
    if np.any(np.diff(t) <= 0):
        raise BadSession(f"{csv_path}: two rows share a start time; cannot order the commands")
    J = d["joints"][order]
    Y = d["markers"][order]
    yaml_text = (
        "# Converted by tests/real_data/tiago.py from FIGAROH's example data (Apache-2.0; Thanh Nguyen, CNRS and Toward).\n"
        f"# Source: {csv_path.name}\n"
        "platform: urdf\n"
        f"description: {URDF_NAME}\n"
        "units: {length: m, time: s}\n"
        f"markers: [{', '.join(MARKERS)}]\n"
        "base_markers: []\n"
        "mocap_rate_hz: null\n"
        "imu: null\n"
        f"moving_link: {MOVING_LINK}\n"
        f"notes: PAL TIAGo arm, Qualisys static postures from {csv_path.name}; t is the start of each averaging "
        "window on the robot clock, from the first row.\n"
    )
    cmd = io.StringIO()
    w = csv.writer(cmd, lineterminator="\n")
    w.writerow(["t"] + JOINTS)
    for ti, row in zip(t, J):
        w.writerow([format(ti, ".6f")] + [format(v, ".17g") for v in row])
    poses = io.StringIO()
    w = csv.writer(poses, lineterminator="\n")
    w.writerow(["t"] + JOINTS + [f"{m}_{a}" for m in MARKERS for a in "xyz"])
    for ti, row, ys in zip(t, J, Y):
        w.writerow([format(ti, ".6f")] + [format(v, ".17g") for v in row] + [format(v, ".17g") for v in ys.ravel()])
    out = Path(out_session)
    with atomic_output_dir(out) as tmp:
        (tmp / "session.yaml").write_text(yaml_text, encoding="utf-8")
        (tmp / "commands.csv").write_text(cmd.getvalue(), encoding="utf-8")
        (tmp / "poses.csv").write_text(poses.getvalue(), encoding="utf-8")
        (tmp / URDF_NAME).write_bytes(urdf.read_bytes())
    return out


def pivot_order(cal) -> list[str]:
    """The stand's parameters a calibration estimated, strongest first (the order the pivoted
    orthogonalisation chose them; the last ones are the least well fixed)."""
    ident = cal.fit.identifiability
    td = set(cal.spec.parameter_names)
    return [ident.names[i] for i in ident.chosen if ident.names[i] in td]


def bl_rmse_mm(cal, poses) -> float:
    """Norm RMSE (mm) of point BL: sqrt(mean |predicted - measured|^2) over the poses where BL was seen."""

    d = point_errors(cal, poses)[:, poses.marker_names.index("BL")]
    d = d[np.isfinite(d)]
    return float(np.sqrt(np.mean(d ** 2)) * 1e3)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="tests/real_data/tiago.py", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("convert", help="write a platkit session folder for one static-postures CSV")
    c.add_argument("csv")
    c.add_argument("out")
    c.add_argument("--urdf", default=None)
    args = parser.parse_args(argv)
    try:
        print(f"wrote {convert(args.csv, args.out, args.urdf)}")
    except BadInput as exc:
        print(f"platkit: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
