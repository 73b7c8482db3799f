"""Simulated calibration sessions for any registered stand, with a known truth.

Two simulators. This module's :func:`simulate` is the additive one (fast, the default of
``platkit simulate``): hidden effects are the model terms diagnosis fits, added to the controls,
the pose or the markers. :func:`platkit.simulate.physics.simulate_physics` (``--physics``) plays
the stand's physics out in time instead (docs/simulation.md). Both take effects by name from the
effect library (platkit.simulate.effects): one implementation per effect, its plugin's.

The additive simulation draws a true stand near the nominal one (parameters perturbed by a few mm or mrad,
seeded), a base-to-mocap transform and marker positions; it sends a command plan, moves the
controls smoothly between commands (minimum-jerk profile), adds a settling transient (a damped
oscillation after each arrival), solves forward kinematics with the true parameters at the
motion-capture rate, and records every marker with Gaussian noise and bursts of occlusion.
Hidden effects enter as model terms (platkit.terms.ModelTerm) with their true
parameters: ``terms=[(term, theta), ...]``.

    sim = simulate(spec, seed=1, n_poses=60)           # in memory: sim.poses, sim.truth
    simulate_session(spec, "out/session", seed=1)      # a session folder with truth.yaml

Only the PlatformSpec / PlatformModel API is used: nothing here knows a particular stand.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from platkit.calibrate.bodies import stream_for_settling, with_settled_bodies
from platkit.calibrate.plan import default_marker_layout, feasible, stand_length_scale
from platkit.calibrate.settle import SettleOptions, direction_of_last_motion, last_step, settle
from platkit.errors import BadInput, NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.io.atomic import atomic_output_dir
from platkit.io.jsonout import plain
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec, controls_from_si, length_scale
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.simulate.effects import simulation_term
from platkit.simulate.files import csv_text, fmt, truth_imu, write_imu_files
from platkit.simulate.physics import PhysicalSession, simulate_physics, write_physical_session
from platkit.simulate.stand import make_plan, perturb_parameters, random_mocap_from_base
from platkit.terms import ModelTerm

__all__ = ["Truth", "Simulation", "Trajectory", "simulate", "simulate_session", "write_session", "perturb_parameters",
           "random_mocap_from_base", "PhysicalSession", "simulate_physics", "write_physical_session"]



@dataclass
class Truth:
    """What the simulated stand really was (SI units).

    td (n_td,) true parameters; td_nominal (n_td,); mocap_from_base (4, 4); markers (M, 3) m
    in the moving frame; terms [(ModelTerm, theta)]; noise_m marker noise per coordinate;
    base_markers (B, 3) m in the base frame, or None. Rigid bodies: body_names, their placements
    on the moving part body_origins (B, 3) m and body_rotvecs (B, 3) rad (body frame -> moving
    frame), body_noise {'position_m', 'rotation_rad'} per-axis sigmas of each sample.
    """

    platform: str
    parameter_names: list[str]
    td: np.ndarray
    td_nominal: np.ndarray
    mocap_from_base: np.ndarray
    marker_names: list[str]
    markers: np.ndarray
    terms: list[tuple[ModelTerm, np.ndarray]]
    noise_m: float
    occlusion: float
    seed: int
    description: str | None = None
    base_marker_names: list[str] = field(default_factory=list)
    base_markers: np.ndarray | None = None  # (B, 3) m in the base frame
    body_names: list[str] = field(default_factory=list)
    body_origins: np.ndarray | None = None
    body_rotvecs: np.ndarray | None = None
    body_noise: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The truth.yaml mapping (SI: metres, radians)."""
        return {
            "platform": self.platform,
            "description": self.description,
            "seed": int(self.seed),
            "units": {"length": "m", "angle": "rad"},
            "parameters": {
                n: {"value": float(v), "nominal": float(v0), "error": float(v - v0)}
                for n, v, v0 in zip(self.parameter_names, self.td, self.td_nominal)
            },
            "mocap_from_base": [[float(x) for x in row] for row in self.mocap_from_base],
            "markers": {n: [float(x) for x in s] for n, s in zip(self.marker_names, self.markers)},
            "base_markers": {n: [float(x) for x in s] for n, s in zip(self.base_marker_names,
                                                                     () if self.base_markers is None else self.base_markers)},
            "effects": [plain(term.to_dict(theta)) for term, theta in self.terms],
            "marker_noise_m": float(self.noise_m),
            "occlusion": float(self.occlusion),
            **({"rigid_bodies": {n: {"position": [float(x) for x in o], "rotation_vector": [float(x) for x in r]}
                                 for n, o, r in zip(self.body_names, self.body_origins, self.body_rotvecs)},
                "rigid_body_noise": {k: float(v) for k, v in self.body_noise.items()}} if self.body_names else {}),
        }


