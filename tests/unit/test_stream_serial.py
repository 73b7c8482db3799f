"""The paired test over a stream's windowed poses holds its level where neighbouring windows'
errors are correlated (platkit.diagnose.stats.serial_signed_rank), and keeps a plain improvement.

The null: paired differences that are an AR(1) process in time order (rho 0.3 from pose to pose,
three poses to a window, 11 windows: a held-out stream of about 10 s), 2000 draws from a fixed
seed. The Wilcoxon signed-rank test over independent poses rejects it about four times as often
as its level; given the windows, the test rejects it at about its level.
"""
from __future__ import annotations

import numpy as np
import pytest

from platkit.diagnose.stats import paired_improvement
from platkit.diagnose.stream import windows_of
from platkit.poses import PoseSet

NODES_PER_WINDOW, N_WINDOWS, DRAWS = 3, 11, 2000


def _ar1(rng: np.random.Generator, n: int, rho: float) -> np.ndarray:
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0] / np.sqrt(1.0 - rho**2)
    for i in range(1, n):
        x[i] = rho * x[i - 1] + e[i]
    return x


@pytest.fixture(scope="module")
def null_p():
    """(DRAWS, 2) p-values of the AR(1) null: as independent poses, and given the windows."""
    rng = np.random.default_rng(0)
    n = NODES_PER_WINDOW * N_WINDOWS
    windows = np.arange(n) // NODES_PER_WINDOW
    out = []
    for _ in range(DRAWS):
        d = _ar1(rng, n, 0.3)
        zero = np.zeros(n)
        out.append((paired_improvement(d, zero), paired_improvement(d, zero, windows)))
    return np.array(out)


def test_an_ar1_null_is_rejected_too_often_as_independent_poses(null_p):
    assert np.mean(null_p[:, 0] < 0.01) > 0.03  # 0.046 on this seed
    assert np.mean(null_p[:, 0] < 0.05) > 0.09  # 0.116


def test_an_ar1_null_is_rejected_at_its_level_given_the_windows(null_p):
    assert np.mean(null_p[:, 1] < 0.01) < 0.015  # 0.008 on this seed
    assert 0.03 < np.mean(null_p[:, 1] < 0.05) < 0.075  # 0.063


def test_a_stream_better_at_every_pose_stays_significant():
    """A held-out stream predicted better at all its 33 windowed poses, by an amount that varies
    smoothly along it (the signed ranks are then autocorrelated although every sign is the same):
    as strong as 11 independent windows all better (Wilcoxon on 11 means: 4.9e-4)."""
    n = NODES_PER_WINDOW * N_WINDOWS
    t = np.linspace(0.0, 1.0, n)
    before = (0.3 + 1.2 * np.sin(np.pi * t)) ** 2
    after = 0.1 * before
    p = paired_improvement(before, after, np.arange(n) // NODES_PER_WINDOW)
    assert p < 1e-3


def test_too_few_windows_prove_nothing():
    d = np.arange(1.0, 13.0)
    assert paired_improvement(d, np.zeros_like(d), np.arange(12) // 3) == 1.0  # 4 windows
    assert paired_improvement(d, np.zeros_like(d)) < 0.001  # as 12 independent poses


def test_windowed_poses_are_numbered_by_their_window():
    poses = PoseSet(platform="stewart", controls=np.zeros((9, 6)), markers=np.zeros((9, 1, 3)), marker_names=["m"],
                    extras={"node": np.arange(9)})
    assert windows_of(poses).tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
