"""Rigid bodies measured in 6 DOF (spec section 1): the estimator's body channels, their weight, the
same data given as markers, calibration.yaml and predict's seven columns per body.

The pose sets are made here from PlatformModel.forward_batch with a known truth (perturbed td, a
random base-to-mocap transform, random body placements), so the geometry can be judged against it.
"""
from __future__ import annotations

import numpy as np
import pytest

from platkit.bodies import average_body, log_so3, quat_mean, right_jacobian, right_jacobian_inv
from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.calibrate.predict import predict_bodies, prediction_table
from platkit.calibrate.problem import CalibrationProblem, parameter_scale
from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.io.calibration import read_calibration
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

SIGMA_P = 1e-4  # m per axis: a mocap rigid body's origin
SIGMA_R = 1e-3  # rad per axis: its orientation (0.057 deg)


class BodyTruth:
    """A simulated stand seen through B rigid bodies: true td, mocap_from_base (A, b), placements."""

    def __init__(self, spec, seed=0, n_bodies=1):
        rng = np.random.default_rng(seed)
        self.spec, self.model, self.rng = spec, PlatformModel(spec), rng
        scale = np.array([parameter_scale(p.unit, p.nominal) for p in spec.parameters])
        free = np.array([p.free for p in spec.parameters])
        self.td = spec.nominal_td() + 3.0 * scale * rng.normal(size=spec.n_td) * free
        self.A = matrix_from_rotvec(rng.normal(0, 0.6, 3))
        self.b = rng.normal(0, 1.5, 3)
        self.origins = rng.normal(0, 0.2, (n_bodies, 3))
        self.rotations = matrix_from_rotvec(rng.normal(0, 1.0, (n_bodies, 3)))

    def controls(self, n, spread=0.3):
        lo, hi = self.spec.control_bounds()
        u0 = self.spec.neutral_u()
        lo = np.where(np.isfinite(lo), lo, u0 - 1.0)
        hi = np.where(np.isfinite(hi), hi, u0 + 1.0)
        return np.clip(u0 + self.rng.uniform(-spread, spread, (n, self.spec.n_u)) * (hi - lo), lo, hi)

    def bodies(self, U, noisy=True):
        """(U kept, bodies (N, B, 7) in the mocap frame, with noise SIGMA_P, SIGMA_R per axis)."""
        fb = self.model.forward_batch(U, self.td, strict=False)
        ok = fb.converged & fb.on_branch
        R = np.einsum("ab,nbc->nac", self.A, matrix_from_quat(fb.q[ok]))
        o = (fb.X[ok] @ self.A.T + self.b)[:, None, :] + np.einsum("nab,kb->nka", R, self.origins)
        Rw = np.einsum("nab,kbc->nkac", R, self.rotations)
        if noisy:
            o = o + self.rng.normal(0, SIGMA_P, o.shape)
            Rw = Rw @ matrix_from_rotvec(self.rng.normal(0, SIGMA_R, o.shape))
        return U[ok], np.concatenate([o, quat_from_matrix(Rw)], axis=2)

    def poses(self, n, declared=True):
        U, bodies = self.bodies(self.controls(n))
        noise = {"position_m": SIGMA_P, "rotation_rad": SIGMA_R} if declared else {}
        return PoseSet(self.spec.name, U, np.zeros((len(U), 0, 3)), [], bodies=bodies,
                       body_names=[f"T{k + 1}" for k in range(bodies.shape[1])], body_noise=noise,
                       length_unit="mm", source="simulated")


def as_markers(poses: PoseSet, arm_m: float) -> PoseSet:
    """The same measurements given as four points of each body's frame: origin and the axis tips at arm_m."""
    o, R = poses.bodies[..., :3], matrix_from_quat(poses.bodies[..., 3:])
    pts = [o] + [o + arm_m * R[..., :, k] for k in range(3)]
    Y = np.stack(pts, axis=2).reshape(poses.n_poses, -1, 3)
    names = [f"{b}{k}" for b in poses.body_names for k in "OXYZ"]
    return PoseSet(poses.platform, poses.controls, Y, names, length_unit=poses.length_unit, source="as markers")


