"""Where a stream is still (platkit.settle): the noise, the neighbouring-halves still
test and the last still stretch of a hold, the trend test of a window, and each command's last step."""
from __future__ import annotations

import functools

import numpy as np
from scipy.special import chdtrc, gammaincinv

from platkit.settle._native import halves, second_difference_mad, still_statistics, trend_statistic

#: sigma below this (1 micrometre) is not believed: noise-free or quantised streams
SIGMA_FLOOR_M = 1e-6

#: coloured noise is believed up to this many times white noise's variance of a mean; beyond, the
#: "noise" is motion (a recording that never rests)
MAX_INFLATION = 30.0


def estimate_noise(markers: np.ndarray, compiled: bool = True) -> float:
    """Marker noise sigma (m, per coordinate) of a stream ``markers`` (K, M, 3), NaN-aware,
    from the median absolute second difference (second differences of white noise have
    variance 6 sigma^2). The compiled kernel (platkit.settle._native.second_difference_mad)
    gives the same number where it is available and ``compiled`` is true."""
    got = second_difference_mad(markers) if compiled and markers.ndim == 3 else None
    if got is not None:
        return SIGMA_FLOOR_M if got[1] < 10 else max(1.4826 * got[0] / np.sqrt(6.0), SIGMA_FLOOR_M)
    # one working array the size of the stream (the medians select in place: their values do
    # not depend on the order they leave behind)
    dd = np.multiply(markers[1:-1], -2.0)
    dd += markers[2:]
    dd += markers[:-2]
    finite = np.isfinite(dd)
    if not finite.all():
        dd = dd[finite]
    del finite
    if dd.size < 10:
        return SIGMA_FLOOR_M
    dd -= np.median(dd, overwrite_input=True)
    np.abs(dd, out=dd)
    mad = np.median(dd, overwrite_input=True)
    return max(1.4826 * mad / np.sqrt(6.0), SIGMA_FLOOR_M)


