"""Settled poses: one row per command, markers averaged over the window where the stand was still.

This is the hand-over between reading sessions (session.py, settle.py) and estimation: every
estimator, diagnosis and `predict` take a :class:`PoseSet`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class PoseSet:
    """N settled poses of one stand, seen by M markers.

    Attributes (SI inside):
        platform: stand name; description: description file or None (the stand's default).
        controls: (N, n_u) in the stand's internal units (metres for 'm' controls).
        markers: (N, M, 3) metres, motion-capture frame; NaN where a marker was not seen.
        marker_names: M names. base_markers: optional (B, 3) m, markers fixed to the base.
        t: (N,) seconds, the time each command was sent (NaN if unknown).
        n_samples: (N, M) samples averaged per marker (0 for unseen), or None.
        length_unit: the session's declared unit ('mm' or 'm'), used for reporting only.
        moving_link: the link carrying the markers (URDF stands), or None; on a tree the
            session's mapping {marker or rigid body: link}.
        marker_links: {marker or rigid body: link it rides on} on a tree (from a mapping
            ``moving_link``); empty where every marker and body rides on the stand's moving frame.
        source: where the data came from (a path, or 'simulated').
        dropped: list of (row, reason) for commands that gave no pose.
        settling: what the settling search found over the whole session (sigma_m, n_commands,
            n_extrapolated, unsettled: which actuators and markers never settled, their time
            constant, a sentence); empty for poses read as they are.
        extras: free-form per-pose arrays (e.g. 'direction' for history effects), length N.
        bodies: (N, B, 7) rigid bodies measured in 6 DOF: origin x, y, z (m) and orientation
            qw, qx, qy, qz (unit quaternion), both in the motion-capture frame; all seven NaN
            where the body was not seen. body_names: B names. n_body_samples: (N, B) samples
            averaged per body (0 for unseen), or None.
        body_noise: declared noise of the bodies ({'position_m', 'rotation_rad'}: per-axis
            sigmas), or empty: the estimator then estimates their ratio from the data.
    """

    platform: str
    controls: np.ndarray
    markers: np.ndarray
    marker_names: list[str]
    description: str | None = None
    base_markers: np.ndarray | None = None
    t: np.ndarray | None = None
    n_samples: np.ndarray | None = None
    length_unit: str = "mm"
    moving_link: str | dict | None = None
    source: str = ""
    dropped: list[tuple[int, str]] = field(default_factory=list)
    extras: dict[str, np.ndarray] = field(default_factory=dict)
    settling: dict = field(default_factory=dict)  # what the settling search found (calibrate.settle), session-wide
    bodies: np.ndarray | None = None
    body_names: list[str] = field(default_factory=list)
    n_body_samples: np.ndarray | None = None
    body_noise: dict = field(default_factory=dict)
    marker_links: dict = field(default_factory=dict)

    def __post_init__(self):
        if not self.marker_links and isinstance(self.moving_link, dict):
            self.marker_links = dict(self.moving_link)
        self.controls = np.atleast_2d(np.asarray(self.controls, float))
        self.markers = np.asarray(self.markers, float)
        if self.markers.ndim != 3 or self.markers.shape[2] != 3:
            raise ValueError(f"markers must be (N, M, 3), got {self.markers.shape}")
        if self.markers.shape[0] != self.controls.shape[0]:
            raise ValueError("controls and markers must have the same number of rows")
        if len(self.marker_names) != self.markers.shape[1]:
            raise ValueError("one marker name per marker column")
        if self.t is None:
            self.t = np.full(len(self.controls), np.nan)
        if self.bodies is None:
            self.bodies = np.full((self.markers.shape[0], len(self.body_names), 7), np.nan)  # unseen
        self.bodies = np.asarray(self.bodies, float)
        if self.bodies.ndim != 3 or self.bodies.shape[2] != 7 or self.bodies.shape[0] != self.markers.shape[0]:
            raise ValueError(f"bodies must be (N, B, 7) with N = {self.markers.shape[0]}, got {self.bodies.shape}")
        if len(self.body_names) != self.bodies.shape[1]:
            raise ValueError("one body name per body")

    @property
    def n_poses(self) -> int:
        return self.controls.shape[0]

    @property
    def n_markers(self) -> int:
        return self.markers.shape[1]

    @property
    def n_bodies(self) -> int:
        return len(self.body_names)

    def subset(self, rows) -> "PoseSet":
        """The poses at ``rows`` (index array or boolean mask), in that order."""
        rows = np.asarray(rows)
        if rows.dtype == bool:
            rows = np.nonzero(rows)[0]
        return PoseSet(
            platform=self.platform, controls=self.controls[rows], markers=self.markers[rows],
            marker_names=list(self.marker_names), description=self.description,
            base_markers=self.base_markers, t=None if self.t is None else self.t[rows],
            n_samples=None if self.n_samples is None else self.n_samples[rows],
            length_unit=self.length_unit, moving_link=self.moving_link, source=self.source,
            dropped=[], extras={k: np.asarray(v)[rows] for k, v in self.extras.items()}, settling=dict(self.settling),
            bodies=np.asarray(self.bodies)[rows] if self.body_names else None, body_names=list(self.body_names),
            n_body_samples=None if self.n_body_samples is None else self.n_body_samples[rows],
            body_noise=dict(self.body_noise), marker_links=dict(self.marker_links),
        )

    def links_of(self, tracked: list[str]) -> list[int]:
        """Index in ``tracked`` (a spec's tracked links; the first is its moving frame) of the link
        each marker, then each rigid body, rides on: (M + B,) ints; all 0 without a mapping.
        ValueError naming a marker or body with no link, or a link that is not tracked."""
        if not self.marker_links:
            return [0] * (self.n_markers + self.n_bodies)
        out = []
        for name in list(self.marker_names) + list(self.body_names):
            link = self.marker_links.get(name)
            if link is None:
                raise ValueError(f"marker or rigid body {name!r} is not mapped to a link in moving_link")
            if link not in tracked:
                raise ValueError(f"{name!r} rides on link {link!r}, which the stand does not track ({tracked})")
            out.append(tracked.index(link))
        return out
