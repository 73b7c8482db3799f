"""Description files: safe YAML reading and where a stand's default description lives.

YAML is read with ``yaml.safe_load`` only (no tags that construct objects); errors name the file
and, where YAML gives one, the line. A text parsed once is read back from platkit's cache
(platkit/io/cache.py) without importing PyYAML, which every verb that looks up a stand would
otherwise pay at start-up.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from platkit.errors import BadDescription
from platkit.io.cache import cached_yaml, keep_yaml
from platkit.io.shipped import shipped_dir

if TYPE_CHECKING:
    import yaml

DESCRIPTIONS_ENV = "PLATKIT_DESCRIPTIONS"


def load_yaml(path: str | Path, error=BadDescription) -> dict[str, Any]:
    """Read a YAML mapping safely. Raises ``error`` (one line: file, line, problem)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot be read ({exc.__class__.__name__}: {exc})") from None
    data = cached_yaml(text)
    if data is not None:  # this text parsed to this mapping before (and passed the alias check)
        return data
    data = parse_yaml(text, path, error)
    keep_yaml(text, data)
    return data


def dump_yaml(data, **options) -> str:
    """``yaml.safe_dump(data, **options)`` through libyaml's safe dumper where PyYAML has it (the
    same text, a fifth of the time: a 20-joint tree's calibration.yaml, 57 kB, in 35 ms)."""
    import yaml

    return yaml.dump(data, Dumper=getattr(yaml, "CSafeDumper", yaml.SafeDumper), **options)


def parse_yaml(text: str, path: Path, error=BadDescription) -> dict[str, Any]:
    """``text`` (the contents of ``path``) parsed safely; ``error`` (one line) when it is not a
    YAML mapping, its aliases expand too far, or an unquoted date in it names no day."""
    import yaml  # here, not at the top: a cached parse needs no PyYAML

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        if "&" in text:  # anchors: aliases to them may expand exponentially (a "billion laughs")
            check_expansion(yaml.compose(text, Loader=loader), path, error)
        # libyaml's safe loader where PyYAML has it: a stand's description parses in a tenth of
        # the time, which every verb that looks up a stand pays
        data = yaml.load(text, Loader=loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{path}:{where} is not valid YAML ({problem})") from None
    except ValueError as exc:  # PyYAML builds dates itself: 2026-02-30 fails inside the parser
        raise error(invalid_date(text, path, exc)) from None
    if not isinstance(data, dict):
        raise error(f"{path}: expected a YAML mapping at the top level, got {type(data).__name__}")
    return data


def invalid_date(text: str, path: Path, exc: ValueError) -> str:
    """The one line for a YAML text whose date or date-time scalar (YAML reads ``2026-02-30``
    unquoted as one) names no day or time: the file, the scalar's line and its mapping key."""
    import yaml  # here, not at the top: as in parse_yaml, whose error path this is

    def timestamps(node, key):
        if isinstance(node, yaml.MappingNode):
            for k, v in node.value:
                yield from timestamps(v, k.value if isinstance(k, yaml.ScalarNode) else key)
        elif isinstance(node, yaml.SequenceNode):
            for v in node.value:
                yield from timestamps(v, key)
        elif node is not None and node.tag == "tag:yaml.org,2002:timestamp":
            yield node, key

    constructor = yaml.SafeLoader("")
    for node, key in timestamps(yaml.compose(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)), None):
        try:
            constructor.construct_yaml_timestamp(node)
        except ValueError as bad:
            line = node.start_mark.line + 1
            if key is None:
                return f"{path}: line {line}: not a valid date ({node.value!r}: {bad})"
            return f"{path}: field '{key}': not a valid date ({node.value!r} on line {line}: {bad})"
    return f"{path}: not valid YAML ({exc})"


MAX_YAML_NODES = 100_000


