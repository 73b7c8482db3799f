"""Outside physics of the cable robot as diagnosis effects, registered through the same
``platkit_register_effects`` hook as platkit's built-in ones.

Both act on the cables' lengths: a term's control offset d_i is added to cable i's command,
so the model's residual row becomes l_i + d_i + o_i - |A_i - (X + R b_i)|. The offsets are
evaluated at the pose the nominal stand takes for each command (forward kinematics at the
description's geometry): the effects are millimetres on metres of cable, so the pose they are
evaluated at moves them by far less than the data's noise.

- ``cable_elasticity``: a cable under tension t_i stretches by t_i l_i / (E A). The tensions
  come from a stated static load model: the platform holds a payload's weight at its origin
  (gravity along the base's -z), and the eight tensions are those of the six equilibrium
  equations nearest to a pretension of PRETENSION times the weight on every cable (the
  closed-form tension distribution), per newton of weight: tau_i. The term: d_i = e l_i tau_i,
  one e for every cable (e = m g / (E A): the strain of a cable carrying the full weight). The
  distribution is not bounded: near the workspace's edges it gives some cables a negative
  tension (a cable the model would let go slack), where the term shortens them.
- ``pulley_radius``: each cable leaves its winch over a swivelling pulley of radius r. It comes
  up the pulley's vertical swivel axis through the anchor A_i, wraps the pulley (centre
  C_i = A_i + r h_i, h_i the horizontal unit vector from A_i toward the cable's platform point
  P_i) by the angle beta_i, and leaves along the tangent to P_i. Its length from A_i is
  r beta_i + sqrt(|P_i - C_i|^2 - r^2) instead of |P_i - A_i|; the term's offset is minus the
  difference less its value at the neutral pose (where the winch's zero o_i is set), one r for
  every pulley (r = 0: no pulley).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from platkit.effects import Effect, SizeHelp
from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat
from platkit.kinematics import platform_model
from platkit.model import PlatformSpec
from platkit.plugins import get_platform
from platkit.terms import ModelTerm

N_CABLES = 8
STAND = "cable"
#: the description the package ships (the stand's default)
SHIPPED_DESCRIPTION = Path(__file__).with_name("cable.yaml")

#: every cable's mean tension, in newtons per newton of the payload's weight (the tension
#: distribution's middle: a pretension that keeps the cables taut over the workspace)
PRETENSION = 1.0

_GEOMETRY: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}


def cable_geometry(spec: PlatformSpec, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At the nominal stand's pose for each command (N, 8): the anchors A (8, 3) m, the platform's
    origin X (N, 3) m and its points turned into the base frame R b_i (N, 8, 3) m (NaN for a
    command with no pose)."""
    controls = np.atleast_2d(np.asarray(controls, float))
    key = (str(spec.description_path), np.ascontiguousarray(controls).tobytes())
    if key not in _GEOMETRY:
        if len(_GEOMETRY) > 64:
            _GEOMETRY.clear()
        model = platform_model(spec)
        td = spec.nominal_td()
        A, b = td[0:24].reshape(N_CABLES, 3), td[24:48].reshape(N_CABLES, 3)
        fb = model.forward_batch(controls, strict=False)
        X = np.full((len(controls), 3), np.nan)
        Rb = np.full((len(controls), N_CABLES, 3), np.nan)
        for k, p in enumerate(fb.p):
            if np.all(np.isfinite(p)):  # the least-squares pose, even beyond the cables' stretch
                q, x = model.pose(p)
                X[k] = np.asarray(x, float).ravel()
                Rb[k] = b @ matrix_from_quat(np.asarray(q, float).ravel()).T
        _GEOMETRY[key] = (A, X, Rb)
    return _GEOMETRY[key]


