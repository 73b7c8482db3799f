"""The identification method of Burlakov, Latonov and Chertopolokhov (2018), as the paper gives it.

Reference for the default estimator (estimate.py), reached by ``platkit calibrate --method paper``.

- Step 1, the rigid marker frame: weighted centroid C^u of the markers at every control u, then
  the marker coordinates S'_i in a frame attached to the moving part and its rotation q^u by the
  paper's iteration (a generalised Procrustes problem): for every u the rotation q^u minimising
  sum_i |P'_i^u - q^u S'_i (q^u)^-1|^2, then S'_i = mean_u (q^u)^-1 P'_i^u q^u re-centred so that
  sum_i w_i S'_i = 0; from S'^0 = P'^{u_0}, until S' stops changing.
- Step 2, the model poses q_m^u by forward kinematics (Newton) under td.
- Step 3, the constant rotation q^delta between the real and model moving frames, minimising
  J = sum_u |q^u o q^delta o (q_m^u)^-1 - q^e| on the unit sphere by Levenberg-Marquardt with
  the equality constraint |q^delta| = 1 (steps in the sphere's tangent space, renormalised).
- Outer loop: J minimised over td by Nelder-Mead (scipy).

The paper assumes that the motion-capture frame coincides with the model's base frame ("without
loss of generality"). A session does not promise that, so step 3 here also carries the constant
rotation q^a of the base in the motion-capture frame, J = sum_u |(q^a)^-1 o q^u o q^delta o
(q_m^u)^-1 - q^e|, on the same sphere-constrained LM; with q^a = q^e it is the paper's functional.
The paper's J sees orientations only; to predict markers the output also needs positions, so
after the fit the translation of the base in the mocap frame and the marker positions on the
moving part are found by linear least squares given the rotations (not part of the paper's
method, and not used to choose td). Poses where a marker is missing are left out (step 1 needs
every marker). No covariance: std is not given. A stand whose moving part never turns, or turns
about one axis only, on the given poses is refused before any work (:func:`refuse_unserved`).
"""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np
from scipy.optimize import minimize

from platkit.calibrate.identifiability import rotation_fixed_directions
from platkit.calibrate.problem import CalibrationProblem, Progress, parameter_scale
from platkit.calibrate.registration import markers_given_rotation
from platkit.calibrate.solve import _rms, blas_threads
from platkit.calibrate.stages import free_mask
from platkit.errors import BadInput
from platkit.geometry import (
    matrix_from_quat,
    quat_conjugate,
    quat_from_matrix,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    rotvec_from_matrix,
)
from platkit.io.calibration import Calibration, FitRecord
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet


def marker_frame(markers: np.ndarray, weights: np.ndarray | None = None, tol: float = 1e-12, max_iter: int = 200):
    """Step 1. markers: (N, M, 3) with every marker seen. Returns (C (N, 3) centroids, q (N, 4)
    rotations of the marker frame, S (M, 3) marker coordinates in it, iterations)."""
    N, M, _ = markers.shape
    w = np.ones(M) if weights is None else np.asarray(weights, float)
    C = (markers * w[None, :, None]).sum(axis=1) / w.sum()
    P = markers - C[:, None, :]
    S = P[0].copy()
    R = np.repeat(np.eye(3)[None], N, axis=0)
    it = 0
    for it in range(1, max_iter + 1):
        # rotation per pose: Kabsch without translation (both sets are centred)
        H = np.einsum("mi,nmj->nij", S * w[:, None], P)
        U, _, Vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(np.einsum("nji,nkj->nik", Vt, U)))
        D = np.repeat(np.eye(3)[None], N, axis=0)
        D[:, 2, 2] = d
        R = np.einsum("nji,njk,nlk->nil", Vt, D, U)  # R = V D U^T
        S_new = np.einsum("nji,nmj->mi", R, P) / N  # mean of R^T P'
        S_new -= (S_new * w[:, None]).sum(axis=0) / w.sum()
        change = np.max(np.abs(S_new - S))
        S = S_new
        if change < tol * max(1.0, np.max(np.abs(S))):
            break
    return C, quat_from_matrix(R), S, it


def _left(p: np.ndarray) -> np.ndarray:
    """(..., 4, 4) matrices L with L(p) q = p o q."""
    w, x, y, z = np.moveaxis(np.asarray(p, float), -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, -z, y], -1),
                     np.stack([y, z, w, -x], -1), np.stack([z, -y, x, w], -1)], -2)


