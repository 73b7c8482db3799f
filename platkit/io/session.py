"""Recording sessions: a folder with session.yaml, commands.csv, markers.csv (or poses.csv, or a
C3D file) and optionally imu.csv. See docs/session-format.md.

``platform: none`` (or null) in session.yaml is an IMU-only recording: it has no stand, so nothing
is checked against controls and commands.csv may be absent; imu.csv is then required. imu.csv is
read by :func:`platkit.io.imu.read_imu_csv`, the one IMU reader, which repairs short gaps
(and says so in ``Session.imu_notes``) and names the file, line and column of anything else.

Units are declared in session.yaml, never guessed. Everything is converted to SI on reading:
controls with :func:`platkit.model.controls_to_si`, marker coordinates to metres, times to
seconds. Every problem is one :class:`~platkit.errors.BadSession` line naming the file, the row
(1-based data row, with the file line) or column, and what was expected.

This module reads a session folder into a :class:`Session`; its parts are one concept each:
session.yaml in :mod:`platkit.io.session_yaml`, the chunked CSV reader in
:mod:`platkit.io.table`, the checks of the streams and controls in
:mod:`platkit.io.session_checks`, C3D in :mod:`platkit.io.c3d`; their names are imported from
there.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadInput, BadSession
from platkit.io.c3d import read_c3d_markers
from platkit.io.importers import export_format, read_recording
from platkit.io.imu import DEFAULT_MAX_REPAIR_S, ImuStream, read_imu_csv
from platkit.io.session_checks import (
    BODY_SUFFIXES,
    _body_block,
    _body_counts,
    _check_marker_header,
    _check_plausible_unit,
    _check_seen,
    _marker_block,
    check_controls,
    check_stream_times,
    check_times,
    checked_marker_block,
)
from platkit.io.session_yaml import TIME_UNITS, _link_mapping, read_session_yaml
from platkit.io.shipped import shipped_dir
from platkit.io.table import read_header, read_table
from platkit.model import LENGTH_UNITS, PlatformSpec
from platkit.plugins import get_platform

__all__ = ["Session", "load_session", "example_session", "EXAMPLES_ENV"]


@dataclass
class Session:
    """A recording session read from its folder; SI units inside.

    Attributes:
        folder: the session folder. platform: stand name or None (``platform: none`` or null in
            session.yaml, and none given: an IMU-only recording).
        spec: the stand's PlatformSpec built with the session's description, or None.
        description: the description file used (None: the stand's default).
        length_unit, time_unit: as declared in session.yaml.
        marker_names (M,), base_marker_names (B,): as declared. body_names: the rigid bodies
            declared (``rigid_bodies``); body_noise: their declared noise {'position_m',
            'rotation_rad'} (per-axis sigmas) or empty.
        mocap_rate_hz: declared rate or None. imu: the declared imu mapping or None.
        moving_link: URDF link carrying the markers, or None; on a tree the mapping {marker or
            rigid body: link}. notes: free text.
        command_t (N,) s; commands (N, n_u) internal units ('m' controls in metres), or None
            without a stand (command_t is still read, and its times checked, if commands.csv
            exists) or without commands.csv.
        marker_t (K,) s and markers (K, M, 3) m (NaN = occluded), base_markers (K, B, 3) m:
            the raw motion-capture stream (from markers.csv or a C3D file), or None.
        bodies: (K, B_body, 7) the rigid bodies' stream from markers.csv (origin m, unit
            quaternion; all seven NaN where occluded), or None.
        poses: the reduced table of poses.csv as a dict (controls (N, n_u), markers (N, M, 3) m,
            n_samples (N, M) or None, t (N,) or None, bodies (N, B_body, 7), n_body_samples
            (N, B_body) or None), or None.
        imu_stream: the inertial stream from imu.csv as read and repaired by
            :func:`platkit.io.imu.read_imu_csv` (times in s), or None.
        imu_t (J,) s, imu_gyr (J, 3) rad/s, imu_acc (J, 3) m/s^2: the same stream's arrays.
        imu_notes: one sentence per repair made while reading imu.csv, and per axis with
            saturated samples (empty: the file was used as it is).
    """

    folder: Path
    platform: str | None
    spec: PlatformSpec | None
    description: Path | None
    length_unit: str
    time_unit: str
    marker_names: list[str]
    base_marker_names: list[str]
    mocap_rate_hz: float | None
    imu: dict | None
    moving_link: str | dict | None
    notes: str
    command_t: np.ndarray | None = None
    commands: np.ndarray | None = None
    marker_t: np.ndarray | None = None
    markers: np.ndarray | None = None
    base_markers: np.ndarray | None = None
    poses: dict | None = None
    imu_t: np.ndarray | None = None
    imu_gyr: np.ndarray | None = None
    imu_acc: np.ndarray | None = None
    imu_stream: ImuStream | None = None
    imu_notes: list[str] = field(default_factory=list)
    markers_source: Path | None = None
    extras: dict = field(default_factory=dict)
    body_names: list[str] = field(default_factory=list)
    body_noise: dict = field(default_factory=dict)
    bodies: np.ndarray | None = None

    @property
    def has_markers(self) -> bool:
        return self.markers is not None or self.poses is not None

    def since_power_on(self, t: np.ndarray | None) -> np.ndarray | None:
        """(N,) seconds since the stand was switched on (session.yaml's ``power_on_t``) at times
        ``t`` (N,) s on the clock of t; None where the session does not say it or t is unknown."""
        on = self.extras.get("power_on_t")
        if on is None or t is None or not np.all(np.isfinite(np.asarray(t, float))):
            return None
        return np.asarray(t, float) - float(on)


def load_session(folder: str | Path, platform: str | None = None, description: str | Path | None = None,
                 spec: PlatformSpec | None = None, imu_max_repair_s: float = DEFAULT_MAX_REPAIR_S,
                 quiet: bool = False) -> Session:
    """Read and check a session folder.

    ``platform``: the stand to read it for (default: session.yaml's); a different name from
    session.yaml's is an error. ``description``: overrides session.yaml's description file.
    ``spec``: an already built stand (skips the plugin lookup; tests and simulation).
    ``imu_max_repair_s``: missing IMU cells and time gaps up to this long (s) are interpolated
    and stated in ``imu_notes``; longer ones are errors. ``quiet``: no progress on stderr while a
    large motion-capture stream is read (:func:`read_table`).
    A session without a stand (``platform: none`` and none given) needs no commands.csv, and
    nothing in it is checked against controls; it needs imu.csv.
    Raises BadSession (one line: file, row or column, what was expected).
    """
    folder = Path(folder)
    y = read_session_yaml(folder)
    ypath = folder / "session.yaml"
    name = y["platform"]
    if spec is not None:
        platform = platform or spec.name
    if platform is not None and name is not None and platform != name:
        raise BadSession(f"{ypath}: the session is for the {name!r} stand, not {platform!r}")
    name = name or platform
    desc_path = Path(description) if description is not None else y["description"]
    joints_file = None
    built = False
    if spec is None and name is not None:

        options = {k: y[k] for k in ("moving_link", "base_link", "payload") if y[k]}
        if isinstance(y["moving_link"], dict):  # a tree: the recorded joints are the controls
            joints_file, options["joints"] = recorded_joints(folder, y)
        spec = _stand(name, desc_path, options, joints_file, ypath)
        built = True
    if spec is not None and not built:
        _same_payload(spec, y["payload"], ypath)
    mapping = (spec.extras.get("platform_options") or {}).get("moving_link") if spec is not None else None
    if spec is not None and not isinstance(y["moving_link"], dict) and isinstance(mapping, dict):
        # the stand's description (or the calibration read with it) maps the markers to links: a
        # tree, the session's mapping as if session.yaml had said it, its recorded joints the controls
        y = dict(y, moving_link=_link_mapping(dict(mapping), y["markers"], y["rigid_bodies"],
                                              Path(spec.description_path or desc_path or ypath)))
        if built:
            joints_file, options["joints"] = recorded_joints(folder, y)
            spec = _stand(name, desc_path, options, joints_file, ypath)
    s = Session(
        folder=folder, platform=name, spec=spec, description=desc_path, length_unit=y["length_unit"],
        time_unit=y["time_unit"], marker_names=y["markers"], base_marker_names=y["base_markers"],
        mocap_rate_hz=y["mocap_rate_hz"], imu=y["imu"], moving_link=y["moving_link"], notes=y["notes"],
        body_names=y["rigid_bodies"], body_noise=y["rigid_body_noise"],
    )
    if isinstance(y["moving_link"], dict) and spec is not None:  # a tree, however its stand was built
        _say_held_joints(s, joints_file or _joints_file(folder))
    tscale = TIME_UNITS[s.time_unit]
    lscale = LENGTH_UNITS[s.length_unit]
    if y.get("power_on_t") is not None:  # s on the clock of t
        s.extras["power_on_t"] = y["power_on_t"] * tscale

    # commands
    cpath = folder / "commands.csv"
    poses_path = folder / "poses.csv"
    if spec is not None and y["platform"] is None and not cpath.is_file() and not poses_path.is_file():
        raise BadSession(
            f"{cpath}: file not found; session.yaml declares no platform (an IMU-only recording), and reading "
            f"it for the {spec.name} stand needs its command log"
        )
    if spec is None and cpath.is_file():
        _read_commands_without_stand(s, cpath, tscale)
    elif spec is not None and (cpath.is_file() or not poses_path.is_file()):
        table = read_table(cpath, "the command log")
        extra = [c for c in table.header if c not in ["t"] + spec.control_names]
        if extra:
            raise BadSession(
                f"{cpath}: column {extra[0]!r} is not a control of the {spec.name} stand; expected columns "
                f"t, {', '.join(spec.control_names)} (is this a session for another stand?)"
            )
        s.commands = check_controls(table, spec, ["t"], s.length_unit, s.extras.setdefault("control_notes", []))
        t = table.column("t") * tscale
        check_times(table, t)
        s.command_t = t

    # motion-capture markers: markers.csv, a C3D file, or the reduced poses.csv
    _read_markers(s, y, folder, lscale, tscale, quiet)
    if s.marker_t is not None and s.markers_source is not None:  # its times against mocap_rate_hz and the commands
        check_stream_times(s.marker_t, s.markers_source, s.time_unit, s.mocap_rate_hz, s.command_t, cpath)
    if s.markers is not None and poses_path.is_file():  # said, so that nobody believes the other file was used
        name = s.markers_source.name if s.markers_source is not None else "the marker stream"
        s.extras.setdefault("control_notes", []).append(
            f"{folder} holds both {name} and poses.csv: {name} (the raw stream, settled by platkit) is used, "
            "poses.csv is ignored; move one out to choose")
    if s.has_markers and not s.marker_names and not s.body_names:
        raise BadSession(f"{ypath}: field 'markers' must name the markers on the moving part (or 'rigid_bodies' "
                         "the bodies measured in 6 DOF)")

    imu_path = folder / "imu.csv"
    if imu_path.is_file():
        _read_imu(s, imu_path, tscale, imu_max_repair_s)
    elif s.imu is not None:
        raise BadSession(f"{ypath}: field 'imu' declares an inertial stream but {imu_path} is missing")
    elif spec is None:
        raise BadSession(
            f"{imu_path}: file not found; session.yaml declares no platform, so this is an IMU-only recording and "
            f"needs its inertial stream (or name the stand in session.yaml's field 'platform')"
        )
    if s.commands is None and s.poses is None and s.imu_t is None:
        raise BadSession(f"{cpath}: file not found; a session needs commands.csv (or poses.csv)")
    return s


def _read_markers(s: Session, y: dict, folder: Path, lscale: float, tscale: float, quiet: bool) -> None:
    """The session's motion capture into ``s``: session.yaml's markers_file (a vendor export,
    recognised by its content; a C3D file; a CSV), else markers.csv (a vendor export saved under
    that name, or the spec's table), else the reduced poses.csv; none is left for the caller."""
    ypath = folder / "session.yaml"
    poses_path = folder / "poses.csv"
    if y["markers_file"]:
        mpath = folder / y["markers_file"]
        fmt = export_format(mpath) or ("c3d" if mpath.suffix.lower() == ".c3d" and s.body_names else None)
        if fmt is not None:  # a vendor export, recognised by its content; a C3D file's bodies are its rotations
            _read_markers_export(s, mpath, fmt, y["markers_time_offset"])
        elif mpath.suffix.lower() == ".c3d":
            _read_markers_c3d(s, mpath, y["markers_time_offset"])
        elif mpath.suffix.lower() == ".csv":
            _read_markers_csv(s, mpath, lscale, tscale, y["markers_time_offset"], quiet)
        else:
            raise BadSession(f"{ypath}: field 'markers_file' must name a .csv or .c3d file, or a Vicon, Qualisys "
                             f"or Motive export, got {y['markers_file']!r}")
    elif (folder / "markers.csv").is_file() and export_format(folder / "markers.csv"):
        # a vendor export saved as markers.csv: read by its content (docs/importers.md)
        _read_markers_export(s, folder / "markers.csv", export_format(folder / "markers.csv") or "", y["markers_time_offset"])
    elif (folder / "markers.csv").is_file():
        _read_markers_csv(s, folder / "markers.csv", lscale, tscale, y["markers_time_offset"], quiet)
    elif poses_path.is_file():
        _read_poses_csv(s, poses_path, lscale, tscale)


#: how the urdf stand names the recorded joints in its errors (replaced by the file that listed them)
JOINTS_WHERE = "urdf stand option 'joints'"


def _stand(name: str, description, options: dict, joints_file: Path | None, ypath: Path) -> PlatformSpec:
    """The stand a session names, its errors as BadSession naming session.yaml (or the file whose
    columns are a tree's recorded joints, for errors about them)."""
    try:
        return get_platform(name, description, **options)
    except BadInput as exc:
        text = str(exc)
        if joints_file is not None and text.startswith(JOINTS_WHERE):
            raise BadSession(f"{joints_file}{text[len(JOINTS_WHERE):]}") from None
        raise BadSession(f"{ypath}: {exc}") from None


def _same_payload(spec: PlatformSpec, payload: list | None, ypath: Path) -> None:
    """A session read with a stand already built (a calibration's) carries that stand's payload:
    BadSession otherwise, since its loads would be another's (predict takes another payload)."""
    given = (spec.extras.get("platform_options") or {}).get("payload") or None
    if (payload or None) == given:
        return
    def said(p):
        return "none" if not p else ", ".join(f"{q['mass_kg']:g} kg at {q['link']}" for q in p)
    raise BadSession(f"{ypath}: field 'payload': the session carries {said(payload)}, the stand it is read with "
                     f"(its calibration's) {said(given)}; a fit's sessions carry one payload (to predict another: "
                     "platkit predict --payload)")


def _joints_file(folder: Path) -> Path:
    """The file whose columns are a tree session's recorded joints: commands.csv, or poses.csv
    without it."""
    cpath = folder / "commands.csv"
    return cpath if cpath.is_file() or not (folder / "poses.csv").is_file() else folder / "poses.csv"


def _say_held_joints(s: Session, joints_file: Path) -> None:
    """On a tree session: the joints below a recorded joint that the file does not record (held
    at their zero), said among the control notes, since the loads of the joints above them take
    that pose (docs/trees.md)."""
    chain = s.spec.extras.get("chain") if s.spec is not None else None
    held = chain.held_under_recorded() if chain is not None and hasattr(chain, "held_under_recorded") else []
    if held:
        shown = ", ".join(held[:12]) + (f" and {len(held) - 12} more" if len(held) > 12 else "")
        s.extras.setdefault("control_notes", []).append(
            f"{joints_file}: not recorded, below recorded joints: {shown}; held at their zero (a mimic joint at its "
            "offset): they move no tracked link, but the gravity loads of the recorded joints above them are "
            "computed in that pose")


def recorded_joints(folder: Path, y: dict) -> tuple[Path, list[str]]:
    """(file, joint names) of a tree session: the columns of commands.csv but ``t`` (of poses.csv
    without commands.csv: but ``t`` and the marker, count and rigid-body columns)."""
    cpath = folder / "commands.csv"
    path = _joints_file(folder)
    if not path.is_file():
        raise BadSession(f"{cpath}: file not found; a session needs commands.csv (or poses.csv)")
    header, _ = read_header(path)
    if path == cpath:
        return path, [h for h in header if h != "t"]
    taken = {"t"}
    for m in y["markers"] + y["base_markers"]:
        taken.update(f"{m}_{a}" for a in ("x", "y", "z", "n"))
    for b in y["rigid_bodies"]:
        taken.update(f"{b}_{a}" for a in BODY_SUFFIXES + ("n",))
    return path, [h for h in header if h not in taken]


def _read_imu(s: Session, path: Path, tscale: float, max_repair_s: float) -> None:
    """imu.csv through the inertial reader (repairs stated, errors naming line and column);
    times scaled to seconds. The declared full scale, if any, flags saturated samples."""
    declared = s.imu or {}
    stream = read_imu_csv(path, max_repair_s=max_repair_s, gyr_range=declared.get("gyr_range_rad_s"),
                          acc_range=declared.get("acc_range_m_s2"), time_scale=tscale,
                          declared_rate_hz=declared.get("rate_hz"))
    s.imu_stream, s.imu_notes = stream, stream.warnings()
    s.imu_t, s.imu_gyr, s.imu_acc = stream.t, stream.gyr, stream.acc


def _read_commands_without_stand(s: Session, path: Path, tscale: float) -> None:
    """commands.csv of a session without a stand: its times are read and checked (the IMU's
    tools may use them); the control columns cannot be interpreted, only required to be
    present and numeric."""
    table = read_table(path, "the command log")
    if "t" not in table.header:
        raise BadSession(f"{path}: missing column 't'; the command log starts with the command times")
    t = table.column("t") * tscale
    check_times(table, t)
    for j, name in enumerate(table.header):
        bad = np.nonzero(~np.isfinite(table.data[:, j]))[0]
        if bad.size:
            raise BadSession(f"{table.where(int(bad[0]), name)}: empty or nan; every command needs every control")
    s.command_t = t


def _read_markers_csv(s: Session, path: Path, lscale: float, tscale: float, offset: float, quiet: bool = False) -> None:
    names = s.marker_names + s.base_marker_names
    if not s.marker_names and not s.body_names:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'markers' must name the markers of {path.name}")
    table = read_table(path, "the motion-capture stream", quiet=quiet)
    _check_marker_header(table, names, ["t"], bodies=s.body_names)
    t = table.column("t") * tscale + offset
    check_times(table, t)
    if s.body_names:  # before the markers are scaled in place
        s.bodies = _body_block(table, s.body_names, lscale)
        _check_plausible_unit(table, s.bodies[..., :3], s.length_unit, s.body_names)
    xyz = checked_marker_block(table, names, lscale, s.length_unit)  # scaled in place: the table is not used after
    M = len(s.marker_names)
    s.marker_t, s.markers, s.base_markers, s.markers_source = t, xyz[:, :M], xyz[:, M:], path


def _read_markers_export(s: Session, path: Path, fmt: str, offset: float) -> None:
    """The marker stream (and rigid bodies) from a vendor export (platkit.io.importers: Vicon CSV,
    Qualisys TSV, Motive CSV, C3D with rotations), times shifted by ``offset`` (s). The export
    says its length unit, which must be session.yaml's; names match as the importers map them
    (``Subject:M1`` is ``M1``); what the export read and left out is said in the control notes."""
    rec = read_recording(path, fmt)
    ypath = s.folder / "session.yaml"
    if rec.unit != s.length_unit:
        raise BadSession(f"{path}: the export's lengths are in {rec.unit}, session.yaml declares {s.length_unit}")
    names = s.marker_names + s.base_marker_names
    for kind, want, have in (("marker", names, rec.markers), ("rigid body", s.body_names, rec.bodies)):
        missing = [n for n in want if n not in have]
        if missing:
            raise BadSession(f"{path}: no {kind} {missing[0]!r} (declared in {ypath}); the export has "
                             f"{', '.join(have) or 'none'}")
    scale = LENGTH_UNITS[rec.unit]
    K = rec.n_samples
    xyz = np.stack([rec.markers[n] for n in names], axis=1) * scale if names else np.zeros((K, 0, 3))
    if s.body_names:
        s.bodies = np.stack([np.column_stack([rec.bodies[b][0] * scale, rec.bodies[b][1]]) for b in s.body_names], axis=1)
        for k, b in enumerate(s.body_names):
            if not np.isfinite(s.bodies[:, k]).all(axis=1).any():
                raise BadSession(f"{path}: rigid body {b!r} is never seen; remove it from {ypath}'s rigid_bodies")
    M = len(s.marker_names)
    s.marker_t, s.markers, s.base_markers, s.markers_source = rec.t + offset, xyz[:, :M], xyz[:, M:], path
    if names:
        _check_seen(xyz, names, path)
    s.extras.setdefault("control_notes", []).extend([rec.summary()] + [f"{path.name}: {n}" for n in rec.notes])


def _read_markers_c3d(s: Session, path: Path, offset: float) -> None:
    """The marker stream from a C3D file (platkit.io.c3d), times shifted by ``offset`` (s)."""
    if s.body_names:
        raise BadSession(f"{s.folder / 'session.yaml'}: rigid bodies are not read from C3D files ({path.name}); give "
                         "them as the seven columns of each body in markers.csv (or poses.csv)")
    t, xyz = read_c3d_markers(path, s.marker_names + s.base_marker_names)
    t = t + offset
    s.marker_t, s.markers_source = t, path
    M = len(s.marker_names)
    s.markers, s.base_markers = xyz[:, :M], xyz[:, M:]
    _check_seen(xyz, s.marker_names + s.base_marker_names, path)


def _read_poses_csv(s: Session, path: Path, lscale: float, tscale: float) -> None:
    if s.spec is None:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'platform' must name the stand that {path.name} is for")
    if not s.marker_names and not s.body_names:
        raise BadSession(f"{s.folder / 'session.yaml'}: field 'markers' must name the markers of {path.name}")
    table = read_table(path, "the settled poses")
    leading = (["t"] if "t" in table.header else []) + s.spec.control_names
    names = s.marker_names + s.base_marker_names
    _check_marker_header(table, names, leading, optional_suffixes=("n",), bodies=s.body_names)
    controls = check_controls(table, s.spec, leading[:1] if leading[:1] == ["t"] else [], s.length_unit,
                              s.extras.setdefault("control_notes", []))
    t = None
    if "t" in table.header:
        t = table.column("t") * tscale
        check_times(table, t)
    xyz = _marker_block(table, names, lscale)
    _check_seen(xyz, names, path)
    _check_plausible_unit(table, xyz, s.length_unit, names)
    n = None
    if any(f"{m}_n" in table.header for m in s.marker_names):
        n = np.zeros((len(table.data), len(s.marker_names)))
        for k, m in enumerate(s.marker_names):
            col = f"{m}_n"
            if col not in table.header:
                raise BadSession(f"{path}: missing column {col!r}; give <marker>_n for every marker or none")
            v = table.column(col)
            bad = np.nonzero(~np.isfinite(v) | (v < 0) | (v != np.round(v)))[0]
            if bad.size:
                raise BadSession(f"{table.where(int(bad[0]), col)}: expected a whole number of samples >= 0")
            n[:, k] = v
        seen = np.isfinite(xyz[:, : len(s.marker_names)]).all(axis=2)
        clash = np.argwhere(seen != (n > 0))
        if clash.size:
            r, k = clash[0]
            raise BadSession(
                f"{table.where(int(r), s.marker_names[k] + '_n')}: {int(n[r, k])} samples but the position is "
                f"{'given' if seen[r, k] else 'empty'}"
            )
    bodies = _body_block(table, s.body_names, lscale)
    _check_plausible_unit(table, bodies[..., :3], s.length_unit, s.body_names)
    M = len(s.marker_names)
    base = xyz[:, M:]
    s.poses = {"controls": controls, "markers": xyz[:, :M], "n_samples": n, "t": t, "bodies": bodies,
               "n_body_samples": _body_counts(table, s.body_names, bodies, path)}
    s.base_markers = base if base.shape[1] else None
    s.markers_source = path
    if s.command_t is not None and len(s.command_t) != len(controls):
        raise BadSession(
            f"{path}: {len(controls)} poses but commands.csv has {len(s.command_t)} rows; poses.csv has one row per command"
        )
    if t is None and s.command_t is not None:
        s.poses["t"] = s.command_t


EXAMPLES_ENV = "PLATKIT_EXAMPLES"


def example_session(platform: str) -> Path:
    """The example session shipped for ``platform``: ``<platform>/`` under the directories of the
    ``PLATKIT_EXAMPLES`` variable, else under the example sessions installed with platkit (the
    repository's examples/sessions/, the package ``platkit_data.sessions``). BadSession if none."""
    searched = [Path(d) for d in os.environ.get(EXAMPLES_ENV, "").split(os.pathsep) if d]
    for folder in searched:
        if (folder / platform / "session.yaml").is_file():
            return folder / platform
    searched.append(shipped_dir("sessions"))
    if (searched[-1] / platform / "session.yaml").is_file():
        return searched[-1] / platform
    raise BadSession(
        f"no example session for the {platform!r} stand (looked for {platform}/session.yaml in "
        f"{', '.join(str(d) for d in searched)})"
    )
