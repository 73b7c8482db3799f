"""The response's kind chosen by what predicts (platkit.calibrate.motion_kind): the second order
kept where the whole fit's BIC is lower and its fit leaves the fast content no worse than the
first order's (but for one noise variance per damping). A Stewart stream of the physical
simulator (second-order drives), cut as benchmarks/diagnose_stream_heldout.py cuts it."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from stream_split import split_stream

from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_kind import fast_content, kind_verdict, known_samples, not_determined, theta_by_name
from platkit.calibrate.response import ResponseModel
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def test_second_order_drives_keep_the_second_order(tmp_path):
    """Seed 5304, clean multisine, second-order drives (damping 1.0-1.3): the first order's misfit
    is smooth in time (a lag's error on a second order is about -tau^2 times the travel's
    acceleration), so the fast content's BIC alone, the dampings charged, preferred the first
    order; the whole fit's BIC prefers the second, its fast content is better too: kept."""
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=5304, motion="multisine", duration_s=30.0, mocap_rate_hz=40.0, noise_mm=0.2,
                           coloured=False)
    write_physical_session(sim, tmp_path / "sim")
    train, _ = split_stream(tmp_path / "sim", tmp_path, 0.7)
    session = load_session(train)
    cal, _ = calibrate_motion(session, session.spec)
    r = cal.motion["response"]
    assert r["kind"] == "second_order", r["choice"]["why"]
    assert r["choice"]["bic"]["second_order"] < r["choice"]["bic"]["first_order"]
    assert r["choice"]["fast_content"]["worse_in_noise_variances"] < 0  # the fast content better too
    zeta = np.array([r["actuators"][c]["damping"]["value"] for c in spec.control_names])
    assert np.all(np.abs(zeta / sim.response.damping - 1) < 0.3)


def test_a_second_order_that_loses_the_fast_content_is_not_kept():
    """Better by the whole fit's BIC but worse in the fast content by more than one noise variance
    per damping added: a smooth misfit bought, the first order kept; within the allowance, or
    better there, the second order kept; without fast content the whole fit's BIC alone."""
    n = 10000
    worse = 7.0  # noise variances, against 6 dampings allowed
    rss1 = 1e-4
    rss2 = rss1 * np.exp(worse / n)
    kept, words, said = kind_verdict(([rss1, rss2], n), 6, (-100.0, -200.0), "second_order")
    assert not kept and said["fast_content"]["worse_in_noise_variances"] == pytest.approx(worse)
    assert "worse by 7 noise variances, 6 allowed" in words
    assert kind_verdict(([rss1, rss1 * np.exp(5.0 / n)], n), 6, (-100.0, -200.0), "second_order")[0]
    assert kind_verdict(([rss1, 0.5 * rss1], n), 6, (-100.0, -200.0), "second_order")[0]
    assert not kind_verdict(([rss1, 0.5 * rss1], n), 6, (-200.0, -100.0), "second_order")[0]
    assert kind_verdict(([0.0, 0.0], 0), 6, (-100.0, -200.0), "second_order")[0]


def test_an_overdamped_second_order_whose_fast_pole_the_samples_miss_is_not_determined():
    """A second order of time constant 15 ms and damping 6.6 (within the damping's bound): its
    fast pole's time constant is 1.1 ms, under a quarter of a 25 ms sample interval: a first order
    of lag 2 zeta tau, said not determined; damping 1.2 at the same time constant is determined."""
    spec = get_platform("stewart")
    rmodel = ResponseModel("second_order", "step", spec.n_u)
    names = list(spec.control_names)

    def cal(zeta):
        theta = theta_by_name(rmodel, names, {"shift_s": 0.03}, {f"tau_s.{c}": 0.015 for c in names},
                              {f"damping.{c}": zeta for c in names})
        return SimpleNamespace(theta=[theta], identifiability={})

    bad = not_determined(rmodel, spec, cal(6.6), 0.025)
    assert sorted(bad) == sorted(names) and "fast pole" in bad[names[0]]
    assert not not_determined(rmodel, spec, cal(1.2), 0.025)


def test_samples_past_the_end_of_a_log_cut_in_motion_do_not_judge_the_kind():
    """A log streamed every 50 ms, cut while moving at 21.45 s, samples at 40 Hz to 21.458 s: a
    sample read by the later lag (-66 ms) past 21.50 s (the last command and one interval) follows
    a command the log does not have, and is left out of the fast content; the same log ended at
    rest (its last commands repeated) leaves every sample in. A second order fitted better at every
    sample but that one (where it reads the command held while the stand moved on) is refused on
    all the samples and kept on the known ones."""
    T = np.round(np.arange(0.5, 21.4501, 0.05), 6)
    U = np.column_stack([np.sin(T), np.cos(0.7 * T)])
    t = np.round(np.arange(20.483135, 21.46, 0.025), 6)  # one window kept as its samples
    lag = np.array([-0.0286, -0.0661])
    known = known_samples(t, T, U, lag)
    assert np.array_equal(known, t + 0.0661 <= 21.5) and known[:-1].all() and not known[-1]
    rest = U.copy()
    rest[-3:] = rest[-4]
    assert known_samples(t, T, rest, lag).all()
    rng = np.random.default_rng(0)
    r1 = 1.1 * rng.normal(0, 2e-4, (len(t), 5, 3))
    r2 = rng.normal(0, 2e-4, (len(t), 5, 3))
    r2[-1] += 4e-3  # 20 noise sigmas at the sample past the log
    win = SimpleNamespace(t=t, blocks=[(0, 0, len(t), None)], nodes=3)
    cals = [SimpleNamespace(fit=SimpleNamespace(residuals_after=r, weights=np.ones(r.shape[:2]))) for r in (r1, r2)]
    bics = (-100.0, -200.0)
    assert not kind_verdict(fast_content(cals, win), 6, bics, "second_order")[0]
    kept, words, said = kind_verdict(fast_content(cals, win, known), 6, bics, "second_order", 1)
    assert kept and said["fast_content"]["samples_past_the_log"] == 1
    assert said["fast_content"]["worse_in_noise_variances"] < 0
