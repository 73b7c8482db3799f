"""The observation model of a calibration: residuals and exact Jacobians of a pose set.

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
Jacobians. The solvers are in :mod:`platkit.calibrate.solve`, the procedure in
:mod:`platkit.calibrate.estimate`.

Rigid bodies measured in 6 DOF (:mod:`platkit.bodies`): body b has an unknown placement
(origin p_b, m, and rotation vector phi_b, rad, on the moving part) and two residual channels
after the M markers': its origin, observed like a marker at p_b (channel M + b), and
rho * log(R_meas^T R_pred) with R_pred = exp(w) exp(dth_n) R(q_n) exp(phi_b) (channel M + B + b),
rho = sigma_position / sigma_rotation (m/rad) so that every channel is metres of equal noise.
Its exact Jacobian is J_r^-1(e) R_b^T vee(Q^T dQ) for Q = exp(w) exp(dth_n) R(q_n) (CasADi) and
J_r^-1(e) J_r(phi_b) for phi_b.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from platkit.bodies import (
    DEFAULT_RHO_M_PER_RAD,
    body_frame_points,
    declared_rho,
    log_so3,
    placement_from_frame_points,
    quat_mean,
    right_jacobian,
    right_jacobian_inv,
)
from platkit.errors import BadInput
from platkit.geometry import (
    ca_matrix_from_quat,
    ca_matrix_from_rotvec,
    matrix_from_quat,
    matrix_from_rotvec,
    quat_from_matrix,
    rigid_fit,
    rotvec_from_matrix,
)
from platkit.io.cache import c_compiler
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.native import compiled_library
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
    """One evaluation: residuals (N, C, 3) m (predicted minus measured, NaN where unseen) and the
    Jacobian (N, C, 3, n_z) with respect to the full unknown vector. C = M + 2 B channels: the
    markers, then each body's origin, then each body's scaled rotation error."""

    r: np.ndarray
    J: np.ndarray | None
    converged: np.ndarray  # (N,) forward kinematics converged


class CalibrationProblem:
    """The least-squares problem of one pose set on one stand; generic over PlatformSpec.

    Full unknown vector z (n_z,) = [td (n_td), w (3), t (3), m (3 M), theta (sum K_k), body origins
    (3 B), body rotation vectors (3 B)]. ``body_rho`` (m/rad) weighs the bodies' rotation channels;
    ``rho_source`` says where it came from ('declared', 'default', 'estimated').
    """

    def __init__(self, spec: PlatformSpec, poses: PoseSet, terms: Sequence[ModelTerm] = ()):
        if poses.controls.shape[1] != spec.n_u:
            raise BadInput(f"{poses.source or 'poses'}: {poses.controls.shape[1]} control columns, the {spec.name} "
                           f"stand has {spec.n_u} ({', '.join(spec.control_names)})")
        self.spec = spec
        self.poses = poses
        self.terms = list(terms)
        self.N, self.M = poses.n_poses, poses.n_markers
        self.B = poses.n_bodies
        rho = declared_rho(poses.body_noise)
        self.body_rho = DEFAULT_RHO_M_PER_RAD if rho is None else rho
        self.rho_source = "default" if rho is None else "declared"
        body_seen = np.all(np.isfinite(_bodies(poses)), axis=2)  # (N, B)
        self.visible = np.concatenate([np.all(np.isfinite(poses.markers), axis=2), body_seen, body_seen], axis=1)
        if not self.visible.any():
            raise BadInput(f"{poses.source or 'poses'}: no marker or rigid body was seen in any pose")
        # a marker position averaged over n samples has variance sigma^2 / n: weight it by n
        # (relative to the median, so that sigma stays the noise of a typical pose)
        self.base_weights = self.visible.astype(float)
        n = None if poses.n_samples is None else np.asarray(poses.n_samples, float)
        if self.B:
            nb = poses.n_body_samples
            if nb is None and n is None:
                n = None
            else:
                n_m = np.ones((self.N, self.M)) if n is None else n
                n_b = np.ones((self.N, self.B)) if nb is None else np.asarray(nb, float)
                n = np.concatenate([n_m, n_b, n_b], axis=1)
        if n is not None and n.shape == self.visible.shape and np.all(n[self.visible] > 0):
            self.base_weights = np.where(self.visible, n / np.median(n[self.visible]), 0.0)
        # on a tree, the tracked link of each marker, then each body (index in spec.tracked_links);
        # None where every point rides on the moving frame
        self.point_links: tuple[int, ...] | None = None
        if poses.marker_links:
            try:
                links = poses.links_of(spec.tracked_links or [spec.moving_frame])
            except ValueError as exc:
                raise BadInput(f"{poses.source or 'poses'}: {exc}") from None
            if any(links):
                if spec.link_poses is None:
                    raise BadInput(f"{poses.source or 'poses'}: the markers ride on several links, but the "
                                   f"{spec.name} stand tracks one moving frame")
                self.point_links = tuple(links)
        self.theta_sizes = [len(t.initial) for t in self.terms]
        n_theta = int(sum(self.theta_sizes))
        self.i_td = slice(0, spec.n_td)
        self.i_w = slice(spec.n_td, spec.n_td + 3)
        self.i_t = slice(spec.n_td + 3, spec.n_td + 6)
        self.i_m = slice(spec.n_td + 6, spec.n_td + 6 + 3 * self.M)
        self.i_theta = slice(self.i_m.stop, self.i_m.stop + n_theta)
        self.i_body_pos = slice(self.i_theta.stop, self.i_theta.stop + 3 * self.B)
        self.i_body_rot = slice(self.i_body_pos.stop, self.i_body_pos.stop + 3 * self.B)
        self.n_z = self.i_body_rot.stop
        self.names = (spec.parameter_names + ["mocap.rx", "mocap.ry", "mocap.rz", "mocap.x", "mocap.y", "mocap.z"]
                      + [f"marker.{m}.{a}" for m in poses.marker_names for a in "xyz"]
                      + [f"term.{t.effect}.{n}" for t in self.terms for n in t.parameter_names]
                      + [f"body.{b}.{a}" for b in poses.body_names for a in "xyz"]
                      + [f"body.{b}.{a}" for b in poses.body_names for a in ("rx", "ry", "rz")])
        self.scale = np.concatenate([
            [parameter_scale(p.unit, p.nominal) for p in spec.parameters],
            np.full(6 + 3 * self.M, 1e-3), np.full(n_theta, 1e-3), np.full(6 * self.B, 1e-3)])
        self.tiers = np.array([TD_TIER] * spec.n_td + [NUISANCE_TIER] * (6 + 3 * self.M) + [TERM_TIER] * n_theta
                              + [NUISANCE_TIER] * (6 * self.B))
        self._p_guess = np.broadcast_to(spec.neutral_p(), (self.N, spec.n_p)).copy()
        self.prior_center = np.zeros(self.n_z)
        self.prior_scale = np.zeros(self.n_z)  # rows prior_scale * (z - prior_center); 0 = none
        # the plausible range of td: nominal +- PLAUSIBLE_RANGE typical corrections (see set_plausible)
        self.nominal = np.concatenate([spec.nominal_td(), np.zeros(self.n_z - spec.n_td)])
        self.half_width = np.full(self.n_z, np.inf)
        self.set_plausible(PLAUSIBLE_RANGE)
        self._last: tuple[np.ndarray, float, FitState] | None = None
        self._kin: tuple | None = None  # (td, controls, P, converged) of the last solve
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
        """The observation functions of this stand and channel count, built once per (stand, M + B)
        and shared by every problem of them, and the stand's PlatformModel, once per stand (a model
        selection, k folds and a diagnosis build dozens of problems of one stand); per thread, as
        their buffers are not to be shared between threads."""
        thread = threading.get_ident()  # the maps' buffers and the model's are one thread's
        key = (id(self.spec), self.M + self.B, self.B > 0, thread, self.point_links)
        hit = _BUILT.get(key)
        if hit is None or hit[0] is not self.spec:
            if len(_BUILT) > 16:
                _BUILT.clear()
            model = next((h[2] for k, h in _BUILT.items() if h[0] is self.spec and k[3] == thread), None) \
                or PlatformModel(self.spec)
            hit = _BUILT[key] = (self.spec, _observation_functions(self.spec, self.M + self.B, self.B > 0,
                                                                   self.point_links, self.B), model)
        self._fns = hit[1]
        self.model: PlatformModel = hit[2]  # its solvers keep only scratch buffers: one per stand

    def _call(self, n: int, with_jac: bool, args: list[np.ndarray]) -> list[np.ndarray]:
        """Evaluate the observation function over n poses, CHUNK poses (fewer for a small n) per
        call of a CasADi map on preallocated buffers (a few maps per stand, whatever n: building
        a map costs time in proportion to its length).

        args: per-pose inputs as (n, size) C-ordered arrays, shared inputs (td, w, t, m) as 1-D
        arrays. Returns each output as an (n, rows, cols) array, row-major per pose.
        """
        buf, run, ins, outs, shapes, per_pose, chunk, _ = self._fns.mapped(with_jac, n)
        res = [np.empty((n,) + sh) for sh in shapes]
        per = [np.ascontiguousarray(np.reshape(a, (n, -1)), dtype=float) if k in per_pose else np.ravel(a)
               for k, a in enumerate(args)]
        for k, a in enumerate(per):
            if k not in per_pose:
                ins[k][:] = a
        for start in range(0, n, chunk):
            stop = min(n, start + chunk)
            m = stop - start
            if m == chunk:  # the map reads and writes the arrays themselves: no copies
                for k in per_pose:
                    buf.set_arg(k, memoryview(per[k][start:stop].reshape(-1)))
                for i, r in enumerate(res):
                    buf.set_res(i, memoryview(r[start:stop].reshape(-1)))
                run()
                continue
            for k in per_pose:  # a short chunk: through the map's own buffers
                dst = ins[k].reshape(chunk, -1)
                dst[:m] = per[k][start:stop]
                dst[m:] = per[k][start]  # padded with the chunk's first pose: finite, and thrown away
                buf.set_arg(k, memoryview(ins[k]))
            for i, o in enumerate(outs):
                buf.set_res(i, memoryview(o))
            run()
            for o, r, sh in zip(outs, res, shapes):
                r[start:stop] = o.reshape((chunk,) + sh)[:m]
        return res

    # ------------------------------------------------------------------ pieces
    def split(self, z):
        theta, k = [], self.i_theta.start
        for size in self.theta_sizes:
            theta.append(z[k:k + size])
            k += size
        return z[self.i_td], z[self.i_w], z[self.i_t], z[self.i_m].reshape(self.M, 3), theta

    def split_bodies(self, z):
        """Body placements in z: origins (B, 3) m and rotation vectors (B, 3) rad, in the moving frame."""
        return z[self.i_body_pos].reshape(self.B, 3), z[self.i_body_rot].reshape(self.B, 3)

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
        """Residuals (and the Jacobian) at z. ``poses``: another pose set (held-out prediction).

        The last evaluation of the problem's own poses is kept: asked again at the same z (the
        next robust round, the identifiability and covariance after a fit) with the same body_rho,
        it is returned as it was, not recomputed. Callers must not write into the returned arrays."""
        z = np.asarray(z, float)
        own = poses is None
        if own and self._last is not None and (self._last[2].J is not None or not with_jac) \
                and self._last[1] == self.body_rho and np.array_equal(self._last[0], z):
            return self._last[2]
        state = self._evaluate(z, with_jac, poses)
        if own:
            self._last = (z.copy(), self.body_rho, state)
        return state

    def _evaluate(self, z, with_jac: bool, poses: PoseSet | None) -> FitState:
        own = poses is None
        poses = self.poses if own else poses
        N, M, B = poses.n_poses, self.M, self.B
        td, w, t, m, theta = self.split(z)
        p_body, phi_body = self.split_bodies(z)
        m = np.concatenate([m, p_body])  # the bodies' origins ride as points after the markers
        U = poses.controls
        guess = self._p_guess if own else None
        if self.terms:
            q0, X0, p0, _ = self.kinematics(td, U, guess)
            du, dpose, dm = self._term_offsets(theta, q0, X0, poses)
        else:
            du, dpose, dm = np.zeros((N, self.spec.n_u)), np.zeros((N, 6)), np.zeros((N, M, 3))
        Uo = U + du
        if B:
            dm = np.concatenate([dm, np.zeros((N, B, 3))], axis=1)
        if self.spec.forward is not None:
            outs = self._call(N, with_jac, [Uo, td, w, t, m.ravel(), dpose, dm.reshape(N, -1)])
            ok = np.ones(N, bool)
        else:
            kin = self._kin
            if own and kin is not None and np.array_equal(kin[0], td) and np.array_equal(kin[1], Uo):
                P, ok = kin[2], kin[3]  # a trial's residuals, then its Jacobian: the same solution
            else:
                _, _, P, ok = self.kinematics(td, Uo, guess)
                if own:
                    self._kin = (td.copy(), Uo, P, ok)
            if own:
                self._p_guess = np.where(ok[:, None], P, self._p_guess)
            P = np.where(ok[:, None], P, self._p_guess if own else self.spec.neutral_p())
            outs = self._call(N, with_jac, [Uo, td, P, w, t, m.ravel(), dpose, dm.reshape(N, -1)])
        nP3 = 3 * (M + B)
        measured = np.concatenate([poses.markers, _bodies(poses)[..., :3]], axis=1)
        if not with_jac:
            y = outs[0].reshape(N, -1)
            r = y[:, :nP3].reshape(N, M + B, 3) - measured
            if B:
                e = self._body_rotation_errors(y[:, nP3:].reshape(self._Q_shape(N)), phi_body, poses)
                r = np.concatenate([r, self.body_rho * e], axis=1)
            r[~ok] = np.nan
            return FitState(r, None, ok)
        y = outs[0][:, :, 0]
        J_main, J_offsets = outs[1], outs[2]  # (N, 3 (M + B) [+ 9], cols), row-major per pose
        Y_m = J_main[:, :, self.i_m.start:]
        Y_dpose, Y_u = J_offsets[:, :, :6], J_offsets[:, :, 6:]
        r = y[:, :nP3].reshape(N, M + B, 3) - measured
        if self.n_z == J_main.shape[2]:  # td, w, t, markers only: the function's output as it is
            J = J_main
        else:
            J = np.empty((N, y.shape[1], self.n_z))
            J[:, :, :self.i_m.stop] = J_main[:, :, :self.i_m.stop]  # td, w, t, markers: one block
            J[:, :, self.i_body_pos] = Y_m[:, :, 3 * M:]
            J[:, :, self.i_body_rot] = 0.0
            J[:, :, self.i_theta] = 0.0
        if self.terms:
            k = self.i_theta.start
            for term, th in zip(self.terms, theta):
                known = term.offset_jacobians(th, poses, self.spec.n_u, q0, X0)
                if known is not None:  # a term linear in theta: its columns in one product each
                    K = len(th)
                    d_u, d_pose, d_mk = known
                    if B:
                        d_mk = np.concatenate([d_mk, np.zeros((N, B, 3, K))], axis=1)
                    J[:, :, k:k + K] = (np.einsum("nak,nkj->naj", Y_u, d_u) + np.einsum("nak,nkj->naj", Y_dpose, d_pose)
                                        + np.einsum("nak,nkj->naj", Y_m, d_mk.reshape(N, -1, K)))
                    k += K
                    continue
                base = (term.control_offset(th, poses, self.spec.n_u), term.pose_offset(th, poses, q0, X0),
                        term.marker_offset(th, poses))
                for j in range(len(th)):
                    h = 1e-6 * max(1.0, abs(th[j]))
                    thp = np.array(th, float).copy()
                    thp[j] += h
                    d_u = (term.control_offset(thp, poses, self.spec.n_u) - base[0]) / h
                    d_pose = (term.pose_offset(thp, poses, q0, X0) - base[1]) / h
                    d_m = (term.marker_offset(thp, poses) - base[2]) / h
                    if B:
                        d_m = np.concatenate([d_m, np.zeros((N, B, 3))], axis=1)
                    col = (np.einsum("nak,nk->na", Y_u, d_u) + np.einsum("nak,nk->na", Y_dpose, d_pose)
                           + np.einsum("nak,nk->na", Y_m, d_m.reshape(N, -1)))
                    J[:, :, k] = col
                    k += 1
        J_pts = J[:, :nP3].reshape(N, M + B, 3, self.n_z)
        if B:
            e, J_rot = self._body_rotation_errors(y[:, nP3:].reshape(self._Q_shape(N)), phi_body, poses,
                                                  J[:, nP3:].reshape(self._Q_shape(N) + (self.n_z,)))
            r = np.concatenate([r, self.body_rho * e], axis=1)
            J_pts = np.concatenate([J_pts, self.body_rho * J_rot], axis=1)
        r[~ok] = np.nan
        return FitState(r, J_pts, ok)

    def _Q_shape(self, N: int) -> tuple[int, ...]:
        """Shape of the bodies' mocap_from_link rotations in the observation: one (N, 3, 3) for
        all, or on a tree one per body (N, B, 3, 3)."""
        return (N, 3, 3) if self.point_links is None else (N, self.B, 3, 3)

    def _body_rotation_errors(self, Q, phi_body, poses: PoseSet, dQ=None):
        """Each body's orientation error e = log(R_meas^T Q exp(phi_b)) (N, B, 3) rad (NaN unseen) and,
        with dQ (N, 3, 3, n_z) the derivatives of Q = mocap_from_moving rotation, de/dz (N, B, 3, n_z).
        On a tree Q (N, B, 3, 3) and dQ (N, B, 3, 3, n_z): each body's own link."""
        N, B = Q.shape[0], self.B
        if Q.ndim == 3:
            Q = np.broadcast_to(Q[:, None], (N, B, 3, 3))
            if dQ is not None:
                dQ = np.broadcast_to(dQ[:, None], (N, B) + dQ.shape[1:])
        Rb = matrix_from_rotvec(phi_body)  # (B, 3, 3)
        seen = np.all(np.isfinite(poses.bodies), axis=2)
        Rm = matrix_from_quat(np.where(seen[..., None], poses.bodies[..., 3:], np.array([1.0, 0, 0, 0])))
        pred = np.einsum("nkab,kbc->nkac", Q, Rb)
        e = log_so3(np.einsum("nkba,nkbc->nkac", Rm, pred))  # (N, B, 3)
        e[~seen] = np.nan
        if dQ is None:
            return e
        S = np.einsum("nkba,nkbcz->nkacz", Q, dQ)  # Q^T dQ: skew, the link's angular rates
        v = 0.5 * np.stack([S[:, :, 2, 1] - S[:, :, 1, 2], S[:, :, 0, 2] - S[:, :, 2, 0], S[:, :, 1, 0] - S[:, :, 0, 1]],
                           axis=2)  # (N, B, 3, n_z)
        Jinv = right_jacobian_inv(np.nan_to_num(e))  # (N, B, 3, 3)
        de = np.einsum("nkab,kcb,nkcz->nkaz", Jinv, Rb, v)
        for b in range(B):
            cols = slice(self.i_body_rot.start + 3 * b, self.i_body_rot.start + 3 * b + 3)
            de[:, b, :, cols] = Jinv[:, b] @ right_jacobian(phi_body[b])
        return e, de

    # ------------------------------------------------------------------ initial values
    def initial_registration(self, td) -> np.ndarray:
        """Transform and markers by rigid alignment at nominal kinematics: z (n_z,).

        A rigid body enters as three points of its frame (origin and two axis tips,
        :func:`~platkit.bodies.body_frame_points`); its placement is read back from them.
        """
        poses = self.poses
        q, X, _, ok = self.kinematics(td, poses.controls)
        R = matrix_from_quat(q)
        M, B = self.M, self.B
        Y = np.concatenate([poses.markers, body_frame_points(_bodies(poses))], axis=1)
        vis = np.concatenate([self.visible[:, :M], np.repeat(self.visible[:, M:M + B], 3, axis=1)], axis=1)
        vis &= ok[:, None]
        if self.point_links is None:
            A = self._initial_rotation(R, X, Y, vis)
            R, X = R[:, None], X[:, None]  # one frame for every point
        else:  # each point on its link's frame; the rotation from the link that carries the most points
            links = np.array(list(self.point_links[:M]) + [k for k in self.point_links[M:] for _ in range(3)])
            R_all, X_all = self.link_frames(td, poses.controls)
            R, X = R_all[:, links], X_all[:, links]
            best = int(np.argmax(np.bincount(links, weights=vis.sum(axis=0))))
            on = links == best
            A = self._initial_rotation(R_all[:, best], X_all[:, best], Y[:, on], vis[:, on])
        keep = vis.copy()
        for _ in range(6):  # alternate: markers by least squares, then Kabsch; gross outliers left out
            mk, b = self._markers_given_rotation(A, R, X, Y, keep)
            pts = X + np.einsum("nmab,mb->nma", R, mk)
            d = np.linalg.norm(pts @ A.T + b - np.where(vis[..., None], Y, 0.0), axis=2)
            sigma = _robust_sigma(d[vis])
            keep = vis & (d <= max(REJECT_K * sigma, 1e-12))
            A, b = rigid_fit(pts[keep], Y[keep])
        mk, b = self._markers_given_rotation(A, R, X, Y, keep)
        z = np.zeros(self.n_z)
        z[self.i_td] = td
        z[self.i_w] = rotvec_from_matrix(A)
        z[self.i_t] = b
        z[self.i_m] = mk[:M].ravel()
        if B:
            origin, Rb = placement_from_frame_points(mk[M:].reshape(B, 3, 3))
            z[self.i_body_pos] = origin.ravel()
            z[self.i_body_rot] = rotvec_from_matrix(Rb).ravel()
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

    def link_frames(self, td, U) -> tuple[np.ndarray, np.ndarray]:
        """:func:`link_frames` of this problem's stand."""
        return link_frames(self.spec, td, U)

    @staticmethod
    def _markers_given_rotation(A, R, X, Y, vis):
        """Linear least squares for marker positions m (M, 3) and translation b given A
        (normal equations; the blocks (A R_n)^T (A R_n) are identities). R (N, M or 1, 3, 3) and
        X (N, M or 1, 3): the frame each marker rides on; R (N, 3, 3) and X (N, 3): one for all."""
        N, M = vis.shape
        R = np.broadcast_to(R[:, None] if R.ndim == 3 else R, (N, M, 3, 3))
        X = np.broadcast_to(X[:, None] if X.ndim == 2 else X, (N, M, 3))
        H = np.zeros((3 * M + 3, 3 * M + 3))
        g = np.zeros(3 * M + 3)
        C = np.einsum("ab,nmbc->nmac", A, R)  # (N, M, 3, 3): d y / d m
        res = Y - X @ A.T  # (N, M, 3)
        for i in range(M):
            v = vis[:, i]
            k = slice(3 * i, 3 * i + 3)
            H[k, k] = v.sum() * np.eye(3)
            Ct = C[v, i].sum(axis=0).T
            H[k, 3 * M:] = Ct
            H[3 * M:, k] = Ct.T
            g[k] = np.einsum("nba,nb->a", C[v, i], res[v, i])
            g[3 * M:] += res[v, i].sum(axis=0)
        H[3 * M:, 3 * M:] = vis.sum() * np.eye(3)
        sol = np.linalg.lstsq(H, g, rcond=None)[0]
        return sol[:3 * M].reshape(M, 3), sol[3 * M:]


