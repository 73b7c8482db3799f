"""The plugin host: built-ins by module name, outside plugins by entry point, each registered once,
and a plugin that cannot work refused in one line naming it."""
import sys
import types
from importlib import metadata

import pytest

from platkit import plugins
from platkit.errors import BadPlugin, PluginConflict, UnknownPlatform
from platkit.hookspecs import hookimpl
from platkit.model import PlatformFactory
from platkit.plugins import BUILTIN_PLUGINS, BUILTIN_SOURCE, PluginHost, may_declare_entry_points

STANDS = {"stewart", "psvr", "rotary", "urdf"}
#: the effects the outer contract names (shared/spec/README.md section 3), less `unexplained`
SPEC_EFFECTS = {"backlash", "compliance", "thermal_drift", "cyclic_error", "scale_nonlinearity",
                "settling_lag", "marker_slip", "base_tilt"}


def _plugin(name, title):
    class P:
        @hookimpl
        def platkit_register_platforms(self):
            return [PlatformFactory(name, title, lambda path, options: None)]

    return P()


def _entry_points(monkeypatch, *eps):
    """Make the ``platkit`` entry-point group hold exactly ``eps`` (name, "module") pairs."""
    listed = [metadata.EntryPoint(name, value, "platkit") for name, value in eps]

    def entry_points(**kw):
        return [ep for ep in listed if kw.get("group") in (None, "platkit")]

    monkeypatch.setattr(metadata, "entry_points", entry_points)
    # the folders on sys.path declare no such group: the host must ask importlib.metadata anyway
    monkeypatch.setattr(plugins, "may_declare_entry_points", lambda group: True)


def test_the_builtin_list_alone_gives_the_four_stands_and_the_effects(builtin_host):
    stands = builtin_host.platforms()
    assert set(stands) == STANDS
    assert {f.package for f in stands.values()} == {BUILTIN_SOURCE}
    effects = builtin_host.effects()
    assert SPEC_EFFECTS <= set(effects)
    assert all(e.name == name for name, e in effects.items())


def test_builtins_are_there_with_no_entry_point_at_all(monkeypatch):
    _entry_points(monkeypatch)  # e.g. a source checkout that was never pip-installed
    host = PluginHost()
    assert set(host.platforms()) == STANDS
    assert SPEC_EFFECTS <= set(host.effects())


def test_an_empty_host_has_nothing():
    host = PluginHost(builtins=False, entry_points=False)
    assert host.platforms() == {} and host.effects() == {}


def test_an_entry_point_naming_a_builtin_is_not_registered_twice(monkeypatch):
    # the metadata of an older platkit listed its built-ins as entry points
    _entry_points(monkeypatch, ("stewart", "platkit_stewart"), ("effects", "platkit_effects"))
    host = PluginHost()
    assert set(host.platforms()) == STANDS
    assert len(host.pm.get_plugins()) == len(BUILTIN_PLUGINS)


def test_an_outside_plugin_comes_through_its_entry_point(monkeypatch):
    outside = types.ModuleType("outside_stand")
    outside.platkit_register_platforms = hookimpl(lambda: [PlatformFactory("hexa", "outside", lambda p, o: None)])
    monkeypatch.setitem(sys.modules, "outside_stand", outside)
    _entry_points(monkeypatch, ("hexa", "outside_stand"))
    assert set(PluginHost().platforms()) == STANDS | {"hexa"}
    assert set(PluginHost(entry_points=False).platforms()) == STANDS


def test_an_outside_plugin_that_fails_to_import_is_named(monkeypatch):
    _entry_points(monkeypatch, ("broken", "no_such_module_platkit_test"))
    with pytest.raises(BadPlugin, match=r"plugin 'broken' \(no_such_module_platkit_test.*ModuleNotFoundError"):
        PluginHost()


def test_duplicate_stand_name_is_an_error_naming_both():
    host = PluginHost(builtins=False, entry_points=False)
    host.register(_plugin("hexa", "one"), name="first", source="pkg-one")
    with pytest.raises(PluginConflict, match="pkg-one.*pkg-two"):
        host.register(_plugin("hexa", "two"), name="second", source="pkg-two")
    assert list(host.platforms()) == ["hexa"]
    assert [host.pm.get_name(p) for p in host.pm.get_plugins()] == ["first"]


