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
a correction by its estimate; where that bound leaves under ``bound_keeps`` of the still stretch
the estimate decides, unless the session's still stretches, pooled, bear out their fitted tails
(:func:`tail_regression`, ``tail_evidence_z``): then the bound's cut stands down to
``bound_keeps_evident`` of it. Each hold's tail is mostly below its own noise, but every hold
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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from platkit.bodies import stream_for_settling, with_settled_bodies
from platkit.errors import BadSession, ComputationFailed
from platkit.io.session import Session, load_session
from platkit.play import play_memory
from platkit.poses import PoseSet
from platkit.settle._approach import Approach, _window_result, tail_free_window, tail_regression, tail_scale
from platkit.settle._fits import extrapolation_checked, fit_approaches, fit_tails
from platkit.settle._native import compiled_fits_reason
from platkit.settle._report import (
    SettleOptions,
    SettleReport,
)
from platkit.settle._still import (
    _last_still_run,
    _quiet_stretches,
    _window_sums,
    approach_start,
    direction_of_last_motion,
    estimate_noise,
    last_step,
    noise_inflation,
    still_mask,
    trend_test,
)
from platkit.settle._tail import profile_start, shared_tail
from platkit.settle._unsettled import _unsettled_summary, _who, refusal


class _Refused(Exception):
    """A refusal of the holds that carries what the search found (``settling``), for the caller
    that reads the stream instead (see :func:`refusal`): ``reason`` (one clause: why the holds were
    refused, with the counts), ``unsettled`` (the summary of the holds that never settled,
    ``_unsettled_summary``; {} when none), ``n_commands``, ``n_settled`` (holds that gave a still
    window) and, where too few extrapolate, ``n_extrapolable`` and ``extrapolable_share`` (the
    share of the unsettled holds needed)."""

    def __init__(self, message: str, settling: dict | None = None):
        super().__init__(message)
        self.settling = dict(settling or {})


class HoldsNeverSettle(_Refused, ComputationFailed):
    """So many holds never settled that the poses left would be a remnant: the stream itself is
    the data (``platkit calibrate`` then fits the motion model, platkit.calibrate.motion)."""


class NeverSettles(_Refused, BadSession):
    """No command gave a still window: a session without holds (``platkit calibrate`` then fits
    the motion model, platkit.calibrate.motion); ``settling['n_settled']`` 0."""


#: where more than ``max_unsettled_fraction`` of the holds never settle, at least this share of
#: them must extrapolate to rest (``extrapolate='auto'``); else the session is refused
MIN_EXTRAPOLABLE_SHARE = 0.8


#: the time scale (s) of the slow noise that trend, decay and window-mean tests are judged against
SLOW_SCALE_S = 0.4


def _nan_mean(x: np.ndarray) -> np.ndarray:
    """(M, 3) the mean of a stretch (K, M, 3) over its samples where the marker is seen (NaN: never)."""
    ok = np.isfinite(x).all(axis=2)
    cnt = ok.sum(axis=0)
    return np.where((cnt > 0)[:, None], np.sum(np.where(ok[..., None], x, 0.0), axis=0) / np.maximum(cnt, 1)[:, None],
                    np.nan)


@dataclass
class _Stream:
    """What every stage of the search reads: the stream, the commands, the noise at the scales
    the tests look at (sigma white, sig_fast the still test's halves, sig_slow a few tenths of a
    second: trends, decays, window means) and the sample counts the options come to."""

    opt: SettleOptions
    t: np.ndarray
    X: np.ndarray
    tc: np.ndarray
    U: np.ndarray
    dt: float
    rate: float
    sigma: float
    sig_fast: float
    sig_slow: float
    slow_inflation: float
    n: int
    min_samples: int

    @property
    def shape(self) -> tuple[int, int]:
        """(commands N, markers M)."""
        return self.U.shape[0], self.X.shape[1]


@dataclass
class _Hold:
    """One command's hold: row i, its stretch (ts, seg), its last still run (None: none), the end
    of what is averaged or fitted, and the start of the approach to rest (None: not found)."""

    i: int
    ts: np.ndarray
    seg: np.ndarray
    run: tuple[int, int] | None
    end: int
    k0: int | None

    @property
    def length(self) -> int:
        return 0 if self.run is None else self.run[1] - self.run[0]