def _right(q: np.ndarray) -> np.ndarray:
    """(..., 4, 4) matrices R with R(q) p = p o q."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, z, -y], -1),
                     np.stack([y, -z, w, x], -1), np.stack([z, y, -x, w], -1)], -2)


def _mismatch_operator(q_real, q_model) -> np.ndarray:
    """(N, 4, 4) M_n with q^u o d o (q_m^u)^-1 = M_n d: the functional is linear in q^delta."""
    return np.einsum("nij,njk->nik", _left(q_real), _right(quat_conjugate(q_model)))


def _residual_from(a, delta, M):
    x = _left(quat_conjugate(a)) @ np.einsum("nij,j->ni", M, delta).T  # (4, N)
    x = x.T
    sign = np.where(x[:, :1] < 0, -1.0, 1.0)
    return x - sign * np.array([1.0, 0, 0, 0])


def _qdelta_residual(a, delta, q_real, q_model):
    """(N, 4) residuals (q^a)^-1 o q^u o q^delta o (q_m^u)^-1 - (+-)q^e (sign of the nearer)."""
    return _residual_from(a, delta, _mismatch_operator(q_real, q_model))


def paper_J(a, delta, q_real, q_model) -> float:
    """The paper's functional: sum over poses of the norm of the quaternion mismatch."""
    return float(np.sum(np.linalg.norm(_qdelta_residual(a, delta, q_real, q_model), axis=1)))


def qdelta_jacobian(a, d, M, fit_base: bool = True) -> np.ndarray:
    """d r / d step (N*4, 3 or 6) of the step-3 residuals at step 0, steps q^delta o exp(s_d) and
    q^a o exp(s_a). Exact: the functional is bilinear in (q^a)^-1 and q^delta, and the choice of
    +-q^e in the residual is locally constant."""
    ac = quat_conjugate(a)
    Md = np.einsum("nij,j->ni", M, d)  # (N, 4)
    pure = np.vstack([np.zeros(3), np.eye(3)])  # (4, 3): the pure quaternions (0, e_j) as columns
    # d o exp(s) ~ d + (1/2) d o (0, s);  exp(s)^-1 o a^-1 ~ a^-1 - (1/2) (0, s) o a^-1
    cols = [np.einsum("ij,njk,kl->nil", _left(ac), M, 0.5 * _left(d) @ pure)]  # (N, 4, 3)
    if fit_base:
        La = np.stack([_left(np.concatenate([[0.0], e])) for e in np.eye(3)])  # (3, 4, 4)
        cols.append(-0.5 * np.einsum("jik,kl,nl->nij", La, _left(ac), Md))
    return np.concatenate(cols, axis=2).reshape(-1, 6 if fit_base else 3)


def fit_qdelta(q_real, q_model, a0=None, delta0=None, fit_base: bool = True, max_iter: int = 50, tol: float = 1e-14):
    """Step 3: Levenberg-Marquardt on the unit sphere(s) for q^delta (and q^a when ``fit_base``).

    Minimises sum_u |r_u|^2; steps are rotation vectors in the tangent space, applied as
    q <- q o exp(step) and renormalised, so |q| = 1 holds at every iterate.
    """
    a = np.array([1.0, 0, 0, 0]) if a0 is None else quat_normalize(np.asarray(a0, float))
    d = np.array([1.0, 0, 0, 0]) if delta0 is None else quat_normalize(np.asarray(delta0, float))
    M = _mismatch_operator(q_real, q_model)

    def apply(a, d, step):
        d2 = quat_normalize(quat_multiply(d, quat_from_rotvec(step[:3])))
        a2 = quat_normalize(quat_multiply(a, quat_from_rotvec(step[3:6]))) if fit_base else a
        return a2, d2

    def res(a, d):
        return _residual_from(a, d, M).ravel()

    r = res(a, d)
    cost = r @ r
    lam = 1e-3
    for _ in range(max_iter):
        J = qdelta_jacobian(a, d, M, fit_base)
        g = J.T @ r
        A = J.T @ J
        improved = False
        while lam < 1e12:
            step = np.linalg.solve(A + lam * np.diag(np.maximum(np.diag(A), 1e-12)), -g)
            a2, d2 = apply(a, d, step)
            r2 = res(a2, d2)
            c2 = r2 @ r2
            if c2 <= cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        gain = cost - c2
        a, d, r, cost = a2, d2, r2, c2
        lam = max(lam / 10, 1e-12)
        if gain <= tol * max(cost, 1e-300) or np.linalg.norm(step) < 1e-13:
            break
    return a, d


