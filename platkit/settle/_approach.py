"""The approach of a hold to rest (platkit.settle): ``x_inf + (a + b s) exp(-s / tau)``
fitted to the stream, the window its tail leaves free, the tail's share of a still stretch, an
extrapolation to rest checked against the stream, and a window's averaged result."""
from __future__ import annotations

import contextlib
import warnings
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import chdtrc, gammaincinv
from threadpoolctl import ThreadpoolController

#: probability that a still stretch is fitted a significant approach tail
TAIL_FALSE_ALARM = 1e-5  # strict: the best of 64 time constants is tested

#: time constants on the coarse grid of an approach fit (then refined around its minima)
COARSE_GRID = 40


@dataclass
class Approach:
    """The fitted approach of one hold: x(s) = x_inf + (a + b s) exp(-s / tau), s = t - t0.

    x_inf, a, b: (M, 3) m (NaN for a marker not seen); x_inf_std (M, 3) m; tau, t0 in s;
    chi2_per_dof: the fit's residual against the stream noise (1 for a good fit);
    remaining_m: (M,) distance still to go at the end of the hold, per marker.
    """

    tau: float
    t0: float
    x_inf: np.ndarray
    x_inf_std: np.ndarray
    a: np.ndarray
    b: np.ndarray
    chi2_per_dof: float
    remaining_m: np.ndarray
    at_limit: bool  # tau at the top of the searched range: slower than the hold can show
    significant: bool = True  # False: the stream shows no decay (a and b set to zero)
    cov_ab: np.ndarray | None = None  # (M, 2, 2) covariance of (a, b) per coordinate, m^2 (tau held)

    def scaled(self, k: float) -> Approach:
        """This approach with its tail scaled by k (rest unchanged); not significant when k is 0."""
        k = float(k)
        out = replace(self, a=self.a * k, b=self.b * k, remaining_m=self.remaining_m * abs(k),
                      cov_ab=None if self.cov_ab is None else self.cov_ab * k * k)
        out.significant = self.significant and k != 0.0
        return out

    def tail_std(self, t: np.ndarray) -> np.ndarray:
        """(K, M) m, the standard error of :meth:`tail` per coordinate (tau taken as known)."""
        s = np.maximum(np.asarray(t, float) - self.t0, 0.0)
        e = np.exp(-s / self.tau)
        g = np.stack([e, (s / self.tau) * e], axis=1)  # (K, 2)
        if self.cov_ab is None:
            return np.zeros((len(s), self.a.shape[0]))
        return np.sqrt(np.maximum(np.einsum("ki,mij,kj->km", g, self.cov_ab, g), 0.0))

    def tail(self, t: np.ndarray) -> np.ndarray:
        """(K, M, 3) m, the part of the approach still to go at times t."""
        s = np.maximum(np.asarray(t, float) - self.t0, 0.0)
        e = np.exp(-s / self.tau)[:, None, None]
        return (self.a[None] + self.b[None] * (s / self.tau)[:, None, None]) * e

    @property
    def good(self) -> bool:
        """The fit describes the stream (residual near the noise, a finite rest position)."""
        return (not self.at_limit and self.chi2_per_dof < 2.0 and bool(np.isfinite(self.x_inf_std).any()))


_controller: list[ThreadpoolController] = []


@contextlib.contextmanager
def _one_blas_thread():
    """BLAS (OpenBLAS, MKL, BLIS) limited to one thread inside the block, restored after: an
    approach fit's products are a few hundred by tens, where worker threads only wake and spin
    (on a shared machine they make each product up to eighty times slower); the results are
    the same, each product's sums being split over rows and columns, not over the samples."""
    if not _controller:
        _controller.append(ThreadpoolController())
    with _controller[0].limit(limits=1, user_api="blas"):
        yield


def fit_approach(t: np.ndarray, markers: np.ndarray, sigma: float, t_end: float | None = None,
                 tau: float | None = None) -> Approach | None:
    """Fit x(s) = x_inf + (a + b s) exp(-s / tau) to a hold's tail, s = t - t[0].

    t: (K,) s; markers: (K, M, 3) m (NaN: occluded); sigma: noise per coordinate (m); t_end:
    the hold's end (default t[-1]), where ``remaining_m`` is evaluated. One tau for every marker,
    searched on a log grid from two samples to three times the stretch (or ``tau`` given: the
    session's); for each tau the rest is linear least squares (normal equations, per marker over
    its visible samples). None when no marker has 8 samples in the stretch.
    """
    with _one_blas_thread():
        return _fit(t, markers, sigma, t_end, tau)


