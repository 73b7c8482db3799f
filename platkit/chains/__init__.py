"""Serial and tree-shaped chains: velocity Jacobian from twists, inverse velocity, tracking servo.

After Sorokin, "Tensor tracking system" (2017); see docs/chains.md.
"""
from platkit.chains.chain import Joint, KinematicChain, read_urdf_text
from platkit.chains.servo import Servo, track
from platkit.chains.solve import Damping, Level, solve_lp, solve_pinv
from platkit.chains.tasks import ServoOptions, ServoResult, Task, parse_selection
from platkit.chains.trajectory import TrajectoryResult, densify, follow_trajectory

__all__ = [
    "Damping", "Joint", "KinematicChain", "Level", "Servo", "ServoOptions", "ServoResult", "Task",
    "TrajectoryResult", "densify", "follow_trajectory", "parse_selection", "read_urdf_text",
    "solve_lp", "solve_pinv", "track",
]
