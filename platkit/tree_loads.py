"""Gravity loads of a whole URDF tree: the torque about every joint's axis and the full moment at
every joint, from the configuration of every joint of the tree, mimic joints included.

Rules:

- The model is pinocchio's of the whole URDF (fixed base, gravity along the root's -z), every
  one-dof joint a joint of its own (joints of more degrees of freedom, floating or planar, held at
  pinocchio's neutral configuration: ``held``); a mimic joint takes ``multiplier * master + offset`` (URDF
  semantics), so its load is the load at the place it really is. Joints not given sit at zero.
- ``loads(Q)``: for each configuration, the spatial force each joint transmits to its subtree
  (pinocchio's rnea at zero velocity and acceleration, ``data.f``; pinocchio's gravity, 9.81 m/s^2), in the joint's own frame:
  ``moment`` (3,) N m about the joint's pivot, ``force`` (3,) N, and ``torque`` = its component
  along the joint's motion (N m about a revolute axis, N along a prismatic one). This is what a
  motor or brake must hold; a joint's elastic deflection follows it.
- A joint's **pivot** is where it is held on its parent: its placement there (pinocchio's joint
  placement), where the links it carries turn when the link before it bends. For a revolute
  joint it is the joint frame's origin; a prismatic joint's frame slides along its axis with its
  value, its pivot stays where the slide is guided (a lift's column bends there, not at the
  height the lift has reached). The torque along the axis is the same about either point.
- ``generalized(torque)``: the torques of the joints that have a value of their own (the recorded
  joints), a mimic joint's torque folded into its master's by the chain rule
  (``tau_master += multiplier * tau_mimic``): pinocchio's computeGeneralizedGravity of a model
  built with mimic joints gives the same.
- A payload at a link (mass, centre of mass in the link's frame) adds to that link's body; several
  payloads (one in each hand) each to its own link.
- A URDF without inertias (every link massless) may be given the **prior of uniform links**
  (``prior=True``): each link a slender body of ``PRIOR_KG_PER_M`` per metre of the mean distance
  from its origin to its child joints (at least ``PRIOR_MIN_KG``), its centre of mass half way
  there. Loads then have the shape a real arm's have (the farther a link reaches, the more it
  weighs and the farther out its weight acts); their overall size is unknown, so a compliance
  fitted on them carries it (``prior`` says the loads are this prior's).
- The prior's spread (``prior_spread()``), for an estimate of the mass moments about it: each
  body's mass known to ``PRIOR_SPREAD`` times its prior mass (the rule of uniform links gets a
  link's weight to its order of magnitude, not its value), at least that share of the mean prior
  body's (a hand, given the least mass, may carry a gripper); each first moment to that mass
  spread times the body's length (its reach, at least the mean body's): the centre anywhere along
  the link. Independent, Gaussian.
- Mass moments: gravity loads are linear in each body's mass and first mass moment
  ``(m, m c_x, m c_y, m c_z)`` (c in the body's joint frame). ``moment_regressor(Q)`` gives the
  moments' derivatives in them, so that loads of a URDF without (or with doubtful) inertias can be
  estimated from data; ``mass_moments()`` are the URDF's own.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.urdf import read_urdf

#: a body heavier than this (kg) in a URDF is absurd for a robot on a calibration stand
MAX_LINK_MASS = 1.0e4
#: the prior of uniform links of a URDF without inertias: kg per metre of a link's reach ...
PRIOR_KG_PER_M = 1.0
#: ... and the least mass of a link (one that reaches no further joint: a hand, a tool)
PRIOR_MIN_KG = 0.05
#: the prior's spread: a body's mass known to this share of its prior mass (prior_spread)
PRIOR_SPREAD = 1.0


@dataclass(frozen=True)
class Payload:
    """A point-like load carried by ``link``: ``mass`` (kg) at ``com`` (3,) m in the link's frame."""

    link: str
    mass: float
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)