def _initial_rotations(q_real, q_model):
    """q^a and q^delta to start step 3: q^a from relative rotations (hand-eye), then q^delta."""
    Rr, Rm = matrix_from_quat(q_real), matrix_from_quat(q_model)
    rows = []
    for n in np.unique(np.linspace(1, len(Rr) - 1, min(len(Rr) - 1, 60)).astype(int)):
        A_rel = Rr[n] @ Rr[0].T
        B_rel = Rm[n] @ Rm[0].T
        rows.append(np.kron(np.eye(3), A_rel) - np.kron(B_rel.T, np.eye(3)))
    A = np.eye(3)
    if rows:
        _, s, Vt = np.linalg.svd(np.vstack(rows))
        if s[-2] > 10 * s[-1]:
            A = Vt[-1].reshape(3, 3, order="F")
            if np.linalg.det(A) < 0:
                A = -A
            U_, _, Vt_ = np.linalg.svd(A)
            A = U_ @ np.diag([1, 1, np.linalg.det(U_ @ Vt_)]) @ Vt_
    # q^u = q^a o q_m^u o (q^delta)^-1  =>  q^delta^-1 = mean of (q_m^u)^-1 (q^a)^-1 q^u
    D = np.einsum("nji,kj,nkl->nil", Rm, A, Rr).mean(axis=0)
    U_, _, Vt_ = np.linalg.svd(D)
    Dinv = U_ @ np.diag([1, 1, np.linalg.det(U_ @ Vt_)]) @ Vt_
    return quat_from_matrix(A), quat_from_matrix(Dinv.T)


def refuse_unserved(spec: PlatformSpec, model: PlatformModel, poses: PoseSet) -> None:
    """BadInput (exit 2, before any work) where the paper's method cannot serve the stand on these
    poses: its functional J sees only the moving part's orientation, and the base rotation q^a
    (hand-eye, step 3) needs turns about two axes. A stand that never turns (a delta robot, a
    gantry) or turns about one axis would leave every parameter where it started and report
    the registration's error twice."""
    fb = model.forward_batch(poses.controls, spec.nominal_td(), strict=False)
    ok = fb.converged & fb.on_branch
    fixed = rotation_fixed_directions(matrix_from_quat(fb.q[ok]))
    if fixed.shape[1]:
        how = "never turns" if fixed.shape[1] == 3 else "turns about one axis only"
        raise BadInput(f"--method paper cannot serve the {spec.name} stand on these poses: the paper's functional sees only "
                       f"the moving part's orientation, which here {how}; use the default --method lsq")


def calibrate_paper(poses: PoseSet, spec: PlatformSpec, free: Sequence[str] | None = None, fit_base: bool = True,
                    max_evaluations: int | None = None, progress: Progress | None = None,
                    platform_options: dict | None = None) -> Calibration:
    """Burlakov et al.'s identification: returns a Calibration (method 'paper', no std).

    free: td entries Nelder-Mead moves (names or groups; default every free parameter, as the
    paper moves all of td). max_evaluations: Nelder-Mead budget (default 200 per parameter).
    fit_base False is the paper's literal assumption that the mocap frame is the base frame.
    """
    with blas_threads(1):
        return _calibrate_paper(poses, spec, free, fit_base, max_evaluations, progress, platform_options)


