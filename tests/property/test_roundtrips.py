"""Round trips over the Stewart workspace: IK -> FK and FK -> IK, compiled and numpy backends."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from platkit import get_platform
from platkit.errors import OutOfWorkspace
from platkit.kinematics import PlatformModel

SPEC = get_platform("stewart")
MODEL = PlatformModel(SPEC)
SLOW = PlatformModel(SPEC, compile=False)
LO, HI = SPEC.control_bounds()

legs = st.lists(st.floats(min_value=float(LO[0]), max_value=float(HI[0]), allow_nan=False), min_size=6, max_size=6)
poses = st.tuples(
    st.floats(-0.4, 0.4), st.floats(-0.4, 0.4), st.floats(-0.3, 0.3),
    st.floats(-0.15, 0.15), st.floats(-0.15, 0.15), st.floats(-0.2, 0.2),
)


@settings(derandomize=True, deadline=None, max_examples=150)
@given(legs)
def test_fk_then_ik_returns_the_legs(u):
    u = np.array(u)
    res = MODEL.forward(u)
    assert res.on_branch and res.residual < 1e-10
    np.testing.assert_allclose(MODEL.inverse(res.q, res.X), u, atol=1e-10)


@settings(derandomize=True, deadline=None, max_examples=150)
@given(poses)
def test_ik_then_fk_returns_the_pose(offset):
    p = SPEC.neutral_p() + np.array(offset)
    q, X = MODEL.pose(p)
    try:
        u = MODEL.inverse(q, X)
    except OutOfWorkspace:
        # outside the strokes: the legs it would need really are outside them
        u = MODEL.inverse(q, X, strict=False)
        assert np.any(u < LO) or np.any(u > HI)
        return
    res = MODEL.forward(u)
    np.testing.assert_allclose(res.X, X, atol=1e-10)
    assert abs(abs(float(np.dot(res.q, q))) - 1) < 1e-12
    np.testing.assert_allclose(res.p, p, atol=1e-9)


@settings(derandomize=True, deadline=None, max_examples=25)
@given(st.lists(legs, min_size=1, max_size=8))
def test_batch_equals_single_and_numpy_backend(U):
    U = np.array(U)
    batch = MODEL.forward_batch(U)
    slow = SLOW.forward_batch(U)
    assert batch.converged.all() and slow.converged.all()
    np.testing.assert_allclose(batch.p, slow.p, atol=1e-11)
    for i, u in enumerate(U):
        np.testing.assert_allclose(batch.p[i], MODEL.forward(u).p, atol=1e-13)


@pytest.mark.parametrize("seed", [0, 1])
def test_velocity_round_trip(seed):
    rng = np.random.default_rng(seed)
    for _ in range(10):
        u = rng.uniform(LO + 0.1, HI - 0.1)
        ud = rng.normal(0, 0.2, 6)
        res = MODEL.forward(u)
        pd = MODEL.forward_velocity(u, ud, p=res.p)
        np.testing.assert_allclose(MODEL.inverse_velocity(res.p, pd, u=u), ud, atol=1e-10)
        v, om = MODEL.forward_velocity_twist(u, ud, p=res.p)
        np.testing.assert_allclose(MODEL.inverse_velocity_twist(res.q, res.X, v, om, u=u), ud, atol=1e-10)
