"""platkit stand ``urdf``: any serial chain, or tree, from any URDF.

The description is a URDF file (the chain runs from ``base_link``, default the root link, to
``moving_link``, default the single leaf) or a YAML file that names one::

    urdf: robot.urdf          # relative to the YAML file
    base_link: base_link      # optional
    moving_link: tool0        # optional

Options (from a session or the command line) ``base_link`` and ``moving_link`` override the
description's. ``payload`` (a session's, a description's or an option): a load the robot carries,
``{link, mass_kg, com_m}`` or a list of them (:func:`platkit.tree_loads.parse_payload`), added to
that link's body in the gravity loads of the tree (compliance); kept in ``extras["payload"]`` and
in the platform options, so a calibration rebuilds its stand with it. Refused on a URDF without
inertias: compliance is then fitted on the prior of uniform links, whose size is unknown, and a
payload in kg beside it would be weighed wrong (predictions 4x worse than without it).

A tree (several tracked links, :func:`platkit.urdf.kinematic_tree`): ``moving_link``
a mapping {marker or rigid body: link} (the first link named is the moving frame, the spec's
pose), and ``joints`` the recorded actuated joints (the columns of commands.csv; default every
actuated joint below the base link), which are then the controls. Controls of a chain: its
actuated joints in chain order, in the URDF's units (rad, m). Parameters (see
:mod:`platkit.urdf`): per joint an offset (free), a scale (fixed at 1: the spec's urdf stand
calibrates offsets and origin errors) and six origin errors (free; the estimator reduces the
unidentifiable ones away and reports them); per mimic joint its multiplier and offset (group
``mimic``, fixed unless freed: ``--free mimic``).
"""
from __future__ import annotations

from pathlib import Path

from platkit.errors import BadDescription, BadInput
from platkit.hookspecs import hookimpl
from platkit.io.description import default_description, load_yaml, require
from platkit.model import PlatformFactory, PlatformSpec
from platkit.tree_loads import parse_payload, payload_option, tree_loads
from platkit.urdf import chain_spec, kinematic_tree, read_urdf, serial_chain

TITLE = "Serial chain from a URDF"
OPTIONS = ("base_link", "moving_link", "joints", "payload")
#: how errors about the recorded joints name their source (a session names its commands.csv instead)
JOINTS_WHERE = "urdf stand option 'joints'"
YAML_FIELDS = ("urdf", "base_link", "moving_link", "notes", "payload")


def _text(value, path: Path, field: str) -> str | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise BadDescription(f"{path}: field {field!r} must be a link name (text)")
    return value


def build(path: Path | None, options: dict | None = None) -> PlatformSpec:
    options = {k: v for k, v in (options or {}).items() if v is not None}
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise BadInput(f"the urdf stand takes the options {', '.join(OPTIONS)}; unknown: {unknown}")
    for k, v in options.items():
        if k == "joints":
            if not isinstance(v, (list, tuple)) or not all(isinstance(n, str) and n for n in v):
                raise BadInput(f"urdf stand option 'joints' must be a list of joint names, got {v!r}")
        elif k == "moving_link" and isinstance(v, dict):
            tracked_links(v, "urdf stand option 'moving_link'")
        elif k == "payload":
            options[k] = payload_option(parse_payload(v, "urdf stand option 'payload'"))
        elif not isinstance(v, str) or not v:
            raise BadInput(f"urdf stand option {k!r} must be a link name, got {v!r}")
    path = path or default_description("urdf_default_arm.urdf")
    chosen: dict = {}
    description: dict
    if path.suffix.lower() in (".yaml", ".yml"):
        data = load_yaml(path)
        extra = sorted(set(data) - set(YAML_FIELDS))
        if extra:
            raise BadDescription(f"{path}: unknown field(s) {extra}; a urdf description has {', '.join(YAML_FIELDS)}")
        urdf_path = (path.parent / require(data, "urdf", path, str)).resolve()
        if not urdf_path.is_file():
            raise BadDescription(f"{path}: field 'urdf' names {urdf_path}, which is not a file")
        for k in ("base_link", "moving_link"):
            v = data.get(k)
            if k == "moving_link" and isinstance(v, dict):
                tracked_links(v, f"{path}: field 'moving_link'")
                chosen[k] = v
            else:
                chosen[k] = _text(v, path, k)
        if data.get("payload") is not None:
            chosen["payload"] = payload_option(parse_payload(data["payload"], f"{path}: field 'payload'",
                                                             BadDescription))
        description = dict(data)
    else:
        urdf_path = path
        description = {}
    chosen.update(options)
    tree = read_urdf(urdf_path)
    payload = parse_payload(chosen.get("payload") or None, "urdf stand option 'payload'")
    for k, p in enumerate(payload):
        if p.link not in tree.links:
            raise BadInput(f"payload{'' if len(payload) == 1 else f'[{k}]'}.link: link {p.link!r} is not in {urdf_path}")
    if payload and tree_loads(str(urdf_path)).total_mass <= 0:
        raise BadInput(f"payload: {urdf_path} has no inertias, so its loads are a prior of unknown size and a payload's "
                       "kilograms cannot be weighed against them; give the URDF its links' masses")
    moving = chosen.get("moving_link")
    if isinstance(moving, dict) or chosen.get("joints") is not None:
        links = tracked_links(moving, "urdf stand option 'moving_link'") if isinstance(moving, dict) else (
            [moving] if moving else [])
        if not links:
            raise BadInput("urdf stand option 'joints' needs 'moving_link' (a link, or a mapping marker -> link)")
        chain = kinematic_tree(tree, links, chosen.get("base_link"), chosen.get("joints"),
                               where=JOINTS_WHERE)
        title = f"{TITLE}: {chain.robot_name} tree {chain.base_link} -> {', '.join(chain.links)}"
    else:
        chain = serial_chain(tree, chosen.get("base_link"), moving)
        title = f"{TITLE}: {chain.robot_name} {chain.base_link} -> {chain.moving_link}"
    description.update(urdf=str(urdf_path), base_link=chain.base_link,
                       moving_link=moving if isinstance(moving, dict) else chain.moving_link)
    spec = chain_spec(
        chain,
        name="urdf",
        title=title,
        free_groups=("offset", "origin"),
        description=description,
        description_path=path,
    )
    # what rebuilds this stand (calibration.yaml's platform_options, effects that rebuild it)
    spec.extras["platform_options"] = {k: v for k, v in chosen.items()
                                       if v is not None and k in OPTIONS and not (k == "payload" and not v)}
    spec.extras["payload"] = payload
    return spec


def tracked_links(mapping: dict, where: str) -> list[str]:
    """The links of a mapping {marker or body: link}, each once, in the order first named (the
    first is the moving frame). BadInput naming ``where`` if it is not such a mapping."""
    if not mapping or not all(isinstance(k, str) and k and isinstance(v, str) and v for k, v in mapping.items()):
        raise BadInput(f"{where} must map marker or rigid-body names to link names, e.g. {{R: right_tcp, L: left_tcp}}, "
                       f"got {mapping!r}")
    return list(dict.fromkeys(mapping.values()))


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory("urdf", TITLE, build, (".urdf", ".yaml", ".yml"))]
