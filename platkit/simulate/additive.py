"""The additive simulator: hidden effects are the model terms diagnosis fits, added to the
controls, the pose or the markers (docs/simulation.md).

It draws a true stand near the nominal one (parameters perturbed by a few mm or mrad, seeded), a
base-to-mocap transform and marker positions; it sends a command plan, moves the controls
smoothly between commands (minimum-jerk profile), adds a settling transient (a damped oscillation
after each arrival), solves forward kinematics with the true parameters at the motion-capture
rate, records every marker with Gaussian noise and bursts of occlusion, and settles the stream.
Each of these is one function below; :func:`simulate` runs them in order.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Unpack

import numpy as np

from platkit.bodies import stream_for_settling, with_settled_bodies
from platkit.calibrate.plan import default_marker_layout, feasible, marker_link_indices, stand_length_scale
from platkit.calibrate.problem import link_frames
from platkit.errors import BadInput, NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import nominal_inverse
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.settle import direction_of_last_motion, last_step, settle
from platkit.simulate.effects import simulation_term
from platkit.simulate.options import (
    PlanOptions,
    RecordingOptions,
    SimulateKeywords,
    SimulationOptions,
    TruthOptions,
    options_from_keywords,
)
from platkit.simulate.results import Simulation, Trajectory, Truth
from platkit.simulate.rigid_bodies import BodyLayout, body_samples, draw_bodies, links_in_mocap, round_bodies
from platkit.simulate.stand import make_plan, perturb_parameters, random_mocap_from_base
from platkit.terms import ModelTerm

__all__ = ["simulate", "plan_commands", "draw_true_stand", "command_schedule", "hidden_effects",
           "settled_poses_directly", "true_trajectory", "record_stream", "settle_stream", "TrueStand", "Schedule",
           "HiddenEffects", "RecordedStream", "TreeTrajectory"]


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
    """Add what pose effects do to an IMU's truth: a term with a ``level_tilt`` turns the whole
    stand about the base's x and y axes in the level world (the mocap transform absorbs it, gravity
    in the model's base frame turns with it), so the accelerometer sees a base tilted by it; the
    tilts add to one the IMU hook was given (``base_tilt_rad``)."""
    tilts = [t for t in (term.level_tilt(np.asarray(theta, float)) for term, theta in terms) if t is not None]
    if tilts:
        truth_imu["base_tilt_rad"] = (np.asarray(truth_imu.get("base_tilt_rad", np.zeros(2)), float)
                                      + np.sum(tilts, axis=0)).tolist()


def _apply_pose_offset(q, X, off):
    """X' = X + dX, R' = exp(dtheta) R for (K, 4), (K, 3), (K, 6)."""
    if not np.any(off):
        return q, X
    R = matrix_from_rotvec(off[:, 3:]) @ matrix_from_quat(q)
    return quat_from_matrix(R), X + off[:, :3]


# ----------------------------------------------------------------------------- the steps


@dataclass
class TrueStand:
    """The stand as it really is, drawn once per session (SI units).

    td (n_td,) true parameters; controls (N, n_u) the planned commands it can reach, and
    poses (N, n_p) its forward solutions; markers (M, 3) m in the moving frame; mocap_from_base
    (4, 4); base_markers (B, 3) m in the base frame or None; bodies placed on the moving part at
    body_origins (T, 3) m with body_rotvecs (T, 3) rad. base_rng and body_rng: the random streams
    of the base markers and the bodies, apart from the session's, so that adding them leaves the
    rest of the simulation as it was.
    """

    td: np.ndarray
    controls: np.ndarray
    poses: np.ndarray
    marker_names: list[str]
    markers: np.ndarray
    mocap_from_base: np.ndarray
    base_marker_names: list[str]
    base_markers: np.ndarray | None
    base_rng: np.random.Generator
    body_names: list[str]
    body_origins: np.ndarray
    body_rotvecs: np.ndarray
    body_noise: dict
    body_rng: np.random.Generator
    marker_links: list[int] | None = None  # a tree: the tracked link each marker rides on (spec.tracked_links)
    body_links: list[int] | None = None  # a tree: the tracked link each rigid body rides on, as the markers

    def moving_link(self, spec: PlatformSpec) -> dict[str, str] | None:
        """A tree's mapping marker or rigid body -> tracked link (session.yaml's moving_link); None
        on a chain."""
        if self.marker_links is None:
            return None
        out = {m: spec.tracked_links[k] for m, k in zip(self.marker_names, self.marker_links)}
        out.update({b: spec.tracked_links[k] for b, k in zip(self.body_names, self.body_links or [])})
        return out

    @property
    def base_markers_mocap(self) -> np.ndarray | None:
        """(B, 3) m, the base markers in the mocap frame."""
        T = self.mocap_from_base
        return None if self.base_markers is None else self.base_markers @ T[:3, :3].T + T[:3, 3]

    def markers_of(self, q: np.ndarray, X: np.ndarray, moff: np.ndarray, frames=None) -> np.ndarray:
        """(K, M, 3) m in the mocap frame of the markers at poses q (K, 4), X (K, 3), displaced
        on the moving part by moff (K, M, 3); on a tree each on its link of ``frames`` (R (K, L, 3, 3),
        X (K, L, 3): every tracked link's pose)."""
        T = self.mocap_from_base
        body = self.markers[None] + moff  # (K, M, 3)
        if self.marker_links is not None and frames is not None:
            R_all, X_all = frames
            k = np.asarray(self.marker_links)
            base = X_all[:, k] + np.einsum("kmij,kmj->kmi", R_all[:, k], body)
            return base @ T[:3, :3].T + T[:3, 3]
        R = matrix_from_quat(q)
        base = X[:, None, :] + np.einsum("kij,kmj->kmi", R, body)
        return base @ T[:3, :3].T + T[:3, 3]

    def bodies_of(self, q: np.ndarray, X: np.ndarray, shrink=1.0, frames=None) -> np.ndarray:
        """(K, n_bodies, 7) in the mocap frame, noise divided by ``shrink`` ((K, n_bodies) or 1); on
        a tree each body on its link of ``frames`` (R (K, L, 3, 3), X (K, L, 3), as :meth:`markers_of`)."""
        noise, layout = self.body_noise, self.body_layout
        R, origin = links_in_mocap(self.mocap_from_base, q, X, len(self.body_names), self.body_links, frames)
        shape = (len(q), len(self.body_names), 3)
        k = np.broadcast_to(np.asarray(shrink, float), shape[:2])[..., None]
        dpos = self.body_rng.normal(size=shape) * noise.get("position_m", 0.0) / k
        drot = self.body_rng.normal(size=shape) * noise.get("rotation_rad", 0.0) / k
        return body_samples(R, origin, layout, dpos, drot)

    @property
    def body_layout(self) -> BodyLayout:
        return BodyLayout(self.body_names, self.body_origins, self.body_rotvecs, self.body_links)


@dataclass
class Schedule:
    """When each command is sent, reached and left: command_t (N,) s as written, move (N,) s
    the duration of each move (min-jerk), arrive_t (N,) s, end_t the end of the recording."""

    command_t: np.ndarray
    move: np.ndarray
    arrive_t: np.ndarray
    end_t: float


@dataclass
class HiddenEffects:
    """The hidden effects on the plan's commands: terms [(ModelTerm, theta)] (given and built by
    name), the controls the stand really receives controls (N, n_u), the marker displacements
    marker_offsets (N, M, 3) m, and the commands as a PoseSet the terms are evaluated on."""

    commands: PoseSet
    terms: list
    controls: np.ndarray
    marker_offsets: np.ndarray
    moves_pose: bool

    def pose_offsets(self, rows: PoseSet, q: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(K, 6) the pose offsets (dX, dtheta) of the terms at poses q (K, 4), X (K, 3)."""
        off = np.zeros((len(q), 6))
        for term, theta in self.terms:
            off += term.pose_offset(np.asarray(theta, float), rows, q, X)
        return off


def plan_commands(spec: PlatformSpec, plan: PlanOptions, rng: np.random.Generator, model: PlatformModel,
                  length_unit: str) -> tuple[np.ndarray, dict]:
    """The planned commands (N, n_u) internal units, checked against the strokes (by make_plan),
    and what the planning says (plan_info)."""
    return make_plan(spec, plan.plan, plan.n_poses, rng, model, length_unit)


def draw_true_stand(spec: PlatformSpec, seed: int, truth: TruthOptions, recording: RecordingOptions,
                    rng: np.random.Generator, model: PlatformModel, U: np.ndarray, plan_info: dict) -> TrueStand:
    """The true parameters, the commands reachable with them (plan_info says how many were not),
    the markers, the motion-capture frame, the base markers and the rigid bodies."""
    td_true = perturb_parameters(spec, rng, truth.perturbation)
    ok, P_true = feasible(spec, U, td_true, model)
    if not np.all(ok):
        plan_info["unreachable_with_true_geometry"] = int((~ok).sum())
        U, P_true = U[ok], P_true[ok]
    if len(U) < 3:
        raise NotIdentifiable(f"{spec.name}: fewer than 3 planned poses are reachable")
    n_markers = recording.n_markers
    if truth.markers is not None:
        S = np.asarray(truth.markers, float)
        if S.ndim != 2 or S.shape[1] != 3 or len(S) < 3:
            raise BadInput(f"markers must be (M, 3) positions on the moving part with M >= 3, got shape {S.shape}")
        n_markers = len(S)
    else:
        S = default_marker_layout(spec, n_markers, rng)
    names = [f"M{k + 1}" for k in range(n_markers)]
    T = random_mocap_from_base(rng, stand_length_scale(spec) / 0.6)
    n_base_markers = recording.n_base_markers
    brng = np.random.default_rng([seed, 7])
    base_names = [f"B{k + 1}" for k in range(n_base_markers)]
    B = None
    if n_base_markers:
        rho = 1.5 * stand_length_scale(spec) / 0.6
        ang = 2 * np.pi * np.arange(n_base_markers) / n_base_markers + brng.uniform(-0.3, 0.3, n_base_markers)
        B = np.stack([rho * np.cos(ang), rho * np.sin(ang), brng.uniform(0, 0.05, n_base_markers) * rho], axis=1)
    n_bodies = recording.n_bodies
    body_rng = np.random.default_rng([seed, 11])
    bodies = draw_bodies(spec, n_bodies, body_rng)
    body_noise = ({"position_m": recording.body_noise_mm * 1e-3, "rotation_rad": np.deg2rad(recording.body_noise_deg)}
                  if n_bodies else {})
    links = marker_link_indices(spec, n_markers)  # a tree: each marker's tracked link, as plan places them
    return TrueStand(td_true, U, P_true, names, S, T, base_names, B, brng, bodies.names, bodies.origins,
                     bodies.rotvecs, body_noise, body_rng, links, bodies.links)


def command_schedule(spec: PlatformSpec, U: np.ndarray, hold_s: float) -> Schedule:
    """Command times: move (min-jerk, duration from the largest stroke fraction), then hold."""
    lo, hi = spec.control_bounds()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    prev = np.vstack([spec.neutral_u()[None], U[:-1]])
    move = np.clip(4.0 * np.max(np.abs(U - prev) / span, axis=1), 0.3, 3.0)
    t_cmd = np.round(0.5 + np.concatenate([[0.0], np.cumsum(move + hold_s)[:-1]]), 6)  # as written
    t_arrive = t_cmd + move
    return Schedule(t_cmd, move, t_arrive, float(t_arrive[-1] + hold_s))


def hidden_effects(spec: PlatformSpec, truth: TruthOptions, rng: np.random.Generator, stand: TrueStand,
                   schedule: Schedule) -> HiddenEffects:
    """The given terms and the effects by name (built on the commands), and what they do to the
    controls and the markers."""
    U = stand.controls
    commands = _commands_poseset(spec, U, schedule.command_t, stand.marker_names)
    all_terms = list(truth.terms) + [simulation_term(n, spec, s, rng, commands) for n, s in truth.effects]
    c_off = np.zeros((len(U), spec.n_u))
    m_off = np.zeros((len(U), len(stand.marker_names), 3))
    for term, theta in all_terms:
        c_off += term.control_offset(np.asarray(theta, float), commands, spec.n_u)
        m_off += term.marker_offset(np.asarray(theta, float), commands)
    moves_pose = any(type(t).pose_offset is not ModelTerm.pose_offset for t, _ in all_terms)
    return HiddenEffects(commands, all_terms, U + c_off, m_off, moves_pose)


def settled_poses_directly(spec: PlatformSpec, model: PlatformModel, options: SimulationOptions,
                           rng: np.random.Generator, stand: TrueStand, schedule: Schedule,
                           hidden: HiddenEffects) -> PoseSet:
    """Settled poses drawn without a stream: each the average of the samples of half a hold,
    its noise shrunk by the samples seen."""
    rec = options.recording
    U, N, n_markers, n_bodies = stand.controls, len(stand.controls), len(stand.marker_names), len(stand.body_names)
    fb = model.forward_batch(hidden.controls, td=stand.td, guess=stand.poses, strict=False)
    if not np.all(fb.converged & fb.on_branch):
        raise NotIdentifiable(f"{spec.name}: the effects push {int((~fb.converged).sum())} poses off the stand")
    q, X = fb.q, fb.X
    frames = None
    if stand.marker_links is not None:  # a tree: every tracked link's pose
        frames = link_frames(spec, stand.td, hidden.controls)
    if hidden.moves_pose:
        off = hidden.pose_offsets(hidden.commands, q, X)
        q, X = _apply_pose_offset(q, X, off)
        if frames is not None:  # the pose offsets move every tracked link alike (as the model's do)
            frames = _offset_frames(frames, off)
    noise = rec.noise_mm * 1e-3
    n_avg = max(1, int(0.5 * rec.hold_s * rec.mocap_rate_hz))
    counts = rng.binomial(n_avg, 1 - rec.occlusion, size=(N, n_markers)).astype(float)
    Y = (stand.markers_of(q, X, hidden.marker_offsets, frames)
         + rng.normal(size=(N, n_markers, 3)) * noise / np.sqrt(np.maximum(counts, 1))[..., None])
    Y[counts == 0] = np.nan
    base_avg = None
    B_mocap = stand.base_markers_mocap
    if B_mocap is not None:
        base_avg = B_mocap + stand.base_rng.normal(size=B_mocap.shape) * noise / np.sqrt(n_avg * N)
    body_counts = stand.body_rng.binomial(n_avg, 1 - rec.occlusion, size=(N, n_bodies)).astype(float)
    bod = stand.bodies_of(q, X, np.sqrt(np.maximum(body_counts, 1)), frames)
    bod[body_counts == 0] = np.nan
    commands = hidden.commands
    return PoseSet(platform=spec.name, controls=U, markers=Y, marker_names=stand.marker_names,
                   description=options.description, base_markers=base_avg, t=schedule.command_t, n_samples=counts,
                   length_unit=rec.length_unit, source="simulated",
                   extras={"row": np.arange(N), "direction": commands.extras["direction"],
                           "last_step": commands.extras["last_step"], "elapsed": commands.extras["elapsed"],
                           "settle_time": np.full(N, 0.5 * rec.hold_s)},
                   bodies=bod, body_names=stand.body_names, n_body_samples=body_counts if n_bodies else None,
                   body_noise=dict(stand.body_noise), moving_link=stand.moving_link(spec))


@dataclass
class RecordedStream:
    """The raw recording: marker_t (K,) s, markers (K, M, 3) and base_markers (K, B, 3) or None
    m in the mocap frame, bodies (K, T, 7) or None, the true trajectory, the IMU's dict or None."""

    marker_t: np.ndarray
    markers: np.ndarray
    base_markers: np.ndarray | None
    bodies: np.ndarray | None
    trajectory: Trajectory
    imu: dict | None


def true_trajectory(spec: PlatformSpec, model: PlatformModel, stand: TrueStand, schedule: Schedule,
                    hidden: HiddenEffects) -> Trajectory:
    """The true motion: controls along min-jerk moves with a damped transient after each arrival,
    solved with the true parameters, pose effects added."""
    t_cmd, move, t_arrive = schedule.command_t, schedule.move, schedule.arrive_t
    N, U_true, m_off = len(t_cmd), hidden.controls, hidden.marker_offsets
    prev_true = np.vstack([spec.neutral_u()[None], U_true[:-1]])
    prev_moff = np.vstack([np.zeros((1, len(stand.marker_names), 3)), m_off[:-1]])
    tau, freq, overshoot = 0.12, 3.0, 0.05
    # paths in the space the stand declares free: poses for a pose-free stand (its controls along a
    # straight control path fit no pose), controls otherwise
    pose_path = spec.pose_free
    prev_poses = np.vstack([spec.neutral_p()[None], stand.poses[:-1]])

    def state(t):
        """(q, X, moff, u the true controls, off the pose offsets or None) at times t."""
        i = np.clip(np.searchsorted(t_cmd, t, side="right") - 1, 0, N - 1)
        before = t < t_cmd[0]
        s = _min_jerk((t - t_cmd[i]) / move[i])
        s = np.where(before, 0.0, s)
        delta = U_true[i] - prev_true[i]
        after = np.maximum(t - t_arrive[i], 0.0)
        wiggle = overshoot * np.exp(-after / tau) * np.sin(2 * np.pi * freq * after) * (t >= t_arrive[i])
        if pose_path:  # a pose-free stand moves along straight lines in its pose coordinates
            u = _pose_path_controls(model, prev_poses[i], stand.poses[i], prev_true[i], U_true[i], s + wiggle)
        else:
            u = prev_true[i] + (s + wiggle)[:, None] * delta
        moff = prev_moff[i] + s[:, None, None] * (m_off[i] - prev_moff[i])
        guess = np.where(before[:, None], spec.neutral_p(), stand.poses[i])
        fb = model.forward_batch(u, td=stand.td, guess=guess, strict=False)
        if not np.all(fb.converged):
            bad = int(np.nonzero(~fb.converged)[0][0])
            raise NotIdentifiable(f"{spec.name}: forward kinematics failed along the path at t={t[bad]:.3f} s")
        q, X = fb.q, fb.X
        off = None
        if hidden.moves_pose:
            rows = hidden.commands.subset(i)
            off = hidden.pose_offsets(rows, q, X) * np.where(before, 0.0, 1.0)[:, None]
            q, X = _apply_pose_offset(q, X, off)
        return q, X, moff, u, off

    def evaluate(t):
        q, X, moff, _, _ = state(t)
        return q, X, moff

    if stand.marker_links is None:
        return Trajectory(t_cmd, stand.controls, t_arrive, schedule.end_t, evaluate)

    def frames(t):  # every tracked link, the pose offsets moving each alike (as the model terms do)
        _, _, _, u, off = state(t)
        return _offset_frames(link_frames(spec, stand.td, u), off)

    return TreeTrajectory(t_cmd, stand.controls, t_arrive, schedule.end_t, evaluate, frames=frames)


@dataclass
class TreeTrajectory(Trajectory):
    """The true motion of a tree: besides the moving frame, frames(t) -> (R (K, L, 3, 3),
    X (K, L, 3)), every tracked link in the base frame at times t (K,), effects included."""

    frames: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]] = field(repr=False, kw_only=True)


