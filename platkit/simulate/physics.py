"""A physical calibration stand in the time domain, recorded only through the session format.

Where the additive simulator (platkit.simulate.simulate) adds the model terms diagnosis fits,
this one plays out physics in time, so that a proof of settling and diagnosis runs on data that
platkit's model terms did not make:

1. commands are sent on a schedule (the move's duration at the drives' limits, then a hold);
2. each actuator follows its command (platkit.simulate.actuator): a rate- and
   acceleration-limited profile through its own damped second-order response, integrated every
   ``fine_step_s``, so every hold begins with an approach that settles in time;
3. the effects' physics act where they act (platkit.effects.EffectPhysics, from each effect's
   ``physics``): the actuators' response, the drive between the position reached and the
   travel the kinematics sees (play, gear errors, heat, load), the base against the level
   world, markers moving on the platform;
4. forward kinematics of the true actuator positions with the true geometry
   (PlatformModel.forward_batch; a stand with more rows than pose coordinates, a cable robot, at
   its rows' weighted least-squares pose whatever their misfit, see ``_Stand.pose``), markers at their true places, through a true
   mocap_from_base, sampled at the motion capture's rate with its latency and clock offset,
   white and correlated noise and bursts of occlusion (platkit.simulate.nuisance, drawn per
   session from the seed);
5. the truth: the true stand, the effects' parameters, the nuisances, and the TRUE SETTLED
   pose and markers of every command: the same physics driven by drives that reach each
   command at once (every transient gone), at the end of its hold (slow states, such as a
   leg's heat, as they are then).

    sim = simulate_physics(spec, seed=3, n_poses=240, effects=[("backlash", 1.0)])
    write_physical_session(sim, "out/session")   # session.yaml, commands.csv, markers.csv,
                                                 # truth.yaml, truth_settled.csv [, imu.csv]

Independent random streams (stand, plan, nuisances, each effect, noise, occlusion) come from
the seed, so adding an effect leaves the stand and the nuisances as they were.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from platkit.calibrate.plan import default_marker_layout, feasible, marker_link_indices, stand_length_scale
from platkit.calibrate.problem import link_frames
from platkit.effects import Effect, EffectPhysics, PhysicsPlan, PhysicsSeries
from platkit.errors import BadInput, ComputationFailed, NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, transform
from platkit.inertial.simulate import imu_for_trajectory
from platkit.io.atomic import atomic_output_dir
from platkit.io.jsonout import plain
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec, controls_from_si, length_scale
from platkit.plugins import effect_library
from platkit.simulate.actuator import ActuatorResponse, actuator_motion, profile_duration
from platkit.simulate.continuous import continuous_plan
from platkit.simulate.files import csv_text, dropped_note, fmt, write_imu_files
from platkit.simulate.nuisance import Nuisances, coloured_noise, draw_nuisances, occlusion_mask
from platkit.simulate.rigid_bodies import BodyLayout, bodies_truth, body_samples, draw_bodies, links_in_mocap, round_bodies
from platkit.simulate.stand import make_plan, perturb_parameters
from platkit.simulate.warmup import WarmupPhysics, draw_warmup
from platkit.simulate.write import body_columns, body_entry, body_row

__all__ = ["PhysicalSession", "simulate_physics", "write_physical_session", "physics_of"]

#: seconds from the start of the recording to the first command
LEAD_IN_S = 0.5
#: m: a rigid body's rotation noise (rad) is its position noise over this lever, the spread of a
#: typical motion-capture body's markers (0.2 mm of noise: 2 mrad, 0.11 deg, per axis and sample)
BODY_LEVER_M = 0.1


@dataclass
class PhysicalSession:
    """A physically simulated session in memory (SI; internal control units).

    command_t (N,) s and commands (N, n_u): the command log; marker_t (K,) s on the motion
    capture's clock (offset and latency included) and markers (K, M, 3) m in the mocap frame
    (NaN occluded); base_markers (K, B, 3) or None; settled_q (N, 4), settled_X (N, 3): the true
    settled pose in the base frame; settled_markers (N, M, 3) m in the mocap frame; td (n_td,)
    the true parameters; mocap_from_base (4, 4); marker_body (M, 3) m the markers' places on
    the moving part at the start; physics [(name, EffectPhysics)]; nuisances; imu or None;
    hold_end_t (N,) when each hold ends (commands clock); settled_controls (N, n_u) the true
    actuator travel at rest (what the kinematics saw for the settled pose). Rigid bodies (or
    None): their placements, stream and settled poses, sampled with the markers (see
    :func:`simulate_physics`).
    """

    spec: PlatformSpec
    seed: int
    length_unit: str
    mocap_rate_hz: float
    command_t: np.ndarray
    commands: np.ndarray
    marker_names: list[str]
    marker_t: np.ndarray
    markers: np.ndarray
    settled_q: np.ndarray
    settled_X: np.ndarray
    settled_markers: np.ndarray
    td: np.ndarray
    mocap_from_base: np.ndarray
    marker_body: np.ndarray
    physics: list[tuple[str, EffectPhysics]]
    nuisances: Nuisances
    response: ActuatorResponse
    plan_info: dict = field(default_factory=dict)
    base_marker_names: list[str] = field(default_factory=list)
    base_markers: np.ndarray | None = None
    base_marker_body: np.ndarray | None = None
    imu: dict | None = None
    description: str | None = None
    hold_end_t: np.ndarray | None = None
    settled_controls: np.ndarray | None = None
    moving_link: dict[str, str] | None = None  # a tree: each marker's and body's tracked link (session.yaml's)
    bodies: BodyLayout | None = None  # the rigid bodies' placements (platkit.simulate.rigid_bodies), or None
    body_stream: np.ndarray | None = None  # (K, B, 7) their samples (origin m, quaternion), mocap frame
    settled_bodies: np.ndarray | None = None  # (N, B, 7) each at rest at the end of each hold, no noise

    def truth(self) -> dict:
        """The truth.yaml mapping (SI: metres, radians, seconds on the commands clock)."""
        spec = self.spec
        return {
            "platform": spec.name,
            "description": self.description,
            "seed": int(self.seed),
            "simulator": "physics",
            "units": {"length": "m", "angle": "rad", "time": "s (commands clock)"},
            "parameters": {n: {"value": float(v), "nominal": float(v0), "error": float(v - v0)}
                           for n, v, v0 in zip(spec.parameter_names, self.td, spec.nominal_td())},
            "mocap_from_base": [[float(x) for x in row] for row in self.mocap_from_base],
            "markers": {n: [float(x) for x in s] for n, s in zip(self.marker_names, self.marker_body)},
            **({"marker_links": dict(self.moving_link)} if self.moving_link else {}),
            "base_markers": {n: [float(x) for x in s] for n, s in zip(
                self.base_marker_names, () if self.base_marker_body is None else self.base_marker_body)},
            **({} if self.bodies is None else bodies_truth(self.bodies.names, self.bodies.origins,
                                                             self.bodies.rotvecs, self.body_noise())),
            "effects": [{"effect": name, "physics": plain(p.parameters())} for name, p in self.physics],
            "nuisances": self.nuisances.to_dict(),
            "actuators_with_effects": self.response.to_dict(spec.control_names),
            "settled": "truth_settled.csv: where the stand comes to rest for every command (no transient), at "
                       "the end of its hold",
        }


    def body_noise(self) -> dict:
        """The bodies' white noise per axis and sample ({'position_m', 'rotation_rad'}); their
        correlated part is the markers' (truth.yaml's nuisances), the rotation's over
        :data:`BODY_LEVER_M`."""
        n = self.nuisances
        return {"position_m": n.noise_m, "rotation_rad": n.noise_m / BODY_LEVER_M}


def physics_of(name: str, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
               plan: PhysicsPlan, library: dict[str, Effect] | None = None) -> EffectPhysics:
    """An effect's physics by name, from ``library`` (effect name -> effect; default: every
    installed effect, built-in and outside plugins')."""
    library = effect_library() if library is None else library
    effect = library.get(name)
    if effect is None:
        raise BadInput(f"--effect {name!r}: unknown effect; installed: {', '.join(sorted(library))}")
    physics = effect.physics(spec, size, rng, plan) if hasattr(effect, "physics") else None
    if physics is None:
        raise BadInput(f"effect {name!r} has no physics for the time-domain simulator; leave out --physics "
                       "to simulate it as its model term")
    if not isinstance(physics, EffectPhysics):
        raise BadInput(f"effect {name!r}: physics() returned {type(physics).__name__}, expected an EffectPhysics")
    return physics