def prediction_vs_crb(cal, test: PoseSet):
    """Per channel: (RMS 3-D error (m) of the calibration's predictions against the noise-free poses
    ``test``, RMS 3-D error the fit's covariance expects (its Cramer-Rao bound when the noise is
    declared right)). Channels as the estimator's: markers, bodies' origins, bodies' rotations * rho."""
    problem, z, active = cal.fit.problem, cal.fit.z, cal.fit.active
    st = problem.evaluate(z, with_jac=True, poses=test)
    J = st.J[..., active]
    var = np.einsum("nmaj,jk,nmak->nm", J, cal.fit.cov, J)
    return np.sqrt(np.mean(np.sum(st.r ** 2, axis=2), axis=0)), np.sqrt(np.mean(var, axis=0))


def noise_free(truth, poses, n=40):
    U, clean = truth.bodies(truth.controls(n), noisy=False)
    return PoseSet(poses.platform, U, np.zeros((len(U), 0, 3)), [], bodies=clean, body_names=list(poses.body_names),
                   body_noise=dict(poses.body_noise), length_unit=poses.length_unit, source="truth")


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def fitted(stewart):
    truth = BodyTruth(stewart, seed=3)
    poses = truth.poses(60)
    return truth, poses, calibrate(poses, stewart)


# ---------------------------------------------------------------------------- rotation algebra

def test_right_jacobian_and_its_inverse():
    rng = np.random.default_rng(0)
    phi = rng.normal(0, 1, (5, 3))
    d = 1e-7 * rng.normal(size=3)
    for p in phi:
        lhs = log_so3(matrix_from_rotvec(p).T @ matrix_from_rotvec(p + d))
        assert np.allclose(lhs, right_jacobian(p) @ d, atol=1e-12)
        assert np.allclose(right_jacobian_inv(p) @ right_jacobian(p), np.eye(3), atol=1e-12)
    assert np.allclose(right_jacobian(np.zeros(3)), np.eye(3))


def test_quaternion_mean_ignores_signs_and_averaging_skips_occluded_rows():
    rng = np.random.default_rng(1)
    q0 = quat_from_matrix(matrix_from_rotvec(np.array([0.3, -1.0, 2.0])))
    noisy = quat_from_matrix(matrix_from_quat(q0) @ matrix_from_rotvec(rng.normal(0, 1e-3, (200, 3))))
    noisy[::2] *= -1  # the same orientations, half with the other sign
    m = quat_mean(noisy)
    assert np.linalg.norm(log_so3(matrix_from_quat(m).T @ matrix_from_quat(q0))) < 3e-4  # 1e-3 / sqrt(200) * 4
    samples = np.concatenate([rng.normal(0, 1e-4, (200, 3)) + [1, 2, 3], noisy], axis=1)
    samples[5] = np.nan
    pose, n = average_body(samples)
    assert n == 199 and np.allclose(pose[:3], [1, 2, 3], atol=5e-5)
    assert average_body(np.full((4, 7), np.nan))[1] == 0


# ---------------------------------------------------------------------------- the observation model

@pytest.mark.parametrize("platform", ["stewart", "rotary"])
def test_body_jacobian_matches_finite_differences(platform):
    spec = get_platform(platform)
    truth = BodyTruth(spec, seed=1, n_bodies=2)
    poses = truth.poses(12)
    poses.bodies[4, 1] = np.nan  # one body unseen in one pose
    problem = CalibrationProblem(spec, poses)
    z = problem.initial_registration(spec.nominal_td())
    z = z + 1e-3 * np.random.default_rng(2).normal(size=z.shape)
    st = problem.evaluate(z)
    assert st.r.shape == (poses.n_poses, 4, 3)  # two origins, two rotation channels
    assert np.isnan(st.r[4, [1, 3]]).all() and np.isfinite(st.r[3]).all()
    h = 1e-6
    for k in range(problem.n_z):
        zp, zm = z.copy(), z.copy()
        zp[k] += h
        zm[k] -= h
        fd = (problem.evaluate(zp, False).r - problem.evaluate(zm, False).r) / (2 * h)
        assert np.nanmax(np.abs(fd - st.J[..., k])) < 1e-6, problem.names[k]


