"""JSON that every reader accepts: no NaN or Infinity (Python's json writes them, strict parsers
such as jq and JavaScript's JSON.parse refuse them). A number that is not finite is written as
null: an unbounded stroke, a held-out error that could not be computed."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np


def strict(obj: Any) -> Any:
    """``obj`` with numpy values made Python ones and non-finite floats made None (recursively
    through dicts, lists and tuples)."""
    if isinstance(obj, dict):
        return {str(k) if not isinstance(k, str) else k: strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return strict(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        value = float(obj)
        return value if math.isfinite(value) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def dumps(obj: Any, **kwargs) -> str:
    """``json.dumps`` of :func:`strict` ``(obj)``; raises rather than write NaN or Infinity."""
    return json.dumps(strict(obj), allow_nan=False, **kwargs)
