import pytest

from platkit.errors import PluginConflict, UnknownPlatform
from platkit.hookspecs import hookimpl
from platkit.model import PlatformFactory
from platkit.plugins import PluginHost


def _plugin(name, title):
    class P:
        @hookimpl
        def platkit_register_platforms(self):
            return [PlatformFactory(name, title, lambda path, options: None)]

    return P()


def test_duplicate_stand_name_is_an_error_naming_both():
    host = PluginHost(load_entry_points=False)
    host.register(_plugin("hexa", "one"), name="first", source="pkg-one")
    with pytest.raises(PluginConflict, match="pkg-one.*pkg-two"):
        host.register(_plugin("hexa", "two"), name="second", source="pkg-two")
    assert list(host.platforms()) == ["hexa"]


def test_unknown_stand_lists_the_known_ones():
    host = PluginHost()
    with pytest.raises(UnknownPlatform, match="stewart"):
        host.factory("no-such-stand")


def test_builtin_stand_comes_through_entry_points():
    host = PluginHost()
    assert host.factory("stewart").package.startswith("platkit")