class Wobble(ModelTerm):
    """A test term touching every offset: a turn of the moving frame about base z and a shift along x
    growing with time, a control offset, and a shift of the first marker."""

    def __init__(self):
        super().__init__("thermal_drift", ["turn", "shift", "control", "marker"], np.zeros(4), ["rad/s", "m/s", "1", "m"],
                         {})

    def pose_offset(self, theta, poses, fk_q, fk_X):
        out = np.zeros((poses.n_poses, 6))
        out[:, 0], out[:, 5] = theta[1] * poses.t, theta[0] * poses.t
        return out

    def control_offset(self, theta, poses, n_u):
        return np.full((poses.n_poses, n_u), theta[2])

    def marker_offset(self, theta, poses):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[:, 0, 0] = theta[3]
        return out


@pytest.mark.parametrize("platform", ["stewart", "rotary"])
def test_jacobian_with_markers_bodies_and_a_term(platform):
    spec = get_platform(platform)
    truth = BodyTruth(spec, seed=2)
    poses = truth.poses(10)
    markers = as_markers(poses, 0.1)
    poses.markers, poses.marker_names = markers.markers[:, :3], markers.marker_names[:3]
    poses.t = np.linspace(0.0, 100.0, poses.n_poses)
    problem = CalibrationProblem(spec, poses, [Wobble()])
    z = problem.initial_registration(spec.nominal_td())
    z = z + 1e-3 * np.random.default_rng(3).normal(size=z.shape)
    z[problem.i_theta] = [1e-4, 1e-5, 1e-3, 1e-3]
    st = problem.evaluate(z)
    assert st.r.shape == (poses.n_poses, 3 + 2, 3)
    for k in range(problem.n_z):
        h = 1e-6
        zp, zm = z.copy(), z.copy()
        zp[k] += h
        zm[k] -= h
        fd = (problem.evaluate(zp, False).r - problem.evaluate(zm, False).r) / (2 * h)
        assert np.nanmax(np.abs(fd - st.J[..., k])) < 1e-5, problem.names[k]


def test_pose_subset_keeps_bodies(fitted):
    _, poses, _ = fitted
    sub = poses.subset([4, 1])
    assert sub.body_names == poses.body_names and np.array_equal(sub.bodies, poses.bodies[[4, 1]])
    assert sub.body_noise == poses.body_noise


# ---------------------------------------------------------------------------- estimation

def test_simulated_bodies_recover_the_geometry_at_its_crb(fitted):
    truth, poses, cal = fitted
    assert int(np.sum(np.array(cal.td_status) == "estimated")) > 20  # a stewart's geometry, not a few numbers
    assert cal.body_rho_source == "declared" and cal.body_rho == pytest.approx(SIGMA_P / SIGMA_R)
    # the geometry is judged where every gauge agrees: predictions at new commands against the
    # noise-free truth. With the noise declared right the fit's covariance is the Cramer-Rao bound,
    # and the errors are that size (one draw of a sum over ~40 directions: within a factor 1.6)
    err, crb = prediction_vs_crb(cal, noise_free(truth, poses))
    assert np.all(err / crb > 1 / 1.6) and np.all(err / crb < 1.6), (err, crb)
    assert crb[0] < SIGMA_P  # 60 poses fix the body's origin better than one measurement
    # residual noise per axis back at the position noise (both channels are metres of that noise)
    assert cal.noise_sigma == pytest.approx(SIGMA_P, rel=0.2)


def test_rho_is_estimated_when_not_declared(stewart):
    truth = BodyTruth(stewart, seed=4)
    poses = truth.poses(60, declared=False)
    cal = calibrate(poses, stewart)
    assert cal.body_rho_source == "estimated"
    # robust scales of 60 residual norms each: 0.92 to 1.04 of the truth over 8 seeds (docs); 15% is ~3.5 sd
    assert cal.body_rho == pytest.approx(SIGMA_P / SIGMA_R, rel=0.15)


