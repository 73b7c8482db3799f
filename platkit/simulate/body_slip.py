"""A rigid body that slips on the stand, put into a simulated session after either simulator
wrote it (the recording artefact ``marker_slip`` at a body: the body knocked on its link, every
sample from the slip on moved with it).

The slip is a small motion of the body in its own frame: its origin shifted by ``shift_m`` and its
frame turned by ``turn_rad`` (rotation vector), both in the body's frame, so that it is the same
motion on the link at every pose. A recorded sample (origin o, orientation Q in the mocap frame)
becomes (o + Q shift, Q exp(turn)); the body's placement on its link (p, R) becomes
(p + R shift, R exp(turn)), written to truth.yaml beside the placement before it.
"""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import yaml

from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix, rotvec_from_matrix
from platkit.model import length_scale

__all__ = ["slip_body", "slipped_placement"]


def slipped_placement(position: np.ndarray, rotvec: np.ndarray, shift_m: np.ndarray,
                      turn_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position (3,) m, rotation vector (3,) rad) of a body on its link after a slip of
    ``shift_m`` and ``turn_rad`` in its own frame, from its placement (``position``, ``rotvec``)."""
    R = matrix_from_rotvec(np.asarray(rotvec, float))
    after = R @ matrix_from_rotvec(np.asarray(turn_rad, float))
    return np.asarray(position, float) + R @ np.asarray(shift_m, float), rotvec_from_matrix(after)


def slip_body(session: str | Path, body: str, t_slip_s: float, shift_m, turn_rad) -> dict:
    """Move rigid body ``body`` of the simulated session folder ``session`` on its link from
    ``t_slip_s`` (s on the files' clock) on: markers.csv's samples of it at or after that time
    rewritten, truth.yaml's ``rigid_bodies[body]['after_slip']`` (position, rotation_vector,
    from_time_s since the first command) added. Returns that ``after_slip`` mapping."""
    session = Path(session)
    meta = yaml.safe_load((session / "session.yaml").read_text())
    if body not in (meta.get("rigid_bodies") or []):
        raise BadInput(f"{session / 'session.yaml'}: no rigid body {body!r} to slip")
    scale = length_scale(meta["units"]["length"])
    rows = list(csv.reader((session / "markers.csv").open()))
    head = rows[0]
    cols = [head.index(f"{body}_{a}") for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    shift, turn = np.asarray(shift_m, float), matrix_from_rotvec(np.asarray(turn_rad, float))
    for r in rows[1:]:
        vals = [r[c] for c in cols]
        if float(r[0]) < t_slip_s or "" in vals:
            continue
        v = np.array(vals, float)
        Q = matrix_from_quat(v[3:] / np.linalg.norm(v[3:]))
        o = v[:3] + Q @ shift / scale
        q = quat_from_matrix(Q @ turn)
        q = q if q[0] >= 0 else -q
        for c, x in zip(cols, [*(f"{x:.3f}" if scale == 1e-3 else f"{x:.6f}" for x in o), *(f"{x:.9f}" for x in q)]):
            r[c] = x
    with (session / "markers.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    truth = yaml.safe_load((session / "truth.yaml").read_text())
    placed = truth["rigid_bodies"][body]
    first = float(list(csv.reader((session / "commands.csv").open()))[1][0])  # the first command's time
    p, w = slipped_placement(placed["position"], placed["rotation_vector"], shift, turn_rad)
    placed["after_slip"] = {"position": [float(x) for x in p], "rotation_vector": [float(x) for x in w],
                            "from_time_s": float(t_slip_s - first)}
    (session / "truth.yaml").write_text(yaml.safe_dump(truth, sort_keys=False))
    return placed["after_slip"]
