"""Serial chains from URDF files: safe reading, chain extraction, CasADi forward kinematics.

The route every URDF-described stand takes (the ``urdf`` and ``rotary`` stands):

1. :func:`read_urdf` parses the file safely (no DTD, no entities, no network, no meshes) and
   checks the numbers of every joint, naming the joint and element on error.
2. :func:`serial_chain` picks the joints from a base link to a moving link.
3. :func:`chain_spec` turns the chain into a :class:`platkit.model.PlatformSpec` with a
   closed-form ``forward(u, td) -> (q, X)``.

Joint model, for every actuated joint j of the chain (revolute, continuous, prismatic)::

    theta_j = scale_j * (c_j * u_j - offset_j)

with ``c_j`` the control's unit conversion (1 for 'rad' and 'm', pi/180 for 'deg'), ``offset_j``
in the joint's SI unit (rad or m) and ``scale_j`` dimensionless. A mimic joint follows its master:
``theta = multiplier * theta_master + offset`` (URDF semantics; the master must be an actuated
joint that is a control: on a chain, a joint of the chain; on a tree, a recorded joint anywhere
in it), with the multiplier and offset parameters of their own (group ``mimic``, nominal the
URDF's numbers, fixed unless freed). Each actuated or mimic joint's origin carries a small rigid
error::

    parent_from_child = origin_nominal * Trans(origin_x, origin_y, origin_z)
                        * Rz(origin_rz) Ry(origin_ry) Rx(origin_rx) * motion(theta)

so an error is expressed in the nominal joint frame (the frame the axis is written in). Errors of
fixed joints are not separate parameters: a small error of a fixed joint between two actuated
joints equals an error of the next actuated joint's origin, one before the first actuated joint is
part of the base-to-mocap transform, one after the last is part of the marker positions.

td layout: per actuated or mimic joint, in chain order, ``<joint>.offset``, ``<joint>.scale``
(actuated only) or ``<joint>.mimic_multiplier``, ``<joint>.mimic_offset`` (mimic only), then
``<joint>.origin_x, _y, _z, _rx, _ry, _rz``. Nominal values: offset 0, scale 1, origin errors 0,
the mimic's own numbers; the URDF's own numbers are kept in ``spec.extras['chain']``.

Trees (:func:`kinematic_tree`, :func:`tree_spec`): several links carry markers (two hands on one
torso). The controls are the recorded actuated joints below the base link (every one by
default), in depth-first order; each joint's parameters are laid out as on a chain, in the same
order, and a joint that moves no tracked link keeps its parameters (the identifiability analysis
holds them). The spec's pose is the first tracked link's; ``spec.link_poses`` gives every
tracked link's.
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import (
    ca_matrix_from_rpy,
    ca_quat_from_rpy,
    ca_quat_multiply,
    matrix_from_rpy,
    quat_from_matrix,
    quat_normalize,
    rpy_from_quat,
)
from platkit.model import Control, Parameter, PlatformSpec, six_dof_pose

#: Largest URDF file read (bytes); real robot descriptions are well under 1 MB without meshes.
MAX_URDF_BYTES = 32 * 1024 * 1024
ACTUATED_TYPES = ("revolute", "continuous", "prismatic")
KNOWN_TYPES = ACTUATED_TYPES + ("fixed", "floating", "planar")
ORIGIN_FIELDS = ("origin_x", "origin_y", "origin_z", "origin_rx", "origin_ry", "origin_rz")
CONTROL_UNIT_FACTORS = {"rad": 1.0, "m": 1.0, "deg": np.pi / 180.0}


# ----------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class UrdfJoint:
    """One URDF joint, as read. ``origin``: 4x4 parent_from_joint; ``axis``: unit (3,)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    lower: float
    upper: float
    mimic: tuple[str, float, float] | None = None  # (master, multiplier, offset)

    @property
    def actuated(self) -> bool:
        return self.type in ACTUATED_TYPES and self.mimic is None

    @property
    def unit(self) -> str:
        return "m" if self.type == "prismatic" else "rad"


@dataclass
class UrdfTree:
    """The kinematic tree of a URDF file: links, joints by name, and the parent joint of links."""

    path: Path
    robot_name: str
    links: list[str]
    joints: dict[str, UrdfJoint]
    parent_joint: dict[str, str]  # child link -> joint name

    @property
    def root(self) -> str:
        roots = [l for l in self.links if l not in self.parent_joint]
        if len(roots) != 1:
            raise BadDescription(f"{self.path}: the URDF must have exactly one root link, found {sorted(roots)}")
        return roots[0]

    def children(self, link: str) -> list[str]:
        return [j.child for j in self.joints.values() if j.parent == link]

    def leaves(self, below: str) -> list[str]:
        """Links with no child joint in the subtree under ``below`` (depth-first order)."""
        out, stack = [], [below]
        while stack:
            link = stack.pop()
            kids = self.children(link)
            if not kids and link != below:
                out.append(link)
            stack.extend(reversed(kids))
        return out


