"""Workspace of any stand: the corner envelope and the true translational envelope.

- :func:`corner_envelope`: forward kinematics at the 2^n_u corners of the control box (every
  control at its lower or upper stroke). For the Stewart platform these are the paper's 64
  min/max leg combinations (Liu, Ma, Lin, table 4). A stand whose pose space is free (a cable
  robot) takes the 2^n_p corners of its pose box through inverse kinematics instead.
- :func:`translational_envelope`: the extreme positions of the moving origin over every pose the
  stand can take with its controls inside their strokes, by constrained optimisation (CasADi +
  IPOPT): maximise / minimise x, y, z subject to lower <= u <= upper, the stand's branch, and
  either the neutral orientation (``orientation="fixed"``) or any orientation within the
  stand's coordinate bounds (``orientation="free"``). Serial chains (closed-form forward) search
  over the controls; stands with a closed-form inverse over the pose coordinates; any other
  stand over both, u held to F(u, td, pose(p)) = 0.
- :func:`coordinate_ranges`: the least and greatest value of each pose coordinate (an
  orientation-only stand's angles, a hexapod's x ... yaw) over the same poses as the free
  orientation's envelope, by the same optimisation with that coordinate as the objective.
- :func:`platkit.workspace.files.write_workspace`: the figures as JSON and CSV, and plots, written
  atomically.

Lengths are metres inside; the writer converts to the requested unit.
"""
from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from platkit.errors import BadInput, ComputationFailed
from platkit.kinematics import PlatformModel
from platkit.kinematics.sampling import controls_of_poses, pose_box

#: corners are enumerated up to this many controls (2^16 forward solves)
MAX_CORNER_CONTROLS = 16
#: a workspace whose origin moves no more than this (m) along every axis is a point
DEGENERATE_SPAN = 1e-6
AXES = ("x", "y", "z")


@dataclass
class CornerEnvelope:
    """Forward kinematics at the corners of the control box. Arrays have a leading axis 2^n_u."""

    U: np.ndarray  # (M, n_u) controls, each at a stroke end
    P: np.ndarray  # (M, n_p) pose coordinates
    X: np.ndarray  # (M, 3) origin positions, m
    q: np.ndarray  # (M, 4)
    converged: np.ndarray  # (M,) bool: solved and on the stand's branch
    neutral_X: np.ndarray  # (3,) origin at the neutral pose, m

    @property
    def lower(self) -> np.ndarray:
        """(3,) smallest origin coordinates over the converged corners, m."""
        return self.X[self.converged].min(axis=0)

    @property
    def upper(self) -> np.ndarray:
        return self.X[self.converged].max(axis=0)


@dataclass
class AxisExtreme:
    """One extreme of the origin along an axis: the value and the pose that reaches it."""

    axis: str
    sense: str  # 'min' or 'max'
    value: float  # m
    p: np.ndarray  # (n_p,) pose coordinates
    u: np.ndarray  # (n_u,) controls
    active: list[str] = field(default_factory=list)  # controls at a stroke end there


@dataclass
class TranslationalEnvelope:
    orientation: str  # 'fixed' or 'free'
    extremes: list[AxisExtreme]
    solver: str

    @property
    def lower(self) -> np.ndarray:
        return np.array([self.get(a, "min").value for a in AXES])

    @property
    def upper(self) -> np.ndarray:
        return np.array([self.get(a, "max").value for a in AXES])

    def get(self, axis: str, sense: str) -> AxisExtreme:
        return next(e for e in self.extremes if e.axis == axis and e.sense == sense)


