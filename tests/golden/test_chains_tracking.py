"""The tracking servo on reference robots (example-robot-data and the real TIAGo URDF).

Tolerances: 1e-6 m and 1e-6 rad on every reached target (the servo's own tolerance), checked
again here by independent forward kinematics. Fixed seeds throughout.
"""
from pathlib import Path

import numpy as np
import pytest
from reference_robots import example_robot_urdf

from platkit.chains import KinematicChain, Servo, ServoOptions, Task, follow_trajectory, track
from platkit.chains.transforms import pose_error
from platkit.errors import OutOfWorkspace
from platkit.geometry import matrix_from_rotvec

TOL = 1e-6
TIAGO = Path("/work/shared/data/real/tiago/tiago_48_schunk.urdf")
_here = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "tiago" / "tiago_48_schunk.urdf"
if _here.is_file():
    TIAGO = _here


@pytest.fixture(scope="module")
def ur5():
    return KinematicChain.from_urdf(example_robot_urdf("ur_description/urdf/ur5_robot.urdf"))


@pytest.fixture(scope="module")
def panda():
    return KinematicChain.from_urdf(example_robot_urdf("panda_description/urdf/panda.urdf"))


@pytest.fixture(scope="module")
def talos():
    return KinematicChain.from_urdf(example_robot_urdf("talos_data/robots/talos_reduced.urdf"))


def _check_reached(chain, theta, link, target, frame="world", weights=np.ones(6)):
    P = chain.relative_placement(theta, link, frame)
    E = pose_error(P, target) * (weights > 0)
    assert np.linalg.norm(E[:3]) <= TOL and np.linalg.norm(E[3:]) <= TOL
    assert np.all(theta >= chain.lower - 1e-12) and np.all(theta <= chain.upper + 1e-12)


@pytest.mark.parametrize("robot, link, seed", [("ur5", "tool0", 10), ("panda", "panda_hand", 20)])
def test_random_reachable_targets_converge(robot, link, seed, request):
    chain = request.getfixturevalue(robot)
    rng = np.random.default_rng(seed)
    first_try = 0
    for k in range(12):
        target = chain.placement(chain.random(rng), link)
        options = ServoOptions(restarts=10, seed=k)
        result = track(chain, Task(link, target), chain.mid_range(), options)
        assert result.converged
        _check_reached(chain, result.theta, link, target)
        first_try += result.restarts == 0
    assert first_try >= 8  # the servo alone, from mid-range, reaches most; restarts the rest


def test_lp_solver_converges(ur5):
    rng = np.random.default_rng(3)
    for k in range(4):
        target = ur5.placement(ur5.random(rng), "tool0")
        result = track(ur5, Task("tool0", target), ur5.mid_range(), ServoOptions(solver="lp", restarts=10, seed=k))
        _check_reached(ur5, result.theta, "tool0", target)


def test_unreachable_target_fails_with_a_clear_sentence(ur5):
    target = np.eye(4)
    target[:3, 3] = [2.0, 0.0, 0.4]
    with pytest.raises(OutOfWorkspace) as info:
        track(ur5, Task("tool0", target, weights=np.array([1, 1, 1, 0, 0, 0.0])), ur5.mid_range())
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith("link 'tool0' did not reach its target: closest ")
    assert "from 'shoulder_pan_joint' but the chain reaches at most" in msg
    assert " rad" not in msg  # the rotation was left free
    closest = float(msg.split("closest ")[1].split(" m")[0])
    # UR5: shoulder at z = 0.089 m, arm length about 0.95 m; the target is 2.02 m from the shoulder
    assert 1.0 < closest < 1.1


