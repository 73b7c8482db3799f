"""platkit's cache folder, and the parsed YAML kept there.

Compiled solvers (platkit/native.py, platkit/calibrate/observation.py, platkit/chains/native_servo.py)
and parsed YAML files are kept in one folder: ``$PLATKIT_CACHE_DIR``, else
``$XDG_CACHE_HOME/platkit``, else ``~/.cache/platkit``.

Parsed YAML: every verb that looks up a stand reads its description, and importing PyYAML costs a
start-up about 8 ms, more than parsing the file. What ``yaml.safe_load`` returned for a
file's text is kept as a :mod:`marshal` blob named by the hash of that text (and of the PyYAML and
Python it was parsed with), so a text parsed once is not parsed again, nor PyYAML imported. Only
texts that parsed to a mapping that passed the alias check are kept; a value marshal cannot
hold (a date) is not kept, that text is parsed each time. A cache that cannot be written or read
is passed over: the file is parsed as if there were none.
"""
from __future__ import annotations

import hashlib
import importlib.util
import marshal
import os
import shutil
import sys
import threading
from pathlib import Path
from typing import Any

#: texts longer than this are parsed each time (descriptions are a few kB)
MAX_CACHED_TEXT = 1 << 20


def cache_dir() -> Path:
    """Where compiled solvers and parsed YAML are kept: $PLATKIT_CACHE_DIR, else
    $XDG_CACHE_HOME/platkit, else ~/.cache/platkit."""
    env = os.environ.get("PLATKIT_CACHE_DIR")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "platkit"


def c_compiler() -> str | None:
    """The system C compiler that builds the compiled solvers kept here ($CC, else cc, gcc,
    clang on the PATH), or None: none found, or compiling switched off (PLATKIT_COMPILE=0)."""
    if os.environ.get("PLATKIT_COMPILE", "1").strip().lower() in ("0", "no", "false", "off"):
        return None
    cc = os.environ.get("CC")
    return next((path for path in map(shutil.which, ([cc] if cc else []) + ["cc", "gcc", "clang"]) if path), None)


def _parser_tag() -> str:
    """Which PyYAML and Python parse: the path and modification time of PyYAML's __init__.py
    (an upgrade or reinstall rewrites it) and the Python and marshal versions, found without
    importing PyYAML."""
    spec = importlib.util.find_spec("yaml")
    origin = spec.origin if spec is not None else None
    try:
        stamp = os.stat(origin).st_mtime_ns if origin else None
    except OSError:
        stamp = None
    return f"{sys.version}\n{marshal.version}\n{origin}:{stamp}"


def yaml_cache_path(text: str) -> Path | None:
    """The cache file of ``text``'s parse (None: too long to keep)."""
    if len(text) > MAX_CACHED_TEXT:
        return None
    key = hashlib.sha256((_parser_tag() + "\0" + text).encode("utf-8", "surrogatepass")).hexdigest()[:32]
    return cache_dir() / "yaml" / f"{key}.marshal"


def cached_yaml(text: str) -> dict[str, Any] | None:
    """What the YAML ``text`` parsed to when it was last kept, or None (never kept, or unreadable)."""
    path = yaml_cache_path(text)
    if path is None:
        return None
    try:
        data = marshal.loads(path.read_bytes())
    except (OSError, ValueError, EOFError, TypeError):
        return None
    return data if isinstance(data, dict) else None


def keep_yaml(text: str, data: dict[str, Any]) -> None:
    """Keep ``text``'s parse ``data`` (a mapping); nothing when marshal cannot hold it or the
    cache cannot be written."""
    path = yaml_cache_path(text)
    if path is None:
        return
    try:
        blob = marshal.dumps(data)
    except ValueError:  # a date, or another object marshal does not write
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")  # one writer each
        tmp.write_bytes(blob)
        os.replace(tmp, path)  # atomic: a reader sees the whole blob or none
    except OSError:
        return
