"""The platform model: constraint residuals F(u, td, q, X) = 0.

Vocabulary (docs/concepts.md):

- ``u``  controls (n_u,): leg lengths, motor counts, joint angles, in the control's own unit.
- ``td`` geometric parameters (n_td,): joint coordinates, offsets, scales; SI units inside.
- ``q``  orientation of the moving frame in the base frame, unit quaternion (w, x, y, z).
- ``X``  position of the moving frame's origin in the base frame, metres.
- ``p``  the stand's pose coordinates (n_p,): the minimal coordinates of the poses the stand
  can take (x, y, z, roll, pitch, yaw for a hexapod; alpha, beta, h for the PSVR). The stand
  supplies ``pose``: p -> (q, X).

A stand is a :class:`PlatformSpec`. The core checks it once (:func:`validate_spec`) and
derives every Jacobian from the CasADi functions; nothing downstream is stand-specific.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import casadi as ca
import numpy as np

from platkit.errors import BadDescription, BadInput
from platkit.geometry import ca_quat_from_rpy

LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}


@dataclass(frozen=True)
class Control:
    """One control of the stand. ``unit``: 'm', 'rad', 'deg' or 'count'.

    Only 'm' controls are rescaled to the session's length unit at the boundaries; the others
    are written in files as they are.
    """

    name: str
    unit: str
    lower: float
    upper: float
    neutral: float


@dataclass(frozen=True)
class Parameter:
    """One geometric parameter in td. ``unit`` is SI ('m', 'rad', '1', 'rad/count', 'count')."""

    name: str
    unit: str
    nominal: float
    lower: float = -np.inf
    upper: float = np.inf
    free: bool = True
    group: str = ""
    source: str = ""


@dataclass(frozen=True)
class Coordinate:
    """One pose coordinate p_k. ``unit`` is 'm' or 'rad'."""

    name: str
    unit: str
    neutral: float
    lower: float = -np.inf
    upper: float = np.inf


@dataclass(frozen=True)
class RowMisfit:
    """How far one residual row may stay from zero on the real stand: a cable's stretch, a leg's
    play. ``name``: the row as a person reads it ('cable c3'); ``unit``: the row's unit ('m',
    'rad' or '1'); ``plausible``: the largest |r_i| the stand takes as real, in that unit (SI).

    A stand with more residual rows than pose coordinates declares one per row: forward
    kinematics is then the weighted least-squares pose (row i weighted by 1/plausible_i), and a
    pose whose rows miss by more than their plausible misfit is refused, naming the rows.
    """

    name: str
    unit: str
    plausible: float


#: the spaces a stand may declare free (a box every point of which the stand takes)
FREE_SPACES = ("controls", "pose")


@dataclass
class PlatformSpec:
    """Everything a stand tells the core about itself.

    Required:
        residual: ``casadi.Function`` inputs (u, td, q, X), output r (n_r,). F = 0 on every pose
            the stand takes under controls u.
        pose: ``casadi.Function`` input p (n_p,), outputs (q, X).
    Optional:
        coordinates_from_pose: (q, X) -> p, the inverse of ``pose`` (needed for IK input as q, X).
        inverse: (td, q, X) -> u, closed-form inverse kinematics on the stand's branch.
        forward: (u, td) -> (q, X), closed-form forward kinematics (serial chains).
        branch: (u, td, q, X) -> g; the stand's assembly mode is g > 0 componentwise. A pose
            with some g <= 0 satisfies F = 0 but is a mirror the stand cannot take.
        tracked_links, link_poses: a tree (several links carry markers): the links, the moving
            frame's (the spec's pose) first, and ``link_poses: (u, td) -> (q (4 L), X (3 L))``,
            every tracked link's orientation and position in the base frame, stacked in that
            order. Empty and None for a stand with one moving part.
    """

    name: str
    title: str
    controls: list[Control]
    parameters: list[Parameter]
    coordinates: list[Coordinate]
    residual: ca.Function
    pose: ca.Function
    coordinates_from_pose: ca.Function | None = None
    inverse: ca.Function | None = None
    forward: ca.Function | None = None
    branch: ca.Function | None = None
    description: dict[str, Any] = field(default_factory=dict)
    description_path: Path | None = None
    moving_frame: str = "platform"
    base_frame: str = "base"
    extras: dict[str, Any] = field(default_factory=dict)
    misfit: list[RowMisfit] | None = None
    free_space: str = "controls"
    tracked_links: list[str] = field(default_factory=list)
    link_poses: ca.Function | None = None

    @property
    def n_u(self) -> int:
        return len(self.controls)

    @property
    def n_td(self) -> int:
        return len(self.parameters)

    @property
    def n_p(self) -> int:
        return len(self.coordinates)

    @property
    def control_names(self) -> list[str]:
        return [c.name for c in self.controls]

    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    @property
    def coordinate_names(self) -> list[str]:
        return [c.name for c in self.coordinates]

    @property
    def pose_free(self) -> bool:
        """True when the stand declares its pose box free (samples are drawn as poses)."""
        return self.free_space == "pose"

    def plausible_misfit(self) -> np.ndarray | None:
        """(n_r,) the rows' plausible misfit (SI), or None where the rows must close exactly."""
        if self.misfit is None:
            return None
        return np.array([m.plausible for m in self.misfit], dtype=float)

    def coordinate_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.array([c.lower for c in self.coordinates], float),
            np.array([c.upper for c in self.coordinates], float),
        )

    def nominal_td(self) -> np.ndarray:
        return np.array([p.nominal for p in self.parameters], dtype=float)

    def neutral_u(self) -> np.ndarray:
        return np.array([c.neutral for c in self.controls], dtype=float)

    def neutral_p(self) -> np.ndarray:
        return np.array([c.neutral for c in self.coordinates], dtype=float)

    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (
            np.array([c.lower for c in self.controls], float),
            np.array([c.upper for c in self.controls], float),
        )

    def with_td(self, td: np.ndarray) -> "PlatformSpec":
        """A copy whose nominal parameters are ``td`` (for calibrated models)."""
        from dataclasses import replace

        td = np.asarray(td, float)
        params = [replace(p, nominal=float(v)) for p, v in zip(self.parameters, td)]
        return replace(self, parameters=params)


