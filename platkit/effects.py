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

from typing import Any

import numpy as np

from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.plugins import default_host
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: relative size (of a control's stroke) below which a change of command is "no move"
MOVE_TOLERANCE = 1e-6


class Effect:
    """Base class of a diagnosis effect (one physical mechanism, e.g. backlash).

    Attributes: ``name`` (the spec's effect name), ``summary`` (one line for people).
    """

    name: str = ""
    summary: str = ""

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


def effect_library() -> dict[str, Effect]:
    """Effect name -> effect, from every installed plugin (built-in and outside)."""

    return default_host().effects()


def term_from_dict(data: dict[str, Any], spec: PlatformSpec | None = None,
                   where: str = "calibration") -> tuple[ModelTerm, np.ndarray]:
    """(term, theta) from a stored mapping, through the effect library; BadInput names an
    unknown effect."""
    if not isinstance(data, dict) or "effect" not in data:
        raise BadInput(f"{where}: each term must be a mapping with an 'effect' field")
    library = effect_library()
    name = data["effect"]
    if name not in library:
        raise BadInput(f"{where}: unknown effect {name!r}; installed effects: {', '.join(sorted(library))}")
    term = library[name].from_dict(data, spec)
    return term, theta_from_dict(data, term.parameter_names, where)


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


def with_history(poses: PoseSet, spec: PlatformSpec | None = None) -> PoseSet:
    """``poses`` with ``extras`` 'direction', 'last_step', 'elapsed' and 'row' filled in from the
    full session's row order (kept if the session reader already supplied them)."""
    extras = dict(poses.extras)
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
    raise KeyError(key)
