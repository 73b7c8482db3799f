"""The motion-capture stream of a calibration from motion (:mod:`platkit.calibrate.motion`): its
checks, and its reduction to nodes that keep what it says of the geometry.

- :func:`check_motion_session`: markers and at least three commands, on two clocks that overlap,
  and a streamed log with no gap the markers move through (BadSession naming commands.csv);
  which reference the log calls for ('step': streamed, 'profile': holds);
- :func:`past_log_end`: where a streamed log cut while the stand moves stops telling its
  commands (the samples past it, read through the response's lag, are left out of the windows);
  a log that ends at rest (its last steps, or the markers still after it) keeps every sample;
- :func:`stream_windows`: the stream cut into windows of about WINDOW_S s, each marker
  coordinate fitted by a polynomial of degree NODES - 1 in time and kept at the window's NODES
  Gauss-Legendre nodes, weighted by the samples it stands for; whole windows, evenly spread,
  about RAW_SAMPLES samples in all, kept as their samples (the response's timing shows in the
  fast content the windows' fit leaves out);
- :func:`projected_positions`: the same projection of the controls reached at every sample,
  evaluated a block of nodes at a time, so that no array over every sample is made;
- :func:`commanded_direction`: the direction of each actuator's last move at the nodes, read from
  the command log through the actuator's response lag (a history effect's 'direction').
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from platkit.calibrate.response import ResponseModel, actuator_positions, lags
from platkit.errors import BadSession
from platkit.io.session import Session

__all__ = ["StreamWindows", "check_motion_session", "commanded_direction", "log_end", "past_log_end",
           "projected_positions", "response_lag", "still_after", "stream_windows", "window_fit", "STREAMED_MAX_S",
           "DIRECTION_TRAVEL", "REST_SHARE", "TAIL_PARTS"]

#: a command log whose median interval is at most this (s) is streamed (step reference); longer
#: intervals are point-to-point moves between holds (profile reference)
STREAMED_MAX_S = 0.25
#: the stream's reduction: windows of about WINDOW_S s, each kept at NODES nodes; a marker seen in
#: under MIN_SEEN_SHARE of a window's samples is left out of it
WINDOW_S, NODES, MIN_SEEN_SHARE = 1.0, 3, 0.5
#: samples kept as they are (whole windows, evenly spread): the response's timing shows in the
#: motion's fast content (each command's step response), which the windows' fit leaves out
RAW_SAMPLES = 1500
#: in a streamed log, an interval this many times the median is a gap; markers moving more than
#: GAP_MOVE_M (m) in its second half, long after any response, mean commands are missing there
GAP_FACTOR, GAP_MOVE_M = 10.0, 1e-3
#: the two clocks must share at least this part of the shorter file's span
OVERLAP_SHARE = 0.5
#: the controls reached at the samples are evaluated about PROJ_SAMPLES samples at a time
#: (:func:`projected_positions`)
PROJ_SAMPLES = 16384
#: a command counts as a move of its actuator where it has travelled more than this share of the
#: actuator's stroke from the last turning point (:func:`commanded_direction`)
DIRECTION_TRAVEL = 1e-3
#: a streamed log ends at rest where every actuator's last step is at most this share of its
#: median step (the commands stopped, not cut in motion: :func:`log_end`)
REST_SHARE = 0.1
#: the markers after a log's end are judged still on TAIL_PARTS parts of the samples
#: (:func:`still_after`)
TAIL_PARTS = 5


def log_end(T: np.ndarray, U: np.ndarray) -> float | None:
    """Where a streamed command log (``T`` (N,) s on the commands' clock, ``U`` (N, n_u)) stops
    telling the stand's commands: None where it ends at rest (no actuator's last step over
    REST_SHARE of its median step: the last command held is what the stand was told, however
    long after); where it ends in motion (cut while the stand moves), its last command's time
    plus the log's median interval (the last command holds for one interval, as every other)."""
    T, U = np.asarray(T, float), np.asarray(U, float)
    if len(T) < 2:
        return None
    step = np.abs(np.diff(U, axis=0))
    median = np.median(step, axis=0)
    if not np.any((median > 0) & (step[-1] > REST_SHARE * median)):
        return None
    return float(T[-1] + np.median(np.diff(T)))


