"""The calibration problem's fast path: compiled observation functions evaluated CHUNK poses per
call, the implicit-function theorem inside them, the last evaluation reused, and the
Levenberg-Marquardt loop that evaluates Jacobians only where a step is accepted.

Each is checked against an independent computation: central differences of the residuals,
CasADi's interpreter (PLATKIT_COMPILE=0), a direct Gauss-Newton normal-equation build.
"""
from __future__ import annotations

import numpy as np
import pytest

from platkit.calibrate import observation as observation_module
from platkit.calibrate.observation import CHUNK, COMPILE_AFTER, LOOK_AFTER
from platkit.calibrate.problem import CalibrationProblem
from platkit.calibrate.solve import _normal_equations, _weighted, levenberg_marquardt
from platkit.plugins import get_platform
from platkit.simulate import simulate


def _problem(name: str, n: int, seed: int = 3) -> tuple[CalibrationProblem, np.ndarray]:
    spec = get_platform(name)
    sim = simulate(spec, seed=seed, n_poses=n, plan="random", raw=False, n_markers=4)
    pb = CalibrationProblem(spec, sim.poses)
    z = pb.initial_registration(spec.nominal_td())
    z = z + 1e-4 * np.random.default_rng(seed).standard_normal(pb.n_z) * pb.scale / 1e-3
    return pb, z


@pytest.mark.parametrize("name", ["stewart", "rotary"])  # through the Newton solution; closed-form forward
def test_jacobian_matches_central_differences_across_chunks(name):
    n = CHUNK + 37  # a full chunk and a short, padded one
    pb, z = _problem(name, n)
    st = pb.evaluate(z)
    assert st.J.shape == (n, pb.M, 3, pb.n_z) and st.converged.all()
    rng = np.random.default_rng(0)
    for k in rng.choice(pb.n_z, 8, replace=False):
        h = 1e-6 * pb.scale[k] / 1e-3
        zp, zm = z.copy(), z.copy()
        zp[k] += h
        zm[k] -= h
        fd = (pb.evaluate(zp, with_jac=False).r - pb.evaluate(zm, with_jac=False).r) / (2 * h)
        assert np.allclose(st.J[..., k], fd, atol=1e-6 * max(1.0, np.abs(fd).max())), pb.names[k]


def test_compiled_and_interpreted_give_the_same_numbers(monkeypatch, tmp_path):
    monkeypatch.setattr(observation_module, "_BUILT", {})
    monkeypatch.setenv("PLATKIT_CACHE_DIR", str(tmp_path))
    pb, z = _problem("stewart", 70)
    assert pb._fns.native(True) is pb._fns.G  # a few poses: interpreted, nothing compiled
    interpreted = pb.evaluate(z)
    # the compiled path is what large calibrations run on; the machines platkit is tested on carry a
    # C compiler (CI's included), so its absence is a failure here, not a skip (the path without
    # one is the next test's)
    assert observation_module._compiler() is not None, "no C compiler (cc, gcc or clang) to test the compiled path"
    pb._fns._evaluated = {True: COMPILE_AFTER, False: COMPILE_AFTER}  # as after a long session
    pb._last = None
    compiled = pb.evaluate(z)
    assert pb._fns.native(True) is not pb._fns.G and list(tmp_path.glob("observe_*.so"))
    np.testing.assert_allclose(interpreted.r, compiled.r, rtol=0, atol=1e-12)
    np.testing.assert_allclose(interpreted.J, compiled.J, rtol=0, atol=1e-11)
    # a new process finds the library in the cache once LOOK_AFTER poses were evaluated
    monkeypatch.setattr(observation_module, "_BUILT", {})
    pb2 = CalibrationProblem(pb.spec, pb.poses)
    pb2._fns._evaluated = {True: LOOK_AFTER, False: LOOK_AFTER}
    assert pb2._fns.native(True) is not pb2._fns.G
    # PLATKIT_COMPILE=0: the interpreter whatever the count
    monkeypatch.setenv("PLATKIT_COMPILE", "0")
    monkeypatch.setattr(observation_module, "_BUILT", {})
    pb3 = CalibrationProblem(pb.spec, pb.poses)
    pb3._fns._evaluated = {True: COMPILE_AFTER, False: COMPILE_AFTER}
    assert pb3._fns.native(True) is pb3._fns.G


