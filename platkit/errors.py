"""The one error hierarchy of platkit.

Every error a user can cause or meet is a :class:`PlatkitError`. The CLI maps
:class:`BadInput` (and its subclasses) to exit code 2 and :class:`ComputationFailed`
(and its subclasses) to exit code 1, printing ``str(error)`` as one line.
"""
from __future__ import annotations


class PlatkitError(Exception):
    """Base of every platkit error; ``str()`` is one line a person can act on."""

    exit_code = 1


class BadInput(PlatkitError):
    """The input is malformed: a file, row, column or field is not what was expected."""

    exit_code = 2


class BadDescription(BadInput):
    """A platform description (YAML or URDF) is malformed or inconsistent."""


class UnknownPlatform(BadInput):
    """No installed stand has the requested name."""

    def __init__(self, name: str, known: list[str]):
        self.name = name
        self.known = sorted(known)
        super().__init__(
            f"unknown platform {name!r}; installed stands: {', '.join(self.known) or 'none'}"
        )


class BadSession(BadInput):
    """A recording session is malformed; the message names file, row or column."""


class BadPlugin(PlatkitError):
    """A plugin cannot be loaded, or implements a hook platkit does not define."""

    exit_code = 2


class PluginConflict(BadPlugin):
    """Two plugins registered the same name."""


class ComputationFailed(PlatkitError):
    """A computation could not produce a trustworthy result."""

    exit_code = 1


class NoConvergence(ComputationFailed):
    """An iterative solver stopped without meeting its tolerance."""

    def __init__(self, what: str, iterations: int, residual: float, hint: str = ""):
        self.iterations = iterations
        self.residual = residual
        msg = f"{what} did not converge after {iterations} iterations (residual {residual:.3g})"
        super().__init__(msg + (f"; {hint}" if hint else ""))


class OutOfWorkspace(ComputationFailed):
    """The requested pose or controls are outside what the stand can reach."""


class WrongBranch(ComputationFailed):
    """A solver converged to an assembly mode (mirror pose) the stand cannot take."""


class NotIdentifiable(ComputationFailed):
    """The data cannot fix the named parameters."""
