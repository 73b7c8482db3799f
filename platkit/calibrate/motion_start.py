"""The actuators' response started from the markers alone, before the fit of calibration from
motion (platkit.calibrate.motion, step 3): each sample's controls by inverse kinematics of its
markers at the nominal geometry (the actuators' travel), and the response fitted to that travel.

Rules:
- the registration (frame and markers by rigid alignment at the nominal geometry and the starting
  response's controls) is taken on the slowest STILL_SHARE of the stream's windows
  (:func:`slowest_rows`): where the stand stands still the controls it reached are the command
  in force whatever its response; where it moves, the starting response's error is a control
  error in proportion to the speed, and on a stream that is mostly motion (point-to-point moves
  between holds) it turned the frame's rotation by up to 140 degrees; where the travel at that
  registration reaches under REACHED_SHARE of the samples (a frame registered wrong, which a stand
  of fewer than six degrees of freedom shows: no pose it reaches comes near the markers), the
  start is taken again on the slowest share of each of OTHER_SHARES in turn, the first whose travel
  reaches REACHED_SHARE kept, else the one that reached most;
- a moving frame's travel: the sample's pose by Kabsch of the marker layout, then the stand's
  inverse kinematics, and where that pose is not reached exactly (a stand of fewer than six degrees
  of freedom never reaches the pose of noisy markers) the controls whose markers come nearest; a
  tree's (each marker on its tracked link): those, by damped Gauss-Newton over the controls; a
  sample with fewer than three markers seen, out of reach or missed by more than TRAVEL_MISS_M is
  left out (NaN), and so is a joint that moves no marker;
- the response: the common shift by a grid (each actuator's best, their median), then each
  actuator's least squares (soft L1) with a shift of its own, the shift at the median of theirs,
  and each actuator's again with it held;
- a second kind's start from a fit (:func:`travel_start`): the same, the travel by inverse
  kinematics at the fit's geometry, frame and markers and the samples' controls at the fit's
  response (a first order's shift takes the second order's apparent dead time: the second order
  started from it with its time constants halved can stop at an overdamped optimum whose shift
  is still that of the first order).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from platkit.calibrate.problem import CalibrationProblem, link_frames
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.stream import StreamWindows, projected_positions
from platkit.errors import ComputationFailed
from platkit.geometry import matrix_from_quat, matrix_from_rotvec, quat_from_matrix, rigid_fit
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.notices import warn
from platkit.poses import PoseSet

__all__ = ["ACCEL_TIME_S", "DELAY_MAX_S", "OTHER_SHARES", "PRE_SAMPLES", "RATE_FREE_FACTOR", "REACHED_SHARE",
           "SHIFT_GRID_S", "START_ROUNDS", "START_SAMPLES", "STILL_MIN_WINDOWS", "STILL_SHARE", "STROKE_TIME_S",
           "TAU0_S", "ZETA0", "actuator_travel", "command_speed", "fd_steps", "marker_points", "response_from_travel",
           "response_start", "slowest_rows", "starting_theta", "travel_start", "window_speeds"]

#: samples that start the response; rounds of the start; samples before the first command that
#: say where a profile's actuators rest
START_SAMPLES, START_ROUNDS, PRE_SAMPLES = 600, 2, 50
#: starting response: time constant (s), damping; a profile's rate and acceleration from the
#: stroke (a full stroke in STROKE_TIME_S, the rate reached in ACCEL_TIME_S)
TAU0_S, ZETA0, STROKE_TIME_S, ACCEL_TIME_S = 0.05, 1.0, 4.0, 0.25

#: the registration at a starting response is taken on the slowest STILL_SHARE of the stream's
#: windows (at least STILL_MIN_WINDOWS of them; all windows where the stream has fewer)
STILL_SHARE, STILL_MIN_WINDOWS = 0.25, 8
#: where the start's travel (its last round's) reaches under REACHED_SHARE of its samples (the
#: markers more than TRAVEL_MISS_M from every pose the stand reaches at that frame: a frame registered
#: wrong, which a stand of fewer than six degrees of freedom shows so), the start is taken again with
#: the registration on the slowest share of the windows of each of OTHER_SHARES in turn (the same
#: rows once), and the first whose travel reaches REACHED_SHARE kept, else the one that reached most
REACHED_SHARE, OTHER_SHARES = 0.5, (0.125, 0.5, 1.0)

#: the shifts (s) tried to start the response
SHIFT_GRID_S = np.arange(-0.5, 0.5001, 0.01)
#: an actuator's own delay lies within +-DELAY_MAX_S of the shift; a streamed drive's rate limit
#: at most RATE_FREE_FACTOR times the log's fastest step over its interval (there the slew takes
#: a tenth of the interval: a limit that does not bind)
DELAY_MAX_S, RATE_FREE_FACTOR = 0.5, 10.0
#: a tree's travel by inverse kinematics of its markers: Gauss-Newton rounds, the controls' forward
#: difference step (internal units), and the RMS marker miss (m) past which a sample is left out
TRAVEL_ROUNDS, TRAVEL_STEP, TRAVEL_MISS_M = 6, 1e-6, 0.01


def _lower_upper(model: ResponseModel, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full(model.size, 1e-9)
    hi = np.full(model.size, np.inf)
    lo[0], hi[0] = -5.0, 5.0
    for j in range(model.n_u):
        lo[model.index("tau_s", j)], hi[model.index("tau_s", j)] = 2e-3, 20.0
        if model.has("damping", j):
            lo[model.index("damping", j)], hi[model.index("damping", j)] = 0.2, 5.0
        if model.delays:
            lo[model.index("delay_s", j)], hi[model.index("delay_s", j)] = -DELAY_MAX_S, DELAY_MAX_S
        if model.slewed:  # a rate limit that never binds: up to RATE_FREE_FACTOR times the start
            hi[model.index("rate", j)] = RATE_FREE_FACTOR * max(float(theta0[model.index("rate", j)]), 1e-9)
    return lo, hi


def marker_points(spec: PlatformSpec, model: PlatformModel, td, mk, links, U: np.ndarray, guess=None):
    """(K, M, 3) the markers ``mk`` (M, 3) in the base frame at controls U (K, n_u) and parameters
    td, each on its link: the moving frame, or on a tree (``links`` (M,) indices in
    ``spec.tracked_links``) its tracked link; NaN where the kinematics fails. The actuators of a
    stream move apart in time: a stand with more rows than pose coordinates (a cable robot) takes its
    rows' weighted least-squares pose whatever their misfit, as the fit's model does
    (:class:`~platkit.calibrate.motion.ResponseTerm`)."""
    if links is not None:
        R, X = link_frames(spec, td, U)
        k = np.asarray(links)
        return X[:, k] + np.einsum("kmab,mb->kma", R[:, k], mk)
    fb = model.forward_batch(U, td, guess=guess, strict=False, refuse_misfit=False)
    pts = fb.X[:, None, :] + np.einsum("kab,mb->kma", matrix_from_quat(fb.q), mk)
    pts[~(fb.converged & fb.on_branch)] = np.nan
    return pts


def _nearest_travel(spec: PlatformSpec, td, mk, links, Yb: np.ndarray, guess_u: np.ndarray,
                    model: PlatformModel | None = None) -> np.ndarray:
    """The actuators' travel (K, n_u) by least squares over the controls: at each sample the
    controls whose markers (each on its tracked link, ``links``; on the moving frame of ``model``
    where ``links`` is None) come nearest the sample's in the base frame ``Yb`` (K, M, 3), by damped
    Gauss-Newton from ``guess_u`` (forward differences over the controls, every sample at once); NaN
    rows where fewer than three markers are seen, the kinematics fails or the markers stay off by
    more than TRAVEL_MISS_M, and a NaN column for a joint that moves no marker (its travel is not
    seen)."""
    seen = np.isfinite(Yb).all(axis=2)
    y = np.where(seen[..., None], Yb, 0.0)
    u = np.array(guess_u, float)
    K, n_u = u.shape
    lo, hi = spec.control_bounds()

    def resid(U):
        return np.where(seen[..., None], marker_points(spec, model, td, mk, links, U) - y, 0.0).reshape(K, -1)

    r = resid(u)
    unseen = np.zeros(n_u, bool)
    for _ in range(TRAVEL_ROUNDS):
        J = np.empty((K, r.shape[1], n_u))
        for j in range(n_u):
            up = u.copy()
            up[:, j] += TRAVEL_STEP
            J[:, :, j] = (resid(up) - r) / TRAVEL_STEP
        unseen = ~(np.where(np.isfinite(J), np.abs(J), 0.0).max(axis=(0, 1)) > 0)  # a failed sample moves none
        J = np.where(np.isfinite(J), J, 0.0)  # a control whose step fails the kinematics moves nothing
        JtJ = np.einsum("kij,kil->kjl", J, J)
        damp = 1e-6 * np.maximum(np.trace(JtJ, axis1=1, axis2=2), 1e-12)[:, None, None] * np.eye(n_u)
        du = -np.linalg.solve(JtJ + damp, np.einsum("kij,ki->kj", J, np.where(np.isfinite(r), r, 0.0))[..., None])[..., 0]
        u = np.clip(u + np.where(np.isfinite(du), du, 0.0), lo, hi)  # a sample the kinematics fails stays put
        r = resid(u)
    miss = np.sqrt(np.sum(r ** 2, axis=1) / np.maximum(seen.sum(axis=1), 1))
    u[(seen.sum(axis=1) < 3) | ~(miss < TRAVEL_MISS_M)] = np.nan
    u[:, unseen] = np.nan
    return u


def actuator_travel(spec: PlatformSpec, model: PlatformModel, td, A, b, mk, Y: np.ndarray, guess_u: np.ndarray, links=None):
    """The actuators' travel (K, n_u) at each sample by inverse kinematics of the pose the markers
    give (Kabsch of the marker layout ``mk`` onto the sample, in the base frame; on a tree, with
    ``links`` each marker's tracked link, :func:`_nearest_travel`); a sample whose pose the inverse
    cannot reach exactly takes the controls whose markers come nearest (:func:`_nearest_travel` on the
    moving frame): a stand of fewer than six degrees of freedom never reaches the pose of noisy
    markers exactly, and without it would have no travel at all; NaN rows where fewer than three
    markers are seen, or that sample misses too (an out-of-reach pose)."""
    K = len(Y)
    out = np.full((K, spec.n_u), np.nan)
    Yb = (Y - b) @ A  # base frame: A^T (y - b)
    if links is not None:
        return _nearest_travel(spec, td, mk, links, Yb, guess_u)
    missed = []
    for k in range(K):
        vis = np.isfinite(Yb[k]).all(axis=1)
        if vis.sum() < 3:
            continue
        R, X = rigid_fit(mk[vis], Yb[k, vis])
        try:
            out[k] = model.inverse(quat_from_matrix(R), X, td, strict=False, guess=guess_u[k])
        except ComputationFailed:  # not reached exactly: the controls nearest, below
            missed.append(k)
    if missed:
        out[missed] = _nearest_travel(spec, td, mk, None, Yb[missed], np.asarray(guess_u, float)[missed], model)
    return out


def response_from_travel(rmodel: ResponseModel, theta0, T, U, t, travel, steps, start=None):
    """The response fitted to the actuators' travel alone: the shift by a grid (each actuator's best,
    their median), then each actuator's least squares (soft L1) with a shift of its own, the shift
    at the median of theirs, and each actuator's again with it held. Actuators that never move
    keep theta0, and so do those whose travel is not seen (a NaN column: a tree's joint that moves no
    marker)."""
    seen = np.isfinite(travel).any(axis=0)
    ok = np.isfinite(travel[:, seen]).all(axis=1)
    t, travel = t[ok], travel[ok]
    if len(t) < 10:
        return np.asarray(theta0, float)
    theta = np.asarray(theta0, float).copy()
    cache: dict = {}
    if rmodel.delays:  # each actuator's own shift first, its delay the excess over their median after
        theta[[rmodel.index("delay_s", j) for j in range(rmodel.n_u)]] = 0.0
    theta[0] = 0.0  # every shift at once: the response at the shifted times
    shifted = (t[None, :] - SHIFT_GRID_S[:, None]).ravel()
    X = actuator_positions(rmodel, theta, T, U, shifted, start=start, cache=cache).reshape(len(SHIFT_GRID_S), len(t), -1)
    # each actuator's best shift, the median over them (a slow actuator's lag is not the clock's)
    moved = (np.ptp(U, axis=0) > 0) & seen
    best = SHIFT_GRID_S[np.argmin(np.sum((X - travel[None]) ** 2, axis=1), axis=0)]
    theta[0] = float(np.median(best[moved])) if moved.any() else 0.0
    lo, hi = _lower_upper(rmodel, theta)
    theta = np.clip(theta, lo + 1e-12, hi - 1e-12)
    shifts = []
    for own_shift in (True, False):  # each actuator with a shift of its own, then all at their median
        for j in range(rmodel.n_u):  # the damping held (the full fit frees it); a delay of its own
            # with the common shift held (the actuator's own shift first, the delay its excess after)
            ks = ([0] if own_shift else []) + [rmodel.index(b, j) for b in rmodel.blocks
                                               if b != "damping" and not (own_shift and b == "delay_s")]
            scale = max(float(np.ptp(travel[:, j])), 1e-9)
            if not moved[j]:
                continue

            def res(x, j=j, ks=ks, scale=scale):
                th = theta.copy()
                th[ks] = x
                return (actuator_positions(rmodel, th, T, U, t, only=j, start=start, cache=cache)
                        - travel[:, j]) / scale

            sol = least_squares(res, theta[ks], bounds=(lo[ks], hi[ks]), loss="soft_l1", f_scale=0.01,
                                x_scale=np.maximum(steps[ks] * 1e3, 1e-6), max_nfev=20)
            if own_shift:
                shifts.append((j, float(sol.x[0])))
                theta[ks[1:]] = sol.x[1:]
            else:
                theta[ks] = sol.x
        if own_shift and shifts:
            theta[0] = float(np.median([x for _, x in shifts]))
            if rmodel.delays:
                for j, x in shifts:
                    theta[rmodel.index("delay_s", j)] = float(np.clip(x - theta[0], -DELAY_MAX_S, DELAY_MAX_S))
    return theta


def starting_theta(model: ResponseModel, spec: PlatformSpec) -> np.ndarray:
    """The response every fit starts from: no shift, every time constant TAU0_S (damping ZETA0), a
    profile's rate and acceleration from the strokes, no delay."""
    span = np.array([c.upper - c.lower for c in spec.controls], float)
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    th = [np.zeros(1), np.full(model.n_u, TAU0_S)]
    if model.kind == "second_order":
        th.append(np.full(sum(model.is_second(j) for j in range(model.n_u)), ZETA0))
    if model.reference == "profile":
        th += [span / STROKE_TIME_S, span / STROKE_TIME_S / ACCEL_TIME_S]
    elif model.rate_limit:  # a streamed drive's rate limit: the caller starts it at the log's speed
        th.append(span / STROKE_TIME_S)
    if model.delays:
        th.append(np.zeros(model.n_u))
    return np.concatenate(th)


