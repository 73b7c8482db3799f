"""A Jacobian held in parts along the unknowns (FitState.parts): the observation function's columns
as the function wrote them and a model term's beside them, laid out whole only when read whole; the
normal equations and the weighted columns taken from the parts are those of the whole Jacobian."""
import numpy as np

from platkit.calibrate import solve
from platkit.calibrate.point_columns import columns_by_structure, point_columns, take
from platkit.calibrate.problem import FitState
from tests.unit.test_runs_by_structure import probe_problem


def test_take_gathers_the_parts_columns_as_from_the_whole_jacobian():
    rng = np.random.default_rng(31)
    J = rng.normal(size=(7, 5, 3, 40))
    parts = (J[..., :25].copy(), J[..., 25:31].copy(), J[..., 31:].copy())
    for cols in (np.array([0, 3, 24, 25, 30, 31, 39]), np.arange(2, 20), np.arange(26, 30), np.array([], int)):
        for points in (slice(None), slice(1, 4)):
            got, whole = take(parts, cols, points=points), J[:, points][..., cols]
            np.testing.assert_array_equal(got, whole)
            assert got.strides == whole.strides  # laid out alike: the products after it take the same path
    np.testing.assert_array_equal(take(parts, np.array([1, 33]), poses=slice(0, 1)), J[:1][..., [1, 33]])
    structure = (J[..., :36] != 0).any(axis=(0, 2))
    cols = np.arange(0, 40, 3)
    np.testing.assert_array_equal(columns_by_structure(parts, cols, structure), point_columns(J, cols))


def test_a_problem_with_terms_keeps_its_jacobian_in_parts_for_the_normal_equations():
    rng = np.random.default_rng(32)
    problem, z = probe_problem(rng)
    st = problem.evaluate(z)
    assert st.has_jacobian and len(st.parts) == 2
    assert [p.shape[-1] for p in st.parts] == [problem.i_theta.start, problem.n_z - problem.i_theta.start]
    whole = FitState(st.r, np.concatenate(st.parts, axis=-1), st.converged, st.structure)
    weights = rng.uniform(0.5, 1.5, st.r.shape[:2])
    active = np.ones(problem.n_z, bool)
    active[[2, problem.i_theta.start + 4]] = False
    by_parts = solve._gram_by_runs(st, weights, active)
    assert by_parts is not None and len(st.parts) == 2  # the runs' columns came from the parts
    for a, b in zip(by_parts, solve._gram_by_runs(whole, weights, active)):
        np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-13 * np.max(np.abs(b)))
    for every in (active, np.ones(problem.n_z, bool)):  # the weighted columns: a gather, or all of them
        np.testing.assert_array_equal(solve._weighted(st, weights, every, scratch={})[1],
                                      solve._weighted(whole, weights, every, scratch={})[1])
    assert len(st.parts) == 2
    # read whole, it is laid out once: the parts side by side
    np.testing.assert_array_equal(st.J, whole.J)
    assert st.parts[0] is st.J and problem.evaluate(z) is st
