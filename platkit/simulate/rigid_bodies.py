"""Rigid bodies on a simulated stand, the one rule both simulators follow (the additive one,
platkit.simulate.additive, and the physical one, platkit.simulate.physics).

A session's bodies T1, T2, ... are drawn from their own random stream (:func:`draw_bodies`), so
adding them leaves the rest of a simulation as it was: body b rides on the moving part, or on a
tree on tracked link b mod L (as the markers, platkit.calibrate.plan.marker_link_indices), at an
origin about 0.3 of the stand's size from its link's origin, turned by a random rotation vector.
A sample of a body is its link's pose in the mocap frame (:func:`links_in_mocap`) composed with
the body's placement, its origin moved by a position error and its frame turned by a rotation
error, both given per sample (:func:`body_samples`): each simulator draws them as it draws its
markers' noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.calibrate.plan import marker_link_indices, stand_length_scale
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix
from platkit.model import PlatformSpec

__all__ = ["BodyLayout", "draw_bodies", "links_in_mocap", "body_samples", "round_bodies", "bodies_truth"]


@dataclass
class BodyLayout:
    """The bodies' names, their placements on their links (origins (B, 3) m, rotvecs (B, 3) rad:
    body frame -> link frame) and, on a tree, the tracked link each rides on (indices into
    spec.tracked_links), None on a stand with one moving part."""

    names: list[str]
    origins: np.ndarray
    rotvecs: np.ndarray
    links: list[int] | None


def draw_bodies(spec: PlatformSpec, n: int, rng: np.random.Generator) -> BodyLayout:
    """``n`` bodies placed on ``spec``'s moving part (a tree: body b on tracked link b mod L)."""
    origins = rng.normal(0, 0.3 * stand_length_scale(spec), (n, 3))
    rotvecs = rng.normal(0, 1.0, (n, 3))
    return BodyLayout([f"T{k + 1}" for k in range(n)], origins, rotvecs, marker_link_indices(spec, n))


def links_in_mocap(T: np.ndarray, q: np.ndarray, X: np.ndarray, n_bodies: int, links: list[int] | None = None,
                   frames: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(R (K, B, 3, 3) mocap_from_link, origin (K, B, 3) m) of the link each body rides on: the
    moving frame at poses q (K, 4), X (K, 3) in the base frame, or on a tree the body's tracked
    link of ``frames`` (R (K, L, 3, 3), X (K, L, 3) in the base frame); T (4, 4) mocap_from_base."""
    if links is not None and frames is not None:
        k = np.asarray(links, int)
        R = np.einsum("ab,kmbc->kmac", T[:3, :3], frames[0][:, k])
        return R, frames[1][:, k] @ T[:3, :3].T + T[:3, 3]
    R = np.broadcast_to((T[:3, :3] @ matrix_from_quat(q))[:, None], (len(q), n_bodies, 3, 3))
    return R, np.broadcast_to((X @ T[:3, :3].T + T[:3, 3])[:, None], (len(q), n_bodies, 3))


def body_samples(R: np.ndarray, origin: np.ndarray, layout: BodyLayout, position_error: np.ndarray | float = 0.0,
                 rotation_error: np.ndarray | float = 0.0) -> np.ndarray:
    """(K, B, 7) the bodies as the motion capture reports them (origin m, unit quaternion
    qw, qx, qy, qz, in the mocap frame): on links at R (K, B, 3, 3), origin (K, B, 3) (from
    :func:`links_in_mocap`), the origin moved by ``position_error`` (K, B, 3) m and the frame
    turned about its own axes by ``rotation_error`` (K, B, 3) rad."""
    o = origin + np.einsum("kmab,mb->kma", R, layout.origins)
    o = o + position_error
    turn = matrix_from_rotvec(np.broadcast_to(np.asarray(rotation_error, float), o.shape))
    Rw = np.einsum("kmab,mbc,kmcd->kmad", R, matrix_from_rotvec(layout.rotvecs), turn)
    return np.concatenate([o, quat_from_matrix(Rw)], axis=2)


def round_bodies(bodies: np.ndarray) -> np.ndarray:
    """``bodies`` (K, B, 7) in the steps the files keep: origins to 1 um, quaternions to 1e-9."""
    bodies[..., :3] = np.round(bodies[..., :3] * 1e6) / 1e6
    bodies[..., 3:] = np.round(bodies[..., 3:] * 1e9) / 1e9
    return bodies


def bodies_truth(names: list[str], origins: np.ndarray | None, rotvecs: np.ndarray | None, noise: dict) -> dict:
    """truth.yaml's ``rigid_bodies`` (each body's placement on its link, SI) and
    ``rigid_body_noise`` (per-axis sigmas of a sample); empty without bodies."""
    if not names or origins is None or rotvecs is None:
        return {}
    return {"rigid_bodies": {n: {"position": [float(x) for x in o], "rotation_vector": [float(x) for x in r]}
                             for n, o, r in zip(names, origins, rotvecs)},
            "rigid_body_noise": {k: float(v) for k, v in noise.items()}}