def tensions(spec: PlatformSpec, controls: np.ndarray) -> np.ndarray:
    """(N, 8) the cable tensions, N per N of payload weight, holding a weight at the platform's
    origin at the nominal pose of each command: sum_i t_i e_i = (0, 0, 1) and
    sum_i (R b_i) x t_i e_i = 0, e_i the unit vector from the platform point toward the anchor;
    of the tensions that do, the ones nearest (least squares) to PRETENSION on every cable (the
    closed-form tension distribution of Pott et al.: t = t_m + S^+ (w - S t_m))."""
    A, X, Rb = cable_geometry(spec, controls)
    out = np.full((len(X), N_CABLES), np.nan)
    rhs = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    for k in range(len(X)):
        if not np.all(np.isfinite(Rb[k])):
            continue
        v = A - (X[k] + Rb[k])
        e = v / np.linalg.norm(v, axis=1, keepdims=True)
        S = np.vstack([e.T, np.cross(Rb[k], e).T])  # (6, 8) the structure matrix
        mid = np.full(N_CABLES, PRETENSION)
        out[k] = mid + np.linalg.pinv(S) @ (rhs - S @ mid)
    return out


def pulley_excess(spec: PlatformSpec, controls: np.ndarray, r: float) -> np.ndarray:
    """(N, 8) m: how much longer each cable is from its anchor over a swivelling pulley of radius
    ``r`` than along the straight line, r beta_i + sqrt(|P_i - C_i|^2 - r^2) - |P_i - A_i|, at the
    nominal pose of each command (the geometry of the module's docstring)."""
    A, X, Rb = cable_geometry(spec, controls)
    P = X[:, None, :] + Rb
    d = P - A[None]
    rho = np.hypot(d[..., 0], d[..., 1])  # in the pulley's plane: horizontal distance, height
    z = d[..., 2]
    straight = np.hypot(rho, z)
    if r == 0:
        return np.zeros_like(straight)
    Dr, Dz = rho - r, z  # from the pulley's centre to the platform point
    dist = np.hypot(Dr, Dz)
    leave = np.arctan2(Dz, Dr) + np.arccos(np.clip(r / dist, -1.0, 1.0))  # the tangent point's angle
    beta = np.pi - leave  # wrapped from the entry (angle pi, coming up the axis) over the top
    return r * beta + np.sqrt(np.maximum(dist**2 - r**2, 0.0)) - straight


def pulley_change(spec: PlatformSpec, controls: np.ndarray, r: float) -> np.ndarray:
    """(N, 8) m: :func:`pulley_excess` less its value at the neutral pose, where each winch's
    zero (the length offset o_i) is set: the part of the pulleys' wrap no offset absorbs."""
    at_neutral = pulley_excess(spec, spec.neutral_u()[None], r)
    return pulley_excess(spec, controls, r) - at_neutral


def _stand(where: dict[str, Any]) -> PlatformSpec:
    if where.get("platform") != STAND:
        raise BadInput(f"where.platform must be '{STAND}', got {where.get('platform')!r}")
    description = where.get("description")
    if description is not None and not isinstance(description, str):
        raise BadInput("where.description must be a path or null")
    return get_platform(STAND, description)


def _stand_where(spec: PlatformSpec) -> dict[str, Any]:
    """Where a term finds its stand again: the description's path, None for the package's own."""
    path = spec.description_path
    own = path is None or Path(path).resolve() == SHIPPED_DESCRIPTION.resolve()
    return {"platform": spec.name, "description": None if own else str(path)}


@dataclass
class CableTerm(ModelTerm):
    """A cable effect's term: one number for every cable (see the module's docstring)."""

    spec: PlatformSpec | None = field(default=None, repr=False)

    def stand(self) -> PlatformSpec:
        if self.spec is None:
            self.spec = _stand(self.where)
        return self.spec


@dataclass
class ElasticityTerm(CableTerm):
    def control_offset(self, theta, poses, n_u):
        spec = self.stand()
        return theta[0] * poses.controls * tensions(spec, poses.controls)

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        spec = self.stand()
        du = (poses.controls * tensions(spec, poses.controls))[..., None]
        return du, np.zeros((poses.n_poses, 6, 1)), np.zeros((poses.n_poses, poses.n_markers, 3, 1))


@dataclass
class PulleyTerm(CableTerm):
    def control_offset(self, theta, poses, n_u):
        return -pulley_change(self.stand(), poses.controls, float(theta[0]))


def _check_stand(spec: PlatformSpec, effect: str) -> None:
    if spec.name != STAND:
        raise BadInput(f"effect {effect}: acts on the {STAND} stand only, not on {spec.name}")


