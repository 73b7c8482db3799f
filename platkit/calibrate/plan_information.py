"""The information side of experiment design (platkit.calibrate.plan): which tracked link each
planned marker rides on, the default marker layout, the identification Jacobian of the markers
(chains and trees), the D-optimal exchange, and the predicted uncertainties, per link on a tree.
The rules and the equations are plan's (see its module docstring)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from platkit.effects import seen_controls
from platkit.errors import BadInput
from platkit.geometry import ca_matrix_from_quat, skew
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.model import controls_moving_links as controls_moving_links
from platkit.model import link_controls as link_controls

# ----------------------------------------------------------------------------- reach


def feasible(spec: PlatformSpec, U: np.ndarray, td=None, model: PlatformModel | None = None):
    """Which control vectors (N, n_u) the stand takes: forward kinematics converges, on the
    stand's branch, within the coordinate bounds. Returns (mask (N,), p (N, n_p)).

    Points that fail from the neutral start are retried from the pose of the nearest success."""
    model = model or PlatformModel(spec)
    U = np.atleast_2d(np.asarray(U, float))
    fb = model.forward_batch(U, td=td, strict=False)
    ok = fb.converged & fb.on_branch
    P = fb.p.copy()
    if np.any(~ok) and np.any(ok):
        good = np.nonzero(ok)[0]
        bad = np.nonzero(~ok)[0]
        lo, hi = spec.control_bounds()
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        d = np.linalg.norm((U[bad, None, :] - U[None, good, :]) / span, axis=2)
        guess = P[good[np.argmin(d, axis=1)]]
        fb2 = model.forward_batch(U[bad], td=td, guess=guess, strict=False)
        ok2 = fb2.converged & fb2.on_branch
        ok[bad] = ok2
        P[bad[ok2]] = fb2.p[ok2]
    plo = np.array([c.lower for c in spec.coordinates])
    phi = np.array([c.upper for c in spec.coordinates])
    with np.errstate(invalid="ignore"):
        inside = np.all((P >= plo) & (P <= phi) | ~np.isfinite(P), axis=1)
    return ok & inside & np.all(np.isfinite(U), axis=1), P


# ----------------------------------------------------------------------------- trees


def idle_controls(spec: PlatformSpec) -> np.ndarray:
    """(n_u,) bool: the controls that move no tracked link (a tree's joints off every tracked
    branch, recorded for the loads); none on a chain."""
    return ~seen_controls(spec)


def planning_bounds(spec: PlatformSpec) -> tuple[np.ndarray, np.ndarray]:
    """The strokes [lo, hi] (n_u,) a plan draws from: the controls' own, but a control without a
    finite stroke (a URDF's continuous joint, a revolute joint whose limits are left out) over one
    turn either way of its neutral (a control in radians), or +- 1 of its unit (any other)."""
    lo, hi = spec.control_bounds()
    unbounded = ~(np.isfinite(lo) & np.isfinite(hi) & (hi > lo))
    if not np.any(unbounded):
        return lo, hi
    u0 = spec.neutral_u()
    half = np.array([np.pi if c.unit == "rad" else 1.0 for c in spec.controls])
    return np.where(unbounded, u0 - half, lo), np.where(unbounded, u0 + half, hi)


def unbounded_controls(spec: PlatformSpec) -> list[str]:
    """The names of the controls without a finite stroke, which :func:`planning_bounds` plans over
    one turn either way."""
    lo, hi = spec.control_bounds()
    return [c.name for c, a, b in zip(spec.controls, lo, hi) if not (np.isfinite(a) and np.isfinite(b) and b > a)]


def homed_at_middle(u0: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """(n_u,) bool: the controls whose neutral ``u0`` lies on or outside their box (lower, upper)
    (a URDF joint whose zero is a limit: an elbow), which a motion takes about the box's middle
    instead of their neutral; a box without finite ends never."""
    return ~((u0 > lower) & (u0 < upper)) & np.isfinite(upper - lower)


def held_at_home(spec: PlatformSpec, moving: np.ndarray, margin: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """(held (n_u,) bool, values (n_u,)): a plan that moves only the controls ``moving`` (n_u,) bool
    holds every other control at its home: its neutral, or the middle of its stroke less ``margin``
    at both ends where the neutral lies on or outside that box (:func:`homed_at_middle`, the home a
    motion starts from). ``values`` is the home of every control."""
    moving = np.asarray(moving, bool)
    if moving.shape != (spec.n_u,):
        raise BadInput(f"moving: expected {spec.n_u} flags (one per control), got {moving.shape}")
    lo, hi = planning_bounds(spec)
    span = hi - lo
    lower, upper = lo + margin * span, hi - margin * span
    u0 = spec.neutral_u()
    home = np.where(homed_at_middle(u0, lower, upper), 0.5 * (lower + upper), u0)
    return ~moving, home


def pin_held(spec: PlatformSpec, U: np.ndarray, P: np.ndarray, held: tuple[np.ndarray, np.ndarray] | None,
             model: PlatformModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Poses (U (N, n_u), P (N, n_p)) with the ``held`` controls (mask, values: :func:`held_at_home`)
    set to their values, the poses solved again; those then out of reach dropped. Controls that move
    no tracked link change no marker, so pinning them alone returns U, P as given."""
    if held is None or not np.any(held[0] & ~idle_controls(spec)):
        return U, P
    U = np.array(U, float)
    U[:, held[0]] = held[1][held[0]]
    ok, P = feasible(spec, U, model=model)
    return U[ok], P[ok]


def marker_link_indices(spec: PlatformSpec, n_markers: int) -> list[int] | None:
    """The rule that places planned and simulated markers on a stand whose links are tracked
    (``spec.link_poses``, a tree): marker k rides on tracked link k mod L (``spec.tracked_links``),
    so that every branch is seen; None on a stand without tracked links (one moving frame).
    Plan, the additive and the physical simulators all place markers by it."""
    if spec.link_poses is None:
        return None
    L = len(spec.tracked_links)
    return [k % L for k in range(n_markers)]


def marker_links(spec: PlatformSpec, n_markers: int) -> list[str]:
    """The link each planned marker rides on: on a tree (two or more tracked links) by
    :func:`marker_link_indices`, as the simulators place them; otherwise the moving frame."""
    index = marker_link_indices(spec, n_markers)
    if index is None or len(spec.tracked_links) < 2:
        return [spec.moving_frame] * n_markers
    return [spec.tracked_links[k] for k in index]


def default_marker_count(spec: PlatformSpec) -> int:
    """Markers a plan places by default: 5 on one moving link; on a tree 3 on each tracked link
    (marker k on link k mod L), the fewest that fix each link's pose on its own."""
    links = set(marker_links(spec, len(spec.tracked_links) or 1))
    return 5 if len(links) < 2 else 3 * len(links)


# ----------------------------------------------------------------------------- markers


def stand_length_scale(spec: PlatformSpec) -> float:
    """A characteristic size of the stand (m): 0.6 x the median magnitude of its nonzero
    length parameters, clipped to [0.03, 2]. Used to place markers generically."""
    vals = np.array([abs(p.nominal) for p in spec.parameters if p.unit == "m" and abs(p.nominal) > 1e-9])
    size = float(np.median(vals)) if vals.size else 0.3
    return float(np.clip(0.6 * size, 0.03, 2.0))


def default_marker_layout(spec: PlatformSpec, n_markers: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """(M, 3) m marker positions on the moving part, in its frame: spread round the origin at
    radius ~ :func:`stand_length_scale`, at different heights (never coplanar)."""
    if n_markers < 3:
        raise BadInput(f"at least 3 markers are needed to fix a pose, got {n_markers}")
    rng = rng or np.random.default_rng(0)
    rho = stand_length_scale(spec)
    ang = 2 * np.pi * np.arange(n_markers) / n_markers + rng.uniform(-0.3, 0.3, n_markers)
    rad = rho * rng.uniform(0.6, 1.0, n_markers)
    z = rho * np.linspace(0.1, 0.4, n_markers)[rng.permutation(n_markers)]
    return np.stack([rad * np.cos(ang), rad * np.sin(ang), z], axis=1)


# ----------------------------------------------------------------------------- information


_MARKER_FUNCTIONS: dict = {}


def _marker_function(spec: PlatformSpec, n_markers: int) -> ca.Function:
    """CasADi (p, s) -> (m, dm/dp, dm/ds): marker positions (3M,) in the base frame."""
    key = (id(spec), n_markers)
    hit = _MARKER_FUNCTIONS.get(key)
    if hit is not None and hit[0] is spec:
        return hit[1]
    fn = _build_marker_function(spec, n_markers)
    _MARKER_FUNCTIONS[key] = (spec, fn)
    return fn


def _build_marker_function(spec: PlatformSpec, n_markers: int) -> ca.Function:
    p = ca.SX.sym("p", spec.n_p)
    S = ca.SX.sym("S", 3, n_markers)
    q, X = spec.pose(p)

    m = ca.repmat(X, 1, n_markers) + ca.mtimes(ca_matrix_from_quat(q), S)
    m = ca.reshape(m, 3 * n_markers, 1)  # column-major: marker k at rows 3k..3k+2
    return ca.Function("markers", [p, ca.reshape(S, 3 * n_markers, 1)],
                       [m, ca.jacobian(m, p), ca.jacobian(m, ca.reshape(S, 3 * n_markers, 1))],
                       ["p", "s"], ["m", "m_p", "m_s"])


@dataclass
class IdentificationJacobian:
    """J (N, 3M, n_theta): d(marker positions in the base frame) / d theta, per pose.

    theta = (free td, mocap translation (3), mocap rotation vector (3), marker positions (3M)),
    named in ``names``, with ``units``.
    """

    J: np.ndarray
    names: list[str]
    units: list[str]
    n_td: int


def identification_jacobian(spec: PlatformSpec, U: np.ndarray, markers: np.ndarray, td=None,
                            P: np.ndarray | None = None, model: PlatformModel | None = None) -> IdentificationJacobian:
    """The identification Jacobian at controls U (N, n_u) with markers (M, 3) m on the moving
    part (on a tree, marker k on tracked link k mod L); ``P`` (N, n_p): the poses if already
    solved."""
    model = model or PlatformModel(spec)
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    U = np.atleast_2d(U)
    if P is None:
        ok, P = feasible(spec, U, td, model)
        if not np.all(ok):
            raise BadInput(f"{spec.name}: {(~ok).sum()} of the planned controls are not reachable")
    M = len(markers)
    free = np.array([p.free for p in spec.parameters])
    if spec.link_poses is not None and len(spec.tracked_links) > 1:
        return _tree_identification_jacobian(spec, U, np.asarray(markers, float), td, free)
    mfun = _marker_function(spec, M)
    s_flat = np.asarray(markers, float).reshape(-1)  # x,y,z per marker, matching the reshape above
    N = len(U)
    n_theta = int(free.sum()) + 6 + 3 * M
    J = np.zeros((N, 3 * M, n_theta))
    for i in range(N):
        _, F_p, _, F_td = (np.asarray(a) for a in model.F_jac(U[i], td, P[i]))
        dp_dtd = -np.linalg.pinv(F_p) @ F_td[:, free]
        m, m_p, m_s = (np.asarray(a) for a in mfun(P[i], s_flat))
        J[i, :, : free.sum()] = m_p @ dp_dtd
        _nuisance_columns(J[i], int(free.sum()), m.reshape(M, 3), m_s)
    return _identification_jacobian(spec, J, M, int(free.sum()))


def _nuisance_columns(J: np.ndarray, k: int, m: np.ndarray, m_s: np.ndarray) -> None:
    """One pose's columns after its ``k`` stand columns: a small motion of the base-to-mocap
    transform (translation, rotation vector) at the markers ``m`` (M, 3), then their places (m_s)."""
    J[:, k:k + 3] = np.tile(np.eye(3), (len(m), 1))
    J[:, k + 3:k + 6] = np.vstack([-skew(mk) for mk in m])
    J[:, k + 6:] = m_s


def _identification_jacobian(spec: PlatformSpec, J: np.ndarray, M: int, n_free: int) -> IdentificationJacobian:
    """J with its unknowns' names and units: the stand's free parameters, the mocap motion, the markers."""
    names = [p.name for p in spec.parameters if p.free] + ["mocap_x", "mocap_y", "mocap_z", "mocap_rx", "mocap_ry", "mocap_rz"]
    units = [p.unit for p in spec.parameters if p.free] + ["m"] * 3 + ["rad"] * 3
    for k in range(M):
        names += [f"marker{k + 1}_{a}" for a in "xyz"]
        units += ["m"] * 3
    return IdentificationJacobian(J, names, units, n_free)


def _tree_identification_jacobian(spec: PlatformSpec, U: np.ndarray, markers: np.ndarray, td: np.ndarray,
                                   free: np.ndarray) -> IdentificationJacobian:
    """:func:`identification_jacobian` of a tree (several tracked links): each marker on its link
    by :func:`marker_link_indices`, so that every branch is planned for; closed form through
    ``spec.link_poses``."""
    M = len(markers)
    index = marker_link_indices(spec, M) or [0] * M
    u = ca.SX.sym("u", spec.n_u)
    t = ca.SX.sym("td", spec.n_td)
    S = ca.SX.sym("s", 3 * M)
    q_all, X_all = spec.link_poses(u, t)
    m = ca.vertcat(*[X_all[3 * i:3 * i + 3] + ca.mtimes(ca_matrix_from_quat(q_all[4 * i:4 * i + 4]), S[3 * k:3 * k + 3])
                     for k, i in enumerate(index)])
    f = ca.Function("tree_markers", [u, t, S], [m, ca.jacobian(m, t), ca.jacobian(m, S)])
    N = len(U)
    n_free = int(free.sum())
    J = np.zeros((N, 3 * M, n_free + 6 + 3 * M))
    s_flat = markers.reshape(-1)
    for i in range(N):
        mv, m_td, m_s = (np.asarray(a) for a in f(U[i], td, s_flat))
        J[i, :, :n_free] = m_td[:, free]
        _nuisance_columns(J[i], n_free, mv.reshape(M, 3), m_s)
    return _identification_jacobian(spec, J, M, n_free)


class _Subspace:
    """Column scaling and the identifiable subspace of a stacked Jacobian."""

    def __init__(self, J_all: np.ndarray, rtol: float = 1e-7):
        A = J_all.reshape(-1, J_all.shape[-1])
        self.scale = np.linalg.norm(A, axis=0)
        self.scale[self.scale == 0] = 1.0
        Rfac = np.linalg.qr(A / self.scale, mode="r")  # same singular values, far smaller
        _, sv, Vt = np.linalg.svd(Rfac, full_matrices=False)
        self.rank = int(np.sum(sv > rtol * sv[0]))
        self.V = Vt[: self.rank].T  # (n_theta, r)
        self.n_theta = A.shape[1]

    def reduce(self, J: np.ndarray) -> np.ndarray:
        """(N, rows, n_theta) -> (N, rows, r)."""
        return (J / self.scale) @ self.V


def _logdet(A):
    sign, val = np.linalg.slogdet(A)
    return val if sign > 0 else -np.inf


def d_optimal(Jr: np.ndarray, n: int, exchange_passes: int = 2, ridge: float = 1e-8) -> np.ndarray:
    """Indices of ``n`` of the candidates Jr (C, rows, r) maximising log det(sum Jr_i^T Jr_i):
    greedy selection with a tiny ridge, then Fedorov exchange passes."""
    C, rows, r = Jr.shape
    if n > C:
        raise BadInput(f"cannot select {n} poses from {C} candidates")
    eps = ridge * float(np.sum(Jr**2)) / max(C * r, 1)
    A = eps * np.eye(r)
    chosen: list[int] = []
    avail = np.ones(C, bool)

    def gains(Ainv):
        G = (Jr @ Ainv) @ Jr.transpose(0, 2, 1) + np.eye(rows)
        sign, val = np.linalg.slogdet(G)
        return np.where(sign > 0, val, -np.inf)

    for _ in range(n):
        g = gains(np.linalg.inv(A))
        g[~avail] = -np.inf
        j = int(np.argmax(g))
        chosen.append(j)
        avail[j] = False
        A = A + Jr[j].T @ Jr[j]
    for _ in range(exchange_passes):
        improved = False
        for pos in range(n):
            j_out = chosen[pos]
            A_minus = A - Jr[j_out].T @ Jr[j_out]
            g = gains(np.linalg.inv(A_minus))
            g[~avail] = -np.inf
            j_in = int(np.argmax(g))
            if g[j_in] > _logdet(A) - _logdet(A_minus) + 1e-9:
                chosen[pos] = j_in
                avail[j_in], avail[j_out] = False, True
                A = A_minus + Jr[j_in].T @ Jr[j_in]
                improved = True
        if not improved:
            break
    return np.array(chosen, int)


def plan_uncertainty(J_plan: np.ndarray, J_candidates: np.ndarray, sigma: float, names: list[str],
                     units: list[str], sub: _Subspace | None = None, links: list[str] | None = None,
                     n_td: int | None = None) -> dict:
    """Predicted uncertainty of the parameters estimated from poses J_plan (N, 3M, n_theta)
    with marker noise ``sigma`` (m per coordinate).

    Returns: identifiable rank and the number of never-identifiable directions (over the
    candidates J_candidates), the plan's own rank, log det of the scaled information, the
    per-parameter std of the minimum-norm solution (SI units), and 'predicted_marker_rms_m':
    the RMS std of the predicted marker positions over the candidate poses (gauge-free).

    ``links`` (M,), the link each marker rides on, naming two or more links (a tree): 'links' too,
    per link (:func:`_per_link`) the same figures over its own markers and how many directions
    they see; ``n_td``: the stand's columns, first (default: the columns not named mocap_ or
    marker).
    """
    sub = sub or _Subspace(J_candidates)
    Jr = sub.reduce(J_plan).reshape(-1, sub.rank)
    info = Jr.T @ Jr
    ev = np.linalg.eigvalsh(info)
    plan_rank = int(np.sum(ev > 1e-14 * max(ev[-1], 1e-300)))  # (1e-7)^2, as the subspace's own cut
    out = {
        "n_poses": int(J_plan.shape[0]),
        "n_parameters": int(sub.n_theta),
        "identifiable_rank": sub.rank,
        "never_identifiable": int(sub.n_theta - sub.rank),
        "plan_rank": plan_rank,
        "sigma_m": float(sigma),
    }
    per_link = links is not None and len(set(links)) > 1
    if plan_rank < sub.rank:
        out.update(logdet=None, predicted_marker_rms_m=None, parameter_std={}, identifiable=False)
        if per_link:
            out["links"] = _per_link(J_plan, J_candidates, sub, links, None, _stand_columns(names, n_td))
        return out
    cov_r = sigma**2 * np.linalg.inv(info)
    cov_s = sub.V @ cov_r @ sub.V.T
    cov = cov_s / np.outer(sub.scale, sub.scale)
    std = np.sqrt(np.maximum(np.diag(cov), 0))
    Jc = J_candidates.reshape(-1, sub.n_theta)
    pred_var = np.einsum("ij,jk,ik->i", Jc, cov, Jc)
    out.update(
        identifiable=True,
        logdet=float(_logdet(info)),
        geometric_mean_std_scaled=float(sigma * math.exp(-_logdet(info) / (2 * sub.rank))),
        predicted_marker_rms_m=float(np.sqrt(np.mean(np.maximum(pred_var, 0)))),
        predicted_marker_max_m=float(np.sqrt(np.max(np.maximum(pred_var, 0)))),
        parameter_std={n: {"std": float(s), "unit": u} for n, s, u in zip(names, std, units)},
    )
    if per_link:
        out["links"] = _per_link(J_plan, J_candidates, sub, links, pred_var, _stand_columns(names, n_td))
    return out


def _stand_columns(names: list[str], n_td: int | None) -> int:
    if n_td is not None:
        return int(n_td)
    return sum(1 for n in names if not (n.startswith("mocap_") or n.startswith("marker")))


def _rank(A: np.ndarray, scale: np.ndarray, rtol: float = 1e-7) -> int:
    """Rank of the rows A (rows, n_theta), columns scaled as the stand's subspace, at its cut."""
    A = A / scale
    if not np.any(A):
        return 0
    Rfac = np.linalg.qr(A, mode="r") if A.shape[0] > A.shape[1] else A
    sv = np.linalg.svd(Rfac, compute_uv=False)
    return int(np.sum(sv > rtol * sv[0]))


def _per_link(J_plan: np.ndarray, J_candidates: np.ndarray, sub: _Subspace, links: list[str],
              pred_var: np.ndarray | None, n_td: int) -> dict:
    """Per tracked link, over its own markers' rows: 'markers'; 'stand_parameters', the stand's
    free parameters that move it (a column nonzero at some reference pose); 'identifiable_rank',
    the directions its markers see over the reference poses (the stand's, the motion-capture
    frame's and its markers' placements; the trunk's shared with the other links), and
    'plan_rank', those the plan's poses see; 'identifiable' where they agree; and, when the whole
    plan identifies the model, 'predicted_marker_rms_m' and 'predicted_marker_max_m', the std of
    its markers' predicted positions over the reference poses (per coordinate, as the whole
    figure)."""
    M = len(links)
    rows_c = J_candidates.reshape(J_candidates.shape[0], M, 3, -1)
    rows_p = J_plan.reshape(J_plan.shape[0], M, 3, -1)
    var = None if pred_var is None else np.maximum(pred_var, 0).reshape(J_candidates.shape[0], M, 3)
    out: dict = {}
    for link in dict.fromkeys(links):
        mine = np.array([lk == link for lk in links])
        A_c = rows_c[:, mine].reshape(-1, rows_c.shape[-1])
        A_p = rows_p[:, mine].reshape(-1, rows_p.shape[-1])
        ref_rank, plan_rank = _rank(A_c, sub.scale), _rank(A_p, sub.scale)
        d = {"markers": int(mine.sum()),
             "stand_parameters": int(np.sum(np.any(A_c[:, :n_td] != 0, axis=0))),
             "identifiable_rank": ref_rank, "plan_rank": plan_rank, "identifiable": bool(plan_rank >= ref_rank)}
        if var is not None:
            v = var[:, mine]
            d.update(predicted_marker_rms_m=float(np.sqrt(np.mean(v))), predicted_marker_max_m=float(np.sqrt(np.max(v))))
        else:
            d.update(predicted_marker_rms_m=None, predicted_marker_max_m=None)
        out[link] = d
    return out
