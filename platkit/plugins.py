"""The plugin host: every stand and effect comes through the ``platkit`` hooks.

Two sources, registered through the same hooks (platkit/hookspecs.py):

- the built-in plugins, :data:`BUILTIN_PLUGINS`, imported by module name: platkit's own stands and
  effects are there in a source checkout or an editable install whatever the installed metadata
  says, and a test can build a host with exactly these (``PluginHost(entry_points=False)``);
- outside plugins, through the ``platkit`` entry-point group of the installed distributions. An
  entry point naming a built-in module (the metadata of an older platkit) is skipped: a plugin is
  registered once.

The entry-point group is read through ``importlib.metadata`` only when some distribution on the path
declares it (:func:`may_declare_entry_points`, a directory listing): importing importlib.metadata
costs a few milliseconds of every verb's start-up, and almost no installation has an
outside plugin.

Every plugin is checked when it registers: a hook name platkit does not define (a misspelling) or
a stand or effect name already taken is one line naming the plugin (:class:`BadPlugin`,
:class:`PluginConflict`).
"""
from __future__ import annotations

import functools
import importlib
import os
import sys
from collections.abc import Mapping
from types import ModuleType
from typing import Any, cast

import numpy as np
import pluggy

from platkit import __version__, hookspecs
from platkit.effects import Effect, theta_from_dict
from platkit.errors import BadInput, BadPlugin, PluginConflict, UnknownPlatform
from platkit.model import PlatformFactory, PlatformSpec
from platkit.terms import ModelTerm

ENTRY_POINT_GROUP = "platkit"

#: platkit's own plugins (import names; the folders under plugins/ of the repository)
BUILTIN_PLUGINS: tuple[str, ...] = ("platkit_stewart", "platkit_psvr", "platkit_rotary", "platkit_urdf",
                                    "platkit_effects")
#: what ``platkit plugins`` shows as the package of a built-in stand or effect
BUILTIN_SOURCE = f"platkit {__version__}"


class PluginHost:
    """Holds a pluggy manager and the stands and effects registered through it.

    ``builtins``: register :data:`BUILTIN_PLUGINS`; ``entry_points``: register the outside plugins
    of the ``platkit`` entry-point group. ``PluginHost(False, False)`` is an empty host.
    """

    def __init__(self, builtins: bool = True, entry_points: bool = True):
        self.pm = pluggy.PluginManager("platkit")
        self.pm.add_hookspecs(hookspecs)
        self._sources: dict[str, str] = {}
        if builtins:
            self.load_builtins()
        if entry_points:
            self.load_entry_points()

    def load_builtins(self) -> None:
        """Import and register every module of :data:`BUILTIN_PLUGINS`."""
        for module_name in BUILTIN_PLUGINS:
            try:
                module = importlib.import_module(module_name)
            except ImportError as exc:
                raise BadPlugin(
                    f"built-in plugin {module_name} cannot be imported ({exc.__class__.__name__}: {exc}); "
                    f"install platkit (pip install -e .) or put plugins/ on PYTHONPATH"
                ) from None
            self.register(module, name=module_name, source=BUILTIN_SOURCE)

    def load_entry_points(self) -> None:
        """Register the outside plugins of the ``platkit`` entry-point group."""
        if not may_declare_entry_points(ENTRY_POINT_GROUP):
            return
        from importlib import metadata

        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.module in BUILTIN_PLUGINS:
                continue
            source = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else ep.value
            try:
                module = ep.load()
            except Exception as exc:  # an outside package's import error, whatever it is
                raise BadPlugin(
                    f"plugin {ep.name!r} ({ep.value}, from {source}) cannot be loaded: "
                    f"{exc.__class__.__name__}: {exc}"
                ) from None
            self.register(module, name=ep.name, source=source)

    def register(self, plugin: ModuleType | Any, name: str | None = None, source: str = "") -> None:
        """Register a plugin object (a module, or any object with hook implementations).

        Raises :class:`BadPlugin` if it implements a hook platkit does not define or a hook with
        arguments the specification lacks, :class:`PluginConflict` if it adds a stand or effect
        name already taken. The host is unchanged after either error.
        """
        name = name or str(getattr(plugin, "__name__", repr(plugin)))
        if self.pm.is_registered(plugin):
            return
        label = f"{name} ({source})" if source and source != name else name
        try:
            self.pm.register(plugin, name=name)
        except ValueError as exc:  # pluggy: the name is taken by another plugin object
            raise PluginConflict(f"plugin name {name!r} is registered twice ({exc})") from None
        except pluggy.PluginValidationError as exc:
            raise BadPlugin(f"plugin {label}: {_one_line(exc)}") from None
        self._sources[name] = source or name
        try:
            self._check_pending(plugin, label)
            self.platforms()
            self.effects()
        except (BadPlugin, PluginConflict):
            self.pm.unregister(plugin)
            del self._sources[name]
            raise

    def _check_pending(self, plugin: Any, label: str) -> None:
        try:
            self.pm.check_pending()
        except pluggy.PluginValidationError:
            unknown = sorted(c.name for c in self.pm.get_hookcallers(plugin) or [] if not c.has_spec())
            known = sorted(n for n in dir(hookspecs) if n.startswith("platkit_"))
            raise BadPlugin(
                f"plugin {label} implements {', '.join(map(repr, unknown))}, not a platkit hook "
                f"(the hooks: {', '.join(known)})"
            ) from None

    def _factories_by_plugin(self) -> dict[str, list[PlatformFactory]]:
        out: dict[str, list[PlatformFactory]] = {}
        for impl in self.pm.hook.platkit_register_platforms.get_hookimpls():
            out[impl.plugin_name] = list(cast("list[PlatformFactory]", impl.function()) or [])
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

    def effects(self) -> dict[str, Effect]:
        """Effect name -> effect from every plugin; two plugins offering one name is an error naming both."""
        found: dict[str, Effect] = {}
        owners: dict[str, str] = {}
        for impl in self.pm.hook.platkit_register_effects.get_hookimpls():
            for e in cast("list[Effect]", impl.function()) or []:
                owner = self._sources.get(impl.plugin_name, impl.plugin_name)
                if e.name in found:
                    raise PluginConflict(
                        f"effect name {e.name!r} is registered twice: by {owners[e.name]} and by {owner}"
                    )
                found[e.name] = e
                owners[e.name] = owner
        return found

    def factory(self, name: str) -> PlatformFactory:
        stands = self.platforms()
        if name not in stands:
            raise UnknownPlatform(name, list(stands))
        return stands[name]

    def build(self, name: str, description=None, **options) -> PlatformSpec:
        return self.factory(name)(description, **options)


