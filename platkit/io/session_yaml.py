"""session.yaml: read and checked field by field (docs/session-format.md)."""
from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

from platkit.errors import BadSession
from platkit.io.description import load_yaml
from platkit.model import LENGTH_UNITS
from platkit.tree_loads import parse_payload, payload_option

#: session.yaml keys platkit reads; any other key is a typo or a newer format, and an error.
SESSION_KEYS = (
    "platform", "description", "units", "markers", "base_markers", "mocap_rate_hz", "imu",
    "moving_link", "notes", "markers_file", "markers_time_offset", "base_link",
    "date",  # (platkit) when it was recorded, ISO 8601: orders a stand's history (platkit batch --history)
    "power_on_t",  # (platkit) when the stand was switched on, on the clock of t: its warm-up (docs/session-format.md)
    "rigid_bodies", "rigid_body_noise",  # 6-DOF bodies (spec section 1) and (platkit) their declared noise
    "payload",  # (platkit) a load the robot carries in this session: {link, mass_kg, com_m} or a list (URDF stands)
)
#: session.yaml ``rigid_body_noise`` keys: each sigma per axis, with its unit in the name
BODY_NOISE_KEYS = {"position_mm": 1e-3, "position_m": 1.0, "rotation_deg": math.pi / 180, "rotation_rad": 1.0}
TIME_UNITS = {"s": 1.0, "ms": 1e-3}
#: keys of session.yaml's ``imu`` mapping: the spec's rate_hz and frame, and (platkit) the
#: sensor's full scale, which flags saturated samples (platkit.io.imu)
IMU_KEYS = ("rate_hz", "frame", "gyr_range_rad_s", "acc_range_m_s2")
#: session.yaml ``platform`` values that mean "no stand" (spec: "none for an IMU-only recording")
NO_PLATFORM = ("none",)


def _names(value, key: str, path: Path) -> list[str]:
    if value is None:
        return []
    if not isinstance(value, list) or not all(isinstance(v, str) and v.strip() for v in value):
        raise BadSession(f"{path}: field {key!r} must be a list of marker names")
    names = [v.strip() for v in value]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadSession(f"{path}: field {key!r} names {dup} more than once")
    for n in names:
        if not all(ch.isalnum() or ch in "-." or ch == "_" for ch in n):
            raise BadSession(f"{path}: field {key!r}: marker name {n!r} may hold only letters, digits, '_', '-', '.'")
    return names


def _body_noise(value, path: Path) -> dict:
    """session.yaml ``rigid_body_noise`` (e.g. {position_mm: 0.1, rotation_deg: 0.05}, per-axis
    sigmas) -> {'position_m', 'rotation_rad'}, or {} when not given."""
    if value is None:
        return {}
    form = "a mapping like {position_mm: 0.1, rotation_deg: 0.05} (per-axis sigmas)"
    if not isinstance(value, dict):
        raise BadSession(f"{path}: field 'rigid_body_noise' must be {form}")
    unknown = sorted(set(value) - set(BODY_NOISE_KEYS), key=str)
    if unknown:
        raise BadSession(f"{path}: field 'rigid_body_noise' has unknown key {unknown[0]!r}; known keys: "
                         f"{', '.join(BODY_NOISE_KEYS)}")
    out = {}
    for kind in ("position", "rotation"):
        keys = [k for k in value if k.startswith(kind)]
        if len(keys) != 1:
            raise BadSession(f"{path}: field 'rigid_body_noise' needs one {kind} sigma; it must be {form}")
        v = value[keys[0]]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or not math.isfinite(v):
            raise BadSession(f"{path}: field 'rigid_body_noise.{keys[0]}' must be a positive number, got {v!r}")
        out[f"{kind}_{'m' if kind == 'position' else 'rad'}"] = float(v) * BODY_NOISE_KEYS[keys[0]]
    return out