class _CableEffect(Effect):
    """An effect of the cable stand: its term rebuilt from a stored one's 'where' (the stand's
    geometry), on the cable stand only."""

    term: Callable[[PlatformSpec], ModelTerm]  # each effect's own term on the stand's geometry

    def from_dict(self, data, spec=None):
        where = data.get("where") if isinstance(data, dict) else None
        if not isinstance(where, dict):
            raise BadInput(f"effect {self.name}: a stored term needs its 'where'")
        if spec is None:
            spec = _stand(where)
        _check_stand(spec, self.name)
        return self.term(spec)


class CableElasticity(_CableEffect):
    name = "cable_elasticity"
    summary = "cables stretch with their tension: l t / (E A), tensions holding the payload's weight"
    simulation_size = SizeHelp("the largest stretch of a cable over the commands", "mm")

    def term(self, spec: PlatformSpec) -> ElasticityTerm:
        where = {"cables": "all", **_stand_where(spec),
                 "load": "static tensions holding the payload's weight at the platform's origin, nearest to "
                         f"{PRETENSION:g} x the weight on every cable, per N of weight; offset e * length * tension"}
        return ElasticityTerm(self.name, ["strain_at_full_weight"], np.zeros(1), ["1"], where, spec=spec)

    def candidates(self, spec, poses, residuals=None):
        if spec.name != STAND:
            return []
        reg = poses.controls * tensions(spec, poses.controls)
        return [self.term(spec)] if np.all(np.isfinite(reg)) and np.ptp(reg) > 0 else []

    def untried(self, spec, poses):
        if spec.name != STAND:
            return []
        bad = int(np.sum(~np.all(np.isfinite(tensions(spec, poses.controls)), axis=1)))
        return [f"{bad} pose(s) the nominal stand takes no pose for (no tensions there)"] if bad else []

    def regressor(self, term, spec, poses):
        reg = poses.controls * tensions(spec, poses.controls)
        return reg @ np.sign(np.nanmean(reg, axis=0))

    def regressor_label(self, term):
        return "sum of length x tension per N of payload weight, signed (m)"

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the largest stretch of a cable over the commands, mm (default 2)."""
        _check_stand(spec, self.name)
        reg = commands.controls * tensions(spec, commands.controls)
        peak = float(np.nanmax(np.abs(reg)))
        if not peak > 0:
            raise BadInput(f"effect {self.name}: the cables carry no load on these commands")
        return self.term(spec), np.array([(2.0 if size is None else size) * 1e-3 / peak])


class PulleyRadius(_CableEffect):
    name = "pulley_radius"
    summary = "cables leave their winches over swivelling pulleys: a wrap r beta per cable"
    simulation_size = SizeHelp("the pulleys' radius", "mm")

    def term(self, spec: PlatformSpec) -> PulleyTerm:
        where = {"cables": "all", **_stand_where(spec),
                 "pulley": "swivel axis vertical through the anchor, the cable coming up it"}
        return PulleyTerm(self.name, ["radius"], np.zeros(1), ["m"], where, spec=spec)

    def candidates(self, spec, poses, residuals=None):
        if spec.name != STAND:
            return []
        ok = np.all(np.isfinite(pulley_excess(spec, poses.controls, 0.01)))
        return [self.term(spec)] if ok else []

    def regressor(self, term, spec, poses):
        """The cables' mean wrap excess from the neutral pose for a 1 mm pulley, mm per mm of radius."""
        return np.mean(pulley_change(spec, poses.controls, 1e-3), axis=1) / 1e-3

    def regressor_label(self, term):
        return "mean over the cables of the wrap excess from neutral of a 1 mm pulley (mm/mm)"

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the pulleys' radius, mm (default 15)."""
        _check_stand(spec, self.name)
        r = (15.0 if size is None else size) * 1e-3
        if not r > 0:
            raise BadInput(f"effect {self.name}: the pulleys' radius must be positive, got {r * 1e3:g} mm")
        return self.term(spec), np.array([r])


EFFECTS = [CableElasticity(), PulleyRadius()]
