"""Calibration as one robust nonlinear least-squares problem with exact Jacobians.

Unknowns (all SI): the stand's free parameters td, the base-to-mocap transform mocap_from_base
(rotation vector w and translation t: 6 numbers), the marker positions m_i on the moving part
(3 per marker) and the parameters theta of any :class:`~platkit.terms.ModelTerm`.
The observation of marker i at pose n is

    y_ni = exp(w) (X_n + exp(dth_n) R(q_n) (m_i + dm_ni) + dX_n) + t

with (q_n, X_n) the forward kinematics of u_n + du_n under td, and (du, dX, dth, dm) the terms'
offsets. Jacobians come from CasADi: for a stand with a closed-form ``forward`` it is
differentiated directly; otherwise through the Newton solution by the implicit-function theorem,
dp/dtd = -F_p^+ F_td and dp/du = -F_p^+ F_u. Terms' offsets are differentiated in theta by
finite differences (they are numpy functions with few parameters) and chained with the exact
Jacobians.

Procedure (:func:`calibrate`):
1. poses by nominal forward kinematics; the transform and the markers by rigid alignment
   (Kabsch, with the rotation from the relative motions so that no translation is needed);
2. registration only (transform and markers, td at nominal): gives ``rms_before``;
3. identifiability: pivoted orthogonalisation of the scaled Jacobian (identifiability.py); the
   parameters the data cannot fix are held at nominal and reported by name;
4. Levenberg-Marquardt over everything identifiable, robust: Huber weights on each marker's
   3-D error (scale from the median error), then outliers beyond 4.5 sigma rejected outright;
5. standard deviations from sigma^2 (J^T W J)^-1; optional k-fold held-out prediction error.
"""
from __future__ import annotations

import contextlib
import ctypes
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import casadi as ca
import numpy as np

from platkit.calibrate.identifiability import (DEFAULT_REL_TOL, apply_marker_convention, classify_held, nuisance_gauge,
                                                select_identifiable, singular_values)
from platkit.calibrate.plan import reference_poses_for
from platkit.errors import BadInput, NoConvergence, NotIdentifiable
from platkit.geometry import (
    ca_matrix_from_quat,
    ca_matrix_from_rotvec,
    matrix_from_quat,
    matrix_from_rotvec,
    quat_from_matrix,
    quat_normalize,
    rigid_fit,
    rotvec_from_matrix,
)
from platkit.io.calibration import Calibration
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: Progress callback: ``progress(stage, info)``; stage is 'registration', 'identifiability',
#: 'iteration', 'robust', 'fold', 'done'; info carries 'iteration', 'rms' (m), ... as fitting.
Progress = Callable[[str, dict], None]

#: Median of the 3-D error norm of isotropic Gaussian noise, in units of the per-axis sigma.
MAXWELL_MEDIAN = 1.5381722
HUBER_K = 3.0  # Huber threshold on the 3-D error, in sigma
REJECT_K = 4.5  # errors beyond this many sigma are outliers (P < 1e-3 for clean 3-D noise)
#: td stays within nominal +- this many typical corrections (10 cm, 0.1 rad, 10%, 100 counts): a
#: description is a drawing of the stand, not a guess; beyond, the fit pays a stiff hinge
PLAUSIBLE_RANGE = 100.0
PLAUSIBLE_STIFFNESS_M = 1e-3  # per typical correction beyond the range, as a marker error of 1 mm

NUISANCE_TIER, TERM_TIER, TD_TIER = 0, 1, 2


def parameter_scale(unit: str, nominal: float) -> float:
    """Typical size of a calibration correction, SI: 1 mm, 1 mrad, 1e-3 relative for the rest."""
    if unit in ("m", "rad", "1", ""):
        return 1e-3
    return 1e-3 * max(abs(nominal), 1e-6) if unit != "count" else 1.0


@dataclass
class FitState:
    """One evaluation: residuals (N, M, 3) m (predicted minus measured, NaN where unseen) and the
    Jacobian (N, M, 3, n_z) with respect to the full unknown vector."""

    r: np.ndarray
    J: np.ndarray | None
    converged: np.ndarray  # (N,) forward kinematics converged


