"""Plugins from outside platkit, for the tests: each module registers through the ``platkit``
hooks exactly as a third-party package would, and a test adds it to a host of its own
(``PluginHost(entry_points=False).register(module)``), never to platkit's built-ins."""
