"""The inverse velocity solvers: damped weighted pseudo-inverse with null space, clamping and
rate scaling; the LP solver; the secondary costs' gradients."""
import numpy as np
import pytest

from platkit.chains.solve import (
    Damping,
    Level,
    damped_pinv,
    joint_limit_gradient,
    manipulability,
    mid_range_gradient,
    solve_lp,
    solve_pinv,
)


def _redundant(seed=0, m=3, n=5):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(m, n)), rng.normal(size=m)


def test_full_rank_solution_is_the_minimum_norm_one():
    J, e = _redundant()
    dq, info = solve_pinv(Level(J, e))
    assert np.allclose(J @ dq, e, atol=1e-12)
    assert np.allclose(dq, np.linalg.pinv(J) @ e, atol=1e-12)
    assert info.damping == 0.0 and info.clamped == [] and info.rate_scale == 1.0


def test_damping_grows_near_a_singularity_and_bounds_the_step():
    d = Damping(threshold=0.1, max_damping=0.05, error_scale=None)
    assert d.factor(0.2) == 0.0
    assert 0 < d.factor(0.05) < d.factor(0.01) < d.factor(0.0) == pytest.approx(0.05**2)
    # a Jacobian one step from singular: the undamped step would be 1e6 long
    J = np.diag([1.0, 1e-6])
    e = np.array([0.0, 1.0])
    dq, info = solve_pinv(Level(J, e), damping=d)
    assert info.sigma_min == pytest.approx(1e-6)
    assert np.linalg.norm(dq) < 1e-3
    # the damping fades with the error, so that the last steps are exact
    d2 = Damping(threshold=0.1, max_damping=0.05, error_scale=1e-2)
    assert d2.factor(0.01, error_norm=1e-8) == pytest.approx(1e-6 * d2.factor(0.01, error_norm=1.0))


def test_null_space_secondary_does_not_disturb_the_task():
    J, e = _redundant(1)
    z = np.array([1.0, -2.0, 0.5, 0.3, -1.0])
    dq0, _ = solve_pinv(Level(J, e))
    dq, _ = solve_pinv(Level(J, e), secondary=z)
    assert np.allclose(J @ dq, e, atol=1e-12)
    assert not np.allclose(dq, dq0)
    _, N, _, _ = damped_pinv(J, Damping())
    assert np.allclose(dq - dq0, N @ z, atol=1e-12)


def test_selective_control_leaves_unselected_components_free():
    J, e = _redundant(2, m=6, n=6)
    w = np.array([1, 1, 1, 0, 0, 0.0])
    dq, _ = solve_pinv(Level(J, e, w))
    assert np.allclose((J @ dq)[:3], e[:3], atol=1e-12)
    assert not np.allclose((J @ dq)[3:], e[3:], atol=1e-3)
    assert np.allclose(dq, np.linalg.pinv(J[:3]) @ e[:3], atol=1e-12)


def test_task_weights_trade_components_within_a_level():
    J = np.array([[1.0], [1.0]])
    e = np.array([1.0, 0.0])
    dq_equal, _ = solve_pinv(Level(J, e, np.array([1.0, 1.0])))
    dq_heavy, _ = solve_pinv(Level(J, e, np.array([9.0, 1.0])))
    assert dq_equal[0] == pytest.approx(0.5)
    assert dq_heavy[0] == pytest.approx(0.9)


def test_priorities_keep_the_first_level_exact():
    rng = np.random.default_rng(3)
    J1, J2 = rng.normal(size=(2, 4)), rng.normal(size=(3, 4))
    e1, e2 = rng.normal(size=2), rng.normal(size=3)
    dq, _ = solve_pinv([Level(J1, e1), Level(J2, e2)])
    assert np.allclose(J1 @ dq, e1, atol=1e-12)
    # the second level gets the best it can in the first one's null space
    N = np.eye(4) - np.linalg.pinv(J1) @ J1
    best = np.linalg.pinv(J1) @ e1 + N @ np.linalg.lstsq(J2 @ N, e2 - J2 @ np.linalg.pinv(J1) @ e1, rcond=None)[0]
    assert np.linalg.norm(J2 @ dq - e2) == pytest.approx(np.linalg.norm(J2 @ best - e2), rel=1e-9)


def test_position_limits_clamp_and_re_solve():
    J, e = _redundant(4)
    free, _ = solve_pinv(Level(J, e))
    i = int(np.argmax(np.abs(free)))
    lower = np.full(5, -np.inf)
    upper = np.full(5, np.inf)
    if free[i] > 0:
        upper[i] = 0.3 * free[i]
    else:
        lower[i] = 0.3 * free[i]
    dq, info = solve_pinv(Level(J, e), lower_step=lower, upper_step=upper)
    assert info.clamped == [i]
    assert dq[i] == pytest.approx(0.3 * free[i])
    assert np.allclose(J @ dq, e, atol=1e-12)  # the other joints made up for it


def test_rate_limits_scale_the_step_without_turning_it():
    J, e = _redundant(5)
    free, _ = solve_pinv(Level(J, e))
    rate = np.full(5, 0.25 * np.max(np.abs(free)))
    dq, info = solve_pinv(Level(J, e), rate_step=rate)
    assert np.max(np.abs(dq)) == pytest.approx(rate[0])
    assert np.allclose(dq, info.rate_scale * free)
    assert info.rate_scale == pytest.approx(0.25)