#: poses per call of the observation map (building a map costs in proportion to its length)
CHUNK = 256
_BUILT: dict = {}


_compile_lock = threading.Lock()
#: pose evaluations of one function (in one process) after which its compiled library is looked
#: for in the cache, and after which it is compiled there. Compiling costs about as much as
#: interpreting some 35,000 pose evaluations (4.4 s for the TIAGo arm's 52,000 instructions, 120
#: us a pose interpreted; 0.6 s for the stewart stand's 7,900), once per machine: a calibration
#: of 10,000 poses compiles at its first evaluation, a diagnosis of the 37 TIAGo postures
#: (1,700 evaluations) after a fifth of its refits, and every later run finds the library; a
#: test of 40 poses never waits for the compiler
LOOK_AFTER, COMPILE_AFTER = 2_000, 10_000
COMPILE_FLAGS = ["-O1", "-ffp-contract=off", "-fPIC", "-shared"]
#: ... and for a function of at most SMALL_FUNCTION instructions: -O2, whose code gives the same
#: numbers bit for bit (no contraction, no reassociation) and evaluates the stewart stand's
#: Jacobians 1.6x as fast (22 against 36 ms for 10,000 poses), for a compile of 1.2 s instead of
#: 0.7 s once per machine; the TIAGo arm's 52,000 instructions would take 16 s instead of 4.9 s
#: (2026-11-25, 2-core machine at load 4), so larger functions keep -O1
COMPILE_FLAGS_SMALL = ["-O2", "-ffp-contract=off", "-fPIC", "-shared"]
SMALL_FUNCTION = 20_000


