"""The approach fits of many holds at once (platkit.settle): ``x_inf + (a + b s) exp(-s / tau)``
fitted to each hold's stream, every hold's candidate time constants evaluated in one batched pass
per search stage (the holds stacked, their samples padded with zero weight), and the checks that
refit a hold (its tail's start, its extrapolation to rest).

The search per hold: a coarse log grid of COARSE_GRID time constants from two samples to three
times the stretch, then three rounds of finer grids (12 points) around every local minimum of the
coarse grid within 20% of its best and around the time constant of the sampled decay's recurrence
(Prony); the lowest residual of the last round wins. For each time constant the rest is linear
least squares per marker over its visible samples: the normal equations of the design
[1, e, (s / tau) e] (e = exp(-s / tau)), regularised by 1e-12 of their trace; the residual of the
search is the data's sum of squares less what the Cholesky factor of those equations explains.
"""
from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc, gammaincinv

from platkit._threads import blas_threads
from platkit.settle._approach import Approach
from platkit.settle._native import Kernels, Packed, fits_function

#: probability that a still stretch is fitted a significant approach tail
TAIL_FALSE_ALARM = 1e-5  # strict: the best of 64 time constants is tested

#: time constants on the coarse grid of an approach fit (then refined around its minima)
COARSE_GRID = 40

#: points of each finer grid, and how many rounds of them
FINE_GRID = 12
FINE_ROUNDS = 3

#: samples x time constants of one batch of holds (the working arrays' size, 8 bytes each)
BATCH_ELEMENTS = 1 << 18

#: stretches prepared and searched together
CHUNK = 512

@dataclass
class _Hold:
    """One hold's stretch, prepared for the fit: times s (K,) from its first sample, the markers
    centred per marker over their visible samples (y (K, M, 3), zero where occluded), the weights
    w (K, M) (1 visible, 0 occluded), seen (M,) markers with at least 8 visible samples."""

    t: np.ndarray
    s: np.ndarray
    w: np.ndarray
    seen: np.ndarray
    mean: np.ndarray
    y: np.ndarray
    yty: np.ndarray
    every: bool  # no occlusion: one design for every marker
    sigma: float
    t_end: float | None
    tau: float | None

    @property
    def dt(self) -> float:
        return max(self.s[-1], 1e-9) / max(len(self.s) - 1, 1)

    @property
    def span(self) -> float:
        return max(self.s[-1], 1e-9)


def _prepare(t: np.ndarray, markers: np.ndarray, sigma: float, t_end: float | None, tau: float | None) -> _Hold | None:
    """The stretch prepared for the fit (:class:`_Hold`); None when it has under 8 samples or no
    marker has 8 visible ones."""
    t = np.asarray(t, float)
    K = len(t)
    if K < 8:
        return None
    ok = np.isfinite(markers).all(axis=2)  # (K, M)
    n_ok = ok.sum(axis=0)
    seen = n_ok >= 8
    if not seen.any():
        return None
    # centred per marker: the sums then hold the decay, not the marker's place (no cancellation)
    mean = np.sum(np.where(ok[..., None], markers, 0.0), axis=0) / np.maximum(n_ok, 1)[:, None]
    y = np.where(ok[..., None], markers - mean[None], 0.0)  # (K, M, 3)
    w = ok.astype(float)
    return _Hold(t=t, s=t - t[0], w=w, seen=seen, mean=mean, y=y, yty=np.sum(y**2, axis=(0, 2)),
                 every=bool(ok.all()), sigma=float(sigma), t_end=t_end, tau=tau)


def _prepare_compiled(kernels: Kernels, chunk: Sequence[tuple]) -> tuple[list[_Hold | None], Packed | None]:
    """:func:`_prepare` of every stretch of ``chunk`` (t, markers, sigma, t_end, tau) by the
    compiled kernel: the holds (None where :func:`_prepare` gives none; y the kernel's (K, Jp)
    rows) and the kept ones as the kernel lays them out (None: none kept)."""
    index = [i for i, x in enumerate(chunk) if len(x[0]) >= 8]
    prepared: list[_Hold | None] = [None] * len(chunk)
    if not index:
        return prepared, None
    packed = Packed(kernels, [(np.asarray(chunk[i][0], float), np.asarray(chunk[i][1], float)) for i in index])
    seen = packed.seen.astype(bool)
    kept = [n for n in range(len(index)) if seen[n].any()]
    for n in kept:
        t, _, sigma, t_end, tau = chunk[index[n]]
        a, b = packed.ks[n]
        prepared[index[n]] = _Hold(t=np.asarray(t, float), s=packed.s[a:b], w=packed.w[a:b], seen=seen[n],
                                   mean=packed.mean[n], y=packed.y[a:b], yty=packed.yty[n],
                                   every=bool(packed.full[a:b].all()), sigma=float(sigma), t_end=t_end, tau=tau)
    return prepared, (packed.subset(kept) if kept else None)


