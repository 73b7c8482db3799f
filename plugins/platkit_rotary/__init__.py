"""platkit stand ``rotary``: the two-stage rotary rig, built on the URDF route.

Joint 1 (outer stage) turns about the base z axis, joint 2 (inner stage) about the outer
stage's y axis 150 mm above joint 1 (descriptions/rotary.urdf). Controls ``u1``, ``u2`` are in
degrees; joint angle ``q_j = k_j (u_j - u0_j)`` with nominal ``k = 1`` (degree per degree) and
``u0 = 0``. In td (SI inside) this is ``theta_j = scale_j * (pi/180 * u_j - offset_j)``:
``joint<j>.scale`` is k, ``joint<j>.offset`` is u0 in radians. Each joint's origin also carries
six errors (``joint<j>.origin_x .. origin_rz``): axis offset (x, y, z), axis misalignment and
non-perpendicularity (rx, ry, rz). All start free; the estimator reduces away what a session
cannot identify (e.g. the rotation of joint 1's origin about its own axis equals its offset).

The description is a URDF with exactly two revolute joints on the chain from the root link to
the single leaf (the ``platform`` link the markers sit on). Like every URDF stand it takes the
options ``base_link`` and ``moving_link`` (a session's ``moving_link:``), for a rig whose
markers sit on another link; the chain must still hold exactly the two stages.
"""
from __future__ import annotations

from pathlib import Path

from platkit.errors import BadDescription, BadInput
from platkit.hookspecs import hookimpl
from platkit.io.description import default_description
from platkit.model import PlatformFactory, PlatformSpec
from platkit.urdf import chain_spec, read_urdf, serial_chain

TITLE = "Two-stage rotary rig (URDF)"


def build(path: Path | None, options: dict | None = None) -> PlatformSpec:
    options = {k: v for k, v in (options or {}).items() if v is not None}
    unknown = sorted(set(options) - {"base_link", "moving_link"})
    if unknown:
        raise BadInput(f"the rotary stand takes the options base_link, moving_link; unknown: {unknown}")
    path = path or default_description("rotary.urdf")
    chain = serial_chain(read_urdf(path), options.get("base_link"), options.get("moving_link"))
    revolute = [j for j in chain.actuated if j.type in ("revolute", "continuous")]
    if len(chain.actuated) != 2 or len(revolute) != 2:
        raise BadDescription(
            f"{path}: the rotary rig needs exactly two revolute joints from {chain.base_link} to "
            f"{chain.moving_link}, found {[f'{j.name} ({j.type})' for j in chain.actuated]}"
        )
    return chain_spec(
        chain,
        name="rotary",
        title=TITLE,
        control_names=["u1", "u2"],
        control_units=["deg", "deg"],
        free_groups=("offset", "scale", "origin"),
        description={"urdf": str(path), "base_link": chain.base_link, "moving_link": chain.moving_link},
        description_path=path,
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory("rotary", TITLE, build, (".urdf",))]
