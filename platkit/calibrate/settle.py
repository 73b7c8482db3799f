"""Settled poses from raw streams: one pose per command, markers averaged where the stand was still.

For every command row i the stream between its time and the next command's is searched for the
window where the platform has settled: the last stretch of samples whose markers do not move
(beyond what the noise explains) for at least ``min_still_s``. Markers are averaged over that
window, NaN-aware (occluded samples are skipped and counted).

Stillness test at sample k: the mean position of each marker over the ``n`` samples before k
and over the ``n`` samples from k on differ by D. Under white noise of standard deviation sigma
per coordinate, D / (sigma sqrt(1/n_before + 1/n_after)) is chi-distributed with 3 degrees of
freedom per marker, so the mean of its square over the m visible markers is chi^2(3m) / m. A
sample is still when that statistic is below its ``1 - false_alarm`` quantile. Sigma is
estimated from the whole stream by the median absolute second difference, which smooth motion
hardly touches.

The neighbouring-halves test cannot see the slow tail of an approach (a stand creeping the last
micrometres towards rest changes little over ``window_s``), and a window that starts in it lags
the settled position along the last step. So the approach itself is fitted: from the end of the
main motion (its speed below half its peak) to the end of the hold, every marker coordinate
follows ``x_inf + (a + b s) exp(-s / tau)`` (s: time since the fit's start; first order and
critically damped second order approaches are both of this form) with one ``tau`` per hold, and
the window starts where the fitted tail's share of the window mean is at most ``tail_fraction``
of the averaging noise (sigma / sqrt(n)). The still stretch says how much of the fitted tail is
there (a regression on the tail's shape, :func:`tail_scale`): the window is chosen by the upper
bound of that share (a decay fitted too slow or too fast still marks where the approach ends),
a correction by its estimate. Each hold's tail is mostly below its own noise, but every hold
lags the same way: the tail as the holds share it (:func:`shared_tail`, timed from each hold's
arrival within ARRIVAL_SIGMA sigma of rest, where every tail starts from the same distance)
moves every window to where the pooled tail biases it by at most ``tail_fraction`` of its
noise. The trend is then tested over the whole window (a regression on time, chi-square over
the markers): a window that still moves is no settled pose.

A hold that never settles (no still stretch, or one that still trends, or a tail that does not
die before the next command) is dropped, unless so many do (more than ``max_unsettled_fraction``
of the commands) that the rest would be a remnant: then each is replaced by the fitted rest
position ``x_inf`` (its uncertainty in ``n_samples`` as sigma^2 / var, so the estimator weights
it) when its approach fits the stream, or the search stops with a ComputationFailed naming the
actuators and markers still moving and their time constant.
"""
from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.stats import chi2, fisher_exact

from platkit.calibrate.bodies import stream_for_settling, with_settled_bodies
from platkit.calibrate.settle_attribution import attribute_actuators
from platkit.errors import BadSession, ComputationFailed
from platkit.io.session import Session, load_session
from platkit.model import length_scale
from platkit.poses import PoseSet

#: sigma below this (1 micrometre) is not believed: noise-free or quantised streams
SIGMA_FLOOR_M = 1e-6

#: probability that a still stretch is fitted a significant approach tail
TAIL_FALSE_ALARM = 1e-5  # strict: the best of 64 time constants is tested

#: coloured noise is believed up to this many times white noise's variance of a mean; beyond, the
#: "noise" is motion (a recording that never rests)
MAX_INFLATION = 30.0

#: time constants on the coarse grid of an approach fit (then refined around its minima)
COARSE_GRID = 40

#: the time scale (s) of the slow noise that trend, decay and window-mean tests are judged against
SLOW_SCALE_S = 0.4

#: the categories a dropped command's reason starts with (``category: detail``)
DROP_CATEGORIES = ("no motion-capture samples", "too few samples", "moved again", "never settled",
                   "every marker occluded")


@dataclass
class SettleOptions:
    """Tuning of the settling search. Times in seconds."""

    window_s: float = 0.1  # length of each half of the stillness test
    min_still_s: float = 0.25  # a pose needs the platform still at least this long
    false_alarm: float = 1e-4  # probability a still sample is called moving
    gap_samples: int = 2  # moving samples tolerated inside a still stretch
    end_slack_s: float = 0.2  # the still stretch may end this long before the next command
                              # (motion starting early: a clock offset between the two files)
    sigma_m: float | None = None  # marker noise per coordinate; None: estimated
    tail_fraction: float = 0.05  # the approach's tail may bias a window mean by this much of its noise
    trend_false_alarm: float = 1e-3  # probability a still window is called trending
    max_unsettled_fraction: float = 0.1  # beyond: unsettled holds are extrapolated to rest (or the search stops)
    extrapolate: str = "auto"  # 'auto' (beyond max_unsettled_fraction), 'always', 'never'
    # an approach is extrapolated to rest only this far (m): markers follow the actuators through
    # the kinematics, and beyond about a millimetre the path to rest bends away from the fitted decay
    max_extrapolation_m: float = 1e-3
    # ... or this share of the hold's step (largest marker): over a small share of a move the
    # kinematics are straight whatever the stand's size
    max_extrapolation_share: float = 0.02
    max_window_s: float | None = None  # the window is at most this long, ending where the hold does
    bound_keeps: float = 0.4  # the tail's upper bound may cut the still stretch to this share (else its estimate rules)


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


