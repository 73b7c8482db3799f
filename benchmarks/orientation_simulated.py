"""Inertial tracking on simulated Stewart and PSVR sessions with an IMU, against the known truth.

For each stand and seed: a true stand (parameters perturbed as platkit.simulate does), a model
that knows it up to a residual calibration error (perturbation x0.1, or the nominal model), 30
commands (Stewart: poses with roll, pitch, yaw within 8 deg and 0.1 m shifts; PSVR: random
motor counts within 60 % of the strokes) held 3 s, moves of 1 s lagging 0.08 s,
an IMU turned by R_SP (a few deg of tilt and 30 deg of yaw) 0.37 m off the platform origin, with
gyro and accelerometer biases, scale errors, bias drift and white noise. Reported:

- orientation error (total and inclination RMSE, deg) of `platkit orient` with --method platkit
  (heading aligned to the commands), paper, and command-aided, with the calibrated model and
  with the nominal one; then again with the IMU calibrated (--imu-calibration: accelerometer
  bias and scale from the bench test, gyro bias, scales and R_SP from the session's moves);
- the misalignment R_SP and the gyro bias the session itself yields (rotations between held
  poses, least squares), and the platform's measured latency;
- a paper-style step-2 run (rotations about the platform's x axis, then its y axis only):
  R_SP from the two axis directions;
- a bench test of the accelerometer (12 static positions, six faces and six random) fitted for
  bias and scale, and the gyro scales fitted from the session's three-axis rotations (the
  PSVR turns about two axes only: no gyro scales there).

Run:  .venv/bin/python benchmarks/orientation_simulated.py [--seeds 3] [--stands stewart,psvr]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_rpy, quat_from_matrix, rotvec_from_matrix
from platkit.inertial.calibration import fit_accelerometer, fit_imu_alignment, sensor_axis_directions, static_means
from platkit.inertial.command_aided import estimate_alignment_from_commands, estimate_timing
from platkit.inertial.orient import orient_session
from platkit.inertial.simulate import imu_from_motion, platform_imu_session, write_platform_imu_session
from platkit.io.imu import ImuStream
from platkit.plugins import get_platform
from platkit.simulate import perturb_parameters

LAG_S, MOVE_S, RATE = 0.08, 1.0, 200.0


def _angle_deg(Ra, Rb):
    return float(np.degrees(np.linalg.norm(rotvec_from_matrix(np.asarray(Ra) @ np.asarray(Rb).T))))


def sensor_errors(rng):
    R_sp = matrix_from_rpy(*np.radians([rng.uniform(-3, 3), rng.uniform(-3, 3), 30.0]))
    bias = np.r_[rng.normal(0, np.radians(0.5), 3), rng.normal(0, 0.1, 3)]
    scale = np.r_[1 + rng.normal(0, 0.005, 3), 1 + rng.normal(0, 0.005, 3)]
    return dict(imu_from_platform=R_sp, bias=bias, scale=scale, bias_drift=np.radians(0.002),
                noise=[np.radians(0.1), 0.02], lever_arm=[0.3, 0.2, 0.1])


def bench_accelerometer(rng, errors):
    """12 static positions held 3 s each on a bench: six faces up, six random."""
    dirs = np.vstack([np.eye(3), -np.eye(3), rng.normal(size=(6, 3))])
    t = np.arange(0, 3.0 * len(dirs), 1 / RATE)
    q = np.empty((len(t), 4))
    for i, d in enumerate(dirs):
        d = d / np.linalg.norm(d)
        # the sensor turned so that its axes see gravity along d
        z = np.array([0.0, 0.0, 1.0])
        v = np.cross(d, z)
        if np.linalg.norm(v) < 1e-9:
            R = np.eye(3) if d[2] > 0 else np.diag([1.0, -1.0, -1.0])
        else:
            ang = np.arccos(np.clip(d @ z, -1, 1))
            from platkit.geometry import matrix_from_rotvec

            R = matrix_from_rotvec(v / np.linalg.norm(v) * ang)
        q[(t >= 3.0 * i) & (t < 3.0 * (i + 1))] = quat_from_matrix(R)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), None, errors["bias"], 0.0, errors["scale"], None,
                          errors["noise"], rng)
    imu = ImuStream(t, sim["gyr"], sim["acc"])
    fit = fit_accelerometer(static_means(imu, min_s=1.5, window_s=0.5))
    return fit


def single_axis_run(spec, td_true, rng, errors):
    """The paper's step 2: roll-only then pitch-only oscillations; R_SP from the axis directions."""
    from platkit.geometry import quat_from_rpy, quat_multiply
    from platkit.kinematics import PlatformModel

    model = PlatformModel(spec)
    q0, X0 = model.pose(spec.neutral_p())
    t = np.arange(0, 6, 1 / RATE)
    s_ = np.clip((t - 1.0) / 4.0, 0, 1)
    ang = np.radians(10) * s_**3 * (10 - 15 * s_ + 6 * s_**2)  # one 10 deg turn, minimum jerk
    segs = []
    for axis in (0, 1):
        rpy = np.zeros((len(t), 3))
        rpy[:, axis] = ang
        q = quat_multiply(q0[None, :], quat_from_rpy(rpy[:, 0], rpy[:, 1], rpy[:, 2]))
        sim = imu_from_motion(t, q, np.tile(X0, (len(t), 1)), rng=rng, **errors)
        w = sim["gyr"] - sim["gyr"][t < 1.0].mean(axis=0)  # bias from the rest before the turn
        segs.append(w[np.linalg.norm(w, axis=1) > np.radians(1)])
    d = sensor_axis_directions(segs)
    fit = fit_imu_alignment(np.eye(3)[:2], d)
    return _angle_deg(fit.sensor_from_platform, errors["imu_from_platform"])