_compiler = c_compiler  # the one lookup (platkit.io.cache); a name here that tests may patch


def compile_flags(f: ca.Function) -> list[str]:
    """The compiler flags of ``f``: :data:`COMPILE_FLAGS_SMALL` up to SMALL_FUNCTION instructions."""
    return COMPILE_FLAGS_SMALL if f.n_instructions() <= SMALL_FUNCTION else COMPILE_FLAGS


def _compiled(f: ca.Function, compile_now: bool) -> ca.Function | None:
    """``f`` compiled to C and loaded as an external function: from the cache, or, with
    ``compile_now``, compiled with the system compiler and kept there
    (:func:`platkit.native.compiled_library`, named by a hash of its C source, the compiler, the
    flags and CasADi's version). None where there is no library and ``compile_now`` is false,
    without a compiler, with PLATKIT_COMPILE=0, or when compiling fails (the caller keeps CasADi's
    interpreter). The same operations, no floating-point contraction: the interpreter's numbers to
    rounding (1e-15 m measured)."""
    cc = _compiler()
    if cc is None:
        return None
    cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
    cg.add(f)
    with _compile_lock:
        built = compiled_library(cg.dump(), "observe", compile_flags(f), cc=cc, salt=ca.__version__,
                                 compile_now=compile_now, timeout=600)
        if isinstance(built, str):
            return None
        try:
            return ca.external(f.name(), str(built))
        except RuntimeError:
            return None