def _schedule(U: np.ndarray, start: np.ndarray, nuisances: Nuisances, rng) -> tuple[np.ndarray, np.ndarray]:
    """(command_t (N,), hold_end_t (N,)): each command sent when the previous hold ends; a hold
    lasts the move's duration at the drives' limits (the slowest actuator) plus the hold."""
    prev = np.vstack([start[None], U[:-1]])
    r = nuisances.response
    move = np.max(profile_duration(U - prev, r.rate[None], r.accel[None]), axis=1)
    hold = nuisances.hold_s * (1 + nuisances.hold_jitter * rng.uniform(-1, 1, len(U)))
    span = move + hold
    t_cmd = np.round(LEAD_IN_S + np.concatenate([[0.0], np.cumsum(span)[:-1]]), 6)  # as written to commands.csv
    return t_cmd, np.append(t_cmd[1:], t_cmd[-1] + span[-1])


def _level_mocap(rng, size_m: float) -> np.ndarray:
    """mocap_from_level (4, 4): the motion capture's vertical is the level world's; any heading,
    offset by about the stand's size."""
    heading = rng.uniform(-np.pi, np.pi)
    c, s = np.cos(heading), np.sin(heading)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return transform(R, rng.uniform(-1, 1, 3) * np.array([2.0, 2.0, 0.5]) * max(size_m, 0.2))


