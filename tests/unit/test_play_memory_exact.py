"""platkit.play.play_memory walks the stack of turning points over fewer samples (runs of equal
samples once, a monotone stretch's inside skipped) and gives the memory of the walk over every
sample to the bit: the same turning points, the same depth cut and infinite swing, the same L. The
reference is the walk over every sample as it was (f34c969), kept verbatim in tests/play_reference.py."""
from __future__ import annotations

import numpy as np
import pytest
from play_reference import full_walk as _reference
from play_reference import random_column, same_bits

from platkit.play import play_memory


def _case(seed: int) -> tuple[np.ndarray, np.ndarray, int]:
    rng = np.random.default_rng(seed)
    T = int(rng.integers(1, 400))
    x = np.column_stack([random_column(rng, T) for _ in range(int(rng.integers(1, 4)))])
    at = rng.integers(0, T, int(rng.integers(0, 12)))  # any order, repeats
    depth = int(rng.choice([1, 2, 3, 4, 6, 10, 200]))
    return x, at, depth


def test_the_memory_is_the_full_walks_to_the_bit_on_random_sequences():
    cut = 0
    for seed in range(1200):
        x, at, depth = _case(seed)
        want = _reference(x, at, depth)
        assert same_bits(play_memory(x, at, depth), want), f"seed {seed}: depth {depth}, rows {at.tolist()}"
        cut += bool(np.isinf(want[..., 0]).any())
    assert cut > 200  # the depth cut bit in many of them


def test_the_memory_is_the_full_walks_on_a_long_stream_at_small_depths():
    # a stream's smooth positions with a few reversals a sample long, rows every 40 samples
    rng = np.random.default_rng(5)
    t = np.arange(20000) / 250
    x = np.column_stack([np.sin(0.7 * t) + 0.3 * np.sin(2.9 * t) + 0.01 * np.sin(40 * t),
                         np.cos(0.5 * t) * np.exp(-t / 60) + rng.normal(0, 1e-4, len(t))]) + 4.0
    at = np.arange(0, len(t), 40)
    for depth in (1, 2, 3, 5, 32):
        assert same_bits(play_memory(x, at, depth), _reference(x, at, depth)), depth


@pytest.mark.parametrize("special", [np.nan, np.inf, -np.inf, 1e-310, 2.0 ** -401, 2.0 ** 401])
def test_a_column_with_values_whose_signs_may_round_is_walked_in_full(special):
    rng = np.random.default_rng(7)
    x = np.column_stack([np.sin(np.arange(300) * 0.3), np.cos(np.arange(300) * 0.2)])
    x[[50, 51, 120], 0] = special
    at = rng.integers(0, 300, 20)
    for depth in (1, 3, 200):
        assert same_bits(play_memory(x, at, depth), _reference(x, at, depth))


def test_a_column_of_tiny_values_whose_products_underflow_is_walked_in_full():
    # (S[-2] - S[-3]) * (S[-1] - S[-2]) is 0 here though both differences are not
    rng = np.random.default_rng(8)
    x = np.sin(np.arange(300) * 0.3)[:, None] * 1e-300 * rng.choice([1, 1e-8], (300, 1))
    at = rng.integers(0, 300, 20)
    for depth in (1, 3, 200):
        assert same_bits(play_memory(x, at, depth), _reference(x, at, depth))


def test_a_row_outside_the_commands_is_an_error():
    with pytest.raises(IndexError, match="row 5 asked of 5 commands"):
        play_memory(np.zeros((5, 2)), np.array([0, 5]))