def _offset_frames(frames, off):
    """Tracked links' frames (R (K, L, 3, 3), X (K, L, 3)) moved by the pose offsets off (K, 6)
    or None: every link alike, as the model terms' pose offsets move them."""
    if off is None or not np.any(off):
        return frames
    return (np.einsum("kab,klbc->klac", matrix_from_rotvec(off[:, 3:]), frames[0]), frames[1] + off[:, None, :3])


def _pose_path_controls(model: PlatformModel, P0: np.ndarray, P1: np.ndarray, U0: np.ndarray, U1: np.ndarray,
                        frac: np.ndarray) -> np.ndarray:
    """Controls (K, n_u) at fractions ``frac`` (K,) of straight moves in pose coordinates from P0 to
    P1 (K, n_p each): the nominal inverse kinematics of the interpolated pose (the stand's closed
    form batched where it has one, else pose by pose), plus the endpoints' differences between the
    controls sent (U0, U1) and that inverse, interpolated alike, so the path starts and ends on the
    controls sent."""
    td0 = model.spec.nominal_td()

    def ik(P):
        return nominal_inverse(model, np.ascontiguousarray(P), td0)[0]

    f = np.asarray(frac, float)[:, None]
    return ik(P0 + f * (P1 - P0)) + (1 - f) * (U0 - ik(P0)) + f * (U1 - ik(P1))