class _Stand:
    """The true stand's motion at any sorted times (commands clock): actuators, drive, kinematics."""

    def __init__(self, spec, model, td, plan: PhysicsPlan, response, physics, P_rest, fine_step_s):
        self.spec, self.model, self.td, self.plan = spec, model, td, plan
        self.response, self.physics, self.P_rest, self.fine = response, physics, P_rest, fine_step_s

    def controls(self, t: np.ndarray, rest: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(u (K, n_u) true actuator travel, segment (K,)) at times t."""
        plan = self.plan
        seg = np.searchsorted(plan.command_t, t, side="right") - 1
        if rest:
            motor = np.where(seg[:, None] < 0, plan.start[None], plan.commands[np.maximum(seg, 0)])
        else:
            motor = actuator_motion(t, plan.command_t, plan.commands, plan.start, self.response, self.fine)
        for name, p in self.physics:
            out = np.asarray(p.drive(PhysicsSeries(t, motor, seg, rest), plan), float)
            if out.shape != motor.shape:
                raise BadInput(f"effect {name!r}: its physics' drive returned shape {out.shape}, expected {motor.shape}")
            motor = out
        return motor, seg

    def frames(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """A tree's tracked links (R (K, L, 3, 3), X (K, L, 3)) in the base frame at true actuator
        travel u (K, n_u); None on a stand with one moving link."""
        if self.spec.link_poses is None:
            return None
        return link_frames(self.spec, self.td, u)

    def pose(self, u: np.ndarray, seg: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q, X) at true actuator travel u. A stand with more rows than pose coordinates (a cable
        robot) sits at its rows' weighted least-squares pose whatever their misfit: the elastic
        equilibrium of rows of stiffness 1 / plausible misfit squared, pulling and pushing alike
        (no slack), so actuators that lag one another move the plate, never stop the run."""
        guess = np.where(seg[:, None] < 0, self.spec.neutral_p(), self.P_rest[np.maximum(seg, 0)])
        fb = self.model.forward_batch(u, td=self.td, guess=guess, strict=False, refuse_misfit=False)
        bad = ~(fb.converged & fb.on_branch)
        if self.model.redundant:  # rows far apart, left unfinished by Gauss-Newton: a trust-region solve
            for k in np.nonzero(bad)[0]:
                start = fb.p[k] if np.all(np.isfinite(fb.p[k])) else guess[k]
                got = self.model.least_squares_pose(u[k], self.td, start)
                if got is not None and got[3]:
                    fb.p[k], fb.q[k], fb.X[k] = got[:3]
                    bad[k] = False
        if np.any(bad):
            k = int(np.nonzero(bad)[0][0])
            raise ComputationFailed(f"{self.spec.name}: forward kinematics of the true stand failed at t={t[k]:.3f} s "
                                    f"(controls {np.round(u[k], 6).tolist()}): an effect or the plan leaves the "
                                    "workspace")
        return fb.q, fb.X

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(q (K, 4), X (K, 3)) of the moving frame in the base frame at times t (the IMU hook's
        trajectory); before the first command the stand rests where it starts."""
        t = np.asarray(t, float)
        u, seg = self.controls(t)
        return self.pose(u, seg, t)


class _Trajectory:
    """What an IMU hook reads (platkit.inertial.simulate.imu_for_trajectory)."""

    def __init__(self, stand: _Stand, end_t: float):
        self.stand, self.end_t, self.command_t = stand, end_t, stand.plan.command_t

    def at(self, t):
        return self.stand.at(t)


def simulate_physics(spec: PlatformSpec, *, seed: int = 0, n_poses: int = 240, plan: Any = "grid",
                     effects=(), n_markers: int = 5, n_base_markers: int = 0, mocap_rate_hz: float = 100.0,
                     length_unit: str = "mm", hold_s: float | None = None, noise_mm: float | None = None,
                     occlusion: float | None = None, latency_s: float | None = None,
                     clock_offset_s: float | None = None, coloured: bool = True, overshoot: bool = False,
                     imu: dict | None = None, perturbation: float = 1.0, description: str | None = None,
                     fine_step_s: float = 2e-3, motion: str | None = None, duration_s: float = 200.0,
                     command_rate_hz: float = 20.0, library: dict[str, Effect] | None = None,
                     warmup: str | None = None, actuator_delay_s=None, actuator_rate_limit=None,
                     n_bodies: int = 0) -> PhysicalSession:
    """Simulate a session of ``spec`` in the time domain (see the module's docstring).

    plan: 'grid', 'random', a plan.csv path, a Plan or an (N, n_u) array (internal units).
    effects: [(name, size or None)], sizes as ``platkit simulate --help`` states them, from
        ``library`` (effect name -> effect, e.g. a PluginHost's ``effects()``; default: every
        installed effect).
    hold_s, noise_mm (white, per coordinate and sample), occlusion, latency_s, clock_offset_s:
        fixed nuisances (None: drawn from the seed); coloured False: white noise only;
        overshoot: drives tuned below critical damping.
    imu: None, or the options of platkit.inertial.simulate.imu_for_trajectory (rate_hz, bias,
        noise, ...): an IMU on the moving part, which feels a tilted base.
    motion: None (holds: each command held after its move), or a continuous-motion kind of
        :mod:`platkit.simulate.continuous` ('multisine', 'path', 'cue'): commands streamed every
        1 / ``command_rate_hz`` s for ``duration_s`` s, without holds, each followed as it comes
        (``plan`` and ``n_poses`` are then unused; the last command is held ``hold_s``).
    warmup: None, or a warm-up with time since power-on (platkit.simulate.warmup: 'visible',
        switched on just before the first command; 'warm', long before), its size drawn from the
        seed like a nuisance; it acts after the effects' drives and is listed with them in the
        truth under the effect that models a warm-up (``Effect.warm_up``), form 'warm-up with time'.
    actuator_delay_s, actuator_rate_limit: None, or one value per actuator (s; control's internal
        unit per s): each actuator's own pure delay and speed limit (platkit.simulate.actuator),
        explicit options (drawing them would move every seeded session), in the truth's
        ``actuators_with_effects``.
    n_bodies: rigid bodies T1, T2, ... on the moving part (a tree: body b on tracked link b mod L),
        placed by platkit.simulate.rigid_bodies from their own random stream (as the additive
        simulator places them) and sampled with the markers: the true link's pose at every
        exposure, the markers' white and correlated noise on the origin, the same over
        :data:`BODY_LEVER_M` (rad) on the orientation, bursts of occlusion of the same law.
    """
    _check_options(n_markers, mocap_rate_hz, fine_step_s, length_unit)
    if n_bodies < 0:
        raise BadInput(f"rigid bodies: 0 or more, got {n_bodies}")
    rng_stand, rng_plan, rng_nuis, rng_noise, rng_occ, rng_base = (np.random.default_rng([seed, k]) for k in range(1, 7))
    model = PlatformModel(spec)
    U, plan_info, td, P_rest = _commands(spec, model, seed, plan, n_poses, motion, hold_s, overshoot, perturbation,
                                         duration_s, command_rate_hz, length_unit, rng_plan, rng_stand)
    S = default_marker_layout(spec, n_markers, rng_stand)
    names = [f"M{k + 1}" for k in range(n_markers)]
    links = marker_link_indices(spec, n_markers)  # a tree: each marker's tracked link, as plan places them
    size_m = stand_length_scale(spec) / 0.6
    mocap_from_level = _level_mocap(rng_stand, size_m)
    nuisances = draw_nuisances(spec, rng_nuis, hold_s=hold_s, noise_mm=noise_mm, occlusion=occlusion,
                               overshoot=overshoot, latency_s=latency_s, clock_offset_s=clock_offset_s,
                               coloured=coloured)
    if motion is None:
        t_cmd, hold_end = _schedule(U, spec.neutral_u(), nuisances, rng_nuis)
    else:
        t_cmd = np.round(LEAD_IN_S + np.arange(len(U)) / command_rate_hz, 6)
        hold_end = np.append(t_cmd[1:], t_cmd[-1] + nuisances.hold_s)
    phys_plan = PhysicsPlan(spec, t_cmd, U, spec.neutral_u(), nuisances.hold_s, float(hold_end[-1]), names)
    physics, response = _physics(spec, seed, effects, phys_plan, nuisances, motion is not None, library, warmup)
    if actuator_delay_s is not None:
        response.delay_s = np.broadcast_to(np.asarray(actuator_delay_s, float), (spec.n_u,)).copy()
    if actuator_rate_limit is not None:
        response.rate_limit = np.broadcast_to(np.asarray(actuator_rate_limit, float), (spec.n_u,)).copy()
    response.check()
    tilt = np.zeros(2)
    for _, p in physics:
        w = p.base_tilt()
        if w is not None:
            tilt = tilt + np.asarray(w, float)[:2]
    level_from_base = transform(matrix_from_rotvec(np.array([tilt[0], tilt[1], 0.0])), np.zeros(3))
    rec = _Recorder(_Stand(spec, model, td, phys_plan, response, physics, P_rest, fine_step_s), S,
                    mocap_from_level @ level_from_base, mocap_rate_hz, links)
    marker_t, Y = rec.stream(nuisances, rng_noise, rng_occ)
    last = np.clip(np.searchsorted(rec.t_exp, hold_end, side="left") - 1, 0, len(rec.t_exp) - 1)
    q_s, X_s, settled_markers, u_settled = rec.rest(last)
    body_rng = np.random.default_rng([seed, 11])
    layout = draw_bodies(spec, n_bodies, body_rng) if n_bodies else None
    body_stream, settled_bodies = (None, None) if layout is None else rec.bodies(layout, nuisances, body_rng)
    base_names = [f"B{k + 1}" for k in range(n_base_markers)]
    B, YB = _base_markers(n_base_markers, size_m, rec, nuisances, rng_base)
    imu_data = None
    if imu is not None:
        options = dict(imu)
        if np.any(tilt):
            options["base_tilt"] = tilt + np.asarray(options.get("base_tilt", np.zeros(2)), float)
        imu_data = imu_for_trajectory(**options)(_Trajectory(rec.stand, phys_plan.end_s), np.random.default_rng([seed, 8]))
    plan_info.update(commands=int(len(U)))
    mapping = None if links is None else {n: spec.tracked_links[k] for n, k in zip(names, links)}
    if mapping is not None and layout is not None and layout.links is not None:
        mapping.update({b: spec.tracked_links[k] for b, k in zip(layout.names, layout.links)})
    return PhysicalSession(spec, seed, length_unit, mocap_rate_hz, t_cmd, U, names, marker_t, Y, q_s, X_s,
                           settled_markers, td, rec.T, S, physics, nuisances, response, plan_info, base_names, YB, B,
                           imu_data, description, hold_end, u_settled, mapping, layout, body_stream, settled_bodies)


def _check_options(n_markers: int, mocap_rate_hz: float, fine_step_s: float, length_unit: str) -> None:
    length_scale(length_unit)
    if n_markers < 3:
        raise BadInput(f"markers: at least 3 on the moving part, got {n_markers}")
    if not mocap_rate_hz > 0:
        raise BadInput(f"motion-capture rate must be positive, got {mocap_rate_hz:g}")
    if not 0 < fine_step_s <= 0.01:
        raise BadInput(f"fine_step_s must be in (0, 0.01] s, got {fine_step_s:g}")


def _commands(spec, model, seed, plan, n_poses, motion, hold_s, overshoot, perturbation, duration_s,
              command_rate_hz, length_unit, rng_plan, rng_stand):
    """(U (N, n_u) the commands the true stand reaches, plan_info, td the true parameters,
    P_rest (N, n_p) the true poses at rest): planned (holds) or streamed (``motion``)."""
    if motion is None:
        U, plan_info = make_plan(spec, plan, n_poses, rng_plan, model, length_unit)
    else:  # streamed: planned within the drives' limits, drawn below with the nuisances
        draw = draw_nuisances(spec, np.random.default_rng([seed, 3]), hold_s=hold_s, overshoot=overshoot)
        td_plan = perturb_parameters(spec, np.random.default_rng([seed, 1]), perturbation)
        U, plan_info = continuous_plan(spec, motion, duration_s, command_rate_hz, rng_plan, model, td_plan,
                                       draw.response.rate, draw.response.accel)
        model.check_controls(U)
    td = perturb_parameters(spec, rng_stand, perturbation)
    ok, P_rest = feasible(spec, U, td, model)
    if not np.all(ok):
        plan_info["unreachable_with_true_geometry"] = int((~ok).sum())
        U, P_rest = U[ok], P_rest[ok]
    if len(U) < 3:
        raise NotIdentifiable(f"{spec.name}: fewer than 3 planned poses are reachable")
    return U, plan_info, td, P_rest


def _warm_up_effect(library: dict[str, Effect]) -> str:
    """The name of the one installed effect that is a warm-up with time (``Effect.warm_up``)."""
    names = sorted(name for name, e in library.items() if getattr(e, "warm_up", False))
    if len(names) != 1:
        raise BadInput("warmup: the simulator lists a warm-up under the effect that models it, and "
                       + ("no installed effect models a warm-up with time" if not names
                          else f"several installed effects say they do ({', '.join(names)})"))
    return names[0]


def _physics(spec, seed, effects, phys_plan: PhysicsPlan, nuisances: Nuisances, streamed: bool, library,
             warmup: str | None) -> tuple[list[tuple[str, EffectPhysics]], ActuatorResponse]:
    """The effects' physics (each from its own random stream), the warm-up's last, and the
    actuators' response they leave."""
    physics = [(name, physics_of(name, spec, size, np.random.default_rng([seed, 100 + k]), phys_plan, library))
               for k, (name, size) in enumerate(effects)]
    if warmup is not None:
        w = draw_warmup(spec, warmup, np.random.default_rng([seed, 9]), float(phys_plan.command_t[0]),
                        _warm_up_effect(effect_library() if library is None else library))
        physics.append((w.effect, w))
    r0 = nuisances.response
    response = ActuatorResponse(np.array(r0.tau_s, float), np.array(r0.damping, float), np.array(r0.rate, float),
                                np.array(r0.accel, float), streamed=streamed)
    for _, p in physics:
        p.respond(response)
    response.check()
    return physics, response


class _Recorder:
    """The motion capture of the true stand: ``T`` (4, 4) mocap_from_base, markers at ``S``
    (M, 3) on the moving part (a tree: marker m on tracked link ``links[m]``), exposures ``t_exp``
    every 1/rate on the commands clock."""

    def __init__(self, stand: _Stand, S: np.ndarray, T: np.ndarray, rate_hz: float, links: list[int] | None = None):
        self.stand, self.S, self.T, self.rate, self.links = stand, S, T, rate_hz, links
        self.t_exp = np.arange(0.0, stand.plan.end_s, 1.0 / rate_hz)

    def offsets(self, t: np.ndarray) -> np.ndarray:
        off = np.zeros((len(t), len(self.S), 3))
        for _, p in self.stand.physics:
            o = p.marker_offsets(t, self.stand.plan)
            if o is not None:
                off = off + np.asarray(o, float)
        return off

    def to_mocap(self, q: np.ndarray, X: np.ndarray, t: np.ndarray, frames) -> np.ndarray:
        """(K, M, 3) the markers in the mocap frame: on the moving frame (q, X), or on a tree each
        on its tracked link of ``frames`` (:meth:`_Stand.frames`)."""
        body = self.S[None] + self.offsets(t)
        if frames is not None and self.links is not None:
            k = np.asarray(self.links)
            base = frames[1][:, k] + np.einsum("kmij,kmj->kmi", frames[0][:, k], body)
        else:
            base = X[:, None, :] + np.einsum("kij,kmj->kmi", matrix_from_quat(q), body)
        return base @ self.T[:3, :3].T + self.T[:3, 3]

    def stream(self, nuisances: Nuisances, rng_noise, rng_occ) -> tuple[np.ndarray, np.ndarray]:
        """(marker_t (K,), markers (K, M, 3)): exposures stamped later by the latency and offset,
        with white and coloured noise, bursts of occlusion (NaN) and 1 um steps."""
        t_exp = self.t_exp
        u, seg = self.stand.controls(t_exp)
        q, X = self.stand.pose(u, seg, t_exp)
        self.exposed = (q, X, self.stand.frames(u) if self.links is not None else None)  # the bodies' true links
        Y = self.to_mocap(q, X, t_exp, self.exposed[2])
        Y = Y + rng_noise.normal(size=Y.shape) * nuisances.noise_m
        Y = Y + coloured_noise(rng_noise, Y.shape, 1.0 / self.rate, nuisances.coloured_m, nuisances.correlation_s)
        Y[occlusion_mask(rng_occ, len(t_exp), len(self.S), nuisances.occlusion, self.burst(nuisances))] = np.nan
        Y = np.round(Y * 1e6) / 1e6  # 1 um steps, as the files keep them
        return np.round(t_exp + nuisances.time_shift_s, 6), Y

    def burst(self, nuisances: Nuisances) -> int:
        return max(1, int(round(nuisances.burst_s * self.rate)))

    def rest(self, last: np.ndarray):
        """(q (N, 4), X (N, 3), markers (N, M, 3), controls (N, n_u)) of the rest series at the
        exposures ``last`` (N,) (the last before each hold ends: on the stream's even grid, which
        slow states such as heat are integrated on)."""
        u_rest, seg_rest = self.stand.controls(self.t_exp, rest=True)
        t_rest = self.t_exp[last]
        q_s, X_s = self.stand.pose(u_rest[last], seg_rest[last], t_rest)
        self.rested = (q_s, X_s, self.stand.frames(u_rest[last]) if self.links is not None else None)
        return q_s, X_s, self.to_mocap(q_s, X_s, t_rest, self.rested[2]), u_rest[last]

    def bodies(self, layout: BodyLayout, nuisances: Nuisances, rng) -> tuple[np.ndarray, np.ndarray]:
        """(stream (K, B, 7), settled (N, B, 7)) of the rigid bodies after :meth:`stream` and
        :meth:`rest`: at every exposure on their true links with the markers' white and correlated
        noise (over :data:`BODY_LEVER_M` on the orientation), occluded in bursts (NaN) and in the
        files' steps; at rest without noise."""
        T, B = self.T, len(layout.names)
        R, origin = links_in_mocap(T, *self.exposed[:2], B, layout.links, self.exposed[2])
        shape, dt = origin.shape, 1.0 / self.rate
        error = [rng.normal(size=shape) * nuisances.noise_m
                 + coloured_noise(rng, shape, dt, nuisances.coloured_m, nuisances.correlation_s) for _ in range(2)]
        stream = body_samples(R, origin, layout, error[0], error[1] / BODY_LEVER_M)
        stream[occlusion_mask(rng, shape[0], B, nuisances.occlusion, self.burst(nuisances))] = np.nan
        settled = body_samples(*links_in_mocap(T, *self.rested[:2], B, layout.links, self.rested[2]), layout)
        return round_bodies(stream), settled


def _base_markers(n: int, size_m: float, rec: _Recorder, nuisances: Nuisances, rng_base):
    """(B (n, 3) the base markers in the base frame, YB (K, n, 3) their stream), or (None, None)."""
    if not n:
        return None, None
    T, K = rec.T, len(rec.t_exp)
    rho = 1.5 * size_m
    ang = 2 * np.pi * np.arange(n) / n + rng_base.uniform(-0.3, 0.3, n)
    B = np.stack([rho * np.cos(ang), rho * np.sin(ang), rng_base.uniform(0, 0.05, n) * rho], axis=1)
    YB = (B @ T[:3, :3].T + T[:3, 3])[None] + rng_base.normal(size=(K, n, 3)) * nuisances.noise_m
    YB[occlusion_mask(rng_base, K, n, nuisances.occlusion, rec.burst(nuisances))] = np.nan
    return B, np.round(YB * 1e6) / 1e6


def settled_table(sim: PhysicalSession) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of truth_settled.csv: per command row ``row``, ``t`` (sent, commands
    clock), ``t_rest`` (the hold's end), the control columns, every marker's ``_x,_y,_z`` in the
    mocap frame, the pose ``x,y,z`` in the base frame (session length unit) and ``qw,qx,qy,qz``:
    the columns of ``platkit predict`` after the first three."""
    spec = sim.spec
    s = length_scale(sim.length_unit)
    ldig = 4 if sim.length_unit == "mm" else 7
    V = controls_from_si(spec, sim.commands, sim.length_unit)
    cdig = [ldig if c.unit == "m" else 9 for c in spec.controls]
    header = ["row", "t", "t_rest"] + list(spec.control_names) + [f"{m}_{a}" for m in sim.marker_names for a in "xyz"]
    header += body_columns(sim.bodies.names if sim.bodies is not None else [])
    header += ["x", "y", "z", "qw", "qx", "qy", "qz"]
    rows = []
    for i in range(len(sim.commands)):
        r = [str(i), f"{sim.command_t[i]:.6f}", f"{sim.hold_end_t[i]:.6f}"]
        r += [fmt(v, d) for v, d in zip(V[i], cdig)]
        r += [fmt(v / s, ldig) for v in sim.settled_markers[i].reshape(-1)]
        r += [] if sim.settled_bodies is None else body_row(sim.settled_bodies[i], s, ldig)
        r += [fmt(v / s, ldig) for v in sim.settled_X[i]] + [f"{v:.10f}" for v in sim.settled_q[i]]
        rows.append(r)
    return header, rows


def write_physical_session(sim: PhysicalSession, out: str | Path, description: str | Path | None = None,
                           notes: str = "", moving_link: str | None = None, base_link: str | None = None) -> Path:
    """Write the session folder (session.yaml, commands.csv, markers.csv, imu.csv with its truth
    files when simulated) and its truth (truth.yaml, truth_settled.csv), whole or not at all.
    A session with a warm-up says when the stand was switched on (session.yaml's ``power_on_t``)."""
    spec = sim.spec
    unit = sim.length_unit
    s = length_scale(unit)
    ldig = 3 if unit == "mm" else 6
    out = Path(out)
    with atomic_output_dir(out) as tmp:
        entry: dict = {
            "platform": spec.name, "description": None, "units": {"length": unit, "time": "s"},
            "markers": list(sim.marker_names), "base_markers": list(sim.base_marker_names),
            "mocap_rate_hz": float(sim.mocap_rate_hz), "imu": None,
            "moving_link": sim.moving_link if sim.moving_link else moving_link,
            "notes": notes or f"simulated in the time domain by platkit (seed {sim.seed}); the truth is in "
                              "truth.yaml and truth_settled.csv",
        }
        dropped = dropped_note(sim.plan_info, len(sim.commands))
        if dropped is not None:  # said where the user reads, whatever notes were given
            entry["notes"] = f"{entry['notes']}; {dropped}"
        if sim.bodies is not None:  # their noise is not declared: drawn per session, as the markers'
            entry.update(body_entry(sim.bodies.names, {}))
        if base_link is not None:
            entry["base_link"] = base_link
        power_on = [p.power_on_s for _, p in sim.physics if isinstance(p, WarmupPhysics)]
        if power_on:  # the stand warms up with time since then (commands clock, the clock of t)
            entry["power_on_t"] = round(float(power_on[0]), 6)
        if description is not None:
            desc = Path(description)
            (tmp / desc.name).write_bytes(desc.read_bytes())
            entry["description"] = desc.name
        V = controls_from_si(spec, sim.commands, unit)
        cdig = [ldig if c.unit == "m" else 9 for c in spec.controls]
        rows = [[f"{t:.6f}"] + [fmt(v, d) for v, d in zip(row, cdig)] for t, row in zip(sim.command_t, V)]
        (tmp / "commands.csv").write_text(csv_text(["t"] + list(spec.control_names), rows), encoding="utf-8")
        Y = sim.markers if sim.base_markers is None else np.concatenate([sim.markers, sim.base_markers], axis=1)
        Y = Y.reshape(len(sim.marker_t), -1) / s
        cols = [f"{m}_{a}" for m in list(sim.marker_names) + list(sim.base_marker_names) for a in "xyz"]
        # one format per row: the stream is long (an occluded sample is written 'nan', as the format allows)
        line = "%.6f" + f",%.{ldig}f" * Y.shape[1]
        lines = [line % tuple(r) for r in np.column_stack([sim.marker_t, Y]).tolist()]
        if sim.bodies is not None and sim.body_stream is not None:  # the additive writer's cells
            cols += body_columns(sim.bodies.names)
            lines = [",".join([r] + body_row(b, s, ldig)) for r, b in zip(lines, sim.body_stream)]
        (tmp / "markers.csv").write_text(",".join(["t"] + cols) + "\n" + "\n".join(lines) + "\n", encoding="utf-8")
        if sim.imu is not None:
            entry["imu"] = write_imu_files(sim.imu, tmp)
        (tmp / "session.yaml").write_text(yaml.safe_dump(entry, sort_keys=False), encoding="utf-8")
        truth = sim.truth()
        truth["plan"] = plain(sim.plan_info)
        (tmp / "truth.yaml").write_text(
            "# The true stand behind this session, simulated in the time domain (SI units).\n"
            + yaml.safe_dump(truth, sort_keys=False), encoding="utf-8")
        header, rows = settled_table(sim)
        (tmp / "truth_settled.csv").write_text(csv_text(header, rows), encoding="utf-8")
    return out