def control_corners(model: PlatformModel) -> np.ndarray:
    """(2^n_u, n_u) controls at every combination of stroke ends (bit i set: control i at its upper)."""
    spec = model.spec
    if spec.n_u > MAX_CORNER_CONTROLS:
        raise BadInput(f"{spec.name}: {spec.n_u} controls give 2^{spec.n_u} corners; at most {MAX_CORNER_CONTROLS} controls")
    lo, hi = spec.control_bounds()
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise BadInput(f"{spec.name}: every control needs a finite stroke for the corner envelope")
    bits = np.array(list(itertools.product([0, 1], repeat=spec.n_u)), dtype=bool)[:, ::-1]
    return np.where(bits, hi, lo)


def corner_envelope(model: PlatformModel, td=None, continuation_steps: int = 8) -> CornerEnvelope:
    """Forward kinematics from the neutral pose at every corner of the control box.

    A corner that Newton cannot reach from neutral in one go (or that lands on a mirror pose) is
    approached by continuation: the controls walk from neutral to the corner in
    ``continuation_steps`` steps, each started from the previous solution.
    """
    spec = model.spec
    if spec.pose_free:
        return pose_corner_envelope(model, td)
    U = control_corners(model)
    batch = model.forward_batch(U, td)
    ok = batch.converged & batch.on_branch
    P, X, q = batch.p.copy(), batch.X.copy(), batch.q.copy()
    u0 = spec.neutral_u()
    for i in np.nonzero(~ok)[0]:
        p = spec.neutral_p()
        try:
            for s in np.linspace(0, 1, continuation_steps + 1)[1:]:
                res = model.forward(u0 + s * (U[i] - u0), td, guess=p)
                p = res.p
        except ComputationFailed:
            continue
        P[i], X[i], q[i], ok[i] = res.p, res.X, res.q, True
    return CornerEnvelope(U, P, X, q, ok, model.pose(spec.neutral_p())[1])


def pose_corner_envelope(model: PlatformModel, td=None) -> CornerEnvelope:
    """The corners of a pose-free stand's pose box (every coordinate at its lower or upper bound,
    2^n_p poses) mapped through inverse kinematics; a corner counts as converged when its
    controls lie inside the strokes with the stand on its branch. Such a stand's control box
    has almost no consistent corner (independent cable lengths fit no pose)."""
    spec = model.spec
    lo, hi = pose_box(spec)
    bits = np.array(list(itertools.product([0, 1], repeat=spec.n_p)), dtype=bool)[:, ::-1]
    P = np.where(bits, hi, lo)
    res = controls_of_poses(model, P, td)
    q = np.array([model.pose(p)[0] for p in P])
    X = np.array([model.pose(p)[1] for p in P])
    U = np.where(np.isfinite(res["controls"]), res["controls"], np.nan)
    return CornerEnvelope(U, P, X, q, res["ok"], model.pose(spec.neutral_p())[1])


def check_envelope(spec, corners: CornerEnvelope, envelopes) -> None:
    """ComputationFailed (one line) when the workspace is degenerate: fewer than two corners
    solved, or the origin's range along every axis, over the corners and the envelopes, no more
    than :data:`DEGENERATE_SPAN` (a point) while the stand has translational coordinates and its
    solved corners turn the platform by no more than :data:`DEGENERATE_SPAN` rad either (a stand
    that only turns, such as a rotary rig, has a workspace of orientations)."""
    n_ok = int(corners.converged.sum())
    what = "pose-box corners" if spec.pose_free else "control-box corners"
    if n_ok < 2:
        raise ComputationFailed(
            f"{spec.name}: the workspace is degenerate: {n_ok} of {len(corners.converged)} {what} solved on the stand's "
            "branch" + ("" if spec.pose_free else "; if its commands are not independent (a cable robot), declare "
                        "free_space='pose'"))
    lengths = any(c.unit == "m" for c in spec.coordinates)
    span = corners.upper - corners.lower
    for env in envelopes:
        span = np.maximum(span, env.upper - env.lower)
    q = corners.q[corners.converged]
    turn = 2.0 * np.arccos(np.clip(np.abs(q @ q[0]), 0.0, 1.0))  # angle of each solved corner from the first
    if lengths and not np.max(span) > DEGENERATE_SPAN and not np.max(turn) > DEGENERATE_SPAN:
        raise ComputationFailed(
            f"{spec.name}: the workspace is degenerate: the origin moves {np.max(span):.3g} m at most along x, y and z "
            f"over {n_ok} {what} and the envelopes (a point)")


