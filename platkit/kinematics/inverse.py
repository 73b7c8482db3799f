"""Inverse kinematics: the controls that put the moving frame at a pose; the stand's closed form
where it has one, else Gauss-Newton over u, and bounded least squares to stay inside the strokes."""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from platkit.errors import NoConvergence, OutOfWorkspace
from platkit.geometry import quat_normalize
from platkit.kinematics.core import ModelCore


class InverseSolver(ModelCore):
    """Controls from a pose (q, X)."""

    def inverse(self, q, X, td=None, strict: bool = True, guess=None) -> np.ndarray:
        """Controls (n_u,) that put the moving frame at (q, X).

        Raises OutOfWorkspace when the pose cannot be reached (no real solution, or controls
        outside their stroke when ``strict``), NoConvergence when the iterative route fails.
        With ``strict``, a stand without a closed-form inverse (a redundant chain) whose Newton
        solution leaves the strokes is solved again by bounded least squares, so a solution
        inside the strokes is found where one exists.
        """
        td = self._td(td)
        q = quat_normalize(np.asarray(q, float))
        X = np.asarray(X, float)
        where = f"the pose at ({', '.join(f'{v / self._display_scale:.1f}' for v in X)}) {self.length_unit}"
        if self.spec.inverse is not None:
            u = np.asarray(self.spec.inverse(td, q, X)).ravel()
            if not np.all(np.isfinite(u)):
                raise OutOfWorkspace(f"{self.spec.name}: {where} has no real inverse solution")
        else:
            try:
                u = self._inverse_newton(q, X, td, guess)
            except NoConvergence:
                if not strict:
                    raise
                u = self._inverse_in_strokes(q, X, td, guess)
                if u is None:
                    raise
            if strict and np.any((u < self._lo_tol) | (u > self._hi_tol)):
                # a redundant chain (or a revolute joint a turn away) has other solutions: look
                # for one inside the strokes before calling the pose out of reach
                inside = self._inverse_in_strokes(q, X, td, guess, u)
                if inside is not None:
                    u = inside
        r = np.asarray(self.spec.residual(u, td, q, X)).ravel()
        if np.linalg.norm(r) > 1e-6:
            raise OutOfWorkspace(
                f"{self.spec.name}: {where} cannot be reached (constraint residual {np.linalg.norm(r):.3g} after solving)"
            )
        if strict:
            bad = np.nonzero((u < self._lo_tol) | (u > self._hi_tol))[0]
            if bad.size:
                c = self.spec.controls[int(bad[0])]
                val, unit = self._show(float(u[bad[0]]), c.unit)
                lo, _ = self._show(c.lower, c.unit)
                hi, _ = self._show(c.upper, c.unit)
                raise OutOfWorkspace(
                    f"{self.spec.name}: {where} is out of reach: control {c.name} would be {val:.6g} {unit}, "
                    f"outside its stroke [{lo:.6g}, {hi:.6g}] {unit}"
                    + (f" ({bad.size} controls out)" if bad.size > 1 else "")
                )
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
        for _ in range(100):
            r, J = self._ik_functions(u, td, q, X)
            r = np.asarray(r).ravel()
            J = np.asarray(J)
            if np.linalg.norm(r) <= self.tol:
                return u
            A = J.T @ J + lam * np.eye(len(u))
            u = u - np.linalg.solve(A, J.T @ r)
        raise NoConvergence(f"{self.spec.name} inverse kinematics", 100, float(np.linalg.norm(r)), "the pose may be unreachable")

    def _inverse_in_strokes(self, q, X, td, guess, u_free=None) -> np.ndarray | None:
        """Controls inside the strokes that solve the residual at (q, X), or None: bounded least
        squares (trust-region reflective) from the neutral controls, the guess, the middle of the
        strokes and the unconstrained solution pulled into them."""
        from scipy.optimize import least_squares

        lo, hi = self._lo, self._hi
        span = np.where(np.isfinite(hi - lo), hi - lo, 2.0)
        inner_lo = np.where(np.isfinite(lo), lo + 1e-9 * span, -np.inf)
        inner_hi = np.where(np.isfinite(hi), hi - 1e-9 * span, np.inf)
        starts = [self.spec.neutral_u()]
        if guess is not None:
            starts.append(np.asarray(guess, float))
        starts.append(np.where(np.isfinite(lo) & np.isfinite(hi), 0.5 * (lo + hi), self.spec.neutral_u()))
        if u_free is not None:
            starts.append(np.asarray(u_free, float))

        def fun(u):
            return np.asarray(self._ik_functions(u, td, q, X)[0]).ravel()

        def jac(u):
            return np.asarray(self._ik_functions(u, td, q, X)[1])

        for u0 in starts:
            u0 = np.clip(u0, inner_lo, inner_hi)
            sol = least_squares(fun, u0, jac=jac, bounds=(lo, hi), method="trf",
                                xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
            u = np.clip(sol.x, lo, hi)
            if np.linalg.norm(fun(u)) <= max(self.tol, 1e-9):
                return u
        return None
