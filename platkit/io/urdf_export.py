"""Write a URDF with calibrated parameters folded in, for tools that read plain URDF.

For every actuated or mimic joint j on the calibrated chain, the joint's ``<origin>`` becomes::

    origin' = origin * Trans(origin_x, origin_y, origin_z) * Rz(origin_rz) Ry(origin_ry) Rx(origin_rx)
              * motion(-offset_j)

where ``motion`` is the rotation about the joint axis (revolute, continuous) or the translation
along it (prismatic), and for a mimic joint ``offset = multiplier * offset_master`` (its
``<mimic multiplier offset>`` written with the calibrated ``mimic_multiplier``, ``mimic_offset``). Then the
exported URDF at joint values ``v = c * u`` (the controls in the URDF's units: rad, m) puts every
link where the calibrated model puts it at controls ``u``: the offsets become the URDF's zero, in
the one place every URDF reader honours (the origin rpy/xyz), rather than in a ``<calibration>``
element most tools ignore. A joint scale cannot be written into a URDF: exporting a model whose
scales differ from 1 is refused, naming the joint.

Everything else in the file (links, inertias, meshes, comments, other joints) is kept as it was.
The file is written atomically.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.errors import BadInput, PlatkitError
from platkit.geometry import matrix_from_rotvec, matrix_from_rpy
from platkit.io.atomic import atomic_write_text
from platkit.io.calibration import read_calibration
from platkit.model import PlatformSpec
from platkit.urdf import ORIGIN_FIELDS, SerialChain, parse_urdf_xml, urdf_rpy

#: |scale - 1| above this cannot be folded into a URDF.
SCALE_TOL = 1e-12


def _number(value: float) -> str:
    return format(float(value), ".17g")


def calibrated_origins(spec: PlatformSpec, td) -> dict[str, np.ndarray]:
    """Joint name -> the 4x4 parent_from_joint origin with ``td`` folded in (see the module
    docstring), for every actuated or mimic joint of the spec's chain."""
    chain: SerialChain | None = spec.extras.get("chain")
    if chain is None:
        raise BadInput(f"stand {spec.name!r} is not described by a URDF chain; it cannot be exported as a URDF")
    td = np.asarray(td, float)
    if td.shape != (spec.n_td,):
        raise BadInput(f"{spec.name}: expected {spec.n_td} parameters, got {td.shape}")
    value = dict(zip(spec.parameter_names, td))
    # offsets of the actuated joints first: a mimic joint may sit before its master
    offsets = {j.name: value[f"{j.name}.offset"] for j in chain.actuated}
    for j in chain.actuated:
        scale = value[f"{j.name}.scale"]
        if abs(scale - 1.0) > SCALE_TOL:
            raise BadInput(
                f"{j.name}.scale = {scale:.12g}: a URDF joint has no scale, so this calibration cannot be "
                "exported as a URDF; calibrate with the scales fixed at 1"
            )
    out: dict[str, np.ndarray] = {}
    for j in chain.calibrated:
        if j.actuated:
            offset = offsets[j.name]
        else:  # the calibrated coupling where the stand has one (mimic_multiplier), else the file's
            master, multiplier, _ = j.mimic
            multiplier = value.get(f"{j.name}.mimic_multiplier", multiplier)
            offset = multiplier * offsets[master]
        d = np.array([value[f"{j.name}.{f}"] for f in ORIGIN_FIELDS[:3]])
        rx, ry, rz = (value[f"{j.name}.{f}"] for f in ORIGIN_FIELDS[3:])
        error = np.eye(4)
        error[:3, :3] = matrix_from_rpy(rx, ry, rz)
        error[:3, 3] = d
        motion = np.eye(4)
        if j.type == "prismatic":
            motion[:3, 3] = -offset * j.axis
        else:
            motion[:3, :3] = matrix_from_rotvec(-offset * j.axis)
        out[j.name] = j.origin @ error @ motion
    return out


def _origin_element(etree, T: np.ndarray):
    el = etree.Element("origin")
    el.set("xyz", " ".join(_number(v) for v in T[:3, 3]))
    el.set("rpy", " ".join(_number(v) for v in urdf_rpy(T[:3, :3])))
    return el


def _add_fixed_frame(etree, root, parent: str, link: str, parent_from_link: np.ndarray, taken: set, path: Path):
    """Append ``<link name=link>`` and a fixed joint ``<link>_joint`` from ``parent``."""
    joint = f"{link}_joint"
    for name in (link, joint):
        if name in taken:
            raise BadInput(f"{path}: the URDF already has a link or joint named {name!r}; cannot add the calibrated frame")
        taken.add(name)
    etree.SubElement(root, "link", name=link)
    el = etree.SubElement(root, "joint", name=joint, type="fixed")
    etree.SubElement(el, "parent", link=parent)
    etree.SubElement(el, "child", link=link)
    el.append(_origin_element(etree, parent_from_link))