def _floats(text: str | None, n: int, path: Path, where: str, default: str) -> np.ndarray:
    raw = default if text is None else text
    try:
        values = np.array([float(v) for v in raw.split()], dtype=float)
    except ValueError:
        raise BadDescription(f"{path}: {where} must be {n} numbers, got {raw!r}") from None
    if values.size != n or not np.all(np.isfinite(values)):
        raise BadDescription(f"{path}: {where} must be {n} finite numbers, got {raw!r}")
    return values


def _optional_float(text: str | None, path: Path, where: str) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise BadDescription(f"{path}: {where} must be a number, got {text!r}") from None
    if np.isnan(value):
        raise BadDescription(f"{path}: {where} must be a number, got {text!r}")
    return value


def parse_urdf_xml(path: Path, keep_comments: bool = False):
    """(lxml tree, bytes) of ``path``; no DTD, entities, network or huge trees; BadDescription
    otherwise. The top element must be <robot>."""
    from lxml import etree

    try:
        size = path.stat().st_size
    except OSError as exc:
        raise BadDescription(f"{path}: cannot be read ({exc.__class__.__name__}: {exc})") from None
    if size > MAX_URDF_BYTES:
        raise BadDescription(f"{path}: {size} bytes is larger than the {MAX_URDF_BYTES} bytes a URDF may have")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BadDescription(f"{path}: cannot be read ({exc.__class__.__name__}: {exc})") from None
    for token in (b"<!DOCTYPE", b"<!ENTITY"):
        at = data.find(token)
        if at >= 0:
            line = data.count(b"\n", 0, at) + 1
            raise BadDescription(f"{path}: line {line}: DTDs and XML entities are not accepted in a URDF")
    parser = etree.XMLParser(
        resolve_entities=False, no_network=True, load_dtd=False, dtd_validation=False,
        huge_tree=False, remove_comments=not keep_comments, remove_pis=True,
    )
    try:
        tree = etree.parse(io.BytesIO(data), parser)
    except etree.XMLSyntaxError as exc:
        line = f" line {exc.lineno}:" if getattr(exc, "lineno", None) else ""
        raise BadDescription(f"{path}:{line} not well-formed XML ({exc.msg})") from None
    # a DTD in another encoding (UTF-16) escapes the byte search above; lxml still reports it
    if tree.docinfo.internalDTD is not None or tree.docinfo.doctype:
        raise BadDescription(f"{path}: DTDs and XML entities are not accepted in a URDF")
    for node in tree.iter():
        if isinstance(node, etree._Entity):
            raise BadDescription(f"{path}: line {node.sourceline}: XML entities are not accepted in a URDF")
    root = tree.getroot()
    if root.tag != "robot":
        raise BadDescription(f"{path}: the top element must be <robot>, got <{root.tag}>")
    return tree, data