def test_stretched_singular_pose_is_handled_without_blow_up(ur5):
    stretched = ur5.neutral()  # UR5 at zero: the arm lies straight out, elbow and wrist aligned
    J = ur5.jacobian(stretched, "tool0")
    assert np.linalg.svd(J, compute_uv=False)[-1] < 1e-9
    options = ServoOptions()
    rate_step = ur5.rate * options.dt
    # a reachable target: the servo leaves the singularity with bounded steps and converges
    goal = ur5.placement(np.array([0.3, -1.0, 1.2, -0.5, 0.8, 0.1]), "tool0")
    result = Servo(ur5, [Task("tool0", goal)], options).run(stretched)
    assert result.converged
    steps = np.abs(np.diff(result.path, axis=0))
    assert np.all(np.isfinite(result.path)) and np.all(steps <= rate_step + 1e-12)
    # a target straight out beyond the stretched tip: a clear refusal, no NaN, bounded steps
    tip = ur5.placement(stretched, "tool0")
    beyond = tip.copy()
    beyond[:3, 3] += 0.3 * (tip[:3, 3] - ur5.placement(stretched, "shoulder_link")[:3, 3]) / np.linalg.norm(tip[:3, 3] - ur5.placement(stretched, "shoulder_link")[:3, 3])
    task = Task("tool0", beyond, weights=np.array([1, 1, 1, 0, 0, 0.0]))
    result = Servo(ur5, [task], options).run(stretched)
    assert not result.converged
    assert np.all(np.isfinite(result.path)) and np.all(np.abs(np.diff(result.path, axis=0)) <= rate_step + 1e-12)
    assert 0.1 < result.best_position_errors[0] <= 0.3
    assert result.reason.startswith("the chain is at a singular pose") and result.reason.endswith("out of reach")
    with pytest.raises(OutOfWorkspace, match=r"^link 'tool0' did not reach its target: closest 0\.\d+ m after \d+ iterations; the chain is at a singular pose"):
        track(ur5, task, stretched)


def test_error_falls_monotonically_without_overshoot(panda):
    theta0 = panda.mid_range()
    start = panda.placement(theta0, "panda_hand")
    goal = start.copy()
    goal[:3, 3] += [0.05, -0.03, 0.02]
    goal[:3, :3] = matrix_from_rotvec([0.0, 0.0, 0.2]) @ start[:3, :3]
    options = ServoOptions(gain=0.5)
    servo = Servo(panda, [Task("panda_hand", goal)], options)
    result = servo.run(theta0)
    assert result.converged
    assert np.all(np.diff(result.merit_history) < 0)
    # aperiodic: the error keeps the direction it started with, shrinking, never crossing zero
    E0 = servo.task_error(result.path[0], 0)
    along = [servo.task_error(th, 0) @ E0 / (E0 @ E0) for th in result.path]
    assert along[0] == pytest.approx(1.0)
    assert np.all(np.array(along) > -1e-9)
    assert np.all(np.diff(along) < 1e-9)


def test_selective_control_position_only(panda):
    rng = np.random.default_rng(4)
    goal = panda.placement(panda.random(rng), "panda_hand")
    w = np.array([1, 1, 1, 0, 0, 0.0])
    result = track(panda, Task("panda_hand", goal, weights=w), panda.mid_range(), ServoOptions(restarts=5))
    _check_reached(panda, result.theta, "panda_hand", goal, weights=w)
    # a single selected rotation component in the link's own basis (keep the tool's z-axis
    # direction, spin free) together with the position
    w2 = np.array([1, 1, 1, 1, 1, 0.0])
    result = track(panda, Task("panda_hand", goal, weights=w2, basis="local"), panda.mid_range(), ServoOptions(restarts=5))
    P = panda.placement(result.theta, "panda_hand")
    assert np.linalg.norm(P[:3, 3] - goal[:3, 3]) <= TOL
    assert np.linalg.norm(P[:3, 2] - goal[:3, 2]) <= 2 * TOL


def _talos_targets(talos, seed):
    rng = np.random.default_rng(seed)
    theta = talos.mid_range()
    arms = [i for i, n in enumerate(talos.joint_names) if n.startswith(("arm", "torso"))]
    theta[arms] = talos.random(rng, margin=0.05)[arms]
    return theta