def _batches(holds: Sequence[_Hold], n_taus: Sequence[int]) -> list[list[int]]:
    """The holds grouped for batched evaluation: by occlusion (none, some), then by length, a
    batch's padding at most a fifth of its longest stretch and its working arrays at most
    BATCH_ELEMENTS."""
    order = sorted(range(len(holds)), key=lambda h: (holds[h].every, len(holds[h].s)))
    out: list[list[int]] = []
    width = 0  # the most time constants of a hold in the last batch
    for h in order:
        K, T = len(holds[h].s), n_taus[h]
        if out:
            b = out[-1]
            first = holds[b[0]]
            if (first.every == holds[h].every and len(first.s) >= 0.8 * K
                    and (len(b) + 1) * max(width, T) * K <= BATCH_ELEMENTS):
                b.append(h)
                width = max(width, T)
                continue
        out.append([h])
        width = T
    return out


def _normal_equations(holds: Sequence[_Hold], taus: Sequence[np.ndarray]):
    """For each batch of holds (:func:`_batches`) and each hold's time constants taus[h] (T_h,,
    padded with its last to the batch's T): (the batch's holds, the normal equations of the design
    [1, e, (s / tau) e] per marker, regularised (unseen markers: the identity), as the six entries
    of the symmetric matrix (a00, a01, a02, a11, a12, a22), each (H, T, M), and the right-hand
    sides (b0, b1, b2), each (H, T, M, 3)). The sums over the samples are taken over every sample
    of a hold, less those over the samples where a marker is occluded (few: a product over them
    alone); padded samples lie so late that their e and (s / tau) e are exactly zero."""
    for batch in _batches(holds, [len(x) for x in taus]):
        H = len(batch)
        K = max(len(holds[h].s) for h in batch)
        T = max(len(taus[h]) for h in batch)
        M = holds[batch[0]].w.shape[1]
        TAU = np.empty((H, T))
        S = np.empty((H, K))
        Y = np.zeros((H, K, 3 * M))
        for r, h in enumerate(batch):
            d = holds[h]
            k = len(d.s)
            S[r, :k] = d.s
            TAU[r, : len(taus[h])] = taus[h]
            TAU[r, len(taus[h]):] = taus[h][-1]
            Y[r, :k] = d.y.reshape(k, -1)
            S[r, k:] = 1e3 * TAU[r].max()  # exp(-1000) is zero in double precision
        X = S[:, None, :] / TAU[:, :, None]  # (H, T, K)
        E = np.exp(-X)
        P = X * E
        shape = (H, T, M)
        a = [np.empty(shape) for _ in range(6)]
        for x, v in zip(a, (np.array([len(holds[h].s) for h in batch], float)[:, None, None], E.sum(axis=2)[..., None],
                            P.sum(axis=2)[..., None], np.einsum("htk,htk->ht", E, E)[..., None],
                            np.einsum("htk,htk->ht", E, P)[..., None], np.einsum("htk,htk->ht", P, P)[..., None])):
            x[...] = v
        for r, h in enumerate(batch):
            d = holds[h]
            if d.every:
                continue
            occ = np.nonzero(d.w.min(axis=1) < 1)[0]  # samples where some marker is occluded
            O = 1.0 - d.w[occ]  # (n, M)
            a[0][r] -= O.sum(axis=0)
            e, p = E[r][:, occ], P[r][:, occ]
            for x, g in zip(a[1:], (e, p, e * e, e * p, p * p)):
                x[r] -= g @ O
        b = [np.broadcast_to(x, (H, T, 3 * M)).reshape(H, T, M, 3) for x in (Y.sum(axis=1)[:, None, :], E @ Y, P @ Y)]
        unseen = ~np.stack([holds[h].seen for h in batch])[:, None, :]  # (H, 1, M)
        if unseen.any():
            for x, v in zip(a, (1.0, 0.0, 0.0, 1.0, 0.0, 1.0)):
                np.copyto(x, v, where=np.broadcast_to(unseen, shape))
        reg = 1e-12 * (a[0] + a[3] + a[5])
        for i in (0, 3, 5):
            a[i] += reg
        yield batch, a, b