def export_calibrated_urdf(spec: PlatformSpec, td, out: str | Path, markers: dict | None = None,
                           mocap_from_base: np.ndarray | None = None) -> Path:
    """Write the spec's URDF with ``td`` folded into its joint origins to ``out`` (atomically).

    ``spec``: a stand built by the URDF route (``urdf``, ``rotary``); ``td`` (n_td,) in SI.
    Optional, from a calibration: ``markers`` {name: (3,) m in the moving link} become links
    ``marker_<name>`` fixed to the moving link; ``mocap_from_base`` (4x4) becomes a link ``mocap``
    fixed to the base link (the frame the markers were measured in).
    Raises BadInput for a stand without a URDF chain, a wrong ``td``, a scale other than 1 or a
    name already taken. Returns the path written.
    """
    from lxml import etree

    out = Path(out)
    chain: SerialChain | None = spec.extras.get("chain")
    origins = calibrated_origins(spec, td)
    tree, _ = parse_urdf_xml(chain.path, keep_comments=True)
    root = tree.getroot()
    by_name = {el.get("name"): el for el in root.findall("joint")}
    for name, T in origins.items():
        el = by_name.get(name)
        if el is None:
            raise BadInput(f"{chain.path}: joint {name!r} is no longer in the file; rebuild the stand from it")
        mimic = el.find("mimic")
        if mimic is not None and f"{name}.mimic_multiplier" in spec.parameter_names:  # the calibrated coupling
            value = dict(zip(spec.parameter_names, np.asarray(td, float)))
            mimic.set("multiplier", _number(value[f"{name}.mimic_multiplier"]))
            mimic.set("offset", _number(value[f"{name}.mimic_offset"]))
        old = el.find("origin")
        new = _origin_element(etree, T)
        if old is None:
            el.insert(0, new)
        else:
            new.tail = old.tail
            el.replace(old, new)
    taken = {el.get("name") for el in root.findall("link")} | set(by_name)
    added = []
    for name, position in (markers or {}).items():
        T = np.eye(4)
        T[:3, 3] = np.asarray(position, float)
        if T[:3, 3].shape != (3,) or not np.all(np.isfinite(T[:3, 3])):
            raise BadInput(f"marker {name!r}: position must be 3 finite numbers (m)")
        _add_fixed_frame(etree, root, chain.moving_link, f"marker_{name}", T, taken, chain.path)
        added.append(f"marker_{name}")
    if mocap_from_base is not None:
        M = np.asarray(mocap_from_base, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            raise BadInput("mocap_from_base must be a finite 4x4 transform")
        _add_fixed_frame(etree, root, chain.base_link, "mocap", np.linalg.inv(M), taken, chain.path)
        added.append("mocap")
    note = etree.Comment(
        (f" calibrated by platkit ({spec.name} stand, chain {chain.base_link} -> {chain.moving_link}): joint offsets "
         f"and origin errors are folded into the <origin> of {', '.join(origins)}"
         + (f"; added frames {', '.join(added)}" if added else "")
         + f"; source {chain.path.name} ").replace("--", "- -")
    )
    note.tail = root.text if root.text and not root.text.strip() else "\n  "
    root.insert(0, note)
    text = etree.tostring(tree, xml_declaration=True, encoding="utf-8").decode("utf-8")
    atomic_write_text(out, text + ("" if text.endswith("\n") else "\n"))
    return out


def export_calibration(calibration_yaml: str | Path, out: str | Path) -> Path:
    """Write the URDF of a calibration.yaml (``platkit calibrate``'s output) for a URDF stand:
    offsets and origin errors folded in, markers and the motion-capture frame added."""

    cal = read_calibration(calibration_yaml)
    if cal.spec.extras.get("chain") is None:
        raise BadInput(f"{calibration_yaml}: the {cal.platform} stand is not described by a URDF; nothing to export")
    markers = dict(zip(cal.marker_names, cal.marker_positions))
    return export_calibrated_urdf(cal.spec, cal.td, out, markers=markers, mocap_from_base=cal.mocap_from_base)


def main(argv: list[str] | None = None) -> int:
    """``python -m platkit.io.urdf_export CALIBRATION.yaml OUT.urdf``; exit 2 on bad input."""
    import argparse
    import sys


    parser = argparse.ArgumentParser(prog="python -m platkit.io.urdf_export", description=export_calibration.__doc__)
    parser.add_argument("calibration", help="calibration.yaml written by platkit calibrate")
    parser.add_argument("out", help="the URDF to write")
    args = parser.parse_args(argv)
    try:
        path = export_calibration(args.calibration, args.out)
    except PlatkitError as exc:
        print(f"platkit: error: {exc}", file=sys.stderr)
        return exc.exit_code
    print(path)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
