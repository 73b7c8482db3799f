"""Forward kinematics from the neutral start honours the coordinates' bounds: a solve that lands
on a pose beyond them starts again from the start library and keeps that pose only when no start
gives one within them.

The stand is a pan-tilt head written for this test: its residual fixes the boresight
d = R(q) e_x only, so Rz(a + pi) Ry(pi - b), the head turned over, closes it too; the pose map
Rz(yaw) Ry(pitch) holds that pose at pitch pi - b, beyond the pitch bounds.
"""
import casadi as ca
import numpy as np
import pytest

from platkit.geometry import ca_matrix_from_quat
from platkit.kinematics import PlatformModel
from platkit.model import Control, Coordinate, Parameter, PlatformSpec


def pan_tilt(pitch_max=1.3) -> PlatformSpec:
    u, td, q, X = ca.SX.sym("u", 2), ca.SX.sym("td", 1), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    a, b = u[0] + td[0], u[1]
    d = ca.mtimes(ca_matrix_from_quat(q), ca.DM([1.0, 0.0, 0.0]))
    e_a = ca.vertcat(-ca.sin(a), ca.cos(a), 0)
    e_b = ca.vertcat(-ca.cos(a) * ca.sin(b), -ca.sin(a) * ca.sin(b), -ca.cos(b))
    d_m = ca.vertcat(ca.cos(a) * ca.cos(b), ca.sin(a) * ca.cos(b), -ca.sin(b))
    residual = ca.Function("F", [u, td, q, X], [ca.vertcat(ca.dot(e_a, d), ca.dot(e_b, d))], ["u", "td", "q", "X"], ["r"])
    branch = ca.Function("branch", [u, td, q, X], [ca.dot(d, d_m)], ["u", "td", "q", "X"], ["g"])
    p = ca.SX.sym("p", 2)
    cz, sz, cy, sy = ca.cos(p[0] / 2), ca.sin(p[0] / 2), ca.cos(p[1] / 2), ca.sin(p[1] / 2)
    pose = ca.Function("pose", [p], [ca.vertcat(cz * cy, -sz * sy, cz * sy, sz * cy), ca.DM.zeros(3)], ["p"], ["q", "X"])
    from_pose = ca.Function("coordinates_from_pose", [q, X],
                            [ca.vertcat(ca.atan2(d[1], d[0]), ca.atan2(-d[2], ca.sqrt(d[0] ** 2 + d[1] ** 2)))],
                            ["q", "X"], ["p"])
    controls = [Control("pan", "rad", -2.6, 2.6, 0.0), Control("tilt", "rad", -1.0, 1.0, 0.0)]
    coordinates = [Coordinate("yaw", "rad", 0.0, -2.8, 2.8), Coordinate("pitch", "rad", 0.0, -pitch_max, pitch_max)]
    return PlatformSpec("pan-tilt", "a pan-tilt head", controls, [Parameter("o_pan", "rad", 0.0)], coordinates,
                        residual, pose, coordinates_from_pose=from_pose, branch=branch)


@pytest.mark.parametrize("compiled", [True, False])
def test_forward_from_neutral_honours_the_bounds_and_keeps_a_pose_beyond_only_where_none_is_within(compiled):
    model = PlatformModel(pan_tilt(), compile=compiled)
    u = np.radians([72.0, 28.8])  # Newton from the neutral pose lands on yaw -108, pitch 151.2 deg
    first = model._solve_one(u, model._td(None), None)
    assert first[1] > 1.3  # the turned-over solution, the reason for this test
    fk = model.forward(u)
    np.testing.assert_allclose(fk.p, u, atol=1e-12)
    batch = model.forward_batch(np.array([u, -u, [0.3, 0.2]]))
    np.testing.assert_allclose(batch.p, [u, -u, [0.3, 0.2]], atol=1e-12)
    assert batch.converged.all() and batch.on_branch.all()
    # from a guess at the neutral pose (calibration's first solve of every pose), with restarts
    np.testing.assert_allclose(model.forward(u, guess=[0.0, 0.0], restarts=True).p, u, atol=1e-12)
    batch = model.forward_batch(np.array([u, -u]), guess=np.zeros((2, 2)))
    np.testing.assert_allclose(batch.p, [u, -u], atol=1e-12)
    # where no start gives a pose within the bounds, the one beyond them is kept
    model = PlatformModel(pan_tilt(pitch_max=0.5), compile=compiled)
    u = np.array([0.2, 0.8])  # tilt 0.8 rad: the head's own pose is beyond the pitch bound 0.5
    np.testing.assert_allclose(model.forward(u).p, u, atol=1e-12)
    batch = model.forward_batch(u[None, :])
    np.testing.assert_allclose(batch.p[0], u, atol=1e-12)
    assert batch.converged[0] and batch.on_branch[0]


@pytest.mark.parametrize("compiled", [True, False])
def test_the_start_library_holds_the_head_turned_over_only_where_no_start_within_the_bounds_reaches_it(compiled):
    """The start library of a stand with a control box is the forward images of a control grid
    from the neutral pose; those that land on the head turned over (beyond the pitch bound) are
    solved again from the nearest pose within the bounds. Before, 87 of 479 library poses (compiled) were
    turned over, so the restarts of pan 1.5, tilt 0.3 rad (the neutral start lands turned over)
    all landed there too and forward kinematics kept the pose beyond the bounds."""
    model = PlatformModel(pan_tilt(), compile=compiled)
    P, _ = model._library
    assert len(P) > 400 and np.all(np.abs(P[:, 1]) <= 1.3)
    U = np.array([[a, b] for a in np.linspace(-2.6, 2.6, 53) for b in np.linspace(-1.0, 1.0, 21)])
    assert model._solve_one(np.array([1.5, 0.3]), model._td(None), None)[1] > 1.3  # turned over from neutral
    np.testing.assert_allclose(model.forward_batch(U).p, U, atol=1e-9)
    np.testing.assert_allclose([model.forward(u).p for u in U], U, atol=1e-9)