def record_stream(options: SimulationOptions, rng: np.random.Generator, stand: TrueStand,
                  trajectory: Trajectory) -> RecordedStream:
    """The motion-capture stream of the trajectory at the mocap rate, with noise and bursts of
    occlusion, rounded to 1 um as the files hold it; the IMU's stream when there is a hook."""
    rec = options.recording
    n_markers, noise = len(stand.marker_names), rec.noise_mm * 1e-3
    burst = max(1, int(0.1 * rec.mocap_rate_hz))
    dt = 1.0 / rec.mocap_rate_hz
    tm = np.round(np.arange(0.0, trajectory.end_t, dt), 6)
    q, X, moff = trajectory.evaluate(tm)
    frames = trajectory.frames(tm) if isinstance(trajectory, TreeTrajectory) else None
    Y = stand.markers_of(q, X, moff, frames) + rng.normal(size=(len(tm), n_markers, 3)) * noise
    Y[_occlusion_mask(rng, len(tm), n_markers, rec.occlusion, burst)] = np.nan
    # keep 1 um steps, as the files do, so in-memory and written sessions agree
    Y = np.round(Y * 1e6) / 1e6
    YB = None
    B_mocap = stand.base_markers_mocap
    if B_mocap is not None:
        YB = B_mocap[None] + stand.base_rng.normal(size=(len(tm),) + B_mocap.shape) * noise
        YB[_occlusion_mask(stand.base_rng, len(tm), len(stand.base_marker_names), rec.occlusion, burst)] = np.nan
        YB = np.round(YB * 1e6) / 1e6
    bod = None
    if stand.body_names:
        bod = stand.bodies_of(q, X, frames=frames)
        bod[_occlusion_mask(stand.body_rng, len(tm), len(stand.body_names), rec.occlusion, burst)] = np.nan
        round_bodies(bod)
    imu_data = options.imu(trajectory, rng) if options.imu is not None else None
    return RecordedStream(tm, Y, YB, bod, trajectory, imu_data)


