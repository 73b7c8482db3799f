"""Work the estimator skips gives the numbers it gave before (issue 24's speed): the forward
kinematics where no term reads them, the last Jacobian of a refit that reads only its solution,
the score test of columns inside the geometry's span, the normal equations' products of zeros."""
import numpy as np

from platkit.calibrate import solve
from platkit.calibrate.estimate import calibrate
from platkit.calibrate.problem import CalibrationProblem, FitState
from platkit.calibrate.solve import levenberg_marquardt
from platkit.diagnose.probes import marker_probe, space_probe, time_probe
from platkit.diagnose.stats import column_basis, score_test
from platkit.effects import with_history
from platkit.plugins import get_platform
from platkit.simulate import simulate


def _session():
    spec = get_platform("stewart")
    poses = with_history(simulate(spec, seed=5, n_poses=36, raw=False, plan="random").poses, spec)
    return spec, poses, calibrate(poses, spec)


def test_terms_that_read_no_kinematics_skip_them_and_give_the_same_rows(monkeypatch):
    spec, poses, cal = _session()
    rng = np.random.default_rng(2)
    probes = [marker_probe(poses), time_probe(poses)]
    assert all(p is not None and not p.uses_kinematics for p in probes)
    z = np.concatenate([cal.fit.z] + [rng.normal(0, 1e-4, len(p.initial)) for p in probes])
    calls = []
    skipping = CalibrationProblem(spec, poses, probes)
    real = skipping.kinematics
    monkeypatch.setattr(skipping, "kinematics", lambda *a, **k: calls.append(1) or real(*a, **k))
    fast = skipping.evaluate(z)
    assert len(calls) == 1  # the stand's own solve at the offset controls only: no probe reads the kinematics
    for p in probes:
        type(p).uses_kinematics = True  # as every term did before: the kinematics computed, unread
    try:
        reading = CalibrationProblem(spec, poses, probes)
        monkeypatch.setattr(reading, "kinematics", lambda *a, **k: calls.append(2) or real(*a, **k))
        slow = reading.evaluate(z)
    finally:
        for p in probes:
            type(p).uses_kinematics = False
    assert calls.count(2) == 2
    np.testing.assert_array_equal(fast.r, slow.r)
    np.testing.assert_array_equal(fast.J, slow.J)
    fk_X = CalibrationProblem(spec, poses).kinematics(cal.td, poses.controls)[1]
    with_space = CalibrationProblem(spec, poses, [space_probe(fk_X)])
    monkeypatch.setattr(with_space, "kinematics", lambda *a, **k: calls.append(3) or real(*a, **k))
    with_space.evaluate(np.concatenate([cal.fit.z, np.zeros(18)]))
    assert calls.count(3) == 2  # the workspace probe reads them


def test_a_refit_without_the_last_jacobian_reaches_the_same_solution():
    spec, poses, cal = _session()
    z0 = cal.fit.z + np.random.default_rng(3).normal(0, 1e-5, len(cal.fit.z)) * cal.fit.active
    weights = np.ones(poses.markers.shape[:2])
    full = levenberg_marquardt(CalibrationProblem(spec, poses), z0, cal.fit.active, weights)
    lean = levenberg_marquardt(CalibrationProblem(spec, poses), z0, cal.fit.active, weights, jacobian_at_end=False)
    assert full.iterations > 1 and full.state.J is not None and lean.state.J is None
    np.testing.assert_array_equal(full.z, lean.z)
    np.testing.assert_array_equal(full.state.r, lean.state.r)
    assert full.cost == lean.cost and full.iterations == lean.iterations


def test_columns_inside_the_span_or_zero_give_no_test_and_no_decomposition():
    rng = np.random.default_rng(4)
    J = rng.normal(size=(60, 5))
    r = rng.normal(size=60)
    basis = column_basis(J)
    assert score_test(r, J, np.zeros((60, 2)), 55, basis=basis) == (0.0, 1.0, 0.0)  # moves no marker
    F, p, sep = score_test(r, J, J[:, :2] @ np.array([[1.0], [2.0]]), 55, basis=basis)
    assert (F, p) == (0.0, 1.0) and sep < 1e-6  # the geometry's own column
    F, p, sep = score_test(r, J, rng.normal(size=(60, 1)), 55, basis=basis)
    assert F > 0 and 0 < p < 1 and sep > 0.5


def test_normal_equations_point_by_point_equal_the_whole_product():
    # a model of 300 unknowns: 30 move every marker (the geometry), 45 each move one marker's rows
    # only (a probe's offsets), as the marker probe's do on a tree
    rng = np.random.default_rng(6)
    N, P, shared, own = 40, 6, 30, 45
    n = shared + P * own
    J = np.zeros((N, P, 3, n))
    J[..., :shared] = rng.normal(size=(N, P, 3, shared))
    for p in range(P):
        J[:, p, :, shared + p * own:shared + (p + 1) * own] = rng.normal(size=(N, 3, own))
    r = rng.normal(size=(N, P, 3))
    r[3, 2] = np.nan  # an unseen marker: its rows weigh nothing
    weights = rng.uniform(0.5, 1.5, (N, P))
    active = np.ones(n, bool)
    active[[0, 40, 299]] = False
    state = FitState(r, J, np.ones(N, bool))
    assert solve._gram_by_point(state, weights, active) is not None
    rw, H, g = solve._normal_equations(state, weights, active)
    rw0, Jw = solve._weighted(state, weights, active)
    np.testing.assert_array_equal(rw, rw0)
    np.testing.assert_allclose(H, Jw.T @ Jw, rtol=0, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(g, Jw.T @ rw0, rtol=0, atol=1e-12 * np.abs(g).max())
    # every unknown moving every point: the whole product, as before
    dense = FitState(r, rng.normal(size=(N, P, 3, n)), np.ones(N, bool))
    assert solve._gram_by_point(dense, weights, active) is None
    _, H, g = solve._normal_equations(dense, weights, active)
    rw0, Jw = solve._weighted(dense, weights, active)
    np.testing.assert_array_equal(H, Jw.T @ Jw)