def read_urdf(path: str | Path) -> UrdfTree:
    """Read a URDF's kinematic tree safely: no DTD or entities, no network, meshes never loaded.

    The XML is checked strictly with lxml first (every number of every joint, naming the joint
    and element on error), then handed to yourdfpy for the tree. Raises BadDescription.
    """
    import yourdfpy

    path = Path(path)
    tree, data = parse_urdf_xml(path)
    root = tree.getroot()
    names = []
    for el in root.findall("joint"):
        name = el.get("name")
        if not name:
            raise BadDescription(f"{path}: line {el.sourceline}: a <joint> has no name")
        where = f"joint {name!r}"
        jtype = el.get("type")
        if jtype not in KNOWN_TYPES:
            raise BadDescription(f"{path}: {where} has type {jtype!r}, expected one of {', '.join(KNOWN_TYPES)}")
        for tag in ("parent", "child"):
            sub = el.find(tag)
            if sub is None or not sub.get("link"):
                raise BadDescription(f"{path}: {where} has no <{tag} link=...>")
        origin = el.find("origin")
        if origin is not None:
            _floats(origin.get("xyz"), 3, path, f"{where} <origin xyz>", "0 0 0")
            _floats(origin.get("rpy"), 3, path, f"{where} <origin rpy>", "0 0 0")
        axis = el.find("axis")
        if axis is not None and jtype in ACTUATED_TYPES:
            a = _floats(axis.get("xyz"), 3, path, f"{where} <axis xyz>", "1 0 0")
            if np.linalg.norm(a) < 1e-9:
                raise BadDescription(f"{path}: {where} <axis xyz> is the zero vector")
        limit = el.find("limit")
        if limit is not None:
            lo, hi = (_optional_float(limit.get(attr), path, f"{where} <limit {attr}>") for attr in ("lower", "upper"))
            # lower == upper (both left out: 0 0) is the URDF's 'no limit'; lower > upper is a typo
            if jtype in ("revolute", "prismatic") and lo is not None and hi is not None and lo > hi:
                raise BadDescription(f"{path}: {where} <limit lower='{limit.get('lower')}' upper='{limit.get('upper')}'>: "
                                     "lower is above upper")
        mimic = el.find("mimic")
        if mimic is not None:
            if not mimic.get("joint"):
                raise BadDescription(f"{path}: {where} <mimic> names no joint")
            for attr in ("multiplier", "offset"):
                v = _optional_float(mimic.get(attr), path, f"{where} <mimic {attr}>")
                if v is not None and not np.isfinite(v):
                    raise BadDescription(f"{path}: {where} <mimic {attr}> must be finite")
        names.append(name)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise BadDescription(f"{path}: joint names used twice: {dup}")
    try:
        model = yourdfpy.URDF.load(io.BytesIO(data), build_scene_graph=False, load_meshes=False,
                                   build_collision_scene_graph=False, load_collision_meshes=False)
    except Exception as exc:  # yourdfpy raises bare exceptions on malformed input
        raise BadDescription(f"{path}: not a valid URDF ({exc.__class__.__name__}: {exc})") from None
    robot = model.robot
    links = [l.name for l in robot.links]
    link_set = set(links)
    joints: dict[str, UrdfJoint] = {}
    parent_joint: dict[str, str] = {}
    for j in robot.joints:
        for end in (j.parent, j.child):
            if end not in link_set:
                raise BadDescription(f"{path}: joint {j.name!r} names link {end!r}, which the file does not define")
        if j.child in parent_joint:
            raise BadDescription(
                f"{path}: link {j.child!r} is the child of two joints ({parent_joint[j.child]!r}, {j.name!r}); a URDF is a tree"
            )
        axis = np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0), float)
        axis = axis / np.linalg.norm(axis) if np.linalg.norm(axis) > 0 else np.array([1.0, 0.0, 0.0])
        lo = hi = None
        if j.limit is not None:
            lo, hi = j.limit.lower, j.limit.upper
        if j.type == "continuous" or lo is None or hi is None or not lo < hi:
            # continuous joints, and limits left out or given as lower == upper (the URDF
            # defaults): the joint is unbounded (lower > upper was refused above)
            lo, hi = -np.inf, np.inf
        mimic = None
        if j.mimic is not None:
            mimic = (str(j.mimic.joint), float(j.mimic.multiplier if j.mimic.multiplier is not None else 1.0),
                     float(j.mimic.offset if j.mimic.offset is not None else 0.0))
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, float)
        joints[j.name] = UrdfJoint(j.name, j.type, j.parent, j.child, origin, axis, float(lo), float(hi), mimic)
        parent_joint[j.child] = j.name
    for start in links:  # a tree has no cycle: walking up from any link ends at a root
        link, steps = start, 0
        while link in parent_joint:
            link = joints[parent_joint[link]].parent
            steps += 1
            if steps > len(joints):
                raise BadDescription(f"{path}: the joints form a cycle through link {start!r}; a URDF is a tree")
    return UrdfTree(path, str(robot.name), links, joints, parent_joint)


# ----------------------------------------------------------------------------- the chain


@dataclass
class SerialChain:
    """The joints from ``base_link`` to ``moving_link``, base first (fixed joints included)."""

    path: Path
    robot_name: str
    base_link: str
    moving_link: str
    joints: list[UrdfJoint]
    tree: UrdfTree = field(repr=False)

    @property
    def actuated(self) -> list[UrdfJoint]:
        """The actuated joints (revolute, continuous, prismatic, not mimic), base first."""
        return [j for j in self.joints if j.actuated]

    @property
    def calibrated(self) -> list[UrdfJoint]:
        """Joints that carry origin-error parameters: actuated and mimic joints."""
        return [j for j in self.joints if j.type in ACTUATED_TYPES]