def _ipopt_options() -> dict:
    return {"ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": 0, "ipopt.tol": 1e-10,
            "ipopt.constr_viol_tol": 1e-9, "ipopt.max_iter": 500,
            # a NaN met on the way (a trial pose where the stand cannot assemble) is handled by
            # IPOPT's line search; CasADi's warning about it would only clutter stderr
            "show_eval_warnings": False}


@dataclass
class _EnvelopeProblem:
    """The optimisation behind one translational envelope: variables ``x`` in [x_lb, x_ub] (the
    controls, the pose coordinates, or both, by the stand's route), and as functions of them the
    controls ``u``, pose coordinates ``p`` and origin ``X``; constraints ``G`` in [lbg, ubg].
    ``pose_lb``, ``pose_ub``: the pose coordinates' box (angles pinned at a fixed orientation);
    ``lo_u``, ``hi_u``: the strokes; ``p0``: the neutral pose."""

    x: ca.SX
    u: ca.SX
    p: ca.SX
    X: ca.SX
    G: ca.SX
    lbg: np.ndarray
    ubg: np.ndarray
    x_lb: np.ndarray
    x_ub: np.ndarray
    pose_lb: np.ndarray
    pose_ub: np.ndarray
    lo_u: np.ndarray
    hi_u: np.ndarray
    p0: np.ndarray
    solver_name: str


def _envelope_problem(model: PlatformModel, orientation: str, td) -> _EnvelopeProblem:
    """The variables, constraints and bounds of the envelope search on the stand's route: serial
    chains (closed-form forward) over the controls, a fixed orientation one scalar constraint;
    stands with a closed-form inverse over the pose coordinates, the controls held to their
    strokes; any other stand over both, held to F(u, td, pose(p)) = 0. The stand's branch holds
    wherever the pose is a variable. An infinite pose bound is read as +-1e6."""
    spec = model.spec
    n_p, n_u = spec.n_p, spec.n_u
    lo_u, hi_u = spec.control_bounds()
    p = ca.SX.sym("p", n_p)
    q, X = spec.pose(p)
    lbx = np.array([c.lower for c in spec.coordinates], float)
    ubx = np.array([c.upper for c in spec.coordinates], float)
    p0 = spec.neutral_p()
    if orientation == "fixed":
        fixed = np.array([c.unit != "m" for c in spec.coordinates])
        lbx[fixed] = ubx[fixed] = p0[fixed]
    lbx = np.where(np.isfinite(lbx), lbx, -1e6)
    ubx = np.where(np.isfinite(ubx), ubx, 1e6)
    if spec.forward is not None:
        # serial chains: the controls are the variables, the pose follows from them
        u = ca.SX.sym("u", n_u)
        q, X = spec.forward(u, td)
        x = u
        g, lbg, ubg = [], [], []
        if orientation == "fixed":
            if spec.coordinates_from_pose is None:
                raise BadInput(f"{spec.name}: a fixed orientation needs the stand's coordinates_from_pose")
            angles = np.nonzero([c.unit != "m" for c in spec.coordinates])[0]
            pc = spec.coordinates_from_pose(q, X)
            # one scalar constraint: a chain with few joints keeps its orientation only on a
            # subset of its motions, and as many equalities as angles would overconstrain it
            g.append(ca.sumsqr(pc[[int(k) for k in angles]] - p0[angles]))
            lbg.append([0.0])
            ubg.append([1e-12])
        x_lb, x_ub = lo_u, hi_u
        p = spec.coordinates_from_pose(q, X) if spec.coordinates_from_pose is not None else ca.SX.zeros(n_p)
        solver_name = "IPOPT over the controls, pose by the closed-form forward kinematics"
    elif spec.inverse is not None:
        u = spec.inverse(td, q, X)
        x = p
        g = [u]
        lbg, ubg = [lo_u], [hi_u]
        x_lb, x_ub = lbx, ubx
        solver_name = "IPOPT over the pose coordinates, controls by the closed-form inverse"
    else:
        u = ca.SX.sym("u", n_u)
        x = ca.vertcat(p, u)
        r = spec.residual(u, td, q, X)
        g = [r]
        lbg, ubg = [np.zeros(r.shape[0])], [np.zeros(r.shape[0])]
        x_lb, x_ub = np.concatenate([lbx, lo_u]), np.concatenate([ubx, hi_u])
        solver_name = "IPOPT over pose coordinates and controls held to F = 0"
    if spec.branch is not None and spec.forward is None:
        gb = spec.branch(u, td, q, X)
        g.append(gb)
        lbg.append(np.full(gb.shape[0], 1e-6))
        ubg.append(np.full(gb.shape[0], np.inf))
    G = ca.vertcat(*g) if g else ca.SX(0, 1)
    return _EnvelopeProblem(x, u, p, X, G, np.concatenate(lbg) if lbg else np.zeros(0),
                            np.concatenate(ubg) if ubg else np.zeros(0), x_lb, x_ub, lbx, ubx, lo_u, hi_u, p0,
                            solver_name)


