"""Generic kinematics of any registered stand, derived from its CasADi residual.

Forward kinematics solves G(p) = F(u, td, pose(p)) = 0 for the pose coordinates p by Newton's
method (Gauss-Newton where the stand has more equations than coordinates); inverse kinematics
uses the stand's closed form where it has one, else Gauss-Newton over u.

Velocities and accelerations come from differentiating the constraint along a motion:

    G_u u' + G_p p' = 0                                  (first order)
    G_u u'' + G_p p'' + c(u, p; u', p') = 0              (second order)

where ``c = w'^T (d2G/dw2) w'`` with ``w = (u, p)`` is CasADi's ``jtimes`` applied twice. The
twist form replaces p' by the twist (v, omega) of the moving frame in the base frame (v: velocity
of its origin, omega: angular velocity, both in base coordinates), through q' = 1/2 (0, omega) q.

Speed: the Newton loop runs in C (platkit/native.py) when a C compiler is found. The stand's residual and its
Jacobian are generated with CasADi's code generator, a generic Newton driver (nothing in it
knows a stand) is appended, and the result is compiled once into a cache directory
(``$PLATKIT_CACHE_DIR``, default ``~/.cache/platkit``) keyed by a hash of the source. Without a
compiler, or with ``PLATKIT_COMPILE=0``, the same Newton iteration runs in numpy over CasADi
evaluations of (r, J). ``PlatformModel.backend`` says which path is used.
"""
from __future__ import annotations

import ctypes
import functools
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from platkit.errors import BadInput, NoConvergence, OutOfWorkspace, WrongBranch
from platkit.geometry import ca_quat_multiply, matrix_from_quat, quat_normalize, rpy_from_quat
from platkit.model import PlatformSpec, length_scale
from platkit.native import (
    CONVERGED,
    MAX_ITERATIONS,
    NOT_FINITE,
    SINGULAR,
    native_for,
    NativeNewton,
    newton_functions,
)


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


@dataclass
class Conditioning:
    """How far a pose is from a (forward) singularity.

    The matrix studied is the inverse velocity Jacobian ``J`` (control rates per unit motion):
    u' = J t with t the twist (v, omega) for six-coordinate stands, else the coordinate rates
    p'. Angular columns are divided by ``characteristic_length`` so that every column is a
    rate per metre of motion (Angeles' characteristic length, chosen where the neutral pose is
    best conditioned). At a forward singularity J loses rank: ``sigma_min`` -> 0.
    """

    condition_number: float  # sigma_max / sigma_min of the scaled J (1 = isotropic)
    sigma_min: float  # smallest singular value (control units per metre)
    sigma_max: float
    inverse_condition: float  # sigma_min / sigma_max, in [0, 1]; 0 at a singularity
    distance_to_singularity: float  # first-order estimate of the scaled pose distance (m) to sigma_min = 0
    characteristic_length: float  # m
    direction: np.ndarray  # (n,) the motion (scaled twist) that the controls feel least


# ---------------------------------------------------------------------------- the model