@dataclass
class PlatformFactory:
    """What a plugin registers: a name and a way to build the spec from a description file.

    ``build(path_or_None, options) -> PlatformSpec``; ``None`` means the plugin's default
    description. ``options`` is a dict of stand-specific choices that come from a session or
    the command line (e.g. ``{"moving_link": "tool0", "base_link": "base"}`` for URDF chains);
    a stand rejects options it does not know with BadInput.
    ``description_suffixes``: the file types ``build`` accepts, e.g. ('.yaml',) or ('.urdf',).
    """

    name: str
    title: str
    build: Callable[[Path | None, dict], PlatformSpec]
    description_suffixes: tuple[str, ...] = (".yaml",)
    package: str = ""

    def __call__(self, description: str | Path | None = None, **options) -> PlatformSpec:
        path = None if description is None else Path(description)
        if path is not None:
            if not path.is_file():
                raise BadDescription(f"{path}: description file not found")
            if self.description_suffixes and path.suffix.lower() not in self.description_suffixes:
                raise BadDescription(
                    f"{path}: the {self.name} stand reads {', '.join(self.description_suffixes)} files"
                )
        spec = self.build(path, dict(options))
        validate_spec(spec)
        return spec


def _check_function(spec_name: str, fn: ca.Function, what: str, inputs: dict[str, int], outputs: dict[str, int]):
    if not isinstance(fn, ca.Function):
        raise BadDescription(f"stand {spec_name!r}: {what} must be a casadi.Function, got {type(fn).__name__}")
    names_in = [fn.name_in(i) for i in range(fn.n_in())]
    names_out = [fn.name_out(i) for i in range(fn.n_out())]
    if names_in != list(inputs):
        raise BadDescription(f"stand {spec_name!r}: {what} inputs are {names_in}, expected {list(inputs)}")
    if names_out != list(outputs):
        raise BadDescription(f"stand {spec_name!r}: {what} outputs are {names_out}, expected {list(outputs)}")
    for i, (n, size) in enumerate(inputs.items()):
        got = fn.size_in(i)
        if size >= 0 and got != (size, 1):
            raise BadDescription(f"stand {spec_name!r}: {what} input {n} has shape {got}, expected ({size}, 1)")
    for i, (n, size) in enumerate(outputs.items()):
        got = fn.size_out(i)
        if size >= 0 and got != (size, 1):
            raise BadDescription(f"stand {spec_name!r}: {what} output {n} has shape {got}, expected ({size}, 1)")


