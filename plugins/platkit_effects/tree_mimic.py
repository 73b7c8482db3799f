"""The elasticity of a coupled joint's master in its own joint alone (the mimic joints that follow
it held where they are commanded), and the every-joint term's loads where the other joints have
given too.

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
- The every-joint term's loads where every joint of it has given: each joint's deflection under
  its own load at its own deflected value (tree_compliance.deflected_torque) leaves out how the
  others' deflections move its load; to first order ``d_k += c_k sum_i G_ki d_i`` (G the gravity
  torques' derivatives across the term's joints, a deflection moving the mimic joints that follow
  it): on the two-arm torso at the benchmark's compliances (deflections to 5 mrad) the
  equilibrium's joints to 1e-7 rad where each joint alone misses them by 2e-5 (markers up to 24
  micrometres, which an actuator's scale nonlinearity took).
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


_COUPLING: dict[tuple, tuple[TreeStand, np.ndarray]] = {}


def cross_slopes(stand: TreeStand, controls: np.ndarray, joints: list[str], alone: list[str]) -> np.ndarray:
    """(N, J_t, J_t): ``G[n, k, i]`` the change of ``joints[k]``'s gravity torque per radian that
    ``joints[i]`` gives, at the commands (pinocchio's gravity derivatives), the deflection moving
    each mimic joint of ``joints[i]`` by its multiplier (held where ``joints[i]`` is in ``alone``),
    less a joint's own slope in its own value (the term's deflected load takes that); once per
    (stand, commands, joints, alone)."""
    import pinocchio as pin

    controls = np.ascontiguousarray(np.atleast_2d(controls), float)
    key = (id(stand), controls.shape, controls.tobytes(), tuple(joints), tuple(alone))
    kept = _COUPLING.get(key)
    if kept is not None and kept[0] is stand:
        return kept[1]
    T = stand.loads
    Q = stand.configuration(controls)
    v = [T.model.joints[j + 1].idx_v for j in range(len(T.joints))]
    rows = [T.index[n] for n in joints]
    P = np.zeros((len(T.joints), len(joints)))  # tree joints moved per radian of each term joint
    for i, n in enumerate(joints):
        P[T.index[n], i] = 1.0
        if n not in alone:
            for m, (master, mult, _) in T.mimic.items():
                if master == n:
                    P[T.index[m], i] += mult
    out = np.zeros((len(Q), len(joints), len(joints)))
    for k, q in enumerate(Q):
        G = pin.computeGeneralizedGravityDerivatives(T.model, T.data, T.pinocchio_q(q))[np.ix_(v, v)]
        out[k] = G[rows] @ P
        out[k][np.arange(len(joints)), np.arange(len(joints))] -= np.diagonal(G)[rows]
    if len(_COUPLING) > 16:
        _COUPLING.clear()
    _COUPLING[key] = (stand, out)
    return out


def coupled_offsets(stand: TreeStand, controls: np.ndarray, indices: list[int], joints: list[str],
                    alone: list[str], theta, own: np.ndarray, jacobian: np.ndarray | None = None):
    """The every-joint term's deflections with each joint's load taken where the other joints of
    the term have given too, to first order: control ``indices[k]`` offset by ``c_k sum_i G_ki d_i``
    more (:func:`cross_slopes`; d_i the deflections ``own`` (N, n_u) of each joint under its own
    load, control units); the (N, n_u) change. With ``jacobian`` (N, n_u, K) the own offsets'
    Jacobian, also that change's (N, n_u, K) (the compliances first in theta). On the prior of
    uniform links (a URDF without inertias) none: there the loads' shape is itself uncertain to
    first order, and the change is second order in the compliances."""
    if stand.loads.prior:
        return np.zeros_like(own) if jacobian is None else (np.zeros_like(own), np.zeros_like(jacobian))
    idx = list(indices)
    scale = stand.scale[idx]
    c = np.asarray(theta[:len(idx)], float)
    G = cross_slopes(stand, controls, joints, alone)
    X = np.einsum("nki,ni->nk", G, own[:, idx] * scale)  # N m: each load's change
    add = np.zeros_like(own)
    add[:, idx] = c * X
    if jacobian is None:
        return add
    J = np.zeros_like(jacobian)
    J[:, idx, :] = c[None, :, None] * np.einsum("nki,nic->nkc", G, jacobian[:, idx, :] * scale[None, :, None])
    J[:, idx, np.arange(len(idx))] += X
    return add, J