def settle_stream(spec: PlatformSpec, options: SimulationOptions, stand: TrueStand, schedule: Schedule,
                  stream: RecordedStream, plan_info: dict) -> PoseSet:
    """The settled poses of the raw stream, as ``platkit calibrate`` would settle a recorded
    session; plan_info gets the settling's sigma and what it kept and dropped."""
    rec = options.recording
    sess = Session(folder=Path("simulated"), platform=spec.name, spec=spec, description=None,
                   length_unit=rec.length_unit, time_unit="s", marker_names=stand.marker_names,
                   base_marker_names=stand.base_marker_names, mocap_rate_hz=rec.mocap_rate_hz, imu=None,
                   moving_link=stand.moving_link(spec), notes="", command_t=schedule.command_t, commands=stand.controls,
                   marker_t=stream.marker_t, markers=stream.markers, base_markers=stream.base_markers,
                   markers_source=Path("simulated"), body_names=stand.body_names, body_noise=dict(stand.body_noise),
                   bodies=stream.bodies)
    poses, report = settle(stream_for_settling(sess), options.settle)
    poses = with_settled_bodies(sess, poses)
    poses.source = "simulated"
    poses.description = options.description
    plan_info.update(settle_sigma_m=report.sigma_m, kept=report.n_kept, dropped=len(report.dropped))
    return poses


