"""Plugins from outside platkit, for the tests: each module registers through the ``platkit``
hooks exactly as a third-party package would, and a test adds it to a host of its own
(``PluginHost(entry_points=False).register(module)``), never to platkit's built-ins."""

from platkit.hookspecs import hookimpl
from platkit.plugins import PluginHost


class EffectsPlugin:
    """A plugin object that registers ``effects`` (outside effects a test writes inline)."""

    def __init__(self, effects):
        self.effects = list(effects)

    @hookimpl
    def platkit_register_effects(self):
        return self.effects


def library_with(*effects, name: str = "tests") -> dict:
    """Effect name -> effect of a host of the built-ins and ``effects``, registered through the
    plugin hooks as an outside package's are (a name already taken is a PluginConflict)."""
    host = PluginHost(entry_points=False)
    host.register(EffectsPlugin(effects), name=name, source="tests")
    return host.effects()