def _link_mapping(value: dict, markers: list[str], bodies: list[str], path: Path) -> dict:
    """A tree's ``moving_link``: {marker or rigid body: link}, every declared marker and body mapped
    (spec section 1), e.g. {R: right_tcp, L: left_tcp}."""
    for k, v in value.items():
        if not isinstance(k, str) or not isinstance(v, str) or not v.strip():
            raise BadSession(f"{path}: field 'moving_link' must map marker names to link names, e.g. "
                             f"{{R: right_tcp, L: left_tcp}}; got {k!r}: {v!r}")
        if k not in markers and k not in bodies:
            raise BadSession(f"{path}: field 'moving_link.{k}': {k!r} is not a marker or rigid body of 'markers' "
                             "or 'rigid_bodies'")
    missing = [n for n in markers + bodies if n not in value]
    if missing:
        raise BadSession(f"{path}: field 'moving_link' maps markers to links but not {missing[0]!r}; on a tree every "
                         "marker and rigid body names its link")
    return {k: v.strip() for k, v in value.items()}


def iso_when(value, path: Path, field: str, error=BadSession) -> dt.datetime | dt.date:
    """An ISO date or date-time from YAML (already a date or datetime, or text; a date-time with a zone
    in UTC, naive); anything else is ``error`` naming the file and the field."""
    if isinstance(value, dt.datetime):
        return value.replace(tzinfo=None) if value.tzinfo is None else value.astimezone(dt.UTC).replace(tzinfo=None)
    if isinstance(value, dt.date):
        return value
    text = str(value).strip()
    try:
        if len(text) <= 10:
            return dt.date.fromisoformat(text)
        when = dt.datetime.fromisoformat(text.replace("Z", "+00:00"))
        return when if when.tzinfo is None else when.astimezone(dt.UTC).replace(tzinfo=None)
    except ValueError:
        raise error(f"{path}: field '{field}': expected an ISO date or date-time such as 2026-03-01 or "
                    f"2026-03-01T14:30, got {value!r}") from None