def _residuals(holds: Sequence[_Hold], taus: Sequence[np.ndarray]) -> list[np.ndarray]:
    """(T_h,) the residual sum of squares over the seen markers of each hold at each of its time
    constants: the data's sum of squares less what the equations' Cholesky factor explains."""
    out: list = [None] * len(holds)
    for batch, (a00, a01, a02, a11, a12, a22), (b0, b1, b2) in _normal_equations(holds, taus):
        with np.errstate(invalid="ignore", divide="ignore"):
            l00 = np.sqrt(a00)
            l10 = a01 / l00
            l20 = a02 / l00
            l11 = np.sqrt(a11 - l10 * l10)
            l21 = (a12 - l20 * l10) / l11
            l22 = np.sqrt(a22 - l20 * l20 - l21 * l21)
            z0 = b0 / l00[..., None]
            z1 = (b1 - l10[..., None] * z0) / l11[..., None]
            z2 = (b2 - l20[..., None] * z0 - l21[..., None] * z1) / l22[..., None]
            explained = np.sum(z0 * z0 + z1 * z1 + z2 * z2, axis=3)  # (H, T, M)
        yty = np.stack([holds[h].yty for h in batch])[:, None, :]
        seen = np.stack([holds[h].seen for h in batch])[:, None, :]
        rss = np.sum(np.where(seen, yty - explained, 0.0), axis=2)  # (H, T)
        for r, h in enumerate(batch):
            out[h] = rss[r, : len(taus[h])]
    return out


def _solutions(holds: Sequence[_Hold], taus: Sequence[float], packed: Packed | None = None):
    """Per hold at its time constant: (coef (M, 3, 3) [param, coord], the equations (M, 3, 3),
    the residual sum of squares over the seen markers). ``packed``: the holds as the compiled
    kernel lays them out (None: numpy's sums)."""
    if packed is not None:
        G, B = packed.equations(taus)
    else:
        M = holds[0].w.shape[1]
        G = np.empty((len(holds), M, 3, 3))
        B = np.empty((len(holds), M, 3, 3))
        for batch, a, b in _normal_equations(holds, [np.array([x]) for x in taus]):
            for (i, j), x in zip(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)), a):
                G[batch, :, i, j] = G[batch, :, j, i] = x[:, 0]
            for i, x in enumerate(b):
                B[batch, :, i, :] = x[:, 0]
    coef = np.linalg.solve(G, B)
    rss = np.stack([d.yty for d in holds]) - np.einsum("hmic,hmic->hm", coef, B)
    seen = np.stack([d.seen for d in holds])
    return coef, G, np.sum(np.where(seen, rss, 0.0), axis=1)


def _starts(d: _Hold, grid: np.ndarray, rss_g: np.ndarray) -> np.ndarray:
    """(S, 2) the bounds of the finer grids of one hold: around every local minimum of its coarse
    grid within 20% of the best (at most four; two time constants can fit a short stretch almost
    equally, a and b trading against tau), and around Prony's time constant (the residual has a
    narrow valley when the tail is many noise levels deep, which the grid can step over)."""
    j = int(np.argmin(rss_g))
    interior = (rss_g[1:-1] <= rss_g[:-2]) & (rss_g[1:-1] <= rss_g[2:])
    minima = sorted({j} | {int(k) + 1 for k in np.nonzero(interior)[0] if rss_g[k + 1] <= 1.2 * rss_g[j]})
    starts = [(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]) for k in minima[:4]]
    tp = _prony_tau(d.y, d.w > 0, d.dt)
    if tp is not None and 2 * d.dt <= tp <= 3 * d.span:
        starts.append((tp / 1.2, tp * 1.2))
    return np.array(starts, float)


