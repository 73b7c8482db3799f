"""platkit stand ``urdf``: any serial chain from any URDF.

The description is a URDF file (the chain runs from ``base_link``, default the root link, to
``moving_link``, default the single leaf) or a YAML file that names one::

    urdf: robot.urdf          # relative to the YAML file
    base_link: base_link      # optional
    moving_link: tool0        # optional

Options (from a session or the command line) ``base_link`` and ``moving_link`` override the
description's. Controls: the chain's actuated joints in chain order, in the URDF's units
(rad, m). Parameters (see :mod:`platkit.urdf`): per joint an offset (free), a scale (fixed at 1:
the spec's urdf stand calibrates offsets and origin errors) and six origin errors (free; the
estimator reduces the unidentifiable ones away and reports them).
"""
from __future__ import annotations

from pathlib import Path

from platkit.errors import BadDescription, BadInput
from platkit.hookspecs import hookimpl
from platkit.io.description import default_description, load_yaml, require
from platkit.model import PlatformFactory, PlatformSpec
from platkit.urdf import chain_spec, read_urdf, serial_chain

TITLE = "Serial chain from a URDF"
OPTIONS = ("base_link", "moving_link")
YAML_FIELDS = ("urdf", "base_link", "moving_link", "notes")


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
        if not isinstance(v, str) or not v:
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
        for k in OPTIONS:
            chosen[k] = _text(data.get(k), path, k)
        description = dict(data)
    else:
        urdf_path = path
        description = {}
    chosen.update(options)
    tree = read_urdf(urdf_path)
    chain = serial_chain(tree, chosen.get("base_link"), chosen.get("moving_link"))
    description.update(urdf=str(urdf_path), base_link=chain.base_link, moving_link=chain.moving_link)
    return chain_spec(
        chain,
        name="urdf",
        title=f"{TITLE}: {chain.robot_name} {chain.base_link} -> {chain.moving_link}",
        free_groups=("offset", "origin"),
        description=description,
        description_path=path,
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory("urdf", TITLE, build, (".urdf", ".yaml", ".yml"))]
