"""Experiment design: which commands to send during a calibration session.

Two plans, after Burlakov et al. (2018) and the optimal-design literature:

- the paper's uniform grid over the control space, visited along a Hamiltonian path (the
  boustrophedon or "snake" order: consecutive grid points differ by one step of one control),
  with the points the stand cannot take dropped (forward kinematics fails or leaves the branch);
- a D-optimal selection of N poses from M feasible candidates, maximising the determinant of
  the information matrix of the identification Jacobian.

The identification Jacobian of a pose is that of the marker positions seen by motion capture
with respect to every parameter calibration estimates: the stand's free geometric parameters
td, a small motion (translation, rotation vector) of the base-to-mocap transform, and the marker
positions on the moving part. By the implicit-function theorem on F(u, td, pose(p)) = 0:

    dp/dtd = -F_p^+ F_td,    d m_k / d td = (d m_k / d p) (dp/dtd),   m_k = X(p) + R(p) s_k.

Some directions of parameter space are never identifiable from markers (e.g. moving the whole
base rigidly is the same as moving the mocap frame); the design works in the identifiable
subspace (the row space of the Jacobian stacked over all candidates) and reports its size.
Predicted uncertainties are for a given marker noise ``sigma`` (per coordinate, of a settled
pose): per-parameter standard deviations of the minimum-norm solution, and, gauge-free, the RMS
uncertainty of the predicted marker positions over the candidate poses.

The information side (reach, the markers' links and layout, the identification Jacobian, the
D-optimal exchange, the predicted uncertainties) is platkit.calibrate.plan_information; its names
are read through this module as well.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.calibrate.identifiability import DEFAULT_REL_TOL, select_identifiable
from platkit.calibrate.plan_information import IdentificationJacobian as IdentificationJacobian
from platkit.calibrate.plan_information import _Subspace as _Subspace
from platkit.calibrate.plan_information import controls_moving_links as controls_moving_links
from platkit.calibrate.plan_information import d_optimal as d_optimal
from platkit.calibrate.plan_information import default_marker_count as default_marker_count
from platkit.calibrate.plan_information import default_marker_layout as default_marker_layout
from platkit.calibrate.plan_information import feasible as feasible
from platkit.calibrate.plan_information import held_at_home as held_at_home
from platkit.calibrate.plan_information import homed_at_middle as homed_at_middle
from platkit.calibrate.plan_information import identification_jacobian as identification_jacobian
from platkit.calibrate.plan_information import idle_controls as idle_controls
from platkit.calibrate.plan_information import marker_link_indices as marker_link_indices
from platkit.calibrate.plan_information import marker_links as marker_links
from platkit.calibrate.plan_information import pin_held as pin_held
from platkit.calibrate.plan_information import plan_uncertainty as plan_uncertainty
from platkit.calibrate.plan_information import planning_bounds as planning_bounds
from platkit.calibrate.plan_information import stand_length_scale as stand_length_scale
from platkit.calibrate.plan_information import unbounded_controls as unbounded_controls
from platkit.errors import BadInput, BadSession, NotIdentifiable
from platkit.io.session_checks import check_controls
from platkit.io.table import read_table
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import controls_of_poses, pose_box, sample_poses
from platkit.model import PlatformSpec, controls_from_si, length_scale
from platkit.notices import warn


@dataclass
class Plan:
    """A command plan: ``controls`` (N, n_u) internal units, in the order to visit them."""

    controls: np.ndarray
    kind: str
    info: dict = field(default_factory=dict)
    poses: np.ndarray | None = None  # (N, n_p) nominal pose coordinates, where known


# ----------------------------------------------------------------------------- grids


def control_box(spec: PlatformSpec, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """The control box [lo, hi] (n_u,) shrunk by ``margin`` of each stroke at both ends, the
    strokes :func:`planning_bounds`'s (a control without a finite stroke: one turn either way, said
    as a warning)."""
    lo, hi = planning_bounds(spec)
    unbounded = unbounded_controls(spec)
    if unbounded:
        warn(f"{spec.name}: {', '.join(unbounded)}: no finite stroke in the description; planned over one turn "
             "either way of neutral")
    span = hi - lo
    return lo + margin * span, hi - margin * span


def snake_order(counts: list[int]) -> np.ndarray:
    """Index tuples (prod(counts), d) of a grid in boustrophedon order: a Hamiltonian path on
    the grid graph (consecutive tuples differ by 1 in exactly one index). The last index runs
    fastest."""
    if not counts:
        return np.zeros((1, 0), int)
    sub = snake_order(counts[1:])
    blocks = []
    for i in range(counts[0]):
        block = sub if i % 2 == 0 else sub[::-1]
        blocks.append(np.hstack([np.full((len(block), 1), i), block]))
    return np.vstack(blocks)


def grid_points(spec: PlatformSpec, points_per_control: int, margin: float = 0.1,
                held: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(k^n, n_u) uniform grid over the control box, in snake order: k values of each of the n
    controls that move, the ``held`` ones (mask, values: :func:`held_at_home`) at their value."""
    k = int(points_per_control)
    if k < 2:
        raise BadInput(f"--grid must be at least 2 points per control, got {k}")
    mask = np.zeros(spec.n_u, bool) if held is None else np.asarray(held[0], bool)
    n = int((~mask).sum())
    if k ** n > 2_000_000:
        raise BadInput(f"--grid {k} gives {k ** n} points for {n} controls; choose fewer, or "
                       "--optimal N (N poses chosen D-optimally from random candidates)")
    lo, hi = control_box(spec, margin)
    axes = [np.array([held[1][j]]) if mask[j] and held is not None else np.linspace(a, b, k)
            for j, (a, b) in enumerate(zip(lo, hi))]
    idx = snake_order([len(a) for a in axes])
    return np.stack([axes[j][idx[:, j]] for j in range(spec.n_u)], axis=1)