class CalibrationProblem:
    """The least-squares problem of one pose set on one stand; generic over PlatformSpec.

    Full unknown vector z (n_z,) = [td (n_td), w (3), t (3), m (3 M), theta (sum K_k)].
    """

    def __init__(self, spec: PlatformSpec, poses: PoseSet, terms: Sequence[ModelTerm] = ()):
        if poses.controls.shape[1] != spec.n_u:
            raise BadInput(f"{poses.source or 'poses'}: {poses.controls.shape[1]} control columns, the {spec.name} "
                           f"stand has {spec.n_u} ({', '.join(spec.control_names)})")
        self.spec = spec
        self.poses = poses
        self.terms = list(terms)
        self.model = PlatformModel(spec)
        self.N, self.M = poses.n_poses, poses.n_markers
        self.visible = np.all(np.isfinite(poses.markers), axis=2)  # (N, M)
        if not self.visible.any():
            raise BadInput(f"{poses.source or 'poses'}: no marker was seen in any pose")
        # a marker position averaged over n samples has variance sigma^2 / n: weight it by n
        # (relative to the median, so that sigma stays the noise of a typical pose)
        self.base_weights = self.visible.astype(float)
        n = None if poses.n_samples is None else np.asarray(poses.n_samples, float)
        if n is not None and n.shape == self.visible.shape and np.all(n[self.visible] > 0):
            self.base_weights = np.where(self.visible, n / np.median(n[self.visible]), 0.0)
        self.theta_sizes = [len(t.initial) for t in self.terms]
        n_theta = int(sum(self.theta_sizes))
        self.i_td = slice(0, spec.n_td)
        self.i_w = slice(spec.n_td, spec.n_td + 3)
        self.i_t = slice(spec.n_td + 3, spec.n_td + 6)
        self.i_m = slice(spec.n_td + 6, spec.n_td + 6 + 3 * self.M)
        self.i_theta = slice(self.i_m.stop, self.i_m.stop + n_theta)
        self.n_z = self.i_theta.stop
        self.names = (spec.parameter_names + ["mocap.rx", "mocap.ry", "mocap.rz", "mocap.x", "mocap.y", "mocap.z"]
                      + [f"marker.{m}.{a}" for m in poses.marker_names for a in "xyz"]
                      + [f"term.{t.effect}.{n}" for t in self.terms for n in t.parameter_names])
        self.scale = np.concatenate([
            [parameter_scale(p.unit, p.nominal) for p in spec.parameters],
            np.full(6 + 3 * self.M, 1e-3), np.full(n_theta, 1e-3)])
        self.tiers = np.array([TD_TIER] * spec.n_td + [NUISANCE_TIER] * (6 + 3 * self.M) + [TERM_TIER] * n_theta)
        self._p_guess = np.broadcast_to(spec.neutral_p(), (self.N, spec.n_p)).copy()
        self.prior_center = np.zeros(self.n_z)
        self.prior_scale = np.zeros(self.n_z)  # rows prior_scale * (z - prior_center); 0 = none
        # the plausible range of td: nominal +- PLAUSIBLE_RANGE typical corrections (see set_plausible)
        self.nominal = np.concatenate([spec.nominal_td(), np.zeros(self.n_z - spec.n_td)])
        self.half_width = np.full(self.n_z, np.inf)
        self.set_plausible(PLAUSIBLE_RANGE)
        self._build()

    def set_plausible(self, corrections: float | None) -> None:
        """Keep td within nominal +- ``corrections`` typical corrections (100: 10 cm, 0.1 rad, 10%).

        Inside the range nothing changes; a parameter pushed beyond it pays, per typical
        correction, as much as a marker error of PLAUSIBLE_STIFFNESS_M. Without it a weakly
        identified direction of the geometry (a crank-rod stand's rod and crank centres) can
        wander metres away while absorbing an unmodelled effect, and the fitted stand is then
        another stand: its forward kinematics fails on new commands. None or inf removes it.
        """
        self.half_width = np.full(self.n_z, np.inf)
        if corrections is not None and np.isfinite(corrections):
            self.half_width[self.i_td] = float(corrections) * self.scale[self.i_td]

    def beyond_plausible(self, z) -> list[str]:
        """Names of the td entries of ``z`` outside their plausible range."""
        d = np.abs(np.asarray(z, float) - self.nominal)
        return [self.names[i] for i in np.nonzero(d > self.half_width * (1 + 1e-9))[0]]

    def set_ridge(self, ridge_m: float, center) -> None:
        """Shrink td towards ``center``: one typical correction (1 mm, 1 mrad) of a parameter costs
        as much as a marker error of ``ridge_m`` metres. 0 removes the prior."""
        self.prior_center = np.asarray(center, float).copy()
        self.prior_scale = np.zeros(self.n_z)
        if ridge_m > 0:
            self.prior_scale[self.i_td] = ridge_m / self.scale[self.i_td]

    def prior_rows(self, z):
        """(values (R,), indices (R,), slopes (R,)): the rows the priors add, each depending on one
        unknown (the ridge, and the plausible range's hinge where z is beyond it), or None."""
        z = np.asarray(z, float)
        idx = [np.nonzero(self.prior_scale > 0)[0]]
        val = [self.prior_scale[idx[0]] * (z[idx[0]] - self.prior_center[idx[0]])]
        slope = [self.prior_scale[idx[0]]]
        d = z - self.nominal
        out = np.nonzero(np.abs(d) > self.half_width)[0]
        if out.size:
            k = PLAUSIBLE_STIFFNESS_M / self.scale[out]
            idx.append(out)
            val.append(k * np.sign(d[out]) * (np.abs(d[out]) - self.half_width[out]))
            slope.append(k)
        idx = np.concatenate(idx)
        return None if idx.size == 0 else (np.concatenate(val), idx, np.concatenate(slope))

    # ------------------------------------------------------------------ CasADi
    def _build(self) -> None:
        spec, M = self.spec, self.M
        u = ca.SX.sym("u", spec.n_u)
        td = ca.SX.sym("td", spec.n_td)
        w = ca.SX.sym("w", 3)
        t = ca.SX.sym("t", 3)
        m = ca.SX.sym("m", 3 * M)
        dpose = ca.SX.sym("dpose", 6)
        dm = ca.SX.sym("dm", 3 * M)
        A = ca_matrix_from_rotvec(w)

        def observe(q, X):
            R = ca.mtimes(ca_matrix_from_rotvec(dpose[3:6]), ca_matrix_from_quat(q))
            pts = [ca.mtimes(A, X + dpose[0:3] + ca.mtimes(R, m[3 * i:3 * i + 3] + dm[3 * i:3 * i + 3])) + t
                   for i in range(M)]
            return ca.vertcat(*pts)

        if spec.forward is not None:
            q, X = spec.forward(u, td)
            y = observe(q, X)
            self._G = ca.Function(
                "observe_fwd", [u, td, w, t, m, dpose, dm],
                [ca.densify(ca.horzcat(y, ca.jacobian(y, td), ca.jacobian(y, u), ca.jacobian(y, w), ca.jacobian(y, t),
                                       ca.jacobian(y, m), ca.jacobian(y, dpose)))],
                ["u", "td", "w", "t", "m", "dpose", "dm"], ["Y"])
            self._cols = [1, spec.n_td, spec.n_u, 3, 3, 3 * M, 6]
            self._Yonly = ca.Function("observe_fwd_y", [u, td, w, t, m, dpose, dm], [y])
            self._pose_of = ca.Function("pose_fwd", [u, td], [q, X], ["u", "td"], ["q", "X"])
        else:
            p = ca.SX.sym("p", spec.n_p)
            q, X = spec.pose(p)
            y = observe(q, X)
            r = spec.residual(u, td, q, X)
            self._G = ca.Function(
                "observe_ift", [u, td, p, w, t, m, dpose, dm],
                [ca.densify(ca.horzcat(y, ca.jacobian(y, p), ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m),
                                       ca.jacobian(y, dpose))),
                 ca.densify(ca.horzcat(ca.jacobian(r, p), ca.jacobian(r, td), ca.jacobian(r, u)))],
                ["u", "td", "p", "w", "t", "m", "dpose", "dm"], ["Y", "F"])
            self._cols = [1, spec.n_p, 3, 3, 3 * M, 6]
            self._fcols = [spec.n_p, spec.n_td, spec.n_u]
            self._Yonly = ca.Function("observe_ift_y", [u, td, p, w, t, m, dpose, dm], [y])
        self._maps: dict[int, ca.Function] = {}

    def _call(self, n: int, with_jac: bool, args: list[np.ndarray]) -> list[np.ndarray]:
        """Evaluate the observation function over n poses on preallocated buffers.

        args: per-pose inputs as (n, size) C-ordered arrays (CasADi's column-major (size, n)),
        shared inputs (td, w, t, m) as 1-D arrays. Returns the outputs as (n, cols, rows) arrays.
        """
        key = (n, with_jac)
        entry = self._maps.get(key)
        if entry is None:
            f = self._G if with_jac else self._Yonly
            shared = [1, 3, 4, 5] if self.spec.forward is None else [1, 2, 3, 4]
            fmap = f.map(f"{f.name()}_{n}", "serial", n, shared, [])
            buf, run = fmap.buffer()
            ins = [np.zeros(fmap.nnz_in(i)) for i in range(fmap.n_in())]
            outs = [np.zeros(fmap.nnz_out(i)) for i in range(fmap.n_out())]
            for i, a in enumerate(ins):
                buf.set_arg(i, memoryview(a))
            for i, a in enumerate(outs):
                buf.set_res(i, memoryview(a))
            shapes = [(n, fmap.size_out(i)[1] // n, fmap.size_out(i)[0]) for i in range(fmap.n_out())]
            entry = self._maps[key] = (buf, run, ins, outs, shapes)
        buf, run, ins, outs, shapes = entry
        for dst, src in zip(ins, args):
            dst[:] = np.ravel(src)
        run()
        return [o.reshape(sh).copy() for o, sh in zip(outs, shapes)]

    # ------------------------------------------------------------------ pieces
    def split(self, z):
        theta, k = [], self.i_theta.start
        for size in self.theta_sizes:
            theta.append(z[k:k + size])
            k += size
        return z[self.i_td], z[self.i_w], z[self.i_t], z[self.i_m].reshape(self.M, 3), theta

    def _term_offsets(self, theta, fk_q, fk_X, poses: PoseSet):
        N = poses.n_poses
        du = np.zeros((N, self.spec.n_u))
        dpose = np.zeros((N, 6))
        dm = np.zeros((N, self.M, 3))
        for term, th in zip(self.terms, theta):
            du += term.control_offset(th, poses, self.spec.n_u)
            dpose += term.pose_offset(th, poses, fk_q, fk_X)
            dm += term.marker_offset(th, poses)
        return du, dpose, dm

    def kinematics(self, td, U, guess=None):
        """Forward kinematics (q (N,4), X (N,3), p (N,n_p), converged (N,)) of controls U (N, n_u)."""
        fb = self.model.forward_batch(U, td, guess=guess, strict=False)
        return fb.q, fb.X, fb.p, fb.converged & fb.on_branch

    def evaluate(self, z, with_jac: bool = True, poses: PoseSet | None = None) -> FitState:
        """Residuals (and the Jacobian) at z. ``poses``: another pose set (held-out prediction)."""
        own = poses is None
        poses = self.poses if own else poses
        N, M = poses.n_poses, self.M
        td, w, t, m, theta = self.split(np.asarray(z, float))
        U = poses.controls
        guess = self._p_guess if own else None
        if self.terms:
            q0, X0, p0, _ = self.kinematics(td, U, guess)
            du, dpose, dm = self._term_offsets(theta, q0, X0, poses)
        else:
            du, dpose, dm = np.zeros((N, self.spec.n_u)), np.zeros((N, 6)), np.zeros((N, M, 3))
        Uo = U + du
        if self.spec.forward is not None:
            outs = self._call(N, with_jac, [Uo, td, w, t, m.ravel(), dpose, dm.reshape(N, -1)])
            ok = np.ones(N, bool)
        else:
            _, _, P, ok = self.kinematics(td, Uo, guess)
            if own:
                self._p_guess = np.where(ok[:, None], P, self._p_guess)
            P = np.where(ok[:, None], P, self._p_guess if own else self.spec.neutral_p())
            outs = self._call(N, with_jac, [Uo, td, P, w, t, m.ravel(), dpose, dm.reshape(N, -1)])
        nM3 = 3 * M
        if not with_jac:
            y = outs[0].reshape(N, M, 3)
            r = y - poses.markers
            r[~ok] = np.nan
            return FitState(r, None, ok)
        Yall = outs[0].transpose(0, 2, 1)  # (N, 3M, cols)
        parts = np.split(Yall, np.cumsum(self._cols)[:-1], axis=2)
        y = parts[0][:, :, 0].reshape(N, M, 3)
        r = y - poses.markers
        r[~ok] = np.nan
        J = np.zeros((N, nM3, self.n_z))
        if self.spec.forward is not None:
            _, Y_td, Y_u, Y_w, Y_t, Y_m, Y_dpose = parts
        else:
            _, Y_p, Y_w, Y_t, Y_m, Y_dpose = parts
            Fall = outs[1].transpose(0, 2, 1)  # (N, n_r, cols)
            F_p, F_td, F_u = np.split(Fall, np.cumsum(self._fcols)[:-1], axis=2)
            if F_p.shape[1] == F_p.shape[2]:
                F_p_inv = np.linalg.inv(F_p)
            else:
                F_p_inv = np.linalg.pinv(F_p)  # (N, n_p, n_r)
            Y_pinv = np.einsum("nap,npr->nar", Y_p, F_p_inv)
            Y_td = -np.einsum("nar,nrk->nak", Y_pinv, F_td)
            Y_u = -np.einsum("nar,nrk->nak", Y_pinv, F_u) if self.terms else None
        J[:, :, self.i_td] = Y_td
        J[:, :, self.i_w] = Y_w
        J[:, :, self.i_t] = Y_t
        J[:, :, self.i_m] = Y_m
        if self.terms:
            k = self.i_theta.start
            for term, th in zip(self.terms, theta):
                base = (term.control_offset(th, poses, self.spec.n_u), term.pose_offset(th, poses, q0, X0),
                        term.marker_offset(th, poses))
                for j in range(len(th)):
                    h = 1e-6 * max(1.0, abs(th[j]))
                    thp = np.array(th, float).copy()
                    thp[j] += h
                    d_u = (term.control_offset(thp, poses, self.spec.n_u) - base[0]) / h
                    d_pose = (term.pose_offset(thp, poses, q0, X0) - base[1]) / h
                    d_m = (term.marker_offset(thp, poses) - base[2]) / h
                    col = (np.einsum("nak,nk->na", Y_u, d_u) + np.einsum("nak,nk->na", Y_dpose, d_pose)
                           + np.einsum("nak,nk->na", Y_m, d_m.reshape(N, -1)))
                    J[:, :, k] = col
                    k += 1
        return FitState(r, J.reshape(N, M, 3, self.n_z), ok)

    # ------------------------------------------------------------------ initial values
    def initial_registration(self, td) -> np.ndarray:
        """Transform and markers by rigid alignment at nominal kinematics: z (n_z,)."""
        poses = self.poses
        q, X, _, ok = self.kinematics(td, poses.controls)
        R = matrix_from_quat(q)
        Y = poses.markers
        vis = self.visible & ok[:, None]
        A = self._initial_rotation(R, X, Y, vis)
        keep = vis.copy()
        for _ in range(6):  # alternate: markers by least squares, then Kabsch; gross outliers left out
            mk, b = self._markers_given_rotation(A, R, X, Y, keep)
            pts = X[:, None, :] + np.einsum("nab,mb->nma", R, mk)
            d = np.linalg.norm(pts @ A.T + b - np.where(vis[..., None], Y, 0.0), axis=2)
            sigma = _robust_sigma(d[vis])
            keep = vis & (d <= max(REJECT_K * sigma, 1e-12))
            A, b = rigid_fit(pts[keep], Y[keep])
        mk, b = self._markers_given_rotation(A, R, X, Y, keep)
        z = np.zeros(self.n_z)
        z[self.i_td] = td
        z[self.i_w] = rotvec_from_matrix(A)
        z[self.i_t] = b
        z[self.i_m] = mk.ravel()
        k = self.i_theta.start
        for term in self.terms:
            z[k:k + len(term.initial)] = term.initial
            k += len(term.initial)
        return z

    def _initial_rotation(self, R, X, Y, vis) -> np.ndarray:
        """mocap_from_base rotation A from relative motions: Rm_n A = A B_n (hand-eye, AX = XB).

        Rm_n: the marker cloud's rotation from a reference pose to pose n (Kabsch), B_n the
        model's. A few references are tried and the one whose clouds fit best is kept, and pose
        pairs whose clouds do not fit as a rigid body (a swapped or jumping marker) are left out.
        """
        N = len(R)
        counts = vis.sum(axis=1)
        best_seen = np.nonzero(counts == counts.max())[0]
        refs = best_seen[np.unique(np.linspace(0, len(best_seen) - 1, min(len(best_seen), 5)).astype(int))]
        # a few dozen well-seen poses fix a rotation; more only cost time
        sample = np.unique(np.linspace(0, N - 1, min(N, 60)).astype(int))
        best = None
        for ref in refs:
            rows, misfit = [], []
            for n in sample:
                common = vis[n] & vis[ref]
                if n == ref or common.sum() < 3:
                    continue
                Rm, tm = rigid_fit(Y[ref, common], Y[n, common])
                misfit.append(np.sqrt(np.mean(np.sum((Y[ref, common] @ Rm.T + tm - Y[n, common]) ** 2, axis=1))))
                rows.append(np.kron(np.eye(3), Rm) - np.kron((R[n] @ R[ref].T).T, np.eye(3)))
            if len(rows) < 2:
                continue
            misfit = np.array(misfit)
            med = float(np.median(misfit))
            good = misfit <= max(4.5 * med, 1e-12)
            if best is None or med < best[0]:
                best = (med, np.vstack([r for r, g in zip(rows, good) if g]))
        if best is not None:
            _, s, Vt = np.linalg.svd(best[1])
            if s[-2] > 10 * s[-1] and s[-2] > 1e-3:
                A = Vt[-1].reshape(3, 3, order="F")
                if np.linalg.det(A) < 0:
                    A = -A
                U_, _, Vt_ = np.linalg.svd(A)
                return U_ @ np.diag([1, 1, np.linalg.det(U_ @ Vt_)]) @ Vt_
        # too little rotation: align the moving frame's path with the markers' centroid path
        full = vis.all(axis=1)
        if full.sum() >= 3:
            A, _ = rigid_fit(X[full], Y[full].mean(axis=1))
            return A
        return np.eye(3)

    @staticmethod
    def _markers_given_rotation(A, R, X, Y, vis):
        """Linear least squares for marker positions m (M, 3) and translation b given A
        (normal equations; the blocks (A R_n)^T (A R_n) are identities)."""
        N, M = vis.shape
        H = np.zeros((3 * M + 3, 3 * M + 3))
        g = np.zeros(3 * M + 3)
        C = np.einsum("ab,nbc->nac", A, R)  # (N, 3, 3): d y / d m
        res = Y - (X @ A.T)[:, None, :]  # (N, M, 3)
        for i in range(M):
            v = vis[:, i]
            k = slice(3 * i, 3 * i + 3)
            H[k, k] = v.sum() * np.eye(3)
            Ct = C[v].sum(axis=0).T
            H[k, 3 * M:] = Ct
            H[3 * M:, k] = Ct.T
            g[k] = np.einsum("nba,nb->a", C[v], res[v, i])
            g[3 * M:] += res[v, i].sum(axis=0)
        H[3 * M:, 3 * M:] = vis.sum() * np.eye(3)
        sol = np.linalg.lstsq(H, g, rcond=None)[0]
        return sol[:3 * M].reshape(M, 3), sol[3 * M:]


# ---------------------------------------------------------------------------- solver


@contextlib.contextmanager
def blas_threads(n: int = 1):
    """Limit OpenBLAS threads inside the block (restored after).

    The estimator's matrices are small (thousands by tens); on a shared machine OpenBLAS worker
    threads spin against other processes and make each product ten times slower. Works on the
    OpenBLAS builds numpy and scipy ship (found through /proc/self/maps); elsewhere a no-op.
    """
    handles = []
    try:
        with open("/proc/self/maps", encoding="utf-8") as fh:
            libs = sorted({line.split()[-1] for line in fh if "openblas" in line and ".so" in line})
    except OSError:
        libs = []
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in ("scipy_openblas_", "openblas_", ""):
            for suffix in ("64_", ""):
                get = getattr(lib, f"{prefix}get_num_threads{suffix}", None) if prefix else None
                put = getattr(lib, f"{prefix}set_num_threads{suffix}", None) if prefix else None
                if get is not None and put is not None:
                    handles.append((put, int(get())))
                    put(int(n))
                    break
            else:
                continue
            break
    try:
        yield
    finally:
        for put, old in handles:
            put(old)


def _robust_sigma(d: np.ndarray) -> float:
    """Per-axis noise sigma from 3-D error norms, robustly (median)."""
    d = d[np.isfinite(d)]
    return float(np.median(d) / MAXWELL_MEDIAN) if d.size else float("nan")


@dataclass
class LMResult:
    z: np.ndarray
    state: FitState
    weights: np.ndarray  # (N, M)
    iterations: int
    converged: bool
    cost: float


def _weighted(state: FitState, weights, active, prior=None):
    """Weighted residual vector and Jacobian columns of the active unknowns; ``prior``: optional
    rows from :meth:`CalibrationProblem.prior_rows` (values, unknown index, slope)."""
    w = np.where(np.isfinite(state.r).all(axis=2), weights, 0.0)  # (N, M)
    r = np.nan_to_num(state.r)
    sw = np.sqrt(w)[:, :, None]
    rw = (r * sw).ravel()
    Jw = None
    if state.J is not None:
        Jw = (state.J[..., active] * sw[..., None]).reshape(-1, int(np.sum(active)))
    if prior is not None:
        val, idx, slope = prior
        on = active[idx]  # a prior on a held unknown is a constant: no row
        val, idx, slope = val[on], idx[on], slope[on]
        if idx.size:
            rw = np.concatenate([rw, val])
            if Jw is not None:
                P = np.zeros((idx.size, int(np.sum(active))))
                cols = np.cumsum(active) - 1
                P[np.arange(idx.size), cols[idx]] = slope
                Jw = np.vstack([Jw, P])
    return rw, Jw


def levenberg_marquardt(problem: CalibrationProblem, z0, active, weights, max_iter=60, ftol=1e-10, xtol=1e-10,
                        progress: Progress | None = None, stage: str = "iteration", it0: int = 0) -> LMResult:
    """Minimise 1/2 sum_nm w_nm |r_nm(z)|^2 over z[active], from z0 (Marquardt-scaled LM)."""
    z = np.array(z0, float)
    active = np.asarray(active, bool)
    st = problem.evaluate(z)
    rw, Jw = _weighted(st, weights, active, problem.prior_rows(z))
    cost = 0.5 * rw @ rw
    lam = 1e-5
    converged = False
    it = 0
    for it in range(1, max_iter + 1):
        g = Jw.T @ rw
        H = Jw.T @ Jw
        D = np.maximum(np.diag(H), 1e-12 * max(1.0, np.max(np.diag(H))))
        accepted = False
        while lam < 1e12:
            try:
                step = np.linalg.solve(H + lam * np.diag(D), -g)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            z_new = z.copy()
            z_new[active] += step
            st_new = problem.evaluate(z_new)
            rw_new, Jw_new = _weighted(st_new, weights, active, problem.prior_rows(z_new))
            cost_new = 0.5 * rw_new @ rw_new
            # a step that loses poses (forward kinematics fails there) only looks cheaper
            lost = np.sum(st_new.converged) < np.sum(st.converged)
            if np.isfinite(cost_new) and cost_new <= cost and not lost:
                accepted = True
                break
            lam *= 10
        if not accepted:
            converged = True  # no descent direction left: at a minimum to working precision
            break
        small_step = np.linalg.norm(step * np.sqrt(D)) <= xtol * (np.linalg.norm(rw) + xtol)
        small_gain = (cost - cost_new) <= ftol * max(cost, 1e-300)
        z, st, rw, Jw, cost = z_new, st_new, rw_new, Jw_new, cost_new
        lam = max(lam / 10, 1e-12)
        if progress is not None:
            n_w = max(1.0, float(np.sum(weights * np.isfinite(st.r).all(axis=2))))
            progress(stage, {"iteration": it0 + it, "rms": float(np.sqrt(2 * cost / n_w)), "lambda": lam})
        if small_step or small_gain:
            converged = True
            break
    return LMResult(z, st, weights, it, converged, cost)


def robust_fit(problem: CalibrationProblem, z0, active, robust: bool = True, max_iter: int = 60,
               progress: Progress | None = None, stage: str = "iteration") -> LMResult:
    """LM with iteratively reweighted Huber weights, then hard rejection beyond REJECT_K sigma.

    Weights start from ``problem.base_weights`` (the samples averaged into each marker position,
    relative to the median); errors are compared in units of their own expected size.
    """
    vis = problem.visible
    base = problem.base_weights
    weights = base.copy()
    res = levenberg_marquardt(problem, z0, active, weights, max_iter, progress=progress, stage=stage)
    if not robust:
        return res
    total_it = res.iterations

    def standardized(state):
        return np.linalg.norm(state.r, axis=2) * np.sqrt(base)

    for _ in range(3):  # Huber rounds
        d = standardized(res.state)
        sigma = _robust_sigma(d[vis])
        if not np.isfinite(sigma) or sigma <= 0:
            break
        c = HUBER_K * sigma
        new_w = np.where(vis & np.isfinite(d), base * np.minimum(1.0, c / np.maximum(d, 1e-300)), 0.0)
        res = levenberg_marquardt(problem, res.z, active, new_w, max_iter, progress=progress, stage=stage, it0=total_it)
        total_it += res.iterations
        if np.max(np.abs(new_w - weights) / np.maximum(base, 1e-300)) < 0.05:
            weights = new_w
            break
        weights = new_w
    keep_prev = None
    for _ in range(3):  # hard rejection rounds: inliers get full weight (no efficiency lost)
        d = standardized(res.state)
        sigma = _robust_sigma(d[vis])
        keep = vis & np.isfinite(d) & (d <= REJECT_K * sigma)
        if keep_prev is not None and np.array_equal(keep, keep_prev):
            break
        res = levenberg_marquardt(problem, res.z, active, np.where(keep, base, 0.0), max_iter, progress=progress,
                                  stage=stage, it0=total_it)
        total_it += res.iterations
        keep_prev = keep
    res.iterations = total_it
    return res


def _rms(state: FitState, weights) -> float:
    d2 = np.sum(np.nan_to_num(state.r) ** 2, axis=2)
    keep = (weights > 0) & np.isfinite(state.r).all(axis=2)
    return float(np.sqrt(np.mean(d2[keep]))) if keep.any() else float("nan")


# ---------------------------------------------------------------------------- public


def free_mask(spec: PlatformSpec, free: Sequence[str] | None) -> np.ndarray:
    """Which td entries to fit: None = every parameter the stand marks free; otherwise names or
    group names (e.g. ['offset', 'origin']). An empty list fits none (registration only)."""
    if free is None:
        return np.array([p.free for p in spec.parameters], bool)
    wanted = set(free)
    known = {p.name for p in spec.parameters} | {p.group for p in spec.parameters}
    unknown = sorted(wanted - known)
    if unknown:
        groups = sorted({p.group for p in spec.parameters if p.group})
        raise BadInput(f"--free: {', '.join(unknown)} is neither a parameter nor a group of the {spec.name} stand "
                       f"(groups: {', '.join(groups)})")
    return np.array([(p.name in wanted or p.group in wanted) for p in spec.parameters], bool)


def calibrate(poses: PoseSet, spec: PlatformSpec, terms: Sequence[ModelTerm] = (), free: Sequence[str] | None = None,
              robust: bool = True, folds: int = 0, rel_tol: float = DEFAULT_REL_TOL, max_iter: int = 60,
              progress: Progress | None = None, platform_options: dict | None = None,
              td_start: np.ndarray | None = None, ridge_m: float = 0.0,
              plausible: float | None = PLAUSIBLE_RANGE) -> Calibration:
    """Estimate td, the base-to-mocap transform, marker positions and term parameters.

    poses: settled poses (SI); spec: the stand (its nominal td is the starting point and the value
    of every parameter held); terms: extra physics (ModelTerm); free: see :func:`free_mask`;
    folds: K > 1 adds K-fold held-out prediction errors to ``Calibration.heldout``.
    ridge_m: optional shrinkage of td towards nominal (see CalibrationProblem.set_ridge); 0 (default)
    is plain (robust) least squares.
    plausible: td is kept within nominal +- this many typical corrections (see
    CalibrationProblem.set_plausible; the names that reach the edge are in
    ``identifiability['at_plausible_limit']``); None lets td go anywhere.
    Raises NotIdentifiable when not even the transform and markers can be fixed, NoConvergence
    when forward kinematics fails on most poses.
    """
    with blas_threads(1):
        return _calibrate(poses, spec, terms, free, robust, folds, rel_tol, max_iter, progress, platform_options,
                          td_start, ridge_m, plausible)


def _calibrate(poses, spec, terms, free, robust, folds, rel_tol, max_iter, progress, platform_options, td_start,
               ridge_m, plausible) -> Calibration:
    t0 = time.perf_counter()
    free_td = free_mask(spec, free)  # bad names are bad input before any work
    problem = CalibrationProblem(spec, poses, terms)
    td0 = spec.nominal_td() if td_start is None else np.asarray(td_start, float)
    z = problem.initial_registration(td0)
    problem.set_ridge(ridge_m, z)
    problem.set_plausible(plausible)
    n_z = problem.n_z
    nuisance = np.zeros(n_z, bool)
    nuisance[problem.i_w] = nuisance[problem.i_t] = nuisance[problem.i_m] = True
    st = problem.evaluate(z, with_jac=False)
    if np.mean(st.converged) < 0.5:
        raise NoConvergence(f"{spec.name} forward kinematics at the nominal parameters", 0, float("nan"),
                            f"{int(np.sum(~st.converged))} of {poses.n_poses} poses have no solution; "
                            "check the platform and the control units")
    candidates = nuisance.copy()
    candidates[problem.i_td] = free_mask(spec, free)
    candidates[problem.i_theta] = True
    # stage 0: gauge freedoms (what no set of poses fixes, told apart from what these poses do not
    # excite on the stand's reference poses); the transform and marker coordinates that are gauges
    # are held, and fixed by the stated convention after the fit
    gauge = nuisance_gauge(problem, z, candidates, nuisance, reference_poses_for(spec, problem.model), rel_tol)
    nuisance[gauge.held] = False
    candidates[gauge.held] = False
    # stage 1: registration only (td held at its nominal), robustly
    reg = robust_fit(problem, z, nuisance, robust, max_iter, progress, "registration")
    rms_before = _rms(reg.state, reg.weights)
    residuals_before = reg.state.r.copy()
    # stage 2: identifiability at the registered start
    st = problem.evaluate(reg.z)
    cand_idx = np.nonzero(candidates)[0]
    # seen and solved; what the registration rejected counts too: the model terms may be what
    # explains it (a slipped marker's later half is an outlier only to the geometry), and a
    # Jacobian column does not depend on the measured value
    used = (problem.base_weights > 0) & np.isfinite(st.r).all(axis=2)
    Jc = (st.J[..., cand_idx] * np.sqrt(np.where(used, problem.base_weights, 0.0))[:, :, None, None])[used]
    Jc = Jc.reshape(-1, len(cand_idx))
    ident = select_identifiable(Jc, [problem.names[i] for i in cand_idx], problem.scale[cand_idx],
                                problem.tiers[cand_idx].tolist(), rel_tol)
    chosen = cand_idx[ident.chosen]
    lost_nuisance = [h.name for h in ident.held if not h.name.startswith(("term.",)) and
                     (h.name.startswith("mocap.") or h.name.startswith("marker."))]
    if lost_nuisance:
        raise NotIdentifiable(f"the poses cannot fix {', '.join(lost_nuisance)}: the platform must rotate about "
                              "two axes or translate, and each marker be seen in several poses")
    classify_held(ident, gauge, cand_idx, problem, rel_tol)
    if progress is not None:
        progress("identifiability", {"n_identifiable": len(chosen), "held": [h.name for h in ident.held]})
    active = np.zeros(n_z, bool)
    active[chosen] = True
    # stage 3: the full robust fit
    fit = robust_fit(problem, reg.z, active, robust, max_iter, progress, "iteration")
    z = fit.z
    st = problem.evaluate(z)
    weights = fit.weights
    keep = (weights > 0) & np.isfinite(st.r).all(axis=2)
    rms_after = _rms(st, weights)
    # covariance over the active unknowns
    rw, Jw = _weighted(st, weights, active)
    n_obs = 3 * int(keep.sum())
    dof = max(1, n_obs - int(active.sum()))
    s2 = float(rw @ rw) / dof
    JtJ = Jw.T @ Jw
    if problem.prior_rows(z) is not None:  # posterior covariance: the prior rows count as data
        _, Jp = _weighted(st, weights, active, problem.prior_rows(z))
        JtJ = Jp.T @ Jp
    try:
        cov = s2 * np.linalg.inv(JtJ)
    except np.linalg.LinAlgError:
        cov = s2 * np.linalg.pinv(JtJ)
    std_full = np.full(n_z, np.nan)
    std_full[active] = np.sqrt(np.clip(np.diag(cov), 0, None))
    z, gauge_map = apply_marker_convention(problem, z, gauge)
    if gauge.held and not np.array_equal(gauge_map, np.eye(n_z)):  # the covariance in the convention's gauge
        cov_full = np.zeros((n_z, n_z))
        cov_full[np.ix_(active, active)] = cov
        cov_full = gauge_map @ cov_full @ gauge_map.T
        cov = cov_full[np.ix_(active, active)]
        moved = active | np.any(gauge_map != np.eye(n_z), axis=1)
        std_full[moved] = np.sqrt(np.clip(np.diag(cov_full)[moved], 0, None))
    sv = singular_values(Jw * problem.scale[active][None, :])
    # report
    free_td = free_mask(spec, free)
    held_names = {h.name for h in ident.held}
    status = []
    for p, f in zip(spec.parameters, free_td):
        status.append("held_at_nominal" if p.name in held_names else ("estimated" if f else "fixed"))
    td_std = std_full[problem.i_td].copy()
    weak = [problem.names[i] for i in np.nonzero(active)[0]
            if i < spec.n_td and std_full[i] > 10 * problem.scale[i]]
    identifiability = ident.to_dict()
    identifiability.update({
        "singular_values_at_estimate": [float(x) for x in sv],
        "scaled_by": "each parameter's typical correction: 1 mm for lengths, 1 mrad for angles, 1e-3 relative otherwise",
        "weakly_identified": weak,
        "at_plausible_limit": [n for n in problem.beyond_plausible(z) if active[problem.names.index(n)]],
        "plausible_range": None if plausible is None else f"nominal +- {plausible:g} typical corrections",
        "rel_tol": rel_tol,
        "gauge": gauge.to_dict(),
    })
    td, w, t, m, theta = problem.split(z)
    theta_std, k = [], problem.i_theta.start
    for size in problem.theta_sizes:
        theta_std.append(std_full[k:k + size])
        k += size
    cal = Calibration(
        platform=spec.name, description=None if spec.description_path is None else str(spec.description_path),
        spec=spec, td=td.copy(), td_std=td_std, td_nominal=spec.nominal_td(), td_status=status,
        mocap_rotvec=w.copy(), mocap_translation=t.copy(),
        mocap_std=np.concatenate([std_full[problem.i_w], std_full[problem.i_t]]),
        marker_names=list(poses.marker_names), marker_positions=m.copy(),
        marker_std=std_full[problem.i_m].reshape(-1, 3), rms_before=rms_before, rms_after=rms_after,
        length_unit=poses.length_unit, platform_options=dict(platform_options or {}), method="lsq",
        converged=bool(fit.converged), iterations=int(fit.iterations), n_poses=poses.n_poses,
        n_markers=poses.n_markers, n_observations=int(keep.sum()),
        n_rejected=int(np.sum(problem.visible & ~keep)), noise_sigma=float(np.sqrt(s2)),
        identifiability=identifiability, terms=list(terms), theta=[np.array(x) for x in theta], theta_std=theta_std,
    )
    cal.extras.update({
        "residuals_before": residuals_before, "residuals_after": st.r.copy(), "weights": weights.copy(),
        "weights_before": reg.weights.copy(), "singular_values": sv, "identifiability": ident,
        "controls": poses.controls.copy(), "active": active, "z": z.copy(), "names": list(problem.names),
        "cov": cov, "problem": problem, "ridge_m": ridge_m,
    })
    if folds and folds > 1:
        cal.heldout = kfold(problem, z, active, folds, robust, max_iter, progress)
    cal.time_s = time.perf_counter() - t0
    if progress is not None:
        progress("done", {"rms_before": rms_before, "rms_after": rms_after, "time_s": cal.time_s})
    return cal


def kfold(problem: CalibrationProblem, z, active, folds: int, robust: bool = True, max_iter: int = 60,
          progress: Progress | None = None) -> dict:
    """K-fold held-out point RMS (m): refit on K-1 folds from z, predict the left-out poses.

    Poses are assigned to folds in an interleaved order (pose n to fold n mod K) so every fold
    spans the session.
    """
    poses = problem.poses
    N = poses.n_poses
    if folds > N:
        raise BadInput(f"--folds {folds} is more than the {N} poses")
    fold_of = np.arange(N) % folds
    errs = np.full((N, problem.M), np.nan)
    per_fold = []
    for k in range(folds):
        train = poses.subset(fold_of != k)
        test = poses.subset(fold_of == k)
        sub = CalibrationProblem(problem.spec, train, problem.terms)
        sub.prior_center, sub.prior_scale = problem.prior_center, problem.prior_scale
        sub.half_width = problem.half_width
        fit = robust_fit(sub, z, active, robust, max_iter)
        st = sub.evaluate(fit.z, with_jac=False, poses=test)
        d = np.linalg.norm(st.r, axis=2)
        errs[fold_of == k] = d
        per_fold.append(float(np.sqrt(np.nanmean(d ** 2))))
        if progress is not None:
            progress("fold", {"fold": k + 1, "folds": folds, "rms": per_fold[-1]})
    d = errs[np.isfinite(errs)]
    med = np.median(d) if d.size else np.nan
    inl = d[d <= REJECT_K * med / MAXWELL_MEDIAN] if d.size else d
    return {"folds": folds, "rms": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
            "rms_inliers": float(np.sqrt(np.mean(inl ** 2))) if inl.size else float("nan"),
            "rms_per_fold": per_fold}


# ---------------------------------------------------------------------------- prediction


def predict_markers(cal: Calibration, controls: np.ndarray, poses: PoseSet | None = None):
    """Model prediction for controls (N, n_u), SI: markers (N, M, 3) in the mocap frame, pose
    (q (N, 4), X (N, 3)) in the base frame and a converged flag (N,).

    ``poses`` supplies what history- or time-dependent terms need (t, row order, extras); by
    default a PoseSet of the controls alone.
    """
    spec = cal.calibrated_spec()
    model = PlatformModel(spec)
    U = np.atleast_2d(np.asarray(controls, float))
    N, M = U.shape[0], len(cal.marker_names)
    if poses is None:
        poses = PoseSet(platform=cal.platform, controls=U, markers=np.full((N, M, 3), np.nan),
                        marker_names=list(cal.marker_names), length_unit=cal.length_unit)
    td = cal.td
    du = np.zeros((N, spec.n_u))
    dpose = np.zeros((N, 6))
    dm = np.zeros((N, M, 3))
    if cal.terms:
        fb = model.forward_batch(U, td, strict=False)
        for term, th in zip(cal.terms, cal.theta):
            du += term.control_offset(th, poses, spec.n_u)
            dpose += term.pose_offset(th, poses, fb.q, fb.X)
            dm += term.marker_offset(th, poses)
    fb = model.forward_batch(U + du, td, strict=False)
    R = matrix_from_quat(fb.q) @ np.eye(3)
    R = np.einsum("nab,nbc->nac", matrix_from_rotvec(dpose[:, 3:]), R)
    X = fb.X + dpose[:, :3]
    A = matrix_from_rotvec(cal.mocap_rotvec)
    pts = X[:, None, :] + np.einsum("nab,nmb->nma", R, cal.marker_positions[None] + dm)
    markers = pts @ A.T + cal.mocap_translation

    q = quat_normalize(quat_from_matrix(R))
    ok = fb.converged & fb.on_branch
    markers[~ok] = np.nan
    return markers, q, X, ok


def point_errors(cal: Calibration, poses: PoseSet) -> np.ndarray:
    """|predicted - measured| (N, M) in metres for a pose set in the same mocap frame (NaN unseen)."""
    pred, _, _, _ = predict_markers(cal, poses.controls, poses)
    return np.linalg.norm(pred - poses.markers, axis=2)


def second_session_errors(cal: Calibration, poses: PoseSet) -> dict:
    """Held-out prediction of another session recorded in the same mocap frame: {'source',
    'n_poses', 'rms' (m), 'rms_per_marker' {name: m}}. Markers are matched by name."""
    missing = [m for m in cal.marker_names if m not in poses.marker_names]
    if missing:
        raise BadInput(f"{poses.source or 'validation session'}: has no marker {missing[0]!r} of the calibration")
    order = [poses.marker_names.index(m) for m in cal.marker_names]
    sub = PoseSet(poses.platform, poses.controls, poses.markers[:, order], list(cal.marker_names), t=poses.t,
                  length_unit=poses.length_unit, source=poses.source, extras=dict(poses.extras))
    d = point_errors(cal, sub)
    per = {m: float(np.sqrt(np.nanmean(d[:, i] ** 2))) for i, m in enumerate(cal.marker_names)}
    return {"source": poses.source, "n_poses": int(poses.n_poses), "rms": float(np.sqrt(np.nanmean(d ** 2))),
            "rms_per_marker": per}


__all__ = ["calibrate", "kfold", "predict_markers", "point_errors", "second_session_errors", "free_mask", "CalibrationProblem",
           "levenberg_marquardt", "robust_fit", "parameter_scale", "Progress"]
