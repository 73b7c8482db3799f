"""The compiled one-target servo loop (platkit.chains.native_servo) against the Python loop it
replaces (Servo._fast_attempt): the same outcome, iterations, solution and reasons on fixed-seed
UR5 and Panda targets; and the Python loop serving alone without a C compiler or with
PLATKIT_COMPILE=0."""
from __future__ import annotations

import numpy as np
import pytest
from native_cache import native_cache_fixtures
from reference_robots import example_robot_urdf

from platkit.chains import KinematicChain, Servo, ServoOptions, Task, native_servo

ROBOTS = [("ur_description/urdf/ur5_robot.urdf", "tool0"), ("panda_description/urdf/panda.urdf", "panda_hand")]

module_cache, cache, empty_cache = native_cache_fixtures(native_servo, "servo_cache")


def _both(chain, task, theta0, **options):
    compiled = Servo(chain, [task], ServoOptions(**options))
    python = Servo(chain, [task], ServoOptions(**options))
    python.compile = False
    a, b = compiled.run(theta0), python.run(theta0)
    assert compiled._compiled is not None and python._compiled is None
    return a, b


def _assert_same(a, b):
    assert a.converged == b.converged
    assert abs(a.iterations - b.iterations) <= 2
    if a.converged:
        assert np.max(np.abs(a.theta - b.theta)) <= 1e-8
        assert a.position_error <= 1e-6 and a.rotation_error <= 1e-6
    if a.iterations == b.iterations:
        assert a.reason == b.reason
        assert a.path.shape == b.path.shape and len(a.merit_history) == len(b.merit_history) == a.path.shape[0]
        assert np.allclose(a.merit_history, b.merit_history, rtol=1e-6, atol=1e-20)
        assert np.allclose(a.best_position_errors, b.best_position_errors, rtol=1e-6, atol=1e-15)


@pytest.mark.parametrize("urdf, link", ROBOTS)
@pytest.mark.parametrize("rate_limits", [True, False])
def test_compiled_loop_takes_the_python_loops_steps(cache, urdf, link, rate_limits):
    chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
    rng = np.random.default_rng(11)
    outcomes = []
    for _ in range(8):
        target = chain.placement(chain.random(rng), link)
        a, b = _both(chain, Task(link, target), chain.mid_range(), use_rate_limits=rate_limits)
        _assert_same(a, b)
        assert np.all(a.theta >= chain.lower - 1e-12) and np.all(a.theta <= chain.upper + 1e-12)
        outcomes.append(a.converged)
    assert any(outcomes)
    assert list(cache.glob("servo_*.so")), "the compiled loop is not in the cache"


MIXED = """<robot name="mixed">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="l4"/><link name="l5"/>
  <link name="l6"/><link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="2"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.2" rpy="0.1 0.2 0.3"/>
    <axis xyz="1 1 0"/><limit lower="-0.2" upper="0.3" effort="1" velocity="0.5"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0.1 0 0.2" rpy="0 0.5 0"/>
    <axis xyz="0.3 0.5 0.81"/><limit lower="-2" upper="2" effort="1" velocity="2"/></joint>
  <joint name="j4" type="continuous"><parent link="l3"/><child link="l4"/><origin xyz="0 0.1 0.2"/>
    <axis xyz="1 0 0"/><limit effort="1" velocity="3"/></joint>
  <joint name="j5" type="revolute"><parent link="l4"/><child link="l5"/><origin xyz="0 0 0.15" rpy="0.3 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="2"/></joint>
  <joint name="j6" type="revolute"><parent link="l5"/><child link="l6"/><origin xyz="0.05 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="2"/></joint>
  <joint name="j7" type="fixed"><parent link="l6"/><child link="tip"/><origin xyz="0 0.02 0.08" rpy="0.1 0 0.2"/></joint>
</robot>"""


def test_prismatic_unaligned_and_continuous_joints(cache):
    """A prismatic joint on a slanted axis, a revolute joint about an unaligned axis, a
    continuous joint (pinocchio stores it as cos, sin) and a link behind a fixed joint: the
    compiled forward kinematics and Jacobian take the Python loop's steps."""
    chain = KinematicChain.from_urdf_text(MIXED)
    rng = np.random.default_rng(9)
    outcomes = []
    for _ in range(8):
        target = chain.placement(chain.random(rng), "tip")
        a, b = _both(chain, Task("tip", target), chain.mid_range())
        _assert_same(a, b)
        outcomes.append(a.converged)
    assert sum(outcomes) >= 4


