"""A profile reference on the fine grid read by runs (platkit.calibrate.response._trapezoid_on_grid):
the same numbers as trapezoid_reference, bit for bit, for moves that end (trapezoids and
triangles), moves cut by the next command, a grid that starts before the first command, a rest
given apart from the first command, and a rate that is not a number."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate.response import (
    FINE_STEP_S,
    _Grid,
    _trapezoid_on_grid,
    trapezoid_reference,
)


def _log(seed=3, n=40):
    rng = np.random.default_rng(seed)
    T = 0.7 + np.cumsum(rng.uniform(0.05, 1.5, n))  # holds short enough to cut some moves
    return T, rng.uniform(-0.05, 0.05, n)


@pytest.mark.parametrize("offset", [0.0, -0.6, 0.25])
def test_runs_give_the_reference_bit_for_bit(offset):
    T, u = _log()
    grid = T[0] + offset + FINE_STEP_S * np.arange(int((T[-1] + 2 - T[0]) / FINE_STEP_S))
    g = _Grid.of(grid, T)
    rng = np.random.default_rng(4)
    for trial in range(30):
        rate, accel = 10 ** rng.uniform(-3, 0), 10 ** rng.uniform(-2, 1.5)  # triangles and trapezoids, cut or not
        start = None if trial % 2 else float(rng.uniform(-0.05, 0.05))
        want = trapezoid_reference(grid, T, u, rate, accel, start, g.seg)
        assert np.array_equal(_trapezoid_on_grid(g, T, u, rate, accel, start), want), (rate, accel, start)
    with np.errstate(invalid="ignore"):
        want = trapezoid_reference(grid, T, u, np.nan, 1.0, None, g.seg)
        assert np.array_equal(_trapezoid_on_grid(g, T, u, np.nan, 1.0, None), want, equal_nan=True)

