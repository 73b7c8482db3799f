"""Forward kinematics: the pose from the controls, one vector or a batch, with the errors a person
reads (no convergence, a mirror pose, controls outside their strokes)."""
from __future__ import annotations

import numpy as np

from platkit.errors import BadInput, NoConvergence, WrongBranch
from platkit.geometry import quat_normalize
from platkit.kinematics.newton import NewtonSolver
from platkit.kinematics.results import ForwardBatch, ForwardResult
from platkit.native import CONVERGED, MAX_ITERATIONS, NOT_FINITE, SINGULAR


class ForwardSolver(NewtonSolver):
    """Pose from controls: the stand's closed form where it has one, else Newton's method."""

    def _mirror_error(self, X, g) -> WrongBranch:
        s = self._display_scale
        bad = int(np.sum(~(np.asarray(g) > 0)))
        return WrongBranch(
            f"{self.spec.name} forward kinematics converged to a mirror pose the stand cannot take: origin at "
            f"({', '.join(f'{v / s:.1f}' for v in X)}) {self.length_unit}, {bad} of {len(g)} branch conditions "
            f"violated; start from a guess on the stand's side (the default, neutral, start is)"
        )

    def forward(self, u, td=None, guess=None, strict: bool = True, allow_mirror: bool = False) -> ForwardResult:
        """Pose from controls ``u`` (n_u,). ``guess``: starting p (default: the neutral pose).

        Raises NoConvergence, OutOfWorkspace (controls outside their stroke, when ``strict``) or
        WrongBranch (converged to a mirror pose the stand cannot take; pass ``allow_mirror`` to
        get it flagged instead).
        """
        fast = self._default_call
        if (fast is not None and td is None and guess is None and strict and type(u) is np.ndarray
                and u.shape == fast[0].shape and u.dtype == np.float64 and fast[4] == (self.tol, self.max_iter)):
            fast[0][:] = u
            if fast[2](*fast[3]) == 0:  # within the strokes: solved
                return self._forward_result(fast[1].copy(), allow_mirror)
        u = self.check_controls(u, strict=strict)
        if u.ndim != 1:
            raise BadInput(f"{self.spec.name}: forward takes one control vector; use forward_batch for many")
        if self.spec.forward is not None:
            td = self._td(td)
            q, X = self.spec.forward(u, td)
            q = quat_normalize(np.asarray(q).ravel())
            X = np.asarray(X).ravel()
            p = self.coordinates(q, X) if self.spec.coordinates_from_pose is not None else np.full(self.spec.n_p, np.nan)
            return ForwardResult(p, q, X, 0, 0.0, True)
        p0 = None
        if guess is not None:
            p0 = np.asarray(guess, float)
            if p0.shape != (self.spec.n_p,):
                raise BadInput(f"{self.spec.name}: a guess has {self.spec.n_p} pose coordinates, got {p0.size}")
        return self._forward_result(self._solve_one(u, None if td is None else np.asarray(td, float), p0), allow_mirror)

    def _forward_result(self, out: np.ndarray, allow_mirror: bool) -> ForwardResult:
        """The ForwardResult of one out row of the Newton driver; NoConvergence or WrongBranch."""
        n_p = self.spec.n_p
        iterations, residual, status, on = out[-4:].tolist()
        if status != CONVERGED:
            why = {MAX_ITERATIONS: "the controls may have no assembly, or the start is too far; try another guess",
                   SINGULAR: "the Jacobian became singular on the way (a singular pose, or a bad start)",
                   NOT_FINITE: "the iteration left the domain of the model (not a number)"}[int(status)]
            raise NoConvergence(f"{self.spec.name} forward kinematics", int(iterations), float(residual), why)
        X = out[n_p + 4:n_p + 7]
        if not on and not allow_mirror:
            raise self._mirror_error(X, out[n_p + 7:-4])
        return ForwardResult(out[:n_p], out[n_p:n_p + 4], X, int(iterations), residual, bool(on))

    def forward_batch(self, U, td=None, guess=None, strict: bool = True) -> ForwardBatch:
        """Forward kinematics of many control vectors. ``U``: (N, n_u) -> ForwardBatch (N, ...).
        ``guess``: (n_p,) for all, or (N, n_p).

        Poses that do not converge are flagged (``converged`` False), not raised; mirror poses
        are flagged by ``on_branch`` False.
        """
        U = self.check_controls(np.atleast_2d(U), strict=strict)
        N = U.shape[0]
        td = self._td(td)
        if N == 0:
            n_p = self.spec.n_p
            return ForwardBatch(np.zeros((0, n_p)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0, int),
                                np.zeros(0), np.zeros(0, bool), np.zeros(0, bool))
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
        if guess is None:
            P0, stride = self._p0[None, :], 0
        else:
            P0 = np.asarray(guess, float)
            if P0.ndim == 1:
                P0, stride = P0[None, :], 0
            else:
                stride = self.spec.n_p
            if P0.shape[-1] != self.spec.n_p or (stride and P0.shape[0] != N):
                raise BadInput(f"{self.spec.name}: guesses must be ({self.spec.n_p},) or ({N}, {self.spec.n_p})")
        out = self._solve(U, td, P0, stride)
        n_p = self.spec.n_p
        status = out[:, -2]
        return ForwardBatch(
            out[:, :n_p], out[:, n_p:n_p + 4], out[:, n_p + 4:n_p + 7], out[:, -4].astype(int), out[:, -3].copy(),
            status == CONVERGED, out[:, -1] > 0.5,
        )
