"""A profile reference's response integrated exactly (platkit.calibrate.response, its pieces):
against the response the module computed before (trapezoid_reference or slew_reference on a
2 ms grid from T_0, the response discretised with a first-order hold, scipy.signal.lfilter, read
by linear interpolation) within that grid's own error, and against the same grid 100 times finer
within the finer grid's error: the grid's answer converges on the exact one. First and second
order (under-, critically and over-damped), trapezoids and triangles, moves cut by the next
command, a rest apart from the first command, slewed step references; the cache changes no bit."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from platkit.calibrate.response import ResponseModel, actuator_positions, slew_reference, trapezoid_reference

GRID_S = 2e-3  # the grid the module integrated on before


def _log(seed=3, n=14):
    rng = np.random.default_rng(seed)
    T = 0.7 + np.cumsum(rng.uniform(0.05, 1.2, n))  # holds short enough to cut some moves
    return T, rng.uniform(-0.05, 0.05, n)


def _on_grid(t, T, u, tau, zeta, rate, accel, start, h):
    """The former computation: the reference on a grid of step h from T_0, the response by the
    first-order hold's exact discretisation (lfilter), linearly interpolated at t."""
    s = T[0] + h * np.arange(int(np.ceil((t.max() - T[0]) / h)) + 2)
    r = (slew_reference(s, T, u, rate, start) if accel is None
         else trapezoid_reference(s, T, u, rate, accel, start)) - start
    if zeta is None:
        sys = (np.array([[-1.0 / tau]]), np.array([[1.0 / tau]]), np.array([[1.0]]), np.array([[0.0]]))
    else:
        w = 1.0 / tau
        sys = (np.array([[0.0, 1.0], [-w * w, -2 * zeta * w]]), np.array([[0.0], [w * w]]), np.array([[1.0, 0.0]]),
               np.array([[0.0]]))
    ad, bd, cd, dd, _ = signal.cont2discrete(sys, h, method="foh")
    num, den = signal.ss2tf(ad, bd, cd, dd)
    x = signal.lfilter(num[0], den, r) + start
    return np.interp(t, s, x, left=start)


def _exact(t, T, u, tau, zeta, rate, accel, start, cache=None):
    """The module's response of one actuator (actuator_positions on a one-actuator model)."""
    if accel is None:
        model, theta = ResponseModel("first_order" if zeta is None else "second_order", "step", 1,
                                     rate_limit=True), [0.0, tau] + ([] if zeta is None else [zeta]) + [rate]
    else:
        model = ResponseModel("first_order" if zeta is None else "second_order", "profile", 1)
        theta = [0.0, tau] + ([] if zeta is None else [zeta]) + [rate, accel]
    if accel is None:  # a step reference rests on its first command
        u = u.copy()
        u[0] = start
    return actuator_positions(model, np.array(theta), T, u[:, None], t, start=np.array([start]), cache=cache)[:, 0], u


CASES = [  # tau, zeta, rate, accel (None: slewed), a rest apart from the first command
    (0.05, None, 0.08, 0.3, False),  # trapezoids, some cut
    (0.02, None, 0.02, 0.5, True),
    (0.08, 0.3, 0.06, 0.15, False),  # triangles and trapezoids
    (0.04, 1.0, 0.05, 1.0, True),  # critically damped
    (0.03, 2.5, 0.1, 3.0, False),
    (0.05, None, 0.04, None, False),  # slewed step references
    (0.03, 0.6, 0.04, None, False),
]


@pytest.mark.parametrize("tau, zeta, rate, accel, apart", CASES)
def test_the_grid_converges_on_the_exact_response(tau, zeta, rate, accel, apart):
    T, u = _log()
    start = float(u[0]) + (0.01 if apart else 0.0)
    t = np.sort(np.random.default_rng(5).uniform(T[0] - 0.4, T[-1] + 1.5, 3000))
    got, u = _exact(t, T, u, tau, zeta, rate, accel, start)
    assert np.array_equal(got[t < T[0]], np.full(int((t < T[0]).sum()), start))
    travel = float(np.ptp(np.append(u, start)))
    coarse = np.abs(got - _on_grid(t, T, u, tau, zeta, rate, accel, start, GRID_S)).max()
    fine = np.abs(got - _on_grid(t, T, u, tau, zeta, rate, accel, start, GRID_S / 100)).max()
    # the 2 ms grid's own error: a reference linear over each step and the response interpolated
    # linearly between steps (its curvature over h^2 / 8 each); a slew's kinks cost more
    assert coarse <= 1e-4 * travel, coarse / travel
    assert fine <= 1e-7 * travel, (fine / travel, coarse / travel)  # the grid's error fell as h^2
    assert fine < 1e-3 * coarse or coarse < 1e-12 * travel


def test_cache_changes_nothing_and_bad_parameters_give_nan():
    T, u = _log(seed=8)
    t = np.linspace(T[0] - 0.3, T[-1] + 1.0, 4000)
    cache: dict = {}
    for tau, zeta, rate, accel, _ in CASES * 2:  # the second round reads the cache
        for shift in (0.0, 0.013):
            want, _ = _exact(t - shift, T, u, tau, zeta, rate, accel, float(u[0]))
            got, _ = _exact(t - shift, T, u, tau, zeta, rate, accel, float(u[0]), cache)
            assert np.array_equal(got, want)
    unsorted = np.random.default_rng(2).permutation(t)
    a, _ = _exact(unsorted, T, u, 0.05, 0.7, 0.05, 0.3, float(u[0]))
    b, _ = _exact(t, T, u, 0.05, 0.7, 0.05, 0.3, float(u[0]))
    assert np.array_equal(a[np.argsort(unsorted)], b)
    with np.errstate(invalid="ignore"):
        bad, _ = _exact(t, T, u, 0.05, 0.7, np.nan, 0.3, float(u[0]))
    assert np.isnan(bad[t >= T[0]]).all() and np.array_equal(bad[t < T[0]], np.full(int((t < T[0]).sum()), u[0]))