def test_weights_selection_gain_and_locked_joints(cache):
    """Rows weighted and left free, a gain below 1, a locked joint, restarts: the same steps."""
    chain = KinematicChain.from_urdf(example_robot_urdf(ROBOTS[1][0]))
    rng = np.random.default_rng(5)
    for k in range(6):
        target = chain.placement(chain.random(rng), "panda_hand")
        weights = [np.array([1, 1, 1, 0, 0, 0.0]), np.array([2, 1, 1, 0.5, 0.5, 3.0])][k % 2]
        a, b = _both(chain, Task("panda_hand", target, weights=weights), chain.mid_range(), gain=0.7,
                     locked=["panda_joint7"] if k >= 3 else (), restarts=2)
        _assert_same(a, b)
        assert a.restarts == b.restarts and a.iterations_total == b.iterations_total


@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-7, 1e-9, 0.0])
def test_the_rotation_error_is_pinocchios_log3_near_zero_and_pi(cache, angle):
    """The first merit (from log3 of the rotation between the start and the target) agrees
    where log3 switches formulas: a half turn, just under it, and almost no rotation."""
    chain = KinematicChain.from_urdf(example_robot_urdf(ROBOTS[0][0]))
    theta0 = chain.mid_range()
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
    target = chain.placement(theta0, "tool0")
    target[:3, :3] = R @ target[:3, :3]
    target[:3, 3] += 0.01
    a, b = _both(chain, Task("tool0", target), theta0, max_iterations=3)
    assert a.merit_history[0] == pytest.approx(b.merit_history[0], rel=1e-12, abs=1e-300)
    _assert_same(a, b)


def test_the_caps_stop_the_compiled_loop_with_the_same_reasons(cache):
    chain = KinematicChain.from_urdf(example_robot_urdf(ROBOTS[0][0]))
    target = chain.placement(chain.random(np.random.default_rng(2)), "tool0")
    a, b = _both(chain, Task("tool0", target), chain.mid_range(), max_iterations=4)
    assert not a.converged and a.iterations == b.iterations == 4
    assert a.reason == b.reason and a.reason.startswith("stopped at the iteration cap (4)")
    a, b = _both(chain, Task("tool0", target), chain.mid_range(), max_seconds=1e-9)
    assert not a.converged and a.iterations == b.iterations == 0
    assert a.reason.startswith("stopped at the time cap") and b.reason.startswith("stopped at the time cap")
    # more iterations than one chunk: the chunks carry the count, the stall and best state on
    long = Servo(chain, [Task("tool0", target)], ServoOptions(max_iterations=3 * native_servo.CHUNK, gain=0.02,
                                                               stall_iterations=10 * native_servo.CHUNK))
    slow = Servo(chain, [Task("tool0", target)], ServoOptions(max_iterations=3 * native_servo.CHUNK, gain=0.02,
                                                               stall_iterations=10 * native_servo.CHUNK))
    slow.compile = False
    a, b = long.run(chain.mid_range()), slow.run(chain.mid_range())
    assert a.iterations > native_servo.CHUNK
    _assert_same(a, b)


def test_without_a_compiler_the_python_loop_serves(empty_cache, monkeypatch):
    monkeypatch.setattr(native_servo, "_compiler", lambda: None)
    chain = KinematicChain.from_urdf(example_robot_urdf(ROBOTS[0][0]))
    target = chain.placement(chain.random(np.random.default_rng(3)), "tool0")
    servo = Servo(chain, [Task("tool0", target)])
    result = servo.run(chain.mid_range())
    assert servo._compiled is None and "no C compiler" in native_servo.compiled_servo_reason()
    assert result.iterations > 0 and (result.converged or result.reason)
    assert not any(empty_cache.iterdir()), "nothing is written without a compiler"


def test_platkit_compile_0_keeps_the_python_loop(empty_cache, monkeypatch):
    monkeypatch.setenv("PLATKIT_COMPILE", "0")
    chain = KinematicChain.from_urdf(example_robot_urdf(ROBOTS[1][0]))
    target = chain.placement(chain.random(np.random.default_rng(4)), "panda_hand")
    servo = Servo(chain, [Task("panda_hand", target)])
    servo.run(chain.mid_range())
    assert servo._compiled is None and not any(empty_cache.iterdir())


def test_the_compiler_is_there_for_the_compiled_path():
    # CI and the development machines have a C compiler: its absence is a failure here, not a
    # skip (the path without one is tested above with the compiler patched away)
    assert native_servo._compiler() is not None, "no C compiler (cc, gcc or clang) to test the compiled path"
