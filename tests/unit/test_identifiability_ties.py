"""Identifiability's ties: which parameter of an exact gauge is held follows the columns' order,
never the rounding of their sums."""
from __future__ import annotations

import numpy as np

from platkit.calibrate.identifiability import select_identifiable

NAMES = ["a", "b", "c", "d", "e", "f", "g"]


def _gauged() -> np.ndarray:
    """(60, 7): random columns, c the largest, g equal to c (an exact gauge: c - g changes nothing),
    f a sum of a and b (a second gauge: f, the largest of the three, is taken first, and then a and
    b keep equal remainders, a tie again)."""
    rng = np.random.default_rng(7)
    J = rng.normal(size=(60, 7))
    J[:, 2] *= 3.0
    J[:, 6] = J[:, 2]
    J[:, 5] = J[:, 0] + J[:, 1]
    return J


def _held(J: np.ndarray, scale: np.ndarray) -> list[str]:
    return sorted(h.name for h in select_identifiable(J, NAMES, scale, [0] * 7).held)


def test_the_held_parameter_of_an_exact_gauge_does_not_follow_rounding():
    J = _gauged()
    ones = np.ones(7)
    seen = {}
    for which in (2, 6):  # either column of the gauge one rounding larger than the other
        scale = ones.copy()
        scale[which] *= 1 + 1e-15
        seen[f"scale {which}"] = _held(J, scale)
    rng = np.random.default_rng(1)
    for k in range(3):  # the same rows in another order: another QR, other last bits
        seen[f"rows {k}"] = _held(J[rng.permutation(len(J))], ones)
    seen["columns summed otherwise"] = _held(J * (1 + 1e-15 * rng.standard_normal(J.shape)), ones)
    assert set(map(tuple, seen.values())) == {("b", "g")}, seen  # b the smallest of its gauge; g equal to c and after it


def test_a_difference_the_data_make_is_no_tie():
    J = _gauged()
    J[:, 6] *= 1 + 1e-6  # g larger than c by far more than rounding: g is taken, c held
    held = _held(J, np.ones(7))
    assert "c" in held and "g" not in held
