"""A simulated session written as a session folder (docs/session-format.md) with its truth files."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from platkit.errors import BadInput
from platkit.io.atomic import atomic_output_dir
from platkit.io.jsonout import plain
from platkit.model import controls_from_si, length_scale
from platkit.simulate.files import csv_text, dropped_note, fmt, truth_imu, write_imu_files
from platkit.simulate.results import Simulation

__all__ = ["write_session", "body_entry", "body_columns", "body_row"]


def write_session(sim: Simulation, out: str | Path, poses_only: bool = False, description: str | Path | None = None,
                  notes: str = "", moving_link: str | None = None, base_link: str | None = None) -> Path:
    """Write a simulated session folder (session.yaml, commands.csv, markers.csv or poses.csv,
    truth.yaml), whole or not at all. Returns the folder.

    With an IMU stream (``sim.imu``): imu.csv (:func:`platkit.inertial.simulate.write_imu`), the
    session.yaml ``imu`` entry, and the truth files ``platkit orient`` scores against:
    truth_orientation.csv (``t,qw,qx,qy,qz``, the platform in the base frame at every IMU
    sample, from ``q_base_from_platform``) and truth_imu.yaml (from ``truth_imu``; the gyro
    bias is the one at the end of the recording when the stream carries ``gyr_bias``, as
    ``platkit orient`` compares it with its final estimate).

    ``description``: the description file the stand was built from (copied into the folder);
    ``moving_link``, ``base_link``: the stand options it was built with (serial chains)."""
    spec = sim.spec
    unit = sim.length_unit
    s = length_scale(unit)
    ldig = 3 if unit == "mm" else 6
    names = sim.truth.marker_names
    bnames = sim.truth.base_marker_names
    out = Path(out)
    ctrl_digits = [ldig if c.unit == "m" else 9 for c in spec.controls]
    V = controls_from_si(spec, sim.commands, unit)
    with atomic_output_dir(out) as tmp:
        entry: dict = {
            "platform": spec.name,
            "description": None,
            "units": {"length": unit, "time": "s"},
            "markers": names,
            "base_markers": list(bnames),
            "mocap_rate_hz": float(sim.mocap_rate_hz),
            "imu": None,
            # a tree: the mapping marker -> link the simulation placed them by (platkit.simulate.additive)
            "moving_link": sim.poses.moving_link if isinstance(sim.poses.moving_link, dict) else moving_link,
            "notes": notes or f"simulated by platkit (seed {sim.truth.seed}); the true stand is in truth.yaml",
        }
        dropped = dropped_note(sim.plan_info, len(sim.commands))
        if dropped is not None:  # said where the user reads, whatever notes were given
            entry["notes"] = f"{entry['notes']}; {dropped}"
        if base_link is not None:
            entry["base_link"] = base_link
        bnames_6dof = list(sim.truth.body_names)
        entry.update(body_entry(bnames_6dof, sim.truth.body_noise))
        bcols = body_columns(bnames_6dof)
        if description is not None:
            desc = Path(description)
            (tmp / desc.name).write_bytes(desc.read_bytes())
            entry["description"] = desc.name
        rows = [[f"{t:.6f}"] + [fmt(v, d) for v, d in zip(row, ctrl_digits)] for t, row in zip(sim.command_t, V)]
        (tmp / "commands.csv").write_text(csv_text(["t"] + spec.control_names, rows), encoding="utf-8")
        mcols = [f"{m}_{a}" for m in names + bnames for a in "xyz"]
        if poses_only or sim.markers is None:
            p = sim.poses
            Vp = controls_from_si(spec, p.controls, unit)
            if len(p.controls) != len(sim.commands):
                raise BadInput("poses.csv needs one row per command; simulate with raw=False for --poses-only")
            rows = []
            for i in range(p.n_poses):
                r = [fmt(v, d) for v, d in zip(Vp[i], ctrl_digits)]
                r += [fmt(v / s, ldig) for v in p.markers[i].reshape(-1)]
                if bnames:
                    r += [fmt(v / s, ldig) for v in p.base_markers.reshape(-1)]
                r += [str(int(n)) for n in p.n_samples[i]]
                if bnames_6dof:
                    r += body_row(p.bodies[i], s, ldig) + [str(int(n)) for n in p.n_body_samples[i]]
                rows.append(r)
            header = (spec.control_names + mcols + [f"{m}_n" for m in names] + bcols
                      + [f"{b}_n" for b in bnames_6dof])
            (tmp / "poses.csv").write_text(csv_text(header, rows), encoding="utf-8")
        else:
            Y = sim.markers if sim.base_markers is None else np.concatenate([sim.markers, sim.base_markers], axis=1)
            Y = Y.reshape(len(sim.marker_t), -1) / s
            rows = [[f"{t:.6f}"] + [fmt(v, ldig) for v in row] for t, row in zip(sim.marker_t, Y)]
            if bnames_6dof:
                rows = [r + body_row(b, s, ldig) for r, b in zip(rows, sim.bodies)]
            (tmp / "markers.csv").write_text(csv_text(["t"] + mcols + bcols, rows), encoding="utf-8")
        if sim.imu is not None:
            entry["imu"] = write_imu_files(sim.imu, tmp)
        (tmp / "session.yaml").write_text(yaml.safe_dump(entry, sort_keys=False), encoding="utf-8")
        truth = sim.truth.to_dict()
        truth["plan"] = plain(sim.plan_info)
        if sim.imu is not None and "truth_imu" in sim.imu:
            truth["imu"] = truth_imu(sim.imu)
        (tmp / "truth.yaml").write_text(
            "# The true stand behind this simulated session (SI units). Calibration should recover it.\n"
            + yaml.safe_dump(truth, sort_keys=False), encoding="utf-8")
    return out


def body_entry(names: list[str], noise: dict) -> dict:
    """session.yaml's rigid-body entries: ``rigid_bodies`` (the names) and, where the noise of a
    sample is declared ({'position_m', 'rotation_rad'} per axis), ``rigid_body_noise``; empty
    without bodies."""
    if not names:
        return {}
    out: dict = {"rigid_bodies": list(names)}
    if noise:
        out["rigid_body_noise"] = {"position_mm": float(noise["position_m"] * 1e3),
                                   "rotation_deg": float(np.rad2deg(noise["rotation_rad"]))}
    return out


def body_columns(names: list[str]) -> list[str]:
    """The seven columns of every body (spec section 1): origin, then unit quaternion."""
    return [f"{b}_{a}" for b in names for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]


def body_row(row7: np.ndarray, s: float, ldig: int) -> list[str]:
    """One row's body cells from (B, 7) (m, quaternion): origins in the length unit of scale ``s``
    m with ``ldig`` decimals, quaternions to 9 decimals, an unseen body's cells empty."""
    return ["" if not np.isfinite(v) else (fmt(v / s, ldig) if j % 7 < 3 else f"{v:.9f}")
            for j, v in enumerate(row7.reshape(-1))]