def _search(holds: Sequence[_Hold]) -> tuple[list[float], list[bool]]:
    """(tau, at the top of the coarse grid) of each hold: its own ``tau`` when given, else the
    coarse grid and the finer rounds (the module's docstring), every hold's grid at once."""
    free = [h for h, d in enumerate(holds) if d.tau is None]
    tau = [float(d.tau) if d.tau is not None else np.nan for d in holds]
    top = [False] * len(holds)
    if not free:
        return tau, top
    grids = [np.geomspace(2 * holds[h].dt, 3 * holds[h].span, COARSE_GRID) for h in free]
    coarse = _residuals([holds[h] for h in free], grids)
    bounds = [_starts(holds[h], g, r) for h, g, r in zip(free, grids, coarse)]
    for h, r in zip(free, coarse):
        top[h] = int(np.argmin(r)) == COARSE_GRID - 1
    ramp = np.linspace(0.0, 1.0, FINE_GRID)
    for _ in range(FINE_ROUNDS):
        fine = [np.exp(np.log(b[:, :1]) + np.log(b[:, 1:] / b[:, :1]) * ramp[None]) for b in bounds]  # (S, 12)
        rss = _residuals([holds[h] for h in free], [f.ravel() for f in fine])
        for n, (f, r) in enumerate(zip(fine, rss)):
            k = np.argmin(r.reshape(f.shape), axis=1)
            rows = np.arange(len(f))
            bounds[n] = np.column_stack([f[rows, np.maximum(k - 1, 0)], f[rows, np.minimum(k + 1, FINE_GRID - 1)]])
        for h, f, r in zip(free, fine, rss):
            tau[h] = float(f.ravel()[int(np.argmin(r))])
    return tau, top


def _search_compiled(holds: Sequence[_Hold], packed: Packed) -> tuple[list[float], list[bool]]:
    """:func:`_search` with the compiled sums (``packed``: the holds as platkit.settle._native
    lays them out), every stage over every hold in whole arrays: the same grids, the same
    starts (:func:`_starts`, Prony's time constant from the kernel), the same choices."""
    free = np.array([h for h, d in enumerate(holds) if d.tau is None], dtype=np.intp)
    tau = [float(d.tau) if d.tau is not None else np.nan for d in holds]
    top = [False] * len(holds)
    if not len(free):
        return tau, top
    if len(free) < len(holds):
        packed = packed.subset(free)
    F = len(free)
    dt = np.array([holds[h].dt for h in free])
    span = np.array([holds[h].span for h in free])
    grids = np.geomspace(2 * dt, 3 * span, COARSE_GRID, axis=1)  # (F, COARSE_GRID)
    coarse = packed.residuals(grids.ravel(), np.arange(F + 1) * COARSE_GRID).reshape(F, COARSE_GRID)
    # the starts: every local minimum within 20% of the best (at most four), then Prony's
    j = np.argmin(coarse, axis=1)
    rows = np.arange(F)
    best = coarse[rows, j]
    minima = np.zeros(coarse.shape, bool)
    minima[rows, j] = True
    minima[:, 1:-1] |= ((coarse[:, 1:-1] <= coarse[:, :-2]) & (coarse[:, 1:-1] <= coarse[:, 2:])
                        & (coarse[:, 1:-1] <= 1.2 * best[:, None]))
    minima &= np.cumsum(minima, axis=1) <= 4
    owner, k = np.nonzero(minima)
    lo = grids[owner, np.maximum(k - 1, 0)]
    hi = grids[owner, np.minimum(k + 1, COARSE_GRID - 1)]
    tp = packed.tp
    prony = np.isfinite(tp) & (2 * dt <= tp) & (tp <= 3 * span)
    owner = np.concatenate([owner, rows[prony]])
    lo = np.concatenate([lo, tp[prony] / 1.2])
    hi = np.concatenate([hi, tp[prony] * 1.2])
    order = np.argsort(owner, kind="stable")  # each hold's grid minima, then its Prony start
    owner, bounds = owner[order], np.column_stack([lo[order], hi[order]])
    offsets = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=F))]) * FINE_GRID
    for h, r in zip(free, j):
        top[h] = int(r) == COARSE_GRID - 1
    ramp = np.linspace(0.0, 1.0, FINE_GRID)
    S = np.arange(len(bounds))
    for _ in range(FINE_ROUNDS):
        fine = np.exp(np.log(bounds[:, :1]) + np.log(bounds[:, 1:] / bounds[:, :1]) * ramp[None])  # (S, 12)
        rss = packed.residuals(fine.ravel(), offsets)
        k = np.argmin(rss.reshape(fine.shape), axis=1)
        bounds = np.column_stack([fine[S, np.maximum(k - 1, 0)], fine[S, np.minimum(k + 1, FINE_GRID - 1)]])
    flat = fine.ravel()
    for n, h in enumerate(free):
        a, b = offsets[n], offsets[n + 1]
        tau[h] = float(flat[a + int(np.argmin(rss[a:b]))])
    return tau, top