@dataclass
class Trajectory:
    """The true motion: command times and controls, and a way to evaluate the true pose.

    ``at(t)`` -> (q (K, 4), X (K, 3)) of the moving frame in the base frame at times t (K,),
    effects included; used for the motion-capture stream and by IMU simulation.
    """

    command_t: np.ndarray
    commands: np.ndarray
    arrive_t: np.ndarray
    end_t: float
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]] = field(repr=False)

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q, X, _ = self.evaluate(np.asarray(t, float))
        return q, X


@dataclass
class Simulation:
    """A simulated session in memory.

    poses: the settled PoseSet (from the raw stream through settle() when raw, else drawn
    directly); truth: Truth; command_t (N,), commands (N, n_u) internal units; marker_t (K,)
    and markers (K, M, 3) m in the mocap frame (raw only); trajectory; imu: dict with t, gyr,
    acc (and optionally 'entry' for session.yaml), or None.
    """

    spec: PlatformSpec
    poses: PoseSet
    truth: Truth
    command_t: np.ndarray
    commands: np.ndarray
    marker_t: np.ndarray | None
    markers: np.ndarray | None
    trajectory: Trajectory | None
    mocap_rate_hz: float
    length_unit: str
    imu: dict | None = None
    plan_info: dict = field(default_factory=dict)
    base_markers: np.ndarray | None = None  # (K, B, 3) m, mocap frame, the stream of markers on the base
    bodies: np.ndarray | None = None  # (K, B, 7) the rigid bodies' stream (origin m, unit quaternion), mocap frame


def _min_jerk(s):
    s = np.clip(s, 0.0, 1.0)
    return s**3 * (10 - 15 * s + 6 * s**2)


def _occlusion_mask(rng, K: int, M: int, fraction: float, mean_burst: int) -> np.ndarray:
    """(K, M) True where occluded: bursts of mean length ``mean_burst`` covering ~``fraction``."""
    if fraction <= 0:
        return np.zeros((K, M), bool)
    p_end = 1.0 / max(mean_burst, 1)
    p_start = fraction * p_end / max(1 - fraction, 1e-9)
    out = np.zeros((K, M), bool)
    for m in range(M):
        u = rng.random(K)
        state = False
        col = out[:, m]
        for k in range(K):
            state = (u[k] >= p_end) if state else (u[k] < p_start)
            col[k] = state
    return out


def _commands_poseset(spec, U, t, marker_names) -> PoseSet:
    steps = last_step(U)
    return PoseSet(platform=spec.name, controls=U, markers=np.zeros((len(U), len(marker_names), 3)),
                   marker_names=list(marker_names), t=t, source="simulated",
                   extras={"row": np.arange(len(U)), "direction": direction_of_last_motion(U), "last_step": steps,
                           "elapsed": t - t[0]})


def _imu_truth_of_terms(truth_imu: dict, terms) -> None:
    """Add what pose effects do to an IMU's truth: a ``base_tilt`` term turns the whole stand
    about the base's x and y axes in the level world (the mocap transform absorbs it, gravity in
    the model's base frame turns with it), so the accelerometer sees a base tilted by its
    (tilt_x, tilt_y); they add to a tilt the IMU hook was given (``base_tilt_rad``)."""
    tilts = [np.asarray(theta, float)[:2] for term, theta in terms if term.effect == "base_tilt"]
    if tilts:
        truth_imu["base_tilt_rad"] = (np.asarray(truth_imu.get("base_tilt_rad", np.zeros(2)), float)
                                      + np.sum(tilts, axis=0)).tolist()