def command_speed(T: np.ndarray, U: np.ndarray) -> np.ndarray:
    """(n_u,) the fastest a streamed log asks of each actuator: the largest step over the log's
    median interval (a slewed reference at this rate just reaches each command as the next
    comes); 0 for an actuator never moved."""
    return np.max(np.abs(np.diff(U, axis=0)), axis=0) / float(np.median(np.diff(T)))


def window_speeds(win: StreamWindows) -> np.ndarray:
    """(windows,) how fast the markers move in each window of ``win`` (m/s): each marker
    coordinate fitted by a polynomial of the windows' degree (nodes - 1) in time over the window's
    rows (its nodes, or its samples where kept raw; each row weighted by the samples it stands
    for), the fit's span over the rows' times divided by their duration, the largest over the
    markers and coordinates; NaN where no marker is fitted."""
    out = np.full(len(win.blocks), np.nan)
    ends = [b[0] for b in win.blocks[1:]] + [len(win.t)]
    for w, ((p, _, _, _), end) in enumerate(zip(win.blocks, ends)):
        t = win.t[p:end]
        if end - p < win.nodes or not float(t[-1] - t[0]) > 0:
            continue
        x = 2.0 * (t - t[0]) / float(t[-1] - t[0]) - 1.0
        V = np.vander(x, win.nodes)
        spans = []
        for m in range(win.Y.shape[1]):
            y = win.Y[p:end, m]
            k = np.nonzero(np.isfinite(y).all(axis=1) & (win.n_eff[p:end, m] > 0))[0]
            if len(k) < win.nodes:
                continue
            sw = np.sqrt(win.n_eff[p + k, m])[:, None]
            coef = np.linalg.lstsq(V[k] * sw, y[k] * sw, rcond=None)[0]
            fit = V[k] @ coef
            spans.append(float(np.max(np.ptp(fit, axis=0))))
        if spans:
            out[w] = max(spans) / float(t[-1] - t[0])
    return out


