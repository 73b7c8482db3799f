"""One motion-capture recording read from an export (platkit.io.importers, platkit.io.c3d), and
the rules every reader shares: names, cells, occluded samples, quaternions."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadInput
from platkit.geometry import quat_normalize

#: a quaternion's norm must be within this of 1 to be taken (platkit.io.session_checks.QUAT_NORM_TOL)
QUAT_NORM_TOL = 1e-3


@dataclass
class Recording:
    """A motion-capture recording read from an export.

    ``t`` (K,) s; ``markers``: name -> (K, 3) in ``unit``; ``bodies``: name -> ((K, 3) position in
    ``unit``, (K, 4) unit quaternion w,x,y,z), NaN where occluded; ``occluded``: name -> samples
    occluded; ``zeros``: name -> how many of them the file wrote as zeros; ``notes``: what was left
    out or converted, one sentence each."""

    source: Path
    format: str
    unit: str
    t: np.ndarray
    markers: dict[str, np.ndarray] = field(default_factory=dict)
    bodies: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    rate_hz: float | None = None
    occluded: dict[str, int] = field(default_factory=dict)
    zeros: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def n_samples(self) -> int:
        return len(self.t)

    def summary(self) -> str:
        """One sentence: what was read, and every occluded count."""
        parts = [f"{self.source}: {self.format}, {self.n_samples} samples"
                 + (f" at {self.rate_hz:g} Hz" if self.rate_hz else "")
                 + f", {len(self.markers)} marker(s), {len(self.bodies)} rigid bod{'y' if len(self.bodies) == 1 else 'ies'}"
                 + f", lengths in {self.unit}"]
        occ = [f"{n} {k}" + (f" ({self.zeros[n]} written as zeros)" if self.zeros.get(n) else "")
               for n, k in self.occluded.items() if k]
        parts.append("occluded samples: " + (", ".join(occ) if occ else "none"))
        return "; ".join(parts)


def name_map(labels: list[str], where: str) -> dict[str, str]:
    """The session name of each export label: the part after the last ':' (Vicon, Motive and
    Qualisys write ``Subject:M1``), or the whole label with ':' and spaces as '_' where two labels
    would share that part; BadInput for an empty label."""
    short = {}
    for lb in labels:
        s = lb.rsplit(":", 1)[-1].strip()
        if not s:
            raise BadInput(f"{where}: an empty name ({lb!r})")
        short[lb] = s
    out = {}
    for lb, s in short.items():
        clash = sum(1 for v in short.values() if v == s) > 1
        out[lb] = lb.strip().replace(":", "_").replace(" ", "_") if clash else s.replace(" ", "_")
    if len(set(out.values())) != len(out):
        raise BadInput(f"{where}: two names read as the same session name: {sorted(out.values())}")
    return out


def number(cell: str, where: str, decimal_comma: bool = False) -> float:
    """A cell as a number: NaN for an empty or 'nan' cell; BadInput naming ``where`` for text."""
    c = cell.strip()
    if c == "" or c.lower() == "nan":
        return np.nan
    if decimal_comma:
        c = c.replace(",", ".")
    try:
        v = float(c)
    except ValueError:
        raise BadInput(f"{where}: expected a number, got {cell.strip()!r}") from None
    if not np.isfinite(v):
        raise BadInput(f"{where}: {cell.strip()!r} is not a finite number")
    return v


def occlude_points(rec: Recording, name: str, xyz: np.ndarray, zeros_missing: bool) -> np.ndarray:
    """``xyz`` (K, 3) with a sample partly empty or (``zeros_missing``) exactly 0,0,0 set to NaN;
    counts in ``rec.occluded`` / ``rec.zeros``."""
    xyz = np.array(xyz, float)
    empty = ~np.isfinite(xyz).all(axis=1)
    zero = np.all(xyz == 0.0, axis=1) if zeros_missing else np.zeros(len(xyz), bool)
    xyz[empty | zero] = np.nan
    rec.occluded[name] = int(np.sum(empty | zero))
    rec.zeros[name] = int(np.sum(zero))
    return xyz


def checked_quaternions(q: np.ndarray, where_row) -> np.ndarray:
    """(K, 4) w,x,y,z quaternions normalised; NaN rows stay NaN; BadInput naming the first row
    (``where_row(k)``) whose norm is not within QUAT_NORM_TOL of 1."""
    q = np.asarray(q, float)
    n = np.linalg.norm(q, axis=1)
    ok = np.isfinite(n)
    bad = np.nonzero(ok & (np.abs(n - 1.0) > QUAT_NORM_TOL))[0]
    if bad.size:
        raise BadInput(f"{where_row(int(bad[0]))}: the quaternion has norm {n[bad[0]]:.6g}, expected 1")
    out = np.full_like(q, np.nan)
    out[ok] = quat_normalize(q[ok])
    return out
