"""Pieces of a simulated session's files shared by both simulators: number formatting, CSV text,
and the IMU stream with its truth files."""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import yaml

from platkit.errors import BadInput
from platkit.inertial.simulate import write_imu
from platkit.io.jsonout import plain

__all__ = ["fmt", "csv_text", "write_imu_files", "truth_imu", "dropped_note"]


def fmt(v: float, digits: int) -> str:
    """A CSV cell: ``v`` with ``digits`` decimals, empty for NaN (an occluded sample)."""
    return "" if not np.isfinite(v) else f"{v:.{digits}f}"


def dropped_note(plan_info: dict, n_kept: int) -> str | None:
    """One sentence saying how many planned commands the simulation dropped and why (forward
    kinematics of the true stand, drawn away from the description, finds no pose for them on the
    stand's branch, within the coordinates' bounds and the rows' plausible misfit), or None when
    none was dropped. ``n_kept``: the commands the session holds."""
    n = int(plan_info.get("unreachable_with_true_geometry", 0))
    if n <= 0:
        return None
    return (f"{n} of {n + n_kept} planned commands dropped: unreachable with the true geometry (the simulated true "
            f"stand takes no pose for them on its branch, within the coordinates' bounds and the rows' plausible "
            f"misfit); the session holds the other {n_kept}")


def csv_text(header: list[str], rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def truth_imu(imu: dict) -> dict:
    """The sensor's true errors for truth_imu.yaml (keys of platkit.inertial.orient.read_truth_imu);
    the gyro bias is its value at the last sample."""
    truth = plain(dict(imu["truth_imu"]))
    if "gyr_bias" in imu:
        truth["gyr_bias_rad_s"] = plain(np.asarray(imu["gyr_bias"], float)[-1])
    return truth


def write_imu_files(imu: dict, folder: Path) -> dict:
    """imu.csv and the IMU truth files in ``folder``; returns the session.yaml ``imu`` entry."""
    t = np.asarray(imu["t"], float)
    n = len(t)
    for key in ("gyr", "acc"):
        if np.shape(imu[key]) != (n, 3):
            raise BadInput(f"the imu hook returned {key!r} of shape {np.shape(imu[key])}, expected ({n}, 3)")
    write_imu(folder / "imu.csv", imu)
    rate = float(1.0 / np.median(np.diff(t)))
    entry = plain(imu.get("entry", {"rate_hz": rate, "frame": "imu"}))
    if "q_base_from_platform" in imu:
        q = np.asarray(imu["q_base_from_platform"], float)
        if q.shape != (n, 4):
            raise BadInput(f"the imu hook returned 'q_base_from_platform' of shape {q.shape}, expected ({n}, 4)")
        # times formatted as format_imu_csv writes them: truth and stream share every timestamp
        rows = [[f"{a:.9g}"] + [f"{v:.10f}" for v in qq] for a, qq in zip(t, q)]
        (folder / "truth_orientation.csv").write_text(csv_text(["t", "qw", "qx", "qy", "qz"], rows), encoding="utf-8")
    if "truth_imu" in imu:
        (folder / "truth_imu.yaml").write_text(
            "# The simulated IMU's true errors (SI), as platkit orient compares them.\n"
            + yaml.safe_dump(truth_imu(imu), sort_keys=False), encoding="utf-8")
    return entry