def serial_chain(tree: UrdfTree, base_link: str | None = None, moving_link: str | None = None) -> SerialChain:
    """The serial chain from ``base_link`` (default: the root link) to ``moving_link`` (default:
    the single leaf below the base). BadInput naming the links on any inconsistency."""
    path = tree.path
    base = base_link if base_link is not None else tree.root
    if base not in tree.links:
        raise BadInput(f"{path}: base_link {base!r} is not a link of the URDF")
    if moving_link is None:
        leaves = tree.leaves(base)
        if not leaves:
            raise BadInput(f"{path}: base_link {base!r} is a leaf: no link moves below it; "
                           f"choose a base_link above the moving part (the root is {tree.root!r})")
        if len(leaves) != 1:
            shown = ", ".join(leaves[:25]) + (f" and {len(leaves) - 25} more" if len(leaves) > 25 else "")
            raise BadInput(
                f"{path}: the tree below {base!r} has {len(leaves)} leaf links; choose moving_link among: {shown}"
            )
        moving_link = leaves[0]
    if moving_link not in tree.links:
        raise BadInput(f"{path}: moving_link {moving_link!r} is not a link of the URDF")
    if moving_link == base:
        raise BadInput(f"{path}: moving_link and base_link are the same link {base!r}")
    chain: list[UrdfJoint] = []
    link = moving_link
    while link != base:
        if link not in tree.parent_joint:
            raise BadInput(f"{path}: moving_link {moving_link!r} is not below base_link {base!r} in the tree")
        joint = tree.joints[tree.parent_joint[link]]
        chain.append(joint)
        link = joint.parent
    chain.reverse()
    names = {j.name for j in chain}
    for j in chain:
        if j.type in ("floating", "planar"):
            raise BadInput(f"{path}: joint {j.name!r} on the chain {base} -> {moving_link} is {j.type}; only revolute, continuous, prismatic and fixed joints can be controlled")
        if j.mimic is not None:
            master = tree.joints.get(j.mimic[0])
            if master is None:
                raise BadDescription(f"{path}: joint {j.name!r} <mimic joint={j.mimic[0]!r}> names no joint of the file")
            if master.name not in names or not master.actuated:
                raise BadInput(
                    f"{path}: joint {j.name!r} mimics {master.name!r}, which is not an actuated joint of the chain {base} -> {moving_link}"
                )
            if j.type not in ACTUATED_TYPES:
                raise BadDescription(f"{path}: joint {j.name!r} is {j.type} but has a <mimic>")
    if not any(j.actuated for j in chain):
        raise BadInput(f"{path}: the chain {base} -> {moving_link} has no actuated joint")
    return SerialChain(path, tree.robot_name, base, moving_link, chain, tree)


# ----------------------------------------------------------------------------- the tree


@dataclass
class KinematicTree:
    """A tree below ``base_link`` whose links ``links`` carry markers (the first is the moving
    link: the spec's pose). ``joints``: every joint below the base, depth-first (fixed included);
    ``recorded``: the actuated joints that are controls, in that order. Quacks like
    :class:`SerialChain` (``actuated``, ``calibrated``, ``moving_link``, ``tree``)."""

    path: Path
    robot_name: str
    base_link: str
    links: list[str]
    joints: list[UrdfJoint]
    recorded: list[str]
    tree: UrdfTree = field(repr=False)

    @property
    def moving_link(self) -> str:
        return self.links[0]

    @property
    def actuated(self) -> list[UrdfJoint]:
        """The controls: the recorded actuated joints (not mimic), depth-first."""
        rec = set(self.recorded)
        return [j for j in self.joints if j.actuated and j.name in rec]

    @property
    def calibrated(self) -> list[UrdfJoint]:
        """Joints with parameters: the controls and the mimic joints whose master is one."""
        rec = set(self.recorded)
        return [j for j in self.joints if (j.actuated and j.name in rec)
                or (j.mimic is not None and j.type in ACTUATED_TYPES and j.mimic[0] in rec)]

    def path_to(self, link: str) -> list[UrdfJoint]:
        """The joints from the base to ``link``, base first."""
        out = []
        while link != self.base_link:
            joint = self.tree.joints[self.tree.parent_joint[link]]
            out.append(joint)
            link = joint.parent
        return out[::-1]

    def required(self) -> dict[str, str]:
        """{joint: tracked link it moves} of the actuated joints that must be controls: those on
        a tracked link's path, and the masters of the mimic joints there."""
        out: dict[str, str] = {}
        for link in self.links:
            for j in self.path_to(link):
                if j.actuated:
                    out.setdefault(j.name, link)
                elif j.mimic is not None:
                    out.setdefault(j.mimic[0], link)
        return out


def _below(tree: UrdfTree, base: str) -> list[UrdfJoint]:
    """The joints in the subtree under ``base``, depth-first (a branch's joints together, in the
    file's order of the children)."""
    children: dict[str, list[UrdfJoint]] = {}
    for j in tree.joints.values():
        children.setdefault(j.parent, []).append(j)
    order: list[UrdfJoint] = []
    stack = list(reversed(children.get(base, [])))
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(children.get(j.child, [])))
    return order


