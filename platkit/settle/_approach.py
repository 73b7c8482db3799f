"""The approach of a hold to rest (platkit.settle): ``x_inf + (a + b s) exp(-s / tau)`` as
fitted to the stream (platkit.settle._fits), the window its tail leaves free, the tail's share of
a still stretch, and a window's averaged result."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np


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
               floor_z: float = 3.0, sums: tuple[float, float] | None = None) -> tuple[float, float]:
    """(kappa, upper bound) of the share of the fitted tail that a still stretch (t (L,), markers
    (L, M, 3)) bears out: the data, centred, regressed on the tail's own shape over the stretch
    (kappa, standard error se against ``sigma``). The bound is kappa + z se, at least 0. A tail
    the stretch cannot tell from the noise (at its start below ``floor_z`` times its own standard
    error, over every marker coordinate) has kappa 0 but keeps the bound; a tail the stretch
    bears out within 4 se keeps kappa 1. ``sums``: :func:`tail_regression` of the stretch on the
    tail when the caller has it."""
    F = approach.tail(t)
    num, den = tail_regression(F, markers) if sums is None else sums
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


def _window_result(ts: np.ndarray, seg: np.ndarray, start: int, end: int, correction: np.ndarray,
                   fit: Approach | None) -> dict | None:
    """The averaged pose of window [start, end) of a hold's stretch (NaN-aware), less
    ``correction`` (M, 3); None when every marker is occluded all window long."""
    w = seg[start:end]
    ok = np.isfinite(w).all(axis=2)
    cnt = ok.sum(axis=0)
    if not np.any(cnt):
        return None
    with np.errstate(invalid="ignore", divide="ignore"):  # a marker occluded all window long: NaN
        # the sums over the seen samples over their count, as numpy's nanmean takes them
        mean = np.sum(np.where(ok[..., None], w, 0.0), axis=0) / cnt[:, None]
        std = np.sqrt(np.sum(np.where(ok, np.sum((w - mean) ** 2, axis=2), 0.0), axis=0) / cnt / 3)
    held = mean.copy()
    mean = mean - correction  # the approach's share of the window mean (zero in a clean window)
    mean[cnt == 0] = np.nan
    held[cnt == 0] = np.nan
    return dict(mean=mean, held=held, cnt=cnt.astype(float), std=std, start=ts[start], end=ts[end - 1],
                tau=np.nan if fit is None else fit.tau,
                remaining=np.nan if fit is None else float(np.nanmax(fit.remaining_m)), extrapolated=0.0)