def test_without_a_compiler_the_interpreter_serves_whatever_the_count(monkeypatch, tmp_path):
    monkeypatch.setattr(observation_module, "_BUILT", {})
    monkeypatch.setenv("PLATKIT_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(observation_module, "_compiler", lambda: None)
    pb, z = _problem("stewart", 70)
    interpreted = pb.evaluate(z)
    pb._fns._evaluated = {True: COMPILE_AFTER, False: COMPILE_AFTER}
    pb._last = None
    again = pb.evaluate(z)
    assert pb._fns.native(True) is pb._fns.G and not list(tmp_path.glob("observe_*"))
    np.testing.assert_array_equal(interpreted.r, again.r)
    np.testing.assert_array_equal(interpreted.J, again.J)


def test_last_evaluation_is_reused_only_for_the_same_inputs():
    pb, z = _problem("stewart", 40)
    st = pb.evaluate(z)
    assert pb.evaluate(z) is st and pb.evaluate(z, with_jac=False) is st
    assert pb.evaluate(z + 1e-9) is not st
    res_only = pb.evaluate(z + 2e-9, with_jac=False)
    assert res_only.J is None and pb.evaluate(z + 2e-9).J is not None  # a Jacobian is never skipped
    pb.body_rho = pb.body_rho * 2  # weights of the bodies' channels change the residuals
    assert pb.evaluate(z + 2e-9, with_jac=False) is not res_only


def test_normal_equations_with_prior_rows_equal_the_stacked_system():
    pb, z = _problem("stewart", 60)
    pb.set_ridge(1e-4, z + 1e-3)
    active = np.ones(pb.n_z, bool)
    active[[0, 5, 7]] = False
    st = pb.evaluate(z)
    w = np.random.default_rng(1).uniform(0.2, 1.0, pb.visible.shape)
    rw, Jw = _weighted(st, w, active, pb.prior_rows(z))
    rw2, H, g = _normal_equations(st, w, active, pb.prior_rows(z))
    np.testing.assert_allclose(rw2, rw)
    np.testing.assert_allclose(H, Jw.T @ Jw, rtol=1e-12, atol=1e-12 * np.abs(H).max())
    np.testing.assert_allclose(g, Jw.T @ rw, rtol=1e-12, atol=1e-12 * np.abs(g).max())


def test_levenberg_marquardt_finds_the_registration_again_from_a_perturbed_start():
    spec = get_platform("stewart")
    sim = simulate(spec, seed=5, n_poses=80, plan="random", raw=False, noise_mm=0.0, occlusion=0.0)
    pb = CalibrationProblem(spec, sim.poses)
    z0 = pb.initial_registration(spec.nominal_td())
    active = np.zeros(pb.n_z, bool)
    active[pb.i_w] = active[pb.i_t] = active[pb.i_m] = True
    best = levenberg_marquardt(pb, z0, active, pb.base_weights)
    start = z0.copy()
    start[active] += 2e-3 * np.random.default_rng(2).standard_normal(int(active.sum()))  # 2 mm, 2 mrad
    res = levenberg_marquardt(pb, start, active, pb.base_weights)
    assert res.converged and res.state.r is pb.evaluate(res.z).r  # the last evaluation is the result's
    assert res.cost <= best.cost * (1 + 1e-6)
    np.testing.assert_allclose(res.z, best.z, atol=1e-6)


def test_problems_in_threads_evaluate_apart():
    """The observation maps and the stand's model are shared by the problems of one thread only:
    two threads evaluating the same stand at once get each their own answer."""
    import threading

    pb, z = _problem("stewart", 300)
    expected = pb.evaluate(z)
    out: dict[int, np.ndarray] = {}
    fns: dict[int, object] = {}
    both = threading.Barrier(2)  # alive together: distinct thread idents

    def work(k: int) -> None:
        both.wait()
        own = CalibrationProblem(pb.spec, pb.poses)
        fns[k] = own._fns
        for _ in range(5):
            own._last = None
            out[k] = own.evaluate(z).J

    threads = [threading.Thread(target=work, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 2 and all(f is not pb._fns for f in fns.values()) and fns[0] is not fns[1]
    for J in out.values():
        np.testing.assert_allclose(J, expected.J, rtol=0, atol=1e-12)


def test_the_reused_weighted_jacobian_gives_the_same_normal_equations_bit_for_bit():
    # the Jacobian's weighted columns are written into one array per Levenberg-Marquardt run
    # (solve._weighted_columns), laid out as the plain expression lays them out, so that H = Jw^T Jw
    # takes the same BLAS path: a choice of held parameters between columns that a symmetry makes
    # alike moves with the last bit of H
    from platkit.calibrate.problem import FitState
    from platkit.calibrate.solve import GATHER_BLOCK, _normal_equations, blas_threads

    rng = np.random.default_rng(3)
    for n_poses in (1, 40, GATHER_BLOCK // 15 + 3):  # 15 rows a pose: the last crosses a block of the gather
        J = rng.standard_normal((n_poses, 5, 3, 63))
        r = rng.standard_normal((n_poses, 5, 3))
        r[0, 1] = np.nan  # an unseen marker: weight 0
        weights = rng.random((n_poses, 5))
        state = FitState(r, J, np.ones(n_poses, bool))
        scratch: dict = {}
        for active in (np.ones(63, bool), np.arange(63) % 7 != 3, np.arange(63) == 5):
            for _ in range(2):  # the second call reuses the array
                with blas_threads(1):  # as the fit runs them
                    plain = _normal_equations(state, weights, active)
                    reused = _normal_equations(state, weights, active, scratch=scratch)
                assert all(np.array_equal(a, b) for a, b in zip(plain, reused))
