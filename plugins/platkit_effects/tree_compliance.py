"""Compliance of a URDF tree: the loads of the whole tree at each pose (platkit.tree_loads), the
joint elasticity of a joint that is no control (a mimic joint), link bending, and the loads of a
URDF without inertias through its identifiable mass moments.

Rules:

- The configuration is every control of the stand mapped to the URDF joint of its name (controls
  named otherwise, like the rotary's u1, u2, take the URDF's one-dof joints in order); joints that
  are no control sit at zero; mimic joints follow their masters. On a tree session every
  recorded joint is a control, so the loads are the whole robot's.
- A deflection is the compliance times the load the joint holds (pinocchio's sign: the torque a
  motor must apply; a joint that gives under its weight has a negative compliance).
- Joint elasticity of a control: a control offset ``c tau_j`` (platkit_effects.compliance), the
  load taken at the deflected configuration: the fixed point ``d = c tau_j(q + d e_j)`` to first
  order in d, ``tau_j / (1 - c g_j)`` with ``g_j = d tau_j / d q_j`` at the commands (pinocchio's
  gravity derivatives); what is left is second order in the deflection (1e-5 of the load at 10 mrad).
- Joint elasticity of a tree: on a session with several tracked links, one compliance per control
  whose load changes over the poses, all fitted together as one term, and its other forms (a
  joint's compliance or the bending of the link before it): platkit_effects.tree_joints. On a
  chain (one tracked link) it is not offered: there the joints are named one by one (on TIAGo's
  arm the term of every joint ranked first by BIC and did not hold out, and crowded out the arm's
  proven backlash).
- Joint elasticity of a mimic joint, and link bending (about the two axes across a joint's axis,
  ``c M_across``: the moment's part across the axis times one compliance, a link as stiff in both
  directions across it; two compliances let a link at a joint mimic the elasticity of the joint
  next to it, whose axis lies across: on TIAGo's wrist such a term ranked above the drive's play
  and was not proven; a tree's every-joint term may take the form with two, 'across2', where the
  data choose it): a small rotation at the joint's origin, linear in the loads at the commanded
  configuration. At a joint that carries every tracked link, a pose offset of the moving frame
  (in the base frame), the translation each other tracked link misses added as a marker offset;
  at one that carries only some (an arm's, on a two-handed session), the markers it carries
  turned as marker offsets, at their places on their links registered from the session
  (:func:`marker_points`).
- A URDF without inertias: a control's gravity torque is linear in the mass moments of the bodies
  below it; the term's parameters are the compliance times the ``MAX_MASS_COMBINATIONS`` best
  determined combinations of them on the session's poses (the regressor's leading singular
  directions), the rank of the rest said in ``where``. The whole tree's mass moments, one set for
  every joint, are estimated with the compliances in a form of the every-joint term
  (platkit_effects.tree_joints).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.effects import stored_where
from platkit.errors import BadInput
from platkit.geometry import rigid_fit
from platkit.model import PlatformSpec
from platkit.plugins import get_platform
from platkit.terms import ModelTerm
from platkit.tree_loads import Loads, TreeLoads, tree_loads

#: |c g_j| above which the deflected load is found by fixed-point iteration, not to first order
LINEAR_LIMIT = 0.05
#: mass-moment combinations kept per joint when the URDF has no inertias
MAX_MASS_COMBINATIONS = 3
#: singular values below this share of the largest are not identifiable on the session
RANK_TOL = 1e-6


def urdf_of(spec: PlatformSpec) -> str | None:
    """The URDF file a stand's loads come from, or None (no URDF: a parallel stand)."""
    p = spec.extras.get("urdf_path")
    if p is not None and Path(p).is_file():
        return str(p)
    p = spec.description_path
    if p is not None and Path(p).suffix.lower() == ".urdf":
        return str(p)
    return None