# ----------------------------------------------------------------------------- the simulation


def simulate(spec: PlatformSpec, options: SimulationOptions | None = None,
             **keywords: Unpack[SimulateKeywords]) -> Simulation:
    """Simulate a session of ``spec`` in memory.

    ``options``: a :class:`~platkit.simulate.options.SimulationOptions` (the plan, the truth, the
    recording, the seed; see there), or the flat keywords of :class:`SimulateKeywords`, e.g.
    ``simulate(spec, seed=1, n_poses=60, noise_mm=0.1)``; keywords given with ``options``
    change those fields of it. The steps, each a function of this module:
    :func:`plan_commands`, :func:`draw_true_stand`, :func:`command_schedule`,
    :func:`hidden_effects`, then :func:`settled_poses_directly` (``raw=False``) or
    :func:`true_trajectory`, :func:`record_stream` and :func:`settle_stream`.

    The optional IMU hook's ``q_base_from_platform`` (J, 4) and ``truth_imu`` (a mapping) become
    the truth files of :func:`write_session`; base markers and rigid bodies draw from their own
    random streams, so adding them leaves the rest of the simulation as it was.
    """
    opts = options_from_keywords(options, **keywords) if keywords else (options or SimulationOptions())
    rec = opts.recording
    rec.check()
    if opts.imu is not None and not opts.raw:
        raise BadInput("an IMU stream needs the simulated motion: simulate with raw=True (not poses only)")
    rng = np.random.default_rng(opts.seed)
    model = PlatformModel(spec)
    U, plan_info = plan_commands(spec, opts.plan, rng, model, rec.length_unit)
    stand = draw_true_stand(spec, opts.seed, opts.truth, rec, rng, model, U, plan_info)
    schedule = command_schedule(spec, stand.controls, rec.hold_s)
    hidden = hidden_effects(spec, opts.truth, rng, stand, schedule)
    truth = Truth(spec.name, spec.parameter_names, stand.td, spec.nominal_td(), stand.mocap_from_base,
                  stand.marker_names, stand.markers, hidden.terms, rec.noise_mm * 1e-3, rec.occlusion, opts.seed,
                  opts.description, stand.base_marker_names, stand.base_markers, stand.body_names,
                  stand.body_origins, stand.body_rotvecs, stand.body_noise)
    if not opts.raw:
        poses = settled_poses_directly(spec, model, opts, rng, stand, schedule, hidden)
        return Simulation(spec, poses, truth, schedule.command_t, stand.controls, None, None, None,
                          rec.mocap_rate_hz, rec.length_unit, plan_info=plan_info)
    trajectory = true_trajectory(spec, model, stand, schedule, hidden)
    stream = record_stream(opts, rng, stand, trajectory)
    if stream.imu is not None and "truth_imu" in stream.imu:
        _imu_truth_of_terms(stream.imu["truth_imu"], hidden.terms)
    poses = settle_stream(spec, opts, stand, schedule, stream, plan_info)
    return Simulation(spec, poses, truth, schedule.command_t, stand.controls, stream.marker_t, stream.markers,
                      trajectory, rec.mocap_rate_hz, rec.length_unit, stream.imu, plan_info,
                      base_markers=stream.base_markers, bodies=stream.bodies)
