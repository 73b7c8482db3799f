"""Reading a URDF safely: no DTD, no entities, no network, no huge trees, meshes never loaded;
every number of every joint and every link's inertial checked, naming the joint or link and element
on error."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from platkit.errors import BadDescription
from platkit.urdf._tree import ACTUATED_TYPES, UrdfJoint, UrdfTree

#: Largest URDF file read (bytes); real robot descriptions are well under 1 MB without meshes.
MAX_URDF_BYTES = 32 * 1024 * 1024
KNOWN_TYPES = ACTUATED_TYPES + ("fixed", "floating", "planar")
#: The heaviest link a URDF may declare (kg); a mass outside [0, this] is a typo or a unit slip.
MAX_LINK_MASS = 1.0e4


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


def _check_inertial(link, path: Path) -> None:
    """A link's <inertial>, if any: its mass a number in [0, MAX_LINK_MASS] kg, its inertia and
    origin finite numbers (the loads of a tree are built from them, by every verb alike)."""
    inertial = link.find("inertial")
    if inertial is None:
        return
    where = f"link {link.get('name')!r} <inertial>"
    mass = inertial.find("mass")
    if mass is not None:
        raw = mass.get("value")
        m = _optional_float(raw, path, f"{where} <mass value>")
        if m is None or not np.isfinite(m) or not 0.0 <= m <= MAX_LINK_MASS:
            raise BadDescription(f"{path}: {where} <mass value={raw!r}>: a link's mass must be a number of kg "
                                 f"in [0, {MAX_LINK_MASS:g}]")
    inertia = inertial.find("inertia")
    if inertia is not None:
        for attr in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
            v = _optional_float(inertia.get(attr), path, f"{where} <inertia {attr}>")
            if v is not None and not np.isfinite(v):
                raise BadDescription(f"{path}: {where} <inertia {attr}> must be a finite number, got {inertia.get(attr)!r}")
    origin = inertial.find("origin")
    if origin is not None:
        _floats(origin.get("xyz"), 3, path, f"{where} <origin xyz>", "0 0 0")
        _floats(origin.get("rpy"), 3, path, f"{where} <origin rpy>", "0 0 0")


def read_urdf(path: str | Path) -> UrdfTree:
    """Read a URDF's kinematic tree safely: no DTD or entities, no network, meshes never loaded.

    The XML is checked strictly with lxml first (every number of every joint and of every link's
    inertial, naming the joint or link and element on error), then handed to yourdfpy for the
    tree. Raises BadDescription.
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
    for el in root.findall("link"):
        _check_inertial(el, path)
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
