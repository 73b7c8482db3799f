"""Stands with more residual rows than pose coordinates (issue 26): forward kinematics is the
weighted least-squares pose with the rows' misfit beside it, refused only beyond the declared
plausible misfit; declarations checked; restarts find the stand's own assembly; angles wrapped;
pose-free stands sampled in pose space; degenerate admissible sets refused.

The stand here is a point hung on four cables (three coordinates, four rows), written for these
tests; the least-squares truth is scipy's, independent of platkit's solver.
"""
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from scipy.optimize import least_squares

from platkit.admissible import AdmissibleGrid, admissible_poses, check_not_degenerate, pose_images
from platkit.calibrate.plan import grid_plan, random_candidates
from platkit.errors import BadDescription, ComputationFailed, NotIdentifiable, OutOfWorkspace, WrongBranch
from platkit.kinematics import PlatformModel
from platkit.model import Control, Coordinate, Parameter, PlatformSpec, RowMisfit, validate_spec
from platkit.plugins import get_platform
from platkit.testing import check_platform

ANCHORS = np.array([[1.0, 1.0, 2.0], [-1.0, 1.0, 2.0], [-1.0, -1.0, 2.0], [1.0, -1.0, 0.0]])
STRETCH = np.array([2e-3, 2e-3, 2e-3, 4e-3])  # the fourth cable may miss twice as much


def point_stand(misfit=True, free_space="pose") -> PlatformSpec:
    u = ca.SX.sym("u", 4)
    td = ca.SX.sym("td", 12)
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    A = ca.reshape(td, 3, 4)
    lengths = ca.sqrt(ca.sum1((A - ca.repmat(X, 1, 4)) ** 2)).T
    residual = ca.Function("F", [u, td, q, X], [u - lengths], ["u", "td", "q", "X"], ["r"])
    inverse = ca.Function("inverse", [td, q, X], [lengths], ["td", "q", "X"], ["u"])
    p = ca.SX.sym("p", 3)
    pose = ca.Function("pose", [p], [ca.DM([1.0, 0, 0, 0]), p], ["p"], ["q", "X"])
    from_pose = ca.Function("coordinates_from_pose", [q, X], [X], ["q", "X"], ["p"])
    params = [Parameter(f"A{i + 1}_{c}", "m", float(ANCHORS[i, k])) for i in range(4) for k, c in enumerate("xyz")]
    X0 = np.array([0.0, 0.0, 1.0])
    u0 = np.linalg.norm(ANCHORS - X0, axis=1)
    controls = [Control(f"c{i + 1}", "m", 0.2, 4.0, float(v)) for i, v in enumerate(u0)]
    coords = [Coordinate(n, "m", float(v), float(v) - 0.4, float(v) + 0.4) for n, v in zip("xyz", X0)]
    rows = [RowMisfit(f"cable c{i + 1}", "m", float(s)) for i, s in enumerate(STRETCH)] if misfit else None
    return PlatformSpec("point4", "a point on four cables", controls, params, coords, residual, pose,
                        coordinates_from_pose=from_pose, inverse=inverse, misfit=rows, free_space=free_space)


