"""Motion-capture exports as users have them, read into one in-memory recording and written as a
session folder in the spec's format (docs/importers.md).

Formats, recognised by their content (never by the file name alone):

- Vicon Nexus / Tracker CSV export (:mod:`.vicon`): sections ("Trajectories", "Segments",
  "Objects"), each a rate row, a name row, a component row (X,Y,Z / RX,RY,RZ,TX,TY,TZ), a units row;
- Qualisys QTM TSV export (:mod:`.qualisys`): the header block (NO_OF_FRAMES, FREQUENCY,
  MARKER_NAMES or BODY_NAMES, ...), then the data, 3D (markers) or 6D (rigid bodies);
- OptiTrack Motive CSV export (:mod:`.motive`): the metadata row (Format Version, Length Units,
  Rotation Type, ...), the Type / Name / ID / Rotation-Position / component rows, then frames;
  rigid bodies' quaternions in x,y,z,w order;
- C3D (:func:`platkit.io.c3d.read_c3d_recording`): points and the ROTATION group's 6-DOF bodies;
- plain tables (:mod:`.plain`): the spec's columns with a comma, semicolon or tab separator, and
  decimal commas where the separator is not a comma (the length unit must be given).

Positions keep the file's unit (mm or m; a file in cm is converted to mm), quaternions are the
spec's w,x,y,z, times are seconds. Occluded samples (empty cells, NaN, or the zeros some
exporters write for a missing sample) are NaN and counted per name.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from platkit.errors import BadInput, BadSession
from platkit.io.atomic import atomic_output_dir
from platkit.io.c3d import read_c3d_recording
from platkit.io.importers import motive, plain, qualisys, vicon
from platkit.io.recording import Recording

__all__ = ["FORMATS", "Recording", "export_format", "read_recording", "sniff", "write_session"]

#: what ``platkit import --format`` accepts
FORMATS = ("vicon", "qualisys", "motive", "c3d", "table")


def sniff(path: str | Path) -> str:
    """The format of an export by its content: one of FORMATS; BadInput when it is none of them."""
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"{path}: file not found")
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if len(head) >= 2 and head[1] == 0x50 and path.suffix.lower() == ".c3d":
        return "c3d"
    text = head.decode("utf-8-sig", errors="replace")
    first = text.splitlines()[0] if text.strip() else ""
    cells = [c.strip() for c in first.replace("\t", ",").split(",")]
    if cells and cells[0] == "Format Version":
        return "motive"
    if cells and vicon.section_name(cells[0]):
        return "vicon"
    if first.startswith("NO_OF_FRAMES"):
        return "qualisys"
    if head[:1] != b"\x00" and cells and cells[0].replace(";", ",").split(",")[0].strip() == "t":
        return "table"
    raise BadInput(f"{path}: not a format platkit import knows (Vicon CSV, Qualisys TSV, OptiTrack Motive CSV, "
                   f"C3D, or a table whose first column is 't'); the first line is {first[:80]!r}")


def export_format(path: str | Path) -> str | None:
    """The vendor format of a file by its content (vicon, qualisys, motive), or None for anything
    else (the spec's own tables, a C3D file, an unreadable file): what the session loader reads
    through the importers."""
    try:
        fmt = sniff(path)
    except (BadInput, OSError):
        return None
    return fmt if fmt in ("vicon", "qualisys", "motive") else None


def read_recording(path: str | Path, fmt: str | None = None, unit: str | None = None) -> Recording:
    """Read an export (``fmt`` None: recognised by its content). ``unit`` (mm or m): the length
    unit of a plain table (required there: units are declared, never guessed); for the vendor
    formats, which say their unit, a ``unit`` that disagrees is an error."""
    path = Path(path)
    fmt = fmt or sniff(path)
    if fmt not in FORMATS:
        raise BadInput(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if unit is not None and unit not in ("mm", "m"):
        raise BadInput(f"--unit: {unit!r}; expected mm or m")
    if fmt == "table":
        if unit is None:
            raise BadInput(f"{path}: a plain table does not say its length unit: give it (--unit mm or --unit m)")
        return plain.read_table_export(path, unit)
    reader = {"vicon": vicon.read_vicon_csv, "qualisys": qualisys.read_qualisys_tsv,
              "motive": motive.read_motive_csv, "c3d": read_c3d_recording}[fmt]
    rec = reader(path)
    if unit is not None and unit != rec.unit:
        raise BadInput(f"{path}: the file says its lengths are in {rec.unit}, --unit says {unit}")
    return rec


def _cells(values: np.ndarray, fmt: str) -> list[str]:
    return ["" if not np.isfinite(v) else fmt % v for v in values]


def write_session(rec: Recording, out: str | Path, platform: str | None = None,
                  commands: str | Path | None = None, time_offset_s: float = 0.0) -> Path:
    """Write ``rec`` as a session folder (session.yaml, markers.csv, and commands.csv copied from
    ``commands``), whole or not at all. ``time_offset_s`` is added to the recording's times (to
    put them on the commands' clock)."""
    if not rec.markers and not rec.bodies:
        raise BadInput(f"{rec.source}: no markers and no rigid bodies to import")
    if commands is not None and not Path(commands).is_file():
        raise BadInput(f"{commands}: file not found (the command log)")
    if (platform is None) != (commands is None):
        raise BadInput("--platform and --commands go together: a session with a stand needs its command log")
    t = np.asarray(rec.t, float) + time_offset_s
    if len(t) > 1 and not np.all(np.diff(t) > 0):
        k = int(np.nonzero(~(np.diff(t) > 0))[0][0]) + 1
        raise BadSession(f"{rec.source}: sample {k + 1}: time {t[k]:.6g} s does not follow {t[k - 1]:.6g} s")
    header = ["t"]
    cols: list[list[str]] = [[f"{v:.6f}" for v in t]]
    digits = "%.4f" if rec.unit == "mm" else "%.7f"
    for name, xyz in rec.markers.items():
        header += [f"{name}_x", f"{name}_y", f"{name}_z"]
        cols += [_cells(xyz[:, j], digits) for j in range(3)]
    for name, (pos, q) in rec.bodies.items():
        header += [f"{name}_{c}" for c in ("x", "y", "z", "qw", "qx", "qy", "qz")]
        cols += [_cells(pos[:, j], digits) for j in range(3)] + [_cells(q[:, j], "%.9f") for j in range(4)]
    lines = [",".join(header)] + [",".join(row) for row in zip(*cols)]
    entry = {
        "platform": platform if platform is not None else "none",
        "description": None,
        "units": {"length": rec.unit, "time": "s"},
        "markers": list(rec.markers),
        "base_markers": [],
        "mocap_rate_hz": float(rec.rate_hz) if rec.rate_hz else None,
        "imu": None,
        "moving_link": None,
        "notes": "; ".join([f"imported by platkit import from {Path(rec.source).name} ({rec.format})", rec.summary()]
                           + rec.notes),
    }
    if rec.bodies:
        entry["rigid_bodies"] = list(rec.bodies)
    with atomic_output_dir(out) as tmp:
        (tmp / "session.yaml").write_text(yaml.safe_dump(entry, sort_keys=False), encoding="utf-8")
        (tmp / "markers.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
        if commands is not None:
            (tmp / "commands.csv").write_bytes(Path(commands).read_bytes())
    return Path(out)