@dataclass
class SettleReport:
    """What the settling search found, for the person reading the calibration report.

    dropped: (row, reason) of the commands that gave no pose; ``counts``: reason category -> count;
    unsettled: a summary of the holds that never settled (empty when none), with ``sentence``.
    """

    sigma_m: float
    n_commands: int
    n_kept: int
    dropped: list[tuple[int, str]]
    rate_hz: float
    n_extrapolated: int = 0
    unsettled: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        return dropped_by_reason(self.dropped)


def dropped_by_reason(dropped: list[tuple[int, str]]) -> dict[str, int]:
    """Reason category (the text before the first ':') -> number of dropped commands, largest first."""
    c = Counter(str(why).split(":", 1)[0].strip() for _, why in dropped)
    return dict(sorted(c.items(), key=lambda kv: -kv[1]))


def dropped_sentence(dropped: list[tuple[int, str]], n_commands: int | None = None) -> str:
    """One line: how many commands were dropped, by reason ('' when none)."""
    if not dropped:
        return ""
    of = f" of {n_commands}" if n_commands is not None else ""
    parts = ", ".join(f"{n} {why}" for why, n in dropped_by_reason(dropped).items())
    return f"{len(dropped)}{of} commands gave no settled pose: {parts}"


def settling_summary(poses: PoseSet, unit: str | None = None) -> dict:
    """What became of every command of a session, for report.json (lengths in ``unit``, default
    the session's): n_commands, n_poses, n_dropped, dropped_by_reason, dropped (row: 1-based data
    row of commands.csv, reason), n_extrapolated and, when holds never settled, ``unsettled``
    (sentence, actuators, markers, time_constant_s, hold_s, remaining, moved_late_along_actuator:
    per actuator, the median over its holds of how far the markers still moved along its own
    Jacobian column late in the hold, reversed; positive: behind its command)."""
    scale = length_scale(unit or poses.length_unit)
    info = poses.settling or {}
    n_commands = int(info.get("n_commands", poses.n_poses + len(poses.dropped)))
    out = {"n_commands": n_commands, "n_poses": int(poses.n_poses), "n_dropped": len(poses.dropped),
           "dropped_by_reason": dropped_by_reason(poses.dropped),
           "dropped": [{"row": int(r) + 1, "reason": str(why)} for r, why in poses.dropped],
           "n_extrapolated": int(info.get("n_extrapolated", 0))}
    un = info.get("unsettled") or {}
    if un:
        out["unsettled"] = {"sentence": un["sentence"], "n": int(un["n"]), "actuators": list(un["actuators"]),
                            "markers": list(un["markers"]),
                            "time_constant_s": _finite(un["time_constant_s"]),
                            "time_constant_quartiles_s": [_finite(v) for v in un["time_constant_quartiles_s"]],
                            "hold_s": _finite(un["hold_s"]), "remaining": _finite(un["remaining_m"] / scale),
                            "moved_late_along_actuator": {
                                k: (None if v is None else v / scale)
                                for k, v in (un.get("moved_late_along_actuator_m") or {}).items()}}
    return out


def _nan_mean(x: np.ndarray) -> np.ndarray:
    """(M, 3) the mean of a stretch (K, M, 3) over its samples where the marker is seen (NaN: never)."""
    ok = np.isfinite(x).all(axis=2)
    cnt = ok.sum(axis=0)
    return np.where((cnt > 0)[:, None], np.sum(np.where(ok[..., None], x, 0.0), axis=0) / np.maximum(cnt, 1)[:, None],
                    np.nan)


