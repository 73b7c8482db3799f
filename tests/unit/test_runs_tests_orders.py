"""The runs tests of one series in many orders at once (stats.runs_tests), as locate runs them along
every control."""
import numpy as np

from platkit.diagnose.stats import runs_test, runs_tests


def test_runs_tests_are_runs_test_in_each_order():
    rng = np.random.default_rng(24)
    for trial in range(300):
        N = int(rng.integers(2, 50))
        x = rng.normal(size=N)
        if trial % 3 == 0:
            x = np.round(x, 1)  # ties at the median
        if trial % 4 == 0:
            x[rng.random(N) < 0.2] = np.nan
        if trial % 11 == 0:
            x[:] = 2.0  # no run above the median
        orders = np.array([rng.permutation(N) for _ in range(3)])
        z, p = runs_tests(x, orders)
        for k, o in enumerate(orders):
            assert runs_test(x[o]) == (float(z[k]), float(p[k]))