def _approach(d: _Hold, tau: float, at_top: bool, coef: np.ndarray, G: np.ndarray, rss: float) -> Approach:
    """The fitted approach of one hold at its time constant: the rest position and its standard
    error (inflated by the fit's chi-square when above 1), the tail; a tail the stream does not
    show is none (:data:`TAIL_FALSE_ALARM`)."""
    seen, sigma = d.seen, d.sigma
    n_obs = 3 * int(d.w[:, seen].sum())
    dof = max(n_obs - 9 * int(seen.sum()) - 1, 1)
    chi = float(max(rss, 0.0) / dof / sigma**2)
    inv = np.linalg.inv(G)  # (M, 3, 3)
    std = np.sqrt(np.maximum(inv[:, 0, 0], 0.0) * max(chi, 1.0)) * sigma
    a = np.where(seen[:, None], coef[:, 1, :], 0.0)
    b = np.where(seen[:, None], coef[:, 2, :], 0.0)
    fit = Approach(tau=float(tau), t0=float(d.t[0]), x_inf=np.where(seen[:, None], d.mean + coef[:, 0, :], np.nan),
                   x_inf_std=np.where(seen[:, None], std[:, None].repeat(3, axis=1), np.nan),
                   a=a, b=b, chi2_per_dof=chi, remaining_m=np.zeros(len(seen)),
                   at_limit=d.tau is None and at_top,
                   cov_ab=np.where(seen[:, None, None], inv[:, 1:, 1:] * max(chi, 1.0) * sigma**2, 0.0))
    # a tail the stream does not show (chi-square of what the decay explains, over every seen
    # coordinate, against sigma: the slow noise's when the caller passes it) is none: noise alone
    # must not move a window or make a hold unsettled
    rss0 = float(np.sum(d.yty[seen]))
    extra = 2 * 3 * int(seen.sum()) + 1
    if not chdtrc(extra, max((rss0 - max(rss, 0.0)) / sigma**2, 0.0)) < TAIL_FALSE_ALARM:
        fit.a, fit.b = np.zeros_like(a), np.zeros_like(b)
        fit.x_inf = np.where(seen[:, None], d.mean, np.nan)
        fit.significant = False
    fit.remaining_m = np.linalg.norm(fit.tail(np.array([d.t[-1] if d.t_end is None else d.t_end]))[0], axis=1)
    return fit


def _approaches(holds: Sequence[_Hold], tau: Sequence[float], top: Sequence[bool], coef: np.ndarray, G: np.ndarray,
                rss: np.ndarray, nok: np.ndarray) -> list[Approach]:
    """:func:`_approach` of every hold at once (the compiled path: ``nok`` (H, M) the visible
    samples of each marker), in whole arrays."""
    seen = np.stack([d.seen for d in holds])  # (H, M)
    sigma = np.array([d.sigma for d in holds])
    sigma2 = sigma**2
    n_seen = seen.sum(axis=1)
    n_obs = 3 * np.where(seen, nok, 0.0).sum(axis=1)
    dof = np.maximum(n_obs - 9 * n_seen - 1, 1)
    chi = np.maximum(rss, 0.0) / dof / sigma2
    inflate = np.maximum(chi, 1.0)
    inv = np.linalg.inv(G)  # (H, M, 3, 3)
    std = np.sqrt(np.maximum(inv[:, :, 0, 0], 0.0) * inflate[:, None]) * sigma[:, None]
    mean = np.stack([d.mean for d in holds])
    S = seen[:, :, None]
    a = np.where(S, coef[:, :, 1, :], 0.0)
    b = np.where(S, coef[:, :, 2, :], 0.0)
    x_inf = np.where(S, mean + coef[:, :, 0, :], np.nan)
    x_inf_std = np.where(S, std[:, :, None].repeat(3, axis=2), np.nan)
    cov_ab = np.where(seen[:, :, None, None], inv[:, :, 1:, 1:] * inflate[:, None, None, None] * sigma2[:, None, None, None],
                      0.0)
    # a tail the stream does not show is none (as _approach)
    rss0 = np.where(seen, np.stack([d.yty for d in holds]), 0.0).sum(axis=1)
    shown = chdtrc(6 * n_seen + 1, np.maximum((rss0 - np.maximum(rss, 0.0)) / sigma2, 0.0)) < TAIL_FALSE_ALARM
    a = np.where(shown[:, None, None], a, 0.0)
    b = np.where(shown[:, None, None], b, 0.0)
    x_inf = np.where(shown[:, None, None], x_inf, np.where(S, mean, np.nan))
    t0 = np.array([float(d.t[0]) for d in holds])
    t_end = np.array([float(d.t[-1]) if d.t_end is None else float(d.t_end) for d in holds])
    taus = np.asarray(tau, float)
    u = np.maximum(t_end - t0, 0.0)
    e = np.exp(-u / taus)
    remaining = np.linalg.norm((a + b * (u / taus)[:, None, None]) * e[:, None, None], axis=2)
    return [Approach(tau=float(taus[h]), t0=float(t0[h]), x_inf=x_inf[h], x_inf_std=x_inf_std[h], a=a[h], b=b[h],
                     chi2_per_dof=float(chi[h]), remaining_m=remaining[h], at_limit=d.tau is None and bool(top[h]),
                     significant=bool(shown[h]), cov_ab=cov_ab[h])
            for h, d in enumerate(holds)]