def _apply_pose_offset(q, X, off):
    """X' = X + dX, R' = exp(dtheta) R for (K, 4), (K, 3), (K, 6)."""
    if not np.any(off):
        return q, X
    R = matrix_from_rotvec(off[:, 3:]) @ matrix_from_quat(q)
    return quat_from_matrix(R), X + off[:, :3]


def simulate(spec: PlatformSpec, *, seed: int = 0, n_poses: int = 80, plan: Any = "grid", noise_mm: float = 0.2,
             occlusion: float = 0.02, n_markers: int = 5, raw: bool = True, terms=(), effects=(),
             mocap_rate_hz: float = 100.0, hold_s: float = 1.5, length_unit: str = "mm",
             imu: Callable | None = None, perturbation: float = 1.0, markers: np.ndarray | None = None,
             settle_options: SettleOptions | None = None, description: str | None = None,
             n_base_markers: int = 0, n_bodies: int = 0, body_noise_mm: float = 0.1,
             body_noise_deg: float = 0.05) -> Simulation:
    """Simulate a session of ``spec`` in memory.

    plan: 'grid' (snake-ordered grid, about n_poses points), 'random', a plan.csv path, a
        Plan, or an (N, n_u) array of controls in internal units.
    noise_mm: marker noise per coordinate (mm); occlusion: fraction of samples occluded.
    terms: [(ModelTerm, theta)] hidden effects; effects: [(name, size or None)] effects by name
        (see platkit.simulate.effects), built on the plan's command rows.
    raw: simulate the stream and settle it (realistic); False draws settled poses directly.
    imu: optional callable ``imu(trajectory, rng) -> dict(t=(J,), gyr=(J, 3), acc=(J, 3)[, entry])``
        that adds an inertial stream (raw only: with raw=False it is an error), e.g.
        :func:`platkit.inertial.simulate.imu_for_trajectory`; its optional ``q_base_from_platform``
        (J, 4) and ``truth_imu`` (a mapping) become the truth files of :func:`write_session`.
    hold_s: time the stand holds each command after arriving (s).
    n_base_markers: markers fixed on the base (B1, B2, ...), around the stand on the floor; they
        pin the base-to-mocap transform.
    n_bodies: rigid bodies measured in 6 DOF on the moving part (T1, T2, ...), each sample with
        per-axis noise body_noise_mm on its origin and body_noise_deg on its orientation (occluded
        like the markers); their placements are drawn from their own random stream, so adding
        them leaves the rest of the simulation as it was.
    """

    length_scale(length_unit)
    if noise_mm < 0 or not 0 <= occlusion < 0.5:
        raise BadInput("noise must be >= 0 and occlusion in [0, 0.5)")
    if imu is not None and not raw:
        raise BadInput("an IMU stream needs the simulated motion: simulate with raw=True (not poses only)")
    rng = np.random.default_rng(seed)
    model = PlatformModel(spec)
    U, plan_info = make_plan(spec, plan, n_poses, rng, model, length_unit)
    model.check_controls(U)
    td_true = perturb_parameters(spec, rng, perturbation)
    ok, P_true = feasible(spec, U, td_true, model)
    if not np.all(ok):
        plan_info["unreachable_with_true_geometry"] = int((~ok).sum())
        U, P_true = U[ok], P_true[ok]
    if len(U) < 3:
        raise NotIdentifiable(f"{spec.name}: fewer than 3 planned poses are reachable")
    if markers is not None:
        S = np.asarray(markers, float)
        if S.ndim != 2 or S.shape[1] != 3 or len(S) < 3:
            raise BadInput(f"markers must be (M, 3) positions on the moving part with M >= 3, got shape {S.shape}")
        n_markers = len(S)
    else:
        S = default_marker_layout(spec, n_markers, rng)
    names = [f"M{k + 1}" for k in range(n_markers)]
    T = random_mocap_from_base(rng, stand_length_scale(spec) / 0.6)
    noise = noise_mm * 1e-3
    N = len(U)
    # base markers draw from their own stream, so adding them leaves everything else as it was
    brng = np.random.default_rng([seed, 7])
    base_names = [f"B{k + 1}" for k in range(n_base_markers)]
    B = None
    if n_base_markers:
        rho = 1.5 * stand_length_scale(spec) / 0.6
        ang = 2 * np.pi * np.arange(n_base_markers) / n_base_markers + brng.uniform(-0.3, 0.3, n_base_markers)
        B = np.stack([rho * np.cos(ang), rho * np.sin(ang), brng.uniform(0, 0.05, n_base_markers) * rho], axis=1)
    B_mocap = None if B is None else B @ T[:3, :3].T + T[:3, 3]
    body_rng = np.random.default_rng([seed, 11])
    body_names = [f"T{k + 1}" for k in range(n_bodies)]
    body_o = body_rng.normal(0, 0.3 * stand_length_scale(spec), (n_bodies, 3))
    body_rv = body_rng.normal(0, 1.0, (n_bodies, 3))
    body_noise = {"position_m": body_noise_mm * 1e-3, "rotation_rad": np.deg2rad(body_noise_deg)} if n_bodies else {}

    def bodies_of(q, X, shrink=1.0):
        """(K, n_bodies, 7) in the mocap frame, noise divided by ``shrink`` ((K, n_bodies) or 1)."""
        R = T[:3, :3] @ matrix_from_quat(q)  # (K, 3, 3) mocap_from_moving
        o = (X @ T[:3, :3].T + T[:3, 3])[:, None] + np.einsum("kab,mb->kma", R, body_o)
        shape = (len(q), n_bodies, 3)
        k = np.broadcast_to(np.asarray(shrink, float), shape[:2])[..., None]
        o = o + body_rng.normal(size=shape) * body_noise.get("position_m", 0.0) / k
        turn = matrix_from_rotvec(body_rng.normal(size=shape) * body_noise.get("rotation_rad", 0.0) / k)
        Rw = np.einsum("kab,mbc,kmcd->kmad", R, matrix_from_rotvec(body_rv), turn)
        return np.concatenate([o, quat_from_matrix(Rw)], axis=2)

    # command times: move (min-jerk, duration from the largest stroke fraction), then hold
    lo, hi = spec.control_bounds()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    prev = np.vstack([spec.neutral_u()[None], U[:-1]])
    move = np.clip(4.0 * np.max(np.abs(U - prev) / span, axis=1), 0.3, 3.0)
    t_cmd = np.round(0.5 + np.concatenate([[0.0], np.cumsum(move + hold_s)[:-1]]), 6)  # as written
    t_arrive = t_cmd + move
    t_end = float(t_arrive[-1] + hold_s)

    commands = _commands_poseset(spec, U, t_cmd, names)
    all_terms = list(terms) + [simulation_term(n, spec, s, rng, commands) for n, s in effects]
    n_u = spec.n_u
    c_off = np.zeros((N, n_u))
    m_off = np.zeros((N, n_markers, 3))
    for term, theta in all_terms:
        c_off += term.control_offset(np.asarray(theta, float), commands, n_u)
        m_off += term.marker_offset(np.asarray(theta, float), commands)
    has_pose_off = any(type(t).pose_offset is not ModelTerm.pose_offset for t, _ in all_terms)
    U_true = U + c_off

    def pose_offsets(rows_ps: PoseSet, q, X):
        off = np.zeros((len(q), 6))
        for term, theta in all_terms:
            off += term.pose_offset(np.asarray(theta, float), rows_ps, q, X)
        return off

    truth = Truth(spec.name, spec.parameter_names, td_true, spec.nominal_td(), T, names, S, all_terms,
                  noise, occlusion, seed, description, base_names, B, body_names, body_o, body_rv, body_noise)

    def markers_of(q, X, moff):
        R = matrix_from_quat(q)
        body = S[None] + moff  # (K, M, 3)
        base = X[:, None, :] + np.einsum("kij,kmj->kmi", R, body)
        return base @ T[:3, :3].T + T[:3, 3]

    if not raw:
        fb = model.forward_batch(U_true, td=td_true, guess=P_true, strict=False)
        if not np.all(fb.converged & fb.on_branch):
            raise NotIdentifiable(f"{spec.name}: the effects push {int((~fb.converged).sum())} poses off the stand")
        q, X = fb.q, fb.X
        if has_pose_off:
            q, X = _apply_pose_offset(q, X, pose_offsets(commands, q, X))
        n_avg = max(1, int(0.5 * hold_s * mocap_rate_hz))
        counts = rng.binomial(n_avg, 1 - occlusion, size=(N, n_markers)).astype(float)
        Y = markers_of(q, X, m_off) + rng.normal(size=(N, n_markers, 3)) * noise / np.sqrt(np.maximum(counts, 1))[..., None]
        Y[counts == 0] = np.nan
        base_avg = None
        if B_mocap is not None:
            base_avg = B_mocap + brng.normal(size=B_mocap.shape) * noise / np.sqrt(n_avg * N)
        body_counts = body_rng.binomial(n_avg, 1 - occlusion, size=(N, n_bodies)).astype(float)
        bod = bodies_of(q, X, np.sqrt(np.maximum(body_counts, 1)))
        bod[body_counts == 0] = np.nan
        poses = PoseSet(platform=spec.name, controls=U, markers=Y, marker_names=names, description=description,
                        base_markers=base_avg, t=t_cmd, n_samples=counts, length_unit=length_unit, source="simulated",
                        extras={"row": np.arange(N), "direction": commands.extras["direction"],
                                "last_step": commands.extras["last_step"], "elapsed": commands.extras["elapsed"],
                                "settle_time": np.full(N, 0.5 * hold_s)},
                        bodies=bod, body_names=body_names, n_body_samples=body_counts if n_bodies else None,
                        body_noise=dict(body_noise))
        return Simulation(spec, poses, truth, t_cmd, U, None, None, None, mocap_rate_hz, length_unit,
                          plan_info=plan_info)

    # raw stream: controls along the trajectory, with a damped transient after each arrival
    prev_true = np.vstack([spec.neutral_u()[None], U_true[:-1]])
    prev_moff = np.vstack([np.zeros((1, n_markers, 3)), m_off[:-1]])
    tau, freq, overshoot = 0.12, 3.0, 0.05

    def evaluate(t):
        i = np.clip(np.searchsorted(t_cmd, t, side="right") - 1, 0, N - 1)
        before = t < t_cmd[0]
        s = _min_jerk((t - t_cmd[i]) / move[i])
        s = np.where(before, 0.0, s)
        delta = U_true[i] - prev_true[i]
        after = np.maximum(t - t_arrive[i], 0.0)
        wiggle = overshoot * np.exp(-after / tau) * np.sin(2 * np.pi * freq * after) * (t >= t_arrive[i])
        u = prev_true[i] + (s + wiggle)[:, None] * delta
        moff = prev_moff[i] + s[:, None, None] * (m_off[i] - prev_moff[i])
        guess = np.where(before[:, None], spec.neutral_p(), P_true[i])
        fb = model.forward_batch(u, td=td_true, guess=guess, strict=False)
        if not np.all(fb.converged):
            bad = int(np.nonzero(~fb.converged)[0][0])
            raise NotIdentifiable(f"{spec.name}: forward kinematics failed along the path at t={t[bad]:.3f} s")
        q, X = fb.q, fb.X
        if has_pose_off:
            rows = commands.subset(i)
            off = pose_offsets(rows, q, X)
            q, X = _apply_pose_offset(q, X, off * np.where(before, 0.0, 1.0)[:, None])
        return q, X, moff

    dt = 1.0 / mocap_rate_hz
    tm = np.round(np.arange(0.0, t_end, dt), 6)
    q, X, moff = evaluate(tm)
    Y = markers_of(q, X, moff) + rng.normal(size=(len(tm), n_markers, 3)) * noise
    Y[_occlusion_mask(rng, len(tm), n_markers, occlusion, max(1, int(0.1 * mocap_rate_hz)))] = np.nan
    # keep 1 um steps, as the files do, so in-memory and written sessions agree
    Y = np.round(Y * 1e6) / 1e6
    YB = None
    if B_mocap is not None:
        YB = B_mocap[None] + brng.normal(size=(len(tm),) + B_mocap.shape) * noise
        YB[_occlusion_mask(brng, len(tm), n_base_markers, occlusion, max(1, int(0.1 * mocap_rate_hz)))] = np.nan
        YB = np.round(YB * 1e6) / 1e6
    bod = None
    if n_bodies:
        bod = bodies_of(q, X)
        bod[_occlusion_mask(body_rng, len(tm), n_bodies, occlusion, max(1, int(0.1 * mocap_rate_hz)))] = np.nan
        bod[..., :3] = np.round(bod[..., :3] * 1e6) / 1e6
        bod[..., 3:] = np.round(bod[..., 3:] * 1e9) / 1e9
    traj = Trajectory(t_cmd, U, t_arrive, t_end, evaluate)
    imu_data = imu(traj, rng) if imu is not None else None
    if imu_data is not None and "truth_imu" in imu_data:
        _imu_truth_of_terms(imu_data["truth_imu"], all_terms)


    sess = Session(folder=Path("simulated"), platform=spec.name, spec=spec, description=None,
                   length_unit=length_unit, time_unit="s", marker_names=names, base_marker_names=base_names,
                   mocap_rate_hz=mocap_rate_hz, imu=None, moving_link=None, notes="",
                   command_t=t_cmd, commands=U, marker_t=tm, markers=Y, base_markers=YB,
                   markers_source=Path("simulated"), body_names=body_names, body_noise=dict(body_noise), bodies=bod)
    poses, report = settle(stream_for_settling(sess), settle_options)
    poses = with_settled_bodies(sess, poses)
    poses.source = "simulated"
    poses.description = description
    plan_info.update(settle_sigma_m=report.sigma_m, kept=report.n_kept, dropped=len(report.dropped))
    return Simulation(spec, poses, truth, t_cmd, U, tm, Y, traj, mocap_rate_hz, length_unit, imu_data, plan_info,
                      base_markers=YB, bodies=bod)


