"""The servo's fast attempt (one world target, the pseudo-inverse, no secondary cost) against
its general loop: the same steps, so the same outcome, on UR5 and Panda targets."""
from __future__ import annotations

import numpy as np
import pytest
from reference_robots import example_robot_urdf

from platkit.chains import KinematicChain, Servo, ServoOptions, Task

ROBOTS = [("ur_description/urdf/ur5_robot.urdf", "tool0"), ("panda_description/urdf/panda.urdf", "panda_hand")]


@pytest.mark.parametrize("urdf, link", ROBOTS)
@pytest.mark.parametrize("rate_limits", [True, False])
def test_fast_attempt_takes_the_general_loops_steps(urdf, link, rate_limits):
    chain = KinematicChain.from_urdf(example_robot_urdf(urdf))
    rng = np.random.default_rng(7)
    outcomes = []
    for _ in range(6):
        target = chain.placement(chain.random(rng), link)
        fast = Servo(chain, [Task(link, target)], ServoOptions(use_rate_limits=rate_limits))
        assert fast._fast is not None
        general = Servo(chain, [Task(link, target)], ServoOptions(use_rate_limits=rate_limits))
        general._fast = None  # the general loop, errors and Jacobians assembled joint by joint
        a, b = fast.run(chain.mid_range()), general.run(chain.mid_range())
        assert a.converged == b.converged
        assert abs(a.iterations - b.iterations) <= 1
        assert np.all(a.theta >= chain.lower - 1e-12) and np.all(a.theta <= chain.upper + 1e-12)
        if a.converged:
            assert a.position_error <= 1e-6 and a.rotation_error <= 1e-6
            assert np.allclose(a.path[0], b.path[0]) and len(a.merit_history) == a.iterations + 1
        outcomes.append(a.converged)
    assert any(outcomes)