def test_lp_is_collinear_within_bounds_and_chooses_by_cost():
    J, e = _redundant(6)
    dq, info = solve_lp(J, e)
    assert info.fraction == pytest.approx(1.0)
    assert np.allclose(J @ dq, e, atol=1e-9)
    # tight bounds: a fraction of e, still collinear with it
    rate = np.full(5, 0.05)
    dq, info = solve_lp(J, e, rate_step=rate)
    assert 0 < info.fraction < 1
    assert np.all(np.abs(dq) <= 0.05 + 1e-12)
    assert np.allclose(J @ dq, info.fraction * e, atol=1e-9)
    # two identical joints: the cost picks the cheaper one
    J2 = np.array([[1.0, 1.0]])
    dq, _ = solve_lp(J2, np.array([0.5]), joint_cost=np.array([1.0, 3.0]))
    assert np.allclose(dq, [0.5, 0.0])
    dq, _ = solve_lp(J2, np.array([0.5]), joint_cost=np.array([3.0, 1.0]))
    assert np.allclose(dq, [0.0, 0.5])


def test_lp_falls_back_to_least_residual_when_e_is_out_of_range():
    J = np.array([[1.0, 0.0], [0.0, 0.0]])  # the second component cannot be produced
    dq, info = solve_lp(J, np.array([0.2, 1.0]))
    assert info.fraction == 0.0
    assert dq == pytest.approx([0.2, 0.0])


def test_secondary_gradients_match_finite_differences():
    lower = np.array([-1.0, 0.0, -2.0, -np.inf])
    upper = np.array([1.0, 3.0, 0.5, np.inf])
    theta = np.array([0.4, 2.5, -1.9, 7.0])

    def mid(t):
        span = upper[:3] - lower[:3]
        return 0.5 * np.sum(((t[:3] - 0.5 * (upper[:3] + lower[:3])) / span) ** 2)

    def lim(t):
        span = upper[:3] - lower[:3]
        return np.sum(span**2 / (4 * (upper[:3] - t[:3]) * (t[:3] - lower[:3])))

    for H, grad in ((mid, mid_range_gradient), (lim, joint_limit_gradient)):
        g = grad(theta, lower, upper)
        h = 1e-7
        fd = np.array([(H(theta + h * np.eye(4)[i]) - H(theta - h * np.eye(4)[i])) / (2 * h) for i in range(4)])
        assert np.allclose(g, fd, rtol=1e-5, atol=1e-7)
        assert g[3] == 0.0
    assert manipulability(np.eye(3)) == pytest.approx(1.0)
    assert manipulability(np.diag([1.0, 2.0, 0.0])) == 0.0


# ----------------------------------------------------------------------------- the servo's fast case (issue 13)


@pytest.mark.parametrize("urdf, link, clamps", [("ur_description/urdf/ur5_robot.urdf", "tool0", False),
                                                ("panda_description/urdf/panda.urdf", "panda_hand", True)])
def test_one_world_target_takes_the_same_steps_as_the_general_servo(urdf, link, clamps):
    """One task in the world frame goes through pinocchio's placement and Jacobian and a
    one-level step (Servo._fast_case); the general path (the chain's own Jacobian, solve_pinv)
    must take the same steps: same path, same outcome, limits kept."""
    from reference_robots import example_robot_urdf

    from platkit.chains import KinematicChain, Servo, ServoOptions, Task

    chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
    rng = np.random.default_rng(7)
    theta0 = chain.mid_range()
    clamped = 0
    for _ in range(6):
        target = chain.placement(chain.random(rng), link)
        fast = Servo(chain, [Task(link, target)], ServoOptions())
        assert fast._fast is not None
        general = Servo(chain, [Task(link, target)], ServoOptions())
        general._fast = None
        np.testing.assert_allclose(fast.task_jacobian(theta0, 0), chain.relative_jacobian(theta0, fast.frame_ids[0], 0),
                                   atol=1e-12)
        a, b = fast.run(theta0), general.run(theta0)
        assert a.converged == b.converged and a.iterations == b.iterations
        np.testing.assert_allclose(a.path, b.path, atol=1e-9)
        assert np.all(a.theta >= chain.lower - 1e-12) and np.all(a.theta <= chain.upper + 1e-12)
        clamped += any(len(fast.step(th, fast.errors(th))[1].clamped) > 0 for th in a.path[:-1])
    assert bool(clamped) == clamps  # the panda's limits exercise the fast step's clamping


def test_other_tasks_keep_the_general_servo():
    from reference_robots import example_robot_urdf

    from platkit.chains import KinematicChain, Servo, ServoOptions, Task

    chain = KinematicChain.from_urdf(example_robot_urdf("ur_description/urdf/ur5_robot.urdf"))
    T = chain.placement(chain.mid_range(), "tool0")
    assert Servo(chain, [Task("tool0", T, frame="base_link")])._fast is None
    assert Servo(chain, [Task("tool0", T, basis="local")])._fast is None
    assert Servo(chain, [Task("tool0", T)], ServoOptions(secondary="mid_range"))._fast is None
    assert Servo(chain, [Task("tool0", T)], ServoOptions(solver="lp"))._fast is None
