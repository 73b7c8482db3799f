"""The plugin host: every stand and effect comes through the ``platkit`` hooks.

Built-in stands are found exactly as outside ones are: through the ``platkit`` entry-point
group of the installed distributions (platkit's own pyproject.toml lists its four).
"""
from __future__ import annotations

import functools
from importlib import metadata
from types import ModuleType
from typing import Any

import pluggy

from platkit import hookspecs
from platkit.errors import PluginConflict, UnknownPlatform
from platkit.model import PlatformFactory, PlatformSpec

ENTRY_POINT_GROUP = "platkit"


class PluginHost:
    """Holds a pluggy manager and the stands and effects registered through it."""

    def __init__(self, load_entry_points: bool = True):
        self.pm = pluggy.PluginManager("platkit")
        self.pm.add_hookspecs(hookspecs)
        self._sources: dict[str, str] = {}
        if load_entry_points:
            self._load_entry_points()

    def _load_entry_points(self) -> None:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            module = ep.load()
            dist = ep.dist.name if ep.dist is not None else "?"
            version = ep.dist.version if ep.dist is not None else ""
            self.register(module, name=ep.name, source=f"{dist} {version}".strip())

    def register(self, plugin: ModuleType | Any, name: str | None = None, source: str = "") -> None:
        """Register a plugin object; raise PluginConflict if it adds a stand name already taken."""
        name = name or getattr(plugin, "__name__", repr(plugin))
        if self.pm.is_registered(plugin):
            return
        before = self._factories_by_plugin()
        self.pm.register(plugin, name=name)
        self._sources[name] = source or getattr(plugin, "__name__", name)
        try:
            self.platforms()
            self.effects()
        except PluginConflict:
            self.pm.unregister(plugin)
            raise
        del before

    def _factories_by_plugin(self) -> dict[str, list[PlatformFactory]]:
        out: dict[str, list[PlatformFactory]] = {}
        for impl in self.pm.hook.platkit_register_platforms.get_hookimpls():
            out[impl.plugin_name] = list(impl.function() or [])
        return out

    def platforms(self) -> dict[str, PlatformFactory]:
        """Stand name -> factory. Two plugins offering one name is an error naming both."""
        found: dict[str, PlatformFactory] = {}
        for plugin_name, factories in self._factories_by_plugin().items():
            for f in factories:
                f.package = f.package or self._sources.get(plugin_name, plugin_name)
                if f.name in found:
                    raise PluginConflict(
                        f"stand name {f.name!r} is registered twice: by {found[f.name].package} and by {f.package}"
                    )
                found[f.name] = f
        return found

    def effects(self) -> dict[str, Any]:
        """Effect name -> effect object from every plugin; duplicates are an error naming both."""
        found: dict[str, Any] = {}
        owners: dict[str, str] = {}
        for impl in self.pm.hook.platkit_register_effects.get_hookimpls():
            for e in impl.function() or []:
                if e.name in found:
                    raise PluginConflict(
                        f"effect name {e.name!r} is registered twice: by {owners[e.name]} and by {impl.plugin_name}"
                    )
                found[e.name] = e
                owners[e.name] = self._sources.get(impl.plugin_name, impl.plugin_name)
        return found

    def factory(self, name: str) -> PlatformFactory:
        stands = self.platforms()
        if name not in stands:
            raise UnknownPlatform(name, list(stands))
        return stands[name]

    def build(self, name: str, description=None, **options) -> PlatformSpec:
        return self.factory(name)(description, **options)


@functools.lru_cache(maxsize=1)
def default_host() -> PluginHost:
    """The process-wide host with every installed plugin."""
    return PluginHost()


def get_platform(name: str, description=None, **options) -> PlatformSpec:
    """Build the named stand's spec from ``description`` (None: the plugin's default).

    ``options``: stand-specific choices (e.g. ``moving_link="tool0"`` for URDF chains); values
    must be hashable (strings, numbers, tuples). Specs are cached per (name, description, options).
    """
    key = tuple(sorted((k, v) for k, v in options.items() if v is not None))
    return _cached_platform(name, None if description is None else str(description), key)


@functools.lru_cache(maxsize=32)
def _cached_platform(name: str, description: str | None, options: tuple) -> PlatformSpec:
    return default_host().build(name, description, **dict(options))


def list_platforms() -> dict[str, PlatformFactory]:
    return default_host().platforms()
