"""The held-out protocol of the physical proof (benchmarks/diagnosis_proof_physical.py), which the
tests that mimic it share: every fifth command from the third on is held out, and its stretch of
the recording cut from markers.csv."""
from __future__ import annotations

from pathlib import Path

import numpy as np

HELD_OUT_EVERY = 5


def held_out_rows(n: int) -> np.ndarray:
    return np.arange(2, n, HELD_OUT_EVERY)


def blank_held_out(folder: Path, sim, rows: np.ndarray) -> int:
    """Cut the held-out commands' stretches (from the command to the next) out of markers.csv
    (rewritten whole): the recording has a gap there. Returns the samples cut."""
    te = sim.marker_t - sim.nuisances.time_shift_s
    cut = np.zeros(len(te), bool)
    for i in rows:
        cut |= (te >= sim.command_t[i]) & (te < sim.hold_end_t[i])
    path = folder / "markers.csv"
    lines = path.read_text().splitlines()
    keep = [lines[0]] + [line for line, c in zip(lines[1:], cut) if not c]
    path.write_text("\n".join(keep) + "\n")
    return int(cut.sum())