def _start_vector(model: PlatformModel, nlp: _EnvelopeProblem, td, pp) -> np.ndarray:
    """The variables ``x`` of the start at pose coordinates ``pp`` (clipped into the pose box;
    controls by the inverse kinematics, clipped into their strokes). Raises ComputationFailed
    where the stand cannot reach the pose."""
    spec = model.spec
    pp = np.clip(np.asarray(pp, float), nlp.pose_lb, nlp.pose_ub)
    if spec.forward is not None:
        qq, XX = model.pose(pp)
        return np.clip(model.inverse(qq, XX, td, strict=False), nlp.lo_u, nlp.hi_u)
    if spec.inverse is not None:
        return pp
    qq, XX = model.pose(pp)
    return np.concatenate([pp, model.inverse(qq, XX, td, strict=False)])


def _feasible_point(nlp: _EnvelopeProblem, G_of: ca.Function, xs) -> bool:
    """True where ``xs`` is finite, inside its bounds (1e-9) and meets the constraints (1e-7)."""
    if not np.all(np.isfinite(xs)) or np.any(xs < nlp.x_lb - 1e-9) or np.any(xs > nlp.x_ub + 1e-9):
        return False
    gv = np.asarray(G_of(xs)).ravel()
    return bool(np.all(np.isfinite(gv))) and max(float(np.max(nlp.lbg - gv, initial=0.0)),
                                                 float(np.max(gv - nlp.ubg, initial=0.0))) <= 1e-7


def _best_extreme(model: PlatformModel, nlp: _EnvelopeProblem, td, solver, G_of: ca.Function, value_of: ca.Function,
                  start_points: list[np.ndarray], k: int, sign: float) -> tuple[float, np.ndarray] | None:
    """(entry k of ``value_of``, variables) of the best feasible candidate minimising ``sign`` times
    entry ``k`` of ``value_of``: from each start that the stand can reach, IPOPT's local optimum and
    the start itself; None where no candidate is feasible. ``G_of``, ``value_of``: the constraints
    and the vector searched (the origin, or the pose coordinates) as functions of the variables;
    ``solver`` minimises its parameter's sign times the direction's dot product with that vector."""
    e = np.zeros(value_of.size1_out(0))
    e[k] = 1.0
    best = None
    for sp in start_points:
        try:
            x0 = _start_vector(model, nlp, td, sp)
        except ComputationFailed:
            continue
        sol = solver(x0=x0, p=np.concatenate([[sign], e]), lbx=nlp.x_lb, ubx=nlp.x_ub, lbg=nlp.lbg, ubg=nlp.ubg)
        # IPOPT's local optimum, and the start itself where it is a feasible pose
        for xs in (np.asarray(sol["x"]).ravel(), np.asarray(x0, float).ravel()):
            if not _feasible_point(nlp, G_of, xs):
                continue
            val = float(np.asarray(value_of(xs)).ravel()[k])
            if best is None or sign * val < sign * best[0]:
                best = (val, xs)
    return best


