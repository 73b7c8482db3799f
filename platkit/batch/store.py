"""Which sessions a batch covers, and its output folder: one sub-folder per finished session,
written whole (a temporary sibling renamed into place), so a re-run skips what is done.

    DIR/batch.json               the verb and its options (a re-run must use the same)
    DIR/sessions/<name>/         the single verb's usual outputs, plus task.json (where, how long)
    DIR/failed/<name>.json       why a session failed (removed when a re-run succeeds)

Each record (task.json, failed/<name>.json) holds the task's *fingerprint*: a hash of every file
of the session folder (paths and contents) and of the files its options name, and a hash of the
options it ran with (:func:`fingerprint`). A re-run redoes a session whose fingerprint differs,
and says why.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from platkit.errors import BadInput
from platkit.io.atomic import atomic_write_text, check_output_dir
from platkit.io.jsonout import dumps

__all__ = ["SessionRef", "find_sessions", "match_sessions", "BatchFolder", "natural_key", "fingerprint", "why_redo"]

TASK_RECORD = "task.json"


@dataclass(frozen=True)
class SessionRef:
    """A session folder matched by the pattern: ``name`` is unique in the batch (the path below
    the matches' common folder, '/' written '__'); ``path`` the folder."""

    name: str
    path: Path


def _hash_files(h, root: Path, label: str) -> None:
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    for p in files:
        rel = p.name if p == root else str(p.relative_to(root))
        h.update(f"{label}/{rel}\0".encode())
        with p.open("rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")


def fingerprint(session: str | Path, options: dict, files: dict[str, str] | None = None) -> dict:
    """What a task's result depends on: ``inputs``, a SHA-256 over every file in the session
    folder (relative paths and contents) and over ``files`` ({option: path}, each file or folder
    an option names, such as a description or a calibration); ``options``, a SHA-256 of the
    options as JSON (keys sorted)."""
    h = hashlib.sha256()
    _hash_files(h, Path(session), "session")
    for key, path in sorted((files or {}).items()):
        p = Path(path)
        if p.exists():
            _hash_files(h, p, key)
        else:
            h.update(f"{key}: missing {p}\0".encode())
    o = hashlib.sha256(dumps(options, sort_keys=True).encode()).hexdigest()
    return {"inputs": h.hexdigest(), "options": o}


def why_redo(record: dict | None, now: dict, redo: bool = False) -> str:
    """Why a session must run (a few words), or '' when its ``record`` (task.json) holds a
    result of these inputs and options: 'new', 'failed before', 'its files changed', 'its
    options changed', 'no fingerprint (an older batch)', '--redo'."""
    if record is None:
        return "new"
    if not record.get("ok"):
        return "failed before"
    if redo:
        return "--redo"
    before = record.get("fingerprint")
    if not isinstance(before, dict):
        return "no fingerprint (an older batch)"
    if before.get("inputs") != now["inputs"]:
        return "its files changed"
    if before.get("options") != now["options"]:
        return "its options changed"
    return ""


def natural_key(text: str) -> list:
    """Sort key in which 'month10' follows 'month9'."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def find_sessions(patterns: str | list[str]) -> list[SessionRef]:
    """The session folders matched by ``patterns`` (see :func:`match_sessions`)."""
    return match_sessions(patterns)[0]


def match_sessions(patterns: str | list[str]) -> tuple[list[SessionRef], list[Path]]:
    """The session folders (holding session.yaml) matched by shell-style ``patterns``
    (``fleet/*``, ``lab/**/month*``; a folder itself), in natural order of their names, and the
    matched folders that hold no session.yaml (skipped: the caller says how many). Nothing
    matched is bad input, naming how many folders were skipped."""
    patterns = [patterns] if isinstance(patterns, str) else list(patterns)
    found: list[Path] = []
    skipped: list[Path] = []
    for pattern in patterns:
        matches = sorted(glob.glob(os.path.expanduser(pattern), recursive=True), key=natural_key)
        for m in matches:
            p = Path(m)
            if (p / "session.yaml").is_file():
                found.append(p.resolve())
            elif p.is_dir():
                skipped.append(p)
    unique = list(dict.fromkeys(found))
    if not unique:
        extra = f" ({len(skipped)} matched folders hold no session.yaml)" if skipped else ""
        raise BadInput(f"{', '.join(patterns)}: no session folder (one holding session.yaml) matches{extra}")
    if len(unique) == 1:
        return [SessionRef(unique[0].name, unique[0])], skipped
    common = Path(os.path.commonpath([str(p) for p in unique]))
    refs = [SessionRef(str(p.relative_to(common)).replace(os.sep, "__"), p) for p in unique]
    return sorted(refs, key=lambda r: natural_key(r.name)), skipped


class BatchFolder:
    """The output folder of one batch (see the module docstring). ``verb`` and ``options`` (a
    plain mapping of the verb's options) are recorded in batch.json; a folder that holds a batch
    of another verb or other options is bad input, so results of two settings never mix.
    ``items`` names the sub-folder of the finished tasks (sessions, or draws of a Monte Carlo)."""

    def __init__(self, out: str | Path, verb: str, options: dict, items: str = "sessions"):
        self.out = check_output_dir(out)
        self.sessions = self.out / items
        self.failed = self.out / "failed"
        record = {"verb": verb, "options": options}
        path = self.out / "batch.json"
        if path.is_file():
            try:
                before = json.loads(path.read_text(encoding="utf-8"))
            except (OSError, ValueError) as exc:
                raise BadInput(f"{path}: not a batch record ({exc}); use another --out") from None
            if before != json.loads(dumps(record)):
                raise BadInput(f"{path}: this folder holds a batch {before.get('verb')} with other options "
                               f"({_difference(before.get('options', {}), options)}); use another --out")
        self._record, self._started = record, False

    def start(self) -> None:
        """Create the folder and batch.json (at the first result: bad input found before any work,
        such as an unreachable scheduler, leaves nothing behind)."""
        if self._started:
            return
        self.sessions.mkdir(parents=True, exist_ok=True)
        path = self.out / "batch.json"
        if not path.is_file():
            atomic_write_text(path, dumps(self._record, indent=2) + "\n")
        self._started = True

    def done(self, name: str) -> bool:
        """True when the session's outputs are there (a re-run skips it)."""
        return (self.sessions / name / TASK_RECORD).is_file()

    def write_session(self, name: str, files: dict[str, bytes], record: dict) -> Path:
        """Write the session's files and its task.json into sessions/<name>/ at once: they are
        written into a temporary sibling that is then renamed (the folder appears whole). A
        folder there from before (a session redone) is replaced by the new one in one rename;
        the old one is removed after."""
        self.start()
        target = self.sessions / name
        tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=self.sessions))
        old = None
        try:
            for rel, data in files.items():
                dest = tmp / rel
                if not dest.resolve().is_relative_to(tmp.resolve()):
                    raise BadInput(f"{name}: output name {rel!r} leaves the session folder")
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.write_bytes(data)
            (tmp / TASK_RECORD).write_text(dumps(record, indent=2) + "\n", encoding="utf-8")
            os.chmod(tmp, 0o777 & ~_umask())
            if target.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{name}.old.", dir=self.sessions))
                os.rename(target, old / "x")
            os.rename(tmp, target)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        self.clear_failure(name)
        return target

    def write_failure(self, name: str, record: dict) -> Path:
        self.start()
        path = self.failed / f"{name}.json"
        atomic_write_text(path, dumps(record, indent=2) + "\n")
        return path

    def clear_failure(self, name: str) -> None:
        path = self.failed / f"{name}.json"
        if path.is_file():
            path.unlink()

    def record(self, name: str) -> dict | None:
        """task.json of a finished session, or failed/<name>.json (with ``ok`` false), or None."""
        for path in (self.sessions / name / TASK_RECORD, self.failed / f"{name}.json"):
            if path.is_file():
                return json.loads(path.read_text(encoding="utf-8"))
        return None


def _difference(before: dict, now: dict) -> str:
    keys = sorted(set(before) | set(now))
    diff = [f"{k}: {before.get(k)!r} then, {now.get(k)!r} now" for k in keys if before.get(k) != now.get(k)]
    return "; ".join(diff[:3]) or "the same options in another form"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
