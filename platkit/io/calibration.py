"""A calibration result and its file, ``calibration.yaml``.

The file (spec/README.md section 2) holds: the platform and the description used; every
parameter of the stand with ``value``, ``std`` and ``nominal`` (and ``unit``, ``status``:
estimated / held_at_nominal / fixed); the base-to-mocap transform; the marker positions on the
moving part; the residual RMS; the identifiability analysis; any model terms (ModelTerm.to_dict).

Units in the file: lengths in the session's length unit (``length_unit``, 'mm' or 'm', stated at
the top and beside every length), angles in radians, other parameters in their SI unit as the
stand declares it (``unit`` beside each). Inside platkit everything is SI.
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from platkit.errors import BadInput, PlatkitError
from platkit.geometry import matrix_from_rotvec, quat_from_rotvec, transform
from platkit.io.description import dump_yaml, load_yaml
from platkit.io.jsonout import strict
from platkit.io.shipped import shipped_dir
from platkit.model import PlatformSpec, length_scale
from platkit.plugins import get_platform, term_from_dict

FORMAT = "platkit-calibration/1"


@dataclass(frozen=True, slots=True)
class FitRecord:
    """What an estimator leaves beside its result, in memory only (calibration.yaml holds none of
    it): for the report's figures, the checks of the fit, the model selection's held-out errors and
    a diagnosis's refits. Channels C: the M markers, then each rigid body's origin, then each body's
    scaled rotation error.

    residuals_before, residuals_after: (N, C, 3) m, predicted minus measured (NaN where unseen),
    after the registration alone (td at its start) and at the estimate; weights_before, weights:
    (N, C) the robust loss's final weights of each fit (0: rejected); controls: (N, n_u) SI, the
    poses' controls. The least-squares estimator's own (None from the paper's method): ``problem``,
    the :class:`platkit.calibrate.problem.CalibrationProblem` fitted (typed loosely: calibrate sits
    above io); ``z`` (n_z,) its unknowns at the estimate; ``active`` (n_z,) bool, those estimated;
    ``cov`` (n_active, n_active) their covariance; ``identifiability``, the
    :class:`platkit.calibrate.identifiability.Identifiability` that ``Calibration.identifiability``
    reports; ``stop``, the :class:`platkit.calibrate.solve.WindowJudgement` of the final fit's last
    Levenberg-Marquardt run where it met no per-step rule within its iterations (None where it did).
    """

    residuals_before: np.ndarray
    residuals_after: np.ndarray
    weights_before: np.ndarray
    weights: np.ndarray
    controls: np.ndarray
    problem: Any = None
    z: np.ndarray | None = None
    active: np.ndarray | None = None
    cov: np.ndarray | None = None
    identifiability: Any = None
    stop: Any = None


@dataclass
class Calibration:
    """What an estimator found. SI inside (metres, radians).

    td, td_std, td_nominal: (n_td,); std is NaN for held and fixed parameters; td_status: n_td of
    'estimated', 'held_at_nominal' (the data cannot fix it) or 'fixed' (not free in this fit).
    mocap_rotvec, mocap_translation: the base-to-mocap transform mocap_from_base (rotation
    vector, rad; translation, m) and their std (6,). marker_positions: (M, 3) m in the moving
    frame, marker_std (M, 3). terms/theta/theta_std: model terms and their parameters.
    rms_before: point RMS (m) with nominal td after fitting only the transform and markers;
    rms_after: point RMS (m) at the estimate (both over the observations the final fit's robust
    loss kept).
    body_names, body_positions (B, 3) m, body_rotvecs (B, 3) rad: rigid bodies' placements on the
    moving part (body frame -> moving frame), body_std (B, 6) (origin m, rotation vector rad);
    body_rho (m/rad): the weight of their rotation errors against position errors, and
    body_rho_source: 'declared' (session.yaml rigid_body_noise), 'estimated' or 'default'.
    marker_links: on a tree, {marker or body: the link it rides on}; marker and body positions
    are then in their own link's frame (empty: all on the moving frame).
    warnings: what to check before trusting the fit, one sentence each (calibration.yaml's
    ``warnings``); paper: the paper's method's own record (report.json's ``paper``); fit: what the
    estimator left in memory (:class:`FitRecord`; None for a calibration read from its file).
    """

    platform: str
    description: str | None
    spec: PlatformSpec
    td: np.ndarray
    td_std: np.ndarray
    td_nominal: np.ndarray
    td_status: list[str]
    mocap_rotvec: np.ndarray
    mocap_translation: np.ndarray
    mocap_std: np.ndarray
    marker_names: list[str]
    marker_positions: np.ndarray
    marker_std: np.ndarray
    rms_before: float
    rms_after: float
    length_unit: str = "mm"
    platform_options: dict[str, Any] = field(default_factory=dict)
    method: str = "lsq"
    converged: bool = True
    iterations: int = 0
    n_poses: int = 0
    n_markers: int = 0
    n_observations: int = 0
    n_rejected: int = 0
    noise_sigma: float = float("nan")  # per-axis marker noise estimated from the residuals, m
    identifiability: dict[str, Any] = field(default_factory=dict)
    terms: list = field(default_factory=list)
    theta: list = field(default_factory=list)
    theta_std: list = field(default_factory=list)
    heldout: dict[str, Any] = field(default_factory=dict)
    time_s: float = 0.0
    #: a calibration from motion (platkit.calibrate.motion): the samples used and the actuators' response
    motion: dict[str, Any] = field(default_factory=dict)
    imu: dict[str, Any] = field(default_factory=dict)  # what an IMU diagnosis added (platkit.diagnose.imu), SI
    body_names: list[str] = field(default_factory=list)
    body_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    body_rotvecs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    body_std: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    body_rho: float = float("nan")
    body_rho_source: str = ""
    marker_links: dict[str, str] = field(default_factory=dict)  # tree: marker or body -> its link
    warnings: list[str] = field(default_factory=list)
    paper: dict[str, Any] = field(default_factory=dict)
    fit: FitRecord | None = None

    # ------------------------------------------------------------------ derived
    @property
    def mocap_from_base(self) -> np.ndarray:
        """4x4 transform mapping base-frame coordinates to the motion-capture frame."""
        return transform(matrix_from_rotvec(self.mocap_rotvec), self.mocap_translation)

    def calibrated_spec(self) -> PlatformSpec:
        """The stand with the estimated td as its nominal parameters."""
        return self.spec.with_td(self.td)

    # ------------------------------------------------------------------ file
    def to_dict(self) -> dict:
        s = length_scale(self.length_unit)
        lu = self.length_unit

        def shown(v, unit):
            return (float(v) / s, lu) if unit == "m" else (float(v), unit)

        params = {}
        for p, v, sd, nom, st in zip(self.spec.parameters, self.td, self.td_std, self.td_nominal, self.td_status):
            value, unit = shown(v, p.unit)
            nominal, _ = shown(nom, p.unit)
            std = None if not np.isfinite(sd) else shown(sd, p.unit)[0]
            params[p.name] = {"value": value, "std": std, "nominal": nominal, "unit": unit,
                              "group": p.group, "status": st}
        R = matrix_from_rotvec(self.mocap_rotvec)
        q = quat_from_rotvec(self.mocap_rotvec)
        markers: dict[str, dict[str, Any]] = {}
        for name, pos, sd in zip(self.marker_names, self.marker_positions, self.marker_std):
            markers[name] = {"position": [float(x / s) for x in pos],
                             "std": [None if not np.isfinite(x) else float(x / s) for x in sd]}
            if self.marker_links:
                markers[name]["link"] = self.marker_links[name]
        out = {
            "format": FORMAT,
            "platform": self.platform,
            "description": self.description,
            "platform_options": dict(self.platform_options),
            "method": self.method,
            "length_unit": lu,
            "units": {"length": lu, "angle": "rad",
                      "note": f"lengths in {lu}; angles in rad; other parameters in the unit written beside them"},
            "parameters": params,
            "mocap_from_base": {
                "rotation_vector": [float(x) for x in self.mocap_rotvec],
                "quaternion_wxyz": [float(x) for x in q],
                "rotation_matrix": [[float(x) for x in row] for row in R],
                "translation": [float(x / s) for x in self.mocap_translation],
                "std_rotation_vector": [None if not np.isfinite(x) else float(x) for x in self.mocap_std[:3]],
                "std_translation": [None if not np.isfinite(x) else float(x / s) for x in self.mocap_std[3:]],
                "note": "x_mocap = R x_base + translation",
            },
            "markers": markers,
            "moving_frame": self.spec.moving_frame,
            "residual": {
                "rms_before": float(self.rms_before / s), "rms_after": float(self.rms_after / s),
                "unit": lu, "noise_sigma_per_axis": float(self.noise_sigma / s),
                "n_poses": int(self.n_poses), "n_markers": int(self.n_markers),
                "n_observations": int(self.n_observations), "n_rejected_as_outliers": int(self.n_rejected),
            },
            "converged": bool(self.converged),
            "iterations": int(self.iterations),
            "identifiability": self.identifiability,
            "terms": [t.to_dict(th, sd) for t, th, sd in zip(self.terms, self.theta, self.theta_std)],
        }
        if self.body_names:
            out["rigid_bodies"] = self._bodies_dict()
        if self.heldout:
            out["heldout"] = heldout_in_unit(self.heldout, self.length_unit)
        if self.warnings:
            out["warnings"] = [str(w) for w in self.warnings]
        if self.motion:  # the actuators' response fitted with the geometry (times s, controls' internal units)
            out["actuator_response"] = strict(self.motion)
        if self.imu:
            # SI (rad, rad/s), whatever the length unit: platkit.diagnose.imu's calibration_entry
            out["imu"] = strict(self.imu)
        return out

    def _bodies_dict(self) -> dict:
        """calibration.yaml's ``rigid_bodies``: each body's placement (moving_from_body) and the weight."""
        s, lu = length_scale(self.length_unit), self.length_unit

        def num(x, k=1.0):
            return None if not np.isfinite(x) else float(x / k)

        bodies: dict[str, dict[str, Any]] = {}
        for name, pos, rv, sd in zip(self.body_names, self.body_positions, self.body_rotvecs, self.body_std):
            bodies[name] = {"position": [float(x / s) for x in pos], "rotation_vector": [float(x) for x in rv],
                            "quaternion_wxyz": [float(x) for x in quat_from_rotvec(rv)],
                            "std_position": [num(x, s) for x in sd[:3]],
                            "std_rotation_vector": [num(x) for x in sd[3:]]}
            if self.marker_links:
                bodies[name]["link"] = self.marker_links[name]
        return {"bodies": bodies, "note": "x_moving = R(rotation_vector) x_body + position",
                "rotation_weight": {f"rho_{lu}_per_rad": num(self.body_rho, s), "source": self.body_rho_source,
                                    "note": "rotation errors (rad) times rho count as position errors"}}

    def to_yaml(self, data: dict | None = None) -> str:
        """calibration.yaml's text: of :meth:`to_dict`, or of ``data`` (that dict, edited)."""
        header = (f"# platkit calibration of the {self.platform} stand. Lengths in {self.length_unit}, "
                  "angles in rad, other parameters in the unit beside them.\n")
        return header + dump_yaml(strict(self.to_dict() if data is None else data), sort_keys=False,
                                  default_flow_style=None, width=120)


#: the folder, beside calibration.yaml, that holds a copy of the description it was made with
DESCRIPTION_DIR = "description"
#: prefix of a description shipped with platkit, written by name (found in any installation)
SHIPPED = "shipped:"


def write_calibration_yaml(cal: Calibration, folder: str | Path, renamed: dict[str, str] | None = None) -> Path:
    """Write ``folder/calibration.yaml`` so that the folder travels: moved, or sent to a colleague,
    it still predicts.

    The rule for the description it names (and the terms' ``where.description``): a description
    shipped with platkit is written ``shipped:<name>``; any other is copied into
    ``folder/description/`` and written relative to calibration.yaml (a URDF-route stand built
    from a YAML that names a URDF: the URDF, as the stand's options keep the YAML's choices).
    ``renamed``: :func:`portable_descriptions` of ``cal`` into ``folder``, where already made.
    """
    folder = Path(folder)
    data = cal.to_dict()
    if renamed is None:
        renamed = portable_descriptions(cal, folder)
    if data.get("description") in renamed:
        data["description"] = renamed[data["description"]]
    for term in data.get("terms") or []:
        where = term.get("where") if isinstance(term, dict) else None
        if isinstance(where, dict) and where.get("description") in renamed:
            where["description"] = renamed[where["description"]]
    path = folder / "calibration.yaml"
    path.write_text(cal.to_yaml(data), encoding="utf-8")
    return path


def with_portable_descriptions(data, renamed: dict[str, str]):
    """``data`` (dicts and lists, e.g. diagnosis.json's) with every ``description`` value that
    ``renamed`` holds written as calibration.yaml writes it (relative to the results folder, or
    ``shipped:<name>``), so that a file beside calibration.yaml names the description it does."""
    if isinstance(data, dict):
        return {k: (renamed[v] if k == "description" and isinstance(v, str) and v in renamed
                    else with_portable_descriptions(v, renamed)) for k, v in data.items()}
    if isinstance(data, list):
        return [with_portable_descriptions(v, renamed) for v in data]
    return data


def portable_descriptions(cal: Calibration, folder: Path) -> dict[str, str]:
    """{description as the calibration names it: as calibration.yaml writes it}, copying what
    must travel into ``folder/description/``."""
    if not cal.description:
        return {}
    src = Path(cal.description)
    if not src.is_file():
        return {}
    try:
        shipped = shipped_dir("descriptions").resolve()
    except PlatkitError:  # a checkout without the data package: nothing is shipped
        shipped = None
    source = src
    urdf = cal.spec.extras.get("urdf_path")
    if src.suffix.lower() in (".yaml", ".yml") and urdf is not None and cal.spec.extras.get("platform_options") is not None:
        source = Path(urdf)
    if shipped is not None and source.resolve().parent == shipped:
        return {cal.description: SHIPPED + source.name}
    (folder / DESCRIPTION_DIR).mkdir(exist_ok=True)
    shutil.copyfile(source, folder / DESCRIPTION_DIR / source.name)
    return {cal.description: f"{DESCRIPTION_DIR}/{source.name}"}


def resolve_description(value, path: Path) -> str | None:
    """A description as calibration.yaml ``path`` names it -> a path to build the stand from:
    ``shipped:<name>`` among the shipped descriptions, a relative path from the file's folder."""
    if value is None:
        return None
    value = str(value)
    if value.startswith(SHIPPED):
        return str(shipped_dir("descriptions") / value[len(SHIPPED):])
    if not Path(value).is_absolute():
        candidate = path.parent / value
        return str(candidate) if candidate.is_file() else value
    return value


#: keys of Calibration.heldout (and of its 'second_session') that are lengths in metres
HELDOUT_LENGTHS = ("rms", "rms_inliers", "rms_per_fold", "rms_per_marker", "rms_per_body")


def heldout_in_unit(heldout: dict, unit: str) -> dict:
    """Calibration.heldout with its lengths (metres inside) in ``unit``, and 'unit' stated."""
    s = length_scale(unit)

    def conv(v):
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        return None if v is None or not np.isfinite(v) else float(v) / s

    out = {}
    for k, v in heldout.items():
        if k in HELDOUT_LENGTHS:
            out[k] = conv(v)
        elif isinstance(v, dict) and not k.endswith("_rad"):  # angles stay in rad, their unit in the name
            out[k] = heldout_in_unit(v, unit)
        else:
            out[k] = v
    out["unit"] = unit
    return out


def _field(data: dict, key: str, path: Path, kind=object):
    if not isinstance(data, dict) or key not in data:
        raise BadInput(f"{path}: missing field {key!r}")
    v = data[key]
    if kind is not object and not isinstance(v, kind):
        raise BadInput(f"{path}: field {key!r} must be {kind.__name__}")
    return v


def _numbers(value, path: Path, where: str, size: int) -> np.ndarray:
    if not isinstance(value, list) or len(value) != size:
        raise BadInput(f"{path}: field {where!r} must be a list of {size} numbers")
    try:
        arr = np.array([np.nan if v is None else float(v) for v in value])
    except (TypeError, ValueError):
        raise BadInput(f"{path}: field {where!r} must be a list of {size} numbers") from None
    return arr


def read_calibration(path: str | Path, options: dict | None = None) -> Calibration:
    """Read a calibration.yaml (as written by :meth:`Calibration.to_yaml`) and rebuild the stand;
    ``options`` replace its platform options (``payload``: the stand carrying another load, for
    prediction; the parameters are the calibration's).

    Model terms are rebuilt by the diagnosis effect library when one is installed
    (``platkit.plugins.term_from_dict``); BadInput names the file and field otherwise. The residual
    block and the warnings too: a calibration written again unchanged says what its file said.
    """

    path = Path(path)
    data = load_yaml(path, error=BadInput)
    if data.get("format") != FORMAT:
        raise BadInput(f"{path}: field 'format' must be {FORMAT!r} (is this a platkit calibration.yaml?)")
    platform = _field(data, "platform", path, str)
    description = resolve_description(data.get("description"), path)
    options_given = options
    options = data.get("platform_options") or {}
    if not isinstance(options, dict):
        raise BadInput(f"{path}: field 'platform_options' must be a mapping")
    options = {**options, **(options_given or {})}
    spec = get_platform(platform, description, **{k: v for k, v in options.items()})
    lu = _field(data, "length_unit", path, str)
    s = length_scale(lu)
    params = _field(data, "parameters", path, dict)
    n = spec.n_td
    td = spec.nominal_td().copy()
    td_std = np.full(n, np.nan)
    td_nom = spec.nominal_td().copy()
    status = ["fixed"] * n
    for i, p in enumerate(spec.parameters):
        if p.name not in params:
            raise BadInput(f"{path}: parameters has no entry for {p.name!r} of the {platform} stand")
        entry = params[p.name]
        k = s if p.unit == "m" else 1.0
        try:
            td[i] = float(entry["value"]) * k
            td_nom[i] = float(entry.get("nominal", td_nom[i] / k)) * k
            td_std[i] = np.nan if entry.get("std") is None else float(entry["std"]) * k
        except (TypeError, ValueError, KeyError):
            raise BadInput(f"{path}: parameters.{p.name} needs a numeric 'value'") from None
        status[i] = str(entry.get("status", "estimated"))
    mocap = _field(data, "mocap_from_base", path, dict)
    rotvec = _numbers(mocap.get("rotation_vector"), path, "mocap_from_base.rotation_vector", 3)
    trans = _numbers(mocap.get("translation"), path, "mocap_from_base.translation", 3) * s
    std = np.concatenate([
        _numbers(mocap.get("std_rotation_vector", [None] * 3), path, "mocap_from_base.std_rotation_vector", 3),
        _numbers(mocap.get("std_translation", [None] * 3), path, "mocap_from_base.std_translation", 3) * s,
    ])
    markers = _field(data, "markers", path, dict)
    names = list(markers)
    rb = data.get("rigid_bodies") or {}
    if not isinstance(rb, dict) or not isinstance(rb.get("bodies", {}), dict):
        raise BadInput(f"{path}: field 'rigid_bodies' must be a mapping with 'bodies' (one entry per body)")
    bodies = rb.get("bodies") or {}
    if not names and not bodies:
        raise BadInput(f"{path}: field 'markers' lists no marker (and 'rigid_bodies' no body)")
    pos = np.array([_numbers(markers[m].get("position") if isinstance(markers[m], dict) else None, path,
                             f"markers.{m}.position", 3) for m in names]).reshape(-1, 3) * s
    mstd = np.array([_numbers(markers[m].get("std", [None] * 3), path, f"markers.{m}.std", 3)
                     for m in names]).reshape(-1, 3) * s
    body_names = list(bodies)
    b_entry = [bodies[b] if isinstance(bodies[b], dict) else {} for b in body_names]
    b_pos = np.array([_numbers(e.get("position"), path, f"rigid_bodies.bodies.{b}.position", 3)
                      for b, e in zip(body_names, b_entry)]).reshape(-1, 3) * s
    b_rot = np.array([_numbers(e.get("rotation_vector"), path, f"rigid_bodies.bodies.{b}.rotation_vector", 3)
                      for b, e in zip(body_names, b_entry)]).reshape(-1, 3)
    b_std = np.array([np.concatenate([
        _numbers(e.get("std_position", [None] * 3), path, f"rigid_bodies.bodies.{b}.std_position", 3) * s,
        _numbers(e.get("std_rotation_vector", [None] * 3), path, f"rigid_bodies.bodies.{b}.std_rotation_vector", 3)])
        for b, e in zip(body_names, b_entry)]).reshape(-1, 6)
    links = {}
    for kind, entries in (("markers", {m: markers[m] for m in names}), ("rigid_bodies.bodies", dict(zip(body_names, b_entry)))):
        for n, e in entries.items():
            link = e.get("link") if isinstance(e, dict) else None
            if link is not None:
                if not isinstance(link, str) or (spec.tracked_links and link not in spec.tracked_links):
                    raise BadInput(f"{path}: field '{kind}.{n}.link': {link!r} is not a link the stand tracks "
                                   f"({', '.join(spec.tracked_links) or spec.moving_frame})")
                links[n] = link
    if links and len(links) != len(names) + len(body_names):
        n = next(n for n in names + body_names if n not in links)
        raise BadInput(f"{path}: field 'link' missing for {n!r}; on a tree every marker and body names its link")
    weight = rb.get("rotation_weight") or {}
    rho = weight.get(f"rho_{lu}_per_rad") if isinstance(weight, dict) else None
    res = data.get("residual") or {}
    motion = data.get("actuator_response") or {}
    if not isinstance(motion, dict):
        raise BadInput(f"{path}: field 'actuator_response' must be a mapping (a calibration from motion)")
    imu = data.get("imu") or {}
    if not isinstance(imu, dict):
        raise BadInput(f"{path}: field 'imu' must be a mapping (what an IMU diagnosis added)")
    terms, theta, theta_std = [], [], []
    for k, tdict in enumerate(data.get("terms") or []):
        where = tdict.get("where") if isinstance(tdict, dict) else None
        if isinstance(where, dict) and isinstance(where.get("description"), str):
            tdict = dict(tdict, where=dict(where, description=resolve_description(where["description"], path)))
        term, th, sd = _term_from_dict(tdict, path, k, spec)
        terms.append(term)
        theta.append(th)
        theta_std.append(sd)
    return Calibration(
        platform=platform, description=description, spec=spec, td=td, td_std=td_std, td_nominal=td_nom,
        td_status=status, mocap_rotvec=rotvec, mocap_translation=trans, mocap_std=std, marker_names=names,
        marker_positions=pos, marker_std=mstd,
        rms_before=float(res.get("rms_before", np.nan) or np.nan) * s,
        rms_after=float(res.get("rms_after", np.nan) or np.nan) * s,
        length_unit=lu, platform_options=dict(options), method=str(data.get("method", "lsq")),
        converged=bool(data.get("converged", True)), iterations=int(data.get("iterations", 0)),
        n_poses=int(res.get("n_poses", 0)), n_markers=len(names),
        n_observations=int(res.get("n_observations", 0) or 0), n_rejected=int(res.get("n_rejected_as_outliers", 0) or 0),
        noise_sigma=float(res.get("noise_sigma_per_axis", np.nan) or np.nan) * s,
        warnings=[str(w) for w in data.get("warnings") or []],
        identifiability=data.get("identifiability") or {}, terms=terms, theta=theta, theta_std=theta_std,
        heldout={},  # written for people in the file's unit; not read back
        imu=dict(imu), motion=dict(motion), body_names=body_names, body_positions=b_pos, body_rotvecs=b_rot, body_std=b_std,
        body_rho=float("nan") if rho is None else float(rho) * s,
        body_rho_source=str(weight.get("source", "")) if isinstance(weight, dict) else "",
        marker_links=links,
    )


def _term_from_dict(tdict, path: Path, k: int, spec: PlatformSpec):
    """Rebuild a model term through the diagnosis effect library (the effect's ``from_dict``)."""
    if not isinstance(tdict, dict) or "effect" not in tdict or not isinstance(tdict.get("parameters"), dict):
        raise BadInput(f"{path}: terms[{k}] must have 'effect' and 'parameters'")

    term, theta = term_from_dict(tdict, spec, where=f"{path}: terms[{k}]")
    std = np.array([np.nan if (tdict["parameters"].get(n) or {}).get("std") is None
                    else float(tdict["parameters"][n]["std"]) for n in term.parameter_names])
    return term, np.asarray(theta, float), std


def quat_of(cal: Calibration) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of mocap_from_base."""
    return quat_from_rotvec(cal.mocap_rotvec)


__all__ = ["Calibration", "read_calibration", "write_calibration_yaml", "resolve_description", "FORMAT"]
