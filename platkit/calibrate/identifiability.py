"""Which parameters a data set can fix: pivoted orthogonalisation of the scaled identification Jacobian.

The identification Jacobian ``J`` (n_obs, n_par) maps small parameter changes to marker
displacements. Each column is scaled by its parameter's typical size (1 mm, 1 mrad, ...) so that
columns compare. Parameters are taken in priority tiers (the base-to-mocap transform and the
marker positions first: without them nothing is predicted; then model terms; then the stand's
td). Within a tier, the column with the largest component outside the span of the columns
already chosen is taken next (QR with column pivoting, as FIGAROH chooses base parameters); of
columns whose remaining components agree with the largest to ``TIE_REL_TOL``, the first (lowest
index) is taken, so that which parameter of an exact gauge is held does not follow rounding; a
column whose remaining component is below ``rel_tol`` of its own norm is *held at nominal* and
reported with the combination of chosen parameters it is aliased with. Nothing is absorbed
silently.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from platkit.calibrate.factors import column_factor
from platkit.calibrate.registration import digest, kept
from platkit.calibrate.solve import weighted_factor
from platkit.errors import NotIdentifiable
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.poses import PoseSet

#: a column keeping less than this fraction of its norm outside the chosen span is not identifiable
DEFAULT_REL_TOL = 1e-6
#: remaining components within this fraction of the largest are equal, and of them the first is taken:
#: far above their rounding (about 1e-15 of a column's norm, so under 1e-9 of a remainder that keeps
#: ``DEFAULT_REL_TOL`` of it), below the differences data make (docs/performance.md, the ninth pass)
TIE_REL_TOL = 1e-8


@dataclass
class HeldParameter:
    """A parameter the data cannot fix, held at its nominal value.

    ``combination``: the direction the data cannot see, as {parameter name: coefficient} in
    scaled units (this parameter 1.0, then the chosen ones it trades against, largest first).
    """

    name: str
    reason: str
    combination: dict[str, float] = field(default_factory=dict)
    remaining: float = 0.0  # fraction of the column's norm outside the chosen span
    #: GAUGE (no set of poses the stand can take fixes it: a symmetry, fixed by a convention),
    #: NOT_EXCITED (the stand's reach fixes it, these poses do not), or '' (not classified)
    kind: str = ""

    def to_dict(self) -> dict:
        out = {"name": self.name, "reason": self.reason, "remaining_fraction": float(self.remaining),
               "combination": {k: float(v) for k, v in self.combination.items()}}
        if self.kind:
            out["kind"] = self.kind
        return out


@dataclass
class Identifiability:
    """Result of :func:`select_identifiable`. Its figures, ``singular_values`` (of the scaled
    Jacobian of all candidate columns, descending) and ``condition_number`` (of the chosen columns,
    scaled), are computed from ``scaled`` when first read: the choice never reads them, nor do the
    gauge analysis and a model selection's scored candidates (:func:`platkit.calibrate.stages.scored_only`)."""

    chosen: list[int]  # column indices estimated, in the order chosen
    held: list[HeldParameter]
    names: list[str]
    scaled: np.ndarray = field(repr=False)  # the scaled Jacobian's R factor (or itself), which the choice was made on

    @cached_property
    def singular_values(self) -> np.ndarray:
        return singular_values(self.scaled) if self.scaled.shape[1] else np.zeros(0)

    @cached_property
    def condition_number(self) -> float:
        if not self.chosen:
            return float("nan")
        s_chosen = singular_values(self.scaled[:, self.chosen])
        return float(s_chosen[0] / s_chosen[-1]) if s_chosen[-1] > 0 else float("inf")

    def to_dict(self) -> dict:
        return {
            "n_candidates": len(self.names),
            "n_identifiable": len(self.chosen),
            "held_at_nominal": [h.to_dict() for h in self.held],
            "singular_values": [float(s) for s in self.singular_values],
            "condition_number": float(self.condition_number),
        }