def scipy_pose(u, x0=(0.0, 0.0, 1.0)):
    """The weighted least-squares point, by scipy."""
    sol = least_squares(lambda x: (u - np.linalg.norm(ANCHORS - x, axis=1)) / STRETCH, np.array(x0, float),
                        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x, u - np.linalg.norm(ANCHORS - sol.x, axis=1)


@pytest.mark.parametrize("compiled", [True, False])
def test_forward_is_the_weighted_least_squares_pose_with_its_misfit(compiled):
    spec = point_stand()
    model = PlatformModel(spec, compile=compiled)
    assert model.redundant and ("compiled C" in model.backend) == compiled
    u = np.linalg.norm(ANCHORS - [0.1, -0.2, 1.1], axis=1) + np.array([1e-3, -1e-3, 5e-4, 2e-3])
    fk = model.forward(u)
    x, r = scipy_pose(u)
    np.testing.assert_allclose(fk.X, x, atol=1e-12)
    np.testing.assert_allclose(fk.misfit, r, atol=1e-12)
    assert fk.misfit_ratio == pytest.approx(np.max(np.abs(r) / STRETCH)) and 0 < fk.misfit_ratio < 1
    # consistent controls: the exact pose, no misfit
    exact = model.forward(np.linalg.norm(ANCHORS - [0.1, -0.2, 1.1], axis=1))
    np.testing.assert_allclose(exact.X, [0.1, -0.2, 1.1], atol=1e-12)
    assert np.max(np.abs(exact.misfit)) < 1e-12


def test_a_misfit_beyond_the_plausible_is_refused_naming_rows_and_amounts():
    model = PlatformModel(point_stand())
    X0 = np.array([0.0, 0.0, 1.0])
    u = np.linalg.norm(ANCHORS - X0, axis=1)
    # lengths along the rows' left null space: no motion of the point absorbs them
    J = (X0 - ANCHORS) / u[:, None]
    n = np.linalg.svd(J)[0][:, -1]
    u = u + 0.02 * n
    _, r = scipy_pose(u)
    assert np.any(np.abs(r) > STRETCH)
    worst = int(np.argmax(np.abs(r) / STRETCH))
    with pytest.raises(OutOfWorkspace) as err:
        model.forward(u)
    msg = str(err.value)
    assert "\n" not in msg and "plausible misfit" in msg
    assert msg.split(": ", 2)[2].startswith(f"cable c{worst + 1} misses by {abs(r[worst]) * 1e3:.4g} mm "
                                            f"(plausible {STRETCH[worst] * 1e3:.4g})")
    assert f"({int(np.sum(np.abs(r) > STRETCH))} of 4 rows beyond)" in msg
    batch = model.forward_batch(np.vstack([u, np.linalg.norm(ANCHORS - [0, 0, 1.0], axis=1)]))
    assert batch.converged.tolist() == [False, True] and batch.misfit.shape == (2, 4)
    np.testing.assert_allclose(batch.misfit[0], r, atol=1e-10)


def test_without_a_declared_misfit_the_rows_must_close():
    spec = point_stand(misfit=False, free_space="controls")
    model = PlatformModel(spec)
    u = np.linalg.norm(ANCHORS - [0.1, 0.0, 1.2], axis=1)
    np.testing.assert_allclose(model.forward(u).X, [0.1, 0.0, 1.2], atol=1e-12)
    with pytest.raises(OutOfWorkspace, match=r"fit no pose exactly .*declares no plausible misfit \(PlatformSpec.misfit\)"):
        model.forward(u + [1e-4, 0, 0, 0])
    with pytest.raises(AssertionError, match=r"point4.*4 residual rows for 3 pose coordinates and no plausible misfit "
                                             r"declared \(field 'misfit'"):
        check_platform(spec)


def test_declarations_are_checked_naming_the_field():
    spec = point_stand()
    validate_spec(spec)
    with pytest.raises(BadDescription, match=r"point4.*field 'misfit' declares 3 rows, the residual has 4"):
        validate_spec(replace(spec, misfit=spec.misfit[:3]))
    with pytest.raises(BadDescription, match=r"field 'misfit'\[1\] \(cable c2\): plausible misfit must be a positive"):
        validate_spec(replace(spec, misfit=[spec.misfit[0], RowMisfit("cable c2", "m", 0.0), *spec.misfit[2:]]))
    with pytest.raises(BadDescription, match=r"field 'free_space' is 'poses', not one of controls, pose"):
        validate_spec(replace(spec, free_space="poses"))
    unbounded = [replace(c, lower=-np.inf) for c in spec.coordinates]
    with pytest.raises(BadDescription, match=r"field 'free_space' is 'pose' but coordinates \['x', 'y', 'z'\] have no "
                                             "finite bounds"):
        validate_spec(replace(spec, coordinates=unbounded))


def test_the_point_stand_passes_the_conformance_check():
    report = check_platform(point_stand())
    assert report["free_space"] == "pose" and report["free_space_taken"] == 1.0 and report["round_trips"] == 20


def test_pose_free_plans_and_images_are_drawn_in_pose_space():
    spec = point_stand()
    plan = grid_plan(spec, 3)
    assert plan.info["space"] == "pose" and plan.info["grid_points"] == 27 and len(plan.controls) == 27
    np.testing.assert_allclose(plan.controls, np.linalg.norm(ANCHORS[None] - plan.poses[:, None], axis=2), atol=1e-12)
    rnd = random_candidates(spec, 10, np.random.default_rng(1))
    assert rnd.info["space"] == "pose" and rnd.controls.shape == (10, 4)
    P = pose_images(spec, 5)
    assert P.shape == (125, 3) and admissible_poses(spec, P)["inside"].all()
    # the same stand with its control box declared free: the box's corners fit no pose, and the
    # refusal says what to declare
    with pytest.raises(NotIdentifiable, match=r"point4: no point of the 2-per-control grid is reachable; its 4 residual "
                                              r"rows outnumber its 3 pose coordinates.*'free_space': 'pose'"):
        grid_plan(replace(spec, free_space="controls"), 2)


def test_a_point_or_a_sliver_is_refused():
    axes = (np.linspace(0, 1, 5), np.linspace(0, 1, 5))
    inside = np.zeros((5, 5), bool)

    def grid(inside):
        return AdmissibleGrid("point4", ("x", "y"), ("m", "m"), axes, {}, inside, np.zeros((5, 5, 4)),
                              ~inside, np.zeros((5, 5), bool), np.zeros((5, 5), bool))

    inside[2, 2] = True
    with pytest.raises(ComputationFailed, match=r"degenerate along x: 1 of 5 grid values"):
        check_not_degenerate(grid(inside))
    inside[2, 3] = True  # a sliver: one x value
    with pytest.raises(ComputationFailed, match="degenerate along x"):
        check_not_degenerate(grid(inside))
    inside[3, 2] = True
    check_not_degenerate(grid(inside))


@pytest.fixture(scope="module")
def stewart():
    return PlatformModel(get_platform("stewart"))


def test_restarts_find_the_stands_own_assembly_from_a_mirror_start(stewart):
    u = stewart.spec.neutral_u() + 0.05
    own = stewart.forward(u)
    with pytest.raises(WrongBranch):
        stewart.forward(u, guess=[0, 0, -3.0, 0, 0, 0])  # an explicit guess is honoured alone
    again = stewart.forward(u, guess=[0, 0, -3.0, 0, 0, 0], restarts=True)
    assert again.on_branch and np.allclose(again.X, own.X, atol=1e-12)
    batch = stewart.forward_batch(np.vstack([u, u]), guess=np.array([[0, 0, -3.0, 0, 0, 0], own.p]))
    assert batch.on_branch.all() and batch.converged.all() and np.allclose(batch.X, own.X, atol=1e-12)


def test_angles_come_back_wrapped(stewart):
    u = stewart.spec.neutral_u() + np.array([0.02, -0.01, 0.03, 0.0, 0.01, -0.02])
    own = stewart.forward(u)
    turned = own.p + np.array([0, 0, 0, 2 * np.pi, -4 * np.pi, 2 * np.pi])  # the same pose, angles a turn off
    res = stewart.forward(u, guess=turned)
    np.testing.assert_allclose(res.p, own.p, atol=1e-10)
    # roll, pitch, yaw near (pi, pi, pi) is the level pose too: the stand's own convention comes back
    near = own.p + np.array([0, 0, 0, np.pi, np.pi, np.pi]) * [0, 0, 0, 1, -1, 1]
    res = stewart.forward(u, guess=near)
    assert np.all(np.abs(res.p[3:]) < 0.5) and np.allclose(res.X, own.X, atol=1e-10)


def test_a_pose_free_stand_streams_along_straight_lines_in_pose():
    from platkit.simulate import simulate

    sim = simulate(point_stand(), seed=3, n_poses=8)
    traj = sim.trajectory
    # half-way through each move the point is half-way between the poses it moves between (the
    # true geometry, 2 mm off nominal, bends the line by well under a millimetre; a straight line
    # in cable lengths sags by centimetres)
    mid = traj.command_t + 0.5 * (traj.arrive_t - traj.command_t)
    _, X, _ = traj.evaluate(mid)
    ends = traj.evaluate(traj.arrive_t - 1e-9)[1]
    starts = np.vstack([traj.evaluate(np.array([traj.command_t[0] - 1e-3]))[1], ends[:-1]])
    assert np.max(np.linalg.norm(X - 0.5 * (starts + ends), axis=1)) < 1e-3


def test_means_over_poses_the_model_could_not_predict_leak_no_numpy_warning():
    """A pose a redundant stand refuses (its rows beyond their plausible misfit) is a row of NaN in
    the residuals calibrate plots and diagnose scores; their means skip it without numpy's
    'Mean of empty slice'."""
    import warnings

    from platkit.calibrate.report import _finite_row_mean
    from platkit.diagnose.evidence import _finite_mean

    a = np.array([[np.nan, np.nan], [1.0, 3.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rows = _finite_row_mean(a)
        per_pose = _finite_mean(a, axis=1)
        column, everything, nothing = _finite_mean(a[:, 0]), _finite_mean(a), _finite_mean(a[:1])
    assert np.isnan(rows[0]) and rows[1] == 2.0 and np.isnan(per_pose[0]) and per_pose[1] == 2.0
    assert column == 1.0 and everything == 2.0 and np.isnan(nothing)


def slider_pair() -> PlatformSpec:
    """Two sliders in series move one carriage: x = u1 + u2, one row, two controls for one coordinate."""
    u, td, q, X = ca.SX.sym("u", 2), ca.SX.sym("td", 1), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    residual = ca.Function("F", [u, td, q, X], [u[0] + u[1] + td[0] - X[0]], ["u", "td", "q", "X"], ["r"])
    p = ca.SX.sym("p", 1)
    pose = ca.Function("pose", [p], [ca.DM([1.0, 0, 0, 0]), ca.vertcat(p, 0, 0)], ["p"], ["q", "X"])
    from_pose = ca.Function("coordinates_from_pose", [q, X], [X[0]], ["q", "X"], ["p"])
    return PlatformSpec("slider2", "two sliders in series", [Control(f"s{i}", "m", -1.0, 1.0, 0.0) for i in (1, 2)],
                        [Parameter("offset", "m", 0.0)], [Coordinate("x", "m", 0.0, -1.0, 1.0)], residual, pose,
                        coordinates_from_pose=from_pose)


def test_fk_says_a_least_squares_solve_and_its_weighted_misfit(capsys, monkeypatch):
    import platkit.commands.fk as fk
    from platkit.cli import main

    monkeypatch.setattr(fk, "platform_from_args", lambda args: point_stand())
    u = ",".join(f"{v * 1e3:.6f}" for v in np.linalg.norm(ANCHORS - [0.1, -0.2, 1.1], axis=1) + [1e-3, 0, 0, 0])
    assert main(["fk", "--platform", "any", "--u", u]) == 0
    out = capsys.readouterr().out
    assert "least-squares iterations" in out and "weighted misfit" in out and "newton" not in out


@pytest.mark.parametrize("stand, free", [(point_stand, False), (slider_pair, True)])
def test_ik_says_the_controls_are_one_of_many_only_where_the_pose_leaves_some_free(capsys, monkeypatch, stand, free):
    # the point on four cables has more controls than coordinates, yet each cable's length is the
    # pose's: F_u has full rank. Two sliders in series leave their sum only.
    import platkit.commands.ik as ik
    from platkit.cli import main

    monkeypatch.setattr(ik, "platform_from_args", lambda args: stand())
    pose = "100,-50,1100" if stand is point_stand else "300"
    assert main(["ik", "--platform", "any", "--pose", pose, "--coordinates"]) == 0
    err = capsys.readouterr().err
    assert ("one solution of many" in err) == free, err


@pytest.mark.parametrize("compiled", [True, False])
def test_consistent_controls_give_the_pose_to_rounding(compiled):
    # once the rows close to the tolerance, one Gauss-Newton step polishes the pose, as Newton's
    # does: finite differences of forward kinematics (check_platform's rates) divide its error by h^2
    model = PlatformModel(point_stand(), compile=compiled)
    rng = np.random.default_rng(3)
    for _ in range(200):
        x = np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.3, 0.3, 3)
        np.testing.assert_allclose(model.forward(np.linalg.norm(ANCHORS - x, axis=1)).X, x, rtol=0, atol=1e-14)


def plate_stand() -> PlatformSpec:
    """A 200 x 100 mm plate on four cables from the corners of a 2 x 1.5 m frame, in the plane:
    x, y, yaw, the turn weakly held (each cable runs nearly along the plate's diagonal)."""
    A = np.array([[-1.0, -0.75], [1.0, -0.75], [1.0, 0.75], [-1.0, 0.75]])
    b = np.array([[-0.1, -0.05], [0.1, -0.05], [0.1, 0.05], [-0.1, 0.05]])
    u, td, q, X = ca.SX.sym("u", 4), ca.SX.sym("td", 1), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
    yaw = 2 * ca.atan2(q[3], q[0])
    c, s = ca.cos(yaw), ca.sin(yaw)
    lengths = ca.vertcat(*[ca.sqrt((A[i, 0] - X[0] - c * b[i, 0] + s * b[i, 1]) ** 2
                                   + (A[i, 1] - X[1] - s * b[i, 0] - c * b[i, 1]) ** 2) for i in range(4)])
    residual = ca.Function("F", [u, td, q, X], [u + td[0] - lengths], ["u", "td", "q", "X"], ["r"])
    p = ca.SX.sym("p", 3)
    pose = ca.Function("pose", [p], [ca.vertcat(ca.cos(p[2] / 2), 0, 0, ca.sin(p[2] / 2)), ca.vertcat(p[0], p[1], 0)],
                       ["p"], ["q", "X"])
    from_pose = ca.Function("coordinates_from_pose", [q, X], [ca.vertcat(X[0], X[1], yaw)], ["q", "X"], ["p"])
    u0 = np.linalg.norm(A - b, axis=1)
    controls = [Control(f"C{i + 1}", "m", 0.1, 2.2, float(v)) for i, v in enumerate(u0)]
    return PlatformSpec("plate4", "a plate on four cables", controls, [Parameter("o", "m", 0.0)],
                        [Coordinate("x", "m", 0.0, -0.6, 0.6), Coordinate("y", "m", 0.0, -0.45, 0.45),
                         Coordinate("yaw", "rad", 0.0, -0.35, 0.35)],
                        residual, pose, coordinates_from_pose=from_pose,
                        misfit=[RowMisfit(f"cable C{i + 1}", "m", 3e-3) for i in range(4)], free_space="pose")


@pytest.mark.parametrize("compiled", [True, False])
def test_rows_that_miss_by_much_along_a_weak_turn_are_refused_as_a_misfit_not_as_no_convergence(compiled):
    # Gauss-Newton converges linearly where the rows miss: 14 mm off one cable takes some 50
    # iterations to the least-squares pose, past Newton's 30
    model = PlatformModel(plate_stand(), compile=compiled)
    u = model.inverse(*model.pose([0.1, 0.05, 0.1])) - np.array([0.0, 0.0, 0.0, 0.014])
    with pytest.raises(OutOfWorkspace, match=r"plausible misfit: cable C4 misses by 3\.669 mm \(plausible 3\), "
                                             r"cable C2 misses by 3\.566 mm"):
        model.forward(u)


def test_beyond_the_plausible_misfit_the_batch_gives_the_least_squares_pose_only_when_asked():
    # the physical simulator's true plate sits at the rows' weighted least-squares pose whatever
    # their misfit (refuse_misfit=False); the recorded side keeps refusing such controls
    model = PlatformModel(point_stand())
    X0 = np.array([0.0, 0.0, 1.0])
    u = np.linalg.norm(ANCHORS - X0, axis=1)
    n = np.linalg.svd((X0 - ANCHORS) / u[:, None])[0][:, -1]  # lengths no motion of the point absorbs
    u = u + 5 * 4e-3 * n / np.max(np.abs(n))
    x, r = scipy_pose(u)
    assert np.max(np.abs(r) / STRETCH) > 1.5
    physical = model.forward_batch(u[None], refuse_misfit=False)
    assert physical.converged[0] and physical.on_branch[0]
    np.testing.assert_allclose(physical.X[0], x, atol=1e-9)  # Gauss-Newton stops short by 1e-10 this far apart
    np.testing.assert_allclose(physical.misfit[0], r, atol=1e-9)
    assert not model.forward_batch(u[None]).converged[0]
    with pytest.raises(OutOfWorkspace, match="plausible misfit"):
        model.forward(u)


def test_a_physical_run_puts_the_plate_where_its_lagging_cables_pull_it():
    # each actuator follows its own response, so between holds the cables of a pose-free stand
    # disagree by more than their plausible misfit: the true point is the rows' weighted
    # least-squares point of the actuators' travel (scipy's here), and the run goes on (before: it
    # stopped, 'forward kinematics of the true stand failed')
    from platkit.simulate.actuator import actuator_motion
    from platkit.simulate.physics import simulate_physics

    spec = point_stand()
    U = np.array([np.linalg.norm(ANCHORS - x, axis=1) for x in ([0, 0, 1.0], [0.3, 0.3, 1.3], [-0.3, -0.3, 0.8])])
    sim = simulate_physics(spec, seed=0, plan=U, perturbation=0.0, noise_mm=0.0, coloured=False, occlusion=0.0,
                           latency_s=0.0, clock_offset_s=0.0)
    t = sim.marker_t
    travel = actuator_motion(t, sim.command_t, sim.commands, spec.neutral_u(), sim.response, 2e-3)
    ratio = np.array([np.max(np.abs(u - np.linalg.norm(ANCHORS - scipy_pose(u)[0], axis=1)) / STRETCH)
                      for u in travel[::10]])
    assert ratio.max() > 1.5  # the rows missed by more than they may, on the way
    k = 10 * int(np.argmax(ratio))
    T = sim.mocap_from_base
    point = (sim.markers[k] - T[:3, 3]) @ T[:3, :3] - sim.marker_body  # the point's place from each marker
    np.testing.assert_allclose(point, np.repeat(scipy_pose(travel[k])[0][None], len(point), axis=0), atol=2e-6)


def test_a_pose_free_stand_streams_its_motion_drawn_in_pose():
    # the shapes are drawn per pose coordinate and mapped by inverse kinematics: every command fits
    # a pose (before: drawn per cable, 'no multisine motion around the neutral pose stays reachable')
    from platkit.simulate.physics import simulate_physics

    spec = point_stand()
    sim = simulate_physics(spec, seed=0, motion="multisine", duration_s=20.0, perturbation=0.0)
    assert sim.plan_info["space"] == "pose" and len(sim.commands) == 400
    fb = PlatformModel(spec).forward_batch(sim.commands)
    assert fb.converged.all() and np.max(np.abs(fb.misfit)) < 1e-9
    lo, hi = spec.coordinate_bounds()
    assert np.all(np.ptp(fb.p, axis=0) > 0.3 * (hi - lo))  # the whole box is travelled, not a corner


def test_a_pose_free_stand_without_a_closed_form_inverse_streams_along_straight_lines_in_pose():
    # its path's controls come from the model's own inverse pose by pose (a straight line in cable
    # lengths misses a pose by more than the cables' plausible 3 mm: the simulation stopped, 'forward
    # kinematics failed along the path')
    from platkit.simulate import simulate

    traj = simulate(plate_stand(), seed=0, n_poses=6).trajectory
    mid = traj.command_t + 0.5 * (traj.arrive_t - traj.command_t)
    _, X, _ = traj.evaluate(mid)
    ends = traj.evaluate(traj.arrive_t - 1e-9)[1]
    starts = np.vstack([traj.evaluate(np.array([traj.command_t[0] - 1e-3]))[1], ends[:-1]])
    assert np.max(np.linalg.norm(X - 0.5 * (starts + ends), axis=1)) < 1e-3


def test_the_report_shows_coverage_in_the_stands_own_pose_coordinates(monkeypatch):
    # the plate moves in x, y and yaw: the coverage plot's axes are those, every one of them (it
    # drew x-y, x-z and roll-pitch, three of them constant, and no yaw)
    import platkit.calibrate.report as report
    from platkit.calibrate.estimate import calibrate
    from platkit.simulate import simulate

    spec = plate_stand()
    sim = simulate(spec, seed=0, n_poses=12)
    cal = calibrate(sim.poses, spec, free=["o"])
    figures = []
    monkeypatch.setattr(report, "_png", lambda fig: figures.append(fig) or "")
    titles = [t for t, _, _ in report._plots(cal, sim.poses)]
    fig = figures[titles.index("Coverage of the workspace")]
    labels = [(a.get_xlabel(), a.get_ylabel()) for a in fig.axes]
    assert labels == [("x [mm]", "y [mm]"), ("yaw [deg]", "x [mm]")]
    assert 10 < np.ptp(fig.axes[1].lines[0].get_xdata()) < 41  # yaw within its +-20 deg box


def test_a_plate_on_cables_is_calibrated_from_its_stream(tmp_path):
    # a stream drawn in pose and simulated with physics (the cables lag one another), calibrated from
    # motion: the model of the stream puts the plate where its lagging cables pull it, as the
    # simulator does, and the settled markers of every command come out at the truth (before: the
    # plan was refused, 'no multisine motion around the neutral pose stays reachable')
    from platkit.calibrate.estimate import predict_markers
    from platkit.calibrate.motion import calibrate_motion
    from platkit.io.session import load_session
    from platkit.simulate.physics import simulate_physics, write_physical_session

    spec = plate_stand()
    sim = simulate_physics(spec, seed=0, motion="multisine", duration_s=24.0, mocap_rate_hz=50.0)
    write_physical_session(sim, tmp_path / "s")
    cal, _ = calibrate_motion(load_session(tmp_path / "s", spec=spec), spec)
    pred = predict_markers(cal, sim.commands)[0]
    truth = np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2)))
    assert truth < 0.05e-3 < cal.rms_before


