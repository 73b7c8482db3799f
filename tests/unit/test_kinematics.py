"""Forward/inverse kinematics of the core: both Newton backends, batching, input checks."""
import shutil

import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import BadInput, NoConvergence, OutOfWorkspace, WrongBranch
from platkit.kinematics import PlatformModel

STATES_MM = np.array([
    [4795, 4795, 4795, 3295, 3295, 3295],
    [3300, 3581, 4158, 4521, 3854, 4029],
    [3500, 4795, 4500, 3600, 3800, 4300],
], float)


@pytest.fixture(scope="module")
def spec():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def model(spec):
    return PlatformModel(spec)


@pytest.fixture(scope="module")
def slow_model(spec):
    return PlatformModel(spec, compile=False)


def test_backend_is_compiled_where_a_compiler_exists(model, slow_model):
    if shutil.which("cc") or shutil.which("gcc") or shutil.which("clang"):
        assert model.backend.startswith("compiled C"), model.backend
    else:
        assert model.backend.startswith("casadi+numpy"), model.backend
    assert slow_model.backend.startswith("casadi+numpy")


def test_environment_switch_turns_compilation_off(spec, monkeypatch):
    monkeypatch.setenv("PLATKIT_COMPILE", "0")
    from platkit import native

    monkeypatch.setattr(native, "_native_by_functions", {})
    m = PlatformModel(spec)
    assert "no C compiler" in m.backend
    res = m.forward(STATES_MM[1] / 1000)
    assert res.residual < 1e-10


def test_compiled_and_numpy_backends_agree(model, slow_model):
    rng = np.random.default_rng(3)
    U = rng.uniform(3.4, 4.6, (40, 6))
    a = model.forward_batch(U)
    b = slow_model.forward_batch(U)
    assert a.converged.all() and b.converged.all()
    np.testing.assert_allclose(a.p, b.p, atol=1e-12)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    for u in U[:5]:
        ra, rb = model.forward(u), slow_model.forward(u)
        np.testing.assert_allclose(ra.p, rb.p, atol=1e-12)
        np.testing.assert_allclose(ra.q, rb.q, atol=1e-12)
        assert ra.iterations == rb.iterations


def test_forward_is_polished_to_machine_precision(model):
    for u in STATES_MM / 1000:
        res = model.forward(u)
        assert res.residual < 1e-12
        np.testing.assert_allclose(model.inverse(res.q, res.X), u, atol=1e-12)


def test_batch_matches_single_and_flags_failures(model):
    U = np.vstack([STATES_MM / 1000, [[1.0, 1.0, 1.0, 9.0, 9.0, 9.0]]])
    batch = model.forward_batch(U, strict=False)
    assert batch.converged[:3].all() and not batch.converged[3]
    for i in range(3):
        np.testing.assert_allclose(batch.p[i], model.forward(U[i]).p, atol=1e-13)
    guesses = batch.p.copy()
    guesses[3] = model.spec.neutral_p()
    again = model.forward_batch(U[:3], guess=guesses[:3])
    assert (again.iterations <= 1).all()


def test_no_assembly_raises_no_convergence(model):
    with pytest.raises(NoConvergence, match="did not converge after .* iterations"):
        model.forward([1.0, 1.0, 1.0, 9.0, 9.0, 9.0], strict=False)


def test_mirror_pose_is_refused_and_can_be_asked_for(model):
    u = STATES_MM[1] / 1000
    with pytest.raises(WrongBranch, match=r"mirror pose .* mm"):
        model.forward(u, guess=[0, 0, -3.0, 0, 0, 0])
    res = model.forward(u, guess=[0, 0, -3.0, 0, 0, 0], allow_mirror=True)
    assert not res.on_branch and res.X[2] < 0


def test_wrong_number_of_controls_is_bad_input(model):
    with pytest.raises(BadInput, match="takes 6 controls .*got 5"):
        model.forward([4.0] * 5)
    with pytest.raises(BadInput, match="not a finite number"):
        model.forward([4.0, 4.0, np.nan, 4.0, 4.0, 4.0])
    with pytest.raises(BadInput, match="guess has 6 pose coordinates"):
        model.forward([4.0] * 6, guess=[0, 0, 3])


def test_stroke_messages_are_in_the_users_unit(spec, model):
    with pytest.raises(OutOfWorkspace) as err:
        model.forward([4.9, 4.0, 4.0, 4.0, 4.0, 4.0])
    msg = str(err.value)
    assert "L1: 4900 is outside the stroke [3295, 4795] mm" in msg and "\n" not in msg
    metres = PlatformModel(spec, length_unit="m")
    with pytest.raises(OutOfWorkspace, match=r"L1: 4.9 is outside the stroke \[3.295, 4.795\] m"):
        metres.forward([4.9, 4.0, 4.0, 4.0, 4.0, 4.0])
    with pytest.raises(OutOfWorkspace, match=r"control L3 \(row 1\): 3000 is outside the stroke"):
        model.forward_batch([[4.0] * 6, [4.0, 4.0, 3.0, 4.0, 4.0, 4.0]])