def _chunk_for(n: int) -> int:
    """Poses per map call for n poses: CHUNK, or n itself below it (no padding: a map of a few
    dozen poses is built in milliseconds, and the folds and refits of a session reuse a few)."""
    return min(CHUNK, max(1, n))


class _ObservationFunctions:
    """The CasADi observation functions of one stand and channel count and their maps.

    The outputs are transposed so that a map lays each pose's block out row-major (rows, cols):
    y, then J = [dy/dtd | dy/dw | dy/dt | dy/dm] in the unknowns' order of CalibrationProblem
    (without model terms or rigid bodies' rotations it is the problem's Jacobian as it is), then
    [dy/ddpose | dy/du] for the terms' offsets. Each function is interpreted by CasADi until it has
    been evaluated on LOOK_AFTER poses, then taken compiled from the cache if there, and
    compiled after COMPILE_AFTER poses (:func:`_compiled`)."""

    def __init__(self, G: ca.Function, Yonly: ca.Function, shared: list[int]):
        self.G, self.Yonly, self.shared = G, Yonly, shared
        self._maps: dict = {}
        self._native: dict = {}  # with_jac -> compiled function, or None once compiling was tried
        self._evaluated = {True: 0, False: 0}
        self._looked = {True: False, False: False}

    def native(self, with_jac: bool) -> ca.Function:
        """The function behind the maps now: compiled where the policy above has made it so."""
        f = self.G if with_jac else self.Yonly
        if with_jac in self._native:  # decided: compiled, or None where compiling failed
            got = self._native[with_jac]
            return f if got is None else got
        n = self._evaluated[with_jac]
        if n >= COMPILE_AFTER:
            got = self._native[with_jac] = _compiled(f, compile_now=True)
            return f if got is None else got
        if n >= LOOK_AFTER and not self._looked[with_jac]:
            self._looked[with_jac] = True
            found = _compiled(f, compile_now=False)
            if found is not None:
                self._native[with_jac] = found
                return found
        return f

    def mapped(self, with_jac: bool, n: int):
        """(buffer, run, inputs, outputs, shapes, per-pose inputs, chunk) of the map for n poses."""
        f = self.native(with_jac)
        self._evaluated[with_jac] += n
        chunk = _chunk_for(n)
        key = (id(f), chunk)
        entry = self._maps.get(key)
        if entry is None:
            if len(self._maps) > 64:
                self._maps.clear()
            fmap = f.map(f"{f.name()}_{chunk}", "serial", chunk, self.shared, [])
            buf, run = fmap.buffer()
            ins = [np.zeros(fmap.nnz_in(i)) for i in range(fmap.n_in())]
            outs = [np.zeros(fmap.nnz_out(i)) for i in range(fmap.n_out())]
            for i, a in enumerate(ins):
                buf.set_arg(i, memoryview(a))
            for i, a in enumerate(outs):
                buf.set_res(i, memoryview(a))
            shapes = [(fmap.size_out(i)[1] // chunk, fmap.size_out(i)[0]) for i in range(fmap.n_out())]
            per_pose = [i for i in range(fmap.n_in()) if i not in self.shared]
            entry = self._maps[key] = (buf, run, ins, outs, shapes, per_pose, chunk, f)
        return entry


def _observation_functions(spec: PlatformSpec, M: int, with_bodies: bool,
                           point_links: tuple[int, ...] | None = None, n_bodies: int = 0) -> _ObservationFunctions:
    """Build the observation function of ``spec`` for M points (markers, then bodies' origins).

    ``point_links`` (M,): on a tree, the tracked link each point rides on (the last ``n_bodies``
    are the bodies' origins; index in
    ``spec.tracked_links``; :attr:`PlatformSpec.link_poses` gives their poses); the terms' pose
    offsets act on each link's pose alike, and each body's orientation is read from its own
    link (9 numbers per body instead of one 3x3 for all)."""
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
        if with_bodies:  # Q = mocap_from_moving rotation, row by row, for the bodies' orientations
            Q = ca.mtimes(A, R)
            pts += [Q[i, j] for i in range(3) for j in range(3)]
        return ca.vertcat(*pts)

    def observe_links(qs, Xs):
        Rs = [ca.mtimes(ca_matrix_from_rotvec(dpose[3:6]), ca_matrix_from_quat(q)) for q in qs]
        pts = []
        for i in range(M):
            k = point_links[i]
            pts.append(ca.mtimes(A, Xs[k] + dpose[0:3] + ca.mtimes(Rs[k], m[3 * i:3 * i + 3] + dm[3 * i:3 * i + 3])) + t)
        if with_bodies:  # each body's mocap_from_link rotation, row by row
            for k in point_links[M - n_bodies:]:
                Q = ca.mtimes(A, Rs[k])
                pts += [Q[i, j] for i in range(3) for j in range(3)]
        return ca.vertcat(*pts)

    if spec.forward is not None and point_links is not None:
        L = len(spec.tracked_links)
        q_all, X_all = spec.link_poses(u, td)
        y = observe_links([q_all[4 * k:4 * k + 4] for k in range(L)], [X_all[3 * k:3 * k + 3] for k in range(L)])
        G = ca.Function(
            "observe_tree", [u, td, w, t, m, dpose, dm],
            [y.T, ca.densify(ca.horzcat(ca.jacobian(y, td), ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m)).T),
             ca.densify(ca.horzcat(ca.jacobian(y, dpose), ca.jacobian(y, u)).T)],
            ["u", "td", "w", "t", "m", "dpose", "dm"], ["y", "J", "J_offsets"])
        return _ObservationFunctions(G, ca.Function("observe_tree_y", [u, td, w, t, m, dpose, dm], [y.T]),
                                     [1, 2, 3, 4])
    if point_links is not None:
        raise BadInput(f"stand {spec.name!r}: markers on several links need a closed-form forward and link_poses")
    if spec.forward is not None:
        q, X = spec.forward(u, td)
        y = observe(q, X)
        G = ca.Function(
            "observe_fwd", [u, td, w, t, m, dpose, dm],
            [y.T, ca.densify(ca.horzcat(ca.jacobian(y, td), ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m)).T),
             ca.densify(ca.horzcat(ca.jacobian(y, dpose), ca.jacobian(y, u)).T)],
            ["u", "td", "w", "t", "m", "dpose", "dm"], ["y", "J", "J_offsets"])
        return _ObservationFunctions(G, ca.Function("observe_fwd_y", [u, td, w, t, m, dpose, dm], [y.T]),
                                     [1, 2, 3, 4])
    # through the Newton solution p(u, td) of r(u, td, p) = 0: dp/d(td, u) = -F_p^+ [F_td F_u],
    # solved per pose inside the function (F_p^+ = F_p^-1, or (F_p^T F_p)^-1 F_p^T with more
    # residuals than pose coordinates)
    p = ca.SX.sym("p", spec.n_p)
    q, X = spec.pose(p)
    y = observe(q, X)
    r = spec.residual(u, td, q, X)
    F_p = ca.jacobian(r, p)
    F_rest = ca.horzcat(ca.jacobian(r, td), ca.jacobian(r, u))  # sparse: a leg's residual, its own parameters
    Y_p = ca.jacobian(y, p)
    if F_p.shape[0] == F_p.shape[1]:  # Y_p F_p^-1 first: fewer right-hand sides, then F_rest's sparsity
        Z = ca.solve(F_p.T, Y_p.T).T
    else:
        Z = ca.mtimes(ca.solve(ca.mtimes(F_p.T, F_p), Y_p.T).T, F_p.T)
    Y_rest = -ca.mtimes(Z, F_rest)
    G = ca.Function(
        "observe_ift", [u, td, p, w, t, m, dpose, dm],
        [y.T, ca.densify(ca.horzcat(Y_rest[:, :spec.n_td], ca.jacobian(y, w), ca.jacobian(y, t), ca.jacobian(y, m)).T),
         ca.densify(ca.horzcat(ca.jacobian(y, dpose), Y_rest[:, spec.n_td:]).T)],
        ["u", "td", "p", "w", "t", "m", "dpose", "dm"], ["y", "J", "J_offsets"])
    return _ObservationFunctions(G, ca.Function("observe_ift_y", [u, td, p, w, t, m, dpose, dm], [y.T]),
                                 [1, 3, 4, 5])