def _calibrate_paper(poses, spec, free, fit_base, max_evaluations, progress, platform_options) -> Calibration:
    t0 = time.perf_counter()
    if poses.n_markers < 3:  # the option cannot serve the session: bad input, before any work
        raise BadInput(f"{poses.source or 'poses'}: --method paper needs at least 3 markers (its marker frame, "
                       f"step 1; it reads no rigid bodies), the session has {poses.n_markers}")
    links = sorted({poses.marker_links.get(n, "") for n in poses.marker_names}) if poses.marker_links else []
    if len(links) > 1:  # step 1's marker frame is one rigid body: markers on several links are none
        raise BadInput(f"{poses.source or 'poses'}: --method paper fits one rigid frame to every marker (step 1), but "
                       f"the markers of this tree session ride on {len(links)} links ({', '.join(links)}); --method "
                       "lsq (the default) fits every branch in one fit")
    full = np.isfinite(poses.markers).all(axis=(1, 2))
    if full.sum() < 3:
        raise BadInput(f"{poses.source or 'poses'}: the paper's method needs poses where every marker is seen; "
                       f"only {int(full.sum())} have all {poses.n_markers}")
    used = poses.subset(full)
    model = PlatformModel(spec)
    mask = free_mask(spec, free)
    refuse_unserved(spec, model, used)
    C, q_real, S, gpa_iterations = marker_frame(used.markers)
    idx = np.nonzero(mask)[0]
    td_nom = spec.nominal_td()
    scale = np.array([parameter_scale(p.unit, p.nominal) for p in spec.parameters])[idx]
    state = {"a": None, "d": None, "evals": 0, "best": np.inf}

    def model_quats(td):
        fb = model.forward_batch(used.controls, td, strict=False)
        return fb.q, fb.converged & fb.on_branch

    q_m, ok = model_quats(td_nom)
    state["a"], state["d"] = _initial_rotations(q_real[ok], q_m[ok])
    if not fit_base:
        state["a"] = np.array([1.0, 0, 0, 0])

    def J_of(x):
        td = td_nom.copy()
        td[idx] = td_nom[idx] + x * scale
        q_m, ok = model_quats(td)
        if ok.sum() < 3:
            return 1e6
        a, d = fit_qdelta(q_real[ok], q_m[ok], state["a"], state["d"], fit_base)
        J = paper_J(a, d, q_real[ok], q_m[ok]) + 4.0 * np.sum(~ok)  # a pose without FK counts as the worst
        state["evals"] += 1
        if J < state["best"]:
            state["best"], state["a"], state["d"] = J, a, d
        if progress is not None and state["evals"] % 200 == 0:
            progress("paper", {"evaluations": state["evals"], "J": state["best"]})
        return J

    J0 = J_of(np.zeros(idx.size))
    budget = max_evaluations if max_evaluations is not None else 200 * max(1, idx.size)
    converged = True
    x = np.zeros(idx.size)
    if idx.size:
        res = minimize(J_of, x, method="Nelder-Mead",
                       options={"maxfev": budget, "xatol": 1e-3, "fatol": 1e-12, "adaptive": idx.size > 5,
                                "initial_simplex": np.vstack([np.zeros(idx.size), np.eye(idx.size)])})
        x, converged = res.x, bool(res.success)
    td = td_nom.copy()
    td[idx] = td_nom[idx] + x * scale
    q_m, ok = model_quats(td)
    a, d = fit_qdelta(q_real[ok], q_m[ok], state["a"], state["d"], fit_base)
    J_final = paper_J(a, d, q_real[ok], q_m[ok])
    # positions for the outputs (not the paper's): linear least squares given the rotations
    problem = CalibrationProblem(spec, poses)
    A = matrix_from_quat(a)

    def registration(td_, A_):
        q, X, _, okk = problem.kinematics(td_, poses.controls)
        vis = problem.visible & okk[:, None]
        m, b = markers_given_rotation(A_, matrix_from_quat(q), X, poses.markers, vis)
        z = np.zeros(problem.n_z)
        z[problem.i_td], z[problem.i_w], z[problem.i_t], z[problem.i_m] = td_, rotvec_from_matrix(A_), b, m.ravel()
        return z

    a0, _ = _initial_rotations(q_real, model_quats(td_nom)[0])
    z_before = registration(td_nom, matrix_from_quat(a0) if fit_base else np.eye(3))
    z_after = registration(td, A)
    st_before = problem.evaluate(z_before, with_jac=False)
    st_after = problem.evaluate(z_after, with_jac=False)
    ones = problem.visible.astype(float)
    _, w, t, m, _ = problem.split(z_after)
    status = ["estimated" if f else "fixed" for f in mask]
    cal = Calibration(
        platform=spec.name, description=None if spec.description_path is None else str(spec.description_path),
        spec=spec, td=td, td_std=np.full(spec.n_td, np.nan), td_nominal=td_nom, td_status=status,
        mocap_rotvec=w.copy(), mocap_translation=t.copy(), mocap_std=np.full(6, np.nan),
        marker_names=list(poses.marker_names), marker_positions=m.copy(), marker_std=np.full((poses.n_markers, 3), np.nan),
        rms_before=_rms(st_before, ones), rms_after=_rms(st_after, ones), length_unit=poses.length_unit,
        platform_options=dict(platform_options or {}), method="paper", converged=converged,
        iterations=int(state["evals"]), n_poses=poses.n_poses, n_markers=poses.n_markers,
        n_observations=int(problem.visible.sum()), n_rejected=0,
        identifiability={"note": "the paper's method does not analyse identifiability; every free parameter is moved"},
    )
    cal.fit = FitRecord(residuals_before=st_before.r, residuals_after=st_after.r, weights_before=ones, weights=ones,
                        controls=poses.controls.copy())
    cal.paper = {"J_before": float(J0), "J_after": float(J_final), "evaluations": int(state["evals"]),
                 "poses_used": int(full.sum()), "procrustes_iterations": int(gpa_iterations),
                 "q_delta": [float(v) for v in d], "q_base_in_mocap": [float(v) for v in a], "fit_base": bool(fit_base)}
    cal.time_s = time.perf_counter() - t0
    if progress is not None:
        progress("done", {"rms_before": cal.rms_before, "rms_after": cal.rms_after, "time_s": cal.time_s})
    return cal
