"""Helpers every effect of platkit_effects shares: the stand's kinematic model, built once per
stand, and the names these modules call platkit.effects' public helpers by (a stored term's
``where``, its actuator and numbers, a simulated size in SI)."""
from __future__ import annotations

from typing import Any

from platkit.effects import actuator_where, control_size, stored_actuator, stored_number, stored_where
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec

# the helpers every effect author needs are public in platkit.effects; this package's modules
# call them by these names
_where = stored_where
_actuator = stored_actuator
_actuator_where = actuator_where
_size = control_size
_number = stored_number


_MODELS: dict[int, tuple[PlatformSpec, Any]] = {}


def _platform_model(spec: PlatformSpec):
    """One PlatformModel per spec object (building one compiles CasADi functions)."""

    hit = _MODELS.get(id(spec))
    if hit is None or hit[0] is not spec:
        if len(_MODELS) > 16:
            _MODELS.clear()
        hit = _MODELS[id(spec)] = (spec, PlatformModel(spec))
    return hit[1]