#: the keys of a payload as a session, a description or an option gives it
PAYLOAD_KEYS = ("link", "mass_kg", "com_m")


def parse_payload(value, where: str, error: type[Exception] = BadInput) -> tuple[Payload, ...]:
    """A payload as a session, a description or an option gives it: a mapping ``{link, mass_kg,
    com_m}`` (``com_m`` the centre of mass [x, y, z] in the link's frame, metres, default its
    origin) or a list of them (one in each hand); None or an empty list for none. ``error`` (one
    line naming ``where`` and the field) if it is not such a value or a mass is negative, absurd
    (over MAX_LINK_MASS) or not a number. Whether the link is in the URDF is checked where the
    URDF is read."""
    if value is None:
        return ()
    items = value if isinstance(value, list) else [value]
    out = []
    for k, item in enumerate(items):
        at = f"{where}[{k}]" if isinstance(value, list) else where
        if not isinstance(item, dict):
            raise error(f"{at} must be a mapping like {{link: tool0, mass_kg: 1.5, com_m: [0, 0, 0.05]}}, got {item!r}")
        unknown = sorted(set(item) - set(PAYLOAD_KEYS), key=str)
        if unknown:
            raise error(f"{at} has unknown key {unknown[0]!r}; a payload has {', '.join(PAYLOAD_KEYS)}")
        link = item.get("link")
        if not isinstance(link, str) or not link.strip():
            raise error(f"{at}.link must be the name of the link that carries the payload, got {link!r}")
        mass = item.get("mass_kg")
        if isinstance(mass, bool) or not isinstance(mass, (int, float)) or not np.isfinite(mass) \
                or not 0 <= mass <= MAX_LINK_MASS:
            raise error(f"{at}.mass_kg must be a mass in [0, {MAX_LINK_MASS:g}] kg, got {mass!r}")
        com = item.get("com_m", [0.0, 0.0, 0.0])
        if not isinstance(com, (list, tuple)) or len(com) != 3 or not all(
                not isinstance(c, bool) and isinstance(c, (int, float)) and np.isfinite(c) for c in com):
            raise error(f"{at}.com_m must be the centre of mass [x, y, z] in metres in the link's frame, got {com!r}")
        out.append(Payload(link.strip(), float(mass), (float(com[0]), float(com[1]), float(com[2]))))
    return tuple(out)


def payload_option(payload: tuple[Payload, ...]) -> list[dict]:
    """The payloads as parse_payload reads them (plain lists and floats: YAML, an option)."""
    return [{"link": p.link, "mass_kg": p.mass, "com_m": list(p.com)} for p in payload]


def _link_frame(model, link: str) -> int | None:
    """Pinocchio's frame index of the link ``link`` (a BODY frame), or None where the URDF has no
    such link. A link is looked up as a body: a URDF may give a joint and a link one name (Unitree's
    Z1 arm: the fixed joint ``gripperStator`` and its child link ``gripperStator``), and pinocchio
    then holds two frames of that name."""
    import pinocchio as pin

    if model.existFrame(link, pin.FrameType.BODY):
        return int(model.getFrameId(link, pin.FrameType.BODY))
    return None


@dataclass
class Loads:
    """Gravity loads at N configurations over the tree's joints (``TreeLoads.joints`` order):
    ``torque`` (N, J) about (along) each joint's axis; ``moment`` (N, J, 3) N m and ``force``
    (N, J, 3) N in each joint's frame, the moment about its pivot; ``origin`` (N, J, 3) m and
    ``rotation`` (N, J, 3, 3) each joint frame's placement in the root frame; ``pivot`` (N, J, 3) m
    each joint's pivot in the root frame (its origin, but a prismatic joint's: see the module
    docstring)."""

    torque: np.ndarray
    moment: np.ndarray
    force: np.ndarray
    origin: np.ndarray
    rotation: np.ndarray
    pivot: np.ndarray


