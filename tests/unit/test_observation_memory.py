"""The observation module keeps freed memory in the process (glibc's allocator set once at import,
platkit.calibrate.observation._keep_freed_memory), unless the user set glibc's own variables."""
from __future__ import annotations

import ctypes
import sys

import pytest

from platkit.calibrate import observation


def _glibc() -> bool:
    return sys.platform == "linux" and hasattr(ctypes.CDLL(None), "gnu_get_libc_version")


@pytest.mark.parametrize("variable", ["MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"])
def test_the_user_s_own_malloc_settings_are_left_alone(monkeypatch, variable):
    monkeypatch.setenv(variable, "65536")
    assert observation._keep_freed_memory() is False


def test_glibc_keeps_freed_memory(monkeypatch):
    monkeypatch.delenv("MALLOC_MMAP_THRESHOLD_", raising=False)
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    assert observation._keep_freed_memory() is _glibc()