def noise_inflation(stretches: list[np.ndarray], sigma: float, L: int) -> float:
    """How much more a mean over L samples varies than white noise of ``sigma`` says (1 to
    MAX_INFLATION): the marker noise of motion capture is often coloured (vibration, air, the
    fit of the markers' images), and tests of slow things (a trend over a window, a decay) must
    use its slow part.

    ``stretches``: (K, M, 3) pieces of the stream where the stand is at rest or nearly. From
    consecutive triples of L-sample blocks, the second difference of their means squared (a
    steady creep cancels), over its white-noise variance; the lower quartile over every triple
    and coordinate, over that of chi-square(1) (a stretch still moving pushes only the upper
    part). 1 when fewer than 10 triples are found."""
    q = []
    for seg in stretches:
        for k in range(0, len(seg) - 3 * L + 1, 3 * L):
            blocks = [seg[k + j * L:k + (j + 1) * L] for j in range(3)]
            oks = [np.isfinite(x).all(axis=2) for x in blocks]
            ns = [o.sum(axis=0) for o in oks]
            use = np.all([nn >= L // 2 + 1 for nn in ns], axis=0)
            if not use.any():
                continue
            ms = [np.sum(np.where(o[..., None], x, 0.0), axis=0) / np.maximum(nn, 1)[:, None]
                  for x, o, nn in zip(blocks, oks, ns)]
            var = sigma**2 * (1.0 / np.maximum(ns[0], 1) + 4.0 / np.maximum(ns[1], 1) + 1.0 / np.maximum(ns[2], 1))
            q.append((((ms[0] - 2 * ms[1] + ms[2]) ** 2) / var[:, None])[use].ravel())
    if len(q) < 10:
        return 1.0
    return float(np.clip(np.percentile(np.concatenate(q), 25) / _chi2_quantile(0.25, 1), 1.0, MAX_INFLATION))


@functools.cache
def _chi2_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of chi-square with ``dof`` degrees of freedom."""
    return float(2.0 * gammaincinv(dof / 2.0, p))


def _quiet_stretches(t: np.ndarray, markers: np.ndarray, command_t: np.ndarray, n: int, sigma: float,
                     gap: int) -> list[np.ndarray]:
    """The last still stretch of every hold by the still test at white ``sigma`` (a strict test
    under coloured noise, but what it calls still is still); the 50-90% part of every hold when
    that finds too little (strongly coloured noise)."""
    ends = np.append(command_t[1:], t[-1] + 1e-9)
    out, fallback = [], []
    for t0, t1 in zip(command_t, ends):
        a, b = np.searchsorted(t, t0), np.searchsorted(t, t1)
        seg = markers[a:b]
        if len(seg) < 2 * n:
            continue
        run = _last_still_run(still_mask(seg, n, sigma, 1e-4), gap)
        if run is not None and run[1] - run[0] >= 6 * n:
            out.append(seg[run[0]:run[1]])
        fallback.append(seg[int(0.5 * len(seg)):int(0.9 * len(seg))])
    return out if len(out) >= max(3, len(command_t) // 4) else fallback


def direction_of_last_motion(controls: np.ndarray) -> np.ndarray:
    """(N, n_u) sign of the last change of each control up to each row (0 before any change).
    ``controls``: (N, n_u) in command order."""
    U = np.asarray(controls, float)
    out = np.zeros_like(U)
    last = np.zeros(U.shape[1])
    for i in range(1, len(U)):
        d = np.sign(U[i] - U[i - 1])
        last = np.where(d != 0, d, last)
        out[i] = last
    return out


def last_step(controls: np.ndarray) -> np.ndarray:
    """(N, n_u) the command step that led to each row, u_i - u_(i-1) (zeros for the first)."""
    U = np.asarray(controls, float)
    return np.vstack([np.zeros((1, U.shape[1])), np.diff(U, axis=0)])


def _window_sums(x: np.ndarray):
    """Cumulative sums for NaN-aware window means: x (K, M, 3) -> (sum (K+1, M, 3), count (K+1, M))."""
    ok = np.isfinite(x).all(axis=2)
    xs = np.where(ok[..., None], x, 0.0)
    S = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(xs, axis=0)])
    C = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(ok, axis=0)])
    return S, C


def _halves(markers: np.ndarray, n: int, sums: tuple[np.ndarray, np.ndarray] | None = None, compiled: bool = True):
    """Means of the n samples before and from each sample k: (mb, ma (K, M, 3), nb, na (K, M)).
    ``sums``: :func:`_window_sums` of a stretch that ``markers`` begins (its first K + 1 rows used).
    The compiled kernel (platkit.settle._native.halves) gives the same numbers where it is
    available and ``compiled`` is true."""
    if compiled:
        got = halves(markers, n)
        if got is not None:
            return got
    K = markers.shape[0]
    S, C = _window_sums(markers) if sums is None else sums
    k = np.arange(K)
    a = np.maximum(k - n, 0)
    b = np.minimum(k + n, K)
    nb = C[k] - C[a]
    na = C[b] - C[k]
    mb = (S[k] - S[a]) / np.maximum(nb, 1)[..., None]
    ma = (S[b] - S[k]) / np.maximum(na, 1)[..., None]
    return mb, ma, nb, na


def still_mask(markers: np.ndarray, n: int, sigma: float, false_alarm: float,
               sums: tuple[np.ndarray, np.ndarray] | None = None, compiled: bool = True) -> np.ndarray:
    """(K,) True where the markers (K, M, 3), one command's stretch, are still at sample k.

    Windows are clipped to the stretch; the first sample (no past) is never still. ``sums``: as
    :func:`_halves` takes them. The statistic is the compiled kernel's where it is available and
    ``compiled`` is true (platkit.settle._native.still_statistics: the same numbers).
    """
    got = still_statistics(markers, n, sigma**2) if compiled else None
    if got is not None:
        stat, _, m = got
    else:
        mb, ma, nb, na = _halves(markers, n, sums, compiled=False)
        vis = (nb > 0) & (na > 0)
        scale2 = sigma**2 * (1.0 / np.maximum(nb, 1) + 1.0 / np.maximum(na, 1))
        z2 = np.where(vis, np.sum((ma - mb) ** 2, axis=2) / scale2, 0.0)
        m = vis.sum(axis=1)
        stat = z2.sum(axis=1) / np.maximum(m, 1)
    # the quantile of chi-square(3m) / m for each number m of visible markers
    limits = np.array([_chi2_quantile(1 - false_alarm, 3 * k) / k for k in range(1, markers.shape[1] + 1)])
    return (m > 0) & (stat < limits[np.maximum(m, 1) - 1])


def _last_still_run(still: np.ndarray, gap: int, min_length: int = 0, tail: int = 0) -> tuple[int, int] | None:
    """[start, end) of the last still stretch, bridging up to ``gap`` moving samples. With
    ``min_length``: the last stretch at least that long when no more than ``tail`` samples follow
    it (a flicker of stillness at the very end, where the test's half-window is clipped, while
    the next move starts, is no stretch of its own)."""
    idx = np.nonzero(still)[0]
    if idx.size == 0:
        return None
    breaks = np.nonzero(np.diff(idx) - 1 > gap)[0]
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    if min_length > 0:
        long_enough = np.nonzero(ends - starts >= min_length)[0]
        if long_enough.size and len(still) - ends[long_enough[-1]] <= tail:
            k = int(long_enough[-1])
            return int(starts[k]), int(ends[k])
    return int(starts[-1]), int(ends[-1])


def approach_start(markers: np.ndarray, n: int, sigma: float,
                   sums: tuple[np.ndarray, np.ndarray] | None = None, compiled: bool = True) -> int | None:
    """Index where the main motion of a hold's stretch (K, M, 3) has slowed to half its peak
    speed (the approach's tail begins; the peak itself when it never slows that much), or None
    when the stretch shows no motion beyond the noise. ``sums``: as :func:`_halves` takes them;
    ``compiled``: as :func:`still_mask` takes it."""
    got = still_statistics(markers, n, sigma**2) if compiled else None
    if got is not None:
        d = np.sqrt(got[1] / np.maximum(got[2], 1))
    else:
        mb, ma, nb, na = _halves(markers, n, sums, compiled=False)
        vis = (nb > 0) & (na > 0)
        d = np.sqrt(np.sum(np.where(vis[..., None], ma - mb, 0.0) ** 2, axis=(1, 2)) / np.maximum(vis.sum(axis=1), 1))
    noise = sigma * np.sqrt(2.0 / n) * np.sqrt(3.0)
    full = np.zeros(len(d), bool)
    full[n:len(d) - n + 1] = True  # both halves whole: a clipped half sees less of the motion
    if not full.any():
        return None
    d = np.where(full, d, 0.0)
    k_peak = int(np.argmax(d))
    if d[k_peak] < 10 * noise:
        return None
    below = np.nonzero(full[k_peak:] & (d[k_peak:] < 0.5 * d[k_peak]))[0]
    # an approach slower than the hold never halves its speed: its decay is fitted from the peak
    return k_peak if below.size == 0 else k_peak + int(below[0])


def trend_test(t: np.ndarray, markers: np.ndarray, sigma: float, compiled: bool = True) -> tuple[float, float]:
    """Regression on time over a whole window: (p-value of "no trend", largest speed in m/s).
    Chi-square of the slopes of every seen marker coordinate (3 per marker). The compiled kernel
    (platkit.settle._native.trend_statistic, the same sums to rounding) where it is available
    and ``compiled`` is true."""
    got = trend_statistic(t, markers, sigma**2) if compiled else None
    if got is not None:
        return (1.0, 0.0) if got[1] == 0 else (float(chdtrc(got[1], got[0])), got[2])
    ok = np.isfinite(markers).all(axis=2)
    stat, dof, vmax = 0.0, 0, 0.0
    for m in range(markers.shape[1]):
        sel = ok[:, m]
        if sel.sum() < 4:
            continue
        tt = t[sel] - t[sel].mean()
        sxx = float(np.sum(tt**2))
        if sxx <= 0:
            continue
        slope = tt @ (markers[sel, m] - markers[sel, m].mean(axis=0)) / sxx  # (3,)
        stat += float(np.sum(slope**2) * sxx / sigma**2)
        dof += 3
        vmax = max(vmax, float(np.linalg.norm(slope)))
    if dof == 0:
        return 1.0, 0.0
    return float(chdtrc(dof, stat)), vmax