class TreeLoads:
    """Gravity loads of the URDF at ``urdf`` (see the module docstring); ``payload`` optional."""

    def __init__(self, urdf: str | Path, payload: Payload | tuple[Payload, ...] | None = None, prior: bool = False):
        import pinocchio as pin

        self.path = Path(urdf)
        tree = read_urdf(self.path)
        self.tree = tree
        model = pin.buildModelFromUrdf(str(self.path))
        # joints of more than one degree of freedom (floating, planar) are held at pinocchio's neutral
        self.held = [model.names[jid] for jid in range(1, model.njoints)
                     if model.joints[jid].nv != 1 or model.joints[jid].nq not in (1, 2)]
        if self.held:
            model = pin.buildReducedModel(model, [model.getJointId(n) for n in self.held], pin.neutral(model))
        self.joints: list[str] = []
        self._idx_q: list[int] = []
        self._circle: list[bool] = []  # a continuous joint: pinocchio's q holds (cos, sin)
        for jid in range(1, model.njoints):
            j = model.joints[jid]
            self.joints.append(model.names[jid])
            self._idx_q.append(j.idx_q)
            self._circle.append(j.nq == 2)
        self.mimic: dict[str, tuple[str, float, float]] = {}
        for name in self.joints:
            m = tree.joints[name].mimic
            if m is not None:
                if m[0] not in self.joints:
                    raise BadDescription(f"{self.path}: joint {name!r}: mimic master {m[0]!r} is not a moving joint "
                                         "of the URDF")
                if tree.joints[m[0]].mimic is not None:
                    raise BadDescription(f"{self.path}: joint {name!r}: mimic master {m[0]!r} is itself a mimic joint")
                self.mimic[name] = (m[0], float(m[1]), float(m[2]))
        self.recorded = [n for n in self.joints if n not in self.mimic]
        self.index = {n: k for k, n in enumerate(self.joints)}
        for jid in range(1, model.njoints):
            m = float(model.inertias[jid].mass)
            if not np.isfinite(m) or m < 0 or m > MAX_LINK_MASS:
                raise BadDescription(f"{self.path}: the links moved by joint {model.names[jid]!r} have mass {m} kg; "
                                     f"masses must lie in [0, {MAX_LINK_MASS:g}] kg")
        self.prior = bool(prior) and not any(model.inertias[j].mass > 0 for j in range(1, model.njoints))
        self._length = np.zeros(model.njoints - 1)  # each body's reach under the prior (m)
        if self.prior:
            self._add_prior(model, tree)
        self.payloads = payloads(payload)
        for one in self.payloads:
            self._add_payload(model, one)
        self.model = model
        self.data = model.createData()
        self.prismatic = np.array([tree.joints[n].type == "prismatic" for n in self.joints])
        self.axes = np.array([tree.joints[n].axis for n in self.joints], float)
        # subtree[j, b]: body b (attached to joint b) hangs below joint j (both in self.joints order)
        J = len(self.joints)
        self.subtree = np.zeros((J, J), bool)
        for b in range(J):
            jid = b + 1
            while jid > 0:
                self.subtree[jid - 1, b] = True
                jid = model.parents[jid]

    def _add_prior(self, model, tree) -> None:
        """Every link's body of the prior of uniform links (see the module docstring)."""
        import pinocchio as pin

        reach: dict[str, list[np.ndarray]] = {}
        for j in tree.joints.values():
            reach.setdefault(j.parent, []).append(np.asarray(j.origin, float)[:3, 3])
        for link in tree.links:
            fid = _link_frame(model, link)
            if fid is None:
                continue
            ends = reach.get(link, [])
            middle = 0.5 * np.mean(ends, axis=0) if ends else np.zeros(3)
            mass = max(PRIOR_KG_PER_M * float(np.mean([np.linalg.norm(e) for e in ends])) if ends else 0.0, PRIOR_MIN_KG)
            frame = model.frames[fid]
            jid = frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent
            if jid == 0:
                continue
            self._length[jid - 1] = max(self._length[jid - 1], float(np.mean([np.linalg.norm(e) for e in ends]))
                                        if ends else 0.0)
            model.inertias[jid] = model.inertias[jid] + frame.placement.act(pin.Inertia(mass, middle, np.zeros((3, 3))))

    def _add_payload(self, model, payload: Payload) -> None:
        import pinocchio as pin

        fid = _link_frame(model, payload.link)
        if fid is None:
            raise BadInput(f"payload: link {payload.link!r} is not in {self.path}")
        if not (np.isfinite(payload.mass) and 0 <= payload.mass <= MAX_LINK_MASS):
            raise BadInput(f"payload: mass {payload.mass} kg must lie in [0, {MAX_LINK_MASS:g}] kg")
        frame = model.frames[fid]
        body = pin.Inertia(float(payload.mass), np.asarray(payload.com, float), np.zeros((3, 3)))
        jid = frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent
        if jid == 0:
            return  # carried by the fixed base: no joint feels it
        model.inertias[jid] = model.inertias[jid] + frame.placement.act(body)

    # ------------------------------------------------------------------ configurations
    @property
    def total_mass(self) -> float:
        return float(sum(self.model.inertias[j].mass for j in range(1, self.model.njoints)))

    def configuration(self, names: list[str] | tuple[str, ...], values: np.ndarray) -> np.ndarray:
        """(N, J) every joint's value from ``values`` (N, n) of the joints ``names`` (SI: rad, m):
        joints not named at zero, mimic joints from their masters. A name that is not a recorded
        joint of the tree is bad input."""
        values = np.atleast_2d(np.asarray(values, float))
        if values.shape[1] != len(names):
            raise BadInput(f"tree loads: {values.shape[1]} values per row for {len(names)} joints")
        Q = np.zeros((len(values), len(self.joints)))
        for k, n in enumerate(names):
            if n not in self.index:
                raise BadInput(f"tree loads: {n!r} is not a moving joint of {self.path}")
            if n in self.mimic:
                raise BadInput(f"tree loads: {n!r} is a mimic joint of {self.path} (it follows "
                               f"{self.mimic[n][0]!r}); give its master")
            Q[:, self.index[n]] = values[:, k]
        return self.follow_mimic(Q)

    def follow_mimic(self, Q: np.ndarray) -> np.ndarray:
        """``Q`` (N, J) with every mimic joint set from its master."""
        Q = np.array(Q, float)
        for n, (master, mult, off) in self.mimic.items():
            Q[:, self.index[n]] = mult * Q[:, self.index[master]] + off
        return Q

    def pinocchio_q(self, q: np.ndarray) -> np.ndarray:
        """pinocchio's configuration vector of one configuration ``q`` (J,) (joint values)."""
        out = np.zeros(self.model.nq)
        for v, i, circle in zip(q, self._idx_q, self._circle):
            if circle:
                out[i], out[i + 1] = np.cos(v), np.sin(v)
            else:
                out[i] = v
        return out

    # ------------------------------------------------------------------ loads
    def loads(self, Q: np.ndarray) -> Loads:
        """Gravity loads at the configurations ``Q`` (N, J) (mimic joints as given: call
        :meth:`follow_mimic` or :meth:`configuration` first)."""
        import pinocchio as pin

        Q = np.atleast_2d(np.asarray(Q, float))
        N, J = Q.shape
        model, data = self.model, self.data
        zero = np.zeros(model.nv)
        moment, force = np.zeros((N, J, 3)), np.zeros((N, J, 3))
        origin, rotation = np.zeros((N, J, 3)), np.zeros((N, J, 3, 3))
        slides = np.nonzero(self.prismatic)[0]
        guide = np.zeros((N, len(slides), 3))  # the prismatic joints' pivots
        for k in range(N):
            q = self.pinocchio_q(Q[k])
            pin.rnea(model, data, q, zero, zero)
            pin.forwardKinematics(model, data, q)
            for j in range(J):
                f = data.f[j + 1]
                moment[k, j], force[k, j] = f.angular, f.linear
                M = data.oMi[j + 1]
                origin[k, j], rotation[k, j] = M.translation, M.rotation
            for i, j in enumerate(slides.tolist()):  # the slide's guide: the placement on the parent
                guide[k, i] = (data.oMi[model.parents[j + 1]] * model.jointPlacements[j + 1]).translation
                moment[k, j] += np.cross(rotation[k, j].T @ (origin[k, j] - guide[k, i]), force[k, j])
        pivot = origin  # a revolute joint's pivot is its origin
        if len(slides):
            pivot = origin.copy()
            pivot[:, slides] = guide
        torque = np.where(self.prismatic[None], np.einsum("njk,jk->nj", force, self.axes),
                          np.einsum("njk,jk->nj", moment, self.axes))
        return Loads(torque, moment, force, origin, rotation, pivot)

    def slopes(self, Q: np.ndarray) -> np.ndarray:
        """(N, J) each joint's gravity torque's slope in its own value, the others held (mimic
        joints too): the diagonal of pinocchio's derivative of the generalized gravity at ``Q``
        (N, J), N m per rad (N per m for a prismatic joint)."""
        import pinocchio as pin

        Q = np.atleast_2d(np.asarray(Q, float))
        v = [self.model.joints[j + 1].idx_v for j in range(len(self.joints))]
        out = np.zeros(Q.shape)
        for k in range(len(Q)):
            out[k] = np.diagonal(pin.computeGeneralizedGravityDerivatives(self.model, self.data,
                                                                          self.pinocchio_q(Q[k])))[v]
        return out

    def link_placements(self, Q: np.ndarray, link: str) -> tuple[np.ndarray, np.ndarray]:
        """(origin (N, 3), rotation (N, 3, 3)): ``link``'s frame in the root frame at ``Q`` (N, J)."""
        import pinocchio as pin

        fid = _link_frame(self.model, link)
        if fid is None:
            raise BadInput(f"tree loads: link {link!r} is not in {self.path}")
        Q = np.atleast_2d(np.asarray(Q, float))
        origin, rotation = np.zeros((len(Q), 3)), np.zeros((len(Q), 3, 3))
        for k, q in enumerate(Q):
            pin.framesForwardKinematics(self.model, self.data, self.pinocchio_q(q))
            origin[k], rotation[k] = self.data.oMf[fid].translation, self.data.oMf[fid].rotation
        return origin, rotation

    def generalized(self, torque: np.ndarray) -> np.ndarray:
        """(N, R) torques of the recorded joints (``self.recorded``), mimic joints' folded into
        their masters' by the chain rule."""
        torque = np.atleast_2d(torque)
        out = np.array(torque[:, [self.index[n] for n in self.recorded]])
        pos = {n: k for k, n in enumerate(self.recorded)}
        for n, (master, mult, _) in self.mimic.items():
            out[:, pos[master]] += mult * torque[:, self.index[n]]
        return out

    # ------------------------------------------------------------------ mass moments
    def mass_moments(self) -> np.ndarray:
        """(4 J,) each body's (m, m c_x, m c_y, m c_z) from the URDF (and payload), c in the
        frame of the joint that carries the body, bodies in ``self.joints`` order."""
        out = np.zeros((len(self.joints), 4))
        for j in range(len(self.joints)):
            I = self.model.inertias[j + 1]
            out[j] = [I.mass, *(I.mass * np.asarray(I.lever))]
        return out.ravel()

    def prior_spread(self) -> np.ndarray:
        """(4 J,) the standard deviation of each of ``mass_moments()`` under the prior of uniform
        links (module docstring): ``PRIOR_SPREAD`` times each body's mass (at least the mean
        body's) for its mass, that times its length (at least the mean body's) for its first
        moments. Zeros where the loads are no prior's (the URDF's own inertias)."""
        if not self.prior:
            return np.zeros(4 * len(self.joints))
        m = np.array([self.model.inertias[j + 1].mass for j in range(len(self.joints))]) - self._payload_mass()
        sd = PRIOR_SPREAD * np.maximum(m, m.mean())
        arm = np.maximum(self._length, self._length.mean())
        return np.column_stack([sd, sd * arm, sd * arm, sd * arm]).ravel()

    def _payload_mass(self) -> np.ndarray:
        """(J,) the payloads' mass on each body (kg)."""
        out = np.zeros(len(self.joints))
        for p in self.payloads:
            frame = self.model.frames[_link_frame(self.model, p.link)]
            jid = frame.parentJoint if hasattr(frame, "parentJoint") else frame.parent
            if jid > 0:
                out[jid - 1] += p.mass
        return out

    def moment_regressor(self, Q: np.ndarray, loads: Loads | None = None) -> np.ndarray:
        """(N, J, 3, 4 J): d(moment of joint j, in its frame) / d(mass moments), so that
        ``moment = regressor @ mass_moments()`` (``loads``: those of ``Q`` if already computed)."""
        Q = np.atleast_2d(np.asarray(Q, float))
        L = self.loads(Q) if loads is None else loads
        N, J = Q.shape
        g = np.array(self.model.gravity.linear, float)
        out = np.zeros((N, J, 3, J, 4))
        for k in range(N):
            O, R, P = L.origin[k], L.rotation[k], L.pivot[k]
            for j in range(J):
                bodies = np.nonzero(self.subtree[j])[0]
                lever = O[bodies] - P[j]                                     # (B, 3) world: about the pivot
                # held moment = -sum (r_b - o_j) x m_b g, with m_b r_b = m_b p_b + R_b h_b
                d_m = -np.cross(lever, g)                                    # (B, 3) per unit mass
                d_h = -np.cross(np.transpose(R[bodies], (0, 2, 1)), g)      # (B, 3 (h comp), 3) world
                Rt = R[j].T
                out[k, j, :, bodies, 0] = d_m @ Rt.T
                out[k, j, :, bodies, 1:] = np.transpose(d_h @ Rt.T, (0, 2, 1))
        return out.reshape(N, J, 3, 4 * J)

    def torque_regressor(self, Q: np.ndarray, loads: Loads | None = None,
                         moment_regressor: np.ndarray | None = None) -> np.ndarray:
        """(N, J, 4 J): d(torque about joint j's axis) / d(mass moments) (a prismatic joint's
        force along its axis depends on the masses below it alone)."""
        Q = np.atleast_2d(np.asarray(Q, float))
        L = self.loads(Q) if loads is None else loads
        Y = self.moment_regressor(Q, L) if moment_regressor is None else moment_regressor
        out = np.einsum("njkp,jk->njp", Y, self.axes)
        g = np.array(self.model.gravity.linear, float)
        for j in np.nonzero(self.prismatic)[0]:
            along = -np.einsum("nkl,k,l->n", L.rotation[:, j], g, self.axes[j])  # axis . R_j^T (-g)
            out[:, j, :] = 0.0
            out[:, j, 0::4] = along[:, None] * self.subtree[j][None]
        return out


def payloads(payload: Payload | tuple[Payload, ...] | list[Payload] | None) -> tuple[Payload, ...]:
    """None, one payload or several, as a tuple (a cache key)."""
    if payload is None:
        return ()
    return (payload,) if isinstance(payload, Payload) else tuple(payload)


@functools.lru_cache(maxsize=8)
def tree_loads(urdf: str, payload: Payload | tuple[Payload, ...] | None = None, prior: bool = False) -> TreeLoads:
    """One :class:`TreeLoads` per URDF file, payload and prior (building one parses the file)."""
    return TreeLoads(urdf, payload, prior)
