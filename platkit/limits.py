"""One policy for a control reading at or past a limit of its stroke, the same in every verb that
reads controls a person gives (a session's commands and poses, predict's commands, fk's --u,
simulate's commands, the kinematic model's checks).

- Inside the stroke (with a rounding slack of 1e-9 of the limit): accepted, nothing said.
- Past a limit by at most RECORDING_TOLERANCE of the stroke (a torso reading 0.350181 m against
  0.35 m: encoder noise, a soft limit): kept as recorded, with one warning per control naming the
  furthest value, the limit and how far past it is, in the control's unit.
- Further out: refused, one line naming the value, the stroke and how far past it is. Only when
  the value is further out than the stroke is long (no reading is) and would fit the stroke in
  the other length unit does the line say so (a file in mm declared m, or the reverse).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from platkit.errors import PlatkitError
from platkit.model import LENGTH_UNITS, PlatformSpec

#: a recorded control this fraction of its stroke past a limit is a reading, kept with a warning
RECORDING_TOLERANCE = 0.01
#: past a limit by this fraction of it (at least 1e-9 of the control's unit): rounding, nothing said
ROUNDING = 1e-9


def _fmt(v: float) -> str:
    return f"{v:.6g}"


def check_strokes(spec: PlatformSpec, U_si: np.ndarray, U_shown: np.ndarray, length_unit: str,
                  where: Callable[[int, str], str], error: type[PlatkitError], declared: str,
                  warn: Callable[[str], None]) -> np.ndarray:
    """Check controls ``U_si`` (N, n_u) (internal units; ``U_shown``: the same as the person
    wrote them, 'm' controls in ``length_unit``) against the strokes under the module's policy.

    ``where(row, control)`` names the place ("file row 3 (line 4) column 'L1'"); ``error`` is the
    class refused with; ``declared`` says who set the length unit ("session.yaml declares mm");
    ``warn`` receives each warning. Returns ``U_si`` unchanged (values are kept as recorded)."""
    U_si = np.atleast_2d(U_si)
    U_shown = np.atleast_2d(U_shown)
    for j, c in enumerate(spec.controls):
        col = U_si[:, j]
        lo_r = c.lower - ROUNDING * max(1.0, abs(c.lower))
        hi_r = c.upper + ROUNDING * max(1.0, abs(c.upper))
        with np.errstate(invalid="ignore"):
            past = (col < lo_r) | (col > hi_r)
        if not past.any():
            continue
        stroke = c.upper - c.lower
        slack = RECORDING_TOLERANCE * stroke if np.isfinite(stroke) and stroke > 0 else 0.0
        rows = np.nonzero(past)[0]
        beyond = np.maximum(c.lower - col[rows], col[rows] - c.upper)  # how far past (internal unit)
        s_file = LENGTH_UNITS[length_unit] if c.unit == "m" else 1.0
        unit = length_unit if c.unit == "m" else c.unit
        lo, hi = c.lower / s_file, c.upper / s_file
        out = rows[beyond > slack + (hi_r - c.upper)]
        if out.size:
            r = int(out[0])
            v_si = float(col[r])
            limit = c.lower if v_si < c.lower else c.upper
            d = abs(v_si - limit) / s_file
            hint = ""
            if c.unit == "m" and np.isfinite(stroke) and abs(v_si - limit) > stroke:
                for other, s in LENGTH_UNITS.items():
                    if other != length_unit and c.lower <= float(U_shown[r, j]) * s <= c.upper:
                        hint = f"; the value fits the stroke in {other}, but {declared}"
            raise error(
                f"{where(r, c.name)}: {_fmt(float(U_shown[r, j]))} is outside the stroke [{_fmt(lo)}, {_fmt(hi)}] "
                f"{unit}: {d:.3g} {unit} past the limit {_fmt(limit / s_file)}, more than the recording tolerance "
                f"({slack / s_file:.3g} {unit}, {RECORDING_TOLERANCE:.0%} of the stroke){hint}"
            )
        r = int(rows[int(np.argmax(beyond))])
        v_si = float(col[r])
        limit = c.lower if v_si < c.lower else c.upper
        warn(f"{where(r, c.name)}: {float(U_shown[r, j]):.9g} is past the limit {limit / s_file:.9g} {unit} by "
             f"{abs(v_si - limit) / s_file:.3g} {unit}"
             + (f" ({rows.size} rows past a limit, this one the furthest)" if rows.size > 1 else "")
             + f"; kept as recorded: within the recording tolerance ({slack / s_file:.3g} {unit}, "
             f"{RECORDING_TOLERANCE:.0%} of the stroke [{_fmt(lo)}, {_fmt(hi)}] {unit}: encoder noise or a soft limit)")
    return U_si
