"""Velocities and accelerations, from differentiating the constraint along a motion:

    G_u u' + G_p p' = 0                                  (first order)
    G_u u'' + G_p p'' + c(u, p; u', p') = 0              (second order)

where ``c = w'^T (d2G/dw2) w'`` with ``w = (u, p)`` is CasADi's ``jtimes`` applied twice. The
twist form replaces p' by the twist (v, omega) of the moving frame in the base frame (v: velocity
of its origin, omega: angular velocity, both in base coordinates), through q' = 1/2 (0, omega) q.
"""
from __future__ import annotations

import functools

import casadi as ca
import numpy as np

from platkit.geometry import ca_quat_multiply, quat_normalize
from platkit.kinematics.forward import ForwardSolver
from platkit.kinematics.inverse import InverseSolver


class RateSolver(ForwardSolver, InverseSolver):
    """Control rates from pose rates and back (the papers' eqs. 5, 8, 10, 11 for any stand), in
    pose coordinates or as a twist."""

    @functools.cached_property
    def _rate_fn(self) -> ca.Function:
        """(u, td, p, ud, pd) -> (G_u, G_p, c): first-order blocks and the second-order term
        c = w'^T G_ww w' of G(u, p) = F(u, td, pose(p)) along w' = (u', p')."""
        s = self.spec
        u, td, p = ca.SX.sym("u", s.n_u), ca.SX.sym("td", s.n_td), ca.SX.sym("p", s.n_p)
        ud, pd = ca.SX.sym("ud", s.n_u), ca.SX.sym("pd", s.n_p)
        q, X = s.pose(p)
        G = s.residual(u, td, q, X)
        w, wd = ca.vertcat(u, p), ca.vertcat(ud, pd)
        c = ca.jtimes(ca.jtimes(G, w, wd), w, wd)
        return ca.Function("rates", [u, td, p, ud, pd], [ca.densify(ca.jacobian(G, u)), ca.densify(ca.jacobian(G, p)), c],
                           ["u", "td", "p", "ud", "pd"], ["G_u", "G_p", "c"])

    @functools.cached_property
    def _twist_fn(self) -> ca.Function:
        """(u, td, q, X, ud, v, omega) -> (F_u, F_t, c): F_t = dF/d(v, omega) with q' = 1/2 (0, omega) q,
        and c the second-order term of F along (u', q', X') plus F_q applied to 1/2 (0, omega) q'."""

        s = self.spec
        u, td, q, X = ca.SX.sym("u", s.n_u), ca.SX.sym("td", s.n_td), ca.SX.sym("q", 4), ca.SX.sym("X", 3)
        ud, v, om = ca.SX.sym("ud", s.n_u), ca.SX.sym("v", 3), ca.SX.sym("omega", 3)
        F = s.residual(u, td, q, X)
        qd = 0.5 * ca_quat_multiply(ca.vertcat(0, om), q)
        qdd_from_omega = 0.5 * ca_quat_multiply(ca.vertcat(0, om), qd)  # the part of q'' not linear in alpha
        w, wd = ca.vertcat(u, q, X), ca.vertcat(ud, qd, v)
        F_q = ca.jacobian(F, q)
        F_t = ca.horzcat(ca.jacobian(F, X), ca.jacobian(ca.mtimes(F_q, qd), om))
        c = ca.jtimes(ca.jtimes(F, w, wd), w, wd) + ca.mtimes(F_q, qdd_from_omega)
        return ca.Function("twist_rates", [u, td, q, X, ud, v, om],
                           [ca.densify(ca.jacobian(F, u)), ca.densify(F_t), c],
                           ["u", "td", "q", "X", "ud", "v", "omega"], ["F_u", "F_t", "c"])

    @functools.cached_property
    def _twist_of_rates_fn(self) -> ca.Function:
        """(p, pd, pdd) -> (v, omega, a, alpha): the moving frame's twist and its derivative in
        the base frame, from the pose coordinates and their rates."""

        s = self.spec
        p, pd, pdd = ca.SX.sym("p", s.n_p), ca.SX.sym("pd", s.n_p), ca.SX.sym("pdd", s.n_p)
        q, X = s.pose(p)
        q = q / ca.norm_2(q)
        v = ca.jtimes(X, p, pd)
        qd = ca.jtimes(q, p, pd)
        om = 2 * ca_quat_multiply(qd, q * ca.DM([1, -1, -1, -1]))[1:]
        a = ca.jtimes(v, p, pd) + ca.jtimes(v, pd, pdd)
        al = ca.jtimes(om, p, pd) + ca.jtimes(om, pd, pdd)
        return ca.Function("twist_of_rates", [p, pd, pdd], [v, om, a, al], ["p", "pd", "pdd"], ["v", "omega", "a", "alpha"])

    def _controls_at(self, p, td, u):
        if u is not None:
            return np.asarray(u, float)
        q, X = self.pose(p)
        return self.inverse(q, X, td, strict=False)

    def _pose_at(self, u, td, p):
        if p is not None:
            return np.asarray(p, float)
        return self.forward(u, td, strict=False).p

    def inverse_velocity(self, p, pdot, td=None, u=None) -> np.ndarray:
        """Control rates u' (n_u,) from pose-coordinate rates p' (n_p,) at pose p (the paper's
        eq. 5 for any stand). ``u``: the controls at p if known (else from inverse kinematics)."""
        td = self._td(td)
        p = np.asarray(p, float)
        u = self._controls_at(p, td, u)
        G_u, G_p, _ = self._rate_fn(u, td, p, np.zeros(self.spec.n_u), np.zeros(self.spec.n_p))
        return self._lstsq(np.asarray(G_u), -np.asarray(G_p) @ np.asarray(pdot, float))

    def inverse_acceleration(self, p, pdot, pddot, td=None, u=None) -> tuple[np.ndarray, np.ndarray]:
        """(u', u'') from (p, p', p''): control rates and accelerations (the paper's eq. 8 for any stand)."""
        td = self._td(td)
        p, pdot, pddot = (np.asarray(a, float) for a in (p, pdot, pddot))
        u = self._controls_at(p, td, u)
        G_u, G_p, _ = (np.asarray(a) for a in self._rate_fn(u, td, p, np.zeros(self.spec.n_u), pdot))
        udot = self._lstsq(G_u, -G_p @ pdot)
        c = np.asarray(self._rate_fn(u, td, p, udot, pdot)[2]).ravel()
        uddot = self._lstsq(G_u, -(G_p @ pddot + c))
        return udot, uddot

    def forward_velocity(self, u, udot, td=None, p=None) -> np.ndarray:
        """Pose-coordinate rates p' (n_p,) from control rates u' (the paper's eq. 10 for any
        stand). ``p``: the forward solution at u if known."""
        td = self._td(td)
        u = np.asarray(u, float)
        p = self._pose_at(u, td, p)
        G_u, G_p, _ = (np.asarray(a) for a in self._rate_fn(u, td, p, np.zeros(self.spec.n_u), np.zeros(self.spec.n_p)))
        return self._lstsq(G_p, -G_u @ np.asarray(udot, float))

    def forward_acceleration(self, u, udot, uddot, td=None, p=None) -> tuple[np.ndarray, np.ndarray]:
        """(p', p'') from (u, u', u'') (the paper's eq. 11 for any stand)."""
        td = self._td(td)
        u, udot, uddot = (np.asarray(a, float) for a in (u, udot, uddot))
        p = self._pose_at(u, td, p)
        G_u, G_p, _ = (np.asarray(a) for a in self._rate_fn(u, td, p, udot, np.zeros(self.spec.n_p)))
        pdot = self._lstsq(G_p, -G_u @ udot)
        c = np.asarray(self._rate_fn(u, td, p, udot, pdot)[2]).ravel()
        pddot = self._lstsq(G_p, -(G_u @ uddot + c))
        return pdot, pddot

    def inverse_velocity_twist(self, q, X, v, omega, td=None, u=None) -> np.ndarray:
        """Control rates u' (n_u,) from the twist: v (3,) velocity of the moving origin and
        omega (3,) angular velocity, both in the base frame (m/s, rad/s)."""
        td = self._td(td)
        q, X = quat_normalize(np.asarray(q, float)), np.asarray(X, float)
        u = self.inverse(q, X, td, strict=False) if u is None else np.asarray(u, float)
        F_u, F_t, _ = (np.asarray(a) for a in self._twist_fn(u, td, q, X, np.zeros(self.spec.n_u), v, omega))
        return self._lstsq(F_u, -F_t @ np.concatenate([v, omega]))

    def inverse_acceleration_twist(self, q, X, v, omega, a, alpha, td=None, u=None) -> tuple[np.ndarray, np.ndarray]:
        """(u', u'') from the twist (v, omega) and its rate (a, alpha): a = X'' (m/s^2), alpha =
        omega' (rad/s^2), base frame."""
        td = self._td(td)
        q, X = quat_normalize(np.asarray(q, float)), np.asarray(X, float)
        v, omega, a, alpha = (np.asarray(x, float) for x in (v, omega, a, alpha))
        u = self.inverse(q, X, td, strict=False) if u is None else np.asarray(u, float)
        F_u, F_t, _ = (np.asarray(x) for x in self._twist_fn(u, td, q, X, np.zeros(self.spec.n_u), v, omega))
        udot = self._lstsq(F_u, -F_t @ np.concatenate([v, omega]))
        c = np.asarray(self._twist_fn(u, td, q, X, udot, v, omega)[2]).ravel()
        uddot = self._lstsq(F_u, -(F_t @ np.concatenate([a, alpha]) + c))
        return udot, uddot

    def forward_velocity_twist(self, u, udot, td=None, p=None) -> tuple[np.ndarray, np.ndarray]:
        """Twist (v, omega) of the moving frame in the base frame from control rates u'."""
        td = self._td(td)
        u = np.asarray(u, float)
        p = self._pose_at(u, td, p)
        pdot = self.forward_velocity(u, udot, td, p)
        v, om, _, _ = self._twist_of_rates_fn(p, pdot, np.zeros(self.spec.n_p))
        return np.asarray(v).ravel(), np.asarray(om).ravel()

    def forward_acceleration_twist(self, u, udot, uddot, td=None, p=None):
        """(v, omega, a, alpha) of the moving frame in the base frame from (u, u', u'')."""
        td = self._td(td)
        u = np.asarray(u, float)
        p = self._pose_at(u, td, p)
        pdot, pddot = self.forward_acceleration(u, udot, uddot, td, p)
        return tuple(np.asarray(x).ravel() for x in self._twist_of_rates_fn(p, pdot, pddot))