def _fit(t: np.ndarray, markers: np.ndarray, sigma: float, t_end: float | None, tau: float | None) -> Approach | None:
    """fit_approach's body (its docstring)."""
    t = np.asarray(t, float)
    K = len(t)
    if K < 8:
        return None
    s = t - t[0]
    span = max(s[-1], 1e-9)
    dt = span / max(K - 1, 1)
    ok = np.isfinite(markers).all(axis=2)  # (K, M)
    if not np.any(ok.sum(axis=0) >= 8):
        return None
    seen = ok.sum(axis=0) >= 8
    M = markers.shape[1]
    # centred per marker: the sums below then hold the decay, not the marker's place (no cancellation)
    mean = np.sum(np.where(ok[..., None], markers, 0.0), axis=0) / np.maximum(ok.sum(axis=0), 1)[:, None]
    y = np.where(ok[..., None], markers - mean[None], 0.0)  # (K, M, 3)
    w = ok.astype(float)
    yty = np.sum(w[..., None] * y**2, axis=(0, 2))  # (M,)
    yw = (w[..., None] * y).reshape(K, -1)

    every = bool(ok.all()) and bool(np.all(w == w.flat[0]))  # no occlusion: one design for every marker

    def solve(taus):
        # the normal equations of the design [1, e, (s / tau) e] (e = exp(-s / tau)) built from
        # sums over the samples (one matrix product per entry, every tau at once)
        X = s[None, :] / taus[:, None]  # (T, K)
        E = np.exp(-X)
        P = X * E
        T = len(taus)
        rows = (E, P)
        Gty = np.empty((T, 3, yw.shape[1]))
        Gty[:, 0] = yw.sum(axis=0)
        Gty[:, 1] = E @ yw
        Gty[:, 2] = P @ yw
        Gty = np.moveaxis(Gty.reshape(T, 3, M, 3), 2, 1)  # (T, M, 3, 3): [param, coord]
        if every:
            # one design for every marker: one 3x3 system per tau, every marker's coordinates its columns
            A = np.empty((T, 3, 3))
            A[:, 0, 0] = K
            for i, g in enumerate(rows, start=1):
                A[:, 0, i] = A[:, i, 0] = g.sum(axis=1)
                for j, h in enumerate(rows[i - 1:], start=i):
                    A[:, i, j] = A[:, j, i] = np.einsum("tk,tk->t", g, h)
            A *= w.flat[0]
            A += np.eye(3) * 1e-12 * np.trace(A, axis1=1, axis2=2)[:, None, None]
            rhs = np.moveaxis(Gty, 1, 2).reshape(T, 3, M * 3)
            coef = np.moveaxis(np.linalg.solve(A, rhs).reshape(T, 3, M, 3), 2, 1)
            GtG = np.broadcast_to(A[:, None], (T, M, 3, 3))
        else:
            GtG = np.empty((T, M, 3, 3))
            GtG[:, :, 0, 0] = w.sum(axis=0)
            for i, g in enumerate(rows, start=1):
                GtG[:, :, 0, i] = GtG[:, :, i, 0] = g @ w
                for j, h in enumerate(rows[i - 1:], start=i):
                    GtG[:, :, i, j] = GtG[:, :, j, i] = (g * h) @ w
            GtG[:, ~seen] = np.eye(3)
            GtG = GtG + np.eye(3) * 1e-12 * np.trace(GtG, axis1=2, axis2=3)[..., None, None]
            coef = np.linalg.solve(GtG, Gty)  # (T, M, 3, 3): [param, coord]
        rss = yty[None] - np.einsum("tmic,tmic->tm", coef, Gty)  # (T, M)
        return np.sum(np.where(seen[None], rss, 0.0), axis=1), coef, GtG

    if tau is not None:
        taus = np.array([float(tau)])
        rss_tot, coef, GtG = solve(taus)
        j = 0
    else:
        # a coarse log grid, then twice a finer one around its best: a tail of millimetres
        # needs its time constant to a fraction of a percent
        # the residual over tau has a narrow valley when the tail is many noise levels deep, which a
        # grid can step over: the recurrence of the sampled decay (Prony) points at it, and both
        # the grid's best and Prony's are refined twice on finer grids; the lower wins
        grid = np.geomspace(2 * dt, 3 * span, COARSE_GRID)
        rss_g = solve(grid)[0]
        j = int(np.argmin(rss_g))
        at_top = j == len(grid) - 1
        # every local minimum of the grid near the best: two time constants can fit a short
        # stretch almost equally (a and b trade against tau), and only the finer search tells them apart
        interior = (rss_g[1:-1] <= rss_g[:-2]) & (rss_g[1:-1] <= rss_g[2:])
        minima = sorted({j} | {int(k) + 1 for k in np.nonzero(interior)[0] if rss_g[k + 1] <= 1.2 * rss_g[j]})
        starts = [(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]) for k in minima[:4]]
        tp = _prony_tau(y, ok, dt)
        if tp is not None and 2 * dt <= tp <= 3 * span:
            starts.append((tp / 1.2, tp * 1.2))
        # every start refined at once (one solve per round over all their grids)
        bounds = np.array(starts, float)  # (S, 2)
        ramp = np.linspace(0.0, 1.0, 12)
        for _ in range(3):
            taus = np.exp(np.log(bounds[:, :1]) + np.log(bounds[:, 1:] / bounds[:, :1]) * ramp[None]).ravel()
            rss_tot, coef, GtG = solve(taus)
            per = rss_tot.reshape(len(bounds), 12)
            k = np.argmin(per, axis=1)
            grid = taus.reshape(len(bounds), 12)
            rows = np.arange(len(bounds))
            bounds = np.column_stack([grid[rows, np.maximum(k - 1, 0)], grid[rows, np.minimum(k + 1, 11)]])
        j = int(np.argmin(rss_tot))
    c = coef[j]
    n_obs = 3 * int(ok[:, seen].sum())
    dof = max(n_obs - 9 * int(seen.sum()) - 1, 1)
    chi = float(max(rss_tot[j], 0.0) / dof / sigma**2)
    inv = np.linalg.inv(GtG[j])  # (M, 3, 3)
    cov00 = inv[:, 0, 0]  # (M,)
    std = np.sqrt(np.maximum(cov00, 0.0) * max(chi, 1.0)) * sigma
    x_inf = np.where(seen[:, None], mean + c[:, 0, :], np.nan)
    a = np.where(seen[:, None], c[:, 1, :], 0.0)
    b = np.where(seen[:, None], c[:, 2, :], 0.0)
    fit = Approach(tau=float(taus[j]), t0=float(t[0]), x_inf=x_inf,
                   x_inf_std=np.where(seen[:, None], std[:, None].repeat(3, axis=1), np.nan),
                   a=a, b=b, chi2_per_dof=chi, remaining_m=np.zeros(M),
                   at_limit=tau is None and at_top,
                   cov_ab=np.where(seen[:, None, None], inv[:, 1:, 1:] * max(chi, 1.0) * sigma**2, 0.0))
    # a tail the stream does not show (chi-square of what the decay explains, over every seen
    # coordinate, against sigma: the slow noise's when the caller passes it) is none: noise alone
    # must not move a window or make a hold unsettled
    rss0 = float(np.sum(yty[seen]))
    extra = 2 * 3 * int(seen.sum()) + 1
    if not chdtrc(extra, max((rss0 - max(rss_tot[j], 0.0)) / sigma**2, 0.0)) < TAIL_FALSE_ALARM:
        fit.a, fit.b = np.zeros_like(a), np.zeros_like(b)
        fit.x_inf = np.where(seen[:, None], mean, np.nan)
        fit.significant = False
    fit.remaining_m = np.linalg.norm(fit.tail(np.array([t[-1] if t_end is None else t_end]))[0], axis=1)
    return fit


