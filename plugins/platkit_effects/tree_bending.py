"""Link bending of a URDF tree as an effect diagnosis names: a link turned at a joint about the two
axes across its axis by one compliance times the gravity moment's part across it
(:class:`platkit_effects.tree_compliance.JointRotationTerm`, ``about`` 'across').

Rules:

- Offered at every joint that moves a tracked link and whose moment across its axis changes
  over the poses. At a joint that carries every tracked link the term is the moving frame's pose
  offset (exact); at one that carries only some (an arm's, on a two-handed session) it turns the
  markers it carries, each at its place on its link registered from the session
  (:func:`~platkit_effects.tree_compliance.marker_points`): such a bend (a shoulder's link) is
  otherwise taken by the compliance of the joint next to it, whose axis lies across.
- A session with rigid bodies is offered the partial joints not: a body's orientation is no marker
  offset, and the verdict says so (:func:`untried_bending`).
"""
from __future__ import annotations

import numpy as np

from platkit.effects import Effect, SizeHelp
from platkit.model import PlatformSpec
from platkit_effects.tree_compliance import (
    _listed,
    across_axes,
    joint_rotation_from_dict,
    joint_rotation_term,
    load_state,
    marker_points,
    moved_by,
    tree_stand,
)


def partial_joints(spec: PlatformSpec, poses) -> list[str]:
    """The tree's joints (in the URDF's order) that move some of the tracked links but not all."""
    stand = tree_stand(spec)
    if stand is None:
        return []
    return sorted(moved_by(stand) - set(stand.shared), key=lambda n: stand.loads.index[n])


def untried_bending(spec: PlatformSpec, poses) -> list[str]:
    """Why link bending is not tried at some joints of a URDF stand (one sentence each)."""
    lone = partial_joints(spec, poses)
    if lone and (poses.n_bodies or not poses.marker_links):
        return [f"{_listed(lone)} carr{'y' if len(lone) > 1 else 'ies'} only some of the tracked links, and "
                + ("the session tracks rigid bodies, whose orientation a marker offset cannot turn"
                   if poses.n_bodies else "the session maps no marker to its link")]
    return []


# ---------------------------------------------------------------------------- link bending
class LinkBending(Effect):
    name = "link_bending"
    summary = "a link bends about the two axes across a joint's axis under the gravity moment there"
    simulation_size = SizeHelp("the largest bending rotation over the commands (default 1)", "mrad")

    def candidates(self, spec, poses, residuals=None):
        stand = tree_stand(spec)
        if stand is None or stand.loads.total_mass <= 0:
            return []
        S = load_state(stand, poses.controls)
        lone = [] if poses.n_bodies or not poses.marker_links else partial_joints(spec, poses)
        points = marker_points(stand, poses) if lone else {}
        out = []
        for name in sorted(set(stand.shared) | set(lone), key=lambda n: stand.loads.index[n]):
            j = stand.loads.index[name]
            across = S.loads.moment[:, j] @ across_axes(stand.loads.axes[j]).T
            if np.max(np.ptp(across, axis=0)) > 1e-6:
                out.append(joint_rotation_term(self.name, spec, name, "across", points if name in lone else None))
        return out

    def untried(self, spec, poses):
        """Why link bending is not tried at some joints (see untried_bending)."""
        return untried_bending(spec, poses)

    def regressor(self, term, spec, poses):
        stand = tree_stand(spec)
        if stand is None:
            return np.zeros(poses.n_poses)
        S = load_state(stand, poses.controls)
        j = stand.loads.index[term.where["joint"]]
        across = S.loads.moment[:, j] @ across_axes(stand.loads.axes[j]).T
        return across[:, int(np.argmax(np.ptp(across, axis=0)))]

    def regressor_label(self, term):
        return f"gravity moment across joint {term.where['joint']} (N m)"

    def from_dict(self, data, spec=None):
        return joint_rotation_from_dict(self.name, data, spec)

    def simulation_term(self, spec, size, rng, commands):
        """``size``: the largest bending rotation over the commands (mrad), default 1."""
        stand = tree_stand(spec)
        if stand is None or stand.loads.total_mass <= 0:
            return None
        S = load_state(stand, commands.controls)
        peaks = []
        for name in stand.shared:
            j = stand.loads.index[name]
            peaks.append(np.max(np.abs(S.loads.moment[:, j] @ across_axes(stand.loads.axes[j]).T)))
        peaks = np.array(peaks)
        if not peaks.size or not peaks.max() > 0:
            return None
        k = int(rng.choice(np.nonzero(peaks >= 0.5 * peaks.max())[0]))
        c = (1.0 if size is None else float(size)) * 1e-3 / peaks[k]
        return joint_rotation_term(self.name, spec, stand.shared[k], "across"), np.array([c])