def _extremes(model: PlatformModel, nlp: _EnvelopeProblem, td, value: ca.SX, names: list[str],
              starts: list[np.ndarray] | None, what: Callable[[str], str]) -> list[AxisExtreme]:
    """The least then the greatest of each entry of ``value`` (the origin, or the pose coordinates,
    as a function of the variables), named ``names``, over the poses ``nlp`` allows: from the
    neutral pose and ``starts`` (:func:`_best_extreme`), each with its pose, controls and the
    controls at a stroke end there. ComputationFailed naming ``what(name)`` where no start gives a
    feasible optimum."""
    spec = model.spec
    sense_sym = ca.SX.sym("sense", 1 + value.shape[0])  # (sign, e): minimise sign * e . value
    objective = sense_sym[0] * ca.dot(sense_sym[1:], value)
    solver = ca.nlpsol("extremes", "ipopt", {"x": nlp.x, "p": sense_sym, "f": objective, "g": nlp.G},
                       _ipopt_options())
    u_of = ca.Function("u_of", [nlp.x], [nlp.u])
    p_of = ca.Function("p_of", [nlp.x], [nlp.p])
    G_of = ca.Function("G_of", [nlp.x], [nlp.G])
    value_of = ca.Function("value_of", [nlp.x], [value])
    start_points = [nlp.p0] + [np.asarray(s, float) for s in (starts or [])]
    lo_u, hi_u = nlp.lo_u, nlp.hi_u
    span = np.maximum(hi_u - lo_u, 1e-12)
    extremes = []
    for k, name in enumerate(names):
        for sense, sign in (("min", 1.0), ("max", -1.0)):
            best = _best_extreme(model, nlp, td, solver, G_of, value_of, start_points, k, sign)
            if best is None:
                raise ComputationFailed(f"{spec.name}: the {sense} of {what(name)} found no feasible optimum")
            val, xs = best
            uu = np.asarray(u_of(xs)).ravel()
            active = [c.name for c, a, l, h, sp in zip(spec.controls, uu, lo_u, hi_u, span) if min(a - l, h - a) < 1e-6 * sp]
            extremes.append(AxisExtreme(name, sense, val, np.asarray(p_of(xs)).ravel(), uu, active))
    return extremes


def translational_envelope(model: PlatformModel, orientation: str = "fixed", td=None,
                           starts: list[np.ndarray] | None = None) -> TranslationalEnvelope:
    """Extreme origin positions over the reachable poses (see the module docstring).

    ``starts``: extra starting pose coordinates (n_p,) tried besides the neutral pose (at a fixed
    orientation, with the orientation coordinates set to the neutral ones); the best feasible
    optimum is kept, and a start that is itself feasible counts as a candidate, so the envelope
    holds every feasible start (a corner of the control box it was given). Raises
    ComputationFailed if no start gives a feasible optimum.
    """
    if orientation not in ("fixed", "free"):
        raise BadInput(f"orientation must be 'fixed' or 'free', got {orientation!r}")
    td = model._td(td)
    nlp = _envelope_problem(model, orientation, td)
    extremes = _extremes(model, nlp, td, nlp.X, list(AXES), starts, lambda axis: f"{axis} ({orientation} orientation)")
    return TranslationalEnvelope(orientation, extremes, nlp.solver_name)


