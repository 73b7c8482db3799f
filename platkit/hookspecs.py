"""The hooks a plugin implements. Stands and effects, built-in or outside, register through these alone.

A plugin is a module (or object) with functions decorated by :data:`hookimpl`: platkit's own are
listed in :data:`platkit.plugins.BUILTIN_PLUGINS`, outside ones are found through the ``platkit``
entry-point group. A decorated function whose name is not one of the hooks below is refused when
the plugin registers (a misspelled hook would otherwise be silently never called). See
docs/plugin-tutorial.md.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:  # annotations only: the effect contract sits beside this module, not below it
    from platkit.effects import Effect
    from platkit.model import PlatformFactory

hookspec = pluggy.HookspecMarker("platkit")
hookimpl = pluggy.HookimplMarker("platkit")


@hookspec
def platkit_register_platforms() -> list[PlatformFactory]:
    """Return the stands this plugin provides, as :class:`platkit.model.PlatformFactory` objects."""


@hookspec
def platkit_register_effects() -> list[Effect]:
    """Return the effects this plugin adds (:class:`platkit.effects.Effect` objects), motion-capture or IMU."""
