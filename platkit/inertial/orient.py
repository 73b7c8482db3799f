"""``platkit orient``: a session's inertial stream to the platform's orientation, with a report.

Inputs in the session folder: ``session.yaml``, ``imu.csv`` (required), ``commands.csv`` (when
the session has a platform), and optionally the truth:

- ``truth_orientation.csv``: ``t,qw,qx,qy,qz``, the platform frame in the base frame (times on
  the session's clock, in its time unit), e.g. from motion capture or a simulation;
- ``truth_imu.yaml``: the sensor's true errors, any of ``gyr_bias_rad_s`` (3, the gyro bias at
  the end of the recording, which the report compares with the estimate's last value),
  ``acc_bias_m_s2`` (3), ``gyr_scale`` (3), ``acc_scale`` (3), ``sensor_from_platform`` (3x3 rows),
  ``base_tilt_rad`` (2, the base tilted against the level about its x and y axes),
  ``gyr_bias_rate_rad_s2`` (3, a linear gyro bias drift); the last two are read, not compared.

Frames: the base frame has z up. The IMU's own axes are turned to the platform's by R_SP,
taken from ``--imu-calibration`` or, in a session with commands, estimated from it (rotations
between held poses, least squares); otherwise the sensor axes are taken as the platform's.
Without commands the heading is relative to the start; with them, the unaided estimators'
heading is aligned to the commanded poses over the held intervals.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadInput, BadSession, NotIdentifiable
from platkit.geometry import quat_conjugate, quat_from_matrix, quat_multiply, quat_normalize, rotvec_from_matrix
from platkit.inertial.calibration import ImuCalibration, gyro_bias_at_rest
from platkit.inertial.command_aided import (
    CommandAidedParams,
    command_poses,
    estimate_alignment_from_commands,
    estimate_command_aided,
    estimate_timing,
    held_mask,
)
from platkit.inertial.estimator import PlatkitParams, estimate_offline, estimate_platkit
from platkit.inertial.metrics import heading_aligned_total_error, inclination_error, rmse, total_error
from platkit.inertial.paper import PaperParams, estimate_paper
from platkit.io.calibration import read_calibration
from platkit.io.description import load_yaml
from platkit.io.imu import read_imu_csv
from platkit.io.session_checks import check_times
from platkit.io.session_yaml import TIME_UNITS, read_session_yaml
from platkit.io.table import read_table
from platkit.kinematics import PlatformModel
from platkit.model import controls_to_si
from platkit.plugins import get_platform

METHODS = ("platkit", "platkit-causal", "paper", "command-aided")


@dataclass
class OrientResult:
    """``t`` (N,) s; ``q`` (N, 4) q_base_from_platform; ``report``: the report.json mapping;
    ``truth``: (t (K,), q (K, 4)) or None; ``errors``: per-truth-sample arrays for plots."""

    t: np.ndarray
    q: np.ndarray
    report: dict
    truth: tuple | None = None
    errors: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def read_truth_orientation(path: Path, time_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """truth_orientation.csv -> (t (K,) s, q (K, 4)); BadSession naming row and column."""

    table = read_table(path, "the true orientation")
    cols = ["t", "qw", "qx", "qy", "qz"]
    for c in cols:
        if c not in table.header:
            raise BadSession(f"{path}: missing column {c!r}; expected {','.join(cols)}")
    t = table.column("t") * time_scale
    check_times(table, t)
    q = np.column_stack([table.column(c) for c in cols[1:]])
    bad = np.argwhere(~np.isfinite(q))
    if bad.size:
        r, c = bad[0]
        raise BadSession(f"{table.where(int(r), cols[1 + c])}: empty; expected a number")
    n = np.linalg.norm(q, axis=1)
    off = np.nonzero(np.abs(n - 1) > 1e-3)[0]
    if off.size:
        raise BadSession(f"{table.where(int(off[0]))}: the quaternion has norm {n[off[0]]:.6g}, expected 1")
    return t, quat_normalize(q)


def read_truth_imu(path: Path) -> dict:

    data = load_yaml(path, error=BadSession)
    out = {}
    shapes = {"gyr_bias_rad_s": (3,), "acc_bias_m_s2": (3,), "gyr_scale": (3,), "acc_scale": (3,),
              "sensor_from_platform": (3, 3), "base_tilt_rad": (2,), "gyr_bias_rate_rad_s2": (3,)}
    for k, v in data.items():
        if k == "effects":  # IMU effects the simulator applied: effect name -> parameters (SI)
            if not isinstance(v, dict) or not all(isinstance(p, list) for p in v.values()):
                raise BadSession(f"{path}: field 'effects' must map effect names to lists of numbers")
            out[k] = {name: np.asarray(p, float) for name, p in v.items()}
            continue
        if k not in shapes:
            raise BadSession(f"{path}: unknown field {k!r}; known fields: {', '.join(shapes)}, effects")
        a = np.asarray(v, float)
        if a.shape != shapes[k]:
            raise BadSession(f"{path}: field {k!r} must have shape {shapes[k]}")
        out[k] = a
    return out


def interpolate_quat(t_src: np.ndarray, q_src: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Orientation at times ``t`` by normalised linear interpolation of (N, 4) quaternions
    (exact enough between samples of a dense stream); outside the range: the end values."""
    q = q_src.copy()
    # make consecutive quaternions agree in sign before interpolating
    flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
    q[1:] *= flip[:, None]
    out = np.column_stack([np.interp(t, t_src, q[:, j]) for j in range(4)])
    return quat_normalize(out)