def validate_spec(spec: PlatformSpec) -> None:
    """Check names and sizes of every function a stand supplies; raise BadDescription if wrong."""
    n_u, n_td, n_p = spec.n_u, spec.n_td, spec.n_p
    if n_u == 0 or n_p == 0:
        raise BadDescription(f"stand {spec.name!r}: it declares no controls or no pose coordinates")
    for kind, items in (("control", spec.controls), ("parameter", spec.parameters), ("coordinate", spec.coordinates)):
        names = [x.name for x in items]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise BadDescription(f"stand {spec.name!r}: duplicate {kind} names {dup}")
    _check_function(spec.name, spec.residual, "residual", {"u": n_u, "td": n_td, "q": 4, "X": 3}, {"r": -1})
    if spec.residual.size_out(0)[1] != 1:
        raise BadDescription(f"stand {spec.name!r}: residual r must be a column vector")
    _check_function(spec.name, spec.pose, "pose", {"p": n_p}, {"q": 4, "X": 3})
    if spec.coordinates_from_pose is not None:
        _check_function(spec.name, spec.coordinates_from_pose, "coordinates_from_pose", {"q": 4, "X": 3}, {"p": n_p})
    if spec.inverse is not None:
        _check_function(spec.name, spec.inverse, "inverse", {"td": n_td, "q": 4, "X": 3}, {"u": n_u})
    if spec.forward is not None:
        _check_function(spec.name, spec.forward, "forward", {"u": n_u, "td": n_td}, {"q": 4, "X": 3})
    if spec.link_poses is not None:
        L = len(spec.tracked_links)
        if L == 0:
            raise BadDescription(f"stand {spec.name!r}: link_poses is given but tracked_links is empty")
        _check_function(spec.name, spec.link_poses, "link_poses", {"u": n_u, "td": n_td}, {"q": 4 * L, "X": 3 * L})
    if spec.branch is not None:
        _check_function(spec.name, spec.branch, "branch", {"u": n_u, "td": n_td, "q": 4, "X": 3}, {"g": -1})
    r = np.asarray(spec.residual(spec.neutral_u(), spec.nominal_td(), *spec.pose(spec.neutral_p()))).ravel()
    if not np.all(np.isfinite(r)):
        raise BadDescription(f"stand {spec.name!r}: the residual is not finite at the neutral pose")
    _check_misfit(spec, r.size)
    _check_free_space(spec)


def _where(spec: PlatformSpec) -> str:
    return f"{spec.description_path}: " if spec.description_path is not None else ""


def _check_misfit(spec: PlatformSpec, n_r: int) -> None:
    """The plausible misfit: one positive finite RowMisfit per residual row, or none at all."""
    if spec.misfit is None:
        return
    where = f"{_where(spec)}stand {spec.name!r}: field 'misfit'"
    rows = list(spec.misfit)
    if len(rows) != n_r:
        raise BadDescription(f"{where} declares {len(rows)} rows, the residual has {n_r}")
    if n_r < spec.n_p:
        raise BadDescription(f"{where}: a plausible misfit needs at least as many residual rows as pose coordinates "
                             f"({n_r} < {spec.n_p})")
    for i, m in enumerate(rows):
        if not isinstance(m, RowMisfit):
            raise BadDescription(f"{where}[{i}] must be a platkit.model.RowMisfit, got {type(m).__name__}")
        if not (isinstance(m.plausible, (int, float)) and np.isfinite(m.plausible) and m.plausible > 0):
            raise BadDescription(f"{where}[{i}] ({m.name}): plausible misfit must be a positive number, got {m.plausible!r}")


def _check_free_space(spec: PlatformSpec) -> None:
    """A declared free space: 'controls' needs finite strokes only where sampled (checked there);
    'pose' needs finite coordinate bounds and a way from poses to controls."""
    where = f"{_where(spec)}stand {spec.name!r}: field 'free_space'"
    if spec.free_space not in FREE_SPACES:
        raise BadDescription(f"{where} is {spec.free_space!r}, not one of {', '.join(FREE_SPACES)}")
    if spec.free_space == "pose":
        lo, hi = spec.coordinate_bounds()
        bad = [c.name for c, a, b in zip(spec.coordinates, lo, hi) if not (np.isfinite(a) and np.isfinite(b) and a < b)]
        if bad:
            raise BadDescription(f"{where} is 'pose' but coordinates {bad} have no finite bounds lower < upper")
        p0 = spec.neutral_p()
        if np.any(p0 < lo) or np.any(p0 > hi):
            raise BadDescription(f"{where} is 'pose' but the neutral pose lies outside the coordinates' bounds")


