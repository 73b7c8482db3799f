"""The effect library's contract: what a diagnosis effect is, and the per-pose history it reads.

An effect (registered through the ``platkit_register_effects`` hook, see
plugins/platkit_effects for the built-in ones) knows three things:

- ``candidates(spec, poses, residuals)``: the places it could act on this stand (one
  :class:`~platkit.terms.ModelTerm` per actuator, marker, period, ...), each with
  its own ``where``;
- ``regressor(term, spec, poses)``: one number per pose that a person can plot the residual
  against (the direction of the last move, the gravity torque, the time since the start);
- ``from_dict(data, spec)``: the term back from what ``ModelTerm.to_dict`` stored in a
  calibration.yaml, so that ``predict`` reproduces the accepted model.

History-dependent effects read the row order and time of the *whole* session; a fold of a
cross-validation sees only some rows, so :func:`with_history` computes the history once on the
full session and stores it in ``poses.extras`` (subsets keep it row by row).
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from platkit.errors import BadInput
from platkit.model import PlatformSpec, controls_moving_links
from platkit.play import play_memory
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: relative size (of a control's stroke) below which a change of command is "no move"
MOVE_TOLERANCE = 1e-6
#: the unit of a simulated size on one actuator (:func:`control_size`), for :class:`SizeHelp`
CONTROL_SIZE_UNIT = "mm for length controls, else the control's unit"


@dataclass(frozen=True)
class SizeHelp:
    """What the size of ``--effect NAME=SIZE`` means in one simulator: ``meaning`` (a phrase,
    e.g. 'the full play') and the ``unit`` it is given in (e.g. 'mm for length controls'; '' for
    a pure number, a fraction or a share)."""

    meaning: str
    unit: str

    def text(self) -> str:
        return f"{self.meaning}, in {self.unit}" if self.unit else self.meaning


class Effect:
    """Base class of a diagnosis effect (one physical mechanism, e.g. a play in a drive).

    What the core knows of an effect, it reads from these class attributes and methods (an
    outside effect declares them like a built-in one; :func:`platkit.testing.check_effect`
    checks them):

    - ``name`` (the name findings and calibration.yaml carry), ``summary`` (one line for people);
    - ``recording``: True for an artefact of the recording rather than of the stand (a pose taken
      before the stand settled, a marker that moved on the platform). Its term is fitted like any
      other, so that the geometry is estimated from corrected data, and left out of the stand's
      calibration (:meth:`moved_marker` says where a marker it moved stays; :meth:`correction`
      says how it was corrected; :meth:`onset` when it began);
    - ``direction``: True for an effect whose signature is the direction of each actuator's last
      move (a play in a drive). Where the settling search extrapolated an actuator's approach to
      rest, the extrapolation's remnant lies along that actuator's last move too, so such an effect
      is not named on that actuator;
    - ``unsettled_holds``: True for the effect that holds which never settled are (a lag of the
      stand behind its commands). The settling search reads it from the raw stream and corrects it
      there: diagnosis reports the stream's finding under this effect's name, and does not fit the
      effect's term where the stream gave one;
    - ``not_separable_advice``: a sentence the verdict adds when a term of this effect cannot be
      told from the geometry on the session's plan ('' for none);
    - ``forecast``: True for an effect whose terms extrapolate in time beyond what was recorded (a
      drift, a warm-up). Its variants fall into forms (a term's ``where['form']``): within a form
      the variants compete by BIC, the forms by how each predicts the later part of the session
      held out (fitted on the earlier part); and it is accepted only where it predicts that later
      part no worse than the model without it;
    - ``warm_up``: True for the effect a stand's warm-up with time since power-on is (the
      time-domain simulator's ``warmup`` option lists its warm-up in the truth under this effect's
      name; at most one installed effect says so);
    - ``simulation_size``, ``physics_size``: what the size of ``platkit simulate --effect
      NAME=SIZE`` means in the additive and in the time-domain simulator (:class:`SizeHelp`, its
      meaning and unit; None where the effect has no such simulation).
    """

    name: str = ""
    summary: str = ""
    recording: bool = False
    direction: bool = False
    unsettled_holds: bool = False
    not_separable_advice: str = ""
    forecast: bool = False
    warm_up: bool = False
    simulation_size: SizeHelp | None = None
    physics_size: SizeHelp | None = None

    def size_help(self, physics: bool = False) -> SizeHelp | None:
        """What a simulated size of this effect means (``physics``: in the time-domain simulator)."""
        return self.physics_size if physics else self.simulation_size

    def onset(self, term: ModelTerm) -> float | None:
        """For a recording artefact: the time (s since the session's first command) from which
        ``term`` acts (a slip's moment), or None when it acts throughout. Diagnosis writes a term
        with an onset into calibration.yaml only when the model with it predicts the held-out poses
        from that time on better (by ``min_relative_gain``, significantly) than the model without
        it; otherwise the fitted model keeps it and calibration.yaml is the fit without it."""
        return None

    def moved_marker(self, term: ModelTerm, theta: np.ndarray,
                     std: np.ndarray | None) -> tuple[int, np.ndarray, np.ndarray] | None:
        """For a recording artefact that moved a marker on the platform: (the marker's index, the
        (3,) m offset from the marker's fitted place to where the stand's calibration puts it,
        that offset's (3,) standard deviation, NaN where unknown); None when it moves no marker."""
        return None

    def moved_markers(self, term: ModelTerm, theta: np.ndarray,
                      std: np.ndarray | None) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Every marker a recording artefact moved, each as :meth:`moved_marker` gives one (a rigid
        body's three points move together); default: :meth:`moved_marker`'s, if any."""
        moved = self.moved_marker(term, theta, std)
        return [] if moved is None else [moved]

    def correction(self, where: dict[str, Any], unwritten: str | None = None) -> str:
        """For a recording artefact: how its accepted term at ``where`` is corrected, a sentence
        for the finding's ``corrected``. ``unwritten``: for a term with an :meth:`onset` whose
        model change is not written, the held-out comparison that decided it (a phrase: the RMS
        with against without, its paired p, the gain it missed)."""
        text = f"in the data: {self.name} is fitted so that the geometry sees the stand; calibration.yaml leaves it out"
        if unwritten is not None:
            text += f" (the model with it predicts the held-out poses from its onset on at {unwritten})"
        return text

    def untried(self, spec: PlatformSpec, poses: PoseSet) -> list[str]:
        """Why the effect cannot be tried (somewhere) on this stand and session: one phrase each,
        read after 'where' (the verdict and diagnosis.json say them; nothing is skipped silently).
        Default: none."""
        return []

    def candidates(self, spec: PlatformSpec, poses: PoseSet, residuals: np.ndarray | None = None) -> list[ModelTerm]:
        """Terms this effect could add on this stand and session. ``residuals``: (N, M, 3) m,
        the current fit's marker residuals in the moving frame (effects that must locate
        something, like a marker's slip time, use them)."""
        raise NotImplementedError

    def regressor(self, term: ModelTerm, spec: PlatformSpec, poses: PoseSet) -> np.ndarray:
        """(N,) the quantity the residual should follow if ``term`` is the cause."""
        raise NotImplementedError

    def regressor_label(self, term: ModelTerm) -> str:
        """Axis label for :meth:`regressor`, with its unit."""
        return self.name

    def from_dict(self, data: dict[str, Any], spec: PlatformSpec | None = None) -> ModelTerm:
        """The term back from a ``ModelTerm.to_dict`` mapping (its ``where`` says where it acts;
        ``spec``, when given, is checked against it). Theta is read by the caller."""
        raise NotImplementedError

    def simulation_term(self, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                        commands: PoseSet) -> tuple[ModelTerm, np.ndarray] | None:
        """(term, true theta) for the additive simulator: the effect as the model term diagnosis fits,
        of ``size`` (None: the effect's default) on the command rows ``commands``; None when the
        effect cannot be simulated that way."""
        return None

    def physics(self, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                plan: PhysicsPlan) -> EffectPhysics | None:
        """The effect's physics in a session for the time-domain simulator (see the physics
        section below), of ``size`` (None: the default); None when the effect has none."""
        return None


# ---------------------------------------------------------------------------- helpers for effect authors
def stored_where(data: Any) -> dict[str, Any]:
    """The ``where`` mapping of a stored term (``ModelTerm.to_dict``), {} when there is none."""
    where = data.get("where") if isinstance(data, dict) else None
    return where if isinstance(where, dict) else {}


def actuator_where(spec: PlatformSpec, i: int) -> dict[str, Any]:
    """The ``where`` of a term on control ``i``: its name, index and unit (what
    :func:`stored_actuator` reads back without the spec)."""
    return {"actuator": spec.control_names[i], "actuator_index": i, "unit": spec.controls[i].unit}


def stored_actuator(spec: PlatformSpec | None, data: dict[str, Any], effect: str) -> tuple[int, str, str]:
    """(index, name, unit) of the actuator a stored term acts on: by name in ``spec`` when given
    (BadInput names an actuator the stand lacks), else from the stored index and unit."""
    where = stored_where(data)
    name, index, unit = where.get("actuator"), where.get("actuator_index"), where.get("unit")
    if spec is not None:
        if name not in spec.control_names:
            raise BadInput(f"effect {effect!r}: actuator {name!r} is not a control of {spec.name} "
                           f"({', '.join(spec.control_names)})")
        i = spec.control_names.index(name)
        return i, str(name), spec.controls[i].unit
    if not isinstance(index, int) or index < 0 or not isinstance(unit, str):
        raise BadInput(f"effect {effect!r}: where needs actuator_index (an integer >= 0) and unit")
    return index, str(name), unit


def stored_number(where: dict[str, Any], key: str, effect: str, positive: bool = False) -> float:
    """A number of a stored term's ``where``; BadInput names the effect and field otherwise."""
    v = where.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (positive and not v > 0):
        raise BadInput(f"effect {effect!r}: where.{key} must be a{' positive' if positive else ''} number")
    return float(v)


def seen_controls(spec: PlatformSpec) -> np.ndarray:
    """(n_u,) bool: the controls that move a tracked link (structurally: the joints on a tracked
    link's path and the masters of mimic joints there; :func:`platkit.model.controls_moving_links`).
    Every control on a stand of one moving frame; on a tree, not the joints no marker moves (a head,
    fingers, a leg that is not tracked)."""
    seen = np.zeros(spec.n_u, bool)
    for m in controls_moving_links(spec).values():
        seen |= m
    return seen


def planted(spec: PlatformSpec, rng: np.random.Generator, drawn: int, options: list[int], effect: str) -> int:
    """The option (an index into ``options``, each a control) a simulated hidden effect is planted
    at: ``drawn`` as drawn, or, where its control moves no tracked link (:func:`seen_controls`),
    one drawn again among the options whose control moves one, so that a simulated session's
    hidden effect is one its markers can show; BadInput (naming the effect) where none does."""
    seen = seen_controls(spec)
    if seen[options[drawn]]:
        return drawn
    ok = [k for k, i in enumerate(options) if seen[i]]
    if not ok:
        raise BadInput(f"effect {effect}: none of the controls it may act on moves a tracked link of {spec.name} "
                       f"({', '.join(spec.control_names[i] for i in sorted(set(options)))})")
    return ok[int(rng.integers(len(ok)))]


def control_size(spec: PlatformSpec, i: int, size: float | None, default: float) -> float:
    """A simulated size on control ``i`` in SI: a given ``size`` in mm for a length control (-> m),
    else in the control's own unit (:data:`CONTROL_SIZE_UNIT`).

    ``size`` None: ``default``, whose number counts mm on a length control and mrad on a control
    counted in radians (a URDF's revolute joint): at a lever of about a metre the same motion of
    the tool, and the size of a real joint's effect (a geared joint's play or its deflection under
    gravity, 1 mrad by the effects' default of 1; a harmonic drive's cyclic error, 0.3 mrad).
    Other units (a stand's own, e.g. degrees) take ``default`` in that unit."""
    if size is None:
        unit = spec.controls[i].unit
        return default * 1e-3 if unit in ("m", "rad") else default
    size = float(size)
    return size * 1e-3 if spec.controls[i].unit == "m" else size


def theta_from_dict(data: dict[str, Any], names: list[str], where: str = "term") -> np.ndarray:
    """The parameter values stored by ``ModelTerm.to_dict`` in the order ``names``."""
    params = data.get("parameters") or {}
    try:
        return np.array([float(params[n]["value"]) for n in names])
    except (KeyError, TypeError, ValueError):
        raise BadInput(f"{where}: effect {data.get('effect')!r} needs parameters {', '.join(names)} with a 'value'") from None


# ---------------------------------------------------------------------------- history
def elapsed_time(poses: PoseSet) -> np.ndarray:
    """(N,) seconds since the session's first command (the row index when times are unknown)."""
    if "elapsed" in poses.extras:
        return np.asarray(poses.extras["elapsed"], float)
    t = np.asarray(poses.t, float)
    if t.size and np.all(np.isfinite(t)):
        return t - t[0]
    return np.arange(poses.n_poses, dtype=float)


def move_direction(controls: np.ndarray, spec: PlatformSpec | None = None) -> np.ndarray:
    """(N, n_u) sign of each actuator's last move before each row (0 before its first move).

    ``controls``: (N, n_u) in command order. A change smaller than MOVE_TOLERANCE of the
    stroke is no move: the actuator keeps the direction it had.
    """
    controls = np.atleast_2d(np.asarray(controls, float))
    if spec is not None:
        lo, hi = spec.control_bounds()
        span = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
    else:
        span = np.ptp(controls, axis=0) + 1e-300
    out = np.zeros_like(controls)
    last = np.zeros(controls.shape[1])
    for k in range(1, len(controls)):
        step = controls[k] - controls[k - 1]
        moved = np.abs(step) > MOVE_TOLERANCE * span
        last = np.where(moved, np.sign(step), last)
        out[k] = last
    return out


def last_step(controls: np.ndarray) -> np.ndarray:
    """(N, n_u) the change of command that led to each row (0 for the first row)."""
    controls = np.atleast_2d(np.asarray(controls, float))
    out = np.zeros_like(controls)
    out[1:] = controls[1:] - controls[:-1]
    return out


def command_order(poses: PoseSet) -> tuple[np.ndarray, np.ndarray]:
    """(x (T, n_u), at (N,)): the session's commands in order as far as ``poses`` (in command order)
    tell them, and each row's place in x. Where the reader gave each row's command row ('row') and
    step ('last_step', from the full log), a row after a gap (commands that gave no pose) gets the
    command before it (its own minus its step) put in before it; commands further back are unknown."""
    U = np.atleast_2d(np.asarray(poses.controls, float))
    rows, steps = poses.extras.get("row"), poses.extras.get("last_step")
    if rows is None or steps is None or np.shape(steps) != U.shape or len(rows) != len(U):
        return U, np.arange(len(U))
    steps = np.asarray(steps, float)
    put = (np.diff(np.concatenate([[-1.0], np.asarray(rows, float)])) > 1) & np.all(np.isfinite(steps), axis=1)
    at = np.arange(len(U)) + np.cumsum(put)
    x = np.empty((len(U) + int(put.sum()), U.shape[1]))
    x[at], x[at[put] - 1] = U, U[put] - steps[put]
    return x, at


def with_history(poses: PoseSet, spec: PlatformSpec | None = None) -> PoseSet:
    """``poses`` with ``extras`` 'direction', 'last_step', 'elapsed', 'row' and 'play' filled in
    from the full session's row order (kept if the session reader already supplied them). 'play'
    (platkit.play.play_memory over :func:`command_order`): a stream's windowed poses carry their
    own (the drives' modelled positions, platkit.diagnose.stream.stream_play); windowed poses
    without it (extras 'node', or a 'direction' read from a command log the rows do not give) get
    a NaN memory: the direction alone."""
    extras = dict(poses.extras)
    if "play" not in extras or np.shape(extras["play"])[:2] != poses.controls.shape:
        if "node" in extras or ("direction" in extras and "row" not in extras):
            extras["play"] = np.full(poses.controls.shape + (1, 3), np.nan)
        else:
            extras["play"] = play_memory(*command_order(poses))
    if "direction" not in extras or np.shape(extras["direction"]) != poses.controls.shape:
        extras["direction"] = move_direction(poses.controls, spec)
    extras.setdefault("last_step", last_step(poses.controls))
    extras.setdefault("elapsed", elapsed_time(poses))
    extras.setdefault("row", np.arange(poses.n_poses, dtype=float))
    out = poses.subset(np.arange(poses.n_poses))
    out.extras = extras
    out.dropped = list(poses.dropped)
    return out


def history(poses: PoseSet, key: str, spec: PlatformSpec | None = None) -> np.ndarray:
    """One history array of ``poses`` (from extras, else computed from its own row order)."""
    if key in poses.extras:
        return np.asarray(poses.extras[key], float)
    if key == "direction":
        return move_direction(poses.controls, spec)
    if key == "last_step":
        return last_step(poses.controls)
    if key == "elapsed":
        return elapsed_time(poses)
    if key == "row":
        return np.arange(poses.n_poses, dtype=float)
    if key == "play":
        return play_memory(*command_order(poses))
    raise KeyError(key)


# ---------------------------------------------------------------------------- physics
# An effect may also carry its physics: what the time-domain simulator (platkit.simulate.physics)
# plays out, where the additive model term is what diagnosis fits. ``Effect.physics(spec, size,
# rng, plan)`` returns an :class:`EffectPhysics`; the simulator calls its stages in this order:
# ``respond`` (the actuators' response), ``drive`` (from the position a drive reaches to the
# travel or angle the kinematics sees), the kinematics with the true geometry, ``base_tilt``
# (the base against the level world), ``marker_offsets`` (markers moving on the platform).


@dataclass
class PhysicsPlan:
    """The session an effect's physics plays out in (internal units, seconds on the commands
    clock): ``spec``; ``command_t`` (N,) when each command is sent; ``commands`` (N, n_u);
    ``start`` (n_u,) where the stand rests before the first command; ``hold_s`` the typical
    hold after arrival; ``end_s`` the end of the recording; ``marker_names`` (M,)."""

    spec: PlatformSpec
    command_t: np.ndarray
    commands: np.ndarray
    start: np.ndarray
    hold_s: float
    end_s: float
    marker_names: list[str]


@dataclass
class PhysicsSeries:
    """Actuator positions over time as a drive stage sees them: ``t`` (K,) s, sorted;
    ``motor`` (K, n_u) the position reaching this stage (internal units); ``segment`` (K,) the
    command in force (-1 before the first); ``rest`` True for the series in which every command
    is reached at once, from which the simulator takes where the stand comes to rest."""

    t: np.ndarray
    motor: np.ndarray
    segment: np.ndarray
    rest: bool = False


class EffectPhysics:
    """The physics of one effect in a session, with its true parameters. Every stage defaults
    to doing nothing; an effect overrides those where it acts. Stages are pure functions of
    their arguments: the simulator calls ``drive`` on the stream and on the rest series."""

    effect: str = ""

    def parameters(self) -> dict[str, Any]:
        """The true parameters and where they act, for truth.yaml (plain values, SI)."""
        return {}

    def respond(self, response: Any) -> None:
        """Change the actuators' response in place: ``response`` has arrays (n_u,) ``tau_s``,
        ``damping``, ``rate``, ``accel`` (platkit.simulate.actuator.ActuatorResponse)."""

    def drive(self, series: PhysicsSeries, plan: PhysicsPlan) -> np.ndarray:
        """(K, n_u) the positions after this stage of the drive (internal units)."""
        return series.motor

    def base_tilt(self) -> np.ndarray | None:
        """(2,) rad: the base turned about its x and y axes against the level world, or None."""
        return None

    def marker_offsets(self, t: np.ndarray, plan: PhysicsPlan) -> np.ndarray | None:
        """(K, M, 3) m: the markers moved on the moving part at times ``t`` (K,), or None."""
        return None


# ---------------------------------------------------------------------------- IMU effects
class ImuEffect(Effect):
    """An effect an IMU riding the moving part sees, registered through ``platkit_register_effects``
    like a motion-capture effect. One implementation serves the IMU simulator
    (:mod:`platkit.inertial.simulate`) and the IMU diagnosis (:mod:`platkit.diagnose.imu`).

    The sensor model both use (S sensor axes, P platform, B the model's base, L the level frame,
    SI throughout; ``theta_e`` each effect's parameters):

        gyr(t) = R_SP w_P(t) + b_g + sum_e gyro_bias_e(theta_e, t - t_ref)
        acc(t) = k * (R_SP R_BP(t)^T (a_B(t) - R_LB^T (0, 0, -g))) + b_a + sum_e accelerometer_bias_e(theta_e, t - t_ref)

    R_SP = the product of every effect's :meth:`sensor_from_platform`, R_LB = the product of every
    effect's :meth:`level_from_base` (identity unless an effect overrides them); the constant
    biases b_g, b_a and the axes' gravity scales k are the sensor's own: the base model, never a
    finding. ``t_ref`` is the caller's reference time (the simulator: the first sample; the
    diagnosis: the middle of the session, where a constant bias is taken); an effect whose form
    changes with it must say so.

    Class attributes:

    - ``sensor``: ``'gyro'`` (tested on the rotations between holds) or ``'accelerometer'``
      (tested on the specific force at the holds);
    - ``parameter_names`` (SI values in the order of ``theta``), ``display_unit`` and
      ``display_scale`` (SI times this is what people read, e.g. rad -> deg);
    - ``min_size``: an estimate smaller than this (display unit, :meth:`size`) is not named;
    - ``nuisance``: fitted in every other gyro effect's test whether named or not (a sensor's
      mounting is always there; a drift fitted without it takes what it leaves);
    - ``min_separability``: tested only where at least this share of the effect's signature is
      beyond what the base model (and the effects already in it) can mimic;
    - ``simulation_keyword``: the keyword of :func:`platkit.inertial.simulate.imu_from_motion`
      whose value is this effect's theta ('' for none: the effect comes through its ``effects``);
    - ``reported_as``: the name its findings carry (the spec's name where the motion capture
      knows the same physical effect, e.g. ``base_tilt``); default ``name``.

    IMU effects add no motion-capture term: :meth:`candidates` is empty.
    """

    sensor: str = "gyro"
    parameter_names: tuple[str, ...] = ()
    display_unit: str = ""
    display_scale: float = 1.0
    min_size: float = 0.0
    nuisance: bool = False
    min_separability: float = 0.0
    simulation_keyword: str = ""
    reported_as: str = ""

    @property
    def finding_name(self) -> str:
        return self.reported_as or self.name

    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    def candidates(self, spec: PlatformSpec, poses: PoseSet, residuals: np.ndarray | None = None) -> list[ModelTerm]:
        return []

    def size_help(self, physics: bool = False) -> SizeHelp | None:
        """An IMU effect's size is in its display unit, with ``--imu``: it acts on the simulated
        IMU's samples through its sensor model (:mod:`platkit.inertial.simulate`), in either simulator."""
        return SizeHelp("with --imu (acts on the simulated IMU's samples through the sensor model, "
                        + ("not in the stand's physics)" if physics else "not as a model term)"), self.display_unit)

    def simulation_term(self, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                        commands: PoseSet) -> tuple[ModelTerm, np.ndarray] | None:
        """None: an IMU effect adds no model term (see :meth:`size_help`)."""
        return None

    def physics(self, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                plan: PhysicsPlan) -> EffectPhysics | None:
        """None: an IMU effect has no physics of the stand (see :meth:`size_help`)."""
        return None

    # --- the sensor model (one implementation for simulation and diagnosis)
    def gyro_bias(self, theta: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 3) rad/s added to the gyro at times ``t`` (N,) s from the reference time."""
        return np.zeros((len(np.atleast_1d(t)), 3))

    def accelerometer_bias(self, theta: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 3) m/s^2 added to the accelerometer at times ``t`` (N,) s from the reference time."""
        return np.zeros((len(np.atleast_1d(t)), 3))

    def sensor_from_platform(self, theta: np.ndarray) -> np.ndarray:
        """(3, 3) the rotation this effect turns the sensor's axes by against the platform's."""
        return np.eye(3)

    def level_from_base(self, theta: np.ndarray) -> np.ndarray:
        """(3, 3) the rotation from the model's base frame to the level frame (gravity along -z)."""
        return np.eye(3)

    # --- how diagnosis judges and reports it
    def size(self, theta: np.ndarray) -> float:
        """The estimate's size in the display unit (default: the norm of theta)."""
        return float(np.linalg.norm(theta)) * self.display_scale

    def frame_covariance(self, theta: np.ndarray, frame_base: np.ndarray | None,
                         frame_platform: np.ndarray | None) -> np.ndarray:
        """(n, n) SI: how much of theta the model's own frames allow (their error against the real
        stand's, ``frame_base`` / ``frame_platform`` (3, 3) rad^2 about base / platform axes, or
        None); zero for an effect the frames cannot mimic."""
        return np.zeros((self.n_params, self.n_params))

    def report(self, theta: np.ndarray, cov: np.ndarray, context: dict[str, Any]) -> dict[str, Any]:
        """``parameters`` (name -> value, std, unit in display units), ``where`` and ``evidence``
        (one sentence) of a finding. ``cov`` (n, n) SI from every source; ``context``: ``sensor``,
        ``n`` (segments or holds), ``span_s`` (first, last) s, ``t_ref`` s, ``b0`` (3) and
        ``b0_std`` (3) the constant gyro bias (rad/s), ``heldout_before``/``heldout_after``
        (deg/s or m/s^2), ``heldout_unit``, ``p_heldout``, ``p_screen``, ``separability``."""
        sd = np.sqrt(np.clip(np.diag(cov), 0, None)) * self.display_scale
        params = {n: {"value": float(v * self.display_scale), "std": float(s), "unit": self.display_unit}
                  for n, v, s in zip(self.parameter_names, theta, sd)}
        c = context
        evidence = (f"{self.summary}: {self.size(theta):.3g} {self.display_unit}; modelling it predicts the held-out "
                    f"{'segments' if self.sensor == 'gyro' else 'holds'} with RMS {c['heldout_before']:.3g} -> "
                    f"{c['heldout_after']:.3g} {c['heldout_unit']} over {c['n']} of them (paired Wilcoxon p = "
                    f"{c['p_heldout']:.2g}; F test Holm p = {c['p_screen']:.2g}).")
        return {"parameters": params, "where": {"sensor": self.sensor}, "evidence": evidence}

    def headline(self, parameters: dict[str, Any]) -> str:
        """A few words for the verdict about an accepted finding's ``parameters``."""
        return ", ".join(f"{n} {p['value']:.3g} +- {p['std']:.2g} {p['unit']}" for n, p in parameters.items())

    def calibration_entry(self, theta: np.ndarray, cov: np.ndarray, context: dict[str, Any]) -> dict[str, Any]:
        """What an accepted finding adds to calibration.yaml's ``imu`` mapping (key -> mapping, SI)."""
        return {self.finding_name: {"parameters": dict(zip(self.parameter_names, np.asarray(theta, float).tolist())),
                                    "std": np.sqrt(np.clip(np.diag(cov), 0, None)).tolist(), "effect": self.name}}

    def simulation_theta(self, size: float, rng: np.random.Generator) -> np.ndarray:
        """SI parameters of a simulated effect of ``size`` (display unit) in a random direction."""
        v = rng.normal(size=self.n_params)
        return v / np.linalg.norm(v) * size / self.display_scale


def imu_effects(library: Mapping[str, Effect]) -> dict[str, ImuEffect]:
    """Name -> IMU effect, from ``library`` (effect name -> effect)."""
    return {n: e for n, e in library.items() if isinstance(e, ImuEffect)}


def imu_sensor_model(effects: list[tuple[ImuEffect, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(R_SP (3, 3), R_LB (3, 3)): the rotations a list of (effect, theta) make together (products
    in the list's order, each applied after the ones before it)."""
    R_sp, R_lb = np.eye(3), np.eye(3)
    for e, theta in effects:
        if type(e).sensor_from_platform is not ImuEffect.sensor_from_platform:
            R_sp = e.sensor_from_platform(np.asarray(theta, float)) @ R_sp
        if type(e).level_from_base is not ImuEffect.level_from_base:
            R_lb = e.level_from_base(np.asarray(theta, float)) @ R_lb
    return R_sp, R_lb
