import os

os.environ.setdefault("MPLBACKEND", "Agg")
import pytest


@pytest.fixture
def builtin_host():
    """A plugin host with platkit's built-in plugins only: no outside plugin installed on this
    machine (an entry point of the ``platkit`` group) can change what a test sees."""
    from platkit.plugins import PluginHost

    return PluginHost(builtins=True, entry_points=False)
