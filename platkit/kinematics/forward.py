"""Forward kinematics: the pose from the controls, one vector or a batch, with the errors a person
reads (no convergence, a mirror pose, controls outside their strokes, a misfit beyond what the
stand declares plausible).

Square stands (as many residual rows as pose coordinates) solve F = 0 by Newton's method; stands
with more rows than coordinates (cable robots, redundantly actuated mechanisms) take the
weighted least-squares pose (Levenberg-Marquardt, rows weighted by their plausible misfit) and
report the rows' misfit beside it. A solution is accepted only when it converged, lies on the
stand's branch, misfits no row beyond its plausible misfit and lies within the coordinates'
bounds. When the first start (the neutral pose) does not give one, the solve starts again from
the poses of a start library (a coarse sample of the stand's free space, with its nominal inverse
kinematics) nearest the controls, nearest first; a pose on the branch beyond the bounds is kept
only when no start gives one within them (Newton from the neutral pose may jump to another
solution of F = 0 that the stand's pose map also holds, a gimbal turned over).
"""
from __future__ import annotations

import functools
import math
import operator

import numpy as np

from platkit.errors import BadInput, NoConvergence, OutOfWorkspace, PlatkitError, WrongBranch
from platkit.geometry import matrix_from_quat, quat_normalize
from platkit.kinematics.newton import NewtonSolver
from platkit.kinematics.results import ForwardBatch, ForwardResult
from platkit.kinematics.sampling import library_poses
from platkit.model import PlatformSpec
from platkit.native import CONVERGED, MAX_ITERATIONS, NOT_FINITE, SINGULAR

#: starts of the library tried, nearest the controls first, after the first start fails
RESTARTS = 8
#: most poses in the start library
LIBRARY_SIZE = 800
_HALF_PI = 0.5 * math.pi