@dataclass
class TreeStand:
    """A stand's URDF tree for loads: ``loads`` (TreeLoads), ``joints`` the tree joint of each
    control, ``scale`` control unit -> SI, ``base_link``, ``chain`` the tree joints (mimic
    included) from the base link to the moving link, base first; ``tracked`` the links that carry
    markers (the moving link first) and ``shared`` the joints of ``chain`` that carry every one of
    them (on a chain: all of ``chain``)."""

    spec: PlatformSpec
    loads: TreeLoads
    joints: list[str]
    scale: np.ndarray
    base_link: str | None
    chain: list[str]
    tracked: list[str] = field(default_factory=list)
    shared: list[str] = field(default_factory=list)

    def configuration(self, controls: np.ndarray) -> np.ndarray:
        return self.loads.configuration(self.joints, np.atleast_2d(np.asarray(controls, float)) * self.scale)

    def carried(self, joint: str) -> list[str]:
        """The tracked links ``joint`` carries (moves), in ``tracked``'s order."""
        return [link for link in self.tracked if joint in ancestors(self.loads, link)]


_STANDS: dict[int, tuple[PlatformSpec, TreeStand | None]] = {}


def tree_stand(spec: PlatformSpec) -> TreeStand | None:
    """The stand's :class:`TreeStand` (None without a URDF), once per spec object."""
    hit = _STANDS.get(id(spec))
    if hit is not None and hit[0] is spec:
        return hit[1]
    urdf = urdf_of(spec)
    stand = None
    if urdf is not None:
        payload = tuple(spec.extras.get("payload") or ())  # what the robot carries (the urdf stand's option)
        T = tree_loads(urdf)
        prior = T.total_mass <= 0  # no inertias: the prior of uniform links (platkit.tree_loads)
        if prior or payload:
            T = tree_loads(urdf, payload, prior=prior)
        names = list(spec.control_names)
        if not all(n in T.recorded for n in names):
            one_dof = list(T.recorded)
            if len(one_dof) < len(names):
                raise BadInput(f"{urdf}: cannot match the controls {', '.join(names)} to the URDF's joints")
            names = one_dof[: len(names)]
        scale = np.array([np.pi / 180 if c.unit == "deg" else 1.0 for c in spec.controls])
        chain = spec.extras.get("chain")
        base = getattr(chain, "base_link", None)
        if chain is not None and hasattr(chain, "path_to"):
            path = [j.name for j in chain.path_to(chain.moving_link)]
        elif chain is not None:
            path = [j.name for j in chain.joints]
        else:
            path = list(T.joints)
        path = [n for n in path if n in T.index]
        moving = getattr(chain, "moving_link", None)
        tracked = list(spec.tracked_links) or ([moving] if moving else [])
        shared = [n for n in path if all(n in ancestors(T, link) for link in tracked)]
        stand = TreeStand(spec, T, names, scale, base if base != T.tree.root else None, path, tracked, shared)
    if len(_STANDS) > 16:
        _STANDS.clear()
    _STANDS[id(spec)] = (spec, stand)
    return stand


def ancestors(T: TreeLoads, link: str) -> set[str]:
    """The moving joints of the tree between its root and ``link``."""
    out, seen = set(), 0
    while link in T.tree.parent_joint and seen <= len(T.tree.joints):
        joint = T.tree.parent_joint[link]
        if joint in T.index:
            out.add(joint)
        link = T.tree.joints[joint].parent
        seen += 1
    return out


