"""Warm-up with time since power-on, as the time-domain simulator plays it (platkit.simulate.physics).

A stand switched on at ``power_on_s`` (seconds on the commands clock) warms towards an
equilibrium whatever it does: each actuator lengthens by

    d_j(t) = A_j (1 - exp(-(t - power_on_s) / tau))      (0 before power-on)

``A_j`` its lengthening once warm, ``tau`` the warm-up's time constant. This is apart from the
heat of the work the actuators do (an effect's physics in the effect library): a warm-up acts
on a stand that stands still. Its size is a nuisance of the recording, drawn from the session's
seed: the largest A_j 0.3 to 1.0 mm (length controls; 0.1% to 0.3% of the stroke otherwise), each
actuator's a share 0.3 to 1 of it, tau 5 to 20 minutes. Two kinds:

- ``'visible'``: switched on 0 to 60 s before the first command, so the session records the
  warm-up;
- ``'warm'``: switched on 6 to 10 time constants before it, so the session is at the
  equilibrium throughout (the geometry absorbs the constant lengthening).

The truth lists it under the name of the effect that says it is a warm-up (``Effect.warm_up``),
with ``form: warm-up with time``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import EffectPhysics, PhysicsPlan, PhysicsSeries
from platkit.errors import BadInput
from platkit.model import PlatformSpec

__all__ = ["WARMUP_KINDS", "WarmupPhysics", "draw_warmup"]

#: the kinds of warm-up :func:`draw_warmup` draws (see the module's docstring)
WARMUP_KINDS = ("visible", "warm")
#: ranges of the draws (uniform): the largest lengthening once warm (mm, length controls), the
#: same as a share of the stroke (other controls), each actuator's share of the largest, the
#: time constant (s), power-on before the first command (s) for 'visible', and in time constants
#: for 'warm'
WARMUP_RANGES = {"largest_mm": (0.3, 1.0), "largest_share_of_stroke": (1e-3, 3e-3), "actuator_share": (0.3, 1.0),
                 "tau_s": (300.0, 1200.0), "visible_before_s": (0.0, 60.0), "warm_before_taus": (6.0, 10.0)}


@dataclass
class WarmupPhysics(EffectPhysics):
    """Every actuator j lengthens by ``amplitude[j] (1 - exp(-(t - power_on_s) / tau_s))``
    (internal units; t and power_on_s seconds on the commands clock)."""

    amplitude: np.ndarray
    tau_s: float
    power_on_s: float
    unit: str
    kind: str = "visible"
    effect: str = ""  # the effect it is listed under in the truth

    def parameters(self):
        return {"form": "warm-up with time", "actuator": "all", "kind": self.kind,
                "amplitude": [float(a) for a in self.amplitude], "warmup_time_constant_s": float(self.tau_s),
                "power_on_s": float(self.power_on_s), "largest_expansion": float(np.max(np.abs(self.amplitude))),
                "unit": self.unit}

    def warmth(self, t: np.ndarray) -> np.ndarray:
        """(K,) the share of the equilibrium reached at times ``t`` (K,) s on the commands clock."""
        age = np.maximum(np.asarray(t, float) - self.power_on_s, 0.0)
        return 1.0 - np.exp(-age / self.tau_s)

    def drive(self, series: PhysicsSeries, plan: PhysicsPlan) -> np.ndarray:
        return series.motor + self.warmth(series.t)[:, None] * np.asarray(self.amplitude, float)[None]


def draw_warmup(spec: PlatformSpec, kind: str, rng: np.random.Generator, first_command_s: float,
                effect: str) -> WarmupPhysics:
    """A warm-up of ``kind`` ('visible' or 'warm', see the module's docstring) for a session whose
    first command is sent at ``first_command_s`` (commands clock), drawn from ``rng``, listed in
    the truth under ``effect``."""
    if kind not in WARMUP_KINDS:
        raise BadInput(f"warm-up: kind must be one of {', '.join(WARMUP_KINDS)}, got {kind!r}")
    R = WARMUP_RANGES
    tau = float(rng.uniform(*R["tau_s"]))
    share = rng.uniform(*R["actuator_share"], spec.n_u)
    share /= share.max()
    lo, hi = spec.control_bounds()
    stroke = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, 1.0)
    largest_mm = float(rng.uniform(*R["largest_mm"]))
    largest_share = float(rng.uniform(*R["largest_share_of_stroke"]))
    largest = np.array([largest_mm * 1e-3 if c.unit == "m" else largest_share * s for c, s in zip(spec.controls, stroke)])
    if kind == "visible":
        before = float(rng.uniform(*R["visible_before_s"]))
    else:
        before = float(rng.uniform(*R["warm_before_taus"])) * tau
    units = {c.unit for c in spec.controls}
    unit = units.pop() if len(units) == 1 else "the control's unit"
    return WarmupPhysics(largest * share, tau, float(first_command_s) - before, unit, kind, effect=effect)
