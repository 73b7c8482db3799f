"""What the tracking servo is asked and what it answers: tasks (a link, its target, the frame and
basis it is read in, weights and priority), the servo's options, its result, and the one-line
messages a failed result becomes. The servo itself is :mod:`platkit.chains.servo`; following a
dense trajectory is :mod:`platkit.chains.trajectory`.

Units: metres and radians; time in seconds.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from platkit.chains.solve import Damping
from platkit.errors import BadInput

COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")
SECONDARY_COSTS = ("none", "mid_range", "joint_limits", "manipulability")


def parse_selection(text: str) -> np.ndarray:
    """'xyz', 'x,y,rz', 'all' -> a 0/1 mask (6,) over (x, y, z, rx, ry, rz)."""
    t = text.replace(",", "").replace(" ", "").lower()
    if t in ("", "all"):
        return np.ones(6)
    mask = np.zeros(6)
    i = 0
    while i < len(t):
        tok = t[i:i + 2] if t[i] == "r" else t[i]
        if tok not in COMPONENTS:
            raise BadInput(f"--select: unknown component {tok!r} in {text!r}; use x, y, z, rx, ry, rz (e.g. 'xyz' or 'xyzrz')")
        mask[COMPONENTS.index(tok)] = 1.0
        i += len(tok)
    return mask


@dataclass
class Task:
    """Drive ``link`` to ``target`` (4, 4), a placement given in ``frame`` ('world' or a link).

    ``weights`` (6,) over (x, y, z, rx, ry, rz): 0 leaves a component free (selective control),
    larger weights trade harder within a priority level. ``basis``: components read in the
    ``frame``'s basis ('reference') or in the link's own ('local'). ``priority``: 0 first;
    higher levels act only in the null space of lower ones.
    """

    link: str
    target: np.ndarray
    frame: str = "world"
    weights: np.ndarray = field(default_factory=lambda: np.ones(6))
    basis: str = "reference"
    priority: int = 0

    def __post_init__(self):
        self.target = np.asarray(self.target, float)
        self.weights = np.asarray(self.weights, float)
        if self.target.shape != (4, 4):
            raise BadInput(f"task {self.link!r}: target must be a 4x4 transform")
        if self.weights.shape != (6,) or np.any(self.weights < 0) or not np.any(self.weights > 0):
            raise BadInput(f"task {self.link!r}: weights must be 6 non-negative numbers, not all zero")
        if self.basis not in ("reference", "local"):
            raise BadInput(f"task {self.link!r}: basis must be 'reference' or 'local', got {self.basis!r}")


@dataclass
class ServoOptions:
    """Tolerances, caps and the solver of the servo (SI units)."""

    tol_position: float = 1e-6       # m
    tol_rotation: float = 1e-6       # rad
    max_iterations: int = 500
    max_seconds: float = 30.0
    gain: float = 1.0                # fraction of E commanded per step (<= 1: aperiodic)
    max_linear_step: float = 0.1     # m per step of the commanded twist
    max_angular_step: float = 0.5    # rad per step
    dt: float = 0.1                  # s per step: rate limits become per-step limits rate * dt
    use_rate_limits: bool = True
    solver: str = "pinv"             # 'pinv' or 'lp'
    secondary: str = "none"          # one of SECONDARY_COSTS
    secondary_gain: float = 0.05
    damping: Damping = field(default_factory=Damping)
    joint_weights: np.ndarray | None = None
    locked: Sequence[str] = ()
    stall_iterations: int = 40       # stop when the error has not fallen 1e-3 in this many steps
    restarts: int = 0                # after a failed attempt, start again from random configurations
    refine_iterations: int = 100     # with a secondary cost: null-space steps after the targets are met
    refine_step: float = 0.05        # rad (or m): largest null-space step while refining
    seed: int = 0                    # of the restarts' random configurations

    def check(self) -> None:
        if self.solver not in ("pinv", "lp"):
            raise BadInput(f"solver must be 'pinv' or 'lp', got {self.solver!r}")
        if self.secondary not in SECONDARY_COSTS:
            raise BadInput(f"secondary cost must be one of {', '.join(SECONDARY_COSTS)}, got {self.secondary!r}")
        if not (0 < self.gain <= 1):
            raise BadInput(f"gain must be in (0, 1], got {self.gain}")
        for name in ("tol_position", "tol_rotation", "max_seconds", "max_linear_step", "max_angular_step", "dt"):
            if not getattr(self, name) > 0:
                raise BadInput(f"{name} must be positive, got {getattr(self, name)}")
        if self.max_iterations < 1:
            raise BadInput(f"max_iterations must be at least 1, got {self.max_iterations}")


@dataclass
class ServoResult:
    """Outcome of the servo: the final configuration (n,), its path (k+1, n) over the steps,
    per task the position error (m) and rotation error (rad) over the selected components,
    and, when it failed, one sentence saying why."""

    theta: np.ndarray
    converged: bool
    iterations: int
    position_errors: list[float]
    rotation_errors: list[float]
    path: np.ndarray
    merit_history: list[float]
    reason: str = ""
    best_position_errors: list[float] = field(default_factory=list)
    best_rotation_errors: list[float] = field(default_factory=list)
    seconds: float = 0.0
    restarts: int = 0                # attempts made before this one's start; the path is this one's
    iterations_total: int = 0        # over all attempts
    refine_iterations: int = 0       # null-space steps taken after convergence (secondary cost)
    secondary_cost: float | None = None  # H at the start of refinement and at the end: see refine
    secondary_cost_before: float | None = None

    @property
    def position_error(self) -> float:
        return max(self.position_errors)

    @property
    def rotation_error(self) -> float:
        return max(self.rotation_errors)


def closest_text(task: Task, position: float, rotation: float, unit: str = "m", scale: float = 1.0) -> str:
    """'0.123 m / 0.0456 rad' over the components the task controls."""
    parts = []
    if np.any(task.weights[:3] > 0):
        parts.append(f"{position / scale:.3g} {unit}")
    if np.any(task.weights[3:] > 0):
        parts.append(f"{rotation:.3g} rad")
    return " / ".join(parts)


def failure_message(tasks: Sequence[Task], result: ServoResult, unit: str = "m", scale: float = 1.0) -> str:
    """One sentence: which link missed, how close it got, after how many steps, and why.
    Position errors are shown in ``unit`` (``scale`` metres each)."""
    k = int(np.argmax([p + r for p, r in zip(result.best_position_errors, result.best_rotation_errors)]))
    closest = closest_text(tasks[k], result.best_position_errors[k], result.best_rotation_errors[k], unit, scale)
    return (f"link {tasks[k].link!r} did not reach its target: closest {closest} "
            f"after {result.iterations} iterations; {result.reason or 'no reason found'}")
