"""Hidden effects by name, for both simulators, from the effect library: one implementation per
effect, the one its plugin registers through ``platkit_register_effects``.

The additive simulator (platkit.simulate.simulate) asks an effect for its model term on the
command rows (``Effect.simulation_term(spec, size, rng, commands) -> (term, theta)``: the same
term class diagnosis fits, evaluated on a PoseSet whose ``t`` is the command times and whose
extras hold 'direction', 'last_step' and 'elapsed', as the settled poses have them). The
time-domain simulator (platkit.simulate.physics) asks for its physics
(``Effect.physics(spec, size, rng, plan) -> EffectPhysics``). The built-in effects are in
plugins/platkit_effects; an outside plugin's effect works in either mode it implements.
"""
from __future__ import annotations

import numpy as np

from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.plugins import effect_library
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["simulation_term", "size_help", "parse_effect"]


def simulation_term(name: str, spec: PlatformSpec, size: float | None, rng: np.random.Generator,
                    commands: PoseSet) -> tuple[ModelTerm, np.ndarray]:
    """An effect by name as (term, true theta) on the command rows ``commands``, from its
    plugin's ``simulation_term`` (``size`` None: the effect's default)."""
    library = effect_library()
    effect = library.get(name)
    if effect is None:
        raise BadInput(f"unknown effect {name!r}; known: {', '.join(sorted(library))}")
    made = effect.simulation_term(spec, size, rng, commands) if hasattr(effect, "simulation_term") else None
    if made is None:
        raise BadInput(f"effect {name!r} has no model term to simulate; its plugin gives it no simulation_term "
                       "(try --physics)")
    return made


def size_help(physics: bool = False) -> dict[str, str]:
    """Effect name -> what its ``--effect NAME=SIZE`` size means (``Effect.size_help``: its meaning
    and unit) in the additive simulator, or the time-domain one (``physics``), for every installed
    effect that says."""
    out = {}
    for name, effect in effect_library().items():
        told = effect.size_help(physics)
        if told is not None:
            out[name] = told.text()
    return out


def parse_effect(text: str) -> tuple[str, float | None]:
    """'backlash:1.5' (or 'backlash=1.5') -> ('backlash', 1.5); 'backlash' -> ('backlash', None)."""
    name, _, size = text.partition(":" if ":" in text else "=")
    name = name.strip()
    if not name:
        raise BadInput(f"--effect {text!r}: expected NAME or NAME:SIZE")
    if not size:
        return name, None
    try:
        value = float(size)
    except ValueError:
        raise BadInput(f"--effect {text!r}: the size after ':' must be a number") from None
    if not np.isfinite(value) or value < 0:
        raise BadInput(f"--effect {text!r}: the size must be a finite number, 0 or more (it is a magnitude)")
    return name, value