def kinematic_tree(tree: UrdfTree, links: list[str], base_link: str | None = None,
                   recorded: list[str] | None = None, where: str = "") -> KinematicTree:
    """The tree below ``base_link`` (default: the root) with the tracked ``links`` (the first is
    the moving link) and the ``recorded`` actuated joints as controls (None: every actuated joint
    below the base). Bad input, one line naming the file and the link or joint: a link not in
    the URDF or not below the base, a mimic joint whose master is missing or not a joint that
    can be recorded, a recorded name that is no actuated joint below the base (``where``: the
    file that named it, e.g. commands.csv), a joint a tracked link needs that is not recorded."""
    path = tree.path
    base = base_link if base_link is not None else tree.root
    if base not in tree.links:
        raise BadInput(f"{path}: base_link {base!r} is not a link of the URDF")
    if not links:
        raise BadInput(f"{path}: a tree needs at least one tracked link")
    joints = _below(tree, base)
    below = {j.child for j in joints}
    for link in links:
        if link not in tree.links:
            raise BadInput(f"{path}: moving_link {link!r} is not a link of the URDF")
        if link not in below:
            raise BadInput(f"{path}: moving_link {link!r} is not below base_link {base!r} in the tree")
    by_name = {j.name: j for j in joints}
    for j in joints:
        if j.mimic is None or j.type not in ACTUATED_TYPES:  # a fixed joint's <mimic> moves nothing
            continue
        if j.mimic[0] not in tree.joints:
            raise BadDescription(f"{path}: joint {j.name!r} <mimic joint={j.mimic[0]!r}>: the master names no joint "
                                 "of the file")
        master = tree.joints[j.mimic[0]]
        if not master.actuated:
            raise BadDescription(f"{path}: joint {j.name!r} <mimic joint={master.name!r}>: the master is "
                                 f"{'itself a mimic joint' if master.mimic else master.type}; it must be an actuated joint")
    actuated = [j.name for j in joints if j.actuated]
    if recorded is None:
        recorded = actuated
    src = where or "the recorded joints"
    for name in recorded:
        j = tree.joints.get(name)
        if j is None:
            raise BadInput(f"{src}: column {name!r} is no joint of the URDF {path}")
        if name not in by_name:
            raise BadInput(f"{src}: column {name!r} is joint {name!r}, which is not below base_link {base!r}")
        if j.mimic is not None:
            raise BadInput(f"{src}: column {name!r} is a mimic joint of {j.mimic[0]!r}: it follows its master "
                           "and is not a column")
        if not j.actuated:
            raise BadInput(f"{src}: column {name!r} is a {j.type} joint; only revolute, continuous and prismatic "
                           "joints are recorded")
    kt = KinematicTree(path, tree.robot_name, base, list(links), joints, [n for n in actuated if n in set(recorded)], tree)
    for link in links:
        for j in kt.path_to(link):
            if j.type in ("floating", "planar"):
                raise BadInput(f"{path}: joint {j.name!r} on the path {base} -> {link} is {j.type}; only revolute, "
                               "continuous, prismatic and fixed joints can be controlled")
    missing = [(n, link) for n, link in kt.required().items() if n not in set(kt.recorded)]
    if missing:
        n, link = missing[0]
        raise BadInput(f"{src}: missing column {n!r}: joint {n!r} moves the tracked link {link!r}")
    if not kt.actuated:
        raise BadInput(f"{path}: the tree below {base!r} has no actuated joint")
    return kt


# ----------------------------------------------------------------------------- parameters