# ----------------------------------------------------------------------------- files


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
            "moving_link": moving_link,
            "notes": notes or f"simulated by platkit (seed {sim.truth.seed}); the true stand is in truth.yaml",
        }
        if base_link is not None:
            entry["base_link"] = base_link
        bnames_6dof = list(sim.truth.body_names)
        if bnames_6dof:
            entry["rigid_bodies"] = bnames_6dof
            entry["rigid_body_noise"] = {"position_mm": float(sim.truth.body_noise["position_m"] * 1e3),
                                         "rotation_deg": float(np.rad2deg(sim.truth.body_noise["rotation_rad"]))}
        bcols = [f"{b}_{a}" for b in bnames_6dof for a in ("x", "y", "z", "qw", "qx", "qy", "qz")]

        def body_cells(row7):  # (B, 7) -> cells: origins in the unit, quaternions to 9 digits, empty if unseen
            return ["" if not np.isfinite(v) else (fmt(v / s, ldig) if j % 7 < 3 else f"{v:.9f}")
                    for j, v in enumerate(row7.reshape(-1))]
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
                    r += body_cells(p.bodies[i]) + [str(int(n)) for n in p.n_body_samples[i]]
                rows.append(r)
            header = (spec.control_names + mcols + [f"{m}_n" for m in names] + bcols
                      + [f"{b}_n" for b in bnames_6dof])
            (tmp / "poses.csv").write_text(csv_text(header, rows), encoding="utf-8")
        else:
            Y = sim.markers if sim.base_markers is None else np.concatenate([sim.markers, sim.base_markers], axis=1)
            Y = Y.reshape(len(sim.marker_t), -1) / s
            rows = [[f"{t:.6f}"] + [fmt(v, ldig) for v in row] for t, row in zip(sim.marker_t, Y)]
            if bnames_6dof:
                rows = [r + body_cells(b) for r, b in zip(rows, sim.bodies)]
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


def simulate_session(spec: PlatformSpec | str, out: str | Path, *, poses_only: bool = False,
                     description: str | Path | None = None, moving_link: str | None = None,
                     base_link: str | None = None, **kwargs) -> Path:
    """Simulate (see :func:`simulate`) and write a session folder; returns its path. ``spec``
    may be a stand name (built with ``description`` and the link options)."""
    if isinstance(spec, str):

        options = {k: v for k, v in (("moving_link", moving_link), ("base_link", base_link)) if v is not None}
        spec = get_platform(spec, description, **options)
    if poses_only:
        kwargs["raw"] = False
    sim = simulate(spec, description=None if description is None else Path(description).name, **kwargs)
    return write_session(sim, out, poses_only=poses_only, description=description, moving_link=moving_link,
                         base_link=base_link)
