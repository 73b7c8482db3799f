"""The tail the holds share (platkit.settle): each hold timed from its arrival near rest,
the pooled tail of every hold, and where each window must start so that it lags by at most a
fraction of its noise."""
from __future__ import annotations

import numpy as np

#: the shared tail is aligned where a hold's distance still to go falls below this many sigma
ARRIVAL_SIGMA = 20.0


def arrival_index(ts: np.ndarray, seg: np.ndarray, k0: int, end: int, rest: np.ndarray, step: np.ndarray,
                  sigma: float, n: int) -> int | None:
    """The index after which a hold's distance still to go along its step (the running mean of
    ``n`` samples of (x - rest) . step / |step|, m) stays below ARRIVAL_SIGMA sigma: the arrival
    its tail is timed from. None when it never was that far (a step too small to time by)."""
    d = seg[k0:end] - rest[None]
    ok = np.isfinite(d).all(axis=2) & np.isfinite(step).all(axis=1)[None]
    norm = np.sqrt(np.sum(np.where(ok[..., None], step[None] ** 2, 0.0), axis=(1, 2)))
    proj = np.sum(np.where(ok[..., None], d * step[None], 0.0), axis=(1, 2)) / np.maximum(norm, 1e-300)
    good = norm > 0
    if good.sum() < n:
        return None
    c = np.concatenate([[0.0], np.cumsum(np.where(good, proj, 0.0))])
    w = np.concatenate([[0], np.cumsum(good)])
    k = np.arange(len(proj))
    lo, hi = np.maximum(k - n // 2, 0), np.minimum(k + n // 2 + 1, len(proj))
    run = (c[hi] - c[lo]) / np.maximum(w[hi] - w[lo], 1)
    far = np.nonzero(np.abs(run) > ARRIVAL_SIGMA * sigma)[0]
    return None if far.size == 0 else k0 + int(far[-1]) + 1


def shared_tail(windows: dict[int, tuple], results: dict[int, dict], sigma: float, n: int) -> tuple | None:
    """The approach's tail as the holds share it: h(s), the distance (m) a hold still has to go
    along its step s seconds after its arrival (:func:`arrival_index`: the distance last above
    ARRIVAL_SIGMA sigma), pooled over every settled hold in bins of ``n`` samples' time. Timed
    from there, every hold's tail starts from the same distance and decays as its drives do,
    whatever the length of the step.

    windows: row -> (t, stretch, approach start, window start, end); results: row -> its settled
    'mean' (M, 3), to which the step (this rest minus the previous hold's, over every marker
    coordinate) is added as 'step' and the arrival index as 'arrival'. Returns (bin edges (B+1,)
    s, h (B,), its standard error (B,)), or None when fewer than 5 holds can be timed."""
    rows = sorted(windows)
    for prev, i in zip([None] + rows[:-1], rows):
        results[i]["step"] = None if prev is None or prev != i - 1 else results[i]["mean"] - results[prev]["mean"]
        results[i]["arrival"] = None
        ts, seg, k0, start, end = windows[i]
        step = results[i]["step"]
        if step is not None and k0 is not None and np.all(np.isfinite(step)):
            results[i]["arrival"] = arrival_index(ts, seg, k0, end, results[i]["mean"], step, sigma, n)
    use = [i for i in rows if results[i]["arrival"] is not None and windows[i][4] - results[i]["arrival"] > n]
    if len(use) < 5:
        return None
    dt = float(np.median(np.diff(windows[use[0]][0])))
    span = max(windows[i][0][windows[i][4] - 1] - windows[i][0][results[i]["arrival"]] for i in use)
    edges = np.arange(0.0, span + n * dt, n * dt)
    num = np.zeros(len(edges) - 1)
    cnt = np.zeros(len(edges) - 1)
    for i in use:
        ts, seg, k0, start, end = windows[i]
        k = results[i]["arrival"]
        step = results[i]["step"]
        d = seg[k:end] - results[i]["mean"][None]  # (L, M, 3)
        ok = np.isfinite(d).all(axis=2)
        norm = np.sqrt(np.sum(np.where(ok[..., None], step[None] ** 2, 0.0), axis=(1, 2)))  # (L,)
        proj = np.sum(np.where(ok[..., None], d * step[None], 0.0), axis=(1, 2)) / np.maximum(norm, 1e-300)
        b = np.searchsorted(edges, ts[k:end] - ts[k], side="right") - 1
        keep = (b >= 0) & (b < len(num)) & (norm > 0)
        np.add.at(num, b[keep], -proj[keep])
        np.add.at(cnt, b[keep], 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(cnt > 0, num / np.maximum(cnt, 1), 0.0)
        se = np.where(cnt > 0, sigma / np.sqrt(np.maximum(cnt, 1)), np.inf)
    return edges, h, se


def profile_start(profile: tuple, arrival: int | None, ts: np.ndarray, start: int, end: int,
                  sigma: float, fraction: float, min_samples: int) -> int | None:
    """The first index s >= start at which the shared tail (:func:`shared_tail`), timed from this
    hold's ``arrival`` index, biases the mean over [s, end) by at most ``fraction`` of its
    averaging noise sigma / sqrt(end - s). The tail decays: from the first bin where the profile
    is within two standard errors of zero on, it is extrapolated from the last resolved bins'
    decay (a later bin off zero by chance must not push every window late). When no window of at
    least ``min_samples`` is that clean, the one whose bias is the smallest share of its noise;
    None when the hold has no arrival
    (a step too small to time) or is shorter than ``min_samples``."""
    if arrival is None or end - start < min_samples:
        return None
    edges, h, se = profile
    gone = np.nonzero(np.abs(h) <= 2 * se)[0]
    r = int(gone[0]) if gone.size else len(h)
    idx = np.arange(len(h))
    if r >= 3 and h[r - 1] * h[r - 3] > 0:
        # below its resolution the tail goes on decaying as its last resolved bins did
        q = min(abs(h[r - 1] / h[r - 3]) ** 0.5, 0.95)
        h = np.where(idx < r, h, h[r - 1] * q ** (idx - r + 1.0))
    else:
        h = np.where(idx < r, h, 0.0)
    s = ts[start:end] - ts[arrival]
    b = np.searchsorted(edges, s, side="right") - 1
    hs = np.where((b >= 0) & (b < len(h)), h[np.clip(b, 0, len(h) - 1)], 0.0)
    hs = np.where(b < 0, h[0] if len(h) else 0.0, hs)  # before the arrival: at least the first bin's
    L = end - start
    nrem = L - np.arange(L)
    share = np.abs(np.cumsum(hs[::-1])[::-1]) / nrem
    ratio = np.where(nrem >= min_samples, share / (sigma / np.sqrt(nrem)), np.inf)
    idx = np.nonzero(ratio <= fraction)[0]
    if idx.size:
        return start + int(idx[0])
    # no window is that clean: the least biased one (a window starting in the tail is the worse)
    return start + int(np.argmin(ratio)) if np.isfinite(ratio).any() else None
