"""A Levenberg-Marquardt run that meets no per-step rule within its iterations is judged on its
last WINDOW iterations: converged where the cost left to gain is what a move of SETTLED_SD
standard deviations would gain, and either way the judgement says what still moves and how."""
import numpy as np

from platkit.calibrate import solve
from platkit.calibrate.estimate import calibrate
from platkit.calibrate.problem import FitState
from platkit.effects import with_history
from platkit.plugins import get_platform
from platkit.simulate import simulate


class _Residuals:
    """A problem of two unknowns (x, y) and six residual rows, as the solvers read one."""

    row_block = None
    names = ["x", "y"]

    def __init__(self, r, J):
        self.r, self.J = r, J

    def evaluate(self, z, with_jac=True):
        J = self.J(z).reshape(2, 1, 3, 2) if with_jac else None
        return FitState(self.r(z).reshape(2, 1, 3), J, np.ones(2, bool))

    def prior_rows(self, z):
        return None


def _large_residual(c=0.9):
    """Dennis and Schnabel's large-residual problem (r1 = x + 1, r2 = c x^2 + x - 1, minimum at x = 0
    with both residuals 1), and y - 2: Gauss-Newton converges only linearly in x, at rate c."""
    return _Residuals(lambda z: np.array([z[0] + 1, c * z[0] ** 2 + z[0] - 1, z[1] - 2, 0, 0, 0.0]),
                      lambda z: np.array([[1, 0], [2 * c * z[0] + 1, 0], [0, 1], [0, 0], [0, 0], [0, 0.0]]))


def _rosenbrock():
    return _Residuals(lambda z: np.array([10 * (z[1] - z[0] ** 2), 1 - z[0], 0, 0, 0, 0.0]),
                      lambda z: np.array([[-20 * z[0], 10], [-1, 0], [0, 0], [0, 0], [0, 0], [0, 0.0]]))


def _fit(problem, z0, max_iter):
    return solve.levenberg_marquardt(problem, np.array(z0, float), np.ones(2, bool), np.ones((2, 1)), max_iter=max_iter)


def test_a_slow_tail_whose_misfit_has_settled_is_converged_and_says_what_still_moves():
    problem = _large_residual()
    res = _fit(problem, [0.5, 0.0], 60)
    assert res.iterations == 60 and res.converged  # no per-step rule met: each step still gains 1e-9 of the cost
    w = res.window
    assert w is not None and w.settled
    assert 0 < w.left_sd <= solve.SETTLED_SD and w.fall < 1e-7
    assert w.moving[0].name == "x" and w.moving[0].how == "drift"
    assert abs(res.z[0]) < 1e-3 and abs(res.z[1] - 2) < 1e-12
    assert "misfit converged" in w.sentence(60) and "x " in w.sentence(60)


def test_a_run_still_descending_is_not_converged_and_says_so():
    problem = _rosenbrock()
    res = _fit(problem, [-1.2, 1.0], 10)
    w = res.window
    assert not res.converged and w is not None and not w.settled and w.left_sd > solve.SETTLED_SD
    assert {m.name for m in w.moving} == {"x", "y"}
    assert "still descending" in w.sentence(10)


def test_a_run_that_meets_a_per_step_rule_is_not_judged():
    problem = _rosenbrock()
    res = _fit(problem, [-1.2, 1.0], 60)
    assert res.converged and res.iterations < 60 and res.window is None
    np.testing.assert_allclose(res.z, [1.0, 1.0], atol=1e-8)


def test_steps_that_reverse_are_a_zigzag_and_a_flat_direction_has_a_large_deviation():
    # costs falling geometrically; x steps back and forth, y one way; H nearly singular along x + y
    costs = 1.0 + 1e-9 * 0.9 ** np.arange(11)
    steps = np.array([[(-1) ** k * 1e-3, 1e-4] for k in range(10)])
    H = np.array([[1.0, 1.0], [1.0, 1.0 + 1e-17]])  # pinv would truncate x + y
    w = solve.judge_window(costs, steps, H, 1000, ["x", "y"])
    assert w.settled and [m.name for m in w.moving] == ["x", "y"]
    assert [m.how for m in w.moving] == ["zig-zag", "drift"]
    # the flat direction's deviation is large (about 1e6 of H's scale), not the 0 of a truncated inverse
    assert all(abs(m.path_sd) < 1e-3 for m in w.moving)
    rising = solve.judge_window(1.0 + 1e-3 * np.arange(11)[::-1] ** 2, steps, H, 1000, ["x", "y"])
    assert not rising.settled  # gains that grow over the window leave no tail to extrapolate


def test_calibrate_says_the_judgement_of_a_final_fit_that_ran_out(monkeypatch):
    spec = get_platform("stewart")
    poses = with_history(simulate(spec, seed=5, n_poses=36, raw=False, plan="random").poses, spec)
    monkeypatch.setattr(solve, "WINDOW", 2)
    cal = calibrate(poses, spec, max_iter=2)  # every run stops at its budget, judged on its two iterations
    stop = cal.fit.stop  # the final fit's judgement, carried with the fit
    assert stop is not None and stop.iterations == 2
    assert cal.converged == stop.settled
    assert stop.sentence(cal.iterations) in cal.warnings


def test_the_exit_line_of_a_fit_that_ran_out_points_at_its_judgement(monkeypatch):
    """calibrate's error line (commands.calibrate.fit_failure) of an lsq fit out of iterations
    points at the warning that says what still moves."""
    from platkit.commands.calibrate import fit_failure

    spec = get_platform("stewart")
    poses = with_history(simulate(spec, seed=5, n_poses=36, raw=False, plan="random").poses, spec)
    monkeypatch.setattr(solve, "WINDOW", 2)
    cal = calibrate(poses, spec, max_iter=2)
    cal.converged = False  # as where the judgement found the run still descending
    assert fit_failure(cal).endswith("; what still moves: the warning 'the fit stopped ...' above")
    cal.warnings = [w for w in cal.warnings if not w.startswith("the fit stopped ")]
    assert "what still moves" not in fit_failure(cal)
