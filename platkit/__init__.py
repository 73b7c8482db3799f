"""platkit: kinematics, calibration, diagnosis and state estimation of motion platforms.

    >>> import platkit
    >>> spec = platkit.get_platform("stewart")
    >>> model = platkit.PlatformModel(spec)
    >>> pose = model.forward(spec.neutral_u())

The names below are imported on first use (PEP 562), so that ``import platkit.cli`` (every
``platkit`` command line, ``--version`` included) starts without CasADi and NumPy, and a
Ctrl-C during start-up reaches the CLI's handler.
"""
import importlib

__version__ = "0.1.0"

#: public name -> the module that defines it
_EXPORTS = {
    "PlatkitError": "platkit.errors",
    "PlatformModel": "platkit.kinematics",
    "Control": "platkit.model", "Coordinate": "platkit.model", "Parameter": "platkit.model",
    "PlatformFactory": "platkit.model", "PlatformSpec": "platkit.model",
    "get_platform": "platkit.plugins", "list_platforms": "platkit.plugins",
    "hookimpl": "platkit.hookspecs", "Effect": "platkit.effects", "ModelTerm": "platkit.terms",
    "PoseSet": "platkit.poses",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'platkit' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