def pose_grid_plan(spec: PlatformSpec, points_per_coordinate: int, margin: float = 0.1, td=None,
                   model: PlatformModel | None = None) -> Plan:
    """The grid plan of a stand whose pose space is free: a uniform grid over the coordinates'
    bounds (shrunk by ``margin``) in snake order, mapped through inverse kinematics; poses whose
    controls leave the strokes or the branch are dropped (and counted)."""
    model = model or PlatformModel(spec)
    k = int(points_per_coordinate)
    if k < 2:
        raise BadInput(f"--grid must be at least 2 points per coordinate, got {k}")
    if k ** spec.n_p > 2_000_000:
        raise BadInput(f"--grid {k} gives {k ** spec.n_p} poses for {spec.n_p} coordinates; choose fewer")
    lo, hi = pose_box(spec, margin)
    axes = [np.linspace(a, b, k) for a, b in zip(lo, hi)]
    idx = snake_order([k] * spec.n_p)
    P = np.stack([axes[j][idx[:, j]] for j in range(spec.n_p)], axis=1)
    res = controls_of_poses(model, P, td)
    ok = res["ok"]
    if not np.any(ok):
        raise NotIdentifiable(f"{spec.name}: no pose of the {k}-per-coordinate grid over the pose box has controls "
                              "inside the strokes on the stand's branch")
    return Plan(res["controls"][ok], "grid", {"space": "pose", "points_per_coordinate": k, "grid_points": int(len(P)),
                                              "infeasible_dropped": int((~ok).sum()), "margin": margin}, P[ok])


def grid_plan(spec: PlatformSpec, points_per_control: int, margin: float = 0.1, td=None,
              model: PlatformModel | None = None, held: tuple[np.ndarray, np.ndarray] | None = None) -> Plan:
    """The paper's plan: the uniform grid in snake order, infeasible points dropped; ``held``
    controls (mask, values: :func:`held_at_home`) kept at their value. A stand whose pose space is
    free (``spec.free_space == 'pose'``) takes the grid over its poses instead
    (:func:`pose_grid_plan`, ``points_per_control`` values per coordinate)."""
    if spec.pose_free:
        if held is not None:
            raise BadInput(f"{spec.name}: its pose space is free (controls from poses through IK); a plan that holds "
                           "some controls is not made for it")
        return pose_grid_plan(spec, points_per_control, margin, td, model)
    U = grid_points(spec, points_per_control, margin, held)
    ok, P = feasible(spec, U, td, model)
    if not np.any(ok):
        raise NotIdentifiable(f"{spec.name}: no point of the {points_per_control}-per-control grid is reachable"
                              + _free_space_hint(spec, model))
    return Plan(U[ok], "grid", {"points_per_control": int(points_per_control), "grid_points": int(len(U)),
                                "infeasible_dropped": int((~ok).sum()), "margin": margin}, P[ok])