def select_identifiable(J: np.ndarray, names: list[str], scale: np.ndarray, tiers: list[int],
                        rel_tol: float = DEFAULT_REL_TOL, max_terms: int = 6) -> Identifiability:
    """Choose the columns of ``J`` the data fixes.

    J: (n_obs, n) identification Jacobian in SI; names: n parameter names; scale: (n,) typical
    size of each parameter (SI); tiers: (n,) priority, lower first. Returns an
    :class:`Identifiability` whose ``chosen`` columns are linearly independent to ``rel_tol``.
    Each step takes, of the tier's columns whose component outside the chosen span is at least
    ``1 - TIE_REL_TOL`` times the largest, the one of lowest index: the columns of an exact gauge
    (equal but for rounding) are decided by their order, not by the last bits of their sums.
    """
    J = np.asarray(J, float)
    scale = np.asarray(scale, float)
    Js = _compress(J * scale[None, :])  # inner products, hence everything below, unchanged
    n = Js.shape[1]
    norms = np.linalg.norm(Js, axis=0)
    basis = np.empty((min(Js.shape), Js.shape[0]))  # orthonormal rows spanning the chosen columns, in order
    chosen: list[int] = []
    held: list[HeldParameter] = []
    tiers = np.asarray(tiers)
    for tier in sorted(set(tiers.tolist())):
        pending = [j for j in range(n) if tiers[j] == tier]
        # the remaining columns as the rows of one array, in pending's order, outside the basis so far
        rest = np.ascontiguousarray(Js[:, pending].T)
        if chosen:
            B = basis[:len(chosen)]
            rest -= (rest @ B.T) @ B
        while pending:
            size = np.sqrt(np.einsum("ij,ij->i", rest, rest))
            nrm = norms[pending]
            frac = np.divide(size, nrm, out=np.zeros_like(size), where=nrm > 0)
            # the first of the largest that keeps rel_tol of its norm
            fits = (size >= (1.0 - TIE_REL_TOL) * np.max(size)) & (frac >= rel_tol) & (size > 0)
            if not fits.any():
                break
            k = int(np.argmax(fits))
            best = pending[k]
            B = basis[:len(chosen)]
            v = rest[k] - B.T @ (B @ rest[k])  # a second time, for numerical orthogonality
            v /= np.linalg.norm(v)
            basis[len(chosen)] = v
            chosen.append(best)
            del pending[k]
            rest = np.delete(rest, k, axis=0)
            rest -= np.outer(rest @ v, v)
        if pending and chosen:
            C = Js[:, chosen]
            coefs = np.linalg.solve(C.T @ C, C.T @ Js[:, pending])  # (n_chosen, n_pending)
        for jj, j in enumerate(pending):
            remaining = float(np.linalg.norm(rest[jj]) / norms[j]) if norms[j] > 0 else 0.0
            if norms[j] == 0:
                reason = "the data do not depend on it at all"
                combo = {names[j]: 1.0}
            else:
                reason = "its effect on the markers is a combination of parameters estimated before it"
                coef = coefs[:, jj]
                order = np.argsort(-np.abs(coef))
                combo = {names[j]: 1.0}
                for k in order[:max_terms]:
                    if abs(coef[k]) >= 0.05 * max(1e-300, np.max(np.abs(coef))):
                        combo[names[chosen[k]]] = -float(coef[k])
            held.append(HeldParameter(names[j], reason, combo, remaining))
    return Identifiability(chosen, held, list(names), Js)


def singular_values(A: np.ndarray, blocked: bool = False) -> np.ndarray:
    """Singular values (descending) of a matrix: of its R factor (QR first, which is cheap for the
    tall identification Jacobians), to full relative accuracy. ``blocked``: the R factor by
    :func:`r_factor` (a third of the time for 10,000 poses; the same values to 1e-13 relative),
    for figures that are reported only: a choice of parameters made on them must not move with
    rounding (two columns a symmetry makes alike are told apart by it)."""
    A = np.asarray(A, float)
    if A.shape[0] > 2 * A.shape[1]:
        A = r_factor(A) if blocked else np.linalg.qr(A, mode="r")
    return np.linalg.svd(A, compute_uv=False)


#: rows per block of :func:`r_factor`: a block and its copies stay in the processor's cache
QR_BLOCK = 4096


