"""Statistics of diagnosis: corrections, runs, whiteness, paired and score tests, location."""
import numpy as np
import pytest

from platkit.diagnose.locate import change_point_test, locate, located
from platkit.diagnose.stats import benjamini_hochberg, bic, holm, ljung_box, paired_improvement, runs_test, score_test
from platkit.plugins import get_platform
from platkit.poses import PoseSet


def test_holm_and_bh_match_hand_computed_values():
    p = np.array([0.01, 0.04, 0.03, 0.005])
    # Holm: sorted 0.005*4, 0.01*3, 0.03*2, 0.04*1, made monotone
    assert np.allclose(holm(p), [0.03, 0.06, 0.06, 0.02])
    # BH: sorted 0.005*4/1, 0.01*4/2, 0.03*4/3, 0.04*4/4, cumulative minimum from the top
    assert np.allclose(benjamini_hochberg(p), [0.02, 0.04, 0.04, 0.02])
    assert holm(np.array([])).size == 0


def test_runs_test_sees_a_smooth_trend_and_not_white_noise():
    rng = np.random.default_rng(1)
    white = rng.normal(size=200)
    assert runs_test(white)[1] > 0.01
    smooth = np.sin(np.linspace(0, 6, 200)) + 0.1 * rng.normal(size=200)
    z, p = runs_test(smooth)
    assert z < -5 and p < 1e-6


def test_ljung_box_flags_autocorrelation():
    rng = np.random.default_rng(2)
    e = rng.normal(size=300)
    ar = np.zeros(300)
    for k in range(1, 300):
        ar[k] = 0.7 * ar[k - 1] + e[k]
    assert ljung_box(e)[1] > 0.01
    assert ljung_box(ar)[1] < 1e-10


def test_paired_improvement_is_one_sided():
    rng = np.random.default_rng(3)
    before = rng.uniform(1, 2, 60)
    assert paired_improvement(before, before * 0.5) < 1e-8
    assert paired_improvement(before * 0.5, before) > 0.99
    assert paired_improvement(before, before + rng.normal(0, 1e-3, 60)) > 0.01


def test_score_test_finds_a_missing_column_and_measures_separability():
    rng = np.random.default_rng(4)
    n = 400
    Jb = rng.normal(size=(n, 5))
    new = rng.normal(size=(n, 1))
    r = 0.5 * new[:, 0] + 0.1 * rng.normal(size=n)
    r -= Jb @ np.linalg.lstsq(Jb, r, rcond=None)[0]  # residual of the fit without the new column
    F, p, sep = score_test(r, Jb, new, n - 5)
    assert p < 1e-20 and sep > 0.9
    # a column inside the base's span is not separable, and is never significant
    inside = Jb @ np.array([[1.0], [2.0], [0.0], [0.0], [1.0]])
    F, p, sep = score_test(r, Jb, inside, n - 5)
    assert sep < 1e-6 and p == 1.0
    assert bic(10.0, 100, 3) < bic(10.0, 100, 4)


def test_change_point_located_in_time():
    rng = np.random.default_rng(5)
    x = rng.normal(0, 1, (60, 3))
    x[37:] += [3.0, 0.0, -2.0]
    k, share, p = change_point_test(x, n_perm=99, rng=rng)
    assert abs(k - 37) <= 2 and p <= 0.02
    k, share, p = change_point_test(rng.normal(0, 1, (60, 3)), n_perm=99, rng=rng)
    assert p > 0.02


def _poses(spec, n, rng):
    lo, hi = spec.control_bounds()
    U = spec.neutral_u() + rng.uniform(-0.2, 0.2, (n, spec.n_u)) * (hi - lo)
    return PoseSet(spec.name, U, np.zeros((n, 3, 3)), ["A", "B", "C"], t=np.arange(n) * 2.0)


def test_locate_finds_nothing_in_white_residuals_and_the_marker_that_stepped():
    spec = get_platform("stewart")
    rng = np.random.default_rng(6)
    poses = _poses(spec, 60, rng)
    r = rng.normal(0, 2e-5, (60, 3, 3))
    assert located(locate(r, poses, spec, n_perm=99), 0.01) == []
    r[30:, 1, :] += 2e-4
    hits = located(locate(r, poses, spec, n_perm=99), 0.01)
    assert hits and all(h.where["marker"] == "B" for h in hits)
    # a smooth error along one control shows as runs along that control
    r = rng.normal(0, 2e-5, (60, 3, 3))
    s = (poses.controls[:, 2] - poses.controls[:, 2].mean()) / np.ptp(poses.controls[:, 2])
    r[:, 0, 2] += 3e-4 * np.cos(3 * np.pi * s)
    hits = located(locate(r, poses, spec, n_perm=99), 0.01)
    assert any(h.where.get("control") == spec.control_names[2] for h in hits)


def test_locate_ignores_rejected_observations():
    spec = get_platform("stewart")
    rng = np.random.default_rng(7)
    poses = _poses(spec, 40, rng)
    r = rng.normal(0, 2e-5, (40, 3, 3))
    r[::2, 2, :] += 5e-3  # every other observation of C is wild, and rejected
    w = np.ones((40, 3))
    w[::2, 2] = 0
    assert located(locate(r, poses, spec, weights=w, n_perm=99), 0.01) == []
    with pytest.raises(Exception):
        locate(r[:, :2], poses, spec, weights=w)