def _heading_offset(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """The rotation about base z (4,) that best turns q_est onto q_ref (both (K, 4))."""
    e = quat_multiply(q_ref, quat_conjugate(q_est))
    psi = 2.0 * np.arctan2(e[:, 3], e[:, 0])
    psi0 = np.arctan2(np.mean(np.sin(psi)), np.mean(np.cos(psi)))
    return np.array([np.cos(psi0 / 2), 0.0, 0.0, np.sin(psi0 / 2)])


def _session_commands(folder: Path, y: dict, calibration: str | Path | None, platform: str | None,
                      description: str | Path | None):
    """(spec, td, t_cmd (M,), U (M, n_u)) or None when the session has no platform/commands."""

    name = platform or y["platform"]
    if isinstance(name, str) and name.lower() == "none":
        name = None  # spec section 1: "none for an IMU-only recording"
    cpath = folder / "commands.csv"
    if name is None or not cpath.is_file():
        return None
    if calibration is not None:

        cal = read_calibration(calibration)
        if cal.platform != name:
            raise BadInput(f"{calibration}: the calibration is for the {cal.platform!r} stand, the session for {name!r}")
        spec = cal.calibrated_spec()
        td = np.asarray(cal.td, float)
    else:

        options = {"moving_link": y["moving_link"]} if y.get("moving_link") else {}
        spec = get_platform(name, description or y["description"], **options)
        td = spec.nominal_td()
    table = read_table(cpath, "the command log")
    missing = [c for c in ["t"] + spec.control_names if c not in table.header]
    if missing:
        raise BadSession(f"{cpath}: missing column {missing[0]!r}; the {spec.name} stand expects "
                         f"t, {', '.join(spec.control_names)}")
    raw = np.column_stack([table.column(c) for c in spec.control_names])
    bad = np.argwhere(~np.isfinite(raw))
    if bad.size:
        r, c = bad[0]
        raise BadSession(f"{table.where(int(r), spec.control_names[c])}: empty; every command needs every control")
    t = table.column("t") * TIME_UNITS[y["time_unit"]]
    check_times(table, t)
    return spec, td, t, controls_to_si(spec, raw, y["length_unit"])


#: fewest IMU samples orient takes (scipy's sosfiltfilt pads a second-order section by 9)
MIN_SAMPLES = 10


def _read_session_imu(folder: Path, y: dict, max_repair_s: float):
    """The session's imu.csv, read with its declared ranges and rate; BadInput below MIN_SAMPLES."""
    imu_decl = y["imu"] or {}
    imu = read_imu_csv(folder / "imu.csv", max_repair_s=max_repair_s, gyr_range=imu_decl.get("gyr_range_rad_s"),
                       acc_range=imu_decl.get("acc_range_m_s2"), time_scale=TIME_UNITS[y["time_unit"]],
                       declared_rate_hz=imu_decl.get("rate_hz"))
    if imu.n < MIN_SAMPLES:
        raise BadInput(f"{folder / 'imu.csv'}: {imu.n} samples are too few to estimate an orientation "
                       f"(need at least {MIN_SAMPLES}: the offline estimator's zero-phase filter)")
    return imu


def _start_bias(imu_c, cal_given: bool, report: dict) -> tuple[np.ndarray, str | None]:
    """(gyro bias at the start, the warning to give if nothing better is found): zero under an IMU
    calibration (it removed the bias), else the first rest of the recording, else zero with the
    reason; the source goes into ``report['gyr_bias_source']``."""
    if cal_given:
        report["gyr_bias_source"] = "imu calibration"
        return np.zeros(3), None
    try:
        bias0 = gyro_bias_at_rest(imu_c, min_s=1.0)
        report["gyr_bias_source"] = "first rest of the recording"
        return bias0, None
    except NotIdentifiable as exc:
        report["gyr_bias_source"] = "none (zero)"
        return np.zeros(3), str(exc)


@dataclass
class _CommandFrame:
    """What the commands give the estimate: the sensor-from-platform rotation, the start bias,
    the command times and poses (``q_cmd`` None where the platform never holds one: no heading to
    align to) and the platform's timing (None where it could not be measured)."""

    R_sp: np.ndarray
    bias0: np.ndarray
    t_cmd: np.ndarray | None = None
    q_cmd: np.ndarray | None = None
    timing: object = None


def _frame_from_commands(folder: Path, cmds, imu_c, method: str, frame: _CommandFrame,
                         calibration: str | Path | None, imu_calibration: str | Path | None,
                         report: dict, warnings: list[str]) -> _CommandFrame:
    """The commanded poses, the platform's timing and, without an IMU calibration, R_SP and the
    bias from the held poses. The unaided methods go on without what cannot be found (and say
    so); command-aided raises NotIdentifiable."""
    cal_given = imu_calibration is not None
    spec, td, t_cmd, U = cmds
    model = PlatformModel(spec)
    q_cmd = command_poses(model, U, td)
    R_sp, bias0 = frame.R_sp, frame.bias0
    try:
        timing = estimate_timing(imu_c, t_cmd, q_cmd, bias0)
        held_any = held_mask(imu_c.t, t_cmd, timing).any()
    except NotIdentifiable as exc:
        if method == "command-aided":
            raise
        warnings.append(f"{exc}; the commands are not used")
        timing, held_any = None, False
    if timing is not None:
        report["timing"] = {"lag_s": timing.lag_s, "settle_s": timing.settle_s, "n_moves": timing.n_moves,
                            "lag_std_s": timing.lag_std_s, "settle_std_s": timing.settle_std_s}
    report["platform"] = spec.name
    report["calibration"] = str(calibration) if calibration else None
    if cal_given:
        report["alignment"] = {"source": f"imu calibration {imu_calibration}"}
    elif timing is not None:
        try:
            fit, bias_held = estimate_alignment_from_commands(imu_c, t_cmd, q_cmd, timing)
        except NotIdentifiable as exc:
            if method == "command-aided":
                raise
            warnings.append(f"{exc}; the sensor axes are taken as the platform axes")
            report["alignment"] = {"source": "none (identity)"}
        else:
            R_sp = fit.sensor_from_platform
            bias0 = bias_held
            report["gyr_bias_source"] = "held poses of the session"
            report["alignment"] = {"source": "estimated from the session's moves",
                                   "rms_rad": fit.rms, "angle_std_rad": fit.angle_std}
    else:
        report["alignment"] = {"source": "none (identity)"}
    if not held_any:
        if method == "command-aided":
            raise NotIdentifiable(f"{folder}: the platform never holds a commanded pose long enough "
                                  "for the command-aided estimator")
        q_cmd = None  # nothing to align the heading with
    return _CommandFrame(R_sp, bias0, t_cmd, q_cmd, timing)


def _estimate(method: str, imu, imu_c, frame: _CommandFrame, q_sp: np.ndarray, cal_given: bool,
              level_base: bool, report: dict, warnings: list[str]):
    """(estimator result, q_base_from_platform (N, 4)) by ``method``; the unaided methods' heading
    aligned to the commanded poses over the held intervals where there are any."""
    t_cmd, q_cmd, timing = frame.t_cmd, frame.q_cmd, frame.timing
    if method == "command-aided":
        params = CommandAidedParams(timing=timing, tilt_from_accelerometer=cal_given or level_base,
                                    level_base=level_base)
        est = estimate_command_aided(imu_c, t_cmd, q_cmd, frame.R_sp, frame.bias0, params)
        if level_base and not cal_given:
            warnings.append("--level-base without --imu-calibration: the accelerometer's bias and scale errors "
                            "go straight into the tilt")
        report["heading"] = "absolute (from the commanded poses)"
        return est, est.q
    if method == "paper":
        est = estimate_paper(imu_c, PaperParams(gyro_bias=tuple(frame.bias0)))
    elif method == "platkit-causal":
        est = estimate_platkit(imu_c, PlatkitParams(initial_bias=tuple(frame.bias0)))
    else:
        est = estimate_offline(imu_c, PlatkitParams(initial_bias=tuple(frame.bias0)))
    q_bp = quat_normalize(quat_multiply(est.q, q_sp[None, :]))
    if q_cmd is not None:
        held = held_mask(imu.t, t_cmd, timing)
        k = np.clip(np.searchsorted(t_cmd, imu.t, side="right") - 1, 0, len(t_cmd) - 1)
        rot = _heading_offset(q_bp[held], q_cmd[k[held]])
        q_bp = quat_normalize(quat_multiply(rot[None, :], q_bp))
        report["heading"] = "aligned to the commanded poses over the held intervals"
    else:
        report["heading"] = "relative to the start (no magnetometer, no commands)"
    return est, q_bp


def _imu_truth_errors(path: Path, R_sp: np.ndarray, bias_end: np.ndarray) -> dict:
    """truth_imu.yaml against the estimate: the alignment's error (deg) and the end bias's (deg/s,
    raw sensor axes), each where the truth gives it."""
    truth = read_truth_imu(path)
    cmp = {}
    if "sensor_from_platform" in truth:
        err = rotvec_from_matrix(np.asarray(R_sp) @ truth["sensor_from_platform"].T)
        cmp["alignment_error_deg"] = float(np.degrees(np.linalg.norm(err)))
    if "gyr_bias_rad_s" in truth:
        # the bias at the end of the run, raw sensor axes, against the true bias
        cmp["gyr_bias_error_deg_s"] = np.degrees(bias_end - truth["gyr_bias_rad_s"]).tolist()
    return cmp


def orient_session(folder: str | Path, method: str = "platkit", calibration: str | Path | None = None,
                   imu_calibration: str | Path | None = None, platform: str | None = None,
                   description: str | Path | None = None, max_repair_s: float = 0.05,
                   level_base: bool = False) -> OrientResult:
    """Estimate the platform's orientation over a session (see the module docstring)."""
    if method not in METHODS:
        raise BadInput(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    folder = Path(folder)
    y = read_session_yaml(folder)
    tscale = TIME_UNITS[y["time_unit"]]
    imu = _read_session_imu(folder, y, max_repair_s)
    warnings = imu.warnings()
    report: dict = {"session": str(folder), "method": method, "n_samples": imu.n, "rate_hz": imu.rate_hz,
                    "duration_s": float(imu.t[-1] - imu.t[0])}

    cal = ImuCalibration()
    cal_given = imu_calibration is not None
    if cal_given:
        cal = ImuCalibration.from_dict(load_yaml(imu_calibration, error=BadInput), str(imu_calibration))
    imu_c = cal.apply(imu) if cal_given else imu

    cmds = _session_commands(folder, y, calibration, platform, description)
    if method == "command-aided" and cmds is None:
        raise BadInput(f"{folder}: --method command-aided needs a session with a platform and commands.csv")

    # the gyro bias at the start: from the calibration, else from the first rest of the recording
    # (replaced below by the held poses' bias when the commands give one)
    bias0, rest_warning = _start_bias(imu_c, cal_given, report)
    frame = _CommandFrame(cal.sensor_from_platform, bias0)
    if cmds is not None:
        frame = _frame_from_commands(folder, cmds, imu_c, method, frame, calibration, imu_calibration, report,
                                     warnings)
    elif not cal_given:
        warnings.append("no IMU calibration and no commands: the sensor axes are taken as the platform axes "
                        "and the heading is relative to the start")
        report["alignment"] = {"source": "none (identity)"}
    if rest_warning is not None and report["gyr_bias_source"] == "none (zero)":
        warnings.append(rest_warning)  # said only when no other source gave the bias
    R_sp = frame.R_sp
    # the identity (no calibration, no commands) needs no conversion (scipy.spatial's import is most of its cost)
    q_sp = np.array([1.0, 0.0, 0.0, 0.0]) if np.array_equal(R_sp, np.eye(3)) else quat_from_matrix(R_sp)
    report["sensor_from_platform"] = np.asarray(R_sp).tolist()
    report["gyr_bias_start_rad_s"] = (cal.gyr_bias + cal.gyr_scale * np.asarray(frame.bias0)).tolist()

    est, q_bp = _estimate(method, imu, imu_c, frame, q_sp, cal_given, level_base, report, warnings)
    report["estimator"] = {k: v for k, v in est.info.items() if k != "params"}
    # the estimators see the calibrated stream; in raw sensor units the bias is b_cal + s r
    bias_end = cal.gyr_bias + cal.gyr_scale * np.asarray(est.bias[-1])
    report["gyr_bias_end_rad_s"] = bias_end.tolist()

    result = OrientResult(imu.t, q_bp, report, warnings=warnings)
    tpath = folder / "truth_orientation.csv"
    if tpath.is_file():
        _score(result, *read_truth_orientation(tpath, tscale), absolute_heading=frame.q_cmd is not None)
    ipath = folder / "truth_imu.yaml"
    if ipath.is_file():
        report["truth_imu"] = _imu_truth_errors(ipath, R_sp, bias_end)
    report["warnings"] = warnings
    return result


def _score(result: OrientResult, t_true: np.ndarray, q_true: np.ndarray, absolute_heading: bool) -> None:

    inside = (t_true >= result.t[0]) & (t_true <= result.t[-1])
    if not inside.any():
        raise BadSession("truth_orientation.csv: no truth sample falls within the IMU recording's time span")
    t_true, q_true = t_true[inside], q_true[inside]
    q_est = interpolate_quat(result.t, result.q, t_true)
    inc = inclination_error(q_est, q_true)
    tot = total_error(q_est, q_true)
    tot_al = heading_aligned_total_error(q_est, q_true)
    result.truth = (t_true, q_true)
    result.errors = {"t": t_true, "inclination": inc, "total": tot, "total_heading_aligned": tot_al}
    result.report["truth"] = {
        "n_samples": int(len(t_true)),
        "inclination_rmse_deg": float(np.degrees(rmse(inc))),
        "inclination_max_deg": float(np.degrees(np.nanmax(inc))),
        "total_rmse_deg": float(np.degrees(rmse(tot))),
        "total_rmse_heading_aligned_deg": float(np.degrees(rmse(tot_al))),
        "heading_reference": "absolute" if absolute_heading else "relative (see total_rmse_heading_aligned_deg)",
    }
