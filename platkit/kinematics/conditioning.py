"""How far a pose is from a forward singularity: the scaled velocity Jacobian, its singular values,
the characteristic length that makes angles and lengths comparable."""
from __future__ import annotations

import functools

import numpy as np

from platkit.kinematics.rates import RateSolver
from platkit.kinematics.results import Conditioning


class SingularityAnalysis(RateSolver):
    """Velocity Jacobian, condition numbers and distance to the nearest forward singularity."""

    @property
    def uses_twist(self) -> bool:
        """Conditioning uses the twist (v, omega) for six-coordinate stands, else p'."""
        return self.spec.n_p == 6

    def _angular_columns(self) -> np.ndarray:
        if self.uses_twist:
            return np.array([False] * 3 + [True] * 3)
        return np.array([c.unit == "rad" for c in self.spec.coordinates])

    def velocity_jacobian(self, p, td=None, u=None) -> np.ndarray:
        """Inverse velocity Jacobian J (n_u, 6 or n_p): u' = J t, t = (v, omega) for six-
        coordinate stands (base frame), else t = p'."""
        td = self._td(td)
        p = np.asarray(p, float)
        u = self._controls_at(p, td, u)
        if self.uses_twist:
            q, X = self.pose(p)
            F_u, F_t, _ = (np.asarray(a) for a in self._twist_fn(u, td, q, X, np.zeros(self.spec.n_u), np.zeros(3), np.zeros(3)))
        else:
            F_u, F_t, _ = (np.asarray(a) for a in self._rate_fn(u, td, p, np.zeros(self.spec.n_u), np.zeros(self.spec.n_p)))
        return -self._lstsq(F_u, F_t)

    @functools.cached_property
    def characteristic_length(self) -> float:
        """Length (m) that makes angular and linear motion comparable: the one minimising the
        condition number of the velocity Jacobian at the neutral pose (1 if there is no angle)."""
        ang = self._angular_columns()
        if not ang.any() or ang.all():
            return 1.0
        from scipy.optimize import minimize_scalar

        J = self.velocity_jacobian(self._p0, u=self.spec.neutral_u())

        def cond(log_L):
            s = np.linalg.svd(J * np.where(ang, 1.0 / np.exp(log_L), 1.0), compute_uv=False)
            return s[0] / s[-1] if s[-1] > 0 else np.inf

        res = minimize_scalar(cond, bounds=(np.log(1e-3), np.log(1e3)), method="bounded", options={"xatol": 1e-4})
        return float(np.exp(res.x))

    def _scaled_svd(self, p, td, u):
        J = self.velocity_jacobian(p, td, u)
        L = self.characteristic_length
        Js = J * np.where(self._angular_columns(), 1.0 / L, 1.0)
        _, s, Vt = np.linalg.svd(Js)
        return s, Vt

    def conditioning(self, p, td=None, u=None) -> Conditioning:
        """Condition number, smallest singular value and distance to the nearest forward
        singularity at pose coordinates p (n_p,)."""
        td = self._td(td)
        p = np.asarray(p, float)
        u = self._controls_at(p, td, u)
        s, Vt = self._scaled_svd(p, td, u)
        smin, smax = float(s[-1]), float(s[0])
        # first-order distance: sigma_min / |grad sigma_min| over the scaled pose coordinates
        L = self.characteristic_length
        scale = np.array([L if c.unit == "rad" else 1.0 for c in self.spec.coordinates])
        grad = np.zeros(self.spec.n_p)
        h = 1e-6
        for k in range(self.spec.n_p):
            dp = np.zeros(self.spec.n_p)
            dp[k] = h / scale[k]
            vals = []
            for sgn in (1.0, -1.0):
                pk = p + sgn * dp
                try:
                    uk = self._controls_at(pk, td, None)
                except Exception:  # noqa: BLE001 - a step off the stand's domain: one-sided below
                    vals.append(np.nan)
                    continue
                vals.append(self._scaled_svd(pk, td, uk)[0][-1])
            grad[k] = (vals[0] - vals[1]) / (2 * h)
        g = float(np.linalg.norm(grad)) if np.all(np.isfinite(grad)) else np.nan
        dist = smin / g if g and np.isfinite(g) and g > 0 else np.inf
        return Conditioning(smax / smin if smin > 0 else np.inf, smin, smax, smin / smax if smax > 0 else 0.0,
                            float(dist), L, Vt[-1])

    def near_singular(self, P, td=None, threshold: float = 0.05) -> np.ndarray:
        """Indices of the poses P (N, n_p) whose inverse condition number is below ``threshold``."""
        td = self._td(td)
        out = []
        for i, p in enumerate(np.atleast_2d(P)):
            s, _ = self._scaled_svd(p, td, None)
            if not s[-1] / s[0] >= threshold:
                out.append(i)
        return np.array(out, dtype=int)

    def inverse_condition_numbers(self, P, td=None, U=None) -> np.ndarray:
        """sigma_min / sigma_max of the scaled velocity Jacobian at each pose P (N, n_p)."""
        td = self._td(td)
        P = np.atleast_2d(P)
        out = np.empty(len(P))
        for i, p in enumerate(P):
            s, _ = self._scaled_svd(p, td, None if U is None else U[i])
            out[i] = s[-1] / s[0] if s[0] > 0 else 0.0
        return out