@pytest.mark.parametrize("family", ["via", "fourier"])
def test_motion_plans_of_a_pose_free_stand_are_drawn_in_pose(family):
    # plan --motion: via points drawn as poses and joined along pose lines, or the Fourier series per
    # pose coordinate; every command is the inverse kinematics of a pose, within the drives' limits,
    # and the plate travels its box (before: drawn per cable, 'fewer than 720 random commands inside
    # the strokes less the margin are reachable')
    from platkit.calibrate import excitation as ex
    from platkit.calibrate import sweeps as sw
    from platkit.calibrate import trajectories as tr
    from platkit.calibrate.plan import default_marker_layout
    from tests.unit.test_plan_excitation import check_every_command

    spec = point_stand()  # a closed-form inverse: the lines' commands in one batch each
    limits = tr.drive_limits(spec, np.full(4, 0.2), np.full(4, 0.4), 0.1)
    markers = default_marker_layout(spec, 5, np.random.default_rng(0))
    common = dict(command_rate_hz=20.0, mocap_rate_hz=100.0, sigma_m=1e-4, markers=markers,
                  rng=np.random.default_rng(1), duration_s=40.0, target_m=None)
    if family == "via":
        plan = sw.plan_sweep(spec, limits, seen=1.0, **common)
    else:
        plan = ex.plan_excitation(spec, limits, period_s=20.0, harmonics=3, evaluations=5, **common)
    U = plan.controls
    check_every_command(spec, U, limits)
    fb = PlatformModel(spec).forward_batch(U)
    assert np.max(np.abs(fb.misfit)) < 1e-9
    lo, hi = spec.coordinate_bounds()
    assert np.all(np.ptp(fb.p, axis=0) > 0.25 * (hi - lo))
    assert plan.report["limits"]["source"]["space"].startswith("pose")
