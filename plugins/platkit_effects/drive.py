"""Effects of the drives, one term per actuator: backlash (play at reversal), cyclic_error (a
periodic error of the travel) and scale_nonlinearity (a travel error smooth over the stroke)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import (
    CONTROL_SIZE_UNIT,
    Effect,
    SizeHelp,
    actuator_where,
    control_size,
    history,
    planted,
    stored_actuator,
    stored_number,
    stored_where,
)
from platkit.errors import BadInput
from platkit.play import play_offset
from platkit.poses import PoseSet
from platkit.terms import ModelTerm
from platkit_effects.physics import BacklashPhysics, CyclicPhysics, ScalePhysics


@dataclass
class BacklashTerm(ModelTerm):
    """A play (deadband) of half width h = |half_play| in the drive of actuator ``index``: over
    the session's commands u_k in order, the output y_k = clamp(y_(k-1), u_k - h, u_k + h) (y before
    the first command = the first command) and the offset y_k - u_k (platkit.play.play_offset,
    from the history 'play' over the whole session: held-out rows and predict's own commands
    included). A true play has half_play < 0: after a move longer than the play the offset is
    half_play times the direction of that move (+1 up, -1 down), what this term's constant offset
    meant before it had a play; a reversal shorter than 2h leaves the output where it was. The play
    stands in for MOVE_TOLERANCE here: a move too small to turn the direction moves the output by
    no more than itself. half_play > 0 (the output ahead of its command) mirrors it: the offset is
    odd in half_play, theta times the direction for long moves on either side of 0.

    A stream's windowed poses (platkit.diagnose.stream.stream_play) carry the play's memory at the
    first sample their window weighs, the drive's positions at its samples ('play_path' (N, n_u,
    S)) and the weights ('play_weight' (N, S)): the same play over the positions, weighed as the
    controls are. Poses with a NaN memory (windowed poses read without it:
    platkit.effects.with_history) read the direction alone: half_play times the direction.
    Nonlinear in half_play: the estimator differentiates it."""

    index: int = 0

    def control_offset(self, theta, poses, n_u):
        out = np.zeros((poses.n_poses, n_u))
        memory = history(poses, "play")[:, self.index]
        if np.isnan(memory[:, -1, 0]).any():
            out[:, self.index] = theta[0] * history(poses, "direction")[:, self.index]
            return out
        sign = -1.0 if theta[0] > 0 else 1.0
        weight = poses.extras.get("play_weight")
        inputs = (poses.controls[:, self.index] if weight is None
                  else np.asarray(poses.extras["play_path"], float)[:, self.index])
        out[:, self.index] = sign * play_offset(memory, inputs, abs(float(theta[0])), weight)
        return out


class Backlash(Effect):
    name = "backlash"
    direction = True
    simulation_size = SizeHelp("the full play", CONTROL_SIZE_UNIT)
    physics_size = SizeHelp("the full play, a deadband in the drive", CONTROL_SIZE_UNIT)
    summary = "an actuator's position depends on the direction it last moved"

    def term(self, i, where):
        return BacklashTerm(self.name, ["half_play"], np.zeros(1), [where["unit"]], dict(where), index=i)

    def candidates(self, spec, poses, residuals=None):
        d = history(poses, "direction", spec)
        return [self.term(i, actuator_where(spec, i)) for i in range(spec.n_u)
                if np.sum(d[:, i] > 0) >= 2 and np.sum(d[:, i] < 0) >= 2]

    def regressor(self, term, spec, poses):
        return history(poses, "direction", spec)[:, term.index]

    def regressor_label(self, term):
        return f"direction of the last move of {term.where['actuator']} (+1/-1)"

    def from_dict(self, data, spec=None):
        i, name, unit = stored_actuator(spec, data, self.name)
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit})

    def simulation_term(self, spec, size, rng, commands):
        i = planted(spec, rng, int(rng.integers(spec.n_u)), list(range(spec.n_u)), self.name)
        return self.term(i, actuator_where(spec, i)), np.array([0.5 * control_size(spec, i, size, 1.0)])

    def physics(self, spec, size, rng, plan):
        i = planted(spec, rng, int(rng.integers(spec.n_u)), list(range(spec.n_u)), self.name)
        return BacklashPhysics(i, spec.control_names[i], control_size(spec, i, size, 1.0), spec.controls[i].unit)


#: candidate periods per control unit: one turn and its harmonics; screw leads for 'm'
PERIODS = {
    "rad": (2 * np.pi, np.pi, 2 * np.pi / 3, np.pi / 2),
    "deg": (360.0, 180.0, 120.0, 90.0),
    "m": (0.02, 0.01, 0.005),
    "count": (1024.0, 512.0, 256.0),
}


@dataclass
class CyclicTerm(ModelTerm):
    index: int = 0
    period: float = 1.0

    def control_offset(self, theta, poses, n_u):
        phase = 2 * np.pi * poses.controls[:, self.index] / self.period
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * np.sin(phase) + theta[1] * np.cos(phase)
        return out



def _draw_cyclic(spec, size, rng, controls: np.ndarray) -> tuple[int, float, float, float]:
    """A cyclic error drawn for simulation: an actuator and one of its PERIODS that the commands
    ``controls`` (N, n_u) span over half of, the amplitude ``size`` (mm for lengths) in internal
    units, and a phase (rad)."""
    options = [(i, P) for i, c in enumerate(spec.controls) for P in PERIODS.get(c.unit, ())
               if np.ptp(controls[:, i]) > P / 2]
    if not options:
        raise BadInput(f"effect cyclic_error: no actuator of {spec.name} spans half of a known period")
    i, P = options[planted(spec, rng, int(rng.integers(len(options))), [i for i, _ in options], "cyclic_error")]
    return i, P, control_size(spec, i, size, 0.3), rng.uniform(0, 2 * np.pi)

class CyclicError(Effect):
    name = "cyclic_error"
    not_separable_advice = ("A periodic error is invisible when every command sits at the same phase of its period "
                            "(a grid whose steps are a multiple of it): record a random or dithered plan to test it.")
    simulation_size = SizeHelp("the amplitude, of a period from PERIODS that the commands span", CONTROL_SIZE_UNIT)
    physics_size = SizeHelp("the amplitude of a gear's error periodic in the actuator's true position", CONTROL_SIZE_UNIT)
    summary = "an error periodic in an actuator's angle or travel (gear or encoder eccentricity)"

    def term(self, i, where, period):
        where = dict(where, period=float(period))
        return CyclicTerm(self.name, ["sin_amplitude", "cos_amplitude"], np.zeros(2), [where["unit"]] * 2, where,
                          index=i, period=float(period))

    def candidates(self, spec, poses, residuals=None):
        out = []
        for i, c in enumerate(spec.controls):
            travel = np.ptp(poses.controls[:, i])
            for P in PERIODS.get(c.unit, ()):
                if travel > P / 2:  # less than half a period seen is an offset and a slope
                    out.append(self.term(i, actuator_where(spec, i), P))
        return out

    def regressor(self, term, spec, poses):
        return np.mod(poses.controls[:, term.index], term.period) / term.period

    def regressor_label(self, term):
        return f"phase of {term.where['actuator']} in a period of {term.period:g} {term.where['unit']} (turns)"

    def from_dict(self, data, spec=None):
        i, name, unit = stored_actuator(spec, data, self.name)
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit},
                         stored_number(stored_where(data), "period", self.name, positive=True))

    def simulation_term(self, spec, size, rng, commands):
        i, P, a, ph = _draw_cyclic(spec, size, rng, commands.controls)
        return self.term(i, actuator_where(spec, i), P), np.array([a * np.cos(ph), a * np.sin(ph)])

    def physics(self, spec, size, rng, plan):
        i, P, a, ph = _draw_cyclic(spec, size, rng, plan.commands)
        return CyclicPhysics(i, spec.control_names[i], P, a * np.cos(ph), a * np.sin(ph), spec.controls[i].unit)


@dataclass
class ScaleTerm(ModelTerm):
    index: int = 0
    lower: float = 0.0
    upper: float = 1.0

    def travel(self, controls):
        return (2 * controls[:, self.index] - (self.lower + self.upper)) / (self.upper - self.lower)

    def control_offset(self, theta, poses, n_u):
        s = self.travel(poses.controls)
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * 0.5 * (3 * s**2 - 1) + theta[1] * 0.5 * (5 * s**3 - 3 * s)
        return out


class ScaleNonlinearity(Effect):
    name = "scale_nonlinearity"
    simulation_size = SizeHelp("the largest deviation from linear travel, at the stroke ends", CONTROL_SIZE_UNIT)
    physics_size = simulation_size
    summary = "an actuator's travel not linear in its command"

    def term(self, i, where, lower, upper):
        where = dict(where, travel=[float(lower), float(upper)])
        return ScaleTerm(self.name, ["quadratic", "cubic"], np.zeros(2), [where["unit"]] * 2, where,
                         index=i, lower=float(lower), upper=float(upper))

    def candidates(self, spec, poses, residuals=None):
        out = []
        for i, c in enumerate(spec.controls):
            lo, hi = c.lower, c.upper
            if not (np.isfinite(lo) and np.isfinite(hi) and hi > lo):
                lo, hi = float(np.min(poses.controls[:, i])), float(np.max(poses.controls[:, i]))
            if hi > lo and np.ptp(poses.controls[:, i]) > 0.2 * (hi - lo):
                out.append(self.term(i, actuator_where(spec, i), lo, hi))
        return out

    def regressor(self, term, spec, poses):
        return term.travel(poses.controls)

    def regressor_label(self, term):
        return f"travel of {term.where['actuator']} over its stroke (-1..1)"

    def from_dict(self, data, spec=None):
        i, name, unit = stored_actuator(spec, data, self.name)
        travel = stored_where(data).get("travel")
        if not (isinstance(travel, list) and len(travel) == 2 and all(isinstance(v, (int, float)) for v in travel)
                and travel[1] > travel[0]):
            raise BadInput("effect 'scale_nonlinearity': where.travel must be [lower, upper] with lower < upper")
        return self.term(i, {"actuator": name, "actuator_index": i, "unit": unit}, *travel)

    def simulation_term(self, spec, size, rng, commands):
        terms = self.candidates(spec, commands)
        if not terms:
            raise BadInput(f"effect scale_nonlinearity: the commands use too little of {spec.name}'s strokes")
        t = terms[planted(spec, rng, int(rng.integers(len(terms))), [t.index for t in terms], self.name)]
        return t, np.array([control_size(spec, t.index, size, 1.0), 0.0])

    def physics(self, spec, size, rng, plan):
        terms = [t for t in self.candidates(spec, PoseSet(spec.name, plan.commands, np.zeros((len(plan.commands), 0, 3)), []))]
        if not terms:
            raise BadInput(f"effect scale_nonlinearity: the commands use too little of {spec.name}'s strokes")
        t = terms[planted(spec, rng, int(rng.integers(len(terms))), [t.index for t in terms], self.name)]
        return ScalePhysics(t.index, t.where["actuator"], t.lower, t.upper, control_size(spec, t.index, size, 1.0), 0.0,
                            t.where["unit"])