def _finite(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def estimate_noise(markers: np.ndarray) -> float:
    """Marker noise sigma (m, per coordinate) of a stream ``markers`` (K, M, 3), NaN-aware,
    from the median absolute second difference (second differences of white noise have
    variance 6 sigma^2)."""
    dd = markers[2:] - 2 * markers[1:-1] + markers[:-2]
    dd = dd[np.isfinite(dd)]
    if dd.size < 10:
        return SIGMA_FLOOR_M
    mad = np.median(np.abs(dd - np.median(dd)))
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
    return float(np.clip(np.percentile(np.concatenate(q), 25) / chi2.ppf(0.25, 1), 1.0, MAX_INFLATION))


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


def _halves(markers: np.ndarray, n: int):
    """Means of the n samples before and from each sample k: (mb, ma (K, M, 3), nb, na (K, M))."""
    K = markers.shape[0]
    S, C = _window_sums(markers)
    k = np.arange(K)
    a = np.maximum(k - n, 0)
    b = np.minimum(k + n, K)
    nb = C[k] - C[a]
    na = C[b] - C[k]
    mb = (S[k] - S[a]) / np.maximum(nb, 1)[..., None]
    ma = (S[b] - S[k]) / np.maximum(na, 1)[..., None]
    return mb, ma, nb, na


def still_mask(markers: np.ndarray, n: int, sigma: float, false_alarm: float) -> np.ndarray:
    """(K,) True where the markers (K, M, 3), one command's stretch, are still at sample k.

    Windows are clipped to the stretch; the first sample (no past) is never still.
    """
    mb, ma, nb, na = _halves(markers, n)
    vis = (nb > 0) & (na > 0)
    scale2 = sigma**2 * (1.0 / np.maximum(nb, 1) + 1.0 / np.maximum(na, 1))
    z2 = np.where(vis, np.sum((ma - mb) ** 2, axis=2) / scale2, 0.0)
    m = vis.sum(axis=1)
    stat = z2.sum(axis=1) / np.maximum(m, 1)
    limit = chi2.ppf(1 - false_alarm, 3 * np.maximum(m, 1)) / np.maximum(m, 1)
    return (m > 0) & (stat < limit)


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


def approach_start(markers: np.ndarray, n: int, sigma: float) -> int | None:
    """Index where the main motion of a hold's stretch (K, M, 3) has slowed to half its peak
    speed (the approach's tail begins; the peak itself when it never slows that much), or None
    when the stretch shows no motion beyond the noise."""
    mb, ma, nb, na = _halves(markers, n)
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


def fit_approach(t: np.ndarray, markers: np.ndarray, sigma: float, t_end: float | None = None,
                 tau: float | None = None) -> Approach | None:
    """Fit x(s) = x_inf + (a + b s) exp(-s / tau) to a hold's tail, s = t - t[0].

    t: (K,) s; markers: (K, M, 3) m (NaN: occluded); sigma: noise per coordinate (m); t_end:
    the hold's end (default t[-1]), where ``remaining_m`` is evaluated. One tau for every marker,
    searched on a log grid from two samples to three times the stretch (or ``tau`` given: the
    session's); for each tau the rest is linear least squares (normal equations, per marker over
    its visible samples). None when no marker has 8 samples in the stretch.
    """
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
        E = np.exp(-s[None, :] / taus[:, None])  # (T, K)
        G = np.stack([np.ones_like(E), E, (s[None, :] / taus[:, None]) * E], axis=2)  # (T, K, 3)
        T = len(taus)
        Gt = G.transpose(0, 2, 1)
        if every:
            GtG = np.broadcast_to(w.flat[0] * (Gt @ G)[:, None], (T, M, 3, 3)).copy()
        else:
            GG = (G[..., :, None] * G[..., None, :]).reshape(T, K, 9)
            GtG = np.moveaxis((GG.transpose(0, 2, 1) @ w).reshape(T, 3, 3, M), 3, 1)  # (T, M, 3, 3)
        Gty = np.moveaxis((Gt @ yw).reshape(T, 3, M, 3), 2, 1)  # (T, M, 3, 3)
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
    if not chi2.sf((rss0 - max(rss_tot[j], 0.0)) / sigma**2, extra) < TAIL_FALSE_ALARM:
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
    r = float(np.max(np.abs(np.roots([1.0, -coef[0], -coef[1]]))))
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


def tail_scale(approach: Approach, t: np.ndarray, markers: np.ndarray, sigma: float, z: float = 2.0,
               floor_z: float = 3.0) -> tuple[float, float]:
    """(kappa, upper bound) of the share of the fitted tail that a still stretch (t (L,), markers
    (L, M, 3)) bears out: the data, centred, regressed on the tail's own shape over the stretch
    (kappa, standard error se against ``sigma``). The bound is kappa + z se, at least 0. A tail
    the stretch cannot tell from the noise (at its start below ``floor_z`` times its own standard
    error, over every marker coordinate) has kappa 0 but keeps the bound; a tail the stretch
    bears out within 4 se keeps kappa 1."""
    F = approach.tail(t)
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


def trend_test(t: np.ndarray, markers: np.ndarray, sigma: float) -> tuple[float, float]:
    """Regression on time over a whole window: (p-value of "no trend", largest speed in m/s).
    Chi-square of the slopes of every seen marker coordinate (3 per marker)."""
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
    return float(chi2.sf(stat, dof)), vmax


def _unsettled_summary(rows: list[int], fits: dict[int, Approach], U: np.ndarray, control_names: list[str],
                       marker_names: list[str], hold_s: np.ndarray, n_commands: int,
                       other_drops: set[int] | None = None, slow_taus: dict[int, float] | None = None,
                       slow_left: dict[int, float] | None = None, held: np.ndarray | None = None,
                       tails: dict[int, np.ndarray] | None = None) -> dict:
    """Which actuators and markers are still moving in the holds ``rows`` that never settled, and
    with what time constant; ``sentence`` says it in one line.

    An actuator is named when what is left of the holds' approaches lies along its own column of
    the stand's Jacobian, read from the session (:func:`attribute_actuators`: ``held`` (N, M, 3)
    where the markers were held, ``tails`` row -> (M, 3) the markers at the end of the hold less
    where they were heading, or any vector along it: what they moved late in the hold, reversed);
    else when the holds after it moved (by more than 5% of its travel in the
    session) never settle significantly more often than the others (one-sided Fisher exact test,
    Bonferroni over the actuators at 0.01), and its excess is at least 0.7 of the largest; when
    none is (every hold unsettled: no contrast), when the distance left at the end of the holds
    grows with its step (a regression on every actuator's step, t > 4, at least half the largest).
    """
    if not rows:
        return {}
    un = np.zeros(len(U), bool)
    un[rows] = True
    use = np.ones(len(U), bool)
    if other_drops:
        use[sorted(other_drops)] = False
    steps = np.abs(last_step(U))
    span = np.ptp(U, axis=0)
    moved = steps / np.where(span > 0, span, 1.0) > 0.05
    attributed: list[int] = []
    left_by: dict = {}
    if held is not None and tails:
        attributed, table = attribute_actuators(U, held, tails)
        left_by = {control_names[j]: _finite(table["moved_late_m"][j]) for j in range(len(control_names))}
    scored = []
    for j in range(len(control_names)):
        m = moved[:, j] & use
        o = ~moved[:, j] & use
        if m.sum() < 3 or o.sum() < 3:
            continue
        table = [[int((un & m).sum()), int((~un & m).sum())], [int((un & o).sum()), int((~un & o).sum())]]
        p = fisher_exact(table, alternative="greater")[1]
        excess = un[m].mean() - un[o].mean()
        if p < 0.01 / len(control_names) and excess > 0:
            scored.append((float(excess), j))
    scored.sort(reverse=True)
    named = attributed or ([j for e, j in scored if e >= 0.7 * scored[0][0]] if scored else [])
    rem_of = dict(slow_left) if slow_left else {i: float(np.nanmax(fits[i].remaining_m)) for i in rows if i in fits}
    if not named and len(rem_of) >= 2 * U.shape[1] + 4:
        # every hold unsettled, no contrast: the distance left at the end grows with the slow
        # actuator's step, whatever the others (correlated in most plans) do
        idx = sorted(rem_of)
        A = np.column_stack([np.ones(len(idx)), steps[idx] / np.where(span > 0, span, 1.0)])
        y = np.array([rem_of[i] for i in idx])
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        s2 = float(np.sum((y - A @ coef) ** 2)) / max(len(y) - A.shape[1], 1)
        se = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(A.T @ A))[1:], 1e-300))
        strong = [j for j in range(U.shape[1]) if coef[1 + j] > 0 and coef[1 + j] / se[j] > 4.0]
        if strong:
            top = max(coef[1 + j] for j in strong)
            named = [j for j in sorted(strong, key=lambda j: -coef[1 + j]) if coef[1 + j] >= 0.5 * top]
    actuators = [control_names[j] for j in named]
    # the end of the approach, where the slowest actuator is alone, when it was seen; else the fits
    tau_of = dict(slow_taus) if slow_taus else {i: fits[i].tau for i in rows if i in fits}
    which = [i for i in rows if i in tau_of and (not named or moved[i, named].any())] or [i for i in rows if i in tau_of]
    taus = np.array([tau_of[i] for i in which])
    rem = np.array([fits[i].remaining_m for i in rows if i in fits])
    markers = []
    if rem.size:
        med = np.nanmedian(rem, axis=0)
        markers = [marker_names[m] for m in np.argsort(-med) if med[m] >= 0.5 * np.nanmax(med)]
    tau_med = float(np.median(taus)) if taus.size else float("nan")
    tau_lo, tau_hi = (float(np.percentile(taus, 25)), float(np.percentile(taus, 75))) if taus.size else (np.nan, np.nan)
    who = (f"actuator{'s' if len(actuators) > 1 else ''} {', '.join(actuators)}" if actuators
           else "the stand (no one actuator stands out)")
    tc = (f"approaching rest with a time constant of {tau_med:.3g} s (quartiles {tau_lo:.3g}-{tau_hi:.3g} s)"
          if taus.size else "its approach not fitted")
    sentence = (f"{len(rows)} of {n_commands} holds never settled: {who} still moving at the next command "
                f"(markers {', '.join(markers) or 'all'}), {tc} against holds of {float(np.median(hold_s)):.3g} s")
    return {"rows": list(rows), "n": len(rows), "n_commands": n_commands, "actuators": actuators, "markers": markers,
            "time_constant_s": tau_med, "time_constant_quartiles_s": [tau_lo, tau_hi],
            "hold_s": float(np.median(hold_s)), "moved_late_along_actuator_m": left_by,
            "remaining_m": float(np.nanmedian(np.nanmax(rem, axis=1))) if rem.size else float("nan"),
            "sentence": sentence}


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
    return stat < chi2.ppf(1 - false_alarm, 3 * int(seen.sum()))


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
    decay (a later bin off zero by chance must not push every window late). When no window of at least ``min_samples`` is that clean,
    the one whose bias is the smallest share of its noise; None when the hold has no arrival
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


