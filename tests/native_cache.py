"""Fixtures for a module that compiles a C kernel into the cache folder (platkit.settle._native,
platkit.chains.native_servo): `cache`, the test module's own cache folder, where the kernel is
compiled once, and `empty_cache`, a fresh empty one; both with nothing loaded yet."""
from __future__ import annotations

import pytest


def native_cache_fixtures(native, name: str):
    """(module_cache, cache, empty_cache) fixtures for the compiling module `native` (its `_loaded`
    table emptied, PLATKIT_CACHE_DIR pointed at the folder); bind them to those names in the test
    module so that pytest finds them."""

    @pytest.fixture(scope="module")
    def module_cache(tmp_path_factory):
        return tmp_path_factory.mktemp(name)

    @pytest.fixture
    def cache(monkeypatch, module_cache):
        """The test module's cache folder (the kernel is compiled there once) and nothing loaded yet."""
        monkeypatch.setattr(native, "_loaded", {})
        monkeypatch.setenv("PLATKIT_CACHE_DIR", str(module_cache))
        return module_cache

    @pytest.fixture
    def empty_cache(monkeypatch, tmp_path):
        """An empty cache folder and nothing loaded yet."""
        monkeypatch.setattr(native, "_loaded", {})
        monkeypatch.setenv("PLATKIT_CACHE_DIR", str(tmp_path))
        return tmp_path

    return module_cache, cache, empty_cache
