"""The observation model of a calibration: residuals and exact Jacobians of a pose set.

Unknowns (all SI): the stand's free parameters td, the base-to-mocap transform mocap_from_base
(rotation vector w and translation t: 6 numbers), the marker positions m_i on the moving part
(3 per marker) and the parameters theta of any :class:`~platkit.terms.ModelTerm`.
The observation of marker i at pose n is

    y_ni = exp(w) (X_n + exp(dth_n) R(q_n) (m_i + dm_ni) + dX_n) + t

with (q_n, X_n) the forward kinematics of u_n + du_n under td, and (du, dX, dth, dm) the terms'
offsets. Jacobians come from CasADi (:mod:`platkit.calibrate.observation`): for a stand with a
closed-form ``forward`` it is differentiated directly; otherwise through the Newton solution by the
implicit-function theorem, dp/dtd = -F_p^+ F_td and dp/du = -F_p^+ F_u. Terms' offsets are
differentiated in theta by finite differences (they are numpy functions with few parameters) and
chained with the exact Jacobians. The start of every fit is a rigid registration (:mod:`platkit.calibrate.registration`);
the solvers are in :mod:`platkit.calibrate.solve`, the procedure in :mod:`platkit.calibrate.estimate`.

Rigid bodies measured in 6 DOF (:mod:`platkit.bodies`): body b has an unknown placement
(origin p_b, m, and rotation vector phi_b, rad, on the moving part) and two residual channels
after the M markers': its origin, observed like a marker at p_b (channel M + b), and
rho * log(R_meas^T R_pred) with R_pred = exp(w) exp(dth_n) R(q_n) exp(phi_b) (channel M + B + b),
rho = sigma_position / sigma_rotation (m/rad) so that every channel is metres of equal noise.
Its exact Jacobian is J_r^-1(e) R_b^T vee(Q^T dQ) for Q = exp(w) exp(dth_n) R(q_n) (CasADi) and
J_r^-1(e) J_r(phi_b) for phi_b.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from platkit.bodies import (
    DEFAULT_RHO_M_PER_RAD,
    body_frame_points,
    declared_rho,
    log_so3,
    placement_from_frame_points,
    right_jacobian,
    right_jacobian_inv,
)
from platkit.calibrate.observation import observation_for
from platkit.calibrate.registration import digest, kept, registered
from platkit.calibrate.term_columns import by_rows, offset_column, one_row_columns, support
from platkit.effects import with_history
from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, rotvec_from_matrix
from platkit.kinematics.forward import link_frames  # noqa: F401 - callers import it from here too
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

#: Progress callback: ``progress(stage, info)``; stage is 'registration', 'identifiability',
#: 'iteration', 'robust', 'fold', 'done'; info carries 'iteration', 'rms' (m), ... as fitting.
Progress = Callable[[str, dict], None]

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


class FitState:
    """One evaluation: residuals (N, C, 3) m (predicted minus measured, NaN where unseen) and the
    Jacobian (N, C, 3, n_z) with respect to the full unknown vector. C = M + 2 B channels: the
    markers, then each body's origin, then each body's scaled rotation error.

    The Jacobian may be held in ``parts``, arrays (N, C, 3, k_i) side by side along the unknowns
    (:meth:`CalibrationProblem.evaluate` leaves the observation function's columns as the function
    wrote them, the terms' beside them): ``J`` lays it out whole at its first read; the normal
    equations take their columns from the parts (:func:`platkit.calibrate.point_columns.take`)."""

    def __init__(self, r: np.ndarray, J: np.ndarray | None, converged: np.ndarray,
                 structure: np.ndarray | None = None, parts: tuple[np.ndarray, ...] | None = None):
        self.r = r
        self.converged = converged  # (N,) forward kinematics converged
        self.structure = structure  # (C, k): False where J[:, c, :, j], j < k, is 0 at every pose; None: unknown
        self._J, self._parts = J, (None if J is not None else parts)

    @property
    def J(self) -> np.ndarray | None:
        """The Jacobian (N, C, 3, n_z), laid out from its parts at the first read; None without one."""
        if self._J is None and self._parts is not None:
            self._J, self._parts = np.concatenate(self._parts, axis=-1), None
        return self._J

    @property
    def parts(self) -> tuple[np.ndarray, ...] | None:
        """The Jacobian as arrays side by side along the unknowns, without laying it out ((J,) once
        whole); None without a Jacobian."""
        return (self._J,) if self._J is not None else self._parts

    @property
    def has_jacobian(self) -> bool:
        """Whether the evaluation has a Jacobian (whole or in parts)."""
        return self._J is not None or self._parts is not None


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
        self.terms = list(terms)
        self._physical_misfit = any(getattr(t, "physical_misfit", False) for t in self.terms)
        # the history a term reads (the play's memory above all), built once here for callers who
        # gave poses without it: a term would otherwise build it again at every evaluation
        self.poses = poses = with_history(poses, spec) if self.terms else poses
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
        self._term_priors()
        # the plausible range of td: nominal +- PLAUSIBLE_RANGE typical corrections (see set_plausible)
        self.nominal = np.concatenate([spec.nominal_td(), np.zeros(self.n_z - spec.n_td)])
        self.half_width = np.full(self.n_z, np.inf)
        self.set_plausible(PLAUSIBLE_RANGE)
        self._last: tuple[np.ndarray, float, FitState] | None = None
        self._kin: tuple | None = None  # (td, controls, P, converged) of the last solve
        #: None: the solvers take the Jacobian of every pose at once; a number of poses: they take
        #: it that many poses at a time (:meth:`evaluate_blocks`: normal equations and R factors
        #: summed over the blocks), and no evaluation keeps a Jacobian of every pose
        self.row_block: int | None = None
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
        self._term_priors()

    def _term_priors(self) -> None:
        """The terms' own priors on their parameters (ModelTerm.prior), in the same rows."""
        k = self.i_theta.start
        for term, size in zip(self.terms, self.theta_sizes):
            p = term.prior()
            if p is not None:
                self.prior_center[k:k + size] = np.asarray(p[0], float)
                self.prior_scale[k:k + size] = np.asarray(p[1], float)
            k += size

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
        """This problem's observation functions and the stand's model, shared with every problem of
        the stand and point count in this thread (:func:`platkit.calibrate.observation.observation_for`)."""
        self._fns, self.model = observation_for(self.spec, self.M, self.B, self.point_links)
        S = self._fns.structure  # each marker's columns of it not structural zeros: FitState.structure
        self._structure = None if self.B or S is None else S[:3 * self.M].reshape(self.M, 3, -1).any(axis=1)

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
        """Forward kinematics (q (N,4), X (N,3), p (N,n_p), converged (N,)) of controls U (N, n_u);
        with a term whose actuators move apart in time (``ModelTerm.physical_misfit``), a stand with
        more rows than pose coordinates at its rows' weighted least-squares pose whatever their misfit."""
        fb = self.model.forward_batch(U, td, guess=guess, strict=False, refuse_misfit=not self._physical_misfit)
        return fb.q, fb.X, fb.p, fb.converged & fb.on_branch

    def evaluate(self, z, with_jac: bool = True, poses: PoseSet | None = None) -> FitState:
        """Residuals (and the Jacobian) at z. ``poses``: another pose set (held-out prediction).

        The last evaluation of the problem's own poses is kept: asked again at the same z (the
        next robust round, the identifiability and covariance after a fit) with the same body_rho,
        it is returned as it was, not recomputed. Callers must not write into the returned arrays."""
        z = np.asarray(z, float)
        own = poses is None
        if own and self._last is not None and (self._last[2].has_jacobian or not with_jac) \
                and self._last[1] == self.body_rho and np.array_equal(self._last[0], z):
            return self._last[2]
        state = self._evaluate(z, with_jac, poses)
        if own:
            self._last = (z.copy(), self.body_rho, state)
        return state

    def forget(self) -> None:
        """Drop the evaluation kept by :meth:`evaluate` (its Jacobian's memory)."""
        self._last = None

    def _evaluate(self, z, with_jac: bool, poses: PoseSet | None) -> FitState:
        own = poses is None
        poses = self.poses if own else poses
        pre = self._prepare(z, poses if own or not self.terms else with_history(poses, self.spec), own)
        return self._rows(pre, slice(0, poses.n_poses), with_jac, self._term_jacobians(pre) if with_jac else [],
                          in_parts=True)

    def evaluate_blocks(self, z, block: int):
        """The residuals and Jacobian of the problem's own poses, ``block`` poses at a time: yields
        (rows, FitState of those poses). The kinematics of every pose and the terms' offsets and
        their Jacobians in theta are evaluated once; the observation function and the Jacobian's
        assembly per block, so that no array of every pose's Jacobian is ever made. Each block's
        rows are those :meth:`evaluate` gives for them."""
        pre = self._prepare(np.asarray(z, float), self.poses, True)
        jacs = self._term_jacobians(pre)
        for s in range(0, self.N, block):
            rows = slice(s, min(self.N, s + block))
            yield rows, self._rows(pre, rows, True, jacs)

    def _prepare(self, z, poses: PoseSet, own: bool) -> dict:
        """What every pose's rows need: the unknowns split, the terms' offsets, the controls
        reached, the poses' solution P (a stand without a closed-form forward) and which solved."""
        N, M, B = poses.n_poses, self.M, self.B
        td, w, t, m, theta = self.split(z)
        p_body, phi_body = self.split_bodies(z)
        m = np.concatenate([m, p_body])  # the bodies' origins ride as points after the markers
        U = poses.controls
        guess = self._p_guess if own else None
        q0 = X0 = None
        if self.terms:
            if any(term.uses_kinematics for term in self.terms):
                q0, X0, _, _ = self.kinematics(td, U, guess)
            du, dpose, dm = self._term_offsets(theta, q0, X0, poses)
        else:
            du, dpose, dm = np.zeros((N, self.spec.n_u)), np.zeros((N, 6)), np.zeros((N, M, 3))
        Uo = U + du
        if B:
            dm = np.concatenate([dm, np.zeros((N, B, 3))], axis=1)
        P = None
        if self.spec.forward is not None:
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
        measured = np.concatenate([poses.markers, _bodies(poses)[..., :3]], axis=1)
        return {"poses": poses, "td": td, "w": w, "t": t, "m": m.ravel(), "theta": theta, "phi_body": phi_body,
                "q0": q0, "X0": X0, "Uo": Uo, "dpose": dpose, "dm": dm.reshape(N, -1), "P": P, "ok": ok,
                "measured": measured}

    def _term_jacobians(self, pre: dict) -> list:
        """Each term's offsets differentiated in its parameters, for every pose: ('known', K, d_u,
        d_pose, d_mk) from the term's own Jacobians (any of the three None: zero), or ('columns', K,
        [(d_u, d_pose, d_m) per parameter]) by forward differences."""
        poses, N, B, n_u = pre["poses"], pre["poses"].n_poses, self.B, self.spec.n_u
        q0, X0 = pre["q0"], pre["X0"]
        out: list = []
        for term, th in zip(self.terms, pre["theta"]):
            K = len(th)
            known = term.offset_jacobians(th, poses, n_u, q0, X0)
            if known is not None:  # a term linear in theta: its columns in one product each
                d_u, d_pose, d_mk = known
                if d_mk is not None:
                    if B:
                        d_mk = np.concatenate([d_mk, np.zeros((N, B, 3, K))], axis=1)
                    d_mk = d_mk.reshape(N, -1, K)
                out.append(("known", K, d_u, d_pose, d_mk, None if d_mk is None else one_row_columns(d_mk)))
                continue
            base = (term.control_offset(th, poses, n_u), term.pose_offset(th, poses, q0, X0), term.marker_offset(th, poses))
            cols = []
            for j in range(K):
                h = 1e-6 * max(1.0, abs(th[j]))
                thp = np.array(th, float).copy()
                thp[j] += h
                d_u = (term.control_offset(thp, poses, n_u) - base[0]) / h
                d_pose = (term.pose_offset(thp, poses, q0, X0) - base[1]) / h
                d_m = (term.marker_offset(thp, poses) - base[2]) / h
                if B:
                    d_m = np.concatenate([d_m, np.zeros((N, B, 3))], axis=1)
                d_m = d_m.reshape(N, -1)
                cols.append((d_u, d_pose, d_m, tuple(support(d) for d in (d_u, d_pose, d_m))))
            out.append(("columns", K, cols))
        return out

    def _rows(self, pre: dict, rows: slice, with_jac: bool, jacs: list, in_parts: bool = False) -> FitState:
        """Residuals (and the Jacobian) of the poses ``rows`` from :meth:`_prepare`'s ``pre`` and,
        with the Jacobian, :meth:`_term_jacobians`' ``jacs``. ``in_parts``: a Jacobian with terms'
        columns and no rigid bodies is left in two parts (FitState.parts), the observation
        function's columns as it wrote them and the terms' in an array of their own."""
        poses = pre["poses"]
        n, M, B = rows.stop - rows.start, self.M, self.B
        args = [pre["Uo"][rows], pre["td"]] + ([] if pre["P"] is None else [pre["P"][rows]]) + [
            pre["w"], pre["t"], pre["m"], pre["dpose"][rows], pre["dm"][rows]]
        outs = self._fns.call(n, with_jac, args)
        ok = pre["ok"][rows]
        nP3 = 3 * (M + B)
        measured = pre["measured"][rows]
        bodies = _bodies(poses)[rows]
        if not with_jac:
            y = outs[0].reshape(n, -1)
            r = y[:, :nP3].reshape(n, M + B, 3) - measured
            if B:
                e = self._body_rotation_errors(y[:, nP3:].reshape(self._Q_shape(n)), pre["phi_body"], bodies)
                r = np.concatenate([r, self.body_rho * e], axis=1)
            r[~ok] = np.nan
            return FitState(r, None, ok)
        y = outs[0][:, :, 0]
        J_main, J_offsets = outs[1], outs[2]  # (n, 3 (M + B) [+ 9], cols), row-major per pose
        Y_m = J_main[:, :, self.i_m.start:]
        Y_dpose, Y_u = J_offsets[:, :, :6], J_offsets[:, :, 6:]
        r = y[:, :nP3].reshape(n, M + B, 3) - measured
        # in parts: J holds the terms' columns only, from column k0, beside the function's own
        whole = not (in_parts and B == 0 and J_main.shape[1:] == (nP3, self.i_theta.start))
        k0 = 0 if whole else self.i_theta.start
        if self.n_z == J_main.shape[2]:  # td, w, t, markers only: the function's output as it is
            J = J_main
        elif not whole:
            J = np.empty((n, y.shape[1], self.n_z - k0))
        else:
            J = np.empty((n, y.shape[1], self.n_z))
            J[:, :, :self.i_m.stop] = J_main[:, :, :self.i_m.stop]  # td, w, t, markers: one block
            J[:, :, self.i_body_pos] = Y_m[:, :, 3 * M:]
            J[:, :, self.i_body_rot] = 0.0  # the terms' columns: each term's below
        k = self.i_theta.start - k0
        finite = None  # whether the function's Jacobian is finite (a product with a zero is then a zero)
        # the structure of the leading terms' columns, point by point, while each is known: a term
        # whose one part is written by rows (by_rows: the rows of each column), or that has none
        beyond: list | None = [] if self._structure is not None and self._structure.shape[1] == k + k0 else None
        for jac in jacs:
            K = jac[1]
            if jac[0] == "known":
                # each pose's block by a (BLAS) matrix product written in place; a part the term
                # has no offset of (None) is skipped, not multiplied by zeros
                col, parts, written = J[:, :, k:k + K], 0, None
                for Y, d in ((Y_u, jac[2]), (Y_dpose, jac[3]), (Y_m, jac[4])):
                    if d is None:
                        continue
                    written = None if d is not jac[4] or jac[5] is None else \
                        by_rows(Y, d[rows], jac[5], col, parts == 0)
                    if written is None and parts == 0:
                        np.matmul(Y, d[rows], out=col)
                    elif written is None:
                        col += np.matmul(Y, d[rows])
                    parts += 1
                if parts == 0:
                    col[...] = 0.0
                    written = np.zeros((nP3, K), bool)
                elif parts > 1:
                    written = None  # the rows of the sum's other parts are not known
                if beyond is not None:
                    beyond = None if written is None else beyond + [written.reshape(M, 3, K).any(axis=1)]
                k += K
                continue
            beyond = None
            if finite is None:
                finite = bool(np.isfinite(J_offsets).all() and np.isfinite(Y_m).all())
            for d_u, d_pose, d_m, supports in jac[2]:
                J[:, :, k] = offset_column(((Y_u, d_u[rows]), (Y_dpose, d_pose[rows]), (Y_m, d_m[rows])),
                                            supports if finite else None)
                k += 1
        structure = self._structure if not beyond else np.concatenate([self._structure, *beyond], axis=1)
        if J is not J_main and not whole:
            r[~ok] = np.nan
            return FitState(r, None, ok, structure, parts=(J_main.reshape(n, M, 3, k0), J.reshape(n, M, 3, -1)))
        J_pts = J[:, :nP3].reshape(n, M + B, 3, self.n_z)
        if B:
            e, J_rot = self._body_rotation_errors(y[:, nP3:].reshape(self._Q_shape(n)), pre["phi_body"], bodies,
                                                  J[:, nP3:].reshape(self._Q_shape(n) + (self.n_z,)))
            r = np.concatenate([r, self.body_rho * e], axis=1)
            J_pts = np.concatenate([J_pts, self.body_rho * J_rot], axis=1)
        r[~ok] = np.nan
        return FitState(r, J_pts, ok, structure)

    def _Q_shape(self, N: int) -> tuple[int, ...]:
        """Shape of the bodies' mocap_from_link rotations in the observation: one (N, 3, 3) for
        all, or on a tree one per body (N, B, 3, 3)."""
        return (N, 3, 3) if self.point_links is None else (N, self.B, 3, 3)

    def _body_rotation_errors(self, Q, phi_body, bodies: np.ndarray, dQ=None):
        """Each body's orientation error e = log(R_meas^T Q exp(phi_b)) (N, B, 3) rad (NaN unseen;
        ``bodies`` (N, B, 7) the poses' measured bodies) and,
        with dQ (N, 3, 3, n_z) the derivatives of Q = mocap_from_moving rotation, de/dz (N, B, 3, n_z).
        On a tree Q (N, B, 3, 3) and dQ (N, B, 3, 3, n_z): each body's own link."""
        N, B = Q.shape[0], self.B
        if Q.ndim == 3:
            Q = np.broadcast_to(Q[:, None], (N, B, 3, 3))
            if dQ is not None:
                dQ = np.broadcast_to(dQ[:, None], (N, B) + dQ.shape[1:])
        Rb = matrix_from_rotvec(phi_body)  # (B, 3, 3)
        seen = np.all(np.isfinite(bodies), axis=2)
        Rm = matrix_from_quat(np.where(seen[..., None], bodies[..., 3:], np.array([1.0, 0, 0, 0])))
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
        """Transform and markers by rigid alignment at the kinematics of ``td``
        (:mod:`platkit.calibrate.registration`): z (n_z,), the terms at their initial values.

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
            rotation_from = (R, X, Y, vis)
            R, X = R[:, None], X[:, None]  # one frame for every point
        else:  # each point on its link's frame; the rotation from the link that carries the most points
            links = np.array(list(self.point_links[:M]) + [k for k in self.point_links[M:] for _ in range(3)])
            # the frames at td, within a selection kept for its candidates (the same td and controls)
            R_all, X_all = kept("link_frames", digest(id(self.spec), np.asarray(td, float), poses.controls),
                                lambda: (self.spec, *self.link_frames(td, poses.controls)),
                                lambda got: (got[0], got[1].copy(), got[2].copy()))[1:]
            R, X = R_all[:, links], X_all[:, links]
            best = int(np.argmax(np.bincount(links, weights=vis.sum(axis=0))))
            on = links == best
            rotation_from = (R_all[:, best], X_all[:, best], Y[:, on], vis[:, on])
        A, b, mk = registered(R, X, Y, vis, rotation_from)
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

    def link_frames(self, td, U) -> tuple[np.ndarray, np.ndarray]:
        """:func:`link_frames` of this problem's stand."""
        return link_frames(self.spec, td, U)


def _bodies(poses: PoseSet) -> np.ndarray:
    """poses.bodies (N, B, 7); (N, 0, 7) for a pose set without bodies whatever its rows were
    changed to after it was made (controls and markers reassigned in place)."""
    return poses.bodies if poses.n_bodies else np.zeros((poses.n_poses, 0, 7))