def past_log_end(session: Session, reference: str, lag_s, settle_s: float) -> float | None:
    """The motion-capture time (s) after which ``session``'s samples follow commands its log does
    not have, under the response's time lags ``lag_s`` (s, per actuator: a sample at t reads the
    commands of t - lag): :func:`log_end` plus the smallest lag (a sample is known where every
    actuator's command is). None where the log ends at rest: by its commands (:func:`log_end`), or
    by the markers, seen still from ``settle_s`` (s: the response's to the last command, settled)
    after that time to the last sample (:func:`still_after`: a log that slows to its last
    command, which the stand then holds); and for a ``reference`` 'profile' (its last command is a
    hold's target: the stand comes to rest on it)."""
    end = log_end(session.command_t, session.commands) if reference == "step" else None
    if end is None:
        return None
    end += float(np.min(lag_s))
    return None if still_after(session.marker_t, session.markers, end + settle_s) else end


def still_after(tm: np.ndarray, Y: np.ndarray, t0: float) -> bool:
    """Whether the markers ``Y`` (K, M, 3) at times ``tm`` (K,) are seen at rest after ``t0``: its
    samples cut into TAIL_PARTS parts of equal samples, no marker seen in every part has means in
    two parts more than GAP_MOVE_M apart. False where fewer than 2 TAIL_PARTS samples lie after
    ``t0``, or no marker is seen in every part (nothing shows the stand at rest)."""
    k = np.nonzero(tm > t0)[0]
    if len(k) < 2 * TAIL_PARTS:
        return False
    means = []
    for part in np.array_split(k, TAIL_PARTS):
        seen = np.isfinite(Y[part]).all(axis=2)  # (len(part), M)
        n = seen.sum(axis=0)
        total = np.where(seen[:, :, None], Y[part], 0.0).sum(axis=0)
        means.append(np.where((n > 0)[:, None], total / np.maximum(n, 1)[:, None], np.nan))
    means = np.stack(means)  # (TAIL_PARTS, M, 3)
    every = np.isfinite(means).all(axis=(0, 2))
    if not every.any():
        return False
    m = means[:, every]
    apart = np.linalg.norm(m[:, None] - m[None, :], axis=3)  # (parts, parts, markers)
    return bool(apart.max() <= GAP_MOVE_M)


def response_lag(model: ResponseModel, theta) -> np.ndarray:
    """(n_u,) the time (s) by which each actuator's position follows its command log at low
    frequency: its whole time lag (:func:`platkit.calibrate.response.lags`: the shift and its
    delay) and its linear response's delay on a ramp (tau_j first order, 2 zeta_j tau_j second
    order). The sum is what the markers fix; the shift alone trades with the time constants."""
    par = model.split(theta)
    tau = np.asarray(par["tau_s"], float)
    zeta = np.asarray(par["damping"], float) if "damping" in par else np.ones(model.n_u)
    ramp = [2.0 * zeta[j] * tau[j] if model.is_second(j) else tau[j] for j in range(model.n_u)]
    return lags(model, theta) + np.asarray(ramp, float)


def commanded_direction(T: np.ndarray, U: np.ndarray, t: np.ndarray, lag: np.ndarray,
                        stroke: np.ndarray) -> np.ndarray:
    """(K, n_u) the sign of each actuator's last move at the motion-capture times ``t`` (K,), 0
    before its first: read from the command log (``T`` (N,) s on the commands clock, ``U`` (N,
    n_u)), never from the controls a response fitted there (a fitted overshoot after the last
    command, or the markers' noise, does not turn it). The rule: actuator j at time t reads the
    commands up to t - ``lag[j]`` (:func:`response_lag`); its direction turns where the commands
    have travelled more than DIRECTION_TRAVEL of its ``stroke`` (n_u,) back from the last turning
    point (the furthest command since the last turn), and holds between."""
    U = np.atleast_2d(np.asarray(U, float))
    t = np.asarray(t, float)
    N, n_u = U.shape
    out = np.zeros((len(t), n_u))
    for j in range(n_u):
        tol = DIRECTION_TRAVEL * float(stroke[j])
        d = np.zeros(N)
        sign, turn = 0.0, float(U[0, j])
        for i in range(1, N):
            x = float(U[i, j])
            if sign * (x - turn) > 0.0:  # further the same way: the turning point moves with it
                turn = x
            elif abs(x - turn) > tol:  # back (or, at first, away) from it by more than the travel
                sign, turn = float(np.sign(x - turn)), x
            d[i] = sign
        read = np.searchsorted(T, t - float(lag[j]), side="right") - 1  # the last command read at each time
        out[:, j] = np.where(read >= 0, d[np.maximum(read, 0)], 0.0)
    return out