def r_factor(A: np.ndarray) -> np.ndarray:
    """The R factor of A = QR (min(m, n), n), computed blockwise for a tall A (TSQR): the R of
    the stacked R factors of blocks of QR_BLOCK rows. Any R of A has the same column inner
    products (R^T R = A^T A), hence the same singular values, spans and pivoting; one LAPACK QR
    over the 150,000 rows of 10,000 poses streams every column through memory (0.16 s for 51
    columns), the blocks stay in the cache (0.06 s), agreeing to rounding (singular values to
    1e-13 relative; measured 2026-11-25)."""
    A = np.asarray(A, float)
    m, n = A.shape
    if m <= 2 * QR_BLOCK or n == 0:
        return np.linalg.qr(A, mode="r")
    blocks = [np.linalg.qr(A[k:k + QR_BLOCK], mode="r") for k in range(0, m, QR_BLOCK)]
    return np.linalg.qr(np.vstack(blocks), mode="r")


def null_space_combinations(J: np.ndarray, names: list[str], scale: np.ndarray, rel_tol: float = 1e-8,
                            max_terms: int = 8) -> list[dict[str, float]]:
    """The parameter combinations with (numerically) zero effect, by name, from the SVD.

    Returns one {name: coefficient} per null direction (scaled units, largest |coefficient|
    first, those under 5% of the largest left out).
    """
    Js = np.asarray(J, float) * np.asarray(scale, float)[None, :]
    _, s, Vt = np.linalg.svd(Js, full_matrices=True)
    s_full = np.zeros(Vt.shape[0])
    s_full[: len(s)] = s
    out = []
    top = s[0] if len(s) else 0.0
    for k in np.nonzero(s_full <= rel_tol * top)[0]:
        v = Vt[k]
        order = np.argsort(-np.abs(v))
        combo = {}
        for j in order[:max_terms]:
            if abs(v[j]) >= 0.05 * np.max(np.abs(v)):
                combo[names[j]] = float(v[j])
        out.append(combo)
    return out


# ---------------------------------------------------------------------------- gauge freedoms
#
# A direction of the unknowns that changes no marker is either a *gauge*, a symmetry of the stand
# and the measurement that no set of poses can break (shifting every marker by c and the mocap
# frame by -A R c when the moving part never turns; a common shift of a hexapod's base joints and
# the mocap frame), or a direction *these* poses fail to excite (the stand could turn about a
# second axis, and did not). The two are told apart on the stand's reference poses, the fixed set
# of random reachable poses `platkit plan` scores designs over: what is invisible there too is a
# gauge. Gauges are fixed by a stated convention and reported; an unexcited transform or marker is
# an error (nothing can be predicted without them), an unexcited stand parameter is held at
# nominal and reported.

GAUGE, NOT_EXCITED = "gauge", "not_excited"
#: a marker shift c is invisible when R_n c is the same at every pose: the singular values of the
#: stacked (R_n - R_0) below this are zero
ROTATION_FIXED_TOL = 1e-9
#: fewer reachable reference poses than this tell nothing about the stand's symmetries
MIN_REFERENCE_POSES = 10


def rotation_fixed_directions(R: np.ndarray) -> np.ndarray:
    """(3, k) orthonormal directions c of the moving frame with R_n c the same for every rotation
    R (N, 3, 3): all three when the moving part never turns, its axis when it turns about one."""
    R = np.asarray(R, float)
    if len(R) < 2:
        return np.eye(3)
    D = (R[1:] - R[0]).reshape(-1, 3)
    _, s, Vt = np.linalg.svd(D)
    s_full = np.zeros(3)
    s_full[: len(s)] = s
    return Vt[s_full <= ROTATION_FIXED_TOL].T


def _outside_span(A: np.ndarray, cols: list[int], js) -> np.ndarray:
    """Fraction of the norm of each column ``js`` of A outside the span of columns ``cols``."""
    V = A[:, list(js)]
    nv = np.linalg.norm(V, axis=0)
    if cols:
        Q, _ = np.linalg.qr(A[:, cols])
        V = V - Q @ (Q.T @ V)
    return np.where(nv > 0, np.linalg.norm(V, axis=0) / np.where(nv > 0, nv, 1.0), 0.0)


