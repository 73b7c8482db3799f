"""An open (possibly tree-shaped) kinematic chain from a URDF, and its velocity Jacobian.

Pinocchio supplies the structure (which joint carries which, the constant placements, the
limits) and the frame placements H_0i at a configuration. The velocity Jacobian is built as
Sorokin (2017) builds it (eqs. 15-21): every joint's unit twist W_i in its own frame,
transported by R_i^n to the reference point (eq. 18), rotated into the chosen basis (eq. 19),
one column per joint (eq. 21).

The configuration ``theta`` (n,) has one number per joint (rad for revolute and continuous
joints, m for prismatic ones), in pinocchio's velocity order; ``joint_names`` lists them.
Only 1-dof joints are accepted (URDF revolute, continuous, prismatic; fixed joints vanish).
"""
from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from platkit.chains.transforms import rotation_action, transport_matrix, unit_twist
from platkit.errors import BadDescription, BadInput
from platkit.urdf import parse_urdf_xml

_AXES = {"X": np.array([1.0, 0, 0]), "Y": np.array([0, 1.0, 0]), "Z": np.array([0, 0, 1.0])}
_UNBOUNDED = 1e10  # limits beyond this are "none" (URDF files write 1e16 and friends)


def read_urdf_text(path: str | Path) -> str:
    """The URDF file's text, read by the one safe URDF reader (platkit.urdf.parse_urdf_xml: no
    DTD, entities or network; size-capped; a <robot> root element)."""
    from lxml import etree


    path = Path(path)
    if not path.is_file():
        raise BadInput(f"{path}: no such URDF file")
    tree, _ = parse_urdf_xml(path)
    return etree.tostring(tree, encoding="unicode")


def check_urdf_text(text: str, source: str) -> None:
    """Reject what a kinematic URDF never needs and an attacker would use (entities, DTDs)."""
    if re.search(r"<!\s*(DOCTYPE|ENTITY)", text, flags=re.IGNORECASE):
        raise BadDescription(f"{source}: the URDF declares a DOCTYPE or ENTITY, which platkit refuses to expand")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise BadDescription(f"{source}: not well-formed XML ({exc})") from None
    if root.tag != "robot":
        raise BadDescription(f"{source}: the root element is <{root.tag}>, expected <robot>")
    # a mimic joint whose master the file lacks: refused, as the URDF stand refuses it (pinocchio
    # would read the joint as a free one)
    names = {j.get("name") for j in root.findall("joint")}
    for j in root.findall("joint"):
        for mimic in j.findall("mimic"):
            if mimic.get("joint") not in names:
                raise BadDescription(f"{source}: joint {j.get('name')!r} <mimic joint={mimic.get('joint')!r}> names no "
                                     "joint of the file")


@dataclass(frozen=True)
class Joint:
    """One 1-dof joint of the chain: its pinocchio index, kind, axis and unit twist W_i."""

    name: str
    index: int          # pinocchio joint index
    column: int         # index in theta and in the Jacobian's columns
    kind: str           # 'revolute', 'continuous' or 'prismatic'
    axis: np.ndarray    # (3,) in the joint frame
    twist: np.ndarray   # (6,) W_i = (v, omega) in the joint frame, eqs. 15-16
    lower: float        # -inf where unbounded (rad or m)
    upper: float
    rate: float         # velocity limit (rad/s or m/s), inf where the URDF gives none


def _joint_kind_axis(jm) -> tuple[str, np.ndarray]:
    short = jm.shortname()
    m = re.fullmatch(r"JointModel(RUB|R|P)([XYZ])", short)
    if m:
        kind = {"RUB": "continuous", "R": "revolute", "P": "prismatic"}[m.group(1)]
        return kind, _AXES[m.group(2)].copy()
    concrete = jm.extract()
    if short == "JointModelRevoluteUnaligned":
        return "revolute", np.array(concrete.axis, float)
    if short == "JointModelRevoluteUnboundedUnaligned":
        return "continuous", np.array(concrete.axis, float)
    if short == "JointModelPrismaticUnaligned":
        return "prismatic", np.array(concrete.axis, float)
    raise ValueError(short)


