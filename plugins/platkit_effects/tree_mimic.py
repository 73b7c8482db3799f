"""The elasticity of a coupled joint's master in its own joint alone: the mimic joints that follow
it held where they are commanded.

Rules:

- A control's compliance offsets the control (platkit_effects.compliance): its mimic joints follow
  the deflection, ``multiplier`` times it (an elastic drive ahead of the coupling). Where the
  elasticity is the master joint's own, behind the coupling, the mimic joints stay where the
  commands put them and only the master's joint turns. The two differ, to first order, by each
  mimic joint turned back about its axis by its multiplier times the master's deflection: a turn
  of the links it carries at another point than the master's, which nothing else in a compliance
  term makes (left out, the bending of the link below the master takes it: a name the physics
  does not hold).
- The turn back is offered only at a mimic joint that carries every tracked link (its turn is the
  moving frame's pose offset and each other link's missing translation, exact); a revolute master
  and revolute mimic joints only.
"""
from __future__ import annotations

import numpy as np

from platkit.model import PlatformSpec
from platkit_effects.tree_compliance import TreeStand, joint_rotation_term


def coupled(stand: TreeStand, joint: str) -> list[tuple[str, float]]:
    """The revolute mimic joints (name, multiplier) that follow the revolute ``joint`` and carry
    every tracked link; [] where there are none."""
    T = stand.loads
    if joint not in T.index or T.prismatic[T.index[joint]]:
        return []
    return [(n, float(mult)) for n, (master, mult, _) in T.mimic.items()
            if master == joint and not T.prismatic[T.index[n]] and n in stand.shared and mult != 0]


def held_mimic_offsets(spec: PlatformSpec, stand: TreeStand, joints: list[str], alone: list[str],
                       deflection: np.ndarray, poses, fk_X) -> tuple[np.ndarray, np.ndarray]:
    """(pose (N, 6), marker (N, M, 3)) offsets that hold the mimic joints of each joint in ``alone``
    where commanded while it deflects by ``deflection[:, k]`` (rad; k its place in ``joints``):
    each mimic joint turned back about its axis by its multiplier times that deflection (linear
    in ``deflection``). ``fk_X`` None: the marker offsets only."""
    pose = np.zeros((poses.n_poses, 6))
    marker = np.zeros((poses.n_poses, poses.n_markers, 3))
    for k, n in enumerate(joints):
        if n not in alone:
            continue
        for mimic, mult in coupled(stand, n):
            axis = stand.loads.axes[stand.loads.index[mimic]]
            turn = joint_rotation_term("compliance", spec, mimic, "axis")
            p, q = turn.turned([1.0], (-mult * deflection[:, k])[:, None] * axis[None], poses, fk_X)
            pose += p
            marker += q
    return pose, marker