@dataclass
class LoadState:
    """The loads at a set of commands: ``Q`` (N, J) the configuration, ``loads``, and the base
    link's frame in the root frame (``base_origin`` (N, 3), ``base_rotation`` (N, 3, 3))."""

    Q: np.ndarray
    loads: Loads
    base_origin: np.ndarray
    base_rotation: np.ndarray
    links: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    slopes: dict[str, np.ndarray] = field(default_factory=dict)
    regressor: np.ndarray | None = None
    moments: np.ndarray | None = None

    def moment_regressor(self, stand: TreeStand) -> np.ndarray:
        """(N, J, 3, 4 J) the moments' regressor in the mass moments (TreeLoads.moment_regressor), once."""
        if self.moments is None:
            self.moments = stand.loads.moment_regressor(self.Q, self.loads)
        return self.moments

    def torque_regressor(self, stand: TreeStand) -> np.ndarray:
        """(N, J, 4 J) the torques' regressor in the mass moments (TreeLoads.torque_regressor), once."""
        if self.regressor is None:
            self.regressor = stand.loads.torque_regressor(self.Q, self.loads, self.moment_regressor(stand))
        return self.regressor

    def slope(self, stand: TreeStand, joint: str) -> np.ndarray:
        """(N,) d tau_j / d q_j of ``joint``'s own load in its own value (mimic joints held where
        they are): TreeLoads.slopes, every joint's at once, once per state."""
        if "all" not in self.slopes:
            self.slopes["all"] = stand.loads.slopes(self.Q)
        return self.slopes["all"][:, stand.loads.index[joint]]

    def link_in_base(self, stand: TreeStand, link: str) -> tuple[np.ndarray, np.ndarray]:
        """(origin (N, 3), rotation (N, 3, 3)) of ``link`` in the base frame (nominal geometry)."""
        if link not in self.links:
            o, R = stand.loads.link_placements(self.Q, link)
            self.links[link] = (np.einsum("nba,nb->na", self.base_rotation, o - self.base_origin),
                                np.einsum("nba,nbc->nac", self.base_rotation, R))
        return self.links[link]


_STATES: dict[tuple, tuple[TreeStand, LoadState]] = {}


def load_state(stand: TreeStand, controls: np.ndarray) -> LoadState:
    """The loads of ``stand`` at ``controls`` (N, n_u), once per (stand, controls array); the
    stand is kept with them, so that a new stand at a freed one's address is not served its loads."""
    controls = np.ascontiguousarray(np.atleast_2d(controls), float)
    key = (id(stand), controls.shape, controls.tobytes())
    kept = _STATES.get(key)
    hit = kept[1] if kept is not None and kept[0] is stand else None
    if hit is None:
        Q = stand.configuration(controls)
        L = stand.loads.loads(Q)
        if stand.base_link is None:
            o, R = np.zeros((len(Q), 3)), np.broadcast_to(np.eye(3), (len(Q), 3, 3)).copy()
        else:
            o, R = stand.loads.link_placements(Q, stand.base_link)
        if len(_STATES) > 128:
            _STATES.clear()
        hit = LoadState(Q, L, o, R)
        _STATES[key] = (stand, hit)
    return hit


def deflected_torque(stand: TreeStand, controls: np.ndarray, joint: str, compliance: float) -> np.ndarray:
    """(N,) the load of ``joint`` at the equilibrium ``d = compliance * tau(q + d)`` of its own
    deflection d (SI): ``tau / (1 - compliance * g)`` to first order in d (g its load's slope in
    its own value); where ``|compliance * g|`` exceeds LINEAR_LIMIT, by fixed-point iteration."""
    S = load_state(stand, controls)
    j = stand.loads.index[joint]
    tau = S.loads.torque[:, j]
    if compliance == 0:
        return tau
    cg = compliance * S.slope(stand, joint)
    if np.max(np.abs(cg), initial=0.0) <= LINEAR_LIMIT:
        return tau / (1.0 - cg)
    d = compliance * tau
    for _ in range(50):
        Q = S.Q.copy()
        Q[:, j] += d
        tau = stand.loads.loads(Q).torque[:, j]
        new = compliance * tau
        if np.max(np.abs(new - d)) < 1e-10:
            break
        d = new
    return tau


def deflected_slope(stand: TreeStand, controls: np.ndarray, joint: str, compliance: float) -> np.ndarray:
    """(N,) d/dc of ``c * deflected_torque(c)`` at ``compliance``, to first order in the
    deflection: ``tau / (1 - c g)^2``."""
    S = load_state(stand, controls)
    tau = S.loads.torque[:, stand.loads.index[joint]]
    return tau / (1.0 - compliance * S.slope(stand, joint)) ** 2