class KinematicChain:
    """A URDF robot as a chain of local frames, with placements and velocity Jacobians.

    Build with :meth:`from_urdf` (a file) or :meth:`from_urdf_text`. Frames are named by URDF
    link (or joint) name; ``'world'`` is the root.
    """

    def __init__(self, model: pin.Model, source: str = "<model>"):
        self.model = model
        self.data = model.createData()
        self.source = source
        joints: list[Joint] = []
        for j in range(1, model.njoints):
            jm = model.joints[j]
            name = model.names[j]
            try:
                kind, axis = _joint_kind_axis(jm)
            except ValueError:
                raise BadDescription(
                    f"{source}: joint {name!r} is a {jm.shortname()} joint; platkit chains take revolute, "
                    "continuous and prismatic joints") from None
            if kind == "continuous":
                lower, upper = -np.inf, np.inf
            else:
                lower = float(model.lowerPositionLimit[jm.idx_q])
                upper = float(model.upperPositionLimit[jm.idx_q])
                lower = -np.inf if lower < -_UNBOUNDED else lower
                upper = np.inf if upper > _UNBOUNDED else upper
                if lower > upper:
                    raise BadDescription(f"{source}: joint {name!r} has lower limit {lower} above upper limit {upper}")
            rate = float(model.velocityLimit[jm.idx_v])
            rate = np.inf if not np.isfinite(rate) or rate <= 0 or rate > _UNBOUNDED else rate
            joints.append(Joint(name, j, jm.idx_v, kind, axis / np.linalg.norm(axis),
                                unit_twist(kind, axis), lower, upper, rate))
        self.joints = joints
        self.n = model.nv
        self.joint_names = [jt.name for jt in joints]
        self.lower = np.array([jt.lower for jt in joints])
        self.upper = np.array([jt.upper for jt in joints])
        self.rate = np.array([jt.rate for jt in joints])
        self.kinds = [jt.kind for jt in joints]
        self._by_index = {jt.index: jt for jt in joints}
        self._cached_theta: np.ndarray | None = None

    # ------------------------------------------------------------------ construction

    @classmethod
    def from_urdf(cls, path: str | Path) -> "KinematicChain":
        """Parse a URDF file safely (no entities, no meshes) into a chain."""
        return cls.from_urdf_text(read_urdf_text(path), str(path))

    @classmethod
    def from_urdf_text(cls, text: str, source: str = "<urdf>") -> "KinematicChain":
        check_urdf_text(text, source)
        try:
            model = pin.buildModelFromXML(text)
        except Exception as exc:  # pinocchio raises plain RuntimeError/ValueError on bad URDF
            raise BadDescription(f"{source}: pinocchio cannot build the URDF ({str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__})") from None
        return cls(model, source)

    # ------------------------------------------------------------------ configuration

    def neutral(self) -> np.ndarray:
        """Zero configuration moved inside the limits (n,)."""
        return np.clip(np.zeros(self.n), self.lower, self.upper)

    def mid_range(self) -> np.ndarray:
        """The middle of each joint's range (0 for unbounded joints) (n,)."""
        ok = np.isfinite(self.lower) & np.isfinite(self.upper)
        mid = np.zeros(self.n)
        mid[ok] = 0.5 * (self.lower[ok] + self.upper[ok])
        return mid

    def random(self, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        """A uniformly random configuration within the limits shrunk by ``margin`` of each range
        (unbounded joints: uniform in [-pi, pi])."""
        lo = np.where(np.isfinite(self.lower), self.lower, -np.pi)
        hi = np.where(np.isfinite(self.upper), self.upper, np.pi)
        span = hi - lo
        return rng.uniform(lo + margin * span, hi - margin * span)

    def clip(self, theta: np.ndarray) -> np.ndarray:
        return np.clip(theta, self.lower, self.upper)

    def pin_configuration(self, theta: np.ndarray) -> np.ndarray:
        """Pinocchio's q (nq,) for theta (n,): continuous joints become (cos, sin)."""
        theta = np.asarray(theta, float)
        q = np.zeros(self.model.nq)
        for jt in self.joints:
            jm = self.model.joints[jt.index]
            if jt.kind == "continuous":
                q[jm.idx_q] = np.cos(theta[jt.column])
                q[jm.idx_q + 1] = np.sin(theta[jt.column])
            else:
                q[jm.idx_q] = theta[jt.column]
        return q

    def check_configuration(self, theta, what: str = "configuration") -> np.ndarray:
        theta = np.asarray(theta, float).reshape(-1)
        if theta.size != self.n:
            raise BadInput(f"{what}: expected {self.n} joint values ({', '.join(self.joint_names)}), got {theta.size}")
        if not np.all(np.isfinite(theta)):
            raise BadInput(f"{what}: joint values must be finite")
        return theta

    # ------------------------------------------------------------------ frames and placements

    def frame_id(self, name: str) -> int:
        """Pinocchio frame index of a link (preferred) or joint frame; BadInput if unknown."""
        if name == "world":
            return 0
        if self.model.existFrame(name, pin.FrameType.BODY):
            return self.model.getFrameId(name, pin.FrameType.BODY)
        if self.model.existFrame(name):
            return self.model.getFrameId(name)
        links = [f.name for f in self.model.frames if f.type == pin.FrameType.BODY]
        shown = ", ".join(links[:30]) + (", ..." if len(links) > 30 else "")
        raise BadInput(f"{self.source}: no link named {name!r}; links: {shown}")

    def _update(self, theta: np.ndarray) -> None:
        theta = np.asarray(theta, float)
        if self._cached_theta is not None and np.array_equal(theta, self._cached_theta):
            return
        pin.forwardKinematics(self.model, self.data, self.pin_configuration(theta))
        pin.updateFramePlacements(self.model, self.data)
        self._cached_theta = theta.copy()

    def placement(self, theta: np.ndarray, frame: str | int) -> np.ndarray:
        """world_from_frame (4, 4) at configuration theta."""
        fid = frame if isinstance(frame, (int, np.integer)) else self.frame_id(frame)
        self._update(theta)
        return self.data.oMf[fid].homogeneous.copy()

    def joint_placement(self, theta: np.ndarray, joint: int) -> np.ndarray:
        """world_from_joint_i (4, 4): H_0i of the paper for pinocchio joint index ``joint``."""
        self._update(theta)
        return self.data.oMi[joint].homogeneous.copy()

    def supporting_joints(self, frame: str | int) -> list[Joint]:
        """The joints that move ``frame``, from the root outwards."""
        fid = frame if isinstance(frame, (int, np.integer)) else self.frame_id(frame)
        parent = self.model.frames[fid].parentJoint
        return [self._by_index[j] for j in list(self.model.supports[parent])[1:]]

    # ------------------------------------------------------------------ velocity Jacobian

    def jacobian(self, theta: np.ndarray, frame: str | int, basis: str = "world") -> np.ndarray:
        """Velocity Jacobian (6, n) of ``frame``'s origin, twist order (v, omega), eqs. 19-21.

        Column i = H R_i^n W_i: W_i the unit twist in joint frame i, R_i^n the transport from
        the joint's origin to the frame's origin (both written in basis i), H the rotation into
        the basis: ``'world'`` (pinocchio LOCAL_WORLD_ALIGNED), ``'local'`` (the frame's own
        basis, pinocchio LOCAL), ``'world_origin'`` (reference point at the world origin,
        pinocchio WORLD), or the name of another frame (its basis, the point still the frame's
        origin). Columns of joints that do not carry the frame are zero.
        """
        fid = frame if isinstance(frame, (int, np.integer)) else self.frame_id(frame)
        self._update(theta)
        oMf = self.data.oMf[fid]
        if basis == "world_origin":
            point = np.zeros(3)
            s_from_0 = np.eye(3)
        else:
            point = oMf.translation
            if basis == "world":
                s_from_0 = np.eye(3)
            elif basis == "local":
                s_from_0 = oMf.rotation.T
            else:
                s_from_0 = self.data.oMf[self.frame_id(basis)].rotation.T
        J = np.zeros((6, self.n))
        for jt in self.supporting_joints(fid):
            oMi = self.data.oMi[jt.index]
            R_0i = oMi.rotation
            r_i = R_0i.T @ (point - oMi.translation)          # from joint i to the point, basis i
            column = rotation_action(s_from_0 @ R_0i) @ transport_matrix(r_i) @ jt.twist
            J[:, jt.column] = column
        return J

    def relative_jacobian(self, theta: np.ndarray, frame: str | int, reference: str | int) -> np.ndarray:
        """Jacobian (6, n) of ``frame``'s motion relative to the moving frame ``reference``.

        The twist of ``frame`` (at its origin) seen from ``reference``, in ``reference``'s basis:
        the twist of the reference transported to the frame's origin (eq. 18) is subtracted,
        then both halves are rotated into the reference basis. Joints that carry both frames
        cancel; joints that carry only the reference enter with the opposite sign.
        """
        fid = frame if isinstance(frame, (int, np.integer)) else self.frame_id(frame)
        rid = reference if isinstance(reference, (int, np.integer)) else self.frame_id(reference)
        J_f = self.jacobian(theta, fid, "world")
        if rid == 0:
            return J_f
        J_r = self.jacobian(theta, rid, "world")
        oMf = self.data.oMf[fid]
        oMr = self.data.oMf[rid]
        moved = transport_matrix(oMf.translation - oMr.translation) @ J_r
        J = rotation_action(oMr.rotation.T) @ (J_f - moved)
        # joints that carry both frames move them together: exactly zero, not a rounding residue
        shared = {jt.column for jt in self.supporting_joints(fid)} & {jt.column for jt in self.supporting_joints(rid)}
        J[:, sorted(shared)] = 0.0
        return J

    def relative_placement(self, theta: np.ndarray, frame: str | int, reference: str | int) -> np.ndarray:
        """reference_from_frame (4, 4)."""
        fid = frame if isinstance(frame, (int, np.integer)) else self.frame_id(frame)
        rid = reference if isinstance(reference, (int, np.integer)) else self.frame_id(reference)
        self._update(theta)
        return (self.data.oMf[rid].inverse() * self.data.oMf[fid]).homogeneous.copy()

    def reach_bound(self, theta: np.ndarray, frame: str | int) -> tuple[float, np.ndarray] | None:
        """(an upper bound on the distance from the first moving joint's origin to the frame's
        origin, that origin (3,)), or None where a prismatic joint has no stroke limit."""
        joints = self.supporting_joints(frame)
        if not joints:
            return None
        self._update(theta)
        points = [self.data.oMi[jt.index].translation.copy() for jt in joints]
        points.append(self.placement(theta, frame)[:3, 3])
        reach = 0.0
        for k in range(len(joints)):
            reach += float(np.linalg.norm(points[k + 1] - points[k]))
        for k, jt in enumerate(joints):
            if jt.kind == "prismatic":
                stroke = jt.upper - jt.lower
                if not np.isfinite(stroke):
                    return None
                reach += stroke
        return reach, points[0]