def test_tree_both_arms_of_talos_reach_together(talos):
    locked = [n for n in talos.joint_names if n.startswith(("leg", "head", "gripper"))]
    for seed in (1, 2):
        theta = _talos_targets(talos, seed)
        tasks = [Task("gripper_left_base_link", talos.placement(theta, "gripper_left_base_link")),
                 Task("gripper_right_base_link", talos.placement(theta, "gripper_right_base_link"))]
        result = track(talos, tasks, talos.mid_range(), ServoOptions(locked=locked, restarts=5, seed=seed))
        for t in tasks:
            _check_reached(talos, result.theta, t.link, t.target)
        assert np.all(result.theta[[talos.joint_names.index(n) for n in locked]] == talos.mid_range()[[talos.joint_names.index(n) for n in locked]])


def test_tree_allegro_fingertips_reach_together():
    hand = KinematicChain.from_urdf(example_robot_urdf("allegro_hand_description/urdf/allegro_right_hand.urdf"))
    tips = ["link_3.0_tip", "link_7.0_tip", "link_11.0_tip", "link_15.0_tip"]
    rng = np.random.default_rng(8)
    w = np.array([1, 1, 1, 0, 0, 0.0])
    for _ in range(3):
        theta = hand.random(rng, margin=0.05)
        tasks = [Task(t, hand.placement(theta, t), weights=w) for t in tips]
        result = track(hand, tasks, hand.mid_range(), ServoOptions(restarts=5))
        for t in tasks:
            _check_reached(hand, result.theta, t.link, t.target, weights=w)


def test_priorities_first_task_exact_when_the_second_cannot_be_met(talos):
    locked = [n for n in talos.joint_names if not n.startswith(("arm", "torso"))]
    theta = _talos_targets(talos, 3)
    left = Task("gripper_left_base_link", talos.placement(theta, "gripper_left_base_link"), priority=0)
    far = np.eye(4)
    far[:3, 3] = [3.0, -1.0, 1.0]
    right = Task("gripper_right_base_link", far, priority=1, weights=np.array([1, 1, 1, 0, 0, 0.0]))
    result = Servo(talos, [left, right], ServoOptions(locked=locked, max_iterations=300)).run(talos.mid_range())
    assert not result.converged
    assert result.position_errors[0] <= TOL and result.rotation_errors[0] <= TOL
    assert result.position_errors[1] > 1.0


def test_control_in_a_moving_local_frame(talos):
    """The left gripper's target is given in the right gripper's frame, which moves too."""
    locked = [n for n in talos.joint_names if not n.startswith(("arm", "torso"))]
    for seed in (4, 5):
        theta = _talos_targets(talos, seed)
        rel = talos.relative_placement(theta, "gripper_left_base_link", "gripper_right_base_link")
        task = Task("gripper_left_base_link", rel, frame="gripper_right_base_link")
        result = track(talos, task, talos.mid_range(), ServoOptions(locked=locked, restarts=5, seed=seed))
        _check_reached(talos, result.theta, task.link, rel, frame="gripper_right_base_link")


def test_tiago_arm_with_prismatic_torso():
    tiago = KinematicChain.from_urdf(TIAGO)
    locked = [n for n in tiago.joint_names if not n.startswith(("arm", "torso"))]
    rng = np.random.default_rng(12)
    for k in range(3):
        theta = tiago.mid_range()
        movable = [i for i, n in enumerate(tiago.joint_names) if n not in locked]
        theta[movable] = tiago.random(rng, margin=0.05)[movable]
        goal = tiago.placement(theta, "wrist_ft_tool_link")
        result = track(tiago, Task("wrist_ft_tool_link", goal), tiago.mid_range(),
                       ServoOptions(locked=locked, restarts=10, seed=k))
        _check_reached(tiago, result.theta, "wrist_ft_tool_link", goal)