def test_same_data_as_markers_gives_the_same_geometry(fitted, stewart):
    truth, poses, cal_b = fitted
    # the same measurements as four points of the body's frame at 0.1 m (their noise: SIGMA_P plus
    # 0.1 m * SIGMA_R through the arm, correlated between the four, which the marker fit ignores)
    cal_m = calibrate(as_markers(poses, 0.1), stewart)
    test = noise_free(truth, poses)
    _, crb = prediction_vs_crb(cal_b, test)
    header_b, rows_b, ok_b = prediction_table(cal_b, test.controls)
    header_m, rows_m, ok_m = prediction_table(cal_m, test.controls)
    assert ok_b.all() and ok_m.all()
    origin_b = rows_b[:, [header_b.index(f"T1_{a}") for a in "xyz"]] * 1e-3
    pts_m = np.stack([rows_m[:, [header_m.index(f"T1{k}_{a}") for a in "xyz"]] * 1e-3 for k in "OXYZ"], axis=1)
    # tolerance: the two geometries differ by less than either is expected to miss the truth (the
    # body fit's CRB): both are unbiased fits of the same noise, only weighted differently
    d_origin = np.sqrt(np.mean(np.sum((origin_b - pts_m[:, 0]) ** 2, axis=1)))
    assert d_origin < crb[0], (d_origin, crb[0])
    R_b = matrix_from_quat(rows_b[:, [header_b.index(f"T1_{a}") for a in ("qw", "qx", "qy", "qz")]])
    axes_m = (pts_m[:, 1:] - pts_m[:, :1]) / 0.1  # (N, 3 axes, 3): the marker fit's body axes
    d_rot = np.sqrt(np.mean(np.sum((np.swapaxes(R_b, 1, 2) - axes_m) ** 2, axis=2)))
    assert d_rot * cal_b.body_rho < crb[1], (d_rot, crb[1] / cal_b.body_rho)


# ---------------------------------------------------------------------------- outputs

