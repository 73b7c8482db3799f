"""Model terms: physics added on top of the geometric model, each with its own parameters.

The estimator (estimate.py) fits td, the base-to-mocap transform, the marker positions and the
parameters ``theta`` of any number of terms together. Diagnosis (platkit/diagnose) builds terms
from the effect library (the effects' plugins: a play in a drive, a bend under load, a thermal
drift, ...) and refits with them; a
calibration.yaml stores the accepted terms so that `predict` reproduces them.

A term acts at up to three places, each a numpy function of theta and the pose set (per pose,
so history- and time-dependent effects see the row order, ``poses.t`` and ``poses.extras``):

- ``control_offset``: added to the controls before kinematics, (N, n_u) in internal units;
- ``pose_offset``: a small motion of the moving frame after kinematics, (N, 6): translation
  (m) then rotation vector (rad), both in the base frame, applied as X' = X + dX,
  R' = exp(dtheta) R;
- ``marker_offset``: added to the marker positions in the moving frame, (N, M, 3) m.

Defaults are exact zeros (a term overrides the places where it acts). Jacobians with respect
to theta are taken by the estimator (finite differences over theta: terms have few parameters).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from platkit.poses import PoseSet


@dataclass
class ModelTerm:
    """Base class: a named extra-physics term with parameters ``theta``.

    Subclasses set ``effect`` (the name of the diagnosis effect it belongs to), ``parameter_names``
    (len K), ``initial`` (K,), ``units`` (K,), ``where`` (what it is attached to: an actuator,
    marker, time span), and override one or more of the offset methods.
    """

    effect: str
    parameter_names: list[str]
    initial: np.ndarray
    units: list[str] = field(default_factory=list)
    where: dict[str, Any] = field(default_factory=dict)
    #: whether the term reads the forward kinematics (``fk_q``, ``fk_X`` of :meth:`pose_offset` and
    #: :meth:`offset_jacobians`); a term that never does sets False: the estimator then passes
    #: None for them and, where no term of a model reads them, does not compute them
    uses_kinematics = True  # a class attribute (not a field): no annotation
    #: whether the term's control offsets are actuators moving apart in time (a stream's response):
    #: a stand with more rows than pose coordinates then takes its rows' weighted least-squares pose
    #: whatever their misfit (the physical plate, as the simulator's), not refused beyond the plausible
    physical_misfit = False

    def control_offset(self, theta: np.ndarray, poses: PoseSet, n_u: int) -> np.ndarray:
        return np.zeros((poses.n_poses, n_u))

    def pose_offset(self, theta: np.ndarray, poses: PoseSet, fk_q: np.ndarray, fk_X: np.ndarray) -> np.ndarray:
        return np.zeros((poses.n_poses, 6))

    def marker_offset(self, theta: np.ndarray, poses: PoseSet) -> np.ndarray:
        return np.zeros((poses.n_poses, poses.n_markers, 3))

    def prior(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(centre (K,), weight (K,)): a Gaussian prior on theta, entered by the estimator as rows
        ``weight * (theta - centre)`` beside the marker residuals (metres), like the calibration's
        ridge on td (CalibrationProblem.prior_rows): weight = marker noise (m) / the parameter's
        prior standard deviation; 0 where a parameter has none. None (the default): no prior."""
        return None

    def level_tilt(self, theta: np.ndarray) -> np.ndarray | None:
        """(2,) rad: how far the term turns the whole stand about its base's x and y axes in the
        level world, or None (the default) for a term that does not. The motion capture cannot see
        such a turn (its transform absorbs it); an IMU's accelerometer reads it against gravity."""
        return None

    def offset_jacobians(self, theta: np.ndarray, poses: PoseSet, n_u: int, fk_q: np.ndarray,
                         fk_X: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None] | None:
        """The offsets' derivatives in ``theta`` (K,): (control (N, n_u, K), pose (N, 6, K),
        marker (N, M, 3, K)), for a term that knows them (a term linear in theta; control, pose or
        marker None where the term has no such offset: zero); None, the default: the estimator takes
        them by finite differences."""
        return None

    def to_dict(self, theta: np.ndarray, std: np.ndarray | None = None) -> dict:
        """What calibration.yaml stores; ``from_dict`` of the effect rebuilds the term."""
        return {
            "effect": self.effect,
            "where": self.where,
            "parameters": {
                n: {"value": float(v), "std": None if std is None else float(s), "unit": u}
                for n, v, s, u in zip(self.parameter_names, theta, std if std is not None else theta, self.units or [""] * len(theta))
            },
        }