def _fit_tail(ts: np.ndarray, seg: np.ndarray, k0: int, end: int, sigma: float) -> Approach | None:
    """The approach of one hold fitted from k0, a quarter or half of the way to the end: the
    earliest whose residual is within 15% of the best one's (per degree of freedom). The end
    of the main motion (a minimum-jerk deceleration, several actuators with their own time
    constants) is not one decay, and a fit that includes it mispredicts the tail; the noise
    level of the stream (coloured noise, a sigma estimated a few percent off) is judged
    against the stretch itself. None when the stretch is too short to fit."""
    def at(f):
        k = k0 + int(f * (end - k0))
        return fit_approach(ts[k:end], seg[k:end], sigma, t_end=ts[end - 1]) if end - k >= 16 else None

    late, first = at(0.5), at(0.0)
    if first is None:
        return late
    if late is None or first.chi2_per_dof <= 1.15 * late.chi2_per_dof:
        return first  # the decay from the end of the main motion on is one decay
    fits = [f for f in (first, at(0.25), late) if f is not None]
    floor = min(f.chi2_per_dof for f in fits)
    return next(f for f in fits if f.chi2_per_dof <= 1.15 * floor)


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


def tail_free_window(approach: Approach, t: np.ndarray, start: int, end: int, sigma: float,
                     fraction: float, min_samples: int,
                     estimate: Approach | None = None) -> tuple[int, np.ndarray] | None:
    """(s, correction): the window [s, end) to average and the fitted tail's share of its mean
    ((M, 3) m, to subtract). s is the first index in [start, end - min_samples] at which that
    share is at most ``fraction`` of the averaging noise sigma / sqrt(end - s) (its norm over
    every marker coordinate: the bias along the tail's direction, where a pose's averaging noise
    is sigma / sqrt(n)); the correction is then zero. When no window is that clean but one's share
    stays below its averaging noise, that window and its share are returned (the mean is corrected
    by a fraction of its noise); None when every window is biased more (the hold has not settled)."""
    if end - start < min_samples:
        return None
    F = np.nan_to_num(approach.tail(t[start:end]))  # (L, M, 3)
    cs = np.cumsum(F[::-1], axis=0)[::-1]  # sum from each index to the end
    L = end - start
    n = L - np.arange(L)
    share = cs / n[:, None, None]
    ratio = np.linalg.norm(share.reshape(L, -1), axis=1) / (sigma / np.sqrt(n))  # along the tail
    ratio[n < min_samples] = np.inf
    idx = np.nonzero(ratio <= fraction)[0]
    if idx.size:
        return start + int(idx[0]), np.zeros(F.shape[1:])
    k = int(np.argmin(ratio))
    if ratio[k] <= 1.0:
        if estimate is not None and estimate is not approach:
            G = np.nan_to_num(estimate.tail(t[start + k:end]))
            return start + k, G.mean(axis=0)
        return start + k, share[k]
    return None