@dataclass
class Gauge:
    """The gauge analysis of one calibration problem (see :func:`nuisance_gauge`).

    held: indices into the problem's unknowns z of the transform and marker coordinates held as
    gauges; J_ref (n, n), n = len(ref_idx): the R factor of the scaled Jacobian over the reference
    poses of the unknowns ``ref_idx`` (every candidate that is not a model term); shift: (3, k) marker-shift directions
    of the moving frame (:func:`rotation_fixed_directions` of the reference poses)."""

    held: list[int]
    held_names: list[str]
    ref_idx: np.ndarray
    J_ref: np.ndarray
    tiers_ref: list[int]  # the tiers of ``ref_idx``, for rank_ref
    rel_tol: float
    shift: np.ndarray
    U_ref: np.ndarray  # (N, n_u) the reference poses' controls
    P_ref: np.ndarray  # (N, n_p) and poses
    conventions: list[str] = field(default_factory=list)
    n_gauge: int = 0
    n_not_excited: int = 0
    labels: dict[str, str] = field(default_factory=dict)
    unclassified: str = ""  # why nothing was classified (no reference poses), or ''

    @cached_property
    def rank_ref(self) -> int:
        """The rank of the reference poses' Jacobian J_ref (:func:`select_identifiable` at ``rel_tol``),
        computed when first read: only the classification of the held parameters reads it."""
        names = [str(i) for i in self.ref_idx]
        return len(select_identifiable(self.J_ref, names, np.ones(len(names)), self.tiers_ref, self.rel_tol).chosen)

    def to_dict(self) -> dict:
        if self.unclassified:
            return {"dimensions": None, "not_excited": None, "conventions": list(self.conventions)}
        return {"dimensions": int(self.n_gauge), "not_excited": int(self.n_not_excited),
                "conventions": list(self.conventions),
                "marker_shift_directions": [[float(x) for x in c] for c in self.shift.T],
                "held_during_the_fit": list(self.held_names),
                "decided_on": f"the stand's {len(self.U_ref)} reference poses, those `platkit plan` scores designs over"}


def _weighted_jacobian(problem, z, idx) -> np.ndarray:
    """Scaled Jacobian (rows, len(idx)) of the problem's seen observations, weighted as the fit; of
    a problem solved block by block (``row_block``), an R factor of it (the same column inner
    products, hence spans and pivoting, to rounding)."""
    if getattr(problem, "row_block", None) is not None:
        st = problem.evaluate(z, with_jac=False)
        used = (problem.base_weights > 0) & np.isfinite(st.r).all(axis=2)
        mask = np.zeros(problem.n_z, bool)
        mask[idx] = True
        order = np.argsort(np.argsort(idx))  # the factor's columns in idx's order
        return weighted_factor(problem, z, st, np.where(used, problem.base_weights, 0.0), mask)[:, order] \
            * problem.scale[idx][None, :]
    J = weighted_rows(problem, problem.evaluate(z), idx)
    J *= problem.scale[idx][None, :]  # scaled in place
    return J


def weighted_rows(problem, st, idx) -> np.ndarray:
    """The columns ``idx`` of the state ``st``'s Jacobian (rows, len(idx)), unscaled, at the
    observations seen and solved (base weight > 0, residual finite), each weighted as the fit (the
    square root of its base weight): np.take's copy weighted in place, every row kept where every
    point is used."""
    used = (problem.base_weights > 0) & np.isfinite(st.r).all(axis=2)
    J = np.take(st.J, idx, axis=-1)
    J *= np.sqrt(np.where(used, problem.base_weights, 0.0))[:, :, None, None]
    return J.reshape(-1, len(idx)) if used.all() else J[used].reshape(-1, len(idx))


def _compress(A: np.ndarray) -> np.ndarray:
    """The R factor of a tall A (:func:`column_factor`), A itself where it is not tall."""
    return column_factor(A) if A.shape[0] > A.shape[1] else A


_REFERENCE_PROBLEMS: dict = {}