@dataclass
class _Search:
    """The search's findings, row by row: results (row -> mean, held, cnt, std, start, end, tau,
    remaining, extrapolated), dropped (row -> reason), the fitted approaches, the holds that
    never settled with their stretches, the settled holds' windows (t, stretch, approach start,
    window start, end), the windows deferred to the session's evidence on its tails (row -> cut,
    correction, the tail's estimate) and that evidence (sum g y, sum g g); for the holds that never
    settled the time constant of the end of their approach, the distance it still had to go (m)
    and what the markers moved late in it (reversed, m); where the markers were held at each
    command (the attribution's Jacobian) and how long each hold lasted (s)."""

    N: int
    M: int
    results: dict[int, dict] = field(default_factory=dict)
    dropped: dict[int, str] = field(default_factory=dict)
    fits: dict[int, Approach] = field(default_factory=dict)
    unsettled: list[int] = field(default_factory=list)
    segments: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    windows: dict[int, tuple] = field(default_factory=dict)
    deferred: dict[int, tuple] = field(default_factory=dict)
    evidence: list[float] = field(default_factory=lambda: [0.0, 0.0])
    slow_taus: dict[int, float] = field(default_factory=dict)
    slow_left: dict[int, float] = field(default_factory=dict)
    slow_tail: dict[int, np.ndarray] = field(default_factory=dict)
    held_at: np.ndarray = field(init=False)
    hold_s: np.ndarray = field(init=False)

    def __post_init__(self):
        self.held_at = np.full((self.N, self.M, 3), np.nan)
        self.hold_s = np.empty(self.N)


def _stream(session: Session, opt: SettleOptions) -> _Stream:
    """The stream and the noise levels of a session (:class:`_Stream`); BadSession without a
    stream, a command log or two samples."""
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
    tc = session.command_t
    quiet = _quiet_stretches(t, X, tc, n, sigma, opt.gap_samples)
    slow_inflation = noise_inflation(quiet, sigma, max(n, int(round(SLOW_SCALE_S * rate))))
    return _Stream(opt=opt, t=t, X=X, tc=tc, U=session.commands, dt=dt, rate=rate, sigma=sigma,
                   sig_fast=sigma * np.sqrt(noise_inflation(quiet, sigma, n)),
                   sig_slow=sigma * np.sqrt(slow_inflation), slow_inflation=slow_inflation, n=n,
                   min_samples=max(3, int(np.ceil(opt.min_still_s * rate))))


def _holds(st: _Stream, found: _Search) -> list[_Hold]:
    """Every command's hold with enough samples that did not move again before the next
    command: its last still run, with the first samples of a next move left out, and the start
    of its approach; the others dropped with their reason."""
    opt, t, dt, n, min_samples = st.opt, st.t, st.dt, st.n, st.min_samples
    N = st.shape[0]
    compiled = compiled_fits_reason() == ""
    holds = []
    for i in range(N):
        t_end = st.tc[i + 1] if i + 1 < N else t[-1] + dt / 2
        found.hold_s[i] = t_end - st.tc[i]
        a, b = np.searchsorted(t, st.tc[i], side="left"), np.searchsorted(t, t_end, side="left")
        if b - a < min_samples:
            if b == a:
                found.dropped[i] = f"no motion-capture samples: none between t={st.tc[i]:.3f} s and t={t_end:.3f} s"
            else:
                found.dropped[i] = f"too few samples: only {b - a} between t={st.tc[i]:.3f} s and t={t_end:.3f} s"
            continue
        seg, ts = st.X[a:b], t[a:b]
        slack = max(opt.gap_samples + 1, int(round(opt.end_slack_s * st.rate)))
        # the still test's and the approach's window means (the compiled kernel takes its own)
        sums = None if compiled else _window_sums(seg)
        run = _last_still_run(still_mask(seg, n, st.sig_fast, opt.false_alarm, sums), opt.gap_samples, min_samples,
                              slack)
        length = 0 if run is None else run[1] - run[0]
        if run is not None and length >= min_samples and run[1] < (b - a) - slack:
            found.dropped[i] = (f"moved again: {(b - a - run[1]) * dt:.2f} s before the next command "
                                f"(after {length * dt:.2f} s still); the stand did not hold the command")
            continue
        end = (b - a) if run is None else run[1]
        if run is not None and length - n >= min_samples:
            # the next move starts smoothly (from rest, under an acceleration limit) and the still
            # test sees it up to one half-window late; a clock offset between the files moves it
            # into the hold: its first samples, drawn towards the next command, are left out
            end -= n
            run = (run[0], end)
        holds.append(_Hold(i, ts, seg, run, end, approach_start(seg[:end], n, st.sig_fast, sums)))
    return holds