def across_axes(axis: np.ndarray) -> np.ndarray:
    """(2, 3) two unit vectors across ``axis``, with it a right-handed frame (u, v, axis)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, e)
    u /= np.linalg.norm(u)
    return np.array([u, np.cross(a, u)])


def _rotation_offset(S: LoadState, j: int, w_local: np.ndarray, fk_X: np.ndarray) -> np.ndarray:
    """(N, 6) the moving frame turned by ``w_local`` (N, 3) rad about joint j's pivot (its origin;
    a prismatic joint's placement on its parent: platkit.tree_loads), in the base frame:
    (w x (X - o), w)."""
    L = S.loads
    w_root = np.einsum("nab,nb->na", L.rotation[:, j], w_local)
    w = np.einsum("nba,nb->na", S.base_rotation, w_root)
    o = np.einsum("nba,nb->na", S.base_rotation, L.pivot[:, j] - S.base_origin)
    return np.hstack([np.cross(w, np.asarray(fk_X, float) - o), w])


def _stand_where(spec: PlatformSpec) -> dict:
    chain = spec.extras.get("chain")
    options = dict(spec.extras.get("platform_options") or {})
    if not options and chain is not None and spec.name == "urdf" and not hasattr(chain, "path_to"):
        options = {"base_link": chain.base_link, "moving_link": chain.moving_link}
    return {"platform": spec.name, "description": None if spec.description_path is None else str(spec.description_path),
            "platform_options": options}


def spec_from_where(where: dict, effect: str) -> PlatformSpec:
    if not isinstance(where.get("platform"), str):
        raise BadInput(f"effect {effect!r}: where.platform must name the stand the loads come from")
    return get_platform(where["platform"], where.get("description"), **(where.get("platform_options") or {}))


@dataclass
class JointRotationTerm(ModelTerm):
    """The links joint ``joint`` carries turned at it: about its axis by ``c tau`` (``about``
    'axis': a mimic joint's elasticity) or about the two axes across it by ``c M_across`` (the
    moment's part across the axis; ``about`` 'across': link bending).

    At a joint that carries every tracked link, the moving frame's pose offset plus, on a tree,
    each other link's missing translation as a marker offset. At a joint that carries only some
    (an arm's, on a two-handed session) a pose offset would move the other links too: the turn is
    a marker offset of the markers it carries, ``R_k^T (w x (X_k + R_k m - o))``, which needs each
    marker's place m on its link: ``points`` (marker -> m in its link's frame, from
    :func:`marker_points` on the session, stored in ``where``)."""

    joint: str = ""
    about: str = "axis"
    spec: PlatformSpec | None = field(default=None, repr=False)
    points: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def stand(self) -> TreeStand:
        if self.spec is None:
            self.spec = spec_from_where(self.where, self.effect)
        stand = tree_stand(self.spec)
        if stand is None or self.joint not in stand.loads.index:
            raise BadInput(f"effect {self.effect!r}: joint {self.joint!r} is not a moving joint of the stand's URDF")
        return stand

    def partial(self, stand: TreeStand) -> bool:
        """Whether the joint carries only some of the tracked links."""
        return self.joint not in stand.shared

    def _unit_rotations(self, stand: TreeStand, S: LoadState, moment: np.ndarray | None = None) -> list[np.ndarray]:
        """Per parameter (one), (N, 3) rad of rotation per unit of it, in the joint's frame;
        ``moment`` (N, 3): the moment at the joint in its frame, if not the loads' own."""
        j = stand.loads.index[self.joint]
        M = S.loads.moment[:, j] if moment is None else moment
        if self.about == "axis":
            tau = S.loads.torque[:, j] if moment is None else M @ stand.loads.axes[j]
            return [tau[:, None] * stand.loads.axes[j][None]]
        U = across_axes(stand.loads.axes[j])
        if self.about == "across2":  # stiffer one way than the other: a compliance per axis across
            return [(M @ u)[:, None] * u[None] for u in U]
        return [sum((M @ u)[:, None] * u[None] for u in U)]

    def turned(self, theta, moment: np.ndarray, poses, fk_X) -> tuple[np.ndarray, np.ndarray]:
        """(pose (N, 6), marker (N, M, 3)) offsets of the links this joint carries turned by the
        compliances ``theta`` under ``moment`` (N, 3) at the joint, in its frame (linear in it)."""
        stand = self.stand()
        S = load_state(stand, poses.controls)
        j = stand.loads.index[self.joint]
        w = sum(t * r for t, r in zip(theta, self._unit_rotations(stand, S, moment)))
        if self.partial(stand):
            return np.zeros((poses.n_poses, 6)), self._carried_markers(stand, S, j, w, poses)
        pose = np.zeros((poses.n_poses, 6)) if fk_X is None else _rotation_offset(S, j, w, fk_X)
        return pose, self._other_links(stand, S, j, w, poses)

    def pose_offset(self, theta, poses, fk_q, fk_X):
        stand = self.stand()
        if self.partial(stand):
            return np.zeros((poses.n_poses, 6))
        S = load_state(stand, poses.controls)
        w = sum(t * r for t, r in zip(theta, self._unit_rotations(stand, S)))
        return _rotation_offset(S, stand.loads.index[self.joint], w, fk_X)

    def marker_offset(self, theta, poses):
        stand = self.stand()
        S = load_state(stand, poses.controls)
        w = sum(t * r for t, r in zip(theta, self._unit_rotations(stand, S)))
        if self.partial(stand):
            return self._carried_markers(stand, S, stand.loads.index[self.joint], w, poses)
        return self._other_links(stand, S, stand.loads.index[self.joint], w, poses)

    def _carried_markers(self, stand: TreeStand, S: LoadState, j: int, w_local: np.ndarray, poses) -> np.ndarray:
        """(N, M, 3): each marker on a link the joint carries turned by ``w_local`` (N, 3) about the
        joint's pivot, ``R_k^T (w x (X_k + R_k m - o))`` in its link's frame; the others still."""
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        carried = set(stand.carried(self.joint))
        w = np.einsum("nba,nb->na", S.base_rotation, np.einsum("nab,nb->na", S.loads.rotation[:, j], w_local))
        o = np.einsum("nba,nb->na", S.base_rotation, S.loads.pivot[:, j] - S.base_origin)
        for m, name in enumerate(poses.marker_names):
            link = poses.marker_links.get(name, stand.tracked[0] if stand.tracked else None)
            if link not in carried:
                continue
            if name not in self.points:
                raise BadInput(f"effect {self.effect!r} at {self.joint}: where.marker_points has no place for marker "
                               f"{name!r}, which the joint carries")
            Xk, Rk = S.link_in_base(stand, link)
            P = Xk + np.einsum("nab,b->na", Rk, self.points[name])
            out[:, m] = np.einsum("nba,nb->na", Rk, np.cross(w, P - o))
        return out

    def _other_links(self, stand: TreeStand, S: LoadState, j: int, w_local: np.ndarray, poses) -> np.ndarray:
        """(N, M, 3): on a tree, where the pose offset (which moves every tracked link alike, by the
        moving link's translation) misses a marker's link: R_k^T (w x (X_k - X_0)) in link k's frame
        (the joint carries every tracked link: ``stand.shared``)."""
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        links = poses.marker_links
        if not links or len(stand.tracked) < 2:
            return out
        w_root = np.einsum("nab,nb->na", S.loads.rotation[:, j], w_local)
        w = np.einsum("nba,nb->na", S.base_rotation, w_root)
        X0, _ = S.link_in_base(stand, stand.tracked[0])
        for m, name in enumerate(poses.marker_names):
            link = links.get(name, stand.tracked[0])
            if link == stand.tracked[0]:
                continue
            Xk, Rk = S.link_in_base(stand, link)
            out[:, m] = np.einsum("nba,nb->na", Rk, np.cross(w, Xk - X0))
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        stand = self.stand()
        S = load_state(stand, poses.controls)
        j = stand.loads.index[self.joint]
        units = self._unit_rotations(stand, S)
        if self.partial(stand):
            pose = np.zeros((poses.n_poses, 6, len(theta)))
            marker = np.stack([self._carried_markers(stand, S, j, r, poses) for r in units], axis=-1)
        else:
            pose = np.stack([_rotation_offset(S, j, r, fk_X) for r in units], axis=-1)
            marker = np.stack([self._other_links(stand, S, j, r, poses) for r in units], axis=-1)
        return np.zeros((poses.n_poses, n_u, len(theta))), pose, marker


_POINTS: dict[tuple, dict[str, np.ndarray]] = {}


def marker_points(stand: TreeStand, poses, iterations: int = 30) -> dict[str, np.ndarray]:
    """Each marker's place on its link (m, in the link's frame), from the session: the markers
    registered to the nominal kinematics at the commands, ``Y = A (X_k + R_k m) + b``: given the
    rotation A the places and b by least squares (closed form: ``m_k = g_k - B_k c``, ``c = A^T b``
    from a 3 x 3 system), then A by Kabsch, alternately, from the places at the links' origins;
    once per (stand, session). Its error (millimetres: the nominal geometry and the elastic sag)
    enters a rotation term times the rotation (milliradians): micrometres."""
    Y = np.ascontiguousarray(poses.markers, float)
    key = (id(stand), tuple(poses.marker_names), Y.shape, Y.tobytes(), np.ascontiguousarray(poses.controls).tobytes())
    if key in _POINTS:
        return _POINTS[key]
    S = load_state(stand, poses.controls)
    names = list(poses.marker_names)
    frames = [S.link_in_base(stand, poses.marker_links.get(n, stand.tracked[0])) for n in names]
    X = np.stack([f[0] for f in frames], axis=1)  # (N, M, 3)
    R = np.stack([f[1] for f in frames], axis=1)  # (N, M, 3, 3)
    seen = np.all(np.isfinite(Y), axis=2)
    m = np.zeros((len(names), 3))
    if seen.sum() >= 3:
        w = seen.astype(float)
        count = np.maximum(w.sum(axis=0), 1.0)
        B = np.einsum("nm,nmba->mab", w, R) / count[:, None, None]  # mean R^T per marker
        RB = np.einsum("nmab,mbc->nmac", R, B)
        lhs = np.einsum("nm,ab->ab", w, np.eye(3)) - np.einsum("nm,nmab->ab", w, RB)
        Yz = np.where(seen[..., None], Y, 0.0)
        for _ in range(iterations):
            A, b = rigid_fit((X + np.einsum("nmab,mb->nma", R, m))[seen], Y[seen])
            D = np.where(seen[..., None], Yz @ A - X, 0.0)  # A^T Y - X
            g = np.einsum("nm,nmba,nmb->ma", w, R, D) / count[:, None]
            c = np.linalg.solve(lhs, np.einsum("nm,nma->a", w, D - np.einsum("nmab,mb->nma", R, g)))
            new = g - np.einsum("mab,b->ma", B, c)
            step, m = np.abs(new - m).max(), new
            if step < 1e-10:
                break
    if len(_POINTS) > 16:
        _POINTS.clear()
    out = _POINTS[key] = {n: m[i] for i, n in enumerate(names)}
    return out


def joint_rotation_term(effect: str, spec: PlatformSpec, joint: str, about: str,
                        points: dict[str, np.ndarray] | None = None) -> JointRotationTerm:
    """The term at ``joint``; ``points`` (marker -> place on its link, m): the places of the markers
    a joint that carries only some tracked links turns (:func:`marker_points`), kept in ``where``."""
    where: dict = {"joint": joint, "about": about}
    where.update(_stand_where(spec))
    prior = ", of the prior of uniform links (the URDF has no inertias)" if tree_stand(spec).loads.prior else ""
    what = "torque of the whole tree about the joint's axis" if about == "axis" else \
        "moment of the whole tree across the joint's axis"
    where["load"] = f"gravity {what}{prior} (N m)"
    points = {n: np.asarray(v, float) for n, v in (points or {}).items()}
    if points:
        where["marker_points"] = {n: [round(float(x), 9) for x in v] for n, v in points.items()}
    names = ["compliance_u", "compliance_v"] if about == "across2" else ["compliance"]
    return JointRotationTerm(effect, names, np.zeros(len(names)), ["rad/(N m)"] * len(names), where, joint=joint,
                             about=about, spec=spec, points=points)


def joint_rotation_from_dict(effect: str, data: dict, spec: PlatformSpec | None) -> JointRotationTerm:
    where = stored_where(data)
    joint, about = where.get("joint"), where.get("about")
    if not isinstance(joint, str) or about not in ("axis", "across", "across2"):
        raise BadInput(f"effect {effect!r}: where needs joint (a URDF joint name) and about ('axis', 'across' or "
                       "'across2')")
    raw = where.get("marker_points") or {}
    try:
        points = {str(n): np.asarray(v, float).reshape(3) for n, v in dict(raw).items()}
    except (TypeError, ValueError):
        raise BadInput(f"effect {effect!r}: where.marker_points must map each marker to its place (3 numbers, m)") \
            from None
    if spec is None:
        spec = spec_from_where(where, effect)
    term = joint_rotation_term(effect, spec, joint, about, points)
    term.stand()
    return term


def loaded_controls(stand: TreeStand, controls: np.ndarray, seen: bool = False) -> list[int]:
    """The controls whose joint's gravity load changes over ``controls`` (a vertical axis, a joint
    that carries nothing: not); ``seen``: only those that move a tracked link (a head's joints
    carry no marker: their deflection cannot be seen, their loads still count)."""
    tau = load_state(stand, controls).loads.torque
    return [i for i, n in enumerate(stand.joints) if np.ptp(tau[:, stand.loads.index[n]]) > 1e-9
            and (not seen or n in moved_by(stand))]


def moved_by(stand: TreeStand) -> set[str]:
    """The tree joints that move a tracked link."""
    return set().union(*(ancestors(stand.loads, link) for link in stand.tracked)) if stand.tracked else set(stand.chain)


# ---------------------------------------------------------------------------- mass moments
@dataclass
class MassMomentTerm(ModelTerm):
    """Control ``index`` (tree joint ``joint``) offset by ``Y_j(q) B theta``: Y_j the joint's
    gravity-torque regressor in the mass moments, B (4 J, r) the combinations kept."""

    index: int = 0
    joint: str = ""
    basis: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    spec: PlatformSpec | None = field(default=None, repr=False)

    def stand(self) -> TreeStand:
        if self.spec is None:
            self.spec = spec_from_where(self.where, self.effect)
        stand = tree_stand(self.spec)
        if stand is None:
            raise BadInput(f"effect {self.effect!r}: the stand has no URDF")
        return stand

    def columns(self, controls: np.ndarray) -> np.ndarray:
        """(N, r) the joint's torque per unit of each kept combination."""
        stand = self.stand()
        S = load_state(stand, controls)
        Y = S.torque_regressor(stand)[:, stand.loads.index[self.joint]]
        return Y @ self.basis

    def control_offset(self, theta, poses, n_u):
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = self.columns(poses.controls) @ theta / self.stand().scale[self.index]
        return out

    def offset_jacobians(self, theta, poses, n_u, fk_q, fk_X):
        K = len(theta)
        control = np.zeros((poses.n_poses, n_u, K))
        control[:, self.index, :] = self.columns(poses.controls) / self.stand().scale[self.index]
        return control, np.zeros((poses.n_poses, 6, K)), np.zeros((poses.n_poses, poses.n_markers, 3, K))


def mass_moment_basis(stand: TreeStand, controls: np.ndarray, joint: str) -> tuple[np.ndarray, int]:
    """(B (4 J, r), rank): the joint's identifiable mass-moment combinations on ``controls``,
    the r <= MAX_MASS_COMBINATIONS best determined, scaled so that each column's torque has unit
    RMS over the poses; rank: how many are identifiable at all."""
    S = load_state(stand, controls)
    Y = S.torque_regressor(stand)[:, stand.loads.index[joint]]
    if not np.any(Y):
        return np.zeros((Y.shape[1], 0)), 0
    _, s, Vt = np.linalg.svd(Y, full_matrices=False)
    rank = int(np.sum(s > RANK_TOL * s[0]))
    r = min(rank, MAX_MASS_COMBINATIONS)
    B = Vt[:r].T / (s[:r] / np.sqrt(len(Y)))
    return B, rank


def mass_moment_term(effect: str, spec: PlatformSpec, i: int, joint: str, basis: np.ndarray, rank: int) -> MassMomentTerm:
    r = basis.shape[1]
    where = {"actuator": spec.control_names[i], "actuator_index": i, "unit": spec.controls[i].unit, "joint": joint,
             "load": "gravity torque from mass moments estimated with the compliance (the URDF has no inertias)",
             "identifiable_mass_moments": int(rank), "kept": int(r), "basis": np.round(basis, 12).tolist()}
    where.update(_stand_where(spec))
    names = [f"compliance_x_mass_moments_{k + 1}" for k in range(r)]
    return MassMomentTerm(effect, names, np.zeros(r), [spec.controls[i].unit] * r, where, index=i, joint=joint,
                          basis=basis, spec=spec)


def mass_moment_from_dict(effect: str, data: dict, spec: PlatformSpec | None) -> MassMomentTerm:
    where = stored_where(data)
    try:
        basis = np.asarray(where["basis"], float)
        i, joint = int(where["actuator_index"]), str(where["joint"])
    except (KeyError, TypeError, ValueError):
        raise BadInput(f"effect {effect!r}: where needs basis (a matrix), actuator_index and joint") from None
    if spec is None:
        spec = spec_from_where(where, effect)
    stand = tree_stand(spec)
    if stand is None or basis.ndim != 2 or basis.shape[0] != 4 * len(stand.loads.joints) or not 0 <= i < spec.n_u:
        raise BadInput(f"effect {effect!r}: where.basis must have 4 rows per moving joint of the stand's URDF")
    return mass_moment_term(effect, spec, i, joint, basis, int(where.get("identifiable_mass_moments", basis.shape[1])))


# ---------------------------------------------------------------------------- what is not tried
def _listed(names: list[str]) -> str:
    return ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")


def untried_compliance(spec: PlatformSpec, poses) -> list[str]:
    """Why compliance is not tried at some joints of a URDF stand (one sentence each)."""
    stand = tree_stand(spec)
    if stand is None:
        return []
    out = []
    T = stand.loads
    if T.prior:
        out.append("the URDF has no inertias: not with the URDF's loads, but with those of uniform links (mass in "
                   "proportion to each link's reach, centred half way; their size carried by the compliances), and "
                   "each joint's compliance also with its gravity load's best-determined mass-moment combinations (at "
                   f"most {MAX_MASS_COMBINATIONS} per joint)"
                   + ("; on a session of several tracked links the whole tree's mass moments are estimated with the "
                      "compliances of every loaded joint and the bends of that term, while link bending named on its "
                      "own and a single joint's compliance stay on the prior's loads" if len(stand.tracked) > 1 else ""))
    massless = [n for n in stand.chain if not T.model.inertias[T.index[n] + 1].mass > 0]
    if massless:
        out.append(f"the links moved by {_listed(massless)} have no mass in the URDF (doubtful where they are real "
                   "links: the loads above them leave them out)")
    tau = load_state(stand, poses.controls).loads.torque
    flat = [n for n in stand.joints if not np.ptp(tau[:, T.index[n]]) > 1e-9]
    if flat:
        out.append(f"the gravity load of {_listed(flat)} does not change over the poses (a vertical axis, or a "
                   "joint that carries nothing)")
    unseen = sorted(set(stand.joints[i] for i in loaded_controls(stand, poses.controls))
                    - set(stand.joints[i] for i in loaded_controls(stand, poses.controls, seen=True)), key=T.index.get)
    if unseen:
        many = len(unseen) > 1
        out.append(f"{_listed(unseen)} move{'' if many else 's'} no tracked link: {'their' if many else 'its'} deflection "
                   f"cannot be seen (the loads {'they carry' if many else 'it carries'} still count)")
    lone = [n for n in stand.chain + [m for m in T.mimic if m not in stand.chain]
            if n in T.mimic and n not in stand.shared and any(n in ancestors(T, link) for link in stand.tracked)]
    if lone:
        out.append(f"the mimic joint{'s' if len(lone) > 1 else ''} {_listed(lone)} carr{'y' if len(lone) > 1 else 'ies'} "
                   "only some of the tracked links, and a model term's pose offset moves every tracked link alike")
    return out