def tail_regression(F: np.ndarray, markers: np.ndarray) -> tuple[float, float]:
    """(sum g y, sum g g) m^2 of the regression of a still stretch (markers (L, M, 3)) on a tail's
    shape F (L, M, 3), both centred per marker coordinate over the samples where the marker is
    seen (markers with fewer than 4 such samples left out): kappa = num / den, its standard error
    sigma / sqrt(den). Sums, so that holds can be pooled."""
    ok = np.isfinite(markers).all(axis=2)
    num = den = 0.0
    for m in range(markers.shape[1]):
        sel = ok[:, m]
        if sel.sum() < 4:
            continue
        g = F[sel, m] - F[sel, m].mean(axis=0)
        y = markers[sel, m] - markers[sel, m].mean(axis=0)
        num += float(np.sum(g * y))
        den += float(np.sum(g * g))
    return num, den


def tail_scale(approach: Approach, t: np.ndarray, markers: np.ndarray, sigma: float, z: float = 2.0,
               floor_z: float = 3.0) -> tuple[float, float]:
    """(kappa, upper bound) of the share of the fitted tail that a still stretch (t (L,), markers
    (L, M, 3)) bears out: the data, centred, regressed on the tail's own shape over the stretch
    (kappa, standard error se against ``sigma``). The bound is kappa + z se, at least 0. A tail
    the stretch cannot tell from the noise (at its start below ``floor_z`` times its own standard
    error, over every marker coordinate) has kappa 0 but keeps the bound; a tail the stretch
    bears out within 4 se keeps kappa 1."""
    F = approach.tail(t)
    num, den = tail_regression(F, markers)
    if den <= 0:
        return 1.0, 1.0
    kappa, se = num / den, sigma / np.sqrt(den)
    hi = max(kappa + z * se, 0.0)
    sd = approach.tail_std(t[:1])[0]
    if np.linalg.norm(F[0]) < floor_z * np.sqrt(3.0) * np.linalg.norm(sd):
        return 0.0, hi  # not established: the bound is what the stretch allows
    if abs(kappa - 1.0) <= 4.0 * se:
        return 1.0, max(hi, 1.0)
    return max(kappa, 0.0), hi


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


def _window_result(ts: np.ndarray, seg: np.ndarray, start: int, end: int, correction: np.ndarray,
                   fit: Approach | None) -> dict | None:
    """The averaged pose of window [start, end) of a hold's stretch (NaN-aware), less
    ``correction`` (M, 3); None when every marker is occluded all window long."""
    w = seg[start:end]
    ok = np.isfinite(w).all(axis=2)
    cnt = ok.sum(axis=0)
    if not np.any(cnt):
        return None
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a marker occluded all window long
        mean = np.nanmean(np.where(ok[..., None], w, np.nan), axis=0)
        std = np.sqrt(np.nanmean(np.sum((w - mean) ** 2, axis=2), axis=0) / 3)
    held = mean.copy()
    mean = mean - correction  # the approach's share of the window mean (zero in a clean window)
    mean[cnt == 0] = np.nan
    held[cnt == 0] = np.nan
    return dict(mean=mean, held=held, cnt=cnt.astype(float), std=std, start=ts[start], end=ts[end - 1],
                tau=np.nan if fit is None else fit.tau,
                remaining=np.nan if fit is None else float(np.nanmax(fit.remaining_m)), extrapolated=0.0)