def _reference_problem(problem, U_ref: np.ndarray):
    """A term-free problem of the same class over the reference controls, with the problem's
    markers and rigid bodies: their names (the unknowns are matched by name), links and count.
    Kept per stand object and per that marker set (a model selection fits one stand many times);
    a problem of the stand with other markers gets its own, never one built for other names."""
    poses = problem.poses
    key = (id(problem.spec), problem.M, tuple(poses.marker_names), tuple(poses.body_names),
           tuple(sorted(poses.marker_links.items())), poses.length_unit, type(problem),
           getattr(problem, "point_links", None))
    hit = _REFERENCE_PROBLEMS.get(key)
    if hit is not None and hit[0] is problem.spec and hit[1] is U_ref:
        return hit[2]
    B = problem.poses.n_bodies  # rigid bodies seen in every reference pose, at the identity orientation
    ref_poses = PoseSet(problem.spec.name, U_ref, np.zeros((len(U_ref), problem.M, 3)), list(problem.poses.marker_names),
                        length_unit=problem.poses.length_unit, source="the stand's reference poses",
                        bodies=np.tile([0.0, 0, 0, 1, 0, 0, 0], (len(U_ref), B, 1)),
                        body_names=list(problem.poses.body_names),
                        marker_links=dict(problem.poses.marker_links))  # on a tree, each marker on its link
    ref_problem = type(problem)(problem.spec, ref_poses)
    if len(_REFERENCE_PROBLEMS) > 16:
        _REFERENCE_PROBLEMS.clear()
    _REFERENCE_PROBLEMS[key] = (problem.spec, U_ref, ref_problem)
    return ref_problem


def problem_digest(problem, z) -> bytes | None:
    """A digest of everything an evaluation of ``problem`` at ``z`` reads (its stand and terms by
    identity, its poses, weights, scales, tiers and priors by value, z), for :func:`kept`; None for
    a stand solved by Newton's method, whose solutions start from the problem's last ones (its
    results are computed, never kept)."""
    spec, poses = problem.spec, problem.poses
    if spec.forward is None:
        return None
    bodies = poses.bodies if poses.bodies is not None else np.zeros(0)
    return digest(type(problem).__name__, id(spec), tuple(id(t) for t in problem.terms), poses.controls, poses.markers,
                  np.asarray(bodies, float), None if poses.n_samples is None else np.asarray(poses.n_samples, float),
                  None if poses.n_body_samples is None else np.asarray(poses.n_body_samples, float),
                  tuple(poses.marker_names), tuple(poses.body_names), tuple(sorted(poses.marker_links.items())),
                  poses.length_unit, problem.point_links, tuple(problem.names), problem.base_weights, problem.scale,
                  problem.tiers, problem.prior_center, problem.prior_scale, problem.nominal, problem.half_width,
                  float(problem.body_rho), problem.rho_source, getattr(problem, "row_block", None),
                  np.asarray(z, float))


def _kept_for(problem, key: bytes | None, kind: str, compute, copy):
    """:func:`kept` of ``compute`` under ``kind`` for ``key`` (its stand and terms held beside the
    result, so that their identities in the key stay theirs), or ``compute()`` where ``key`` is None."""
    if key is None:
        return compute()

    def compute_held():
        return problem.spec, tuple(problem.terms), compute()

    return kept(kind, key, compute_held, lambda got: (got[0], got[1], copy(got[2])))[2]


def _data_view(problem, z, nuis_idx: np.ndarray, rel_tol: float) -> list[int]:
    """The columns of ``nuis_idx`` (the transform and markers) the data of ``problem`` fix at
    ``z``, in the order chosen (:func:`select_identifiable` of their scaled weighted Jacobian)."""
    Jn = _compress(_weighted_jacobian(problem, z, nuis_idx))
    return list(select_identifiable(Jn, [problem.names[i] for i in nuis_idx], np.ones(len(nuis_idx)),
                                    [0] * len(nuis_idx), rel_tol).chosen)