def _free_space_hint(spec: PlatformSpec, model: PlatformModel | None) -> str:
    """The hint for a stand whose control box is sampled but whose rows outnumber its pose
    coordinates (its independent commands are almost never consistent)."""
    model = model or PlatformModel(spec)
    if model.n_r > spec.n_p and not spec.pose_free:
        return (f"; its {model.n_r} residual rows outnumber its {spec.n_p} pose coordinates, so independent commands "
                "rarely fit a pose: declare its pose space free (PlatformSpec field 'free_space': 'pose')")
    return ""


def grid_plan_for(spec: PlatformSpec, n_poses: int, margin: float = 0.1, td=None,
                  model: PlatformModel | None = None) -> Plan:
    """A snake-ordered grid plan of about ``n_poses`` poses: the coarsest grid with enough
    feasible points, thinned evenly along its path."""
    model = model or PlatformModel(spec)
    k = 2
    n_dim = spec.n_p if spec.pose_free else spec.n_u  # the free space's dimension
    while True:
        if k ** n_dim > 200_000:
            raise NotIdentifiable(f"{spec.name}: no grid with {n_poses} reachable points was found")
        if k ** n_dim >= n_poses:
            plan = grid_plan(spec, k, margin, td, model)
            if len(plan.controls) >= n_poses:
                break
        k += 1
    keep = np.unique(np.round(np.linspace(0, len(plan.controls) - 1, n_poses)).astype(int))
    plan.info["thinned_to"] = int(len(keep))
    return Plan(plan.controls[keep], "grid", plan.info, plan.poses[keep])


def random_candidates(spec: PlatformSpec, n: int, rng: np.random.Generator, margin: float = 0.1, td=None,
                      model: PlatformModel | None = None, hold_idle: bool = False,
                      held: tuple[np.ndarray, np.ndarray] | None = None) -> Plan:
    """``n`` feasible controls drawn uniformly from the control box (rejection sampling); for a
    stand whose pose space is free, ``n`` poses drawn from the pose box and their controls.
    ``hold_idle``: the controls that move no tracked link (:func:`idle_controls`: a humanoid's legs
    and head when its hands are tracked) keep their neutral command instead; ``held`` (mask, values:
    :func:`held_at_home`), the controls a plan does not move, keep their value (this before
    ``hold_idle``)."""
    model = model or PlatformModel(spec)
    if spec.pose_free:
        P, U, drawn = sample_poses(model, n, rng, margin, td)
        return Plan(U, "random", {"margin": margin, "space": "pose", "infeasible_dropped": int(drawn - n)}, P)
    lo, hi = control_box(spec, margin)
    if hold_idle:
        idle = idle_controls(spec)
        lo, hi = np.where(idle, spec.neutral_u(), lo), np.where(idle, spec.neutral_u(), hi)
    if held is not None:
        lo, hi = np.where(held[0], held[1], lo), np.where(held[0], held[1], hi)
    U_out, P_out = [], []
    tries = 0
    while sum(len(u) for u in U_out) < n:
        tries += 1
        if tries > 50:
            raise NotIdentifiable(f"{spec.name}: fewer than {n} random controls are reachable" + _free_space_hint(spec, model))
        U = rng.uniform(lo, hi, size=(max(2 * n, 16), spec.n_u))
        ok, P = feasible(spec, U, td, model)
        U_out.append(U[ok])
        P_out.append(P[ok])
    U = np.vstack(U_out)[:n]
    return Plan(U, "random", {"margin": margin}, np.vstack(P_out)[:n])