def settle(session: Session, options: SettleOptions | None = None) -> tuple[PoseSet, SettleReport]:
    """Settled poses of a session with a raw marker stream (markers.csv or C3D).

    Returns the PoseSet (kept poses only; ``dropped`` lists (row, reason) of the others, rows
    0-based in commands.csv order, each reason ``category: detail`` with a category of
    DROP_CATEGORIES) and a SettleReport. ``extras``: 'row' (N,) command row,
    'direction' (N, n_u) sign of the last change of each control, 'last_step' (N, n_u) the command
    step that led to the row (u_i - u_(i-1), internal units), 'elapsed' (N,) s since the first
    command, 'settle_time' (N,) s from the command to the start of the averaging window,
    'window_start'/'window_end' (N,) s, 'marker_std' (N, M) m spread of each marker over its
    window, 'approach_tau_s' (N,) the fitted approach's time constant (NaN: no approach seen),
    'remaining_m' (N,) m the distance the approach still had to go at the end of the hold (largest
    over the markers), 'extrapolated' (N,) 1.0 where the pose is the fitted rest position of a hold
    that never settled, 'held_markers' (N, M, 3) m where the stream was at the end of each hold
    (the window mean before any tail correction; the last ``min_still_s`` of a hold that never
    settled): what a search that took the stream as it came would have averaged. ``settling``:
    sigma_m, slow_noise_inflation, n_commands, n_kept, n_extrapolated and ``unsettled`` (the holds
    that never settled: rows, actuators, markers, time_constant_s, sentence).
    Raises BadSession when no command settles, ComputationFailed when more than
    ``max_unsettled_fraction`` of the holds never settle and their approach cannot be extrapolated
    (or extrapolation is off): the message names the actuators and markers still moving.
    """
    opt = options or SettleOptions()
    if opt.extrapolate not in ("auto", "always", "never"):
        raise ValueError(f"extrapolate must be 'auto', 'always' or 'never', not {opt.extrapolate!r}")
    if session.markers is None:
        raise BadSession(f"{session.folder}: the session has no motion-capture stream (markers.csv or a C3D file)")
    if session.commands is None:
        raise BadSession(f"{session.folder / 'commands.csv'}: file not found; settling needs the command log")
    t, X = session.marker_t, session.markers
    dt = np.median(np.diff(t)) if len(t) > 1 else np.nan
    if not np.isfinite(dt) or dt <= 0:
        raise BadSession(f"{session.markers_source}: fewer than two samples; cannot find settled windows")
    rate = 1.0 / dt
    sigma = opt.sigma_m if opt.sigma_m is not None else estimate_noise(X)
    n = max(2, int(round(opt.window_s * rate)))
    min_samples = max(3, int(np.ceil(opt.min_still_s * rate)))
    tc, U = session.command_t, session.commands
    # the noise at the scales the tests look at: the still test's halves (fast) and a few tenths
    # of a second (slow: trends, decays, window means); white noise gives sigma at both
    quiet = _quiet_stretches(t, X, tc, n, sigma, opt.gap_samples)
    sig_fast = sigma * np.sqrt(noise_inflation(quiet, sigma, n))
    slow_inflation = noise_inflation(quiet, sigma, max(n, int(round(SLOW_SCALE_S * rate))))
    sig_slow = sigma * np.sqrt(slow_inflation)
    N, M = U.shape[0], X.shape[1]
    direction = direction_of_last_motion(U)
    results: dict[int, dict] = {}  # row -> mean, cnt, std, start, end, tau, remaining, extrapolated
    dropped: dict[int, str] = {}
    fits: dict[int, Approach] = {}
    unsettled: list[int] = []
    segments: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # the stretches of the holds that never settled
    windows: dict[int, tuple] = {}  # settled holds: (t, stretch, approach start, window start, end)
    slow_taus: dict[int, float] = {}  # holds that never settled: the time constant of the end of their approach
    slow_left: dict[int, float] = {}  # ... and the distance it still had to go (m)
    slow_tail: dict[int, np.ndarray] = {}  # ... and what the markers moved late in it, reversed (m)
    held_at = np.full((N, M, 3), np.nan)  # where the markers were held at each command (attribution's Jacobian)
    hold_s = np.empty(N)
    for i in range(N):
        t_end = tc[i + 1] if i + 1 < N else t[-1] + dt / 2
        hold_s[i] = t_end - tc[i]
        a, b = np.searchsorted(t, tc[i], side="left"), np.searchsorted(t, t_end, side="left")
        if b - a < min_samples:
            if b == a:
                dropped[i] = f"no motion-capture samples: none between t={tc[i]:.3f} s and t={t_end:.3f} s"
            else:
                dropped[i] = f"too few samples: only {b - a} between t={tc[i]:.3f} s and t={t_end:.3f} s"
            continue
        seg, ts = X[a:b], t[a:b]
        slack = max(opt.gap_samples + 1, int(round(opt.end_slack_s * rate)))
        run = _last_still_run(still_mask(seg, n, sig_fast, opt.false_alarm), opt.gap_samples, min_samples, slack)
        length = 0 if run is None else run[1] - run[0]
        if run is not None and length >= min_samples and run[1] < (b - a) - slack:
            dropped[i] = (f"moved again: {(b - a - run[1]) * dt:.2f} s before the next command "
                          f"(after {length * dt:.2f} s still); the stand did not hold the command")
            continue
        end = (b - a) if run is None else run[1]
        if run is not None and length - n >= min_samples:
            # the next move starts smoothly (from rest, under an acceleration limit) and the still
            # test sees it up to one half-window late; a clock offset between the files moves it
            # into the hold: its first samples, drawn towards the next command, are left out
            end -= n
            run = (run[0], end)
            length = end - run[0]
        k0 = approach_start(seg[:end], n, sig_fast)
        fit = None
        if k0 is not None and end - k0 >= 8:
            fit = _fit_tail(ts, seg, k0, end, sig_slow)
        if fit is not None:
            fits[i] = fit
        why = None
        start = None
        correction = np.zeros((M, 3))
        if run is None or length < min_samples:
            why = (f"never settled: still for {length * dt:.2f} s before the next command, "
                   f"{opt.min_still_s:.2f} s needed")
        else:
            start = run[0]
            bound = fit
            if fit is not None and fit.significant:
                # how much of the fitted tail the still stretch bears out: the window is chosen by
                # its upper bound (a fit whose decay is off still marks where the approach ends;
                # dropping it would start the window in the tail), a correction by its estimate
                kappa, k_hi = tail_scale(fit, ts[run[0]:end], seg[run[0]:end], sig_slow)
                bound = fit.scaled(k_hi)
                fit = fit.scaled(kappa)
            if fit is not None and bound is not None:
                window = tail_free_window(bound, ts, run[0], end, sig_slow, opt.tail_fraction, min_samples,
                                          estimate=fit)
                if bound is not fit and (window is None or end - window[0] < opt.bound_keeps * (end - run[0])):
                    # the bound leaves no clean window, or a small part of the still stretch (a
                    # decay the stretch hardly supports, a short hold): the estimate decides
                    window = (tail_free_window(fit, ts, run[0], end, sig_slow, opt.tail_fraction, min_samples)
                              if fit.significant else (run[0], np.zeros((M, 3))))
                start = None if window is None else window[0]
                if window is not None:
                    correction = window[1]
                if start is None:
                    why = (f"never settled: the approach (time constant {fit.tau:.3g} s) still had "
                           f"{1e3 * float(np.nanmax(fit.remaining_m)):.3g} mm to go at the next command")
            if start is not None:
                p, v = trend_test(ts[start:end], seg[start:end], sig_slow)
                while p < opt.trend_false_alarm and end - start >= 2 * min_samples:
                    # the early part goes (what is left of an approach), a quarter at a time
                    start += max(1, (end - start) // 4)
                    p, v = trend_test(ts[start:end], seg[start:end], sig_slow)
                    correction = np.zeros((M, 3))
                if p < opt.trend_false_alarm:
                    why = (f"never settled: still moving at {1e3 * v:.3g} mm/s across its "
                           f"{(end - start) * dt:.2f} s window (trend p = {p:.2g})")
        if why is not None:
            dropped[i] = why
            unsettled.append(i)
            segments[i] = (ts[:end], seg[:end])
            if k0 is not None:
                # the slowest actuator's time constant shows once the others have arrived: the
                # second half of what is left of the hold
                k = k0 + (end - k0) // 2
                late = fit_approach(ts[k:end], seg[k:end], sig_slow, t_end=ts[end - 1]) if end - k >= 16 else None
                if late is not None and late.significant:
                    slow_taus[i] = late.tau
                    slow_left[i] = float(np.nanmax(late.remaining_m))
            # where the markers still go at the end of the hold (m): what they moved over its last
            # third against the third before, which no extrapolation enters (its sign: behind)
            k = (k0 if k0 is not None else 0) + (end - (k0 if k0 is not None else 0)) // 3
            third = (end - k) // 2
            if third >= 4:
                slow_tail[i] = _nan_mean(seg[k:k + third]) - _nan_mean(seg[end - third:end])
            held_at[i] = _nan_mean(seg[max(end - min_samples, 0):end])
            continue
        if opt.max_window_s is not None and end - start > max(min_samples, int(round(opt.max_window_s * rate))):
            start = end - max(min_samples, int(round(opt.max_window_s * rate)))
            correction = np.zeros((M, 3))
        r = _window_result(ts, seg, start, end, correction, fit)
        if r is None:
            dropped[i] = "every marker occluded: no sample in the settled window"
            continue
        results[i] = r
        windows[i] = (ts, seg, k0, start, end)
    # the tail the holds share: a start each hold could not justify alone (its tail below its
    # own noise) still biases every pose the same way, along its step
    profile = shared_tail(windows, results, sig_slow, n)
    if profile is not None:
        for i, (ts, seg, _k0, start, end) in windows.items():
            later = profile_start(profile, results[i]["arrival"], ts, start, end, sig_slow, opt.tail_fraction,
                                  min_samples)
            if later is not None and later > start:
                r = _window_result(ts, seg, later, end, np.zeros((M, 3)), fits.get(i))
                if r is not None:
                    r["step"] = results[i]["step"]
                    results[i] = r
    names = (list(session.spec.control_names) if session.spec is not None
             else [f"u{j + 1}" for j in range(U.shape[1])])
    for i, r in results.items():
        held_at[i] = r["mean"]
    summary = _unsettled_summary(unsettled, fits, U, names, list(session.marker_names), hold_s, N,
                                 set(dropped) - set(unsettled), slow_taus, slow_left, held_at, slow_tail)
    many = len(unsettled) > opt.max_unsettled_fraction * N and len(unsettled) >= 2  # one of a few is no pattern
    n_extrapolated = 0
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        moved = np.linalg.norm(np.diff(held_at, axis=0), axis=2)  # (N - 1, M)
        step_m = np.concatenate([[0.0], np.where(np.isfinite(moved).any(axis=1),
                                                 np.nanmax(np.where(np.isfinite(moved), moved, -np.inf), axis=1), 0.0)])
    if unsettled and (opt.extrapolate == "always" or (opt.extrapolate == "auto" and many)):
        good = [i for i in unsettled if i in fits and fits[i].good
                and float(np.nanmax(fits[i].remaining_m)) <= max(opt.max_extrapolation_m,
                                                                 opt.max_extrapolation_share * step_m[i])
                and extrapolation_checked(*segments[i], fits[i], segments[i][1].shape[0], sig_slow)]
        if opt.extrapolate == "auto" and len(good) < 0.8 * len(unsettled):
            if results:
                raise ComputationFailed(
                    f"{session.markers_source}: {summary['sentence']}; the approach of only {len(good)} of them "
                    "fits the stream well enough to extrapolate to rest: record longer holds (or a slower plan)")
            good = []  # nothing settled and little extrapolates: the recording never settles (below)
        for i in good:
            f = fits[i]
            var = np.nanmax(f.x_inf_std, axis=1) ** 2
            # as many samples as would average to that variance (window means vary as sig_slow^2 / n)
            cnt = np.where(np.isfinite(var) & (var > 0), sig_slow**2 / np.where(var > 0, var, 1.0), 0.0)
            tail_t, tail_x = segments[i]
            last = tail_x[-min_samples:]
            with np.errstate(invalid="ignore"), warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                held = np.nanmean(np.where(np.isfinite(last).all(axis=2)[..., None], last, np.nan), axis=0)
            results[i] = dict(mean=f.x_inf, held=held, cnt=cnt, std=np.full(M, np.nan), start=np.nan, end=np.nan,
                              tau=f.tau, remaining=float(np.nanmax(f.remaining_m)), extrapolated=1.0)
            dropped.pop(i)
            n_extrapolated += 1
    elif many and len(unsettled) > 0.5 * N and results:
        raise ComputationFailed(
            f"{session.markers_source}: {summary['sentence']}; calibrating from the {N - len(dropped)} that did "
            "would fit a remnant: record longer holds, or settle with extrapolation to rest")
    kept = sorted(results)
    dropped_list = sorted(dropped.items())
    if not kept:
        reason = dropped_list[0][1] if dropped_list else "no commands"
        raise BadSession(
            f"{session.markers_source}: the recording never settles: none of {N} commands gave a still window "
            f"(first: row {dropped_list[0][0] + 1 if dropped_list else 0}: {reason})"
            + (f"; {summary['sentence']}" if summary else "")
        )
    kept_a = np.array(kept)
    col = lambda key: np.array([results[i][key] for i in kept])  # noqa: E731
    base = None
    if session.base_markers is not None and session.base_markers.shape[1]:
        with np.errstate(invalid="ignore"):
            base = np.nanmean(session.base_markers, axis=0)
    poses = PoseSet(
        platform=session.platform, controls=U[kept_a], markers=col("mean"),
        marker_names=list(session.marker_names),
        description=None if session.description is None else str(session.description),
        base_markers=base, t=tc[kept_a], n_samples=col("cnt"), length_unit=session.length_unit,
        moving_link=session.moving_link, source=str(session.folder), dropped=dropped_list,
        extras={
            "row": kept_a, "direction": direction[kept_a], "last_step": last_step(U)[kept_a],
            "elapsed": tc[kept_a] - tc[0], "settle_time": col("start") - tc[kept_a],
            "window_start": col("start"), "window_end": col("end"), "marker_std": col("std"),
            "approach_tau_s": col("tau"), "remaining_m": col("remaining"), "extrapolated": col("extrapolated"),
            "held_markers": col("held"),
        },
        settling={"sigma_m": float(sigma), "slow_noise_inflation": float(slow_inflation), "n_commands": N,
                  "n_kept": len(kept), "n_extrapolated": n_extrapolated,
                  "unsettled": summary},
    )
    return poses, SettleReport(float(sigma), N, len(kept), dropped_list, float(rate), n_extrapolated, summary)


def poses_from_table(session: Session) -> PoseSet:
    """The PoseSet of a session whose folder holds poses.csv (already reduced)."""
    p = session.poses
    U = p["controls"]
    t = p["t"] if p["t"] is not None else np.full(len(U), np.nan)
    base = None
    if session.base_markers is not None:
        with np.errstate(invalid="ignore"):
            base = np.nanmean(session.base_markers, axis=0)
    return PoseSet(
        platform=session.platform, controls=U, markers=p["markers"], marker_names=list(session.marker_names),
        description=None if session.description is None else str(session.description), base_markers=base,
        t=t, n_samples=p["n_samples"], length_unit=session.length_unit, moving_link=session.moving_link,
        source=str(session.folder),
        extras={"row": np.arange(len(U)), "direction": direction_of_last_motion(U), "last_step": last_step(U),
                "elapsed": t - t[0] if np.all(np.isfinite(t)) else np.arange(len(U), dtype=float)},
    )


def load_poses(folder: str | Path, platform: str | None = None, description: str | Path | None = None,
               options: SettleOptions | None = None, spec=None, session: Session | None = None) -> PoseSet:
    """Settled poses of a session folder: from markers.csv or a C3D file (through :func:`settle`)
    or from poses.csv as they are. BadSession if the session has no markers. ``session``: the
    folder already read by :func:`load_session` (its streams are not read again)."""
    if session is None:
        session = load_session(folder, platform=platform, description=description, spec=spec)
    if session.spec is None:
        raise BadSession(f"{Path(folder) / 'session.yaml'}: declares no platform (an IMU-only recording); calibration needs a stand")
    if session.markers is not None:  # rigid bodies: averaged over the windows found (calibrate.bodies)
        return with_settled_bodies(session, settle(stream_for_settling(session), options)[0])
    if session.poses is not None:
        return with_settled_bodies(session, poses_from_table(session))
    raise BadSession(
        f"{folder}: the session has no markers: expected markers.csv, poses.csv or session.yaml's markers_file"
    )
