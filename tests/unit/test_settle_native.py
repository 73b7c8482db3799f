"""The approach fits' compiled sums (platkit.settle._native) against numpy's, and the numpy path
without a compiler or with PLATKIT_COMPILE=0."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from native_cache import native_cache_fixtures

from platkit.settle import _native, load_poses
from platkit.settle._fits import fit_approaches
from tests.unit.test_settle import RATE, SIGMA

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "sessions" / "stewart"

module_cache, cache, empty_cache = native_cache_fixtures(_native, "settle_cache")


def _stretches(n_markers: int, seed: int) -> list[tuple]:
    """Stretches of different lengths, decays and noise: with and without occluded samples, with
    a jittered clock and a gap, a marker seen too little, one with its time constant given."""
    rng = np.random.default_rng(seed)
    out = []
    for j in range(10):
        K = int(rng.integers(40, 500))
        t = 3.0 + np.arange(K) / RATE
        if j == 3:
            t = t + rng.normal(size=K) * 1e-4  # a jittered clock: exp of every sample
        if j == 4:
            t[K // 2:] += 0.2  # a gap of twenty samples
        tau = float(rng.uniform(0.05, 1.0))
        s = t - t[0]
        amp = rng.normal(size=(n_markers, 3)) * 1e-3 * (j % 3)  # every third without a decay
        X = 0.1 * rng.normal(size=(1, n_markers, 3)) + amp[None] * ((1 + 2 * s / tau) * np.exp(-s / tau))[:, None, None]
        X = X + rng.normal(size=X.shape) * SIGMA
        if j % 2:
            X[rng.random((K, n_markers)) < 0.1] = np.nan
        if j == 5:
            X[5:, 1] = np.nan  # a marker seen for five samples only
        out.append((t, X, SIGMA, t[-1] + 0.05, 0.3 if j == 7 else None))
    return out


def _assert_same_fits(compiled, python):
    for f, g in zip(compiled, python):
        assert (f is None) == (g is None)
        if f is None:
            continue
        assert f.tau == pytest.approx(g.tau, rel=1e-12)  # the same grid point
        assert f.significant == g.significant and f.at_limit == g.at_limit
        np.testing.assert_array_equal(np.isfinite(f.x_inf), np.isfinite(g.x_inf))
        np.testing.assert_allclose(f.x_inf, g.x_inf, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.a, g.a, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f.b, g.b, rtol=0, atol=1e-12)
        assert f.chi2_per_dof == pytest.approx(g.chi2_per_dof, rel=1e-6)
        np.testing.assert_allclose(f.x_inf_std, g.x_inf_std, rtol=1e-6)
        np.testing.assert_allclose(f.cov_ab, g.cov_ab, rtol=1e-6, atol=1e-30)
        np.testing.assert_allclose(f.remaining_m, g.remaining_m, rtol=1e-6, atol=1e-12)
        assert f.t0 == g.t0


@pytest.mark.parametrize("n_markers", [4, 7])  # 12 and 21 columns: one and two groups of the kernel's 16
def test_the_compiled_fits_are_numpys(cache, n_markers):
    assert _native.compiled_fits_reason() == ""
    stretches = _stretches(n_markers, 2800 + n_markers)
    compiled = fit_approaches(stretches)
    python = fit_approaches(stretches, compiled=False)
    assert compiled[7].tau == 0.3 and {f.significant for f in compiled} == {True, False}
    assert np.isnan(compiled[5].x_inf[1]).all()
    _assert_same_fits(compiled, python)
    assert any(cache.glob("settle_fits_*.so")), "the kernel is kept in the cache folder"


def test_the_settled_poses_of_a_session_are_the_same_on_both_paths(cache, monkeypatch):
    compiled = load_poses(EXAMPLE)
    assert _native.compiled_fits_reason() == ""
    monkeypatch.setattr(_native, "_loaded", {"fn": "switched off by the test"})
    python = load_poses(EXAMPLE)
    np.testing.assert_array_equal(compiled.markers, python.markers)
    np.testing.assert_array_equal(compiled.n_samples, python.n_samples)
    assert compiled.dropped == python.dropped
    np.testing.assert_allclose(compiled.extras["approach_tau_s"], python.extras["approach_tau_s"], rtol=1e-12)


def test_without_a_compiler_numpy_fits(empty_cache, monkeypatch):
    monkeypatch.setattr(_native, "_compiler", lambda: None)
    stretches = _stretches(4, 11)
    fits = fit_approaches(stretches)
    assert "no C compiler" in _native.compiled_fits_reason()
    _assert_same_fits(fits, fit_approaches(stretches, compiled=False))
    assert not any(empty_cache.iterdir()), "nothing is written without a compiler"


def test_platkit_compile_0_keeps_numpy(empty_cache, monkeypatch):
    monkeypatch.setenv("PLATKIT_COMPILE", "0")
    fits = fit_approaches(_stretches(4, 12)[:3])
    assert all(f is not None for f in fits)
    assert "PLATKIT_COMPILE=0" in _native.compiled_fits_reason() and not any(empty_cache.iterdir())


def test_the_compiler_is_there_for_the_compiled_path():
    # CI and the development machines have a C compiler: its absence is a failure here, not a
    # skip (the path without one is tested above with the compiler patched away)
    assert _native._compiler() is not None, "no C compiler (cc, gcc or clang) to test the compiled path"


def _view(X: np.ndarray) -> np.ndarray:
    """X (K, M, 3) as a view of a wider table (a time column first), as a session's stream is."""
    table = np.empty((X.shape[0], 1 + X[0].size))
    table[:, 1:] = X.reshape(len(X), -1)
    view = table[:, 1:].reshape(X.shape)
    assert not view.flags["C_CONTIGUOUS"] and np.shares_memory(view, table)
    return view


