"""platkit: kinematics, calibration, diagnosis and state estimation of motion platforms.

    >>> import platkit
    >>> spec = platkit.get_platform("stewart")
    >>> model = platkit.PlatformModel(spec)
    >>> pose = model.forward(spec.neutral_u())
"""
from platkit.errors import PlatkitError
from platkit.kinematics import PlatformModel
from platkit.model import Control, Coordinate, Parameter, PlatformFactory, PlatformSpec
from platkit.plugins import get_platform, list_platforms

__version__ = "0.1.0"
__all__ = [
    "Control", "Coordinate", "Parameter", "PlatformFactory", "PlatformModel", "PlatformSpec",
    "PlatkitError", "get_platform", "list_platforms",
]