def projected_positions(proj: sparse.csr_matrix, model: ResponseModel, theta, T: np.ndarray, U: np.ndarray,
                        sample_t: np.ndarray, only: int | None = None, start: np.ndarray | None = None,
                        cache: dict | None = None) -> np.ndarray:
    """``proj @ actuator_positions(model, theta, T, U, sample_t, ...)`` (P, n_u), or (P,) for
    ``only``, for nodes whose rows run forward in time (:class:`StreamWindows`): the positions
    are evaluated for one block of nodes at a time (about PROJ_SAMPLES samples), at the samples
    its rows span, so that no array over every sample is made; each node's sum is the whole
    product's, term for term in the same order."""
    P = proj.shape[0]
    ip, ix, data = proj.indptr, proj.indices, proj.data
    out = np.zeros((P,) if only is not None else (P, model.n_u))
    if not len(ix):
        return out
    first = np.maximum.accumulate(ix[np.minimum(ip[:-1], len(ix) - 1)])  # each row's first sample
    cuts = np.searchsorted(first, np.arange(PROJ_SAMPLES, int(first[-1]) + 1, PROJ_SAMPLES), side="left")
    for r0, r1 in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [P]])):
        lo, hi = int(ip[r0]), int(ip[r1])
        if lo == hi:
            continue
        c0, c1 = int(ix[lo:hi].min()), int(ix[lo:hi].max()) + 1
        block = sparse.csr_matrix((data[lo:hi], ix[lo:hi] - c0, ip[r0:r1 + 1] - lo), shape=(r1 - r0, c1 - c0))
        out[r0:r1] = block @ actuator_positions(model, theta, T, U, sample_t[c0:c1], only=only, start=start,
                                                cache=cache)
    return out


def check_motion_session(session: Session) -> str:
    """The reference the command log calls for ('step': streamed, 'profile': holds), after the
    checks: markers (rigid bodies alone are read as points first: platkit.calibrate.motion_points)
    and commands present, on clocks that overlap. BadSession naming the file otherwise."""
    cmd_file = session.folder / "commands.csv"
    mk_file = session.markers_source or session.folder / "markers.csv"
    if session.body_names and not session.marker_names:  # the windows and the response's start read markers
        raise BadSession(f"{session.folder / 'session.yaml'}: no markers, only rigid bodies "
                         f"{', '.join(session.body_names)}: this fit from motion reads markers (the stream's samples "
                         "and the response's start are found from them); the bodies alone are calibrated from "
                         "motion as three points each (platkit.calibrate.motion_points, what platkit calibrate does)")
    if session.markers is None or session.marker_t is None:
        raise BadSession(f"{session.folder}: the session has no motion-capture stream; calibrating from motion "
                         "needs markers.csv or a C3D file")
    if session.commands is None or session.command_t is None or len(session.command_t) < 3:
        raise BadSession(f"{cmd_file}: fewer than 3 commands; calibrating from motion needs the command log")
    tc, tm = session.command_t, session.marker_t
    last = float(tc[-1] + np.median(np.diff(tc)))  # the last command is held about as long as the others
    overlap = min(float(tm[-1]), last) - max(float(tm[0]), float(tc[0]))
    if overlap < OVERLAP_SHARE * min(last - float(tc[0]), float(tm[-1] - tm[0])):
        raise BadSession(f"{cmd_file}: its times ({tc[0]:.3f} to {tc[-1]:.3f} s) and those of {mk_file} "
                         f"({tm[0]:.3f} to {tm[-1]:.3f} s) do not overlap: the two files are on clocks that do not "
                         "meet (write both from one clock, or shift one by the known offset)")
    span = np.diff(tc)
    med = float(np.median(span))
    reference = "step" if med <= STREAMED_MAX_S else "profile"
    if reference == "step":
        _check_gaps(tc, tm, session.markers, cmd_file, mk_file, med)
    return reference


