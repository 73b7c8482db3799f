"""The points' columns of the normal equations' runs taken from the observation function's structure
(columns_by_structure, FitState.structure, observation.structural_nonzeros), and from the rows the
marker probe's columns are written in."""
from pathlib import Path

import casadi as ca
import numpy as np

from platkit.calibrate import solve
from platkit.calibrate.observation import structural_nonzeros
from platkit.calibrate.point_columns import columns_by_structure, point_columns
from platkit.calibrate.problem import CalibrationProblem, FitState
from platkit.diagnose.probes import marker_probe
from platkit.plugins import get_platform
from platkit.poses import PoseSet


def _two_hands(rng, N=40, shared=30, own=60, terms=6):
    # a tree's Jacobian: 6 markers, 3 on each hand; the trunk's columns move every marker, each
    # arm's only its hand's; after them `terms` columns (a term's), each moving one marker
    n = shared + 2 * own + terms
    J = np.zeros((N, 6, 3, n))
    J[..., :shared] = rng.normal(size=(N, 6, 3, shared))
    for h in range(2):
        J[:, 3 * h:3 * h + 3, :, shared + h * own:shared + (h + 1) * own] = rng.normal(size=(N, 3, 3, own))
    for p in range(terms):
        J[:, p % 6, :, shared + 2 * own + p] = rng.normal(size=(N, 3))
    structure = (J[..., :shared + 2 * own] != 0).any(axis=(0, 2))
    return J, structure


def test_columns_by_structure_are_the_columns_read_off_the_jacobian():
    rng = np.random.default_rng(21)
    J, structure = _two_hands(rng)
    cols = np.flatnonzero(np.arange(J.shape[3]) % 7 != 3)
    got = columns_by_structure(J, cols, structure)
    assert got is not None
    np.testing.assert_array_equal(got, point_columns(J, cols))
    # NaN is a nonzero, as read off J
    J[5, 1, 0, -5] = np.nan
    np.testing.assert_array_equal(columns_by_structure(J, cols, structure), point_columns(J, cols))
    # a structural column zero at the first pose: read J whole
    K = J.copy()
    K[0, 2, :, 4] = 0.0
    assert columns_by_structure(K, cols, structure) is None
    # and zero at every pose: the structure would say more than J, so J is read
    K[:, 2, :, 4] = 0.0
    assert columns_by_structure(K, cols, structure) is None
    # most columns beyond the structure, or none given: J read whole
    assert columns_by_structure(J, cols, structure[:, :20]) is None
    assert columns_by_structure(J, cols, None) is None


def test_normal_equations_by_structure_equal_those_read_off_the_jacobian():
    rng = np.random.default_rng(22)
    J, structure = _two_hands(rng)
    N, P, _, n = J.shape
    r = rng.normal(size=(N, P, 3))
    r[3, 4] = np.nan
    weights = rng.uniform(0.5, 1.5, (N, P))
    active = np.ones(n, bool)
    active[[1, 50, 140, n - 2]] = False
    plain = solve._gram_by_runs(FitState(r, J, np.ones(N, bool)), weights, active)
    known = solve._gram_by_runs(FitState(r, J, np.ones(N, bool), structure), weights, active)
    assert plain is not None and known is not None
    for a, b in zip(plain, known):  # the same runs, the same sums: bit for bit
        np.testing.assert_array_equal(a, b)


def test_structural_nonzeros_and_the_problems_structure():
    x = ca.SX.sym("x", 3)
    e = ca.vertcat(x[0] * x[1], x[2], 0)
    S = structural_nonzeros(ca.jacobian(e, x))
    np.testing.assert_array_equal(S, [[True, True, False], [False, False, True], [False, False, False]])
    # a stand's problem: its Jacobian is zero wherever the structure says so, at every pose
    spec = get_platform("rotary")
    rng = np.random.default_rng(23)
    lo, hi = spec.control_bounds()
    U = rng.uniform(lo, hi, size=(30, spec.n_u))
    poses = PoseSet(spec.name, U, rng.normal(size=(30, 2, 3)), ["a", "b"])
    problem = CalibrationProblem(spec, poses)
    z = problem.initial_registration(spec.nominal_td())
    st = problem.evaluate(z)
    assert st.structure is not None and st.structure.shape == (2, problem.i_m.stop)
    moves = (st.J != 0).any(axis=(0, 2))[:, :problem.i_m.stop]
    assert not (moves & ~st.structure).any()
    # each marker's own coordinates, not the other's
    m0 = problem.i_m.start
    assert st.structure[0, m0:m0 + 3].all() and not st.structure[0, m0 + 3:m0 + 6].any()


def probe_problem(rng: np.random.Generator) -> tuple[CalibrationProblem, np.ndarray]:
    """A two-armed tree's problem with the marker probe (each marker's own controls), 60 random
    poses, and unknowns with the probe's parameters small and nonzero."""
    urdf = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
    mapping = {"R1": "right_tcp", "R2": "right_tcp", "L1": "left_tcp", "L2": "left_tcp", "L3": "left_tcp"}
    spec = get_platform("urdf", urdf, moving_link=mapping)
    lo, hi = spec.control_bounds()
    poses = PoseSet("urdf", rng.uniform(0.8 * lo, 0.8 * hi, (60, spec.n_u)), rng.normal(size=(60, 5, 3)),
                    list(mapping), moving_link=mapping)
    problem = CalibrationProblem(spec, poses, [marker_probe(poses, spec)])
    z = problem.initial_registration(spec.nominal_td())
    z[problem.i_theta] = rng.normal(0, 1e-3, problem.i_theta.stop - problem.i_theta.start)
    return problem, z


def test_the_marker_probes_columns_are_in_the_structure():
    # a tree's probe (each marker's own controls), written row by row: the state's structure covers
    # its columns, so the runs are read without a pass over the whole Jacobian, and are the same
    problem, z = probe_problem(np.random.default_rng(24))
    st = problem.evaluate(z)
    assert st.structure is not None and st.structure.shape == (5, problem.n_z)
    moves = (st.J != 0).any(axis=(0, 2))
    assert not (moves & ~st.structure).any()
    cols = np.flatnonzero(np.arange(problem.n_z) % 5 != 2)
    got = columns_by_structure(st.J, cols, st.structure)
    assert got is not None
    np.testing.assert_array_equal(got, point_columns(st.J, cols))
    # each marker's block of the probe (3 axes x 6 features) moves that marker only
    for m in range(5):
        block = slice(problem.i_theta.start + 18 * m, problem.i_theta.start + 18 * (m + 1))
        assert st.structure[m, block].all() and not np.delete(st.structure, m, axis=0)[:, block].any()