def nuisance_gauge(problem, z, candidates: np.ndarray, nuisance: np.ndarray, reference: tuple[np.ndarray, np.ndarray],
                   rel_tol: float = DEFAULT_REL_TOL) -> Gauge:
    """Which transform and marker coordinates are gauges, at the start ``z`` of a calibration.

    problem: a :class:`~platkit.calibrate.problem.CalibrationProblem`; candidates, nuisance: (n_z,)
    masks of the unknowns the fit may estimate and of the transform and markers among them;
    reference: (controls (N, n_u), poses (N, n_p)) of the stand's reference poses
    (:func:`platkit.calibrate.plan.reference_poses_for`). The Jacobian over the reference poses
    comes from a term-free problem of the same class and stand. Raises NotIdentifiable naming
    the transform or marker coordinates these poses fail to fix where the reference poses fix them.
    """
    names = problem.names
    z = np.asarray(z, float)
    U_ref, P_ref = reference
    # the reference problem knows the stand, the transform and the markers (no model terms, nor
    # anything else a session may add): unknowns are matched by name
    idx_of = {n: i for i, n in enumerate(names)}
    lacking = len(U_ref) < MIN_REFERENCE_POSES
    if not lacking:
        ref_problem = _reference_problem(problem, U_ref)
        at = {n: k for k, n in enumerate(ref_problem.names)}
        z_ref = np.zeros(ref_problem.n_z)
        for n, k in at.items():
            if n in idx_of:
                z_ref[k] = z[idx_of[n]]
        st = ref_problem.evaluate(z_ref)
        if getattr(problem, "row_block", None) is not None:  # bounded memory: the reference problem, kept
            ref_problem.forget()  # per stand, keeps no Jacobian after this
        lacking = st.converged.sum() < MIN_REFERENCE_POSES
    if lacking:
        # nothing to tell a gauge from a gap in the plan: every direction the data cannot fix is
        # judged as before (transform and markers: an error; stand parameters: held, unclassified)
        at, st = idx_of, problem.evaluate(z)
    ref_idx = np.array([i for i in np.nonzero(candidates)[0] if names[i] in at], int)
    cols = [at[names[i]] for i in ref_idx]
    J_ref = _compress(st.J[st.converged][..., cols].reshape(-1, len(cols)) * problem.scale[ref_idx][None, :])
    tiers_ref = problem.tiers[ref_idx].tolist()
    if len(U_ref):
        q_ref, _, _, ok = problem.kinematics(z[problem.i_td], U_ref, P_ref)
        R = matrix_from_quat(q_ref[ok])
    else:
        R = np.zeros((0, 3, 3))
    shift = rotation_fixed_directions(R)
    # the data's own view of the transform and markers: the same for every candidate set of a
    # selection (kept while it runs)
    nuis_idx = np.nonzero(nuisance)[0]
    key = problem_digest(problem, z)
    chosen = set(_kept_for(problem, None if key is None else digest(key, nuis_idx, rel_tol), "gauge_data",
                           lambda: _data_view(problem, z, nuis_idx, rel_tol), list))
    pos = {int(i): k for k, i in enumerate(ref_idx)}
    known = [k for k, i in enumerate(nuis_idx) if int(i) in pos]  # judged on the reference poses
    Jr = J_ref[:, [pos[int(nuis_idx[k])] for k in known]]
    chosen_known = [j for j, k in enumerate(known) if k in chosen]
    unchosen_known = [j for j, k in enumerate(known) if k not in chosen]
    outside = _outside_span(Jr, chosen_known, unchosen_known) if unchosen_known else np.zeros(0)
    lost = [nuis_idx[known[j]] for j, f in zip(unchosen_known, outside) if f >= rel_tol]
    lost += [nuis_idx[k] for k in range(len(nuis_idx)) if k not in chosen and int(nuis_idx[k]) not in pos]
    n_gauge_nuis = len(known) - len(select_identifiable(Jr, [names[nuis_idx[k]] for k in known], np.ones(len(known)),
                                                        [0] * len(known), rel_tol).chosen)
    if lacking and unchosen_known:
        lost = [nuis_idx[k] for k in unchosen_known] + lost
    if lost or len(unchosen_known) > n_gauge_nuis:
        what = lost or [nuis_idx[k] for k in range(len(nuis_idx)) if k not in chosen]
        raise NotIdentifiable(
            f"the poses cannot fix {', '.join(names[i] for i in what)}: the stand's reach would, these poses do not "
            "(turn or move the platform more, and see each marker in several poses)")
    held = [int(nuis_idx[k]) for k in range(len(nuis_idx)) if k not in chosen]
    gauge = Gauge(held, [names[i] for i in held], ref_idx, J_ref, tiers_ref, rel_tol, shift, U_ref, P_ref)
    if lacking:
        gauge.unclassified = (f"fewer than {MIN_REFERENCE_POSES} of the stand's random reference commands are "
                              "reachable: what the data cannot fix is held, not classified as gauge or not excited")
    return gauge