def nearest_neighbour_order(U: np.ndarray, spec: PlatformSpec, start: np.ndarray | None = None) -> np.ndarray:
    """An order visiting every row of U (N, n_u) by nearest neighbour in stroke-scaled control
    space, starting nearest ``start`` (default: neutral controls). Returns indices (N,)."""
    lo, hi = spec.control_bounds()
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    Z = U / span
    cur = (spec.neutral_u() if start is None else start) / span
    left = list(range(len(U)))
    order = []
    while left:
        d = np.linalg.norm(Z[left] - cur, axis=1)
        j = left.pop(int(np.argmin(d)))
        order.append(j)
        cur = Z[j]
    return np.array(order, int)


#: the fixed set of poses over which predicted marker errors are averaged, so that plans of one
#: stand are comparable between runs: this many random feasible poses from this seed
REFERENCE_POSES, REFERENCE_SEED = 300, 20260
_REFERENCE: dict = {}


def reference_poses(spec: PlatformSpec, margin: float = 0.1, model: PlatformModel | None = None) -> Plan:
    """The stand's reference poses (REFERENCE_POSES random feasible controls, fixed seed)."""
    key = (id(spec), margin)
    hit = _REFERENCE.get(key)
    if hit is None or hit[0] is not spec:
        plan = random_candidates(spec, REFERENCE_POSES, np.random.default_rng(REFERENCE_SEED), margin, model=model)
        _REFERENCE[key] = hit = (spec, plan)
    return hit[1]