def may_declare_entry_points(group: str) -> bool:
    """False only where no distribution that ``importlib.metadata`` would find can declare an
    entry point of ``group``: the metadata folders (``*.dist-info``, ``*.egg-info``, an egg's
    ``EGG-INFO``) of every folder on ``sys.path`` are listed as importlib.metadata lists them, and
    none has an ``entry_points.txt`` with a section header naming ``group``. True (ask
    importlib.metadata) for anything it cannot tell: a path entry that is a file (a zip or an egg),
    a metadata file it cannot read, a finder that finds distributions other than the standard path
    finder and the importlib_metadata backport's (which read the same folders)."""
    from importlib.machinery import PathFinder

    def reads_the_path(finder) -> bool:
        # the standard path finder, or the importlib_metadata backport's finder (installed on
        # sys.meta_path when a library imports the backport): both read the folders of sys.path
        return finder is PathFinder or (type(finder).__name__ == "MetadataPathFinder"
                                        and type(finder).__module__.split(".")[0] in ("importlib_metadata", "importlib"))

    if any(getattr(f, "find_distributions", None) is not None and not reads_the_path(f) for f in sys.meta_path):
        return True
    needle = group.encode()
    for root in sys.path:
        if not isinstance(root, str):
            return True
        folder = root or "."
        try:
            children = os.listdir(folder)
        except OSError:
            if os.path.isfile(folder):  # importlib.metadata reads a zip on the path
                return True
            continue
        is_egg = os.path.basename(folder).lower().endswith(".egg")
        for child in children:
            low = child.lower()
            if not (low.endswith((".dist-info", ".egg-info")) or (is_egg and low == "egg-info")):
                continue
            try:
                with open(os.path.join(folder, child, "entry_points.txt"), "rb") as fh:
                    text = fh.read()
            except (FileNotFoundError, NotADirectoryError):
                continue
            except OSError:
                return True
            if needle in text and any(line.strip().startswith(b"[") and needle in line for line in text.splitlines()):
                return True
    return False


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())


@functools.lru_cache(maxsize=1)
def default_host() -> PluginHost:
    """The process-wide host: the built-in plugins and every installed outside plugin."""
    return PluginHost()


def effect_library() -> dict[str, Effect]:
    """Effect name -> effect, from every installed plugin (built-in and outside): the process-wide
    host's (:func:`default_host`)."""
    return default_host().effects()


def term_from_dict(data: dict[str, Any], spec: PlatformSpec | None = None, where: str = "calibration",
                   library: Mapping[str, Effect] | None = None) -> tuple[ModelTerm, np.ndarray]:
    """(term, theta) from a mapping ``ModelTerm.to_dict`` stored, through ``library`` (effect name
    -> effect; default: every installed effect); BadInput names an unknown effect."""
    if not isinstance(data, dict) or "effect" not in data:
        raise BadInput(f"{where}: each term must be a mapping with an 'effect' field")
    library = effect_library() if library is None else library
    name = data["effect"]
    if name not in library:
        raise BadInput(f"{where}: unknown effect {name!r}; installed effects: {', '.join(sorted(library))}")
    term = library[name].from_dict(data, spec)
    return term, theta_from_dict(data, term.parameter_names, where)


def get_platform(name: str, description=None, **options) -> PlatformSpec:
    """Build the named stand's spec from ``description`` (None: the plugin's default).

    ``options``: stand-specific choices (e.g. ``moving_link="tool0"`` for URDF chains); values
    are strings, numbers, lists or mappings of them (a tree's ``moving_link={"R": "right_tcp"}``).
    Specs are cached per (name, description, options).
    """
    key = tuple(sorted((k, _frozen(v)) for k, v in options.items() if v is not None))
    return _cached_platform(name, None if description is None else str(description), key)


class _FrozenDict(tuple):
    """A mapping's items, hashable, told apart from a list's tuple."""


def _frozen(v):
    if isinstance(v, dict):
        return _FrozenDict((k, _frozen(x)) for k, x in v.items())
    if isinstance(v, (list, tuple)):
        return tuple(_frozen(x) for x in v)
    return v


def _thawed(v):
    if isinstance(v, _FrozenDict):
        return {k: _thawed(x) for k, x in v}
    if isinstance(v, tuple):
        return [_thawed(x) for x in v]
    return v


@functools.lru_cache(maxsize=32)
def _cached_platform(name: str, description: str | None, options: tuple) -> PlatformSpec:
    return default_host().build(name, description, **{k: _thawed(v) for k, v in options})


def list_platforms() -> dict[str, PlatformFactory]:
    return default_host().platforms()
