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
  probes move every marker together and cannot see it). On a tree each marker's offset reads only
  the controls that move the link it rides on (a joint off the path from the base to that link
  cannot bend its mount): those controls and their mean squared distance, per marker.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.calibrate.plan_information import link_controls
from platkit.effects import history
from platkit.model import PlatformSpec
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
    #: on a tree, each marker's controls (indices), those that move its link; None: every control
    #: for every marker
    movers: tuple[np.ndarray, ...] | None = None
    uses_kinematics = False

    def features(self, poses: PoseSet) -> np.ndarray:
        """(N, n_u + 1) the controls from the middle of their range (in half ranges) and the mean
        of their squares."""
        u = (np.asarray(poses.controls, float) - self.mid) / self.half
        return np.hstack([u, np.mean(u * u, axis=1, keepdims=True)])

    def marker_features(self, poses: PoseSet) -> list[np.ndarray]:
        """Each marker's features (N, F_m): :meth:`features` without ``movers``; with them, the
        marker's own controls and the mean of their squares (none for a marker no control moves);
        markers with the same controls (a hand's) share one array."""
        if self.movers is None:
            return [self.features(poses)] * self.n_markers
        u = (np.asarray(poses.controls, float) - self.mid) / self.half
        made: dict[bytes, np.ndarray] = {}
        for c in self.movers:
            key = np.asarray(c, np.int64).tobytes()
            if key not in made:
                made[key] = np.hstack([u[:, c], np.mean(u[:, c] ** 2, axis=1, keepdims=True)]) if len(c) \
                    else np.zeros((len(u), 0))
        return [made[np.asarray(c, np.int64).tobytes()] for c in self.movers]

    def marker_offset(self, theta, poses):
        if self.movers is None:
            f = self.features(poses)
            A = np.asarray(theta, float).reshape(self.n_markers, 3, f.shape[1])
            return np.einsum("nf,maf->nma", f, A)
        theta = np.asarray(theta, float)
        out = np.zeros((poses.n_poses, self.n_markers, 3))
        k = 0
        for m, f in enumerate(self.marker_features(poses)):
            F = f.shape[1]
            out[:, m] = f @ theta[k:k + 3 * F].reshape(3, F).T
            k += 3 * F
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        """Linear in theta: marker m, axis a moves by its features through its own block of
        theta ((m, a, feature) order)."""
        feats = self.marker_features(poses)
        N = poses.n_poses
        d_m = np.zeros((N, self.n_markers, 3, len(theta)))
        k = 0
        for m, f in enumerate(feats):
            F = f.shape[1]
            for a in range(3):
                d_m[:, m, a, k:k + F] = f
                k += F
        return None, None, d_m  # no control or pose offset


def link_movers(spec: PlatformSpec | None, poses: PoseSet) -> tuple[np.ndarray, ...] | None:
    """Each marker's controls that move the link it rides on (indices, from the structural
    dependence of ``spec.link_poses`` on the controls, :func:`platkit.calibrate.plan_information.
    link_controls`: a joint off the path from the base to the link cannot move it); None where
    the markers ride on one moving frame, or where every control moves every marker's link."""
    if spec is None or spec.link_poses is None or not poses.marker_links:
        return None
    by_link = link_controls(spec)
    moved = np.array([by_link[link] for link in spec.tracked_links])  # (L, n_u)
    links = poses.links_of(spec.tracked_links)[:poses.n_markers]
    if moved[links].all():
        return None
    return tuple(np.flatnonzero(moved[k]) for k in links)


def marker_probe(poses: PoseSet, spec: PlatformSpec | None = None) -> MarkerProbe | None:
    """A :class:`MarkerProbe` over ``poses``' control range (on a tree, ``spec``'s: each marker
    with the controls that move its link, :func:`link_movers`); None with fewer than 30 poses, or
    with fewer marker coordinates than 4 times the parameters (too few to judge it)."""
    U = np.asarray(poses.controls, float)
    M = poses.n_markers
    if len(U) < 30 or M < 2 or U.ndim != 2:
        return None
    movers = link_movers(spec, poses)
    cols = [np.arange(U.shape[1])] * M if movers is None else list(movers)
    n_f = [len(c) + 1 if len(c) else 0 for c in cols]
    if len(U) * M * 3 < 4 * 3 * sum(n_f):
        return None
    lo, hi = U.min(axis=0), U.max(axis=0)
    half = np.where(hi > lo, 0.5 * (hi - lo), 1.0)
    names = [f"{m}_{a}_{f}" for m, c in zip(poses.marker_names, cols) if len(c) for a in "xyz"
             for f in [f"u{j + 1}" for j in c] + ["reach"]]
    where = ("each marker its own offset, linear in the controls and in their squared distance from the middle "
             "of the strokes") if movers is None else (
             "each marker its own offset, linear in the controls that move its link and in their squared "
             "distance from the middle of the strokes")
    return MarkerProbe("unexplained", names, np.zeros(len(names)), ["m"] * len(names), {"markers": where},
                       mid=0.5 * (lo + hi), half=half, n_markers=M, movers=movers)