def chain_parameters(chain, free_groups: tuple[str, ...] = ("offset", "origin")) -> list[Parameter]:
    """The td list of a chain or tree (layout in the module docstring). ``free_groups``: which of
    the groups 'offset', 'scale', 'origin', 'mimic' start free (the estimator may fix
    unidentifiable ones)."""
    params = []
    src = str(chain.path)
    for j in chain.calibrated:
        if j.actuated:
            params.append(Parameter(f"{j.name}.offset", j.unit, 0.0, free="offset" in free_groups, group="offset",
                                    source=f"{src}: joint {j.name} zero (nominal: the URDF zero)"))
            params.append(Parameter(f"{j.name}.scale", "1", 1.0, lower=0.0, free="scale" in free_groups, group="scale",
                                    source=f"{src}: joint {j.name} (nominal: one joint unit per control unit)"))
        else:
            master, multiplier, offset = j.mimic
            params.append(Parameter(f"{j.name}.mimic_multiplier", "1", multiplier, free="mimic" in free_groups,
                                    group="mimic", source=f"{src}: joint {j.name} <mimic joint='{master}' multiplier>"))
            params.append(Parameter(f"{j.name}.mimic_offset", j.unit, offset, free="mimic" in free_groups,
                                    group="mimic", source=f"{src}: joint {j.name} <mimic joint='{master}' offset>"))
        xyz = " ".join(format(v + 0.0, ".9g") for v in j.origin[:3, 3])  # + 0.0: no '-0'
        rpy = " ".join(format(v + 0.0, ".9g") for v in urdf_rpy(j.origin[:3, :3]))
        for f in ORIGIN_FIELDS:
            unit = "m" if f in ("origin_x", "origin_y", "origin_z") else "rad"
            params.append(Parameter(f"{j.name}.{f}", unit, 0.0, free="origin" in free_groups, group="origin",
                                    source=f"{src}: error of joint {j.name} <origin xyz='{xyz}' rpy='{rpy}'>, in the joint frame"))
    return params


def joint_origins(chain) -> dict[str, dict]:
    """The URDF's nominal numbers of the chain's joints, plain (for reports):
    {joint: {type, parent, child, xyz (m), rpy (rad), axis, lower, upper}}."""
    return {
        j.name: {"type": j.type, "parent": j.parent, "child": j.child,
                 "xyz": j.origin[:3, 3].tolist(), "rpy": urdf_rpy(j.origin[:3, :3]).tolist(),
                 "axis": j.axis.tolist(), "lower": j.lower, "upper": j.upper}
        for j in chain.joints
    }


# ----------------------------------------------------------------------------- kinematics


def _axis_rotation(axis: np.ndarray, theta):
    """CasADi rotation matrix and quaternion of angle ``theta`` about the unit ``axis``."""
    K = ca.DM(np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]]))
    R = ca.DM.eye(3) + ca.sin(theta) * K + (1 - ca.cos(theta)) * ca.mtimes(K, K)
    q = ca.vertcat(ca.cos(theta / 2), ca.sin(theta / 2) * ca.DM(axis))
    return R, q


def joint_values(calibrated: list[UrdfJoint], control_units: list[str], u, td):
    """(theta {joint: SI value}, td_start {joint: index of its first parameter}) of the actuated and
    mimic joints ``calibrated`` (td laid out as :func:`chain_parameters`), for controls ``u`` in
    ``control_units``: actuated joints take the controls in order, mimic joints follow their master."""
    theta_of: dict[str, object] = {}
    td_start: dict[str, int] = {}
    k = i = 0
    for j in calibrated:
        td_start[j.name] = k
        if j.actuated:
            offset, scale = td[k], td[k + 1]
            theta_of[j.name] = scale * (CONTROL_UNIT_FACTORS[control_units[i]] * u[i] - offset)
            i += 1
        k += 8
    assert k == td.shape[0] and i == u.shape[0], "td or u does not match the chain"
    for j in calibrated:  # a mimic joint may come before its master
        if not j.actuated:
            k = td_start[j.name]
            theta_of[j.name] = td[k] * theta_of[j.mimic[0]] + td[k + 1]
    return theta_of, td_start


def _joint_local(j: UrdfJoint, theta_of: dict, td_start: dict, td):
    """(R, q, X) of parent_from_child of joint ``j``: its origin, origin error and motion. A joint
    without parameters (fixed, or not a control: held at its zero, a mimic at its offset) is its
    origin and that constant motion."""
    R0 = j.origin[:3, :3]
    t0 = j.origin[:3, 3]
    q0 = quat_from_matrix(R0)
    if j.name in td_start:
        theta = theta_of[j.name]
        k = td_start[j.name] + 2
        d = td[k:k + 3]
        rx, ry, rz = td[k + 3], td[k + 4], td[k + 5]
        X_local = ca.DM(t0) + ca.mtimes(ca.DM(R0), d)
        R_local = ca.mtimes(ca.DM(R0), ca_matrix_from_rpy(rx, ry, rz))
        q_local = ca_quat_multiply(ca.DM(q0), ca_quat_from_rpy(rx, ry, rz))
    else:
        theta = 0.0 if j.mimic is None else j.mimic[2]
        X_local, R_local, q_local = ca.DM(t0), ca.DM(R0), ca.DM(q0)
        if j.type not in ACTUATED_TYPES:
            return R_local, q_local, X_local
    # parent_from_child = origin * Trans(d) * R_err * motion(theta)
    if j.type == "prismatic":
        X_local = X_local + ca.mtimes(R_local, ca.DM(j.axis)) * theta
    else:
        R_joint, q_joint = _axis_rotation(j.axis, theta)
        R_local = ca.mtimes(R_local, R_joint)
        q_local = ca_quat_multiply(q_local, q_joint)
    return R_local, q_local, X_local


