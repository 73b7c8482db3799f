"""Generic, deliberately unphysical terms that check a name.

A named effect is accepted only if it predicts held-out poses about as well as a flexible
model of the same kind of structure: when a probe predicts much better, the structure is real
but the library's name would be wrong, and diagnosis reports it as ``unexplained`` with the
probe's ``where``. Probes are never written to calibration.yaml.

- :class:`TimeProbe`: the moving frame translated by a piecewise-constant offset over B equal
  time bins (the first bin is the reference): any change with time.
- :class:`SpaceProbe`: the moving frame translated by a quadratic function of its nominal
  position (6 monomials per axis): any smooth error over the workspace.
- :class:`MarkerProbe`: each marker moved on the moving frame by its own offset, linear in the
  controls and in their mean squared distance from the middle of the strokes (n_u + 1 terms per
  marker and axis): a marker plate or mount that is not rigid, bending with the pose (the frame
  probes move every marker together and cannot see it).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import history
from platkit.poses import PoseSet
from platkit.terms import ModelTerm


@dataclass
class TimeProbe(ModelTerm):
    t_edges: np.ndarray | None = None
    uses_kinematics = False

    def pose_offset(self, theta, poses, fk_q, fk_X):
        t = history(poses, "elapsed")
        b = np.clip(np.searchsorted(self.t_edges, t, side="right") - 1, 0, len(self.t_edges) - 2)
        table = np.vstack([np.zeros(3), np.asarray(theta).reshape(-1, 3)])
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = table[b]
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        """Linear in theta: bin b >= 1 moves the frame along axis a by its (b - 1, a) entry."""
        t = history(poses, "elapsed")
        b = np.clip(np.searchsorted(self.t_edges, t, side="right") - 1, 0, len(self.t_edges) - 2)
        N, K = poses.n_poses, len(theta)
        d_pose = np.zeros((N, 6, K))
        for a in range(3):
            rows = np.flatnonzero(b >= 1)
            d_pose[rows, a, 3 * (b[rows] - 1) + a] = 1.0
        return None, d_pose, None  # no control or marker offset


def time_probe(poses: PoseSet, bins: int = 6) -> TimeProbe | None:
    t = history(poses, "elapsed")
    if np.ptp(t) <= 0 or poses.n_poses < 4 * bins:
        return None
    edges = np.linspace(t.min(), t.max(), bins + 1)
    edges[-1] += 1e-9
    names = [f"bin{b}_{a}" for b in range(1, bins) for a in "xyz"]
    return TimeProbe("unexplained", names, np.zeros(3 * (bins - 1)), ["m"] * len(names),
                     {"time": "piecewise constant over the session", "bins": bins}, t_edges=edges)


@dataclass
class SpaceProbe(ModelTerm):
    center: np.ndarray | None = None
    scale: float = 1.0

    def pose_offset(self, theta, poses, fk_q, fk_X):
        s = (np.asarray(fk_X) - self.center) / self.scale
        x, y, z = s.T
        mono = np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=1)  # (N, 6)
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = mono @ np.asarray(theta).reshape(6, 3)
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        """Linear in theta: monomial i moves the frame along axis a by its (i, a) entry."""
        s = (np.asarray(fk_X) - self.center) / self.scale
        x, y, z = s.T
        mono = np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=1)
        N, K = poses.n_poses, len(theta)
        d_pose = np.zeros((N, 6, K))
        for i in range(6):
            for a in range(3):
                d_pose[:, a, 3 * i + a] = mono[:, i]
        return None, d_pose, None  # no control or marker offset


def space_probe(fk_X: np.ndarray) -> SpaceProbe | None:
    X = np.asarray(fk_X, float)
    if len(X) < 30:
        return None
    scale = float(np.max(np.std(X, axis=0)))
    if scale <= 0:
        return None
    names = [f"{m}_{a}" for m in ("xx", "yy", "zz", "xy", "xz", "yz") for a in "xyz"]
    return SpaceProbe("unexplained", names, np.zeros(18), ["m"] * 18,
                      {"region": "the workspace, quadratic in the moving frame's position"},
                      center=X.mean(axis=0), scale=scale)


@dataclass
class MarkerProbe(ModelTerm):
    mid: np.ndarray | None = None
    half: np.ndarray | None = None
    n_markers: int = 0
    uses_kinematics = False

    def features(self, poses: PoseSet) -> np.ndarray:
        """(N, n_u + 1) the controls from the middle of their range (in half ranges) and the mean
        of their squares."""
        u = (np.asarray(poses.controls, float) - self.mid) / self.half
        return np.hstack([u, np.mean(u * u, axis=1, keepdims=True)])

    def marker_offset(self, theta, poses):
        f = self.features(poses)
        A = np.asarray(theta, float).reshape(self.n_markers, 3, f.shape[1])
        return np.einsum("nf,maf->nma", f, A)

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        """Linear in theta: marker m, axis a moves by the features through its own block of
        theta ((m, a, feature) order)."""
        f = self.features(poses)
        N, F = f.shape
        d_m = np.zeros((N, self.n_markers, 3, self.n_markers * 3 * F))
        for m in range(self.n_markers):
            for a in range(3):
                k = (3 * m + a) * F
                d_m[:, m, a, k:k + F] = f
        return None, None, d_m  # no control or pose offset


def marker_probe(poses: PoseSet) -> MarkerProbe | None:
    """A :class:`MarkerProbe` over ``poses``' control range; None with fewer than 30 poses, or
    with fewer poses than 4 times the parameters' share of one marker's (too few to judge it)."""
    U = np.asarray(poses.controls, float)
    M = poses.n_markers
    if len(U) < 30 or M < 2 or U.ndim != 2:
        return None
    n_f = U.shape[1] + 1
    if len(U) * M * 3 < 4 * M * 3 * n_f:
        return None
    lo, hi = U.min(axis=0), U.max(axis=0)
    half = np.where(hi > lo, 0.5 * (hi - lo), 1.0)
    names = [f"{m}_{a}_{f}" for m in poses.marker_names for a in "xyz"
             for f in [f"u{j + 1}" for j in range(n_f - 1)] + ["reach"]]
    return MarkerProbe("unexplained", names, np.zeros(len(names)), ["m"] * len(names),
                       {"markers": "each marker its own offset, linear in the controls and in their squared "
                                   "distance from the middle of the strokes"},
                       mid=0.5 * (lo + hi), half=half, n_markers=M)
