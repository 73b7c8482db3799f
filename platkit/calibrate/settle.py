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
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from platkit.errors import BadSession
from platkit.io.session import Session, load_session
from platkit.poses import PoseSet

#: sigma below this (1 micrometre) is not believed: noise-free or quantised streams
SIGMA_FLOOR_M = 1e-6


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


@dataclass
class SettleReport:
    """What the settling search found, for the person reading the calibration report."""

    sigma_m: float
    n_commands: int
    n_kept: int
    dropped: list[tuple[int, str]]
    rate_hz: float


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


def still_mask(markers: np.ndarray, n: int, sigma: float, false_alarm: float) -> np.ndarray:
    """(K,) True where the markers (K, M, 3), one command's stretch, are still at sample k.

    Windows are clipped to the stretch; the first sample (no past) is never still.
    """
    K = markers.shape[0]
    S, C = _window_sums(markers)
    k = np.arange(K)
    a = np.maximum(k - n, 0)
    b = np.minimum(k + n, K)
    nb = C[k] - C[a]  # (K, M) samples before
    na = C[b] - C[k]
    mb = (S[k] - S[a]) / np.maximum(nb, 1)[..., None]
    ma = (S[b] - S[k]) / np.maximum(na, 1)[..., None]
    vis = (nb > 0) & (na > 0)
    scale2 = sigma**2 * (1.0 / np.maximum(nb, 1) + 1.0 / np.maximum(na, 1))
    z2 = np.where(vis, np.sum((ma - mb) ** 2, axis=2) / scale2, 0.0)
    m = vis.sum(axis=1)
    stat = z2.sum(axis=1) / np.maximum(m, 1)
    limit = chi2.ppf(1 - false_alarm, 3 * np.maximum(m, 1)) / np.maximum(m, 1)
    return (m > 0) & (stat < limit)


def _last_still_run(still: np.ndarray, gap: int) -> tuple[int, int] | None:
    """[start, end) of the last still stretch, bridging up to ``gap`` moving samples."""
    idx = np.nonzero(still)[0]
    if idx.size == 0:
        return None
    end = idx[-1] + 1
    start = idx[-1]
    for j in range(idx.size - 2, -1, -1):
        if idx[j + 1] - idx[j] - 1 > gap:
            break
        start = idx[j]
    return int(start), int(end)


def settle(session: Session, options: SettleOptions | None = None) -> tuple[PoseSet, SettleReport]:
    """Settled poses of a session with a raw marker stream (markers.csv or C3D).

    Returns the PoseSet (kept poses only; ``dropped`` lists (row, reason) of the others, rows
    0-based in commands.csv order) and a SettleReport. ``extras``: 'row' (N,) command row,
    'direction' (N, n_u) sign of the last change of each control, 'last_step' (N, n_u) the command
    step that led to the row (u_i - u_(i-1), internal units), 'elapsed' (N,) s since the first
    command, 'settle_time' (N,) s from the
    command to the start of the averaging window, 'window_start'/'window_end' (N,) s,
    'marker_std' (N, M) m spread of each marker over its window.
    Raises BadSession when no command settles.
    """
    opt = options or SettleOptions()
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
    N, M = U.shape[0], X.shape[1]
    direction = direction_of_last_motion(U)
    kept, dropped = [], []
    means, counts, stds, starts, ends = [], [], [], [], []
    for i in range(N):
        t_end = tc[i + 1] if i + 1 < N else t[-1] + dt / 2
        a, b = np.searchsorted(t, tc[i], side="left"), np.searchsorted(t, t_end, side="left")
        if b - a < min_samples:
            why = "no motion-capture samples" if b == a else f"only {b - a} motion-capture samples"
            dropped.append((i, f"{why} between t={tc[i]:.3f} s and t={t_end:.3f} s"))
            continue
        seg = X[a:b]
        run = _last_still_run(still_mask(seg, n, sigma, opt.false_alarm), opt.gap_samples)
        length = 0 if run is None else run[1] - run[0]
        slack = max(opt.gap_samples + 1, int(round(opt.end_slack_s * rate)))
        if run is not None and length >= min_samples and run[1] < (b - a) - slack:
            dropped.append((i, f"moved again {(b - a - run[1]) * dt:.2f} s before the next command "
                               f"(after {length * dt:.2f} s still); the stand did not hold the command"))
            continue
        if run is None or length < min_samples:
            dropped.append((i, f"never settled: still for {length * dt:.2f} s before the next command, "
                               f"{opt.min_still_s:.2f} s needed"))
            continue
        w = seg[run[0]:run[1]]
        ok = np.isfinite(w).all(axis=2)
        cnt = ok.sum(axis=0)
        if not np.any(cnt):
            dropped.append((i, "every marker occluded in the settled window"))
            continue
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a marker occluded all window long
            mean = np.nanmean(np.where(ok[..., None], w, np.nan), axis=0)
            std = np.sqrt(np.nanmean(np.sum((w - mean) ** 2, axis=2), axis=0) / 3)
        mean[cnt == 0] = np.nan
        kept.append(i)
        means.append(mean)
        counts.append(cnt)
        stds.append(std)
        starts.append(t[a + run[0]])
        ends.append(t[a + run[1] - 1])
    if not kept:
        reason = dropped[0][1] if dropped else "no commands"
        raise BadSession(
            f"{session.markers_source}: the recording never settles: none of {N} commands gave a still window "
            f"(first: row {dropped[0][0] + 1 if dropped else 0}: {reason})"
        )
    kept_a = np.array(kept)
    base = None
    if session.base_markers is not None and session.base_markers.shape[1]:
        with np.errstate(invalid="ignore"):
            base = np.nanmean(session.base_markers, axis=0)
    poses = PoseSet(
        platform=session.platform, controls=U[kept_a], markers=np.array(means),
        marker_names=list(session.marker_names),
        description=None if session.description is None else str(session.description),
        base_markers=base, t=tc[kept_a], n_samples=np.array(counts, float), length_unit=session.length_unit,
        moving_link=session.moving_link, source=str(session.folder), dropped=dropped,
        extras={
            "row": kept_a, "direction": direction[kept_a], "last_step": last_step(U)[kept_a],
            "elapsed": tc[kept_a] - tc[0], "settle_time": np.array(starts) - tc[kept_a],
            "window_start": np.array(starts), "window_end": np.array(ends), "marker_std": np.array(stds),
        },
    )
    return poses, SettleReport(float(sigma), N, len(kept), dropped, float(rate))


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
               options: SettleOptions | None = None, spec=None) -> PoseSet:
    """Settled poses of a session folder: from markers.csv or a C3D file (through :func:`settle`)
    or from poses.csv as they are. BadSession if the session has no markers."""
    session = load_session(folder, platform=platform, description=description, spec=spec)
    if session.spec is None:
        raise BadSession(f"{Path(folder) / 'session.yaml'}: declares no platform (an IMU-only recording); calibration needs a stand")
    if session.markers is not None:
        return settle(session, options)[0]
    if session.poses is not None:
        return poses_from_table(session)
    raise BadSession(
        f"{folder}: the session has no markers: expected markers.csv, poses.csv or session.yaml's markers_file"
    )