def _compose(acc, local):
    R_acc, q_acc, X_acc = acc
    R_local, q_local, X_local = local
    return ca.mtimes(R_acc, R_local), ca_quat_multiply(q_acc, q_local), X_acc + ca.mtimes(R_acc, X_local)


_IDENTITY = (ca.DM.eye(3), ca.DM([1.0, 0.0, 0.0, 0.0]), ca.DM.zeros(3))


def chain_kinematics(chain, control_units: list[str], u, td, link: str | None = None):
    """Symbolic forward kinematics of a chain or tree: (R 3x3, q (4,), X (3,)) of ``link`` (default:
    the moving link) in the base link, for controls ``u`` (n_u,) in ``control_units`` and
    parameters ``td`` laid out as :func:`chain_parameters`."""
    return link_kinematics(chain, control_units, u, td, [link or chain.moving_link])[0]


def link_kinematics(chain, control_units: list[str], u, td, links: list[str]):
    """[(R 3x3, q (4,), X (3,)) per link of ``links``] in the base link of a chain or tree; the
    joints shared by several links' paths are composed once."""
    theta_of, td_start = joint_values(chain.calibrated, control_units, u, td)
    tree = chain.tree
    done: dict[str, tuple] = {chain.base_link: _IDENTITY}

    def pose_of(link: str):
        path = []
        while link not in done:
            joint = tree.joints[tree.parent_joint[link]]
            path.append(joint)
            link = joint.parent
        acc = done[link]
        for j in reversed(path):
            acc = done[j.child] = _compose(acc, _joint_local(j, theta_of, td_start, td))
        return acc

    return [pose_of(link) for link in links]


def orientation_error(q_model, q):
    """Rotation vector (small-angle) taking q_model to q, sign-safe: 2 * vec(q_model^-1 q) * sign(w).

    Zero exactly when q = +-q_model; ``q`` need not be unit."""
    conj = ca.vertcat(q_model[0], -q_model[1], -q_model[2], -q_model[3])
    d = ca_quat_multiply(conj, q)
    return 2 * ca.if_else(d[0] < 0, -1, 1) * d[1:]


def chain_spec(
    chain: SerialChain | KinematicTree,
    *,
    name: str,
    title: str,
    control_names: list[str] | None = None,
    control_units: list[str] | None = None,
    free_groups: tuple[str, ...] = ("offset", "origin"),
    description: dict | None = None,
    description_path: Path | None = None,
) -> PlatformSpec:
    """A PlatformSpec for a serial chain or a tree: closed-form forward, 6-row residual, six-dof
    pose of the moving link; on a tree also ``tracked_links`` and ``link_poses`` (every tracked
    link's pose, the moving link first).

    Residual (6 rows): ``[X - X_fk(u, td); orientation_error(q_fk(u, td), q)]`` in metres and
    radians. Controls default to the actuated joints' names in their URDF units (rad, m);
    ``control_units`` may say 'deg' for revolute joints. Bounds are the URDF limits in the
    control's unit at nominal scale; neutral controls are 0 clipped into the limits.
    """
    actuated = chain.actuated
    n_u = len(actuated)
    names = control_names or [j.name for j in actuated]
    units = control_units or [j.unit for j in actuated]
    if len(names) != n_u or len(units) != n_u:
        raise BadInput(f"{chain.path}: {n_u} actuated joints on the chain but {len(names)} control names / {len(units)} units")
    for j, unit in zip(actuated, units):
        if unit not in (("m",) if j.type == "prismatic" else ("rad", "deg")):
            raise BadInput(f"{chain.path}: joint {j.name!r} ({j.type}) cannot take controls in {unit!r}")
    params = chain_parameters(chain, free_groups)
    u = ca.SX.sym("u", n_u)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    tracked = list(chain.links) if isinstance(chain, KinematicTree) else []
    frames = link_kinematics(chain, units, u, td, tracked or [chain.moving_link])
    _, q_fk, X_fk = frames[0]
    forward = ca.Function("forward", [u, td], [q_fk, X_fk], ["u", "td"], ["q", "X"])
    link_poses = None
    if tracked:
        link_poses = ca.Function("link_poses", [u, td], [ca.vertcat(*[f[1] for f in frames]),
                                                         ca.vertcat(*[f[2] for f in frames])],
                                 ["u", "td"], ["q", "X"])
    residual = ca.Function("F", [u, td, q, X], [ca.vertcat(X - X_fk, orientation_error(q_fk, q))],
                           ["u", "td", "q", "X"], ["r"])
    controls = []
    for j, n, unit in zip(actuated, names, units):
        c = CONTROL_UNIT_FACTORS[unit]
        lo, hi = j.lower / c, j.upper / c
        controls.append(Control(n, unit, lo, hi, float(np.clip(0.0, lo, hi))))
    u0 = np.array([c.neutral for c in controls])
    td0 = np.array([p.nominal for p in params])
    q0, X0 = (np.asarray(a).ravel() for a in forward(u0, td0))
    coords, pose, from_pose = six_dof_pose(X0, rpy_from_quat(quat_normalize(q0)))
    return PlatformSpec(
        name=name,
        title=title,
        controls=controls,
        parameters=params,
        coordinates=coords,
        residual=residual,
        pose=pose,
        coordinates_from_pose=from_pose,
        forward=forward,
        description=description if description is not None else {
            "urdf": str(chain.path), "base_link": chain.base_link, "moving_link": chain.moving_link},
        description_path=description_path if description_path is not None else chain.path,
        moving_frame=chain.moving_link,
        base_frame=chain.base_link,
        extras={"chain": chain, "control_units": units, "urdf_path": chain.path,
                "joint_origins": joint_origins(chain)},
        tracked_links=tracked,
        link_poses=link_poses,
    )