def read_session_yaml(folder: Path) -> dict:
    """session.yaml checked field by field; returns a dict of clean values."""
    path = folder / "session.yaml"
    if folder.is_file():
        raise BadSession(f"{folder}: is a file; a session is a folder holding session.yaml")
    if not folder.is_dir():
        raise BadSession(f"{folder}: session folder not found")
    if not path.is_file():
        raise BadSession(f"{path}: file not found; a session folder needs session.yaml")
    data = load_yaml(path, error=BadSession)
    unknown = sorted(set(data) - set(SESSION_KEYS))
    if unknown:
        raise BadSession(f"{path}: unknown field {unknown[0]!r}; known fields: {', '.join(SESSION_KEYS)}")
    out: dict = {}
    platform = data.get("platform")
    if platform is not None and (not isinstance(platform, str) or not platform.strip()):
        raise BadSession(f"{path}: field 'platform' must be a stand name, or none for an IMU-only recording")
    if isinstance(platform, str) and platform.strip().lower() in NO_PLATFORM:
        platform = None  # YAML reads `none` as text; the spec means no stand
    out["platform"] = platform.strip() if isinstance(platform, str) else None
    desc = data.get("description")
    if desc is not None and not isinstance(desc, str):
        raise BadSession(f"{path}: field 'description' must be a file path relative to the folder, or null")
    out["description"] = None
    if desc:
        dpath = (folder / desc) if not Path(desc).is_absolute() else Path(desc)
        if not dpath.is_file():
            raise BadSession(f"{path}: field 'description': file {dpath} not found")
        out["description"] = dpath
    units = data.get("units")
    if units is None:
        raise BadSession(f"{path}: missing field 'units'; declare e.g. units: {{length: mm, time: s}}")
    if not isinstance(units, dict):
        raise BadSession(f"{path}: field 'units' must be a mapping like {{length: mm, time: s}}")
    extra = sorted(set(units) - {"length", "time"})
    if extra:
        raise BadSession(f"{path}: field 'units' has unknown key {extra[0]!r}; expected length and time")
    length = units.get("length")
    if length not in LENGTH_UNITS:
        raise BadSession(
            f"{path}: field 'units.length' must be one of {', '.join(sorted(LENGTH_UNITS))}, got {length!r}"
        )
    time = units.get("time")
    if time not in TIME_UNITS:
        raise BadSession(f"{path}: field 'units.time' must be one of {', '.join(TIME_UNITS)}, got {time!r}")
    out["length_unit"], out["time_unit"] = length, time
    out["markers"] = _names(data.get("markers"), "markers", path)
    out["base_markers"] = _names(data.get("base_markers"), "base_markers", path)
    both = sorted(set(out["markers"]) & set(out["base_markers"]))
    if both:
        raise BadSession(f"{path}: marker {both[0]!r} is listed in both 'markers' and 'base_markers'")
    out["rigid_bodies"] = _names(data.get("rigid_bodies"), "rigid_bodies", path)
    both = sorted(set(out["rigid_bodies"]) & set(out["markers"] + out["base_markers"]))
    if both:
        raise BadSession(f"{path}: {both[0]!r} is listed both as a marker and in 'rigid_bodies'")
    out["rigid_body_noise"] = _body_noise(data.get("rigid_body_noise"), path)
    rate = data.get("mocap_rate_hz")
    if rate is not None and (isinstance(rate, bool) or not isinstance(rate, (int, float)) or not rate > 0
                             or not math.isfinite(rate)):
        raise BadSession(f"{path}: field 'mocap_rate_hz' must be a positive number, got {rate!r}")
    out["mocap_rate_hz"] = None if rate is None else float(rate)
    imu = data.get("imu")
    if imu is not None:
        if not isinstance(imu, dict):
            raise BadSession(f"{path}: field 'imu' must be null or a mapping like {{rate_hz: 200, frame: imu}}")
        unknown = sorted(set(imu) - set(IMU_KEYS), key=str)
        if unknown:
            raise BadSession(f"{path}: field 'imu' has unknown key {unknown[0]!r}; known keys: {', '.join(IMU_KEYS)}")
        for key in ("rate_hz", "gyr_range_rad_s", "acc_range_m_s2"):
            r = imu.get(key)
            if r is not None and (isinstance(r, bool) or not isinstance(r, (int, float)) or not r > 0
                                  or not math.isfinite(r)):
                raise BadSession(f"{path}: field 'imu.{key}' must be a positive number, got {r!r}")
        if "frame" in imu and not isinstance(imu["frame"], str):
            raise BadSession(f"{path}: field 'imu.frame' must be a frame name")
    out["imu"] = imu
    for key in ("moving_link", "base_link"):
        link = data.get(key)
        if key == "moving_link" and isinstance(link, dict):
            out[key] = _link_mapping(link, out["markers"], out["rigid_bodies"], path)
            continue
        if link is not None and (not isinstance(link, str) or not link.strip()):
            raise BadSession(f"{path}: field {key!r} must be a link name or null"
                             + (", or on a tree a mapping {marker: link}" if key == "moving_link" else ""))
        out[key] = link
    payload = parse_payload(data.get("payload"), f"{path}: field 'payload'", BadSession)
    out["payload"] = payload_option(payload) if payload else None
    notes = data.get("notes")
    out["notes"] = "" if notes is None else str(notes)
    mfile = data.get("markers_file")
    if mfile is not None and (not isinstance(mfile, str) or not mfile):
        raise BadSession(f"{path}: field 'markers_file' must be a file name in the folder, e.g. markers.c3d")
    out["markers_file"] = mfile
    off = data.get("markers_time_offset", 0.0)
    if isinstance(off, bool) or not isinstance(off, (int, float)) or not math.isfinite(off):
        raise BadSession(f"{path}: field 'markers_time_offset' must be a number of seconds, got {off!r}")
    out["markers_time_offset"] = float(off)
    on = data.get("power_on_t")
    if on is not None and (isinstance(on, bool) or not isinstance(on, (int, float)) or not math.isfinite(on)):
        raise BadSession(f"{path}: field 'power_on_t' must be the time the stand was switched on, a number on the "
                         f"clock of t in the session's time unit (negative: before t = 0), or null; got {on!r}")
    out["power_on_t"] = None if on is None else float(on)
    date = data.get("date")
    out["date"] = None if date is None else iso_when(date, path, "date")
    return out


# ----------------------------------------------------------------------------- controls