@dataclass
class CoordinateRange:
    """One pose coordinate's least and greatest value over the poses the stand takes (SI: m or
    rad), each with the pose that reaches it."""

    name: str
    unit: str  # 'm' or 'rad'
    neutral: float
    lower: AxisExtreme
    upper: AxisExtreme


def coordinate_ranges(model: PlatformModel, td=None, starts: list[np.ndarray] | None = None) -> list[CoordinateRange]:
    """The range of every pose coordinate over the poses the stand takes with its controls inside
    their strokes, on its branch and within the coordinates' bounds (the free orientation's
    envelope problem, the coordinate itself the objective); each extreme from the neutral pose
    and ``starts`` (a start that is itself feasible counts). Empty for a stand whose pose has no
    coordinates to read (a chain without ``coordinates_from_pose``). ComputationFailed where no
    start gives a feasible optimum."""
    spec = model.spec
    if spec.forward is not None and spec.coordinates_from_pose is None:
        return []
    td = model._td(td)
    nlp = _envelope_problem(model, "free", td)
    names = [c.name for c in spec.coordinates]
    ends = _extremes(model, nlp, td, nlp.p, names, starts, lambda name: f"coordinate {name}")
    return [CoordinateRange(c.name, c.unit, float(nlp.p0[k]), ends[2 * k], ends[2 * k + 1])
            for k, c in enumerate(spec.coordinates)]


def fixed_orientation_section(model: PlatformModel, plane: str, level: float, bounds_m: tuple, n: int = 81, td=None):
    """Reachability at the neutral orientation on a grid in a coordinate plane of the origin.

    ``plane``: 'xy', 'xz' or 'yz'; ``level``: the third coordinate (m); ``bounds_m``: ((a0, a1),
    (b0, b1)). Returns (A (n,), B (n,), reachable (n, n) bool, indexed [b, a]). Needs the stand's
    closed-form inverse (a grid of Newton solves would be slow); None otherwise.
    """
    spec = model.spec
    if spec.inverse is None:
        return None
    td = model._td(td)
    ia, ib = "xyz".index(plane[0]), "xyz".index(plane[1])
    ic = 3 - ia - ib
    A = np.linspace(*bounds_m[0], n)
    B = np.linspace(*bounds_m[1], n)
    AA, BB = np.meshgrid(A, B)
    Xs = np.zeros((n * n, 3))
    Xs[:, ia], Xs[:, ib], Xs[:, ic] = AA.ravel(), BB.ravel(), level
    q0, X0 = model.pose(spec.neutral_p())
    qs = np.repeat(q0[None, :], n * n, axis=0)
    U = np.asarray(spec.inverse.map(n * n)(td, qs.T, Xs.T)).T
    lo, hi = spec.control_bounds()
    ok = np.all(np.isfinite(U), axis=1) & np.all((U >= lo) & (U <= hi), axis=1)
    if spec.branch is not None:
        g = np.asarray(spec.branch.map(n * n)(U.T, td, qs.T, Xs.T)).T
        ok &= np.all(g > 0, axis=1)
    return A, B, ok.reshape(n, n)