def reference_poses_for(spec: PlatformSpec, model: PlatformModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(controls (N, n_u), poses (N, n_p)) of the stand's reference poses (:func:`reference_poses`),
    over which calibration tells a gauge (invisible at every pose the stand takes) from a direction
    a session's poses fail to excite. A stand with unbounded strokes (a continuous joint) is
    sampled over one turn, or +- 1 unit, about its neutral controls, with the same seed; a stand
    where few random commands are reachable gets those that are (possibly none)."""
    lo, hi = spec.control_bounds()
    if np.all(np.isfinite(lo) & np.isfinite(hi)):
        try:
            ref = reference_poses(spec, model=model)
            return ref.controls, ref.poses
        except NotIdentifiable:
            pass
    hit = _REFERENCE_SAMPLED.get(id(spec))
    if hit is not None and hit[0] is spec:
        return hit[1], hit[2]
    lo, hi = planning_bounds(spec)
    rng = np.random.default_rng(REFERENCE_SEED)
    U = lo + (0.1 + 0.8 * rng.uniform(size=(2 * REFERENCE_POSES, spec.n_u))) * (hi - lo)
    ok, P = feasible(spec, U, model=model)
    _REFERENCE_SAMPLED[id(spec)] = (spec, U[ok][:REFERENCE_POSES], P[ok][:REFERENCE_POSES])
    return U[ok][:REFERENCE_POSES], P[ok][:REFERENCE_POSES]


_REFERENCE_SAMPLED: dict = {}


def gauge_counts(J_plan: np.ndarray, J_reference: np.ndarray, names: list[str], units: list[str], n_td: int,
                 rel_tol: float = DEFAULT_REL_TOL) -> dict:
    """What `platkit calibrate` will decide for these poses, by the same test
    (:func:`platkit.calibrate.identifiability.select_identifiable`, the same tiers and scales):
    'gauge_dimensions', the directions no set of poses fixes (fixed by its stated conventions,
    docs/calibration.md), and 'not_excited', those the reference poses fix and these do not.
    J_plan, J_reference: (N, 3M, n_theta) identification Jacobians; n_td: the stand's columns first."""
    scale = np.array([1e-3 if u in ("m", "rad", "1", "") else 1.0 for u in units])
    tiers = [1] * n_td + [0] * (len(names) - n_td)
    rank_ref = len(select_identifiable(J_reference.reshape(-1, len(names)), names, scale, tiers, rel_tol).chosen)
    rank_plan = len(select_identifiable(J_plan.reshape(-1, len(names)), names, scale, tiers, rel_tol).chosen)
    return {"gauge_dimensions": int(len(names) - rank_ref), "not_excited": int(max(0, rank_ref - rank_plan))}


def optimal_plan(spec: PlatformSpec, n: int, n_candidates: int, rng: np.random.Generator, sigma: float,
                 n_markers: int = 5, markers: np.ndarray | None = None, candidates: Plan | None = None,
                 margin: float = 0.1, held: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[Plan, dict]:
    """A D-optimal plan of ``n`` poses from ``n_candidates`` random feasible candidates (or the
    given ``candidates``), ordered by nearest neighbour. Returns the plan and, for comparison,
    the uncertainty of ``n`` random candidates (the first n drawn). Uncertainties are over the
    stand's :func:`reference_poses`. ``held`` (mask, values: :func:`held_at_home`): the controls
    the plan does not move, at their value in the candidates and in the reference poses
    (:func:`pin_held`)."""
    model = PlatformModel(spec)
    markers = default_marker_layout(spec, n_markers, np.random.default_rng(0)) if markers is None else markers
    cand = candidates or random_candidates(spec, n_candidates, rng, margin, model=model, hold_idle=True, held=held)
    ij = identification_jacobian(spec, cand.controls, markers, P=cand.poses, model=model)
    sub = _Subspace(ij.J)
    sel = d_optimal(sub.reduce(ij.J), n)
    sel = sel[nearest_neighbour_order(cand.controls[sel], spec)]
    ref = reference_poses(spec, margin, model)
    U_ref, P_ref = pin_held(spec, ref.controls, ref.poses, held, model)
    J_ref = identification_jacobian(spec, U_ref, markers, P=P_ref, model=model).J
    ref_sub = _Subspace(J_ref)
    links = marker_links(spec, len(markers))
    info = plan_uncertainty(ij.J[sel], J_ref, sigma, ij.names, ij.units, ref_sub, links, ij.n_td)
    first = np.arange(min(n, len(cand.controls))) if candidates is None else np.unique(
        np.round(np.linspace(0, len(cand.controls) - 1, n)).astype(int))
    baseline = plan_uncertainty(ij.J[first], J_ref, sigma, ij.names, ij.units, ref_sub, links, ij.n_td)
    info.update(kind="d_optimal", candidates=int(len(cand.controls)))
    info.update(gauge_counts(ij.J[sel], J_ref, ij.names, ij.units, ij.n_td))
    return Plan(cand.controls[sel], "d_optimal", info, cand.poses[sel]), baseline


def evaluate_plan(spec: PlatformSpec, plan: Plan, sigma: float, n_markers: int = 5, markers=None,
                  margin: float = 0.1, held: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """Predicted uncertainty of ``plan``, over the stand's :func:`reference_poses` (the ``held``
    controls at their value there: :func:`pin_held`)."""
    model = PlatformModel(spec)
    markers = default_marker_layout(spec, n_markers, np.random.default_rng(0)) if markers is None else markers
    ij = identification_jacobian(spec, plan.controls, markers, P=plan.poses, model=model)
    ref = reference_poses(spec, margin, model)
    U_ref, P_ref = pin_held(spec, ref.controls, ref.poses, held, model)
    J_ref = identification_jacobian(spec, U_ref, markers, P=P_ref, model=model).J
    out = plan_uncertainty(ij.J, J_ref, sigma, ij.names, ij.units, links=marker_links(spec, len(markers)), n_td=ij.n_td)
    out.update(gauge_counts(ij.J, J_ref, ij.names, ij.units, ij.n_td))
    return out


# ----------------------------------------------------------------------------- files


def write_plan_csv(path: Path, spec: PlatformSpec, U: np.ndarray, length_unit: str) -> None:
    """plan.csv: one row per command, the control columns in the file's units."""
    V = controls_from_si(spec, U, length_unit)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(spec.control_names)
        for row in V:
            w.writerow([f"{v:.9g}" for v in row])


def read_plan_csv(path: str | Path, spec: PlatformSpec, length_unit: str) -> np.ndarray:
    """Controls (N, n_u) internal units from a plan file with the control columns (a ``t``
    column, as in commands.csv, is allowed and ignored). BadSession naming row and column."""

    table = read_table(Path(path), "the command plan")
    extra = [c for c in table.header if c not in ["t"] + spec.control_names]
    if extra:
        raise BadSession(f"{path}: column {extra[0]!r} is not a control of the {spec.name} stand; expected "
                         f"{', '.join(spec.control_names)}")
    length_scale(length_unit)
    return check_controls(table, spec, [], length_unit)