def test_unreachable_pose_for_inverse(model):
    from platkit.geometry import quat_from_rpy

    with pytest.raises(OutOfWorkspace, match=r"stewart: the pose at \(0.0, 0.0, 6000.0\) mm is out of reach: control L1 would be 6515.96 mm"):
        model.inverse(quat_from_rpy(0, 0, 0), [0.0, 0.0, 6.0])
    u = model.inverse(quat_from_rpy(0, 0, 0), [0.0, 0.0, 6.0], strict=False)
    assert np.all(u > 4.795)


def test_gauss_newton_when_the_stand_has_more_equations(spec):
    """A stand with more residual rows than pose coordinates (here every leg twice) solves by
    Gauss-Newton on both backends."""
    from dataclasses import replace

    import casadi as ca

    u, td, q, X = ca.SX.sym("u", 6), ca.SX.sym("td", 42), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    r = spec.residual(u, td, q, X)
    doubled = ca.Function("F", [u, td, q, X], [ca.vertcat(r, 2 * r)], ["u", "td", "q", "X"], ["r"])
    tall = replace(spec, residual=doubled)
    fast, slow = PlatformModel(tall), PlatformModel(tall, compile=False)
    assert fast.n_r == 12
    reference = PlatformModel(spec).forward(STATES_MM[2] / 1000)
    for m in (fast, slow):
        res = m.forward(STATES_MM[2] / 1000)
        np.testing.assert_allclose(res.p, reference.p, atol=1e-11)
        batch = m.forward_batch(STATES_MM / 1000)
        assert batch.converged.all()


def test_forward_with_other_parameters(spec, model, slow_model):
    """Calibrated parameters go through the same compiled solver."""
    td = spec.nominal_td().copy()
    td[36:42] += [0.01, -0.02, 0.0, 0.005, 0.0, -0.01]  # leg offsets
    u = STATES_MM[1] / 1000
    a, b = model.forward(u, td), slow_model.forward(u, td)
    np.testing.assert_allclose(a.p, b.p, atol=1e-12)
    np.testing.assert_allclose(model.inverse(a.q, a.X, td), u, atol=1e-10)
    assert np.linalg.norm(a.X - model.forward(u).X) > 1e-3
    batch = model.forward_batch(STATES_MM / 1000, td)
    np.testing.assert_allclose(batch.p[1], a.p, atol=1e-13)


def test_compiled_solver_is_cached_and_a_broken_compiler_falls_back(spec, monkeypatch, tmp_path):
    from platkit import native

    if not (shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")):
        assert PlatformModel(spec).backend.startswith("casadi+numpy")
        return
    monkeypatch.setenv("PLATKIT_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(native, "_native_by_functions", {})
    monkeypatch.setattr(native, "_native_by_hash", {})
    m = PlatformModel(spec)
    assert m.backend.startswith(f"compiled C ({tmp_path / 'cache'}")
    assert len(list((tmp_path / "cache").glob("newton_*.so"))) == 1
    np.testing.assert_allclose(m.forward(STATES_MM[0] / 1000).p, PlatformModel(spec, compile=False).forward(STATES_MM[0] / 1000).p, atol=1e-12)
    monkeypatch.setenv("CC", shutil.which("false") or "/bin/false")
    monkeypatch.setattr(native, "_native_by_functions", {})
    broken = PlatformModel(spec)
    assert broken.backend.startswith("casadi+numpy (the C compiler failed"), broken.backend
    assert broken.forward(STATES_MM[0] / 1000).iterations <= 5


def test_empty_batch(model, slow_model):
    for m in (model, slow_model):
        batch = m.forward_batch(np.zeros((0, 6)))
        assert batch.p.shape == (0, 6) and batch.converged.shape == (0,)


def test_the_warm_single_call_agrees_with_the_general_path():
    """forward(u) takes a path with the strokes checked in C (issue 13); it must give what the
    general path gives (a guess at the neutral pose goes that way) and the same errors."""
    spec = get_platform("stewart")
    model = PlatformModel(spec)
    rng = np.random.default_rng(4)
    lo, hi = spec.control_bounds()
    for u in rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), (20, spec.n_u)):
        fast, general = model.forward(u), model.forward(u, guess=spec.neutral_p())
        np.testing.assert_array_equal(fast.p, general.p)
        np.testing.assert_array_equal(fast.q, general.q)
        assert fast.iterations == general.iterations and fast.on_branch
    first = model.forward(u)
    assert model.forward(u).p is not first.p  # every call its own arrays
    outside = u.copy()
    outside[2] = hi[2] + 0.05  # beyond the recording tolerance (15 mm)
    with pytest.raises(OutOfWorkspace, match="control L3: .* is outside the stroke"):
        model.forward(outside)
    with pytest.raises(BadInput, match="not a finite number"):
        model.forward(np.full(spec.n_u, np.nan))
    with pytest.raises(BadInput, match="takes 6 controls"):
        model.forward(u[:5])
    model.max_iter = 1  # settings changed after the first call are honoured
    with pytest.raises(NoConvergence):
        model.forward(u)