class PlatformModel:
    """Numeric solvers for one stand; all Jacobians come from the stand's CasADi functions.

    ``length_unit`` is only the unit in which error messages show lengths ('mm' or 'm').
    ``compile``: False forces the numpy/CasADi Newton (no C compiler involved).
    Instances are not meant to be shared between threads.
    """

    def __init__(self, spec: PlatformSpec, tol: float = 1e-10, max_iter: int = 30, length_unit: str = "mm",
                 compile: bool = True):
        self.spec = spec
        self.tol = tol
        self.max_iter = max_iter
        self.length_unit = length_unit
        self._display_scale = length_scale(length_unit)
        self._compile = compile
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
        self._branch = spec.branch
        self._td0 = spec.nominal_td()
        self._p0 = spec.neutral_p()
        self._lo, self._hi = spec.control_bounds()
        self._lo_tol = self._lo - 1e-12
        self._hi_tol = self._hi + 1e-12
        # the same bounds as Python floats: one control vector is checked faster without numpy
        self._strokes = tuple(zip(self._lo_tol.tolist(), self._hi_tol.tolist()))

    # ------------------------------------------------------------------ helpers
    def _td(self, td) -> np.ndarray:
        return self._td0 if td is None else np.asarray(td, float)

    def _show(self, value: float, unit: str) -> tuple[float, str]:
        """A value in the unit a person reads: 'm' quantities in ``length_unit``."""
        if unit == "m":
            return value / self._display_scale, self.length_unit
        return value, unit

    def check_controls(self, u, strict: bool = True) -> np.ndarray:
        """Controls as an array (n_u,) or (N, n_u); BadInput for a wrong length or a non-finite
        value, OutOfWorkspace (strict) for a value outside its stroke. Messages show lengths in
        the model's ``length_unit``."""
        u = np.asarray(u, dtype=float)
        if u.shape[-1:] != (self.spec.n_u,):
            got = u.shape[-1] if u.ndim else 1
            raise BadInput(
                f"{self.spec.name} takes {self.spec.n_u} controls ({', '.join(self.spec.control_names)}), got {got}"
            )
        # fast path: every value finite and inside its stroke (NaN fails every comparison)
        if strict:
            if u.ndim == 1:
                if all(lo <= v <= hi for (lo, hi), v in zip(self._strokes, u.tolist())):
                    return u
            elif bool(((u >= self._lo_tol) & (u <= self._hi_tol)).all()):
                return u
        finite = np.isfinite(u)
        if not finite.all():
            i = int(np.argwhere(~finite)[0][-1])
            raise BadInput(f"{self.spec.name}: control {self.spec.controls[i].name} is not a finite number")
        if strict:
            bad = (u < self._lo_tol) | (u > self._hi_tol)
            if np.any(bad):
                idx = np.argwhere(bad)[0]
                c = self.spec.controls[int(idx[-1])]
                val, unit = self._show(float(u[tuple(idx)]), c.unit)
                lo, _ = self._show(c.lower, c.unit)
                hi, _ = self._show(c.upper, c.unit)
                row = f" (row {int(idx[0])})" if u.ndim > 1 else ""
                raise OutOfWorkspace(
                    f"{self.spec.name}: control {c.name} = {val:.6g} {unit}{row} is outside its stroke "
                    f"[{lo:.6g}, {hi:.6g}] {unit}"
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

    # ------------------------------------------------------------------ Newton backends
    @functools.cached_property
    def _newton_fns(self):
        return newton_functions(self.spec)

    @functools.cached_property
    def _native(self):
        rj, post, n_g = self._newton_fns
        if not self._compile:
            return "compilation switched off for this model"
        return native_for(self.spec, rj, post, n_g)

    @property
    def backend(self) -> str:
        """Which forward solver runs: 'compiled C (<library>)' or 'casadi+numpy (<why>)'."""
        if self.spec.forward is not None:
            return "closed form (the stand's forward function)"
        nat = self._native
        if isinstance(nat, NativeNewton):
            return f"compiled C ({nat.path})"
        return f"casadi+numpy ({nat})"

    @functools.cached_property
    def _single_buffers(self):
        """Preallocated inputs and output of one forward solve, with their addresses."""
        n_out = self.spec.n_p + 7 + self._newton_fns[2] + 4
        bufs = {"u": np.zeros(self.spec.n_u), "td": np.zeros(self.spec.n_td), "p0": np.zeros(self.spec.n_p),
                "td0": self._td0.copy(), "neutral": self._p0.copy(), "out": np.zeros(n_out)}
        return bufs, {k: v.ctypes.data for k, v in bufs.items()}

    @functools.cached_property
    def _default_call(self):
        """(u buffer, out buffer, the compiled checked solve, its ctypes arguments, (tol,
        max_iter) they were built with) of a solve with the nominal td from the neutral pose
        that first checks the strokes; arguments built once, not converted on every call (a
        warm forward call is a few microseconds, issue 13). None without the compiled solver."""
        nat = self._native
        if not isinstance(nat, NativeNewton) or self.spec.forward is not None:
            return None
        bufs, addr = self._single_buffers
        bounds = np.ascontiguousarray(np.stack([self._lo_tol, self._hi_tol]), dtype=float)
        args = (ctypes.c_void_p(addr["u"]), ctypes.c_void_p(bounds.ctypes.data),
                ctypes.c_void_p(bounds.ctypes.data + bounds.strides[0]), ctypes.c_void_p(addr["td0"]),
                ctypes.c_void_p(addr["neutral"]), ctypes.c_double(self.tol), ctypes.c_int(self.max_iter),
                ctypes.c_void_p(addr["out"]))
        return bufs["u"], bufs["out"], nat.checked, args, (self.tol, self.max_iter), bounds

    def _solve_one(self, u: np.ndarray, td, p0) -> np.ndarray:
        """One Newton solve; returns a fresh out row (see _solve)."""
        nat = self._native
        if not isinstance(nat, NativeNewton):
            return self._solve_numpy_one(u, self._td0 if td is None else td, self._p0 if p0 is None else p0)
        bufs, addr = self._single_buffers
        bufs["u"][:] = u
        if td is None:
            td_addr = addr["td0"]
        else:
            bufs["td"][:] = td
            td_addr = addr["td"]
        if p0 is None:
            p0_addr = addr["neutral"]
        else:
            bufs["p0"][:] = p0
            p0_addr = addr["p0"]
        nat.single(addr["u"], td_addr, p0_addr, self.tol, self.max_iter, addr["out"])
        return bufs["out"].copy()

    def _solve(self, u: np.ndarray, td: np.ndarray, P0: np.ndarray, stride: int) -> np.ndarray:
        """Newton for N problems: u (N, n_u), P0 (N, n_p) or (1, n_p) with stride 0.
        Returns out (N, n_p + 7 + n_g + 4): p, q, X, g, iterations, |r|, status, on_branch."""
        nat = self._native
        N = u.shape[0]
        if isinstance(nat, NativeNewton):
            u = np.ascontiguousarray(u, dtype=float)
            td = np.ascontiguousarray(td, dtype=float)
            P0 = np.ascontiguousarray(P0, dtype=float)
            out = np.empty((N, nat.n_out))
            nat.batch(N, u.ctypes.data, td.ctypes.data, P0.ctypes.data, stride, self.tol, self.max_iter,
                      out.ctypes.data)
            return out
        return self._solve_numpy(u, td, np.broadcast_to(P0, (N, self.spec.n_p)))

    def _solve_numpy_one(self, u: np.ndarray, td: np.ndarray, p0: np.ndarray) -> np.ndarray:
        """One Newton solve with numpy over CasADi buffer evaluations; the C driver's out row."""
        square = self.n_r == self.spec.n_p
        p = np.array(p0, dtype=float)
        status, k = CONVERGED, 0
        while True:
            r, J = self._rj_one(u, td, p)
            nrm = math.sqrt(float(r @ r))
            if not math.isfinite(nrm):
                status = NOT_FINITE
                break
            if nrm <= self.tol:
                if nrm > 0:  # polish, as the C driver does
                    try:
                        step = np.linalg.solve(J, r) if square else np.linalg.lstsq(J, r, rcond=None)[0]
                        rt, _ = self._rj_one(u, td, p - step)
                        nt = math.sqrt(float(rt @ rt))
                        if nt <= nrm:
                            p, nrm = p - step, nt
                    except np.linalg.LinAlgError:
                        pass
                break
            if k >= self.max_iter:
                status = MAX_ITERATIONS
                break
            try:
                step = np.linalg.solve(J, r) if square else np.linalg.lstsq(J, r, rcond=None)[0]
            except np.linalg.LinAlgError:
                status = SINGULAR
                break
            p = p - step
            k += 1
        q, X, g = self._post_one(u, td, p)
        q = q / math.sqrt(float(q @ q))
        if q[0] < 0:
            q = -q
        on = bool(np.all(g > 0))
        return np.concatenate([p, q, X, g, [k, nrm, status, on]])

    def _solve_numpy(self, U: np.ndarray, td: np.ndarray, P0: np.ndarray) -> np.ndarray:
        """The same iteration as the C driver, vectorised over the N problems with numpy."""
        rj, post, n_g = self._newton_fns
        N, n_p = U.shape[0], self.spec.n_p
        P = np.array(P0, dtype=float)
        iters = np.zeros(N)
        norms = np.full(N, np.inf)
        status = np.full(N, -1.0)
        active = np.arange(N)
        for k in range(self.max_iter + 1):
            if active.size == 0:
                break
            if active.size == 1:
                r, J = self._rj_one(U[active[0]], td, P[active[0]])
                r, J = r.reshape(1, -1), J.reshape(1, self.n_r, n_p)
            else:
                r, J = self._rj_map(active.size)(U[active].T, td, P[active].T)
                r = np.asarray(r).T
                J = np.asarray(J).reshape(self.n_r, active.size, n_p).transpose(1, 0, 2)
            nrm = np.linalg.norm(r, axis=1)
            norms[active] = nrm
            iters[active] = k
            done = ~np.isfinite(nrm)
            status[active[done]] = NOT_FINITE
            ok = np.isfinite(nrm) & (nrm <= self.tol)
            status[active[ok]] = CONVERGED
            for j in np.nonzero(ok & (nrm > 0))[0]:  # polish, as the C driver does
                i = active[j]
                try:
                    step = self._lstsq(J[j], r[j]) if self.n_r == n_p else np.linalg.lstsq(J[j], r[j], rcond=None)[0]
                except np.linalg.LinAlgError:
                    continue
                rt, _ = self._rj_one(U[i], td, P[i] - step)
                if np.linalg.norm(rt) <= nrm[j]:
                    P[i] -= step
                    norms[i] = np.linalg.norm(rt)
            keep = ~(done | ok)
            if k >= self.max_iter:
                status[active[keep]] = MAX_ITERATIONS
                break
            active, r, J = active[keep], r[keep], J[keep]
            if active.size == 0:
                break
            if self.n_r != n_p:
                Jt = J.transpose(0, 2, 1)
                A, b = Jt @ J, (Jt @ r[..., None])[..., 0]
            else:
                A, b = J, r
            try:
                step = np.linalg.solve(A, b[..., None])[..., 0]
                good = np.isfinite(step).all(axis=1)
            except np.linalg.LinAlgError:
                step = np.zeros_like(b)
                good = np.zeros(active.size, bool)
                for j in range(active.size):
                    try:
                        step[j] = np.linalg.solve(A[j], b[j])
                        good[j] = np.isfinite(step[j]).all()
                    except np.linalg.LinAlgError:
                        pass
            status[active[~good]] = SINGULAR
            P[active[good]] -= step[good]
            active = active[good]
        if N == 1:
            q, X, g = (a.reshape(1, -1) for a in self._post_one(U[0], td, P[0]))
        else:
            q, X, g = (np.asarray(a).T for a in self._post_map(N)(U.T, td, P.T))
        q = quat_normalize(q)
        on = np.all(g > 0, axis=1) if n_g else np.ones(N, bool)
        return np.column_stack([P, q, X, g.reshape(N, n_g), iters, norms, status, on])

    @functools.cached_property
    def _rj_buffer(self):
        """CasADi's low-overhead evaluation of (r, J) on fixed numpy buffers."""
        rj = self._newton_fns[0]
        arrays = [np.zeros(self.spec.n_u), np.zeros(self.spec.n_td), np.zeros(self.spec.n_p),
                  np.zeros(self.n_r), np.zeros(self.n_r * self.spec.n_p)]
        buf, evaluate = rj.buffer()
        for i in range(3):
            buf.set_arg(i, memoryview(arrays[i]))
        for i in range(2):
            buf.set_res(i, memoryview(arrays[3 + i]))
        return buf, evaluate, arrays

    def _rj_one(self, u, td, p) -> tuple[np.ndarray, np.ndarray]:
        """(r (n_r,), J (n_r, n_p)) at one point, copies."""
        _, evaluate, (ub, tdb, pb, rb, Jb) = self._rj_buffer
        ub[:], tdb[:], pb[:] = u, td, p
        evaluate()
        return rb.copy(), Jb.reshape(self.spec.n_p, self.n_r).T.copy()

    @functools.cached_property
    def _post_buffer(self):
        post, n_g = self._newton_fns[1], self._newton_fns[2]
        arrays = [np.zeros(self.spec.n_u), np.zeros(self.spec.n_td), np.zeros(self.spec.n_p),
                  np.zeros(4), np.zeros(3), np.zeros(n_g)]
        buf, evaluate = post.buffer()
        for i in range(3):
            buf.set_arg(i, memoryview(arrays[i]))
        for i in range(3):
            buf.set_res(i, memoryview(arrays[3 + i]))
        return buf, evaluate, arrays

    def _post_one(self, u, td, p) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q (4,), X (3,), g (n_g,)) at one point, copies."""
        _, evaluate, (ub, tdb, pb, qb, Xb, gb) = self._post_buffer
        ub[:], tdb[:], pb[:] = u, td, p
        evaluate()
        return qb.copy(), Xb.copy(), gb.copy()

    @functools.lru_cache(maxsize=16)
    def _rj_map(self, n: int) -> ca.Function:
        return self._newton_fns[0].map(n)

    @functools.lru_cache(maxsize=16)
    def _post_map(self, n: int) -> ca.Function:
        return self._newton_fns[1].map(n)

    # ------------------------------------------------------------------ forward
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
        for it in range(100):
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

    # ------------------------------------------------------------------ velocity and acceleration
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

    @staticmethod
    def _lstsq(A: np.ndarray, b: np.ndarray) -> np.ndarray:
        if A.shape[0] == A.shape[1]:
            return np.linalg.solve(A, b)
        return np.linalg.lstsq(A, b, rcond=None)[0]

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

    # ------------------------------------------------------------------ conditioning
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