def frame_jacobian(spec: PlatformSpec, link: str | None = None) -> ca.Function:
    """CasADi ``J(u, td) -> (J_lin (3, n_u), J_ang (3, n_u))``: the origin velocity and angular
    velocity of ``link`` (default: the moving frame; on a tree any link of it), both in base-frame
    axes, per unit control rate (control units). Mimic joints move with their master."""
    chain = spec.extras["chain"]
    if link is not None:
        link_pose_function(spec, [link])  # BadInput for a link not in the URDF or not below the base
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    R, _, X = chain_kinematics(chain, spec.extras["control_units"], u, td, link)
    J_lin = ca.jacobian(X, u)
    cols = []
    for i in range(spec.n_u):
        W = ca.mtimes(ca.jacobian(ca.vec(R), u[i]).reshape((3, 3)), R.T)  # dR/du_i R^T = skew(w_i)
        cols.append(ca.vertcat(W[2, 1], W[0, 2], W[1, 0]))
    J_ang = ca.horzcat(*cols)
    return ca.Function("frame_jacobian", [u, td], [J_lin, J_ang], ["u", "td"], ["J_lin", "J_ang"])


def link_pose_function(spec: PlatformSpec, links: list[str]) -> ca.Function:
    """CasADi ``(u, td) -> (q (4 L), X (3 L))``: the poses of any ``links`` of a URDF-route stand's
    tree (below its base link) in the base frame, stacked in that order. BadInput naming a link
    that is not in the URDF or not below the base."""
    chain = spec.extras.get("chain")
    if chain is None:
        raise BadInput(f"stand {spec.name!r} is not described by a URDF; it has no links to ask for")
    tree = chain.tree
    for link in links:
        if link not in tree.links:
            raise BadInput(f"{chain.path}: link {link!r} is not a link of the URDF")
        walk = link
        while walk != chain.base_link:
            if walk not in tree.parent_joint:
                raise BadInput(f"{chain.path}: link {link!r} is not below base_link {chain.base_link!r}")
            walk = tree.joints[tree.parent_joint[walk]].parent
    u = ca.SX.sym("u", spec.n_u)
    td = ca.SX.sym("td", spec.n_td)
    frames = link_kinematics(chain, spec.extras["control_units"], u, td, list(links))
    return ca.Function("link_poses", [u, td], [ca.vertcat(*[f[1] for f in frames]), ca.vertcat(*[f[2] for f in frames])],
                       ["u", "td"], ["q", "X"])


def urdf_rpy(R: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) of a URDF <origin rpy> (R = Rz(yaw) Ry(pitch) Rx(roll)), accurate to
    rounding also near pitch = +-pi/2: yaw is taken from what roll and pitch leave, so an error
    of roll along the gimbal-lock direction is absorbed."""
    R = np.asarray(R, float)
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    roll = np.arctan2(R[2, 1], R[2, 2]) if np.hypot(R[2, 1], R[2, 2]) > 1e-12 else 0.0
    rest = R @ matrix_from_rpy(roll, pitch, 0.0).T  # = Rz(yaw)
    yaw = np.arctan2(rest[1, 0], rest[0, 0])
    return np.array([roll, pitch, yaw])
