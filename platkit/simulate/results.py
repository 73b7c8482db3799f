"""What an additive simulation returns: the session in memory (Simulation), the true stand behind it
(Truth, written as truth.yaml) and the true motion (Trajectory)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from platkit.io.jsonout import plain
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.simulate.rigid_bodies import bodies_truth
from platkit.terms import ModelTerm

__all__ = ["Truth", "Trajectory", "Simulation"]


@dataclass
class Truth:
    """What the simulated stand really was (SI units).

    td (n_td,) true parameters; td_nominal (n_td,); mocap_from_base (4, 4); markers (M, 3) m
    in the moving frame; terms [(ModelTerm, theta)]; noise_m marker noise per coordinate;
    base_markers (B, 3) m in the base frame, or None. Rigid bodies: body_names, their placements
    on the moving part body_origins (B, 3) m and body_rotvecs (B, 3) rad (body frame -> moving
    frame), body_noise {'position_m', 'rotation_rad'} per-axis sigmas of each sample.
    """

    platform: str
    parameter_names: list[str]
    td: np.ndarray
    td_nominal: np.ndarray
    mocap_from_base: np.ndarray
    marker_names: list[str]
    markers: np.ndarray
    terms: list[tuple[ModelTerm, np.ndarray]]
    noise_m: float
    occlusion: float
    seed: int
    description: str | None = None
    base_marker_names: list[str] = field(default_factory=list)
    base_markers: np.ndarray | None = None  # (B, 3) m in the base frame
    body_names: list[str] = field(default_factory=list)
    body_origins: np.ndarray | None = None
    body_rotvecs: np.ndarray | None = None
    body_noise: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """The truth.yaml mapping (SI: metres, radians)."""
        return {
            "platform": self.platform,
            "description": self.description,
            "seed": int(self.seed),
            "units": {"length": "m", "angle": "rad"},
            "parameters": {
                n: {"value": float(v), "nominal": float(v0), "error": float(v - v0)}
                for n, v, v0 in zip(self.parameter_names, self.td, self.td_nominal)
            },
            "mocap_from_base": [[float(x) for x in row] for row in self.mocap_from_base],
            "markers": {n: [float(x) for x in s] for n, s in zip(self.marker_names, self.markers)},
            "base_markers": {n: [float(x) for x in s] for n, s in zip(self.base_marker_names,
                                                                     () if self.base_markers is None else self.base_markers)},
            "effects": [plain(term.to_dict(theta)) for term, theta in self.terms],
            "marker_noise_m": float(self.noise_m),
            "occlusion": float(self.occlusion),
            **bodies_truth(self.body_names, self.body_origins, self.body_rotvecs, self.body_noise),
        }


@dataclass
class Trajectory:
    """The true motion: command times and controls, and a way to evaluate the true pose.

    ``at(t)`` -> (q (K, 4), X (K, 3)) of the moving frame in the base frame at times t (K,),
    effects included; used for the motion-capture stream and by IMU simulation.
    """

    command_t: np.ndarray
    commands: np.ndarray
    arrive_t: np.ndarray
    end_t: float
    evaluate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]] = field(repr=False)

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q, X, _ = self.evaluate(np.asarray(t, float))
        return q, X


@dataclass
class Simulation:
    """A simulated session in memory.

    poses: the settled PoseSet (from the raw stream through settle() when raw, else drawn
    directly); truth: Truth; command_t (N,), commands (N, n_u) internal units; marker_t (K,)
    and markers (K, M, 3) m in the mocap frame (raw only); trajectory; imu: dict with t, gyr,
    acc (and optionally 'entry' for session.yaml), or None.
    """

    spec: PlatformSpec
    poses: PoseSet
    truth: Truth
    command_t: np.ndarray
    commands: np.ndarray
    marker_t: np.ndarray | None
    markers: np.ndarray | None
    trajectory: Trajectory | None
    mocap_rate_hz: float
    length_unit: str
    imu: dict | None = None
    plan_info: dict = field(default_factory=dict)
    base_markers: np.ndarray | None = None  # (K, B, 3) m, mocap frame, the stream of markers on the base
    bodies: np.ndarray | None = None  # (K, B, 7) the rigid bodies' stream (origin m, unit quaternion), mocap frame
