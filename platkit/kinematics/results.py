"""What the kinematic solvers return: one forward solution, a batch of them, the conditioning of
a pose. Lengths in metres, angles in radians."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.geometry import matrix_from_quat, rpy_from_quat


@dataclass
class ForwardResult:
    """One forward-kinematics solution. Lengths in metres, angles in radians."""

    p: np.ndarray  # (n_p,) pose coordinates
    q: np.ndarray  # (4,) orientation, w x y z
    X: np.ndarray  # (3,) position, m
    iterations: int
    residual: float  # final |F| (a redundant stand: |F| weighted by the rows' plausible misfit)
    on_branch: bool
    #: a stand with more residual rows than pose coordinates: each row's residual at the
    #: least-squares pose (n_r,), in the rows' units (SI); None for a square stand (rows close)
    misfit: np.ndarray | None = None
    #: the rows' plausible misfit (n_r,) as the stand declares it, None where it declares none
    plausible: np.ndarray | None = None

    @property
    def misfit_ratio(self) -> float:
        """The worst row's |misfit| over its plausible misfit (0 for a square stand; at most 1
        for an accepted solution); NaN where the stand declares no plausible misfit."""
        if self.misfit is None:
            return 0.0
        if self.plausible is None:
            return float("nan")
        return float(np.max(np.abs(self.misfit) / self.plausible))

    @property
    def rpy(self) -> np.ndarray:
        return rpy_from_quat(self.q)

    @property
    def R(self) -> np.ndarray:
        return matrix_from_quat(self.q)


@dataclass
class ForwardBatch:
    """Batched forward kinematics. Arrays have a leading axis N."""

    p: np.ndarray  # (N, n_p)
    q: np.ndarray  # (N, 4)
    X: np.ndarray  # (N, 3)
    iterations: np.ndarray  # (N,)
    residual: np.ndarray  # (N,)
    converged: np.ndarray  # (N,) bool (a redundant stand: False where rows miss beyond their plausible misfit)
    on_branch: np.ndarray  # (N,) bool
    misfit: np.ndarray | None = None  # (N, n_r) rows' residual of a redundant stand, SI; None if square


@dataclass
class Conditioning:
    """How far a pose is from a (forward) singularity.

    The matrix studied is the inverse velocity Jacobian ``J`` (control rates per unit motion):
    u' = J t with t the twist (v, omega) for six-coordinate stands, else the coordinate rates
    p'. Angular columns are divided by ``characteristic_length`` so that every column is a
    rate per metre of motion (Angeles' characteristic length, chosen where the neutral pose is
    best conditioned). At a forward singularity J loses rank: ``sigma_min`` -> 0.
    """

    condition_number: float  # sigma_max / sigma_min of the scaled J (1 = isotropic)
    sigma_min: float  # smallest singular value (control units per metre)
    sigma_max: float
    inverse_condition: float  # sigma_min / sigma_max, in [0, 1]; 0 at a singularity
    distance_to_singularity: float  # first-order estimate of the scaled pose distance (m) to sigma_min = 0
    characteristic_length: float  # m
    direction: np.ndarray  # (n,) the motion (scaled twist) that the controls feel least
