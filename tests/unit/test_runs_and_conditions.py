"""The normal equations summed by runs of points (solve._gram_by_runs) and the leave-one-pose-out
errors' test of near-singular systems (selection._ill_conditioned)."""
import numpy as np

from platkit.calibrate import selection, solve
from platkit.calibrate.problem import FitState


def _two_hands(rng, N=50, shared=30, own=60):
    # a tree's Jacobian: 6 markers, 3 on each hand; the trunk's columns move every marker, each
    # arm's only its hand's (a few held columns and a marker's own offsets beside)
    n = shared + 2 * own + 6
    J = np.zeros((N, 6, 3, n))
    J[..., :shared] = rng.normal(size=(N, 6, 3, shared))
    for h in range(2):
        J[:, 3 * h:3 * h + 3, :, shared + h * own:shared + (h + 1) * own] = rng.normal(size=(N, 3, 3, own))
    for p in range(6):
        J[:, p, :, shared + 2 * own + p] = rng.normal(size=(N, 3))
    return J


def test_normal_equations_by_runs_equal_the_whole_product():
    rng = np.random.default_rng(11)
    J = _two_hands(rng)
    N, P, _, n = J.shape
    r = rng.normal(size=(N, P, 3))
    r[4, 1] = np.nan  # an unseen marker: its rows weigh nothing
    weights = rng.uniform(0.5, 1.5, (N, P))
    active = np.ones(n, bool)
    active[[2, 40, 100, n - 1]] = False
    state = FitState(r, J, np.ones(N, bool))
    assert solve._gram_by_runs(state, weights, active) is not None
    rw0, Jw = solve._weighted(state, weights, active)
    rw, H, g = solve._normal_equations(state, weights, active)
    np.testing.assert_array_equal(rw, rw0)
    np.testing.assert_allclose(H, Jw.T @ Jw, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(g, Jw.T @ rw0, rtol=0, atol=1e-12 * np.abs(g).max())
    # every unknown moving every point, or too few unknowns: the whole product
    dense = FitState(r, rng.normal(size=J.shape), np.ones(N, bool))
    assert solve._gram_by_runs(dense, weights, active) is None
    few = np.zeros(n, bool)
    few[:solve.GRAM_BY_RUNS_FROM - 1] = True
    assert solve._gram_by_runs(state, weights, few) is None


def _with_condition(rng, m, cond):
    U, _ = np.linalg.qr(rng.normal(size=(m, m)))
    V, _ = np.linalg.qr(rng.normal(size=(m, m)))
    return (U * np.geomspace(1.0, 1.0 / cond, m)) @ V.T


def test_ill_conditioned_decides_as_singular_values_do():
    rng = np.random.default_rng(12)
    L = selection.WOODBURY_COND
    # near the limit on both sides (the Frobenius bound is above it for all of these), far inside,
    # far beyond
    X = np.stack([_with_condition(rng, 18, c) for c in (0.9 * L, 0.99 * L, 1.01 * L, 1.1 * L, 10.0, 1e14)])
    expected = np.linalg.cond(X) > L
    np.testing.assert_array_equal(selection._ill_conditioned(X), expected)
    assert expected.tolist() == [False, False, True, True, False, True]
    # an exactly singular matrix in the stack (no inverse of the stack): all by singular values
    Y = np.concatenate([X[:-1], np.zeros((1, 18, 18))])
    np.testing.assert_array_equal(selection._ill_conditioned(Y), np.linalg.cond(Y) > L)
