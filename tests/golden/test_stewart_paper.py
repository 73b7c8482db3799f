"""The Stewart stand against the facts of Liu, Ma, Lin (shared/seeds/stewart-kinematics-liu.zh.txt).

Their frame has z down; platkit's base frame has z up, so their start "below the base"
x(0) = (0, 0, 3000) is platkit's z = -3000 mm. Tolerances: iterations exact (<= 5), envelope
within 1 mm of the figures in shared/spec/stands.md (the paper prints them rounded to 0.1 m).
"""
import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import WrongBranch
from platkit.kinematics import PlatformModel
from platkit.workspace import corner_envelope, translational_envelope

STATES_MM = {
    "state 1": [4795, 4795, 4795, 3295, 3295, 3295],
    "state 2": [3300, 3581, 4158, 4521, 3854, 4029],
    "state 3": [3500, 4795, 4500, 3600, 3800, 4300],
}
#: envelope of the 64 min/max leg combinations, relative to neutral, mm (paper: +-1.5, +-1.6, +-0.9 m)
CORNERS_MM = {"x": (-1493, 1511), "y": (-1601, 1601), "z": (-1050, 919)}


@pytest.fixture(scope="module")
def spec():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def model(spec):
    return PlatformModel(spec)


@pytest.fixture(scope="module")
def corners(model):
    return corner_envelope(model)


def test_geometry_neutral_pose(spec, model):
    np.testing.assert_allclose(spec.neutral_u() * 1000, 4044.9, atol=0.05)
    q, X = model.pose(spec.neutral_p())
    np.testing.assert_allclose(X * 1000, [0, 0, 3147], atol=1e-9)
    assert spec.n_td == 42
    lo, hi = spec.control_bounds()
    np.testing.assert_allclose(lo * 1000, 3295)
    np.testing.assert_allclose(hi * 1000, 4795)


@pytest.mark.parametrize("name", list(STATES_MM))
def test_newton_from_neutral_converges_within_five_iterations(model, name):
    u = np.array(STATES_MM[name]) / 1000
    res = model.forward(u)
    assert res.iterations <= 5, f"{name}: {res.iterations} iterations"
    assert res.residual < 1e-10 and res.on_branch
    np.testing.assert_allclose(model.inverse(res.q, res.X), u, atol=1e-9)  # legs back to 1e-6 mm


@pytest.mark.parametrize("name", list(STATES_MM))
def test_start_below_the_base_converges_to_the_mirror_pose(model, name):
    u = np.array(STATES_MM[name]) / 1000
    good = model.forward(u)
    with pytest.raises(WrongBranch) as err:
        model.forward(u, guess=[0, 0, -3.0, 0, 0, 0])
    msg = str(err.value)
    assert "mirror pose" in msg and " mm" in msg and "\n" not in msg
    assert f"{-good.X[2] * 1000:.1f}" in msg  # the mirror origin's height, in mm
    mirror = model.forward(u, guess=[0, 0, -3.0, 0, 0, 0], allow_mirror=True)
    assert not mirror.on_branch
    # the mirror is the reflection of the stand's pose in the base plane z = 0
    np.testing.assert_allclose(mirror.X, good.X * [1, 1, -1], atol=1e-9)
    reflect = np.diag([1.0, 1.0, -1.0])
    np.testing.assert_allclose(mirror.R, reflect @ good.R @ reflect, atol=1e-9)


@pytest.mark.parametrize("name", list(STATES_MM))
def test_start_far_above_converges_to_the_stand_pose(model, name):
    """The paper's start 2, (0, 0, -6000) in their z-down frame: outside the envelope but on the
    stand's side; Newton still finds the one pose."""
    u = np.array(STATES_MM[name]) / 1000
    res = model.forward(u, guess=[0, 0, 6.0, 0, 0, 0])
    np.testing.assert_allclose(res.X, model.forward(u).X, atol=1e-10)


def test_envelope_of_the_64_min_max_leg_combinations(corners):
    assert len(corners.U) == 64 and corners.converged.all()
    rel = (corners.X - corners.neutral_X) * 1000
    for k, axis in enumerate("xyz"):
        lo, hi = CORNERS_MM[axis]
        assert abs(rel[:, k].min() - lo) < 1.0, f"{axis} min {rel[:, k].min():.2f} mm"
        assert abs(rel[:, k].max() - hi) < 1.0, f"{axis} max {rel[:, k].max():.2f} mm"
    # the paper's rounded statement, +-1.5 m, +-1.6 m, +-0.9 m; its "-0.9" for z is loose (-1.05 m)
    lo_m, hi_m = np.round(rel.min(axis=0) / 100) / 10, np.round(rel.max(axis=0) / 100) / 10
    np.testing.assert_allclose(lo_m[:2], [-1.5, -1.6])
    np.testing.assert_allclose(hi_m, [1.5, 1.6, 0.9])


def test_no_leg_state_inside_the_strokes_leaves_the_corner_envelope(model, corners):
    rng = np.random.default_rng(11)
    U = rng.uniform(3.295, 4.795, (3000, 6))
    batch = model.forward_batch(U)
    assert batch.converged.all() and batch.on_branch.all()
    assert np.all(batch.X >= corners.lower - 1e-9) and np.all(batch.X <= corners.upper + 1e-9)


def test_true_envelope_by_optimisation(model, corners):
    """Free orientation: the optimiser finds the corner extremes (every leg at a stroke end);
    at the neutral orientation the reach is smaller in x and y, equal in z."""
    free = translational_envelope(model, "free", starts=[corners.P[i] for i in range(0, 64, 9)])
    np.testing.assert_allclose(free.lower, corners.lower, atol=5e-4)
    np.testing.assert_allclose(free.upper, corners.upper, atol=5e-4)
    fixed = translational_envelope(model, "fixed")
    rel_lo = (fixed.lower - corners.neutral_X) * 1000
    rel_hi = (fixed.upper - corners.neutral_X) * 1000
    np.testing.assert_allclose(rel_lo, [-1463.7, -1267.6, -1049.5], atol=1.0)
    np.testing.assert_allclose(rel_hi, [1463.7, 1267.6, 919.2], atol=1.0)
    for e in fixed.extremes:  # an optimum at a fixed orientation sits on some stroke ends
        assert e.active, f"{e.axis} {e.sense}: no leg at a stroke end"
        q, X = model.pose(e.p)
        np.testing.assert_allclose(model.inverse(q, X, strict=False), e.u, atol=1e-9)