def check_expansion(root: yaml.Node | None, path: Path, error=BadDescription) -> None:
    """Refuse a YAML document whose aliases expand to more than MAX_YAML_NODES nodes.

    PyYAML shares an aliased object rather than copying it, so loading is cheap, but anything that
    walks the result (printing notes, writing a report) visits every expansion: nine levels of
    nine-fold aliases is 9^9 nodes from a few hundred bytes. Counted on the composed node graph,
    each node's expanded size once (memoised), so the check itself stays linear in the file.
    """
    import yaml

    sizes: dict[int, int] = {}

    def expanded(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        sizes[key] = MAX_YAML_NODES + 1  # a node reached again while being counted: a cycle
        if isinstance(node, yaml.SequenceNode):
            total = 1 + sum(expanded(child) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            total = 1 + sum(expanded(k) + expanded(v) for k, v in node.value)
        else:
            total = 1
        sizes[key] = total = min(total, MAX_YAML_NODES + 1)
        return total

    if root is not None and expanded(root) > MAX_YAML_NODES:
        raise error(f"{path}: its YAML aliases (*name) expand to more than {MAX_YAML_NODES:,} values; "
                    "write the values out instead")


def default_description(filename: str) -> Path:
    """The shipped description ``filename`` (e.g. ``"stewart.yaml"``), a stand's default.

    Searched in order: the directories of the ``PLATKIT_DESCRIPTIONS`` variable (os.pathsep
    separated), then the descriptions installed with platkit (the repository's top-level
    descriptions/, found through the installed package ``platkit_data.descriptions``).
    """
    searched = [Path(d) for d in os.environ.get(DESCRIPTIONS_ENV, "").split(os.pathsep) if d]
    for folder in searched:
        if (folder / filename).is_file():
            return folder / filename
    searched.append(shipped_dir("descriptions"))
    if (searched[-1] / filename).is_file():
        return searched[-1] / filename
    raise BadDescription(
        f"default description {filename!r} not found (looked in {', '.join(str(d) for d in searched)})"
    )


def check_platform(data: dict, name: str, path: Path) -> None:
    """A description may say which stand it describes (``platform: NAME``); a file written for
    another stand is refused by name, before its fields are read as this stand's."""
    declared = data.get("platform")
    if declared is not None and str(declared) != name:
        raise BadDescription(f"{path}: field 'platform' says this file describes {declared!r}, not the {name} stand")


METADATA_FIELDS = ("platform", "notes", "source")


def check_fields(data: dict, known: tuple[str, ...] | list[str], path: Path, where: str = "") -> None:
    """Refuse a field this description does not read (a typo such as ``ofset:`` would otherwise be
    ignored and the stand built from its default), naming the closest known field.

    ``known``: the fields of this mapping; at the top level (``where`` empty) the metadata fields
    ``platform``, ``notes`` and ``source`` are allowed too.
    """
    allowed = tuple(known) + (METADATA_FIELDS if not where else ())
    unknown = [str(k) for k in data if k not in allowed]
    if not unknown:
        return
    key = unknown[0]
    field = f"{where}.{key}" if where else key
    import difflib  # here: only a refused field needs it

    close = difflib.get_close_matches(key, allowed, n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    others = f" and {len(unknown) - 1} more" if len(unknown) > 1 else ""
    raise BadDescription(f"{path}: unknown field {field!r}{hint}{others}; known here: {', '.join(allowed)}")


def require(data: dict, key: str, path: Path, kind: type | tuple = object, where: str = "") -> Any:
    """``data[key]`` or a BadDescription naming the file and field."""
    field = f"{where}.{key}" if where else key
    if key not in data:
        raise BadDescription(f"{path}: missing field {field!r}")
    value = data[key]
    if kind is not object and not isinstance(value, kind):
        names = kind.__name__ if isinstance(kind, type) else "/".join(k.__name__ for k in kind)
        raise BadDescription(f"{path}: field {field!r} must be {names}, got {type(value).__name__}")
    return value


def number(data: dict, key: str, path: Path, where: str = "") -> float:
    value = require(data, key, path, (int, float), where)
    if isinstance(value, bool) or not np.isfinite(value):
        raise BadDescription(f"{path}: field {where + '.' if where else ''}{key} must be a finite number")
    return float(value)


def vector(data: dict, key: str, path: Path, size: int, where: str = "") -> np.ndarray:
    value = require(data, key, path, list, where)
    field = f"{where}.{key}" if where else key
    if len(value) != size or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise BadDescription(f"{path}: field {field!r} must be a list of {size} numbers")
    arr = np.array(value, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise BadDescription(f"{path}: field {field!r} has a non-finite number")
    return arr
