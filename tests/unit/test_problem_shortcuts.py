"""Work the estimator skips gives the numbers it gave before (issue 24's speed): the forward
kinematics where no term reads them, the last Jacobian of a refit that reads only its solution,
the score test of columns inside the geometry's span."""
import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.calibrate.problem import CalibrationProblem
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
