"""The structures of a URDF's kinematics: the tree as read, a serial chain from a base link to a
moving link, and a kinematic tree below a base link with several tracked links; building a chain
or a tree checks it and names the file, link or joint on bad input."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.errors import BadDescription, BadInput

ACTUATED_TYPES = ("revolute", "continuous", "prismatic")


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
        several = [n.strip() for n in moving_link.split(",")] if "," in moving_link else []
        if several and all(n in tree.links for n in several):
            raise BadInput(f"{path}: moving_link {moving_link!r} is not a link of the URDF; several tracked links (a "
                           "tree) are a mapping from each marker (or each link) to its link, e.g. moving_link="
                           + repr({n: n for n in several}) + " (the command line's --moving-link a,b is read so)")
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
            raise BadInput(f"{path}: joint {j.name!r} on the chain {base} -> {moving_link} is {j.type}; only revolute, "
                           "continuous, prismatic and fixed joints can be controlled")
        if j.mimic is not None:
            master = tree.joints.get(j.mimic[0])
            if master is None:
                raise BadDescription(f"{path}: joint {j.name!r} <mimic joint={j.mimic[0]!r}> names no joint of the file")
            if master.name not in names or not master.actuated:
                raise BadInput(
                    f"{path}: joint {j.name!r} mimics {master.name!r}, which is not an actuated joint of the chain "
                    f"{base} -> {moving_link}"
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

    def held_under_recorded(self) -> list[str]:
        """The moving joints that are not controls and follow none (an actuated joint not recorded,
        held at its zero; a mimic joint of such a joint, held at its offset) and hang below a
        recorded joint: they move no tracked link, but the gravity loads of the recorded joints
        above them depend on them. Depth-first."""
        rec = set(self.recorded)

        def moves(j: UrdfJoint) -> bool:
            return j.name in rec or (j.mimic is not None and j.type in ACTUATED_TYPES and j.mimic[0] in rec)

        out = []
        for j in self.joints:
            if j.type not in ACTUATED_TYPES or moves(j):
                continue
            link = j.parent
            while link != self.base_link and link in self.tree.parent_joint:
                above = self.tree.joints[self.tree.parent_joint[link]]
                if moves(above):
                    out.append(j.name)
                    break
                link = above.parent
        return out

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