def test_calibration_yaml_round_trip_and_predict_writes_seven_columns(fitted, tmp_path):
    truth, poses, cal = fitted
    path = tmp_path / "calibration.yaml"
    path.write_text(cal.to_yaml())
    back = read_calibration(path)
    assert back.body_names == ["T1"] and back.body_rho_source == "declared"
    assert np.allclose(back.body_positions, cal.body_positions) and np.allclose(back.body_rotvecs, cal.body_rotvecs)
    U, clean = truth.bodies(truth.controls(20), noisy=False)
    header, rows, ok = prediction_table(back, U)
    cols = [header.index(f"T1_{a}") for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    assert cols == list(range(cols[0], cols[0] + 7))
    pred = rows[:, cols]
    assert ok.all()
    # against the noise-free truth: the origin within the position noise scale (in mm), the
    # orientation within the rotation noise scale
    assert np.max(np.linalg.norm(pred[:, :3] * 1e-3 - clean[:, 0, :3], axis=1)) < 5 * SIGMA_P
    ang = np.linalg.norm(log_so3(np.einsum("nba,nbc->nac", matrix_from_quat(pred[:, 3:]),
                                           matrix_from_quat(clean[:, 0, 3:]))), axis=1)
    assert np.max(ang) < 5 * SIGMA_R
    assert np.all(pred[:, 3] >= 0)
    assert predict_bodies(back, np.tile([1.0, 0, 0, 0], (2, 1)), np.zeros((2, 3))).shape == (2, 1, 7)


# ---------------------------------------------------------------------------- session files

def _write_session(folder, spec, U, bodies, names, stream_t=None, noise=True, settled=True, extra_yaml=""):
    """A session folder by hand: commands.csv, and poses.csv (settled) or markers.csv (stream,
    ``bodies`` then (K, B, 7) at ``stream_t``), lengths in mm."""
    folder.mkdir()
    noise_yaml = "rigid_body_noise: {position_mm: 0.1, rotation_deg: 0.0572958}\n" if noise else ""
    (folder / "session.yaml").write_text(
        f"platform: {spec.name}\nunits: {{length: mm, time: s}}\nmarkers: []\nrigid_bodies: [{', '.join(names)}]\n"
        + noise_yaml + extra_yaml)
    cols = [f"{b}_{a}" for b in names for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]

    def body_rows(B):
        out = np.array(B, float).reshape(len(B), -1)
        for k in range(len(names)):
            out[:, 7 * k:7 * k + 3] *= 1e3
        return out

    t_cmd = np.arange(len(U)) * 1.0
    U_file = np.array([[u * 1e3 if c.unit == "m" else u for u, c in zip(row, spec.controls)] for row in U])
    with open(folder / "commands.csv", "w") as f:
        f.write(",".join(["t"] + spec.control_names) + "\n")
        for t, row in zip(t_cmd, U_file):
            f.write(",".join([f"{t:.6f}"] + [f"{v:.9f}" for v in row]) + "\n")
    if settled:
        with open(folder / "poses.csv", "w") as f:
            f.write(",".join(["t"] + spec.control_names + cols) + "\n")
            for t, row, b in zip(t_cmd, U_file, body_rows(bodies)):
                f.write(",".join([f"{t:.6f}"] + [f"{v:.9f}" for v in row] + ["" if not np.isfinite(v) else f"{v:.9f}"
                                                                             for v in b]) + "\n")
    else:
        with open(folder / "markers.csv", "w") as f:
            f.write(",".join(["t"] + cols) + "\n")
            for t, b in zip(stream_t, body_rows(bodies)):
                f.write(",".join([f"{t:.6f}"] + ["" if not np.isfinite(v) else f"{v:.9f}" for v in b]) + "\n")
    return folder


def test_poses_csv_with_a_body_calibrates(stewart, tmp_path):
    from platkit.settle import load_poses
    truth = BodyTruth(stewart, seed=5)
    U, bodies = truth.bodies(truth.controls(50))
    bodies[7, 0] = np.nan  # occluded: all seven empty
    folder = _write_session(tmp_path / "s", stewart, U, bodies, ["T1"])
    poses = load_poses(folder)
    assert poses.body_names == ["T1"] and poses.n_markers == 0 and np.isnan(poses.bodies[7, 0]).all()
    assert poses.body_noise["position_m"] == pytest.approx(1e-4)
    assert poses.body_noise["rotation_rad"] == pytest.approx(1e-3, rel=1e-6)
    assert np.allclose(poses.bodies[:7, 0, :3], bodies[:7, 0, :3], atol=1e-12)
    cal = calibrate(poses, stewart)
    err, crb = prediction_vs_crb(cal, noise_free(truth, poses))
    assert np.all(err < 1.6 * crb)


def test_stream_of_a_body_is_settled_and_averaged(stewart, tmp_path):
    from platkit.settle import load_poses
    truth = BodyTruth(stewart, seed=6)
    U, clean = truth.bodies(truth.controls(30), noisy=False)
    rate, hold = 100.0, 1.0
    rng = np.random.default_rng(0)
    t = np.arange(int(len(U) * hold * rate)) / rate
    row = np.minimum((t / hold).astype(int), len(U) - 1)
    stream = clean[row].copy()  # (K, 1, 7): holds without motion between them (steps)
    stream[..., :3] += rng.normal(0, SIGMA_P, stream[..., :3].shape)
    R = matrix_from_quat(stream[..., 3:]) @ matrix_from_rotvec(rng.normal(0, SIGMA_R, stream[..., :3].shape))
    stream[..., 3:] = quat_from_matrix(R) * np.where(rng.random((len(t), 1, 1)) < 0.5, -1, 1)  # either sign
    stream[::37, 0] = np.nan
    folder = _write_session(tmp_path / "s", stewart, U, stream, ["T1"], stream_t=t, settled=False)
    poses = load_poses(folder)
    assert poses.n_markers == 0 and poses.n_bodies == 1 and poses.n_poses >= 25
    seen = poses.n_body_samples[:, 0] > 0
    assert seen.all()
    rows = poses.extras["row"]
    # averaged over the settled windows: tenths of the sample noise
    d_pos = np.linalg.norm(poses.bodies[:, 0, :3] - clean[rows, 0, :3], axis=1)
    assert np.max(d_pos) < 4 * SIGMA_P
    d_rot = np.linalg.norm(log_so3(np.einsum("nba,nbc->nac", matrix_from_quat(poses.bodies[:, 0, 3:]),
                                             matrix_from_quat(clean[rows, 0, 3:]))), axis=1)
    assert np.max(d_rot) < 4 * SIGMA_R


@pytest.mark.parametrize("change, message", [
    (lambda b: b.__setitem__((3, 0, 4), np.nan), "row 4 (line 5) column 'T1_qx': empty while other columns"),
    (lambda b: b.__setitem__((5, 0, 3), 2.0), "row 6 (line 7) column 'T1_qw': the quaternion of body 'T1' has norm"),
])
def test_bad_body_rows_are_one_line_errors(stewart, tmp_path, change, message):
    from platkit.errors import BadSession
    from platkit.io.session import load_session
    truth = BodyTruth(stewart, seed=7)
    U, bodies = truth.bodies(truth.controls(10))
    change(bodies)
    folder = _write_session(tmp_path / "s", stewart, U, bodies, ["T1"])
    with pytest.raises(BadSession, match=message.replace("(", r"\(").replace(")", r"\)")) as info:
        load_session(folder)
    assert "\n" not in str(info.value) and "poses.csv" in str(info.value)


def test_bad_body_declarations_are_one_line_errors(stewart, tmp_path):
    from platkit.errors import BadSession
    from platkit.io.session import load_session
    truth = BodyTruth(stewart, seed=8)
    U, bodies = truth.bodies(truth.controls(10))
    folder = _write_session(tmp_path / "a", stewart, U, bodies, ["T1"], noise=False,
                            extra_yaml="rigid_body_noise: {position_mm: 0.1}\n")
    with pytest.raises(BadSession, match="rigid_body_noise' needs one rotation sigma"):
        load_session(folder)
    folder = _write_session(tmp_path / "b", stewart, U, bodies, ["T1"], extra_yaml="markers_file: m.c3d\n")
    (folder / "m.c3d").write_bytes(b"")
    with pytest.raises(BadSession, match="cannot be read as C3D"):  # bodies come from its ROTATION group
        load_session(folder)
    folder = _write_session(tmp_path / "c", stewart, U, bodies, ["T1"])
    (folder / "session.yaml").write_text((folder / "session.yaml").read_text().replace("[T1]", "[S]"))
    with pytest.raises(BadSession, match="column 'T1_x' is for a rigid body 'T1' that session.yaml does not declare"):
        load_session(folder)


def test_cli_calibrates_a_body_session_and_predict_writes_its_columns(stewart, tmp_path):
    from platkit.cli import main
    truth = BodyTruth(stewart, seed=9)
    U, bodies = truth.bodies(truth.controls(40))
    folder = _write_session(tmp_path / "s", stewart, U, bodies, ["T1"], noise=False)
    out = tmp_path / "out"
    assert main(["calibrate", str(folder), "--quiet", "--out", str(out)]) == 0
    cal = read_calibration(out / "calibration.yaml")
    assert cal.body_names == ["T1"] and cal.body_rho_source == "estimated"
    U_new, clean = truth.bodies(truth.controls(6), noisy=False)
    with open(tmp_path / "commands.csv", "w") as f:
        f.write(",".join(stewart.control_names) + "\n")
        for row in U_new:
            f.write(",".join(f"{v * 1e3:.9f}" for v in row) + "\n")
    assert main(["predict", "--calibration", str(out / "calibration.yaml"), "--commands",
                 str(tmp_path / "commands.csv"), "--out", str(tmp_path / "pred.csv")]) == 0
    lines = (tmp_path / "pred.csv").read_text().splitlines()
    header = lines[0].split(",")
    cols = [header.index(f"T1_{a}") for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]
    values = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])[:, cols]
    assert np.max(np.abs(values[:, :3] * 1e-3 - clean[:, 0, :3])) < 5 * SIGMA_P  # a 40-pose fit: below the noise