def classify_held(ident: Identifiability, gauge: Gauge, cand_idx: np.ndarray, problem, rel_tol: float = DEFAULT_REL_TOL) -> None:
    """Label each held parameter of ``ident`` (chosen over ``cand_idx``, the gauge-held transform
    and markers left out: they are no parameter held at nominal, the convention places them) GAUGE
    or NOT_EXCITED, count the gauge and unexcited directions and state the conventions in
    ``gauge``. Model terms are not judged (the reference poses carry none)."""
    if gauge.unclassified:
        gauge.conventions.append(gauge.unclassified)
        return
    pos = {int(i): k for k, i in enumerate(gauge.ref_idx)}
    chosen_ref = [pos[int(cand_idx[k])] for k in ident.chosen if int(cand_idx[k]) in pos]
    by_name = {problem.names[i]: i for i in cand_idx}
    td_gauge, td_unexcited = [], []
    judged = [h for h in ident.held if h.name in by_name and int(by_name[h.name]) in pos]
    outside = _outside_span(gauge.J_ref, chosen_ref, [pos[int(by_name[h.name])] for h in judged]) if judged else []
    for h, frac in zip(judged, outside):
        if frac < rel_tol and not np.any(gauge.J_ref[:, pos[int(by_name[h.name])]]):
            h.kind = GAUGE  # no marker depends on it at any pose: nothing tracked hangs on it
            h.reason += ("; no marker moves with it at any pose the stand can take (a part of the stand no tracked "
                         "link or marker hangs on): held at nominal")
            td_gauge.append(h.name)
        elif frac < rel_tol:
            h.kind = GAUGE
            h.reason += "; no set of poses the stand can take fixes it (a symmetry): held at nominal by convention"
            td_gauge.append(h.name)
        else:
            h.kind = NOT_EXCITED
            h.reason += "; the stand's reach would fix it, these poses do not excite it: held at nominal"
            td_unexcited.append(h.name)
    n_nonterm_chosen = len(chosen_ref)
    gauge.n_gauge = len(gauge.ref_idx) - gauge.rank_ref
    gauge.n_not_excited = max(0, gauge.rank_ref - n_nonterm_chosen)
    gauge.labels = {h.name: h.kind for h in ident.held if h.kind}
    k = gauge.shift.shape[1]
    if gauge.held:
        if k == 3:
            gauge.conventions.append(
                "the moving part never turns: a common shift c of every marker and the shift -A R c of the motion-capture "
                "frame change nothing; the markers' centroid is put at the moving frame's origin")
        elif k == 1:
            axis = ", ".join(f"{x:+.4f}" for x in gauge.shift[:, 0])
            gauge.conventions.append(
                f"the moving part turns about one axis only ({axis} in the moving frame): a common shift of every marker "
                "along it and the opposite shift of the motion-capture frame change nothing; the markers' centroid is "
                "put in the plane through the moving frame's origin normal to that axis")
        rest = len(gauge.held) - k
        if rest > 0:
            gauge.conventions.append(
                f"{rest} more direction(s) of the transform and markers no pose can fix (a turn of the motion-capture "
                "frame with the markers about the only axis the stand turns about, or a plane it moves in): "
                f"{', '.join(gauge.held_names)} held at the initial rigid registration, the others measured against them")
    if td_gauge:
        gauge.conventions.append(f"stand parameters no pose can fix (a symmetry, or no marker moves with them) held at "
                                 f"nominal: {', '.join(td_gauge)}")