def test_the_compiled_still_test_halves_are_numpys_bit_for_bit(cache):
    # the still test decides the windows: its halves must be numpy's numbers, not close to them
    from platkit.settle._still import _halves, _window_sums

    rng = np.random.default_rng(2803)
    X = _view(rng.normal(size=(900, 5, 3)))
    X[rng.random((900, 5)) < 0.05] = np.nan
    X[100:200, 2] = np.nan  # a marker occluded for a while
    for n in (1, 5, 40, 2000):
        for stretch in (X, X[:57], X[:1]):
            got = _halves(stretch, n)
            want = _halves(stretch, n, _window_sums(X), compiled=False)
            for a, b in zip(got, want):
                assert a.shape == b.shape
                assert np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))
    assert _native.halves(X, 5) is not None


@pytest.mark.parametrize("n_markers", [5, 9, 50])  # numpy's sums: sequential below 8, pairwise above, in blocks past 128
def test_the_compiled_still_test_is_numpys_bit_for_bit(cache, n_markers):
    from platkit.settle._still import _halves, approach_start, still_mask

    rng = np.random.default_rng(2804 + n_markers)
    X = np.cumsum(rng.normal(size=(500, n_markers, 3)) * 1e-4, axis=0) + rng.normal(size=(1, n_markers, 3))
    X[rng.random((500, n_markers)) < 0.05] = np.nan
    X[100:150, 0] = np.nan
    X = _view(X) if n_markers == 5 else X
    sigma = 2.3e-4
    for n in (2, 10, 60, 1000):
        for stretch in (X, X[:33], X[:1], X[:0]):
            stat, num, m = _native.still_statistics(stretch, n, sigma**2)
            mb, ma, nb, na = _halves(stretch, n, compiled=False)
            vis = (nb > 0) & (na > 0)
            z2 = np.where(vis, np.sum((ma - mb) ** 2, axis=2) / (sigma**2 * (1.0 / np.maximum(nb, 1)
                                                                            + 1.0 / np.maximum(na, 1))), 0.0)
            np.testing.assert_array_equal(m, vis.sum(axis=1))
            np.testing.assert_array_equal(stat, z2.sum(axis=1) / np.maximum(m, 1))
            np.testing.assert_array_equal(num, np.sum(np.where(vis[..., None], ma - mb, 0.0) ** 2, axis=(1, 2)))
            np.testing.assert_array_equal(still_mask(stretch, n, sigma, 1e-3),
                                          still_mask(stretch, n, sigma, 1e-3, compiled=False))
            assert approach_start(stretch, n, sigma) == approach_start(stretch, n, sigma, compiled=False)


def test_the_compiled_trend_test_is_numpys_to_rounding(cache):
    from platkit.settle._still import trend_test

    rng = np.random.default_rng(2805)
    for n_markers in (1, 5, 9):
        for K in (3, 5, 40, 700):
            for speed in (0.0, 1e-4, 1e-2):
                t = 10 + np.arange(K) / 200.0
                X = rng.normal(size=(K, n_markers, 3)) * 1e-4 + speed * t[:, None, None]
                X[rng.random((K, n_markers)) < 0.1] = np.nan
                X = _view(X) if K % 2 else X
                (p, v), (p0, v0) = trend_test(t, X, 1e-4), trend_test(t, X, 1e-4, compiled=False)
                assert p == pytest.approx(p0, rel=1e-9, abs=1e-300) and v == pytest.approx(v0, rel=1e-9, abs=1e-300)
                assert (speed >= 1e-2 and K >= 40) <= (p0 < 1e-6)  # the test sees a clear trend


def test_the_compiled_noise_estimate_is_numpys_bit_for_bit(cache):
    from platkit.settle._still import estimate_noise

    rng = np.random.default_rng(2806)
    for K in (2, 3, 7, 12, 1001, 30000):  # under 10 differences, a few, and enough for the sampled medians
        for occluded in (0.0, 0.1, 0.95):
            X = rng.normal(size=(K, 5, 3)) * 1e-3
            X[rng.random((K, 5)) < occluded] = np.nan
            for stream in (X, np.round(X, 5), _view(X)):  # quantised: many ties
                assert estimate_noise(stream) == estimate_noise(stream, compiled=False)
    assert _native.second_difference_mad(X)[1] > 0
