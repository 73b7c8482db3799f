"""Outputs appear whole or not at all: write to a temporary sibling, then rename."""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

from platkit.errors import BadInput


def _blocking_file(path: Path) -> Path | None:
    """The first of ``path``'s ancestors that exists and is not a folder, if any."""
    for parent in reversed(path.parents):
        if parent.exists() and not parent.is_dir():
            return parent
    return None


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists."""
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")


def _check_writable(out: Path, folder: Path) -> None:
    """BadInput unless files can be made in ``folder`` (or, where it does not exist yet, in the
    nearest folder above it that does): a read-only --out is found before any work."""
    where = _nearest_existing(folder)
    if where.is_dir() and not os.access(where, os.W_OK | os.X_OK):
        raise BadInput(f"--out {out}: {where} is not writable (permissions or a read-only file system); "
                       "choose another folder")


def check_output_dir(out: str | Path) -> Path:
    """Raise :class:`BadInput` unless ``out`` can be an output folder (it is one, or it and the
    folders above it can be created, and files can be written there and beside it, where the
    outputs are assembled). Commands call this before they compute."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise BadInput(f"--out {out}: is a file; expected a folder to write into")
    blocker = _blocking_file(out)
    if blocker is not None:
        raise BadInput(f"--out {out}: {blocker} is a file, so no folder can be made under it")
    _check_writable(out, out.parent if str(out.parent) else Path("."))
    if out.is_dir():
        _check_writable(out, out)
    return out


def check_output_file(path: str | Path) -> Path:
    """Raise :class:`BadInput` unless ``path`` can be written as a file (it is not a folder and
    no file stands where one of its folders should be). Commands call this before they compute."""
    path = Path(path)
    if path.is_dir():
        raise BadInput(f"--out {path}: is a folder; expected a file name to write")
    blocker = _blocking_file(path)
    if blocker is not None:
        raise BadInput(f"--out {path}: {blocker} is a file, so no folder can be made under it")
    _check_writable(path, path.parent if str(path.parent) else Path("."))
    return path


@contextlib.contextmanager
def atomic_output_dir(out: str | Path):
    """Yield a temporary directory; on success its files are moved into ``out`` (created if
    needed), replacing files of the same name. On an exception nothing in ``out`` changes.
    Raises :class:`BadInput` at once if ``out`` is a file (see :func:`check_output_dir`)."""
    out = check_output_dir(out)
    parent = out.parent if str(out.parent) else Path(".")
    parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=parent))
    try:
        yield tmp
        out.mkdir(parents=True, exist_ok=True)
        for item in sorted(tmp.rglob("*")):
            rel = item.relative_to(tmp)
            target = out / rel
            if item.is_dir():
                target.mkdir(parents=True, exist_ok=True)
            else:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.replace(item, target)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def atomic_write_text(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and an atomic rename. The file gets
    the permissions a plain ``open`` would give it (mkstemp's are owner-only)."""
    path = check_output_file(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