def _check_gaps(tc, tm, Y, cmd_file, mk_file, med: float) -> None:
    """A streamed log with an interval over GAP_FACTOR times its median, in whose second half the
    markers' centroid moves more than GAP_MOVE_M: commands are missing there (BadSession)."""
    if Y.shape[1]:  # the centroid of the markers seen; NaN at a sample with none seen
        n = np.isfinite(Y).sum(axis=1)
        c = np.where(n > 0, np.nansum(Y, axis=1) / np.maximum(n, 1), np.nan)
    else:
        c = np.zeros((len(tm), 3))
    for i in np.nonzero(np.diff(tc) > GAP_FACTOR * med)[0]:
        a, b = float(tc[i]), float(tc[i + 1])
        mid = 0.5 * (a + b)
        first = c[(tm >= mid) & (tm < mid + 0.2 * (b - a))]
        last = c[(tm >= b - 0.2 * (b - a)) & (tm < b)]
        if not (np.isfinite(first).all(axis=1).any() and np.isfinite(last).all(axis=1).any()):
            continue
        moved = float(np.linalg.norm(np.nanmean(last, axis=0) - np.nanmean(first, axis=0)))
        if moved > GAP_MOVE_M:
            raise BadSession(f"{cmd_file}: no command from t={a:.3f} to t={b:.3f} s ({b - a:.3g} s, the log's interval is "
                             f"{med:.3g} s) while the markers in {mk_file} moved {1e3 * moved:.3g} mm late in it: the "
                             "log is sparser than the motion (commands missing)")


@dataclass
class StreamWindows:
    """The stream reduced to nodes: the samples of each window of about ``window_s`` s, every
    marker coordinate fitted by a polynomial of degree ``nodes`` - 1 in time and kept as its values
    at the window's ``nodes`` Gauss-Legendre nodes (module docstring, 2.).

    t (P,) the nodes' times (motion-capture clock); Y (P, M, 3) the fitted markers there (NaN where
    a marker was left out of a window); n_eff (P, M) what each is worth in samples (the inverse of
    its variance in units of one sample's, 0 where left out); proj (P, K) sparse: the same fit of
    the controls (every sample of the window) from the K samples at ``sample_t`` (the stream's
    from ``first`` on); blocks: per window (first row, first sample, samples, {marker: (its rows
    within the window and the fit (nodes, rows), or (None, None) for all rows and the window's own
    fit, its rows of proj)}, or None for a window kept raw);
    counts: the stream's samples, those used (a marker seen, in a window that served), kept raw,
    with no marker seen, before the second command, in windows too short to fit (the stream's
    end), and the marker observations left out (a marker seen too little in a window); with a
    start given, the samples from the second command to it (``n_start_transient``: the first
    command's transient, :mod:`platkit.calibrate.motion_transient`), and ``second``: the first
    sample at or after the second command; with an end given, the samples after it
    (``n_past_log``: past the end of a log cut in motion, :func:`past_log_end`), and ``end``: the
    first of them (None where none is left out: the stream's samples run to its last)."""

    t: np.ndarray
    Y: np.ndarray
    n_eff: np.ndarray
    proj: sparse.csr_matrix
    sample_t: np.ndarray
    first: int
    blocks: list
    n_stream: int
    n_used: int
    n_raw: int
    n_unseen: int
    n_before: int
    n_short: int
    n_left_out: int
    n_windows: int
    n_raw_windows: int
    window_s: float
    nodes: int
    n_start_transient: int = 0
    second: int = -1
    n_past_log: int = 0
    end: int | None = None


