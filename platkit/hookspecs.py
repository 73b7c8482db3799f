"""The hooks a plugin implements. Stands (built-in or outside) register through these alone.

A plugin is a module (or object) with functions decorated by :data:`hookimpl`, found through the
``platkit`` entry-point group. See docs/plugin-tutorial.md.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import pluggy

if TYPE_CHECKING:
    from platkit.model import PlatformSpec

hookspec = pluggy.HookspecMarker("platkit")
hookimpl = pluggy.HookimplMarker("platkit")


@hookspec
def platkit_register_platforms() -> list["PlatformFactory"]:
    """Return the stands this plugin provides, as :class:`platkit.model.PlatformFactory` objects."""


@hookspec
def platkit_register_effects() -> list[Any]:
    """Return diagnosis effects (:class:`platkit.diagnose.effects.Effect` objects) this plugin adds."""


from platkit.model import PlatformFactory  # noqa: E402  (for the annotation above)