def apply_marker_convention(problem, z, gauge: Gauge) -> tuple[np.ndarray, np.ndarray]:
    """Move ``z`` along the marker-shift gauge so that the markers' centroid has no component
    along ``gauge.shift`` (the stated convention). Returns (z', T) with z' = T z near z (T (n_z,
    n_z), linear: for the covariance, cov' = T cov T^T). A no-op (T = I) when there is no shift
    gauge, or when the shift would change a prediction (model terms that turn the moving frame)."""
    z = np.asarray(z, float)
    n_z, M = problem.n_z, problem.M
    T = np.eye(n_z)
    if not gauge.held or M == 0:
        return z, T
    # the moving frame's turns under the fitted td (its origin errors turn the fixed axis too)
    q, _, _, ok = problem.kinematics(z[problem.i_td], gauge.U_ref, gauge.P_ref)
    R = matrix_from_quat(q[ok])
    C = gauge.shift = rotation_fixed_directions(R)
    if C.shape[1] == 0 or len(R) == 0:
        return z, T
    A = matrix_from_rotvec(z[problem.i_w])
    G = np.zeros((n_z, C.shape[1]))
    G[problem.i_m] = np.tile(C, (M, 1))
    G[problem.i_t] = -(A @ R[0] @ C)
    K = np.zeros((C.shape[1], n_z))
    K[:, problem.i_m] = -np.tile(C.T, (1, M)) / M
    T = T + G @ K
    z_new = z + G @ (K @ z)
    before = problem.evaluate(z, with_jac=False).r
    after = problem.evaluate(z_new, with_jac=False).r
    change = np.nanmax(np.abs(after - before)) if np.isfinite(before).any() else 0.0
    if not change <= 1e-9 * max(1.0, float(np.nanmax(np.abs(problem.poses.markers)))):
        return z, np.eye(n_z)
    return z_new, T


#: a marker left with fewer kept observations than this by a robust fit's outlier rejection
MIN_KEPT_PER_MARKER = 6


def keep_one_side_of_a_lost_marker(kept: np.ndarray, residuals: np.ndarray, problem=None, z=None,
                                   min_kept: int = MIN_KEPT_PER_MARKER) -> tuple[np.ndarray, list[int]]:
    """A robust fit rejects every observation of a marker that sits in two places (a marker that
    slipped on the moving part: the fit places it between, and both halves are outliers); a fit
    on the kept observations alone then has nothing to fix that marker with. Such a marker's
    observations before or after its step are kept, whichever side is longer: its place there is
    consistent and the poses fix it (a diagnosis names the slip).

    kept: (N, C) observations the fit kept (channels: the M markers first); residuals: (N, M, 3)
    its residuals, poses in session order; problem, z: the fit's problem and unknowns, to turn the
    residuals into the moving frame, where a slip is a step (in the motion capture's frame it
    turns with the platform). Returns (kept with those sides restored, the marker indices
    restored)."""
    kept = np.array(kept, bool, copy=True)
    if problem is not None and z is not None:
        td, w = problem.split(z)[:2]
        R = matrix_from_quat(problem.kinematics(td, problem.poses.controls)[0])  # (N, 3, 3) moving -> base
        residuals = np.einsum("nji,kj,nmk->nmi", R, matrix_from_rotvec(w), residuals)
    restored = []
    for m in range(residuals.shape[1]):
        seen = np.nonzero(np.all(np.isfinite(residuals[:, m]), axis=1))[0]
        if kept[:, m].sum() >= min_kept or len(seen) < 2 * min_kept:
            continue
        x = residuals[seen, m] - residuals[seen, m].mean(axis=0)
        n = len(x)
        j = np.arange(min_kept, n - min_kept + 1)
        csum = np.cumsum(x, axis=0)
        k = int(j[np.argmax(np.sum(csum[j - 1] ** 2, axis=1) * n / (j * (n - j)))])  # the step's split
        side = seen[:k] if k >= n - k else seen[k:]
        kept[side, m] = True
        restored.append(m)
    return kept, restored
