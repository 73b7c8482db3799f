"""Generic kinematics of any registered stand, derived from its CasADi residual.

Forward kinematics solves F(u, td, pose(p)) = 0 for the pose coordinates p by Newton's method
(Gauss-Newton where the stand has more equations than coordinates); inverse kinematics uses the
stand's closed form where it has one, else Gauss-Newton over u.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import casadi as ca
import numpy as np

from platkit.errors import BadInput, NoConvergence, OutOfWorkspace, WrongBranch
from platkit.geometry import matrix_from_quat, quat_normalize, rpy_from_quat
from platkit.model import PlatformSpec

#: Newton steps unrolled into one CasADi call; more are taken one at a time if needed.
UNROLLED_STEPS = 6


@dataclass
class ForwardResult:
    """One forward-kinematics solution. Lengths in metres, angles in radians."""

    p: np.ndarray  # (n_p,) pose coordinates
    q: np.ndarray  # (4,) orientation, w x y z
    X: np.ndarray  # (3,) position, m
    iterations: int
    residual: float  # final |F|
    on_branch: bool

    @property
    def rpy(self) -> np.ndarray:
        return rpy_from_quat(self.q)

    @property
    def R(self) -> np.ndarray:
        return matrix_from_quat(self.q)


@dataclass
class ForwardBatch:
    """Batched forward kinematics. Arrays have a leading axis N."""

    p: np.ndarray  # (N, n_p)
    q: np.ndarray  # (N, 4)
    X: np.ndarray  # (N, 3)
    iterations: np.ndarray  # (N,)
    residual: np.ndarray  # (N,)
    converged: np.ndarray  # (N,) bool
    on_branch: np.ndarray  # (N,) bool


class PlatformModel:
    """Numeric solvers for one stand; all Jacobians come from the stand's CasADi functions."""

    def __init__(self, spec: PlatformSpec, tol: float = 1e-10, max_iter: int = 30):
        self.spec = spec
        self.tol = tol
        self.max_iter = max_iter
        u = ca.SX.sym("u", spec.n_u)
        td = ca.SX.sym("td", spec.n_td)
        p = ca.SX.sym("p", spec.n_p)
        q, X = spec.pose(p)
        r = spec.residual(u, td, q, X)
        self.n_r = r.shape[0]
        Jp = ca.jacobian(r, p)
        self.F = ca.Function("F", [u, td, p], [r], ["u", "td", "p"], ["r"])
        self.F_jac = ca.Function(
            "F_jac", [u, td, p], [r, Jp, ca.jacobian(r, u), ca.jacobian(r, td)],
            ["u", "td", "p"], ["r", "F_p", "F_u", "F_td"],
        )
        self.pose_fn = spec.pose
        # Newton steps, unrolled: p_{k+1} = p_k - J^-1 r (least squares if n_r > n_p).
        p_k = p
        norms = []
        for _ in range(UNROLLED_STEPS):
            qk, Xk = spec.pose(p_k)
            rk = spec.residual(u, td, qk, Xk)
            Jk = ca.substitute(Jp, p, p_k)
            norms.append(ca.norm_2(rk))
            if self.n_r == spec.n_p:
                step = ca.solve(Jk, rk)
            else:
                step = ca.solve(ca.mtimes(Jk.T, Jk), ca.mtimes(Jk.T, rk))
            p_k = p_k - step
        qk, Xk = spec.pose(p_k)
        norms.append(ca.norm_2(spec.residual(u, td, qk, Xk)))
        self._newton = ca.Function("newton", [u, td, p], [p_k, ca.vertcat(*norms)], ["u", "td", "p0"], ["p", "norms"])
        self._branch = spec.branch
        self._td0 = spec.nominal_td()
        self._p0 = spec.neutral_p()

    # ------------------------------------------------------------------ helpers
    def _td(self, td) -> np.ndarray:
        return self._td0 if td is None else np.asarray(td, float)

    def check_controls(self, u, strict: bool = True) -> np.ndarray:
        """Controls as an array (n_u,) or (N, n_u); BadInput for a wrong length, OutOfWorkspace
        (strict) for a value outside its stroke."""
        u = np.asarray(u, float)
        if u.shape[-1:] != (self.spec.n_u,):
            raise BadInput(
                f"{self.spec.name} takes {self.spec.n_u} controls ({', '.join(self.spec.control_names)}), got {u.shape[-1] if u.ndim else 1}"
            )
        if not np.all(np.isfinite(u)):
            raise BadInput(f"{self.spec.name}: controls must be finite numbers")
        if strict:
            lo, hi = self.spec.control_bounds()
            bad = (u < lo - 1e-12) | (u > hi + 1e-12)
            if np.any(bad):
                idx = np.argwhere(bad)[0]
                i = idx[-1]
                c = self.spec.controls[i]
                val = u[tuple(idx)]
                raise OutOfWorkspace(
                    f"control {c.name} = {val:.6g} {c.unit} is outside its range [{c.lower:.6g}, {c.upper:.6g}] {c.unit}"
                )
        return u

    def pose(self, p) -> tuple[np.ndarray, np.ndarray]:
        q, X = self.pose_fn(np.asarray(p, float))
        return quat_normalize(np.asarray(q).ravel()), np.asarray(X).ravel()

    def on_branch(self, u, td, q, X) -> bool:
        if self._branch is None:
            return True
        g = np.asarray(self._branch(u, self._td(td), q, X)).ravel()
        return bool(np.all(g > 0))

    def residual(self, u, p, td=None) -> np.ndarray:
        return np.asarray(self.F(np.asarray(u, float), self._td(td), np.asarray(p, float))).ravel()

    # ------------------------------------------------------------------ forward
    def forward(self, u, td=None, guess=None, strict: bool = True, allow_mirror: bool = False) -> ForwardResult:
        """Pose from controls. ``guess``: starting p (default: the neutral pose).

        Raises NoConvergence, OutOfWorkspace (controls outside their stroke, when ``strict``) or
        WrongBranch (converged to a mirror pose the stand cannot take; pass ``allow_mirror`` to
        get it flagged instead).
        """
        u = self.check_controls(u, strict=strict)
        td = self._td(td)
        if self.spec.forward is not None:
            q, X = self.spec.forward(u, td)
            q = quat_normalize(np.asarray(q).ravel())
            X = np.asarray(X).ravel()
            p = self.coordinates(q, X) if self.spec.coordinates_from_pose is not None else np.full(self.spec.n_p, np.nan)
            return ForwardResult(p, q, X, 0, 0.0, True)
        p0 = self._p0 if guess is None else np.asarray(guess, float)
        p_out, norms = self._newton(u, td, p0)
        norms = np.asarray(norms).ravel()
        p = np.asarray(p_out).ravel()
        hit = np.nonzero(norms <= self.tol)[0]
        if hit.size:
            iterations = int(hit[0])
            if iterations < UNROLLED_STEPS:
                # the unrolled chain took extra steps past convergence; they are harmless
                # (a Newton step at a root is ~0), so keep the final iterate.
                pass
            residual = float(norms[-1])
        else:
            iterations = UNROLLED_STEPS
            residual = float(norms[-1])
            while residual > self.tol and iterations < self.max_iter and np.isfinite(residual):
                r, Jp, _, _ = self.F_jac(u, td, p)
                r = np.asarray(r).ravel()
                Jp = np.asarray(Jp)
                step = np.linalg.lstsq(Jp, r, rcond=None)[0]
                p = p - step
                iterations += 1
                residual = float(np.linalg.norm(self.residual(u, p, td)))
            if not (residual <= self.tol):
                raise NoConvergence(
                    f"{self.spec.name} forward kinematics", iterations, residual,
                    "the controls may have no assembly, or the start is too far; try another --guess",
                )
        q, X = self.pose(p)
        branch = self.on_branch(u, td, q, X)
        if not branch and not allow_mirror:
            raise WrongBranch(
                f"{self.spec.name} forward kinematics converged to a mirror pose the stand cannot take "
                f"(position {np.round(X * 1000, 1).tolist()} mm); start from a guess on the stand's side"
            )
        return ForwardResult(p, q, X, iterations, residual, branch)

    @functools.cached_property
    def _newton_map_cache(self) -> dict:
        return {}

    def forward_batch(self, U, td=None, guess=None, strict: bool = True) -> ForwardBatch:
        """Forward kinematics of many control vectors. ``U``: (N, n_u) -> ForwardBatch (N, ...).

        Poses that do not converge are flagged (``converged`` False), not raised.
        """
        U = self.check_controls(np.atleast_2d(U), strict=strict)
        N = U.shape[0]
        td = self._td(td)
        if self.spec.forward is not None:
            fmap = self.spec.forward.map(N)
            q, X = fmap(U.T, np.repeat(td[:, None], N, axis=1))
            q = quat_normalize(np.asarray(q).T)
            X = np.asarray(X).T
            p = np.full((N, self.spec.n_p), np.nan)
            if self.spec.coordinates_from_pose is not None:
                p = np.asarray(self.spec.coordinates_from_pose.map(N)(q.T, X.T)).T
            ones = np.ones(N, bool)
            return ForwardBatch(p, q, X, np.zeros(N, int), np.zeros(N), ones, ones)
        P0 = np.broadcast_to(self._p0 if guess is None else np.asarray(guess, float), (N, self.spec.n_p))
        newton_map = self._newton_map_cache.get(N)
        if newton_map is None:
            newton_map = self._newton.map(N)
            self._newton_map_cache[N] = newton_map
        P, norms = newton_map(U.T, td, P0.T)
        P = np.asarray(P).T
        norms = np.asarray(norms).T  # (N, steps+1)
        ok = norms <= self.tol
        iterations = np.where(ok.any(axis=1), ok.argmax(axis=1), UNROLLED_STEPS)
        residual = norms[:, -1].copy()
        converged = residual <= self.tol
        for i in np.nonzero(~converged)[0]:
            try:
                res = self.forward(U[i], td, guess=P[i], strict=False, allow_mirror=True)
            except NoConvergence:
                continue
            P[i] = res.p
            iterations[i] = UNROLLED_STEPS + res.iterations
            residual[i] = res.residual
            converged[i] = True
        q, X = self.pose_fn.map(N)(P.T)
        q = quat_normalize(np.asarray(q).T)
        X = np.asarray(X).T
        if self._branch is not None:
            g = np.asarray(self._branch.map(N)(U.T, td, q.T, X.T)).T
            on_branch = np.all(g > 0, axis=1)
        else:
            on_branch = np.ones(N, bool)
        return ForwardBatch(P, q, X, iterations, residual, converged, on_branch)

    # ------------------------------------------------------------------ inverse
    def coordinates(self, q, X) -> np.ndarray:
        """Pose coordinates p of a pose (q, X); needs the stand's coordinates_from_pose."""
        if self.spec.coordinates_from_pose is None:
            raise BadInput(f"stand {self.spec.name!r} cannot convert a pose to its coordinates")
        return np.asarray(self.spec.coordinates_from_pose(quat_normalize(np.asarray(q, float)), np.asarray(X, float))).ravel()

    def inverse(self, q, X, td=None, strict: bool = True, guess=None) -> np.ndarray:
        """Controls (n_u,) that put the moving frame at (q, X).

        Raises OutOfWorkspace when the pose cannot be reached (no real solution, or controls
        outside their stroke when ``strict``), NoConvergence when the iterative route fails.
        """
        td = self._td(td)
        q = quat_normalize(np.asarray(q, float))
        X = np.asarray(X, float)
        if self.spec.inverse is not None:
            u = np.asarray(self.spec.inverse(td, q, X)).ravel()
            if not np.all(np.isfinite(u)):
                raise OutOfWorkspace(f"{self.spec.name}: the pose {np.round(X * 1000, 1).tolist()} mm has no real inverse solution")
        else:
            u = self._inverse_newton(q, X, td, guess)
        r = np.asarray(self.spec.residual(u, td, q, X)).ravel()
        if np.linalg.norm(r) > 1e-6:
            raise OutOfWorkspace(
                f"{self.spec.name}: the pose cannot be reached (constraint residual {np.linalg.norm(r):.3g} after solving)"
            )
        if strict:
            self.check_controls(u, strict=True)
        return u

    @functools.cached_property
    def _ik_functions(self):
        u = ca.SX.sym("u", self.spec.n_u)
        td = ca.SX.sym("td", self.spec.n_td)
        q = ca.SX.sym("q", 4)
        X = ca.SX.sym("X", 3)
        r = self.spec.residual(u, td, q, X)
        return ca.Function("ik_step", [u, td, q, X], [r, ca.jacobian(r, u)])

    def _inverse_newton(self, q, X, td, guess) -> np.ndarray:
        u = self.spec.neutral_u() if guess is None else np.asarray(guess, float)
        lam = 1e-9
        for it in range(100):
            r, J = self._ik_functions(u, td, q, X)
            r = np.asarray(r).ravel()
            J = np.asarray(J)
            if np.linalg.norm(r) <= self.tol:
                return u
            A = J.T @ J + lam * np.eye(len(u))
            u = u - np.linalg.solve(A, J.T @ r)
        raise NoConvergence(f"{self.spec.name} inverse kinematics", 100, float(np.linalg.norm(r)), "the pose may be unreachable")