def _legendre(x: np.ndarray, n: int) -> np.ndarray:
    """(len(x), n) Legendre polynomials P_0 .. P_(n-1) at x."""
    return np.stack([np.polynomial.legendre.Legendre.basis(k)(x) for k in range(n)], axis=1)


def _window_span(t: np.ndarray) -> tuple[float, float]:
    """The span a window's samples ``t`` stand for: each sample its interval, so that the values of
    the window's fit at its nodes are uncorrelated (to about 1e-3)."""
    half = 0.5 * float(t[-1] - t[0]) / (len(t) - 1)
    return float(t[0]) - half, float(t[-1]) + half


def window_fit(t: np.ndarray, nodes: int, k: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The windowed fit of :class:`StreamWindows` for a window whose samples are at times ``t``
    (motion-capture clock), from its samples ``k`` alone (indices into ``t``; all where None):
    ``A`` (nodes, len(k)), the polynomial of degree ``nodes`` - 1 fitted by least squares to those
    samples, read at the window's Gauss-Legendre nodes, and ``n_eff`` (nodes,), what each value is
    worth in samples (the inverse of its variance in units of one sample's)."""
    lo, hi = _window_span(t)
    xg, _ = np.polynomial.legendre.leggauss(nodes)
    Pn = _legendre(xg, nodes)
    Phi = _legendre(2.0 * (t - lo) / (hi - lo) - 1.0, nodes)
    if k is not None:
        Phi = Phi[k]
    G = np.linalg.inv(Phi.T @ Phi)
    return Pn @ G @ Phi.T, 1.0 / np.einsum("ij,jk,ik->i", Pn, G, Pn)


def seen_around_nodes(t: np.ndarray, k: np.ndarray, nodes: int) -> bool:
    """Whether a channel (a marker, a rigid body) seen at the samples ``k`` of a window whose
    samples are at times ``t`` is reduced to the window's ``nodes`` nodes: seen in at least
    MIN_SEEN_SHARE of the window's samples (and 2 ``nodes``), and on both sides of every node (a
    sample seen at or before the first node and one at or after the last). A node outside the span
    seen would be the polynomial extrapolated: its weight (``n_eff``) tells its variance, not its
    bias, which grows with the motion's third derivative (a 1 Hz path seen over the window's first
    55 % put the last node 150 mm off)."""
    if len(k) < max(2 * nodes, MIN_SEEN_SHARE * len(t)):
        return False
    lo, hi = _window_span(t)
    xg, _ = np.polynomial.legendre.leggauss(nodes)
    node_t = lo + (xg + 1.0) * 0.5 * (hi - lo)
    return bool(t[k[0]] <= node_t[0] and t[k[-1]] >= node_t[-1])


def stream_windows(session: Session, window_s: float = WINDOW_S, nodes: int = NODES,
                   raw_samples: int = RAW_SAMPLES, start_t: float | None = None,
                   end_t: float | None = None) -> StreamWindows:
    """The stream from the second command on (from ``start_t`` on, motion-capture clock, where that
    is later: the samples between counted) up to ``end_t`` (motion-capture clock; None: its last
    sample; the samples after it counted: past the end of a log cut in motion,
    :func:`past_log_end`; the windows are those of the stream to its last sample, the samples
    after ``end_t`` left out of the windows they fall in, so that the others are not moved), cut
    into windows of equal length near ``window_s``
    s, each reduced to ``nodes`` nodes (:class:`StreamWindows`), but one window in every so many
    (evenly, about ``raw_samples`` samples in all; every window of a short stream) kept as its
    samples. A marker seen in fewer than MIN_SEEN_SHARE of a window's samples (or fewer than 2
    ``nodes``), or not on both sides of every node (:func:`seen_around_nodes`), is left out of that
    window; a window with fewer than 2 ``nodes`` samples (the stream's end) is left out; both
    counted."""
    tm, Y = session.marker_t, session.markers
    M = Y.shape[1]
    seen_any = np.isfinite(Y).all(axis=2).any(axis=1)
    second = int(np.searchsorted(tm, session.command_t[1], side="left"))
    a0 = second if start_t is None else max(second, int(np.searchsorted(tm, start_t, side="left")))
    end = len(tm) if end_t is None else max(a0, int(np.searchsorted(tm, end_t, side="right")))
    span = float(tm[-1] - tm[a0]) if a0 < len(tm) else 0.0
    n_win = max(1, int(round(span / window_s)))
    edges = np.searchsorted(tm, tm[a0] + np.arange(n_win + 1) * (span / n_win), side="left")
    edges[-1] = len(tm)
    edges = np.minimum(edges, end)  # past the log's end: a window shortened, or empty
    xg, _ = np.polynomial.legendre.leggauss(nodes)
    ts, Ys, ns, blocks = [], [], [], []
    rows, cols, vals = [], [], []
    left_out = short = 0
    p = 0
    sizes = np.diff(edges)
    # whole windows kept raw, evenly spread, up to raw_samples samples
    every = max(1, int(np.ceil(float(sizes.sum()) / max(raw_samples, 1))))
    raw = (np.arange(n_win) % every == 0) if raw_samples > 0 else np.zeros(n_win, bool)
    n_raw = 0
    for w in range(n_win):
        a, b = int(edges[w]), int(edges[w + 1])
        if raw[w]:
            k = np.nonzero(seen_any[a:b])[0]
            if not len(k):
                continue
            rows.append(p + np.arange(len(k)))
            cols.append(a - a0 + k)
            vals.append(np.ones(len(k)))
            ts.append(tm[a + k])
            Ys.append(Y[a + k])
            ns.append(np.isfinite(Y[a + k]).all(axis=2).astype(float))
            blocks.append((p, a, b - a, None))
            p += len(k)
            n_raw += len(k)
            continue
        if b - a < 2 * nodes:
            short += int(seen_any[a:b].sum())
            continue
        lo, hi = _window_span(tm[a:b])
        A, n_full = window_fit(tm[a:b], nodes)  # (nodes, b - a): the fit's values at the nodes
        r, c = np.nonzero(np.ones_like(A, bool))
        rows.append(p + r)
        cols.append(a - a0 + c)
        vals.append(A.ravel())
        Yw = Y[a:b]
        vis = np.isfinite(Yw).all(axis=2)  # (b - a, M)
        out = np.full((nodes, M, 3), np.nan)
        n_eff = np.zeros((nodes, M))
        per = {}
        full = vis.all(axis=0)
        if full.any():
            out[:, full] = np.einsum("ik,kmc->imc", A, Yw[:, full])
            n_eff[:, full] = n_full[:, None]
            for m in np.nonzero(full)[0]:
                per[int(m)] = (None, None)  # the window's own fit: its rows of proj
        for m in np.nonzero(~full)[0]:
            k = np.nonzero(vis[:, m])[0]
            if not seen_around_nodes(tm[a:b], k, nodes):
                left_out += len(k)
                continue
            Am, n_eff[:, m] = window_fit(tm[a:b], nodes, k)
            out[:, m] = Am @ Yw[k, m]
            per[int(m)] = (k, Am)
        ts.append(lo + (xg + 1.0) * 0.5 * (hi - lo))
        Ys.append(out)
        ns.append(n_eff)
        blocks.append((p, a, b - a, per))
        p += nodes
    K = end - a0
    if not ts:  # nothing to fit: the caller says so
        ts, Ys, ns = [np.zeros(0)], [np.zeros((0, M, 3))], [np.zeros((0, M))]
        rows, cols, vals = [np.zeros(0, int)], [np.zeros(0, int)], [np.zeros(0)]
    proj = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(p, K))
    n_unseen = int((~seen_any[a0:]).sum())
    n_used = int(seen_any[a0:end].sum()) - short
    return StreamWindows(np.concatenate(ts), np.concatenate(Ys), np.concatenate(ns), proj, tm[a0:end], a0, blocks,
                         len(tm), n_used, n_raw, n_unseen, int(seen_any[:second].sum()), short, left_out, len(blocks),
                         int(raw.sum()), span / n_win, nodes, int(seen_any[second:a0].sum()), second,
                         int(seen_any[end:].sum()), None if end_t is None else end)