def slowest_rows(win: StreamWindows, share: float = STILL_SHARE) -> np.ndarray:
    """(P,) bool: the rows of ``win`` in its slowest windows (:func:`window_speeds`): those at or
    under the ``share`` quantile of the windows' speeds, all rows where fewer than
    STILL_MIN_WINDOWS windows would serve. Where the stand stands still the controls it reached are
    the command in force whatever its response; where it moves fast a response's error (its timing,
    an actuator's lag) is a control error in proportion to the speed: the registration of the
    markers at a starting response is taken where that response matters least."""
    speed = window_speeds(win)
    ok = np.isfinite(speed)
    if ok.sum() < STILL_MIN_WINDOWS / share:
        return np.ones(len(win.t), bool)
    slow = ok & (speed <= np.quantile(speed[ok], share))
    rows = np.zeros(len(win.t), bool)
    ends = [b[0] for b in win.blocks[1:]] + [len(win.t)]
    for w in np.nonzero(slow)[0]:
        rows[win.blocks[w][0]:ends[w]] = True
    return rows


def response_start(session: Session, spec: PlatformSpec, rmodel: ResponseModel, win: StreamWindows):
    """Step 3: the response's start from the actuators' travel at the nominal geometry, twice (the
    second registration at the controls the first response gives), on START_SAMPLES samples of
    the stream; a profile's actuators rest before the first command where the samples before it
    put them. The registration is taken on the slowest STILL_SHARE of the windows, and on others
    where the travel there reaches too few samples (REACHED_SHARE, OTHER_SHARES). Returns the
    start, the profile's rest (None: on the first command) and the geometry the curvature
    correction is first taken at: (kinematic model, each marker's link, td, A, b, markers)."""
    T, U = session.command_t, session.commands
    theta0 = starting_theta(rmodel, spec)
    if rmodel.slewed:
        speed = command_speed(T, U)
        theta0[[rmodel.index("rate", j) for j in range(spec.n_u)]] = np.where(speed > 0, speed, theta0[
            [rmodel.index("rate", j) for j in range(spec.n_u)]])
    seen = np.isfinite(session.markers).all(axis=2).sum(axis=1) >= 3
    cand = win.first + np.nonzero(seen[win.first:win.end])[0]  # not past the end of a log cut in motion
    sub = cand[np.unique(np.linspace(0, len(cand) - 1, min(len(cand), START_SAMPLES)).astype(int))]
    pre = np.nonzero(seen & (session.marker_t < T[0]))[0][-PRE_SAMPLES:]
    best, tried = None, []
    for share in (STILL_SHARE,) + OTHER_SHARES:
        still = slowest_rows(win, share)
        if any(np.array_equal(still, rows) for rows in tried):
            continue
        tried.append(still)
        got = _start_on(session, spec, rmodel, win, still, theta0, sub, pre)
        if best is None or got[3] > best[3]:
            best = got
        if best[3] >= REACHED_SHARE:
            break
    if best[3] < REACHED_SHARE:
        warn(f"calibration from motion: the response's start read the actuators' travel on {best[3]:.0%} of its "
             f"{len(sub)} samples (under {REACHED_SHARE:.0%} at each of {len(tried)} registrations tried: the markers "
             "far from every pose the stand reaches); the fit starts from "
             + ("that reading" if best[3] > 0 else "the starting response (no shift, time constants "
                f"{TAU0_S * 1e3:g} ms)"))
    return best[:3]


