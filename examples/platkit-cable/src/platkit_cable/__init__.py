"""platkit stand ``cable``: a cable-driven parallel robot, eight cables on a six-degree platform.

Cable i runs from its winch's exit point A_i on the frame (base frame) to the point b_i of the
platform (platform frame). The control is the length paid out, l_i; a length offset o_i (the
winch's zero) makes the cable's true length l_i + o_i. One residual row per cable, written the
natural way:

    F_i = l_i + o_i - |A_i - (X + R b_i)|

Eight rows for six pose coordinates (x, y, z, roll, pitch, yaw): eight independent lengths are
almost never consistent. The stand declares how far a real cable may miss its command (its
stretch, ``misfit``): platkit's forward kinematics is then the least-squares pose, with each
cable's misfit reported, and a command that misses by more is refused naming the cables. Any
pose of the workspace box is reachable with taut cables, while the box of lengths is not free:
the stand declares its pose space free (``free_space='pose'``), so plans and checks draw poses
and map them through the closed-form inverse kinematics.

td = (A_1..A_8, b_1..b_8, o_1..o_8): 56 numbers, metres.

The package also registers the cable robot's outside physics as diagnosis effects
(``cable_elasticity``, ``pulley_radius``: see platkit_cable.effects), through the same hook as
platkit's built-in effects.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import ca_matrix_from_quat
from platkit.hookspecs import hookimpl
from platkit.io.description import check_fields, check_platform, load_yaml, number, require, vector
from platkit.model import Control, Parameter, PlatformFactory, PlatformSpec, RowMisfit, length_scale, six_dof_pose
from platkit_cable.effects import EFFECTS

NAME = "cable"
N_CABLES = 8
DEFAULT_DESCRIPTION = Path(__file__).with_name("cable.yaml")
#: the platform counts as upright (the stand's branch) while its z axis is within 60 deg of the base's
UPRIGHT_COS = 0.5


def read_description(path: Path) -> dict:
    """Parse and check a description; return SI arrays. Every error names the file and field."""
    data = load_yaml(path)
    check_platform(data, NAME, path)
    check_fields(data, ("units", "cables", "cable_length", "stretch", "neutral_pose", "workspace"), path)
    units = require(data, "units", path, dict)
    check_fields(units, ("length",), path, "units")
    scale = length_scale(str(units.get("length", "")))
    cables = require(data, "cables", path, list)
    if len(cables) != N_CABLES:
        raise BadDescription(f"{path}: field 'cables' must list {N_CABLES} cables, got {len(cables)}")
    names, A, b = [], [], []
    for i, cable in enumerate(cables):
        where = f"cables[{i}]"
        if not isinstance(cable, dict):
            raise BadDescription(f"{path}: {where} must be a mapping")
        check_fields(cable, ("name", "anchor", "platform_point"), path, where)
        names.append(str(require(cable, "name", path, str, where)))
        A.append(vector(cable, "anchor", path, 3, where) * scale)
        b.append(vector(cable, "platform_point", path, 3, where) * scale)
    if len(set(names)) != N_CABLES:
        raise BadDescription(f"{path}: field 'cables' names a cable twice")
    stroke = vector(data, "cable_length", path, 2) * scale
    if not 0 <= stroke[0] < stroke[1]:
        raise BadDescription(f"{path}: field 'cable_length' must be [min, max] with 0 <= min < max")
    stretch = number(data, "stretch", path) * scale
    if not stretch > 0:
        raise BadDescription(f"{path}: field 'stretch' must be a positive length (a cable's plausible misfit)")
    neutral = require(data, "neutral_pose", path, dict)
    check_fields(neutral, ("position",), path, "neutral_pose")
    X0 = vector(neutral, "position", path, 3, "neutral_pose") * scale
    box = require(data, "workspace", path, dict)
    check_fields(box, ("min", "max", "max_angle_deg"), path, "workspace")
    lo = vector(box, "min", path, 3, "workspace") * scale
    hi = vector(box, "max", path, 3, "workspace") * scale
    angle = np.radians(number(box, "max_angle_deg", path, "workspace"))
    if not (np.all(lo < X0) and np.all(X0 < hi)):
        raise BadDescription(f"{path}: field 'neutral_pose.position' must lie inside 'workspace' (min < position < max)")
    if not 0 < angle < np.pi / 3:
        raise BadDescription(f"{path}: field 'workspace.max_angle_deg' must be between 0 and 60")
    return dict(names=names, A=np.array(A), b=np.array(b), stroke=stroke, stretch=stretch, X0=X0, lo=lo, hi=hi,
                angle=angle, raw=data)


def cable_vectors(td, q, X):
    """CasADi 3x8: the cables as vectors from the platform point to the anchor, A_i - (X + R b_i)."""
    A = ca.reshape(td[0:24], 3, N_CABLES)
    b = ca.reshape(td[24:48], 3, N_CABLES)
    R = ca_matrix_from_quat(q)
    return A - (ca.repmat(X, 1, N_CABLES) + ca.mtimes(R, b))


def build(path: Path | None, options: dict) -> PlatformSpec:
    """Build the stand from a description file (None: the one shipped in this package)."""
    if options:
        raise BadInput(f"the {NAME} stand takes no options, got {sorted(options)}")
    path = path or DEFAULT_DESCRIPTION
    desc = read_description(path)
    src = str(path)
    names = desc["names"]
    params = [Parameter(f"A{i + 1}_{c}", "m", float(v), group="anchors", source=src)
              for i in range(N_CABLES) for c, v in zip("xyz", desc["A"][i])]
    params += [Parameter(f"b{i + 1}_{c}", "m", float(v), group="platform_points", source=src)
               for i in range(N_CABLES) for c, v in zip("xyz", desc["b"][i])]
    params += [Parameter(f"o{i + 1}", "m", 0.0, group="length_offsets", source=src) for i in range(N_CABLES)]

    u = ca.SX.sym("u", N_CABLES)
    td = ca.SX.sym("td", len(params))
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    lengths = ca.sqrt(ca.sum1(cable_vectors(td, q, X) ** 2)).T
    residual = ca.Function("F", [u, td, q, X], [u + td[48:56] - lengths], ["u", "td", "q", "X"], ["r"])
    inverse = ca.Function("inverse", [td, q, X], [lengths - td[48:56]], ["td", "q", "X"], ["u"])
    # Assembly: the platform upright (its z axis within 60 deg of the base's). Turned over, the
    # same lengths close with the cables crossing through the platform: not this robot.
    R = ca_matrix_from_quat(q)
    branch = ca.Function("branch", [u, td, q, X], [R[2, 2] - UPRIGHT_COS], ["u", "td", "q", "X"], ["g"])

    coords, pose, from_pose = six_dof_pose(desc["X0"], position_min=desc["lo"], position_max=desc["hi"],
                                           angle_max=desc["angle"])
    td0 = np.array([prm.nominal for prm in params])
    u0 = np.asarray(inverse(td0, [1.0, 0.0, 0.0, 0.0], desc["X0"])).ravel()
    lo, hi = desc["stroke"]
    controls = []
    for name, neutral in zip(names, u0):
        if not lo <= neutral <= hi:
            raise BadDescription(f"{path}: field 'neutral_pose' needs cable {name} at {neutral / 1e-3:.1f} mm, "
                                 "outside 'cable_length'")
        controls.append(Control(name, "m", float(lo), float(hi), float(neutral)))
    misfit = [RowMisfit(f"cable {name}", "m", float(desc["stretch"])) for name in names]
    return PlatformSpec(
        name=NAME, title="cable-driven parallel robot (8 cables, 6-DOF platform)", controls=controls,
        parameters=params, coordinates=coords, residual=residual, pose=pose, coordinates_from_pose=from_pose,
        inverse=inverse, branch=branch, description=desc["raw"], description_path=path, misfit=misfit,
        free_space="pose",
    )


@hookimpl
def platkit_register_platforms():
    return [PlatformFactory(NAME, "cable-driven parallel robot (8 cables, 6-DOF platform)", build, (".yaml", ".yml"))]


@hookimpl
def platkit_register_effects():
    return list(EFFECTS)