def link_frames(spec: PlatformSpec, td, U) -> tuple[np.ndarray, np.ndarray]:
    """Every tracked link's rotation (N, L, 3, 3) and position (N, L, 3) m in the base frame of a
    tree stand (``spec.link_poses``), for controls U (N, n_u) and parameters td (n_td,)."""
    U = np.atleast_2d(np.asarray(U, float))
    N, L = len(U), len(spec.tracked_links)
    q_all, X_all = spec.link_poses.map(N)(U.T, np.asarray(td, float))
    q_all = np.asarray(q_all).T.reshape(N, L, 4)
    X_all = np.asarray(X_all).T.reshape(N, L, 3)
    return matrix_from_quat(q_all), X_all


def _bodies(poses: PoseSet) -> np.ndarray:
    """poses.bodies (N, B, 7); (N, 0, 7) for a pose set without bodies whatever its rows were
    changed to after it was made (controls and markers reassigned in place)."""
    return poses.bodies if poses.n_bodies else np.zeros((poses.n_poses, 0, 7))


def _robust_sigma(d: np.ndarray) -> float:
    """Per-axis noise sigma from 3-D error norms, robustly (median)."""
    d = d[np.isfinite(d)]
    return float(np.median(d) / MAXWELL_MEDIAN) if d.size else float("nan")