class ForwardSolver(NewtonSolver):
    """Pose from controls: the stand's closed form where it has one, else Newton's method (least
    squares where the rows outnumber the pose coordinates), restarted when it fails."""

    def _mirror_error(self, X, g) -> WrongBranch:
        s = self._display_scale
        bad = int(np.sum(~(np.asarray(g) > 0)))
        return WrongBranch(
            f"{self.spec.name} forward kinematics converged to a mirror pose the stand cannot take: origin at "
            f"({', '.join(f'{v / s:.1f}' for v in X)}) {self.length_unit}, {bad} of {len(g)} branch conditions "
            f"violated; start from a guess on the stand's side (the default, neutral, start is)"
        )

    # ------------------------------------------------------------------ misfit and angles

    @property
    def redundant(self) -> bool:
        """True when the stand's residual has more rows than pose coordinates (least squares)."""
        return self._redundant

    @functools.cached_property
    def _redundant(self) -> bool:
        return self.n_r > self.spec.n_p

    @functools.cached_property
    def _n_p(self) -> int:
        return self.spec.n_p

    @functools.cached_property
    def _plausible(self) -> np.ndarray | None:
        return self.spec.plausible_misfit()

    def _row_misfit(self, u, td, p) -> np.ndarray:
        """The rows' residual (n_r,) at pose coordinates p, SI (unweighted); a copy."""
        _, evaluate, (ub, tdb, pb, rb) = self._F_buffer
        ub[:], tdb[:], pb[:] = u, td, p
        evaluate()
        return rb.copy()

    @functools.cached_property
    def _F_buffer(self):
        """CasADi's low-overhead evaluation of F(u, td, p) on fixed numpy buffers."""
        arrays = [np.zeros(self.spec.n_u), np.zeros(self.spec.n_td), np.zeros(self.spec.n_p), np.zeros(self.n_r)]
        buf, evaluate = self.F.buffer()
        for i in range(3):
            buf.set_arg(i, memoryview(arrays[i]))
        buf.set_res(0, memoryview(arrays[3]))
        return buf, evaluate, arrays

    def _implausible(self, r: np.ndarray) -> bool:
        """Whether the rows' residual r is beyond what the stand declares plausible (rows of a
        stand that declares nothing must close to the solver's tolerance)."""
        if self._plausible is None:
            return not math.sqrt(float(r @ r)) <= max(self.tol, 1e-9)
        return not bool(np.all(np.abs(r) <= self._plausible))

    def _misfit_error(self, r: np.ndarray) -> OutOfWorkspace:
        """The one line naming the rows that miss by more than they may, and by how much."""
        name = self.spec.name
        if self._plausible is None:
            worst = np.argsort(-np.abs(r))[:3]
            rows = ", ".join(f"row {int(i)} misses by {abs(r[i]):.3g}" for i in worst)
            return OutOfWorkspace(
                f"{name} forward kinematics: the controls fit no pose exactly ({rows}); the stand declares no "
                f"plausible misfit (PlatformSpec.misfit), so its {self.n_r} rows must close")
        ratio = np.abs(r) / self._plausible
        bad = np.nonzero(ratio > 1)[0]
        bad = bad[np.argsort(-ratio[bad])]
        parts = []
        for i in bad[:4]:
            m = self.spec.misfit[int(i)]  # type: ignore[index]
            val, unit = self._show(float(abs(r[i])), m.unit)
            lim, _ = self._show(float(m.plausible), m.unit)
            parts.append(f"{m.name} misses by {val:.4g} {unit} (plausible {lim:.4g})")
        more = f" and {bad.size - 4} more" if bad.size > 4 else ""
        return OutOfWorkspace(
            f"{name} forward kinematics: the controls fit no pose within the stand's plausible misfit: "
            f"{', '.join(parts)}{more} ({bad.size} of {self.n_r} rows beyond)")

    @functools.cached_property
    def _angle_index(self) -> list[int]:
        return [k for k, c in enumerate(self.spec.coordinates) if c.unit == "rad"]

    @functools.cached_property
    def _angle_getter(self):
        """values (list) -> the angle coordinates as a tuple; None for a stand without angles."""
        idx = self._angle_index
        if not idx:
            return None
        if len(idx) == 1:
            k = idx[0]
            return lambda values: (values[k],)
        return operator.itemgetter(*idx)

    def _wrapped(self, p: np.ndarray, q: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Pose coordinates with their angles in (-pi, pi], in the stand's own convention where it
        has one. Angles within (-pi/2, pi/2] are kept as solved; otherwise the first of: the
        stand's coordinates of (q, X) (its canonical angles, e.g. pitch within +-pi/2), each
        angle wrapped into (-pi, pi], that gives the same pose; p unchanged when none does."""
        idx = self._angle_index
        if not idx:
            return p
        values = p.tolist()
        if all(-_HALF_PI < values[k] <= _HALF_PI for k in idx):
            return p
        for cand in self._angle_candidates(p, q, X):
            if not all(-math.pi < cand[k] <= math.pi for k in idx):
                continue
            q2, X2 = self.pose(cand)
            if np.max(np.abs(X2 - X)) <= 1e-9 and 1 - abs(float(q2 @ q)) <= 1e-12:
                return cand
        return p

    def _angle_candidates(self, p, q, X):
        if self.spec.coordinates_from_pose is not None:
            yield self.coordinates(q, X)
        w = p.copy()
        for k in self._angle_index:
            w[k] = math.pi - (math.pi - w[k]) % (2 * math.pi)  # into (-pi, pi]
        yield w

    # ------------------------------------------------------------------ one control vector

    def forward(self, u, td=None, guess=None, strict: bool = True, allow_mirror: bool = False,
                restarts: bool | None = None) -> ForwardResult:
        """Pose from controls ``u`` (n_u,). ``guess``: starting p (default: the neutral pose).

        ``restarts`` (default: when no guess is given): when the first start does not reach the
        stand's own assembly (no convergence, a mirror pose, a misfit beyond the plausible, a pose
        beyond the coordinates' bounds, kept when no restart lands within them), the
        solve starts again from the nearest poses of the start library; an explicit guess is
        honoured alone unless ``restarts`` is True.

        Raises NoConvergence, OutOfWorkspace (controls outside their stroke, when ``strict``, or
        rows missing by more than their plausible misfit) or WrongBranch (converged to a mirror
        pose the stand cannot take; pass ``allow_mirror`` to get it flagged instead).
        """
        fast = self._default_call
        if (fast is not None and td is None and guess is None and strict and type(u) is np.ndarray
                and u.shape == fast[0].shape and u.dtype == np.float64 and fast[4] == (self.tol, self.max_iter)):
            fast[0][:] = u
            if fast[2](*fast[3]) == 0:  # within the strokes: solved
                out = fast[1].copy()
                values = out.tolist()
                if values[-2] == CONVERGED and values[-1] and not self._redundant:
                    n_p = self._n_p
                    p = out[:n_p]
                    get = self._angle_getter
                    if get is not None:
                        angles = get(values)
                        if not (min(angles) > -_HALF_PI and max(angles) <= _HALF_PI):
                            p = self._wrapped(p, out[n_p:n_p + 4], out[n_p + 4:n_p + 7])
                            values[:n_p] = p.tolist()
                    if all(lo <= values[k] <= hi for k, lo, hi in self._bounds):
                        return ForwardResult(p, out[n_p:n_p + 4], out[n_p + 4:n_p + 7], int(values[-4]), values[-3],
                                             True)
                return self._forward_checked(u.copy(), None, None, allow_mirror, restarts is not False, out)
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
        again = (guess is None) if restarts is None else bool(restarts)
        return self._forward_checked(u, None if td is None else np.asarray(td, float), p0, allow_mirror, again)

    def _forward_checked(self, u, td, p0, allow_mirror: bool, again: bool, out=None) -> ForwardResult:
        """Solve from p0 (None: neutral; ``out``: that solve's row, already done); restart from
        the library when the solution is not accepted."""
        if out is None:
            out = self._solve_one(u, td, p0)
        verdict, r = self._verdict(out, u, td)
        if verdict == "ok" or (verdict == "outside" and p0 is None and not again):
            return self._result(out, r)
        first = (out, verdict, r)
        mirror = (out, r) if verdict == "mirror" else None
        outside = (out, r) if verdict == "outside" else None
        if again:
            accepted, outside, mirror = self._from_starts(u, td, self._restart_poses(u, self._td(td), p0), p0,
                                                          outside, mirror)
            if accepted is not None:
                return self._result(*accepted)
        if outside is not None:  # on the branch, beyond the coordinates' bounds, and nothing better found
            return self._result(*outside)
        if allow_mirror and mirror is not None:
            return self._result(*mirror)
        out, verdict, r = first
        n_p = self.spec.n_p
        if verdict == "misfit":
            raise self._misfit_error(r)
        if mirror is not None:
            o = mirror[0]
            raise self._mirror_error(o[n_p + 4:n_p + 7], o[n_p + 7:-4])
        iterations, residual, status = out[-4], out[-3], out[-2]
        why = {MAX_ITERATIONS: "the controls may have no assembly, or the start is too far; try another guess",
               SINGULAR: "the Jacobian became singular on the way (a singular pose, or a bad start)",
               NOT_FINITE: "the iteration left the domain of the model (not a number)"}[int(status)]
        if again:
            why += f" (nor from {RESTARTS} other starts)"
        raise NoConvergence(f"{self.spec.name} forward kinematics", int(iterations), float(residual), why)

    def _verdict(self, out: np.ndarray, u, td, refuse_misfit: bool = True) -> tuple[str, np.ndarray | None]:
        """'ok', 'failed' (no convergence), 'mirror' (off the branch), 'misfit' (rows beyond
        their plausible misfit, where ``refuse_misfit``) or 'outside' (on the branch, outside the
        coordinates' bounds: a solution the restarts try to better, kept when they do not) for one
        out row, with the rows' residual of a redundant stand."""
        if out[-2] != CONVERGED:
            return "failed", None
        r = None
        if self._redundant:
            r = self._row_misfit(u, self._td(td), out[:self.spec.n_p])
            if refuse_misfit and self._implausible(r):
                return "misfit", r
        if not out[-1]:
            return "mirror", r
        if self._bounds:
            n_p = self._n_p
            p = self._wrapped(out[:n_p], out[n_p:n_p + 4], out[n_p + 4:n_p + 7]).tolist()
            if not all(lo <= p[k] <= hi for k, lo, hi in self._bounds):
                return "outside", r
        return "ok", r

    @functools.cached_property
    def _bounds(self) -> tuple[tuple[int, float, float], ...]:
        """(k, lower, upper) of the coordinates whose bounds restrict them: finite, and for an
        angle narrower than (-pi, pi] (angles are wrapped there)."""
        out = []
        for k, c in enumerate(self.spec.coordinates):
            lo, hi = float(c.lower), float(c.upper)
            if c.unit == "rad" and lo <= -math.pi and hi >= math.pi:
                continue
            if math.isfinite(lo) or math.isfinite(hi):
                out.append((k, lo - 1e-9, hi + 1e-9))
        return tuple(out)

    @functools.cached_property
    def _bounds_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """_bounds as arrays: (indices, lower, upper)."""
        b = self._bounds
        return (np.array([x[0] for x in b], int), np.array([x[1] for x in b]), np.array([x[2] for x in b]))

    def within_bounds(self, P: np.ndarray) -> np.ndarray:
        """(N,) bool: which poses P (N, n_p), angles wrapped as forward kinematics gives them, lie
        within the coordinates' bounds (those that restrict, ``_bounds``)."""
        P = np.atleast_2d(P)
        if not self._bounds:
            return np.ones(len(P), bool)
        k, lo, hi = self._bounds_arrays
        return np.all((P[:, k] >= lo) & (P[:, k] <= hi), axis=1)

    def _result(self, out: np.ndarray, r: np.ndarray | None = None) -> ForwardResult:
        n_p = self.spec.n_p
        iterations, residual, _status, on = out[-4:].tolist()
        q, X = out[n_p:n_p + 4], out[n_p + 4:n_p + 7]
        p = self._wrapped(out[:n_p], q, X)
        return ForwardResult(p, q, X, int(iterations), residual, bool(on), r, self._plausible)

    # ------------------------------------------------------------------ the start library

    @functools.cached_property
    def _library(self) -> tuple[np.ndarray, np.ndarray]:
        """(P (K, n_p), U (K, n_u)): poses on the stand's branch with their nominal controls
        inside the strokes, spread over the stand's free space; the starts of a restart.

        A pose-free stand: a grid over the coordinates' bounds mapped through inverse
        kinematics. A control-free stand: the forward images (from the neutral pose) of a grid
        over the control box. Empty where neither can be sampled.
        """
        return library_poses(self, LIBRARY_SIZE)

    def _restart_poses(self, u: np.ndarray, td, p0) -> list[np.ndarray]:
        """The starts of a restart: the neutral pose (when the first start was not it), then the
        library's poses whose nominal controls are nearest ``u`` (stroke-scaled)."""
        starts = [] if p0 is None else [self._p0]
        P, U = self._library
        if len(P):
            span = self._span
            d = np.sum(((U - u) / span) ** 2, axis=1)
            k = min(RESTARTS, len(P))
            near = np.argpartition(d, k - 1)[:k] if len(P) > k else np.arange(len(P))
            starts += [P[i] for i in near[np.argsort(d[near])]]
        return starts

    @functools.cached_property
    def _span(self) -> np.ndarray:
        return np.where(np.isfinite(self._hi - self._lo) & (self._hi > self._lo), self._hi - self._lo, 1.0)

    # ------------------------------------------------------------------ batches

    def forward_batch(self, U, td=None, guess=None, strict: bool = True, restarts: bool = True,
                      refuse_misfit: bool = True) -> ForwardBatch:
        """Forward kinematics of many control vectors. ``U``: (N, n_u) -> ForwardBatch (N, ...).
        ``guess``: (n_p,) for all, or (N, n_p) (the last solution along a path, say).

        Poses that do not converge are flagged (``converged`` False), not raised; mirror poses
        are flagged by ``on_branch`` False; a redundant stand's rows missing by more than their
        plausible misfit count as not converged (``misfit`` holds the rows' residual) unless
        ``refuse_misfit`` is False: then the weighted least-squares pose is the answer whatever
        the rows' misfit (the physical simulator's true plate, held by its rows as by springs of
        stiffness 1 / plausible misfit squared). Rows not solved on the branch from their start are
        solved again from the neutral pose and the start library (``restarts``).
        """
        U = self.check_controls(np.atleast_2d(U), strict=strict)
        N = U.shape[0]
        td = self._td(td)
        n_p = self.spec.n_p
        if N == 0:
            return ForwardBatch(np.zeros((0, n_p)), np.zeros((0, 4)), np.zeros((0, 3)), np.zeros(0, int),
                                np.zeros(0), np.zeros(0, bool), np.zeros(0, bool),
                                np.zeros((0, self.n_r)) if self.redundant else None)
        if self.spec.forward is not None:
            q, X = self._closed_form_map(N)(U.T, td)
            q = quat_normalize(np.asarray(q).T)
            X = np.asarray(X).T
            p = np.full((N, n_p), np.nan)
            if self.spec.coordinates_from_pose is not None:
                p = np.asarray(self._coordinates_map(N)(q.T, X.T)).T
            ones = np.ones(N, bool)
            return ForwardBatch(p, q, X, np.zeros(N, int), np.zeros(N), ones, ones)
        if guess is None:
            P0, stride = self._p0[None, :], 0
        else:
            P0 = np.asarray(guess, float)
            if P0.ndim == 1:
                P0, stride = P0[None, :], 0
            else:
                stride = n_p
            if P0.shape[-1] != n_p or (stride and P0.shape[0] != N):
                raise BadInput(f"{self.spec.name}: guesses must be ({n_p},) or ({N}, {n_p})")
        out = self._solve(U, td, P0, stride)
        R = None
        converged = out[:, -2] == CONVERGED
        if self._redundant:
            R = np.asarray(self._F_map(N)(U.T, td, out[:, :n_p].T)).T
            if refuse_misfit:
                converged &= np.array([not self._implausible(r) for r in R], bool)
        on = out[:, -1] > 0.5
        if restarts:
            retry = ~(converged & on)
            outside = np.zeros(N, bool)
            if self._bounds:
                rows = np.nonzero(~retry)[0]
                P = out[rows, :n_p].copy()
                idx = self._angle_index
                if idx:
                    for j in np.nonzero(np.any(np.abs(P[:, idx]) > _HALF_PI, axis=1))[0]:
                        i = rows[j]
                        P[j] = self._wrapped(out[i, :n_p], out[i, n_p:n_p + 4], out[i, n_p + 4:n_p + 7])
                outside[rows[~self.within_bounds(P)]] = True
                retry |= outside
            for i in np.nonzero(retry)[0]:
                from_neutral = guess is None
                again = self._batch_restart(U[i], td, None if from_neutral else P0[i if stride else 0],
                                            keep_outside=not (from_neutral and outside[i]), refuse_misfit=refuse_misfit)
                if again is not None:
                    out[i], r = again
                    converged[i], on[i] = True, True
                    if R is not None:
                        R[i] = r
        P = out[:, :n_p].copy()
        idx = self._angle_index
        if idx and np.any((P[:, idx] <= -_HALF_PI) | (P[:, idx] > _HALF_PI)):
            for i in np.nonzero(np.any((P[:, idx] <= -_HALF_PI) | (P[:, idx] > _HALF_PI), axis=1))[0]:
                P[i] = self._wrapped(P[i], out[i, n_p:n_p + 4], out[i, n_p + 4:n_p + 7])
        return ForwardBatch(P, out[:, n_p:n_p + 4], out[:, n_p + 4:n_p + 7], out[:, -4].astype(int),
                            out[:, -3].copy(), converged, on, R)

    def least_squares_pose(self, u, td, p0) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool] | None:
        """(p, q, X, on_branch) of one control vector ``u`` of a redundant stand: the rows' weighted
        least-squares pose from ``p0`` by a trust-region solve (scipy's), for rows far apart, where
        the Gauss-Newton steps of :meth:`forward_batch` converge only linearly along a weakly held
        direction (a cable robot's turn); None where it does not converge."""
        from scipy.optimize import least_squares

        td = self._td(td)
        u = np.asarray(u, float)
        sol = least_squares(lambda p: self._rj_one(u, td, p)[0], np.asarray(p0, float),
                            jac=lambda p: self._rj_one(u, td, p)[1], method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-12)
        if sol.status <= 0 or not np.all(np.isfinite(sol.x)):
            return None
        q, X, g = self._post_one(u, td, sol.x)
        return sol.x, quat_normalize(q), X, bool(np.all(g > 0))

    def _batch_restart(self, u, td, p0, keep_outside: bool = True,
                       refuse_misfit: bool = True) -> tuple[np.ndarray, np.ndarray | None] | None:
        """(out row, rows' residual) of the first restart accepted (else, with ``keep_outside``, one
        on the branch beyond the coordinates' bounds: the neutral start's where it gave one, else
        the first), or None. ``p0``: the row's guess, None for the neutral; ``keep_outside`` False
        where the row's own solve is already such a pose; ``refuse_misfit`` as :meth:`forward_batch`'s."""
        try:
            starts = self._restart_poses(u, td, p0)
        except PlatkitError:
            return None
        accepted, outside, _ = self._from_starts(u, td, starts, p0, keep_outside=keep_outside,
                                                 refuse_misfit=refuse_misfit)
        return outside if accepted is None else accepted

    def _from_starts(self, u, td, starts, p0, outside=None, mirror=None, keep_outside: bool = True,
                     refuse_misfit: bool = True):
        """A restart of the solve of ``u``: from each of ``starts`` in turn (:meth:`_restart_poses`
        after the start ``p0``, None for the neutral one) until one is accepted. Returns
        (accepted, outside, mirror), each an (out row, rows' residual) or None: the first solve
        accepted; the pose on the branch beyond the coordinates' bounds kept, ``outside`` as given,
        else the first such, replaced by the neutral start's after a guess (none with
        ``keep_outside`` False); the first mirror pose, ``mirror`` as given. ``refuse_misfit`` as
        :meth:`forward_batch`'s."""
        for j, start in enumerate(starts):
            o = self._solve_one(u, td, start)
            v, r = self._verdict(o, u, td, refuse_misfit)
            if v == "ok":
                return (o, r), outside, mirror
            if v == "mirror" and mirror is None:
                mirror = (o, r)
            if v == "outside" and keep_outside and (outside is None or (p0 is not None and j == 0)):
                outside = (o, r)  # the neutral start's (j = 0 after a guess) before any other
        return None, outside, mirror

    @functools.lru_cache(maxsize=16)  # noqa: B019 - kept with the long-lived model, one per batch size
    def _F_map(self, n: int):
        return self.F.map(n)

    @functools.lru_cache(maxsize=16)  # noqa: B019 - kept with the long-lived model, one per batch size
    def _closed_form_map(self, n: int):
        """The closed-form forward over n poses, td shared by all (read once, not n copies): the
        same numbers as a map over td repeated, in half the time (300 poses of a 20-joint tree)."""
        return self.spec.forward.map(f"forward_{n}", "serial", n, [1], [])

    @functools.lru_cache(maxsize=16)  # noqa: B019 - kept with the long-lived model, one per batch size
    def _coordinates_map(self, n: int):
        return self.spec.coordinates_from_pose.map(n)


@functools.lru_cache(maxsize=32)
def _link_map(f, n: int):
    """``f.map(n)`` (a CasADi function: hashed and compared by identity), built once per function
    and batch size and kept (the link frames of one pose set are asked for again and again: each
    candidate of a model selection, each fit's start)."""
    return f.map(n)


def link_frames(spec: PlatformSpec, td, U) -> tuple[np.ndarray, np.ndarray]:
    """Every tracked link's rotation (N, L, 3, 3) and position (N, L, 3) m in the base frame of a
    tree stand (``spec.link_poses``), for controls U (N, n_u) and parameters td (n_td,)."""
    U = np.atleast_2d(np.asarray(U, float))
    N, L = len(U), len(spec.tracked_links)
    q_all, X_all = _link_map(spec.link_poses, N)(U.T, np.asarray(td, float))
    q_all = np.asarray(q_all).T.reshape(N, L, 4)
    X_all = np.asarray(X_all).T.reshape(N, L, 3)
    return matrix_from_quat(q_all), X_all