def _start_on(session: Session, spec: PlatformSpec, rmodel: ResponseModel, win: StreamWindows, still: np.ndarray,
              theta0: np.ndarray, sub: np.ndarray, pre: np.ndarray):
    """:func:`response_start`'s rounds with the registration on the rows ``still`` of ``win``, the
    travel on the samples ``sub`` (a profile's rest from the samples ``pre``): the start, the rest,
    the geometry, and the share of ``sub`` its last travel reaches (every actuator seen)."""
    T, U = session.command_t, session.commands
    steps = fd_steps(rmodel, theta0)
    names = list(session.marker_names)
    theta_start, start = theta0, None
    for _ in range(START_ROUNDS):
        X0 = projected_positions(win.proj, rmodel, theta_start, T, U, win.sample_t, start=start)
        poses0 = PoseSet(platform=spec.name, controls=X0[still], markers=win.Y[still], marker_names=names,
                         t=win.t[still], n_samples=win.n_eff[still], length_unit=session.length_unit,
                         source=str(session.folder), moving_link=session.moving_link)
        problem = CalibrationProblem(spec, poses0)
        links = problem.point_links  # a tree: each marker's tracked link
        z = problem.initial_registration(spec.nominal_td())
        _, w, tr, mk, _ = problem.split(z)
        A = matrix_from_rotvec(w)
        Xs = actuator_positions(rmodel, theta_start, T, U, session.marker_t[sub], start=start)
        travel = actuator_travel(spec, problem.model, spec.nominal_td(), A, tr, mk, session.markers[sub], Xs, links)
        if rmodel.reference == "profile" and len(pre):
            before = actuator_travel(spec, problem.model, spec.nominal_td(), A, tr, mk, session.markers[pre],
                                     np.repeat(U[:1], len(pre), axis=0), links)
            cols = np.isfinite(before).any(axis=0)  # a joint that moves no marker rests at its first command
            if cols.any() and np.isfinite(before[:, cols]).all(axis=1).any():
                start = np.where(cols, np.nanmedian(np.where(cols, before, 0.0), axis=0), U[0])
        theta_start = response_from_travel(rmodel, theta_start, T, U, session.marker_t[sub], travel, steps, start)
    cols = np.isfinite(travel).any(axis=0)
    reached = float(np.mean(np.isfinite(travel[:, cols]).all(axis=1))) if cols.any() and len(travel) else 0.0
    return theta_start, start, (problem.model, links, spec.nominal_td(), A, tr, mk), reached


