"""JSON that every reader accepts: no NaN or Infinity (Python's json writes them, strict parsers
such as jq and JavaScript's JSON.parse refuse them). A number that is not finite is written as
null: an unbounded stroke, a held-out error that could not be computed."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def plain(obj: Any, finite_only: bool = False) -> Any:
    """``obj`` with numpy values made Python ones, recursively through dicts (keys made str),
    lists and tuples; paths made str. With ``finite_only`` a non-finite float becomes None.
    What YAML and JSON writers are given."""
    if isinstance(obj, dict):
        return {str(k): plain(v, finite_only) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v, finite_only) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist(), finite_only)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) or not finite_only else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def strict(obj: Any) -> Any:
    """:func:`plain` with non-finite floats made None: what strict JSON readers accept."""
    return plain(obj, finite_only=True)


def dumps(obj: Any, **kwargs) -> str:
    """``json.dumps`` of :func:`strict` ``(obj)``; raises rather than write NaN or Infinity."""
    return json.dumps(strict(obj), allow_nan=False, **kwargs)