def run_seed(seed: int, spec, workdir: Path) -> dict:
    rng = np.random.default_rng(seed)
    td_true = perturb_parameters(spec, rng)
    td_cal = td_true + 0.1 * (perturb_parameters(spec, rng) - spec.nominal_td())
    errors = sensor_errors(rng)
    # the hexapod gets poses (tilts, yaw, shifts); the PSVR, which has no yaw, random controls
    plan = {"controls_fraction": 0.6} if spec.name == "psvr" else {}
    sim = platform_imu_session(spec, td_true, td_cal, rng, n_commands=30, hold_s=3.0, move_s=MOVE_S,
                               lag_s=LAG_S, rate_hz=RATE, **plan, **errors)
    workdir = workdir / spec.name
    workdir.mkdir(exist_ok=True)
    out: dict = {"seed": seed}
    folder = write_platform_imu_session(sim, spec, workdir / f"s{seed}",
                                        {"gyr_bias_rad_s": sim["gyr_bias"][-1],  # drifted: the bias at the end
                                         "sensor_from_platform": errors["imu_from_platform"]})
    # a calibration file for the calibrated model: the model's td as a platkit calibration.yaml
    cal_path = write_calibration(spec, td_cal, workdir / f"cal{seed}")
    for method in ("platkit", "paper", "command-aided"):
        r = orient_session(folder, method, calibration=cal_path).report
        out[method] = (r["truth"]["total_rmse_deg"], r["truth"]["inclination_rmse_deg"])
        if method == "command-aided":
            out["alignment_deg"] = r["truth_imu"]["alignment_error_deg"]
            out["bias_err_deg_s"] = float(np.max(np.abs(r["truth_imu"]["gyr_bias_error_deg_s"])))
            out["onset_s"] = r["timing"]["lag_s"]
    r = orient_session(folder, "command-aided").report  # nominal model: no calibration file
    out["command-aided-nominal"] = (r["truth"]["total_rmse_deg"], r["truth"]["inclination_rmse_deg"])
    # gyro scale from the session's own moves (three independent axes on a hexapod)
    imu = ImuStream(sim["t"], sim["gyr"], sim["acc"])
    timing = estimate_timing(imu, sim["t_cmd"], sim["q_cmd"], errors["bias"][:3])
    try:
        fit, fit_bias = estimate_alignment_from_commands(imu, sim["t_cmd"], sim["q_cmd"], timing, fit_scale=True)
        out["gyr_scale_err"] = float(np.max(np.abs(fit.gyr_scale - errors["scale"][:3])))
    except NotIdentifiable:  # a stand that turns about two axes only (the PSVR): no gyro scales
        fit, fit_bias = estimate_alignment_from_commands(imu, sim["t_cmd"], sim["q_cmd"], timing)
        out["gyr_scale_err"] = float("nan")
    acc = bench_accelerometer(rng, errors)
    out["acc_bias_err"] = float(np.max(np.abs(acc.bias - errors["bias"][3:])))
    out["acc_scale_err"] = float(np.max(np.abs(acc.scale - errors["scale"][3:])))
    out["paper_step2_deg"] = single_axis_run(spec, td_true, rng, errors)
    # the same session again, now with the IMU calibrated: accelerometer from the bench, gyro
    # bias, scales and R_SP from the session's moves
    import yaml

    from platkit.inertial.calibration import ImuCalibration

    imu_cal = ImuCalibration(gyr_bias=fit_bias, gyr_scale=fit.gyr_scale, acc_bias=acc.bias, acc_scale=acc.scale,
                             sensor_from_platform=fit.sensor_from_platform)
    cal_file = workdir / f"imu{seed}.yaml"
    cal_file.write_text(yaml.safe_dump(imu_cal.to_dict()))
    for method in ("platkit", "paper", "command-aided"):
        r = orient_session(folder, method, calibration=cal_path, imu_calibration=cal_file).report
        out[method + " (IMU calibrated)"] = (r["truth"]["total_rmse_deg"], r["truth"]["inclination_rmse_deg"])
    r = orient_session(folder, "command-aided", imu_calibration=cal_file, level_base=True).report
    out["command-aided-nominal (IMU calibrated, level base)"] = (r["truth"]["total_rmse_deg"], r["truth"]["inclination_rmse_deg"])
    r = orient_session(folder, "command-aided", imu_calibration=cal_file).report
    out["command-aided-nominal (IMU calibrated)"] = (r["truth"]["total_rmse_deg"], r["truth"]["inclination_rmse_deg"])
    return out