def travel_start(session: Session, spec: PlatformSpec, rmodel: ResponseModel, theta0: np.ndarray, fitted,
                 win: StreamWindows, start=None) -> np.ndarray:
    """``rmodel``'s response started from the actuators' travel at a fit (:func:`response_from_travel`
    from ``theta0``, each damping held at its start): ``fitted`` = (kinematic model, each marker's
    link, td, A, b, markers, the fit's response model, its theta) gives the geometry the travel is
    taken at (inverse kinematics of START_SAMPLES samples of the stream) and the controls its
    inverse kinematics starts from."""
    model, links, td, A, b, mk, fit_model, fit_theta = fitted
    T, U = session.command_t, session.commands
    seen = np.isfinite(session.markers).all(axis=2).sum(axis=1) >= 3
    cand = win.first + np.nonzero(seen[win.first:win.end])[0]  # not past the end of a log cut in motion
    sub = cand[np.unique(np.linspace(0, len(cand) - 1, min(len(cand), START_SAMPLES)).astype(int))]
    t = session.marker_t[sub]
    guess = actuator_positions(fit_model, fit_theta, T, U, t, start=start)
    travel = actuator_travel(spec, model, td, A, b, mk, session.markers[sub], guess, links)
    return response_from_travel(rmodel, theta0, T, U, t, travel, fd_steps(rmodel, theta0), start)


def fd_steps(rmodel: ResponseModel, theta: np.ndarray) -> np.ndarray:
    """Finite-difference steps: 1e-4 s for the shift and the delays, 1e-4 relative for the rest."""
    h = 1e-4 * np.maximum(np.abs(np.asarray(theta, float)), 1e-2)
    h[0] = 1e-4
    if rmodel.delays:
        h[[rmodel.index("delay_s", j) for j in range(rmodel.n_u)]] = 1e-4
    return h