def fit_approaches(stretches: Sequence[tuple], compiled: bool = True) -> list[Approach | None]:
    """:func:`fit_approach` of many stretches of one stream (the same markers) at once: each
    (t, markers, sigma[, t_end[, tau]]); the same fits, their grids evaluated in batches, CHUNK
    stretches prepared at a time (a prepared stretch is a centred copy of its markers). The sums
    over the samples are compiled (platkit.settle._native) where a C compiler is available and
    ``compiled`` is true, else numpy's; the two agree to rounding."""
    out: list[Approach | None] = []
    kernels = fits_function() if compiled else "not asked for"
    with blas_threads(1):  # products of a few hundred by tens: worker threads only spin
        for c in range(0, len(stretches), CHUNK):
            chunk = [(tuple(x) + (None, None))[:5] for x in stretches[c:c + CHUNK]]
            if isinstance(kernels, str):
                packed = None
                prepared = [_prepare(*x) for x in chunk]
            else:
                prepared, packed = _prepare_compiled(kernels, chunk)
            holds = [d for d in prepared if d is not None]
            if not holds:
                out += [None] * len(prepared)
                continue
            tau, top = _search(holds) if packed is None else _search_compiled(holds, packed)
            coef, G, rss = _solutions(holds, tau, packed)
            if packed is None:
                fits = iter(_approach(d, tau[h], top[h], coef[h], G[h], float(rss[h])) for h, d in enumerate(holds))
            else:
                fits = iter(_approaches(holds, tau, top, coef, G, rss, packed.nok))
            out += [None if d is None else next(fits) for d in prepared]
    return out


def fit_approach(t: np.ndarray, markers: np.ndarray, sigma: float, t_end: float | None = None,
                 tau: float | None = None) -> Approach | None:
    """Fit x(s) = x_inf + (a + b s) exp(-s / tau) to a hold's tail, s = t - t[0].

    t: (K,) s; markers: (K, M, 3) m (NaN: occluded); sigma: noise per coordinate (m); t_end:
    the hold's end (default t[-1]), where ``remaining_m`` is evaluated. One tau for every marker,
    searched on a log grid from two samples to three times the stretch (or ``tau`` given: the
    session's); for each tau the rest is linear least squares (per marker over its visible
    samples). None when no marker has 8 samples in the stretch.
    """
    return fit_approaches([(t, markers, sigma, t_end, tau)])[0]