def write_calibration(spec, td, folder: Path) -> Path:
    """A minimal platkit calibration.yaml holding ``td`` (through platkit.io.calibration)."""
    from platkit.io.calibration import Calibration

    n = spec.n_td
    cal = Calibration(platform=spec.name, description=None, spec=spec, td=np.asarray(td), td_std=np.full(n, np.nan),
                      td_nominal=spec.nominal_td(), td_status=["estimated"] * n, mocap_rotvec=np.zeros(3),
                      mocap_translation=np.zeros(3), mocap_std=np.zeros(6), marker_names=["M1"],
                      marker_positions=np.zeros((1, 3)), marker_std=np.zeros((1, 3)), rms_before=0.0, rms_after=0.0,
                      length_unit="m")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "calibration.yaml"
    path.write_text(cal.to_yaml(), encoding="utf-8")
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--stands", default="stewart,psvr")
    args = ap.parse_args(argv)
    for name in args.stands.split(","):
        spec = get_platform(name)
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seeds):
                rows.append(run_seed(seed, spec, Path(tmp)))
                print(f"  {name} seed {seed} done", file=sys.stderr, flush=True)
        print(f"=== {spec.name}: {spec.title}")
        report(rows)
    return 0


def report(rows) -> None:
    print("orientation error against the truth, deg (total RMSE / inclination RMSE)")
    for m in ("platkit", "paper", "command-aided", "command-aided-nominal", "platkit (IMU calibrated)",
              "paper (IMU calibrated)", "command-aided (IMU calibrated)", "command-aided-nominal (IMU calibrated)",
              "command-aided-nominal (IMU calibrated, level base)"):
        vals = np.array([r[m] for r in rows])
        per = "  ".join(f"{a:.3f}/{b:.3f}" for a, b in vals)
        print(f"  {m:<52} {per}   mean {vals[:, 0].mean():.3f}/{vals[:, 1].mean():.3f}")
    print("what the session and a bench test recover (per seed)")
    for key, label in (("alignment_deg", "R_SP error from the session's moves, deg"),
                       ("paper_step2_deg", "R_SP error from single-axis rotations (paper), deg"),
                       ("bias_err_deg_s", "gyro bias error (max axis), deg/s"),
                       ("gyr_scale_err", "gyro scale error (max axis)"),
                       ("acc_bias_err", "accelerometer bias error (max axis), m/s^2"),
                       ("acc_scale_err", "accelerometer scale error (max axis)"),
                       ("onset_s", f"motion onset after command, s (true lag {LAG_S} + 5 % of a {MOVE_S} s move)")):
        print(f"  {label:<62} " + "  ".join(f"{r[key]:.4g}" for r in rows))


if __name__ == "__main__":
    sys.exit(main())