def _fitted_tails(st: _Stream, holds: list[_Hold], found: _Search) -> list[Approach | None]:
    """The approach of every hold whose start was found (:func:`fit_tails`, all at once)."""
    fit_at = [h for h in holds if h.k0 is not None and h.end - h.k0 >= 8]
    fits = dict(zip((h.i for h in fit_at), fit_tails([(h.ts, h.seg, h.k0, h.end, st.sig_slow) for h in fit_at])))
    out = [fits.get(h.i) for h in holds]
    for h, f in zip(holds, out):
        if f is not None:
            found.fits[h.i] = f
    return out


def _window(st: _Stream, h: _Hold, fit: Approach | None,
            found: _Search) -> tuple[int | None, np.ndarray, Approach | None, str | None]:
    """(window start, correction (M, 3), the tail's estimate, why the hold never settled or None)
    of one hold. The still run's start, moved past the fitted tail: the window chosen by the upper
    bound of the share of the tail the still stretch bears out (:func:`tail_scale`), a correction
    by its estimate, the estimate deciding where the bound leaves under ``bound_keeps`` of the
    stretch (deferred to the session's evidence down to ``bound_keeps_evident``); then the early
    part dropped, a quarter at a time, while the window trends."""
    opt, ts, seg, run, end, M = st.opt, h.ts, h.seg, h.run, h.end, st.shape[1]
    correction = np.zeros((M, 3))
    if run is None or h.length < st.min_samples:
        return None, correction, fit, (f"never settled: still for {h.length * st.dt:.2f} s before the next command, "
                                       f"{opt.min_still_s:.2f} s needed")
    start = run[0]
    bound = fit
    if fit is not None and fit.significant:
        # how much of the fitted tail the still stretch bears out: the window is chosen by its upper
        # bound (a fit whose decay is off still marks where the approach ends; dropping it would
        # start the window in the tail), a correction by its estimate
        num, den = tail_regression(fit.tail(ts[run[0]:end]), seg[run[0]:end])
        kappa, k_hi = tail_scale(fit, ts[run[0]:end], seg[run[0]:end], st.sig_slow, sums=(num, den))
        found.evidence[0] += num
        found.evidence[1] += den
        bound = fit.scaled(k_hi)
        fit = fit.scaled(kappa)
    if fit is not None and bound is not None:
        window = tail_free_window(bound, ts, run[0], end, st.sig_slow, opt.tail_fraction, st.min_samples, estimate=fit)
        if bound is not fit and (window is None or end - window[0] < opt.bound_keeps * (end - run[0])):
            if window is not None and end - window[0] >= opt.bound_keeps_evident * (end - run[0]):
                found.deferred[h.i] = (window[0], window[1], fit)
            # the bound leaves no clean window, or a small part of the still stretch (a decay the
            # stretch hardly supports, a short hold): the estimate decides
            window = (tail_free_window(fit, ts, run[0], end, st.sig_slow, opt.tail_fraction, st.min_samples)
                      if fit.significant else (run[0], np.zeros((M, 3))))
        if window is None:
            return None, correction, fit, (f"never settled: the approach (time constant {fit.tau:.3g} s) still had "
                                           f"{1e3 * float(np.nanmax(fit.remaining_m)):.3g} mm to go at the next command")
        start, correction = window
    p, v = trend_test(ts[start:end], seg[start:end], st.sig_slow)
    while p < opt.trend_false_alarm and end - start >= 2 * st.min_samples:
        # the early part goes (what is left of an approach), a quarter at a time
        start += max(1, (end - start) // 4)
        p, v = trend_test(ts[start:end], seg[start:end], st.sig_slow)
        correction = np.zeros((M, 3))
    if p < opt.trend_false_alarm:
        return None, correction, fit, (f"never settled: still moving at {1e3 * v:.3g} mm/s across its "
                                       f"{(end - start) * st.dt:.2f} s window (trend p = {p:.2g})")
    return start, correction, fit, None


def _never_settled(st: _Stream, h: _Hold, why: str, found: _Search) -> None:
    """A hold that never settled: dropped with its reason, its stretch kept for extrapolation,
    what its markers still moved late in it (its last third against the third before, which no
    extrapolation enters; the sign: behind) and where they were held (its last ``min_still_s``)."""
    i, ts, seg, end, k0 = h.i, h.ts, h.seg, h.end, h.k0
    found.dropped[i] = why
    found.unsettled.append(i)
    found.segments[i] = (ts[:end], seg[:end])
    k = (k0 if k0 is not None else 0) + (end - (k0 if k0 is not None else 0)) // 3
    third = (end - k) // 2
    if third >= 4:
        found.slow_tail[i] = _nan_mean(seg[k:k + third]) - _nan_mean(seg[end - third:end])
    found.held_at[i] = _nan_mean(seg[max(end - st.min_samples, 0):end])


def _late_fits(st: _Stream, holds: list[_Hold], found: _Search) -> None:
    """The time constant of the end of each unsettled hold's approach and the distance it still
    had to go: the slowest actuator's shows once the others have arrived, in the second half of
    what is left of the hold (fitted all at once)."""
    late = [(h, h.k0 + (h.end - h.k0) // 2) for h in holds if h.i in found.segments and h.k0 is not None]
    late = [(h, k) for h, k in late if h.end - k >= 16]
    fits = fit_approaches([(h.ts[k:h.end], h.seg[k:h.end], st.sig_slow, h.ts[h.end - 1]) for h, k in late])
    for (h, _k), f in zip(late, fits):
        if f is not None and f.significant:
            found.slow_taus[h.i] = f.tau
            found.slow_left[h.i] = float(np.nanmax(f.remaining_m))


def _search_holds(st: _Stream, found: _Search) -> None:
    """Every hold's window or why it never settled (:func:`_window`), its pose averaged over the
    window (the window at most ``max_window_s``, ending where the hold does)."""
    opt, rate, min_samples, M = st.opt, st.rate, st.min_samples, st.shape[1]
    holds = _holds(st, found)
    for h, fit in zip(holds, _fitted_tails(st, holds, found)):
        start, correction, fit, why = _window(st, h, fit, found)
        if why is not None:
            _never_settled(st, h, why, found)
            continue
        ts, seg, end = h.ts, h.seg, h.end
        if opt.max_window_s is not None and end - start > max(min_samples, int(round(opt.max_window_s * rate))):
            start = end - max(min_samples, int(round(opt.max_window_s * rate)))
            correction = np.zeros((M, 3))
        r = _window_result(ts, seg, start, end, correction, fit)
        if r is None:
            found.dropped[h.i] = "every marker occluded: no sample in the settled window"
            continue
        found.results[h.i] = r
        found.windows[h.i] = (ts, seg, h.k0, start, end)
    _late_fits(st, holds, found)
    found.dropped = dict(sorted(found.dropped.items()))
    found.unsettled.sort()


def _shared_windows(st: _Stream, found: _Search) -> None:
    """The windows the session moves: the deferred cuts where the still stretches, pooled, bear
    out their fitted tails (``tail_evidence_z``), then every window moved past the tail the holds
    share (:func:`shared_tail`: a start each hold could not justify alone still biases every pose
    the same way, along its step)."""
    opt, M, sig_slow = st.opt, st.shape[1], st.sig_slow
    ev = found.evidence
    z = ev[0] / (sig_slow * np.sqrt(ev[1])) if ev[1] > 0 else 0.0
    if z >= opt.tail_evidence_z:
        for i, (cut, corr, estimate) in found.deferred.items():
            if i in found.windows and cut > found.windows[i][3]:
                ts, seg, k0, _start, end = found.windows[i]
                r = _window_result(ts, seg, cut, end, corr, estimate)
                if r is not None:
                    found.results[i] = r
                    found.windows[i] = (ts, seg, k0, cut, end)
    profile = shared_tail(found.windows, found.results, sig_slow, st.n)
    if profile is not None:
        for i, (ts, seg, _k0, start, end) in found.windows.items():
            later = profile_start(profile, found.results[i]["arrival"], ts, start, end, sig_slow, opt.tail_fraction,
                                  st.min_samples)
            if later is not None and later > start:
                r = _window_result(ts, seg, later, end, np.zeros((M, 3)), found.fits.get(i))
                if r is not None:
                    r["step"] = found.results[i]["step"]
                    found.results[i] = r


def _extrapolate(session: Session, st: _Stream, found: _Search, summary: dict) -> int:
    """The holds that never settled replaced by their fitted rest positions where so many never
    settle that the rest would be a remnant (``extrapolate``, ``max_unsettled_fraction``) and their
    approach fits the stream and extrapolates within bounds; the number replaced. HoldsNeverSettle
    when too few extrapolate, or when over half never settle and extrapolation is off."""
    opt, N, M, found_r = st.opt, st.shape[0], st.shape[1], found.results
    unsettled, fits, segments = found.unsettled, found.fits, found.segments
    many = len(unsettled) > opt.max_unsettled_fraction * N and len(unsettled) >= 2  # one of a few is no pattern
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        moved = np.linalg.norm(np.diff(found.held_at, axis=0), axis=2)  # (N - 1, M)
        step_m = np.concatenate([[0.0], np.where(np.isfinite(moved).any(axis=1),
                                                 np.nanmax(np.where(np.isfinite(moved), moved, -np.inf), axis=1), 0.0)])
    n_settled = len(found_r)
    if not (unsettled and (opt.extrapolate == "always" or (opt.extrapolate == "auto" and many))):
        if many and len(unsettled) > 0.5 * N and found_r:
            raise HoldsNeverSettle(
                f"{session.markers_source}: {summary['sentence']}; calibrating from the {N - len(found.dropped)} that "
                "did would fit a remnant: record longer holds, or settle with extrapolation to rest",
                refusal(f"{n_settled} of {N} holds settled; {len(unsettled)} never did{_who(summary)}, over half, and "
                        "extrapolation to rest is off", summary, N, n_settled))
        return 0
    good = [i for i in unsettled if i in fits and fits[i].good
            and float(np.nanmax(fits[i].remaining_m)) <= max(opt.max_extrapolation_m,
                                                             opt.max_extrapolation_share * step_m[i])
            and extrapolation_checked(*segments[i], fits[i], segments[i][1].shape[0], st.sig_slow)]
    if opt.extrapolate == "auto" and len(good) < MIN_EXTRAPOLABLE_SHARE * len(unsettled):
        if found_r:
            need = f"{100 * MIN_EXTRAPOLABLE_SHARE:g}% needed"
            raise HoldsNeverSettle(
                f"{session.markers_source}: {summary['sentence']}; the approach of only {len(good)} of them "
                f"fits the stream well enough to extrapolate to rest ({need}): record longer holds (or a slower plan)",
                refusal(f"{n_settled} of {N} holds settled; {len(unsettled)} never did{_who(summary)}, and only "
                        f"{len(good)} of those extrapolate to rest ({need})", summary, N, n_settled,
                        n_extrapolable=len(good), extrapolable_share=MIN_EXTRAPOLABLE_SHARE))
        good = []  # nothing settled and little extrapolates: the recording never settles (settle says it)
    for i in good:
        f = fits[i]
        var = np.nanmax(f.x_inf_std, axis=1) ** 2
        # as many samples as would average to that variance (window means vary as sig_slow^2 / n)
        cnt = np.where(np.isfinite(var) & (var > 0), st.sig_slow**2 / np.where(var > 0, var, 1.0), 0.0)
        last = segments[i][1][-st.min_samples:]
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            held = np.nanmean(np.where(np.isfinite(last).all(axis=2)[..., None], last, np.nan), axis=0)
        found_r[i] = dict(mean=f.x_inf, held=held, cnt=cnt, std=np.full(M, np.nan), start=np.nan, end=np.nan,
                          tau=f.tau, remaining=float(np.nanmax(f.remaining_m)), extrapolated=1.0)
        found.dropped.pop(i)
    return len(good)


def _pose_set(session: Session, st: _Stream, found: _Search, n_extrapolated: int, summary: dict) -> PoseSet:
    """The PoseSet of the kept holds (settle's docstring); NeverSettles when none is kept."""
    N = st.shape[0]
    results, U, tc = found.results, st.U, st.tc
    kept = sorted(results)
    dropped_list = sorted(found.dropped.items())
    if not kept:
        reason = dropped_list[0][1] if dropped_list else "no commands"
        raise NeverSettles(
            f"{session.markers_source}: the recording never settles: none of {N} commands gave a still window "
            f"(first: row {dropped_list[0][0] + 1 if dropped_list else 0}: {reason})"
            + (f"; {summary['sentence']}" if summary else ""),
            refusal(f"none of {N} commands gave a still window", summary, N, 0))
    kept_a = np.array(kept)
    col = lambda key: np.array([results[i][key] for i in kept])  # noqa: E731
    base = None
    if session.base_markers is not None and session.base_markers.shape[1]:
        with np.errstate(invalid="ignore"):
            base = np.nanmean(session.base_markers, axis=0)
    return PoseSet(
        platform=session.platform, controls=U[kept_a], markers=col("mean"),
        marker_names=list(session.marker_names),
        description=None if session.description is None else str(session.description),
        base_markers=base, t=tc[kept_a], n_samples=col("cnt"), length_unit=session.length_unit,
        moving_link=session.moving_link, source=str(session.folder), dropped=dropped_list,
        extras={
            "row": kept_a, "direction": direction_of_last_motion(U)[kept_a], "last_step": last_step(U)[kept_a],
            "play": play_memory(U, kept_a), "elapsed": tc[kept_a] - tc[0], "settle_time": col("start") - tc[kept_a],
            "window_start": col("start"), "window_end": col("end"), "marker_std": col("std"),
            "approach_tau_s": col("tau"), "remaining_m": col("remaining"), "extrapolated": col("extrapolated"),
            "held_markers": col("held"),
        },
        settling={"sigma_m": float(st.sigma), "slow_noise_inflation": float(st.slow_inflation), "n_commands": N,
                  "n_kept": len(kept), "n_extrapolated": n_extrapolated,
                  "unsettled": summary},
    )


def settle(session: Session, options: SettleOptions | None = None) -> tuple[PoseSet, SettleReport]:
    """Settled poses of a session with a raw marker stream (markers.csv or C3D).

    Returns the PoseSet (kept poses only; ``dropped`` lists (row, reason) of the others, rows
    0-based in commands.csv order, each reason ``category: detail`` with a category of
    DROP_CATEGORIES) and a SettleReport. ``extras``: 'row' (N,) command row,
    'direction' (N, n_u) sign of the last change of each control, 'last_step' (N, n_u) the command
    step that led to the row (u_i - u_(i-1), internal units), 'play' a play's memory over every
    command of the log up to the row, those that gave no pose included (platkit.play.play_memory),
    'elapsed' (N,) s since the first
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

    The stages: the stream and its noise (:func:`_stream`), every hold's window or why it never
    settled (:func:`_search_holds`), the windows the session moves (:func:`_shared_windows`), the
    unsettled holds said (:func:`_unsettled_summary`) and extrapolated (:func:`_extrapolate`),
    the PoseSet (:func:`_pose_set`).
    """
    st = _stream(session, options or SettleOptions())
    N, M = st.shape
    found = _Search(N, M)
    _search_holds(st, found)
    _shared_windows(st, found)
    names = (list(session.spec.control_names) if session.spec is not None
             else [f"u{j + 1}" for j in range(st.U.shape[1])])
    for i, r in found.results.items():
        found.held_at[i] = r["mean"]
    summary = _unsettled_summary(found.unsettled, found.fits, st.U, names, list(session.marker_names), found.hold_s, N,
                                 set(found.dropped) - set(found.unsettled), found.slow_taus, found.slow_left,
                                 found.held_at, found.slow_tail)
    n_extrapolated = _extrapolate(session, st, found, summary)
    poses = _pose_set(session, st, found, n_extrapolated, summary)
    report = SettleReport(float(st.sigma), N, len(poses.controls), sorted(found.dropped.items()), float(st.rate),
                          n_extrapolated, summary)
    return poses, report


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
        raise BadSession(f"{Path(folder) / 'session.yaml'}: declares no platform (an IMU-only recording); "
                         "calibration needs a stand")
    if session.markers is not None or session.poses is not None:
        # rigid bodies: averaged over the windows found (calibrate.bodies)
        poses = settle(stream_for_settling(session), options)[0] if session.markers is not None \
            else poses_from_table(session)
        poses = with_settled_bodies(session, poses)
        since = session.since_power_on(poses.t)  # the time since power-on that a warm-up reads
        if since is not None:
            poses.extras["since_power_on"] = since
        return poses
    raise BadSession(
        f"{folder}: the session has no markers: expected markers.csv, poses.csv or session.yaml's markers_file"
    )
