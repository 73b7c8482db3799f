"""Forward kinematics' Newton iteration, compiled or in numpy.

The Newton loop runs in C (platkit/native.py) when a C compiler is found. The stand's residual
and its Jacobian are generated with CasADi's code generator, a generic Newton driver (nothing in
it knows a stand) is appended, and the result is compiled once into a cache directory
(``$PLATKIT_CACHE_DIR``, default ``~/.cache/platkit``) keyed by a hash of the source. Without a
compiler, or with ``PLATKIT_COMPILE=0``, the same Newton iteration runs in numpy over CasADi
evaluations of (r, J). ``PlatformModel.backend`` says which path is used.
"""
from __future__ import annotations

import ctypes
import functools
import math

import casadi as ca
import numpy as np

from platkit.geometry import quat_normalize
from platkit.kinematics.core import ModelCore
from platkit.native import CONVERGED, MAX_ITERATIONS, NOT_FINITE, SINGULAR, NativeNewton, native_for, newton_functions

#: a least-squares solve (more rows than pose coordinates) gets this many times Newton's iterations:
#: Gauss-Newton on rows that do not close converges linearly, at a rate that nears 1 as the rows'
#: misfit grows along a weakly held direction (a small plate's turn on long cables)
LEAST_SQUARES_ITERATIONS = 10


class NewtonSolver(ModelCore):
    """G(p) = F(u, td, pose(p)) = 0 solved for p: one problem or N, in C or in numpy; out rows
    (p, q, X, g, iterations, |r|, status, on_branch). Where rows outnumber pose coordinates the
    solve is Levenberg-Marquardt on the rows weighted by their plausible misfit, and |r| is the
    weighted misfit at the least-squares pose."""

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

    @property
    def _iterations(self) -> int:
        """The solve's iteration budget: ``max_iter``, times LEAST_SQUARES_ITERATIONS for a
        least-squares solve."""
        return self.max_iter * LEAST_SQUARES_ITERATIONS if self.n_r > self.spec.n_p else self.max_iter

    @functools.cached_property
    def _default_call(self):
        """(u buffer, out buffer, the compiled checked solve, its ctypes arguments, (tol,
        max_iter) they were built with) of a solve with the nominal td from the neutral pose
        that first checks the strokes; arguments built once, not converted on every call (a
        warm forward call is a few microseconds). None without the compiled solver."""
        nat = self._native
        if not isinstance(nat, NativeNewton) or self.spec.forward is not None:
            return None
        bufs, addr = self._single_buffers
        bounds = np.ascontiguousarray(np.stack([self._lo_tol, self._hi_tol]), dtype=float)
        args = (ctypes.c_void_p(addr["u"]), ctypes.c_void_p(bounds.ctypes.data),
                ctypes.c_void_p(bounds.ctypes.data + bounds.strides[0]), ctypes.c_void_p(addr["td0"]),
                ctypes.c_void_p(addr["neutral"]), ctypes.c_double(self.tol), ctypes.c_int(self._iterations),
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
        nat.single(addr["u"], td_addr, p0_addr, self.tol, self._iterations, addr["out"])
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
            nat.batch(N, u.ctypes.data, td.ctypes.data, P0.ctypes.data, stride, self.tol, self._iterations,
                      out.ctypes.data)
            return out
        return self._solve_numpy(u, td, np.broadcast_to(P0, (N, self.spec.n_p)))

    def _lm_numpy_one(self, u: np.ndarray, td: np.ndarray, p0: np.ndarray) -> np.ndarray:
        """Levenberg-Marquardt on the (weighted) rows of a stand with more rows than pose
        coordinates: the C driver's rule and out row (platkit/native.py)."""
        n_p = self.spec.n_p
        p = np.array(p0, dtype=float)
        r, J = self._rj_one(u, td, p)
        nrm = math.sqrt(float(r @ r))
        lam, status, k = 1e-4, CONVERGED, 0
        while True:
            if not math.isfinite(nrm):
                status = NOT_FINITE
                break
            if nrm <= self.tol:
                p, nrm = self._polished(u, td, p, r, J, nrm)
                break
            if k >= self._iterations:
                status = MAX_ITERATIONS
                break
            N, gr = J.T @ J, J.T @ r
            scale = float(np.max(np.abs(N)))
            d = np.diag(N).copy()
            d = np.where(d > 1e-12 * scale, d, 1e-12 * scale + 1e-300)
            kept = False
            step = 0.0
            for _ in range(40):
                try:
                    b = np.linalg.solve(N + lam * np.diag(d), gr)
                except np.linalg.LinAlgError:
                    lam *= 4.0
                    continue
                pt = p - b
                rt, Jt = self._rj_one(u, td, pt)
                nt = math.sqrt(float(rt @ rt))
                if math.isfinite(nt) and nt < nrm:
                    kept, step = True, float(np.max(np.abs(b)))
                    p, r, J, nrm = pt, rt, Jt, nt
                    lam = max(lam / 3.0, 1e-12)
                    break
                lam *= 4.0
            k += 1
            if not kept or step <= 1e-11 * (1.0 + float(np.max(np.abs(p)))):
                break
        q, X, g = self._post_one(u, td, p)
        q = q / math.sqrt(float(q @ q))
        if q[0] < 0:
            q = -q
        on = bool(np.all(g > 0))
        return np.concatenate([p[:n_p], q, X, g, [k, nrm, status, on]])

    def _polished(self, u: np.ndarray, td: np.ndarray, p: np.ndarray, r: np.ndarray, J: np.ndarray,
                  nrm: float) -> tuple[np.ndarray, float]:
        """(p, |r|) after one more step once |r| <= tol (Newton's; Gauss-Newton's where rows
        outnumber pose coordinates), kept only where it does not raise |r|: the C driver's polish."""
        if not nrm > 0:
            return p, nrm
        try:
            step = np.linalg.solve(J, r) if J.shape[0] == J.shape[1] else np.linalg.lstsq(J, r, rcond=None)[0]
        except np.linalg.LinAlgError:
            return p, nrm
        rt, _ = self._rj_one(u, td, p - step)
        nt = math.sqrt(float(rt @ rt))
        return (p - step, nt) if nt <= nrm else (p, nrm)

    def _solve_numpy_one(self, u: np.ndarray, td: np.ndarray, p0: np.ndarray) -> np.ndarray:
        """One Newton solve with numpy over CasADi buffer evaluations; the C driver's out row."""
        if self.n_r > self.spec.n_p:
            return self._lm_numpy_one(u, td, p0)
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
                p, nrm = self._polished(u, td, p, r, J, nrm)
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
        if self.n_r > n_p:
            return np.array([self._lm_numpy_one(U[i], td, P0[i]) for i in range(N)]).reshape(N, n_p + 7 + n_g + 4)
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

    # the maps are kept with the (long-lived) model they belong to: one per batch size, at most 16
    @functools.lru_cache(maxsize=16)  # noqa: B019
    def _rj_map(self, n: int) -> ca.Function:
        return self._newton_fns[0].map(n)

    @functools.lru_cache(maxsize=16)  # noqa: B019
    def _post_map(self, n: int) -> ca.Function:
        return self._newton_fns[1].map(n)
