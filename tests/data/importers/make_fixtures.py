"""Writes the importer fixtures of this folder: small files laid out as each vendor's export
documents its format (written by this script from a known truth, not exported by the vendors'
software; docs/importers.md). Run from the repository root to rewrite them:

    .venv/bin/python tests/data/importers/make_fixtures.py

The truth: markers M1, M2 and a rigid body T, 6 frames at 100 Hz from frame 1 (mm, quaternions
w,x,y,z). Gaps: M2 missing at frame 3 (an empty cell, or the zeros the vendor writes), T missing
at frame 4.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
N, RATE = 6, 100.0
FRAMES = np.arange(1, N + 1)
M = {"M1": np.array([1650.549, 864.247, 3553.671]) + np.outer(np.arange(N), [1.25, 0.5, -0.25]),
     "M2": np.array([2518.512, 1290.504, 3463.172]) + np.outer(np.arange(N), [-0.75, 1.0, 0.125])}
POS = np.array([1193.014, 3071.078, -1725.361]) + np.outer(np.arange(N), [0.5, -0.25, 1.0])
AXIS = np.array([0.6, -0.48, 0.64])  # unit
ANGLE = 0.3 + 0.05 * np.arange(N)
Q = np.column_stack([np.cos(ANGLE / 2), np.outer(np.sin(ANGLE / 2), AXIS)])  # w,x,y,z
ROTVEC = np.outer(ANGLE, AXIS)
GAP_M2, GAP_T = 2, 3  # 0-based frame index


def matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rpy_xyz(R):
    """Roll, pitch, yaw (deg) with R = Rx(roll) Ry(pitch) Rz(yaw)."""
    pitch = np.arcsin(R[0, 2])
    roll = np.arctan2(-R[1, 2], R[2, 2])
    yaw = np.arctan2(-R[0, 1], R[0, 0])
    return np.degrees([roll, pitch, yaw])


def f(v, d=3):
    return f"{v:.{d}f}"


def vicon():
    rows = ["Devices", "1000", ",,Force Plate 1 - Force,,", "Frame,Sub Frame,Fx,Fy,Fz", ",,N,N,N",
            "1,0,0.1,0.2,9.8", "1,1,0.1,0.2,9.7", ""]
    rows += ["Trajectories", "100", ",,Stand:M1,,,Stand:M2,,", "Frame,Sub Frame,X,Y,Z,X,Y,Z", ",,mm,mm,mm,mm,mm,mm"]
    for k in range(N):
        m2 = ",," if k == GAP_M2 else ",".join(f(v) for v in M["M2"][k])
        if k == GAP_M2 + 2:
            m2 = "0,0,0"  # a gap written as zeros
        rows.append(f"{FRAMES[k]},0," + ",".join(f(v) for v in M["M1"][k]) + "," + m2)
    rows += ["", "Segments", "100", ",,Stand:T,,,,,", "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ", ",,deg,deg,deg,mm,mm,mm"]
    for k in range(N):
        six = ",,,,," if k == GAP_T else ",".join([f(v, 5) for v in np.degrees(ROTVEC[k])] + [f(v) for v in POS[k]])
        rows.append(f"{FRAMES[k]},0,{six}")
    (HERE / "vicon_nexus.csv").write_text("\r\n".join(rows) + "\r\n")


def qualisys_3d():
    head = [f"NO_OF_FRAMES\t{N}", "NO_OF_CAMERAS\t8", "NO_OF_MARKERS\t2", f"FREQUENCY\t{RATE:g}", "NO_OF_ANALOG\t0",
            "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--", "TIME_STAMP\t2026-03-01, 10:15:33.456\t12345.678",
            "DATA_INCLUDED\t3D", "MARKER_NAMES\tM1\tM2", "TRAJECTORY_TYPES\tMeasured\tMeasured",
            "Frame\tTime\tM1 X\tM1 Y\tM1 Z\tM2 X\tM2 Y\tM2 Z"]
    for k in range(N):
        m2 = ["0.000"] * 3 if k == GAP_M2 else [f(v) for v in M["M2"][k]]  # QTM writes zeros for a gap
        head.append("\t".join([str(FRAMES[k]), f"{k / RATE:.5f}"] + [f(v) for v in M["M1"][k]] + m2))
    (HERE / "qualisys_3d.tsv").write_text("\n".join(head) + "\n")


def qualisys_6d():
    head = [f"NO_OF_FRAMES\t{N}", "NO_OF_CAMERAS\t8", "NO_OF_BODIES\t1", f"FREQUENCY\t{RATE:g}", "NO_OF_ANALOG\t0",
            "ANALOG_FREQUENCY\t0", "DESCRIPTION\t--", "TIME_STAMP\t2026-03-01, 10:15:33.456\t12345.678",
            "DATA_INCLUDED\t6D", "BODY_NAMES\tT",
            "Frame\tTime\tX\tY\tZ\tRoll\tPitch\tYaw\tResidual\t" + "\t".join(f"Rot[{i}]" for i in range(9))]
    for k in range(N):
        if k == GAP_T:
            cells = ["NaN"] * 16
        else:
            R = matrix(Q[k])
            cells = ([f(v) for v in POS[k]] + [f(v, 4) for v in rpy_xyz(R)] + ["0.512"]
                     + [f(v, 6) for v in R.T.ravel()])  # Rot[0..8] column by column
        head.append("\t".join([str(FRAMES[k]), f"{k / RATE:.5f}"] + cells))
    (HERE / "qualisys_6d.tsv").write_text("\n".join(head) + "\n")


def motive():
    meta = ("Format Version,1.23,Take Name,Take 2026-03-01 10.15.33 AM,Take Notes,,Capture Frame Rate,100.000000,"
            "Export Frame Rate,100.000000,Capture Start Time,2026-03-01 10.15.33.456 AM,Capture Start Frame,0,"
            "Total Frames in Take,6,Total Exported Frames,6,Rotation Type,Quaternion,Length Units,Millimeters,"
            "Coordinate Space,Global")
    types = ",Type," + ",".join(["Rigid Body"] * 8 + ["Rigid Body Marker"] * 4 + ["Marker"] * 9)
    names = ",Name," + ",".join(["T"] * 8 + ["T:Marker1"] * 4 + ["M1"] * 3 + ["M2"] * 3 + ["Unlabeled 1000"] * 3)
    ids = ",ID," + ",".join(["1"] * 8 + ["1"] * 4 + ["2"] * 3 + ["3"] * 3 + ["1000"] * 3)
    cats = ",," + ",".join(["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"] + ["Position"] * 3
                           + ["Marker Quality"] + ["Position"] * 9)
    comps = "Frame,Time (Seconds)," + ",".join(list("XYZW") + list("XYZ") + [""] + list("XYZ") + [""] + list("XYZ") * 3)
    rows = [meta, "", types, names, ids, cats, comps]
    for k in range(N):
        if k == GAP_T:
            body = [""] * 8
        else:
            w, x, y, z = Q[k]
            body = [f(v, 6) for v in (x, y, z, w)] + [f(v) for v in POS[k]] + ["0.000143"]
        rbm = [f(v) for v in POS[k] + [10.0, 0.0, 0.0]] + ["1.0"]
        m2 = ["", "", ""] if k == GAP_M2 else [f(v) for v in M["M2"][k]]
        if k == GAP_M2 + 3:
            m2 = ["0.000000"] * 3  # a gap written as zeros
        unl = [f(v) for v in (5.0 * k, 1.0, 2.0)]
        rows.append(",".join([str(k), f"{k / RATE:.6f}"] + body + rbm + [f(v) for v in M["M1"][k]] + m2 + unl))
    (HERE / "motive.csv").write_text("\r\n".join(rows) + "\r\n")


def table():
    header = ["t"] + [f"{m}_{c}" for m in M for c in "xyz"] + [f"T_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    for name, sep in (("table_semicolon.csv", ";"), ("table_tab.tsv", "\t")):
        rows = [sep.join(header)]
        for k in range(N):
            cells = [f"{k / RATE:.3f}"] + [f(v) for v in M["M1"][k]]
            cells += [""] * 3 if k == GAP_M2 else [f(v) for v in M["M2"][k]]
            cells += [""] * 7 if k == GAP_T else [f(v) for v in POS[k]] + [f(v, 9) for v in Q[k]]
            rows.append(sep.join(c.replace(".", ",") for c in cells))  # decimal commas
        (HERE / name).write_text("\n".join(rows) + "\n")


def c3d():
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c["parameters"]["POINT"]["LABELS"]["value"] = ("Stand:M1", "Stand:M2")
    pts = np.ones((4, 2, N))
    pts[:3, 0] = M["M1"].T
    pts[:3, 1] = M["M2"].T
    c["data"]["points"] = pts
    c["data"]["meta_points"]["residuals"] = np.zeros((1, 2, N))
    c["data"]["meta_points"]["residuals"][0, 1, GAP_M2] = -1.0
    c.add_parameter("POINT", "UNITS", "mm")
    rot = np.zeros((4, 4, 1, N))
    for k in range(N):
        rot[:3, :3, 0, k] = matrix(Q[k])
        rot[:3, 3, 0, k] = POS[k]
        rot[3, 3, 0, k] = 1.0
    rot[:, :, 0, GAP_T] = np.nan
    c["data"]["rotations"] = rot
    c.add_parameter("ROTATION", "LABELS", ("Stand:T",))
    c.write(str(HERE / "c3d_rigid.c3d"))


if __name__ == "__main__":
    vicon()
    qualisys_3d()
    qualisys_6d()
    motive()
    table()
    c3d()