def workspace_figures(model: PlatformModel, td=None, conditioning_threshold: float = 0.05):
    """Everything `platkit workspace` reports, in SI: (figures dict, corners, fixed, free)."""
    spec = model.spec
    corners = corner_envelope(model, td)
    if not corners.converged.any():
        box = "pose box (inverse kinematics)" if spec.pose_free else "control box"
        raise ComputationFailed(f"{spec.name}: forward kinematics failed at every corner of the {box}")
    # both searches start from the extreme corners too: a local optimum from neutral alone can be
    # smaller than corner poses already found (a delta robot's z max at fixed orientation)
    fixed = translational_envelope(model, "fixed", td, starts=_extreme_corner_starts(corners))
    free = translational_envelope(model, "free", td, starts=_extreme_corner_starts(corners))
    check_envelope(spec, corners, (fixed, free))
    ranges = coordinate_ranges(model, td, starts=_extreme_corner_coordinates(corners))
    inv_cond = model.inverse_condition_numbers(corners.P[corners.converged], td, corners.U[corners.converged])
    neutral_cond = model.conditioning(spec.neutral_p(), td, spec.neutral_u())

    def env(lo, hi):
        return {a: {"min": float(l), "max": float(h), "range": float(h - l)} for a, l, h in zip(AXES, lo, hi)}

    c_lo, c_hi = corners.lower - corners.neutral_X, corners.upper - corners.neutral_X
    figures = {
        "platform": spec.name,
        "neutral_position": corners.neutral_X.tolist(),
        "corners": {
            "count": int(len(corners.U)), "converged": int(corners.converged.sum()),
            "relative_to_neutral": env(c_lo, c_hi),
        },
        "true_envelope": {},
        "conditioning": {
            "characteristic_length": model.characteristic_length,
            "uses_twist": model.uses_twist,
            "neutral": {"condition_number": neutral_cond.condition_number, "sigma_min": neutral_cond.sigma_min,
                        "distance_to_singularity": neutral_cond.distance_to_singularity},
            "corners_min_inverse_condition": float(inv_cond.min()),
            "threshold": conditioning_threshold,
            "near_singular_corners": [int(i) for i in np.nonzero(corners.converged)[0][inv_cond < conditioning_threshold]],
        },
        "solver": {"forward": model.backend, "envelope": fixed.solver},
    }
    for env_obj in (fixed, free):
        lo, hi = env_obj.lower - corners.neutral_X, env_obj.upper - corners.neutral_X
        entry = env(lo, hi)
        for a, cl, ch in zip(AXES, c_lo, c_hi):
            entry[a]["larger_than_corners_min"] = float(cl - entry[a]["min"])
            entry[a]["larger_than_corners_max"] = float(entry[a]["max"] - ch)
            entry[a]["range_ratio_to_corners"] = float(entry[a]["range"] / (ch - cl)) if ch > cl else None
        entry["poses"] = {f"{e.axis}_{e.sense}": {"p": e.p.tolist(), "u": e.u.tolist(), "active_controls": e.active}
                          for e in env_obj.extremes}
        figures["true_envelope"][env_obj.orientation + "_orientation"] = entry
    figures["coordinates"] = {
        r.name: {"unit": r.unit, "neutral": r.neutral, "min": r.lower.value, "max": r.upper.value,
                 "range": r.upper.value - r.lower.value,
                 "poses": {e.sense: {"p": e.p.tolist(), "u": e.u.tolist(), "active_controls": e.active}
                           for e in (r.lower, r.upper)}}
        for r in ranges}
    return figures, corners, fixed, free


def _extreme_corner_coordinates(corners: CornerEnvelope) -> list[np.ndarray]:
    """Corner poses that hold the least or greatest value of some pose coordinate: good starts
    for the coordinates' ranges."""
    ok = np.nonzero(corners.converged & np.all(np.isfinite(corners.P), axis=1))[0]
    if not ok.size:
        return []
    picks = set()
    for k in range(corners.P.shape[1]):
        picks.add(int(ok[np.argmin(corners.P[ok, k])]))
        picks.add(int(ok[np.argmax(corners.P[ok, k])]))
    return [corners.P[i] for i in sorted(picks)]


def _extreme_corner_starts(corners: CornerEnvelope) -> list[np.ndarray]:
    """Corner poses that are extreme along some axis: good starts for the envelope searches."""
    ok = np.nonzero(corners.converged)[0]
    picks = set()
    for k in range(3):
        picks.add(int(ok[np.argmin(corners.X[ok, k])]))
        picks.add(int(ok[np.argmax(corners.X[ok, k])]))
    return [corners.P[i] for i in sorted(picks)]