def test_simulated_session_with_a_body_round_trips_through_its_files(stewart, tmp_path):
    from platkit.settle import load_poses
    from platkit.simulate import simulate, write_session
    plain = simulate(stewart, seed=2, n_poses=30, raw=False)
    sim = simulate(stewart, seed=2, n_poses=30, raw=False, n_bodies=1)
    assert np.array_equal(plain.poses.markers, sim.poses.markers, equal_nan=True)  # bodies draw from their own stream
    folder = write_session(sim, tmp_path / "s", poses_only=True)
    poses = load_poses(folder)
    assert poses.body_names == ["T1"] and poses.body_noise == pytest.approx(sim.truth.body_noise)
    assert np.allclose(poses.bodies[..., :3], sim.poses.bodies[..., :3], atol=1e-6, equal_nan=True)
    assert np.array_equal(poses.n_body_samples, sim.poses.n_body_samples)
    cal = calibrate(poses, stewart)
    assert cal.body_rho_source == "declared"
    # the simulated body is where the truth put it, seen through the fitted stand: predict it
    U = sim.poses.controls[:5]
    fb = PlatformModel(stewart).forward_batch(U, sim.truth.td, strict=False)
    T = sim.truth.mocap_from_base
    R = T[:3, :3] @ matrix_from_quat(fb.q)
    true_origin = fb.X @ T[:3, :3].T + T[:3, 3] + np.einsum("nab,b->na", R, sim.truth.body_origins[0])
    _, q, X, _ = predict_markers(cal, U)
    pred = predict_bodies(cal, q, X)
    assert np.max(np.linalg.norm(pred[:, 0, :3] - true_origin, axis=1)) < 5 * SIGMA_P