def test_an_outside_effect_with_a_builtin_name_is_an_error_naming_both(builtin_host):
    backlash = builtin_host.effects()["backlash"]

    class Copy:
        @hookimpl
        def platkit_register_effects(self):
            return [backlash]

    with pytest.raises(PluginConflict, match=rf"effect name 'backlash'.*{BUILTIN_SOURCE}.*other-pkg 1\.0"):
        builtin_host.register(Copy(), name="copy", source="other-pkg 1.0")
    assert "copy" not in [builtin_host.pm.get_name(p) for p in builtin_host.pm.get_plugins()]


def test_a_misspelled_hook_is_one_line_naming_the_plugin(builtin_host):
    class Typo:
        @hookimpl
        def platkit_register_platfroms(self):
            return []

    with pytest.raises(BadPlugin) as err:
        builtin_host.register(Typo(), name="typo", source="typo-pkg 0.3")
    message = str(err.value)
    assert "\n" not in message
    assert "typo (typo-pkg 0.3)" in message and "'platkit_register_platfroms'" in message
    assert "platkit_register_platforms" in message.split("the hooks:")[1]
    # refused whole: the host works on without it
    assert not builtin_host.pm.has_plugin("typo")
    builtin_host.pm.check_pending()


def test_a_hook_with_arguments_the_specification_lacks_is_refused(builtin_host):
    class Extra:
        @hookimpl
        def platkit_register_effects(self, spec):
            return []

    with pytest.raises(BadPlugin, match=r"plugin extra \(extra-pkg\).*spec"):
        builtin_host.register(Extra(), name="extra", source="extra-pkg")


def test_unknown_stand_lists_the_known_ones(builtin_host):
    with pytest.raises(UnknownPlatform, match="psvr, rotary, stewart, urdf"):
        builtin_host.factory("no-such-stand")


def _dist(folder, name, entry_points=None):
    info = folder / name
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name.split('-')[0]}\nVersion: 1.0\n")
    if entry_points is not None:
        (info / "entry_points.txt").write_text(entry_points)


def test_the_entry_point_precheck_finds_what_importlib_metadata_finds(tmp_path, monkeypatch):
    # a folder on the path with distributions that declare other groups only: nothing to ask for
    _dist(tmp_path, "tool-1.0.dist-info", "[console_scripts]\nplatkit-like = tool:main\n")
    _dist(tmp_path, "old-1.0.egg-info", "[pytest11]\nplatkit = old.plug\n")
    _dist(tmp_path, "bare-1.0.dist-info")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert not list(metadata.entry_points(group="platkit-test-group"))
    assert not may_declare_entry_points("platkit-test-group")
    # one that declares the group (a header with spaces, a second section): found, and by
    # importlib.metadata too
    _dist(tmp_path, "Hexa_Stand-2.0.dist-info", "[console_scripts]\nx = y:z\n\n  [platkit-test-group]  \nhexa = hexa_stand\n")
    assert may_declare_entry_points("platkit-test-group")
    assert [ep.value for ep in metadata.entry_points(group="platkit-test-group")] == ["hexa_stand"]


def test_the_entry_point_precheck_asks_where_it_cannot_tell(tmp_path, monkeypatch):
    archive = tmp_path / "plugins.zip"
    archive.write_bytes(b"PK\x05\x06" + bytes(18))  # an (empty) zip on the path: importlib.metadata reads zips
    monkeypatch.syspath_prepend(str(archive))
    assert may_declare_entry_points("platkit-test-group")


def test_the_entry_point_precheck_agrees_with_importlib_metadata_here():
    groups = {ep.group for dist in metadata.distributions() for ep in dist.entry_points}
    assert groups, "this environment has entry points (pytest's, platkit's console script)"
    assert all(may_declare_entry_points(g) for g in groups)
    assert not may_declare_entry_points("platkit-no-such-group")


def test_the_entry_point_precheck_reads_past_the_importlib_metadata_backport(monkeypatch):
    # a library that imports the importlib_metadata backport puts its path finder on sys.meta_path;
    # it reads the same folders, so the precheck still tells; any other distribution finder: ask
    backport = type("MetadataPathFinder", (), {"__module__": "importlib_metadata",
                                               "find_distributions": lambda self, *a, **k: iter(())})
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, backport()])
    assert not may_declare_entry_points("platkit-no-such-group")
    other = type("ZipDistFinder", (), {"__module__": "somewhere", "find_distributions": lambda self, *a, **k: iter(())})
    monkeypatch.setattr(sys, "meta_path", [*sys.meta_path, other()])
    assert may_declare_entry_points("platkit-no-such-group")