def test_trajectory_line_with_slerp(ur5):
    theta0 = np.array([0.2, -1.2, 1.4, -0.8, -1.5, 0.3])
    a = ur5.placement(theta0, "tool0")
    b = a.copy()
    b[:3, 3] += [0.1, 0.15, -0.05]
    b[:3, :3] = matrix_from_rotvec([0.0, 0.3, 0.2]) @ a[:3, :3]
    res = follow_trajectory(ur5, "tool0", np.array([0.0, 2.0]), np.array([a, b]), theta0=theta0)
    assert res.times[0] == 0.0 and res.times[-1] == 2.0
    assert np.all(res.position_errors <= TOL) and np.all(res.rotation_errors <= TOL)
    # every sample lies on the straight segment, at most 5 mm / 0.02 rad from the previous one
    P = np.array([ur5.placement(th, "tool0")[:3, 3] for th in res.thetas])
    d = b[:3, 3] - a[:3, 3]
    s = (P - a[:3, 3]) @ d / (d @ d)
    assert np.allclose(a[:3, 3] + s[:, None] * d, P, atol=2 * TOL)
    assert np.all(np.diff(s) > 0) and np.max(np.linalg.norm(np.diff(P, axis=0), axis=1)) <= 0.005 + 1e-9
    assert np.allclose(s, res.times / 2.0, atol=1e-6)


def test_trajectory_in_an_externally_moving_frame(panda):
    """A target fixed in a frame that turns about the base's z axis (a turntable)."""
    theta0 = panda.mid_range()
    P0 = panda.placement(theta0, "panda_hand")

    def turntable(t):
        M = np.eye(4)
        M[:3, :3] = matrix_from_rotvec([0.0, 0.0, 0.3 * t])
        return M

    res = follow_trajectory(panda, "panda_hand", np.array([0.0, 1.0]), np.array([P0, P0]), theta0=theta0,
                            moving_frame=turntable, max_angular_step=0.01)
    assert res.times.size >= 30
    for t, th in zip(res.times, res.thetas):
        goal = turntable(t) @ P0
        _check_reached(panda, th, "panda_hand", goal)


@pytest.mark.parametrize("cost", ["mid_range", "manipulability", "joint_limits"])
def test_secondary_cost_falls_in_the_null_space(panda, cost):
    """Panda is redundant by one joint: after the target is met, the secondary cost keeps
    falling along the self-motion while the target stays met."""
    rng = np.random.default_rng(2)
    fell = 0
    for k in range(3):
        goal = panda.placement(panda.random(rng, margin=0.1), "panda_hand")
        options = ServoOptions(secondary=cost, refine_iterations=30, restarts=5, seed=k)
        servo = Servo(panda, [Task("panda_hand", goal)], options)
        result = servo.run(panda.mid_range())
        assert result.converged
        _check_reached(panda, result.theta, "panda_hand", goal)
        assert result.secondary_cost <= result.secondary_cost_before
        assert result.secondary_cost == pytest.approx(servo.secondary_value(result.theta))
        # the refining steps are servo steps too: within the rate limits, and in the path
        assert np.all(np.abs(np.diff(result.path, axis=0)) <= panda.rate * options.dt + 1e-12)
        assert len(result.path) >= result.iterations + result.refine_iterations + 1
        fell += result.secondary_cost < result.secondary_cost_before - 1e-6
    assert fell >= 2


def test_caps_stop_the_servo_with_a_reason(ur5):
    goal = ur5.placement(np.array([0.3, -1.0, 1.2, -0.5, 0.8, 0.1]), "tool0")
    result = Servo(ur5, [Task("tool0", goal)], ServoOptions(max_iterations=3)).run(ur5.neutral())
    assert not result.converged and result.iterations == 3
    assert result.reason.startswith("stopped at the iteration cap (3)")
    result = Servo(ur5, [Task("tool0", goal)], ServoOptions(max_seconds=1e-9)).run(ur5.neutral())
    assert not result.converged and result.iterations <= 1
    assert result.reason.startswith("stopped at the time cap")