def test_validate_with_bodies_reports_their_errors(fitted, stewart):
    from platkit.calibrate.estimate import second_session_errors
    truth, poses, cal = fitted
    other = truth.poses(30)
    out = second_session_errors(cal, other)
    # a new session with the same noise: each origin off by its 3-D noise, sqrt(3) sigma (+ the fit's share)
    assert out["rms_per_body"]["T1"] == pytest.approx(np.sqrt(3) * SIGMA_P, rel=0.3)
    assert out["rotation_rms_per_body_rad"]["T1"] == pytest.approx(np.sqrt(3) * SIGMA_R, rel=0.3)
    assert out["rms"] == pytest.approx(out["rms_per_body"]["T1"])
    renamed = other.subset(np.arange(other.n_poses))
    renamed.body_names = ["S"]
    with pytest.raises(BadInput, match="has no marker or rigid body 'T1'"):
        second_session_errors(cal, renamed)


def test_diagnose_reads_bodies_as_points_and_says_so(fitted, capsys):
    """diagnose reads a session's rigid bodies as three points each beside its markers
    (platkit.diagnose.bodies; tests/unit/test_diagnose_bodies.py diagnoses with them)."""
    from platkit.commands.diagnose import with_body_points
    from platkit.notices import collecting
    _, poses, _ = fitted
    with collecting() as said:
        alone = with_body_points(poses.subset(np.arange(5)), "s")
    assert alone.n_bodies == 0 and alone.marker_names == ["T1.o", "T1.x", "T1.y"]
    assert np.allclose(alone.markers[:, 0], poses.bodies[:5, 0, :3])
    assert said == ["s: rigid bodies diagnosed as three points each, origin and axis tips at 100 mm "
                    "(T1 as T1.o/T1.x/T1.y)"]
    both = as_markers(poses, 0.1).subset(np.arange(5))
    both.bodies, both.body_names = poses.bodies[:5], ["T1"]
    with collecting():
        out = with_body_points(both, "s")
    assert out.n_bodies == 0 and out.n_markers == 4 + 3 and out.marker_names[4:] == ["T1.o", "T1.x", "T1.y"]
    assert "rigid bodies diagnosed as three points each" in capsys.readouterr().err


def test_markers_and_a_body_together(stewart):
    truth = BodyTruth(stewart, seed=10)
    U = truth.controls(60)
    U, noisy = truth.bodies(U)
    _, clean = truth.bodies(U, noisy=False)
    body_only = PoseSet("stewart", U, np.zeros((len(U), 0, 3)), [], bodies=noisy, body_names=["T1"],
                        body_noise={"position_m": SIGMA_P, "rotation_rad": SIGMA_R})
    pts = as_markers(PoseSet("stewart", U, np.zeros((len(U), 0, 3)), [], bodies=clean, body_names=["T1"]), 0.1)
    both = PoseSet("stewart", U, pts.markers + truth.rng.normal(0, SIGMA_P, pts.markers.shape), pts.marker_names,
                   bodies=noisy, body_names=["T1"], body_noise=dict(body_only.body_noise))
    cal = calibrate(both, stewart)
    test = noise_free(truth, body_only)
    test.markers = as_markers(test, 0.1).markers
    test.marker_names = pts.marker_names
    err, crb = prediction_vs_crb(cal, test)
    assert err.shape == (4 + 2,)  # four markers, the body's origin and rotation
    # each channel one draw: 0.60 to 1.51 of its CRB over seeds 10-15, so a factor 2 either way
    assert np.all(err / crb > 0.5) and np.all(err / crb < 2.0), (err, crb)
    # the markers add information: the body's origin is predicted better than from the body alone
    _, crb_alone = prediction_vs_crb(calibrate(body_only, stewart), noise_free(truth, body_only))
    assert crb[4] < crb_alone[0]