def fit_tails(holds: Sequence[tuple]) -> list[Approach | None]:
    """The approach of each hold (ts, seg, k0, end, sigma) fitted from k0, a quarter or half of
    the way to the end: the earliest whose residual is within 15% of the best one's (per degree
    of freedom). The end of the main motion (a minimum-jerk deceleration, several actuators with
    their own time constants) is not one decay, and a fit that includes it mispredicts the tail;
    the noise level of the stream (coloured noise, a sigma estimated a few percent off) is judged
    against the stretch itself. None for a hold whose stretch is too short to fit. The fits from
    k0 and from half-way are made for every hold at once, then the quarter-way ones that are needed."""
    def at(hold, f):
        ts, seg, k0, end, sigma = hold
        k = k0 + int(f * (end - k0))
        return (ts[k:end], seg[k:end], sigma, ts[end - 1]) if end - k >= 16 else None

    def fitted(fractions):
        jobs = [(i, f, at(h, f)) for i, h in enumerate(holds) for f in fractions]
        done = fit_approaches([j[2] for j in jobs if j[2] is not None])
        got = iter(done)
        return {(i, f): (None if job is None else next(got)) for i, f, job in jobs}

    fits = fitted((0.0, 0.5))
    need = [i for i in range(len(holds))
            if fits[i, 0.0] is not None and fits[i, 0.5] is not None
            and not fits[i, 0.0].chi2_per_dof <= 1.15 * fits[i, 0.5].chi2_per_dof]
    quarter = fitted((0.25,)) if need else {}
    out: list[Approach | None] = []
    for i in range(len(holds)):
        late, first = fits[i, 0.5], fits[i, 0.0]
        if first is None:
            out.append(late)
        elif late is None or first.chi2_per_dof <= 1.15 * late.chi2_per_dof:
            out.append(first)  # the decay from the end of the main motion on is one decay
        else:
            cands = [f for f in (first, quarter.get((i, 0.25)), late) if f is not None]
            floor = min(f.chi2_per_dof for f in cands)
            out.append(next(f for f in cands if f.chi2_per_dof <= 1.15 * floor))
    return out


def _prony_tau(y: np.ndarray, ok: np.ndarray, dt: float) -> float | None:
    """Time constant (s) of the slowest mode of a second-order recurrence fitted to y (K, M, 3):
    block means (about 30 blocks, so that noise does not drown the differences), their
    differences (which remove the rest position) shared by every seen coordinate. None when no
    mode decays or too little is seen."""
    K = len(y)
    L = max(1, K // 30)
    nb = K // L
    if nb < 8:
        return None
    w = ok[: nb * L].reshape(nb, L, -1).astype(float)  # (nb, L, M)
    ys = y[: nb * L].reshape(nb, L, *y.shape[1:])
    cnt = w.sum(axis=1)  # (nb, M)
    blocks = np.sum(ys * w[..., None], axis=1) / np.maximum(cnt, 1)[..., None]  # (nb, M, 3)
    seen = np.all(cnt > 0, axis=0)
    if not seen.any():
        return None
    d = np.diff(blocks[:, seen], axis=0).reshape(nb - 1, -1)  # (nb-1, 3m)
    A = np.stack([d[1:-1], d[:-2]], axis=-1).reshape(-1, 2)
    b = d[2:].reshape(-1)
    coef, *_ = np.linalg.lstsq(A, b, rcond=None)
    # the larger modulus of the roots of z^2 - c0 z - c1
    c0, c1 = float(coef[0]), float(coef[1])
    disc = c0 * c0 + 4.0 * c1
    r = (abs(c0) + np.sqrt(disc)) / 2.0 if disc >= 0 else float(np.sqrt(-c1))
    if not 0 < r < 1:
        return None
    return -L * dt / np.log(r)


def extrapolation_checked(ts: np.ndarray, seg: np.ndarray, fit: Approach, end: int, sigma: float,
                          false_alarm: float = 1e-3) -> bool:
    """Whether the approach model predicts the hold's own future: refit without the last third
    of the stretch the fit saw and compare its prediction of that third's mean with the
    measured mean (chi-square over the seen markers' coordinates, with the prediction's and the
    mean's noise). An approach whose shape the model misses (several time constants, a creep)
    fails it, and is not extrapolated to rest."""
    k = int(np.searchsorted(ts, fit.t0))
    L = end - k
    cut = end - L // 3
    if cut - k < 16 or end - cut < 4:
        return False
    early = fit_approach(ts[k:cut], seg[k:cut], sigma, tau=fit.tau)
    if early is None:
        return False
    w = seg[cut:end]
    ok = np.isfinite(w).all(axis=2)
    cnt = ok.sum(axis=0)
    seen = (cnt > 0) & np.isfinite(early.x_inf).all(axis=1)
    if not seen.any():
        return False
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        meas = np.nanmean(np.where(ok[..., None], w, np.nan), axis=0)
    pred = early.x_inf + np.mean(early.tail(ts[cut:end]), axis=0)
    var = early.x_inf_std**2 + sigma**2 / np.maximum(cnt, 1)[:, None]
    stat = float(np.sum(((meas - pred) ** 2 / var)[seen]))
    return stat < 2.0 * gammaincinv(1.5 * int(seen.sum()), 1 - false_alarm)  # the chi-square quantile