def length_scale(unit: str) -> float:
    """Metres per one ``unit`` ('m' or 'mm'); BadInput otherwise."""
    try:
        return LENGTH_UNITS[unit]
    except KeyError:
        raise BadInput(f"length unit {unit!r} is not one of {sorted(LENGTH_UNITS)}") from None


def controls_to_si(spec: PlatformSpec, u: np.ndarray, length_unit: str) -> np.ndarray:
    """Controls in a file's units -> internal units (only 'm' controls are rescaled). u: (..., n_u)."""
    u = np.array(u, dtype=float, copy=True)
    s = length_scale(length_unit)
    for i, c in enumerate(spec.controls):
        if c.unit == "m":
            u[..., i] *= s
    return u


def controls_from_si(spec: PlatformSpec, u: np.ndarray, length_unit: str) -> np.ndarray:
    """Internal controls -> a file's units. u: (..., n_u)."""
    u = np.array(u, dtype=float, copy=True)
    s = length_scale(length_unit)
    for i, c in enumerate(spec.controls):
        if c.unit == "m":
            u[..., i] /= s
    return u


def six_dof_pose(neutral_position_m, neutral_rpy=(0.0, 0.0, 0.0), position_min=None, position_max=None, angle_max=np.pi):
    """Pose coordinates p = (x, y, z, roll, pitch, yaw) for a stand with six free degrees.

    Returns (coordinates, pose, coordinates_from_pose) ready for a PlatformSpec, with
    R = Rz(yaw) Ry(pitch) Rx(roll). Positions in metres.
    """

    lo = [-np.inf] * 3 if position_min is None else list(position_min)
    hi = [np.inf] * 3 if position_max is None else list(position_max)
    coords = [
        Coordinate(n, "m", float(v), float(l), float(h))
        for n, v, l, h in zip(("x", "y", "z"), neutral_position_m, lo, hi)
    ] + [Coordinate(n, "rad", float(v), -angle_max, angle_max) for n, v in zip(("roll", "pitch", "yaw"), neutral_rpy)]
    p = ca.SX.sym("p", 6)
    pose = ca.Function("pose", [p], [ca_quat_from_rpy(p[3], p[4], p[5]), p[:3]], ["p"], ["q", "X"])
    q = ca.SX.sym("q", 4)
    X = ca.SX.sym("X", 3)
    w, x, y, z = q[0], q[1], q[2], q[3]
    roll = ca.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = ca.asin(ca.fmin(ca.fmax(2 * (w * y - z * x), -1), 1))
    yaw = ca.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    from_pose = ca.Function("coordinates_from_pose", [q, X], [ca.vertcat(X, roll, pitch, yaw)], ["q", "X"], ["p"])
    return coords, pose, from_pose


# the structural dependence of each tracked link on the controls, per spec (id and the spec itself)
_LINK_CONTROLS: dict = {}


def controls_moving_links(spec: PlatformSpec) -> dict[str, np.ndarray]:
    """Per tracked link (a chain: its moving frame), which controls (n_u,) bool move it: its pose
    depends on them (structurally: through the joints on its path, and a mimic joint's master)."""
    if spec.link_poses is None or len(spec.tracked_links) < 2:
        return {spec.moving_frame: np.ones(spec.n_u, bool)}
    return link_controls(spec)


def link_controls(spec: PlatformSpec) -> dict[str, np.ndarray]:
    """Per tracked link of a stand with ``link_poses`` (a tree, one tracked link or more), which
    controls (n_u,) bool its pose depends on, structurally (kept per spec)."""
    hit = _LINK_CONTROLS.get(id(spec))
    if hit is not None and hit[0] is spec:
        return hit[1]
    if spec.link_poses is None:
        raise ValueError(f"{spec.name}: no link_poses (a stand of one moving frame): see controls_moving_links")
    u, t = ca.SX.sym("u", spec.n_u), ca.SX.sym("td", spec.n_td)
    q, X = spec.link_poses(u, t)
    out = {link: np.array(ca.which_depends(ca.vertcat(q[4 * k:4 * k + 4], X[3 * k:3 * k + 3]), u, 1, False), bool)
           for k, link in enumerate(spec.tracked_links)}
    _LINK_CONTROLS[id(spec)] = (spec, out)
    return out
