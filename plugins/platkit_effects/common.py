"""Helpers every effect of platkit_effects shares: reading a stored term's ``where`` (its actuator,
its numbers), a simulation size in SI, and the stand's kinematic model, built once per stand."""
from __future__ import annotations

from typing import Any

from platkit.errors import BadInput
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec


def _where(data: dict) -> dict:
    where = data.get("where") if isinstance(data, dict) else None
    return where if isinstance(where, dict) else {}


def _actuator(spec: PlatformSpec | None, data: dict, effect: str) -> tuple[int, str, str]:
    """(index, name, unit) of the actuator a stored term acts on."""
    where = _where(data)
    name, index, unit = where.get("actuator"), where.get("actuator_index"), where.get("unit")
    if spec is not None:
        if name not in spec.control_names:
            raise BadInput(f"effect {effect!r}: actuator {name!r} is not a control of {spec.name} "
                           f"({', '.join(spec.control_names)})")
        i = spec.control_names.index(name)
        return i, name, spec.controls[i].unit
    if not isinstance(index, int) or index < 0 or not isinstance(unit, str):
        raise BadInput(f"effect {effect!r}: where needs actuator_index (an integer >= 0) and unit")
    return index, str(name), unit


def _actuator_where(spec: PlatformSpec, i: int) -> dict:
    return {"actuator": spec.control_names[i], "actuator_index": i, "unit": spec.controls[i].unit}


def _size(spec: PlatformSpec, i: int, size: float | None, default: float) -> float:
    """A simulation size in SI for control i: mm -> m for length controls, else the control's unit."""
    size = default if size is None else float(size)
    return size * 1e-3 if spec.controls[i].unit == "m" else size


def _number(where: dict, key: str, effect: str, positive: bool = False) -> float:
    v = where.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (positive and not v > 0):
        raise BadInput(f"effect {effect!r}: where.{key} must be a{' positive' if positive else ''} number")
    return float(v)


_MODELS: dict[int, tuple[PlatformSpec, Any]] = {}


def _platform_model(spec: PlatformSpec):
    """One PlatformModel per spec object (building one compiles CasADi functions)."""

    hit = _MODELS.get(id(spec))
    if hit is None or hit[0] is not spec:
        if len(_MODELS) > 16:
            _MODELS.clear()
        hit = _MODELS[id(spec)] = (spec, PlatformModel(spec))
    return hit[1]
