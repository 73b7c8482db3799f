"""Calibration from motion: every motion-capture sample as data, through the actuators' response.

Where a session's holds do not settle, or it has none (a stand streaming a path), each sample
of the stream is an observation: the markers follow the stand's pose at the controls its
actuators had reached at that instant, from the command log through a per-actuator response
(:mod:`platkit.calibrate.response`: a step or rate/acceleration-limited profile reference, a
first- or second-order response, one time shift for the clock offset and common delay). The
response is a :class:`~platkit.terms.ModelTerm` whose control offset is the reached controls
minus the starting ones, so geometry, markers, frame and response are one sparse least-squares
problem of :func:`platkit.calibrate.estimate.calibrate`: the same exact Jacobians (CasADi) for
the geometry, the same robust loss and outlier rule, the same identifiability (a response the
data cannot tell from the geometry is held at its start and said). The response's own columns
are forward differences per actuator (each parameter moves one actuator, or all for the shift).

Procedure (:func:`calibrate_motion`):
1. checks: markers and at least three commands, on two clocks that overlap (BadSession naming
   commands.csv); after the fit (4.), markers off by more than MISFIT_RATIO times their own
   noise say that the log does not explain the motion (commands missing: a log sparser than the
   motion, or another recording's), BadSession naming commands.csv;
2. the samples: every sample from the second command on (the stand's place before the first is
   not logged), reduced without losing what they say of the geometry (:func:`stream_windows`):
   the stream is cut into windows of about WINDOW_S s; in each, every marker coordinate is fitted
   by a polynomial of degree NODES - 1 in time and kept as its values at the window's NODES
   Gauss-Legendre nodes, each weighted by the samples it stands for (at those nodes the values
   are uncorrelated and their weights sum to the window's samples: the low-frequency content is
   kept whole); the model of a node is the stand at the same windowed fit of the controls
   reached (the response at every sample, projected alike), and the markers are corrected for
   the kinematics' curvature (the fit of g(u) minus g at the fit of u, g the markers of the
   controls, at the start's geometry: exact to first order in the model's error). The response's
   timing shows in the fast content (each command's step response), which the fit leaves out:
   whole windows, evenly spread, about RAW_SAMPLES samples in all (all of a short stream), are
   kept as their samples;
3. the response's start (:mod:`platkit.calibrate.motion_start`): the markers registered at the
   commanded controls (rigid alignment),
   each sample's pose by Kabsch, the actuators' travel by inverse kinematics at the nominal
   geometry, and the response fitted to that travel alone (a grid over the shift, then
   least squares): an actuator that moved too little to show its response keeps the start;
4. the full fit with :func:`calibrate` and the response as a term; the term leaves the
   calibration afterwards (calibration.yaml keeps it as ``actuator_response``; prediction of
   settled poses needs no response);
5. the curvature correction taken again at the fit (stand, frame, markers, response) and the fit
   repeated from it while the correction moves the nodes by more than CORRECTION_SHARE of their
   own noise (at most CORRECTION_REFITS times): taken at the start, its error is first order in
   the start's, which on a fast stream exceeds the nodes' noise.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy import sparse

from platkit.calibrate.estimate import calibrate, marker_noise_floor
from platkit.calibrate.motion_start import actuator_travel, marker_points, response_from_travel
from platkit.calibrate.problem import CalibrationProblem, Progress
from platkit.calibrate.response import ResponseModel, actuator_positions, lags
from platkit.calibrate.stream import (
    MIN_SEEN_SHARE,
    NODES,
    RAW_SAMPLES,
    WINDOW_S,
    StreamWindows,
    check_motion_session,
    projected_positions,
    stream_windows,
)
from platkit.errors import BadSession, NotIdentifiable
from platkit.geometry import matrix_from_rotvec
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["LocalResponseTerm", "ResponseTerm", "calibrate_motion", "command_speed", "motion_poses", "motion_stream",
           "without_response"]

#: windows per block of the curvature correction
CORRECTION_BLOCK = 32
#: samples that start the response; rounds of the start; samples before the first command that
#: say where a profile's actuators rest
START_SAMPLES, START_ROUNDS, PRE_SAMPLES = 600, 2, 50
#: starting response: time constant (s), damping; a profile's rate and acceleration from the
#: stroke (a full stroke in STROKE_TIME_S, the rate reached in ACCEL_TIME_S)
TAU0_S, ZETA0, STROKE_TIME_S, ACCEL_TIME_S = 0.05, 1.0, 4.0, 0.25
#: a fit whose RMS is this many times the markers' own 3-D noise (from the distances between
#: them) does not describe the stream: the command log does not say where the stand was sent
MISFIT_RATIO = 5.0
#: the fit takes the Jacobian this many nodes at a time (normal equations summed over the blocks:
#: the memory of one block however long the stream)
ROW_BLOCK = 32
#: the curvature correction (step 2) is taken at the start's geometry and response, exact to first
#: order in their error; on a fast stream that error can exceed the nodes' own noise (the fit then
#: rejects them as outliers and leans on the raw samples). After the fit it is taken again at the
#: fit, and the fit repeated, while it moves the nodes by more than CORRECTION_SHARE of their own
#: noise (RMS over the nodes' coordinates, each in units of the fit's noise over the root of the
#: samples it stands for), at most CORRECTION_REFITS times
CORRECTION_SHARE, CORRECTION_REFITS = 0.5, 2


class ResponseTerm(ModelTerm):
    """The actuators' response as a model term: control offset = the controls reached at each
    pose minus ``poses.controls``. The controls reached are those at ``poses.t`` (motion-capture
    clock) or, with ``proj`` (a stream reduced to nodes, :class:`StreamWindows`), the same
    windowed fit of the controls reached at every sample (``sample_t``) that the markers had,
    at the nodes ``poses.extras['node']``; with ``proj``, poses without nodes are not the stream's
    (settled poses, a held-out session): no offset there."""

    uses_kinematics = False  # its offsets read the controls and times alone

    def __init__(self, model: ResponseModel, T: np.ndarray, U: np.ndarray, control_names: list[str],
                 theta0: np.ndarray, steps: np.ndarray, start: np.ndarray | None = None,
                 proj: sparse.csr_matrix | None = None, sample_t: np.ndarray | None = None):
        units = []
        for name in model.names(control_names):
            block = name.split(".")[0]
            units.append({"shift_s": "s", "tau_s": "s", "damping": "1", "rate": "unit/s",
                          "accel": "unit/s^2", "delay_s": "s"}[block])
        super().__init__("actuator_response", model.names(control_names), np.asarray(theta0, float).copy(), units,
                         {"kind": model.kind, "reference": model.reference})
        self.model, self.T, self.U, self.steps, self.start = model, T, U, np.asarray(steps, float), start
        self.proj, self.sample_t = proj, sample_t
        self._cache: tuple | None = None
        # actuator_positions' cache of this log: a profile's (or a slewed step's) reference and
        # response on the fine grid; a plain step reference keeps none (what it would keep, each
        # sample's command, is an array over the samples per shift tried, quickly found again)
        self._positions: dict | None = {} if model.reference == "profile" or model.slewed else None

    def _at(self, theta, poses: PoseSet, only: int | None = None) -> np.ndarray:
        """The controls reached under ``theta`` at the poses (K, n_u), or actuator ``only``'s (K,)."""
        if self.proj is None:
            return actuator_positions(self.model, theta, self.T, self.U, poses.t, only=only, start=self.start,
                                      cache=self._positions)
        x = projected_positions(self.proj, self.model, theta, self.T, self.U, self.sample_t, only=only,
                                start=self.start, cache=self._positions)
        node = poses.extras.get("node")
        return x if node is None or (len(node) == len(x) and np.array_equal(node, np.arange(len(x)))) else x[node]

    def control_offset(self, theta, poses: PoseSet, n_u: int) -> np.ndarray:
        if self.proj is not None and "node" not in poses.extras:  # not the stream's nodes: settled, no response
            return np.zeros_like(poses.controls)
        return self.reached(theta, poses) - poses.controls

    def reached(self, theta, poses: PoseSet) -> np.ndarray:
        key = (np.asarray(theta, float).tobytes(), id(poses.t), len(poses.t))
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        x = self._at(theta, poses)
        self._cache = (key, x)
        return x

    def offset_jacobians(self, theta, poses: PoseSet, n_u: int, fk_q, fk_X):
        theta = np.asarray(theta, float)
        if self.proj is not None and "node" not in poses.extras:
            return np.zeros((poses.n_poses, n_u, len(theta))), None, None
        # no pose or marker offset: no arrays of zeros
        d_u = self._differences(theta, self.reached(theta, poses), lambda th, j: self._at(th, poses, j))
        return d_u, None, None

    def _differences(self, theta: np.ndarray, base: np.ndarray, at) -> np.ndarray:
        """(P, n_u, K) the controls reached ``base`` (P, n_u) differentiated by forward differences:
        one evaluation per parameter, of its actuator alone (``at(theta, j)``: actuator j's (P,),
        or with j None every actuator's (P, n_u), for the shift)."""
        d = np.zeros(base.shape + (len(theta),))
        for k in range(len(theta)):
            h = self.steps[k]
            up = theta.copy()
            up[k] += h
            j = self.model.actuator_of(k)
            if j is None:
                d[:, :, k] = (at(up, None) - base) / h
            else:
                d[:, j, k] = (at(up, j) - base[:, j]) / h
        return d


#: the Jacobian of :class:`LocalResponseTerm` is taken again where the response's change since it
#: was taken departs from its linear prediction by more than LINEAR_SHARE of that change plus
#: LINEAR_FLOOR (controls' internal units, max over nodes and actuators)
LINEAR_SHARE, LINEAR_FLOOR = 0.1, 1e-7


class LocalResponseTerm(ResponseTerm):
    """The response of a stream reduced to nodes (``proj`` given), as a diagnosis frees it: its
    control offset exact (:class:`ResponseTerm`'s), its Jacobian kept while the response stays
    linear. The Jacobian D (forward differences per actuator, as ResponseTerm's) is taken at some
    theta_J and reused at theta while the controls reached there, X(theta), differ from
    X(theta_J) + D (theta - theta_J) by at most LINEAR_SHARE of X(theta) - X(theta_J) plus
    LINEAR_FLOOR; it is taken again at theta otherwise. A fit thus converges to the exact
    response's optimum (its residuals are exact) with the Jacobian of a nearby theta, which
    differs from the exact one by at most that share. Positions and derivatives are of every node,
    a subset of the nodes reads its rows; poses without nodes are not the stream's (settled poses,
    a held-out session): no offset there."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._jac: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (theta_J, X(theta_J), D)

    def _nodes(self, theta) -> np.ndarray:
        """The controls reached at every node under ``theta`` (P, n_u), the last kept."""
        key = np.asarray(theta, float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        x = projected_positions(self.proj, self.model, theta, self.T, self.U, self.sample_t, start=self.start,
                                cache=self._positions)
        self._cache = (key, x)
        return x

    def reached(self, theta, poses: PoseSet) -> np.ndarray:
        return self._nodes(theta)[np.asarray(poses.extras["node"])]

    def offset_jacobians(self, theta, poses: PoseSet, n_u: int, fk_q, fk_X):
        theta = np.asarray(theta, float)
        if "node" not in poses.extras:
            return np.zeros((poses.n_poses, n_u, len(theta))), None, None
        x = self._nodes(theta).copy()
        if self._jac is not None:
            th_j, x_j, d = self._jac
            miss = np.abs(x - x_j - d @ (theta - th_j)).max()
            if miss <= LINEAR_SHARE * np.abs(x - x_j).max() + LINEAR_FLOOR:
                return d[np.asarray(poses.extras["node"])], None, None
        d = self._differences(theta, x, lambda th, j: projected_positions(
            self.proj, self.model, th, self.T, self.U, self.sample_t, only=j, start=self.start, cache=self._positions))
        self._jac = (theta.copy(), x, d)
        return d[np.asarray(poses.extras["node"])], None, None


def _starting_theta(model: ResponseModel, spec: PlatformSpec) -> np.ndarray:
    span = np.array([c.upper - c.lower for c in spec.controls], float)
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    th = [np.zeros(1), np.full(model.n_u, TAU0_S)]
    if model.kind == "second_order":
        th.append(np.full(model.n_u, ZETA0))
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



def _curvature_correction(spec: PlatformSpec, model: PlatformModel, td, A, b, mk, win: StreamWindows,
                          X_nodes: np.ndarray, reached, links=None) -> np.ndarray:
    """(P, M, 3) what the windowed fit of the markers differs, under the model (stand ``td``,
    frame A, b, markers ``mk``), from the markers at the windowed fit of the controls: the fit of
    g(u(t)) at the nodes minus g(fit of u at the nodes), g the markers of the controls (nonlinear).
    Subtracted from the fitted markers, it leaves the model of the nodes g(fit of u) exact to
    first order in the model's own error. Evaluated CORRECTION_BLOCK windows at a time, ``reached(a,
    b)`` the controls reached at samples a to b of ``win.sample_t``; 0 where the kinematics fails.
    On a tree (``links``: each marker's tracked link) each marker moves with its own link."""
    M = len(mk)
    out = np.zeros((len(win.t), M, 3))

    def markers(U):
        return marker_points(spec, model, td, mk, links, U) @ A.T + b

    g_nodes = markers(X_nodes)
    for s in range(0, len(win.blocks), CORRECTION_BLOCK):
        chunk = win.blocks[s:s + CORRECTION_BLOCK]
        a0 = chunk[0][1] - win.first
        a1 = chunk[-1][1] + chunk[-1][2] - win.first
        g = markers(reached(a0, a1))
        for p, a, n, per in chunk:
            if per is None:  # a raw window: its samples are the model's own
                continue
            gw = g[a - win.first - a0:a - win.first - a0 + n]
            for m, (k, Am) in per.items():
                if Am is None:  # the window's own fit, read from its rows of proj (each of n samples)
                    Am = win.proj.data[win.proj.indptr[p]:win.proj.indptr[p + win.nodes]].reshape(win.nodes, n)
                fit = Am @ (gw[:, m] if k is None else gw[k, m])
                out[p:p + win.nodes, m] = fit - g_nodes[p:p + win.nodes, m]
    return np.nan_to_num(out)


def calibrate_motion(session: Session, spec: PlatformSpec, *, kind: str = "second_order", free=None,
                     robust: bool = True, window_s: float = WINDOW_S, nodes: int = NODES,
                     raw_samples: int = RAW_SAMPLES, progress: Progress | None = None,
                     platform_options: dict | None = None, ridge_m: float = 0.0,
                     reason: str = "", delays: bool = False, rate_limit: bool = False) -> tuple[Calibration, PoseSet]:
    """Calibrate ``spec`` from the whole stream of ``session`` (module docstring). Returns the
    calibration (its ``motion`` says which samples served, how they were reduced, and the fitted
    response with its uncertainty) and the pose set of the nodes fitted. ``reason``: why the
    motion model serves (said in the report). ``delays``: each actuator's own pure delay beyond
    the shift; ``rate_limit``: a streamed log's actuators each with a speed limit, started at the
    log's fastest step (a profile has its rate limit always) (platkit.calibrate.response)."""
    t0 = time.perf_counter()
    reference = check_motion_session(session)
    rmodel = ResponseModel(kind, reference, spec.n_u, delays, rate_limit)
    win = stream_windows(session, window_s, nodes, raw_samples)
    if len(win.t) < 20:
        raise BadSession(f"{session.markers_source}: only {len(win.t)} poses from the samples with markers seen "
                         "after the second command; calibrating from motion needs the stand moving under the markers")
    T, U = session.command_t, session.commands
    t = win.t
    theta0 = _starting_theta(rmodel, spec)
    if rmodel.slewed:
        speed = command_speed(T, U)
        theta0[[rmodel.index("rate", j) for j in range(spec.n_u)]] = np.where(speed > 0, speed, theta0[
            [rmodel.index("rate", j) for j in range(spec.n_u)]])
    steps = _steps(rmodel, theta0)
    names = list(session.marker_names)
    # 3. the response's start from the actuators' travel at the nominal geometry, twice (the
    # second registration at the controls the first response gives), on START_SAMPLES samples of
    # the stream; a profile's actuators rest before the first command where the samples before
    # it put them
    theta_start, start = theta0, None
    seen = np.isfinite(session.markers).all(axis=2).sum(axis=1) >= 3
    cand = win.first + np.nonzero(seen[win.first:])[0]
    sub = cand[np.unique(np.linspace(0, len(cand) - 1, min(len(cand), START_SAMPLES)).astype(int))]
    pre = np.nonzero(seen & (session.marker_t < T[0]))[0][-PRE_SAMPLES:]
    for _ in range(START_ROUNDS):
        X0 = projected_positions(win.proj, rmodel, theta_start, T, U, win.sample_t, start=start)
        poses0 = PoseSet(platform=spec.name, controls=X0, markers=win.Y, marker_names=names, t=t,
                         n_samples=win.n_eff, length_unit=session.length_unit, source=str(session.folder),
                         moving_link=session.moving_link)
        problem = CalibrationProblem(spec, poses0)
        links = problem.point_links  # a tree: each marker's tracked link
        z = problem.initial_registration(spec.nominal_td())
        _, w, tr, mk, _ = problem.split(z)
        A = matrix_from_rotvec(w)
        Xs = actuator_positions(rmodel, theta_start, T, U, session.marker_t[sub], start=start)
        travel = actuator_travel(spec, problem.model, spec.nominal_td(), A, tr, mk, session.markers[sub], Xs, links)
        if reference == "profile" and len(pre):
            before = actuator_travel(spec, problem.model, spec.nominal_td(), A, tr, mk, session.markers[pre],
                             np.repeat(U[:1], len(pre), axis=0), links)
            cols = np.isfinite(before).any(axis=0)  # a joint that moves no marker rests at its first command
            if cols.any() and np.isfinite(before[:, cols]).all(axis=1).any():
                start = np.where(cols, np.nanmedian(np.where(cols, before, 0.0), axis=0), U[0])
        theta_start = response_from_travel(rmodel, theta_start, T, U, session.marker_t[sub], travel, steps, start)
    steps = _steps(rmodel, theta_start)
    # 4. the nodes' markers corrected for the kinematics' curvature at the start, and the full fit
    X1 = projected_positions(win.proj, rmodel, theta_start, T, U, win.sample_t, start=start)
    correction = _curvature_correction(spec, problem.model, spec.nominal_td(), A, tr, mk, win, X1, lambda a, b: (
        actuator_positions(rmodel, theta_start, T, U, win.sample_t[a:b], start=start)), links)
    term = ResponseTerm(rmodel, T, U, list(spec.control_names), theta_start, steps, start, win.proj, win.sample_t)
    poses = PoseSet(platform=spec.name, controls=X1, markers=win.Y - correction, marker_names=names, t=t,
                    n_samples=win.n_eff,
                    description=None if session.description is None else str(session.description),
                    length_unit=session.length_unit, moving_link=session.moving_link, source=str(session.folder),
                    extras={"node": np.arange(len(t)), "elapsed": t - t[0]})
    cal = calibrate(poses, spec, terms=[term], free=free, robust=robust, progress=progress,
                    platform_options=platform_options, ridge_m=ridge_m, row_block=ROW_BLOCK)
    floor = np.sqrt(3) * marker_noise_floor(poses)
    if np.isfinite(floor) and floor > 0 and cal.rms_after > MISFIT_RATIO * floor:
        raise BadSession(f"{session.folder / 'commands.csv'}: the command log does not explain the motion in "
                         f"{session.markers_source}: after the fit the markers are off by {1e3 * cal.rms_after:.3g} mm "
                         f"RMS, {cal.rms_after / floor:.0f} times their own noise: commands are missing (a log "
                         "sparser than the motion) or the log is another recording's")
    # 5. the correction taken again at the fit (stand, frame, markers, response) while it moves the
    # nodes by more than CORRECTION_SHARE of their own noise, and the fit repeated from there
    rms_before = cal.rms_before  # at the nominal geometry, as a fit from settled poses says it
    for _ in range(CORRECTION_REFITS):
        theta = np.asarray(cal.theta[0], float)
        X2 = projected_positions(win.proj, rmodel, theta, T, U, win.sample_t, start=start)
        again = _curvature_correction(spec, problem.model, cal.td, matrix_from_rotvec(cal.mocap_rotvec),
                                      cal.mocap_translation, cal.marker_positions, win, X2, lambda a, b, th=theta: (
                                          actuator_positions(rmodel, th, T, U, win.sample_t[a:b], start=start)), links)
        node = win.n_eff > 1.0  # the windows' nodes (a raw sample has no correction)
        moved = (again - correction)[node] * np.sqrt(win.n_eff[node])[:, None] / cal.noise_sigma
        if not (np.isfinite(cal.noise_sigma) and cal.noise_sigma > 0 and moved.size
                and np.sqrt(np.mean(moved ** 2)) > CORRECTION_SHARE):
            break
        correction = again
        term = ResponseTerm(rmodel, T, U, list(spec.control_names), theta, _steps(rmodel, theta), start, win.proj,
                            win.sample_t)
        poses = replace(poses, controls=X2, markers=win.Y - correction)
        cal = calibrate(poses, spec, terms=[term], free=free, robust=robust, progress=progress,
                        platform_options=platform_options, ridge_m=ridge_m, row_block=ROW_BLOCK, td_start=cal.td)
        cal.rms_before = rms_before
    held = [h["name"] for h in cal.identifiability.get("held_at_nominal", [])]
    cal.motion = {
        "used": "motion",
        "why": reason or "calibrated from the whole stream",
        "response": _response_report(rmodel, spec, cal, held, T, U, kind, reference),
        "samples": {"n_stream": win.n_stream, "n_used": win.n_used, "n_kept_raw": win.n_raw, "n_unseen": win.n_unseen,
                    "n_before_second_command": win.n_before, "n_in_short_windows": win.n_short,
                    "n_marker_observations_left_out": win.n_left_out,
                    "n_windows": win.n_windows, "n_raw_windows": win.n_raw_windows, "window_s": win.window_s,
                    "n_fitted": int(len(t)), "n_fitted_rejected_as_outliers": int(cal.n_rejected),
                    "rule": f"every sample from the second command on, in windows of {win.window_s:.3g} s; in each, "
                            f"every marker coordinate fitted by a polynomial of degree {win.nodes - 1} in time and "
                            f"kept at {win.nodes} Gauss-Legendre nodes, weighted by the samples it stands for (a "
                            f"marker seen in under {MIN_SEEN_SHARE:.0%} of a window's samples left out there); "
                            f"{win.n_raw_windows} whole windows evenly spread ({win.n_raw} samples) kept as they are"},
        "held": [n for n in held if n.startswith("term.actuator_response.")],
        "time_s": time.perf_counter() - t0,
    }
    cal.terms, cal.theta, cal.theta_std = [], [], []  # settled poses need no response
    if progress is not None:
        progress("motion", {"response": cal.motion["response"]})
    if not np.isfinite(cal.rms_after):
        raise NotIdentifiable(f"{session.folder}: the motion model did not fit the stream")
    return cal, poses


def motion_poses(session: Session, cal: Calibration) -> PoseSet:
    """:func:`motion_stream`'s poses alone (the response held as calibrated)."""
    return motion_stream(session, cal)[0]


def motion_stream(session: Session, cal: Calibration) -> tuple[PoseSet, LocalResponseTerm]:
    """The poses a calibration from motion (``cal``: its ``motion``, calibration.yaml's
    ``actuator_response``) sees in ``session``'s stream: the stream's windows as calibrate_motion
    cuts them, every window reduced to its nodes (none kept as raw samples: those served the
    response's timing, held here), each node at the controls the calibrated response reached there and its markers
    corrected for the kinematics' curvature at the calibration's geometry, frame and markers; the
    response held as calibrated. What a diagnosis of a stream without holds reads in place of
    settled poses. A profile reference's actuators rest on the first command before it (the rest
    calibrate_motion read from the samples before it is not kept). Returns the poses and the
    response as a term at the calibration's values (its control offset zero there), which a fit
    that carries it frees again, as calibrate_motion did (:class:`LocalResponseTerm`: the same
    response, its Jacobian reused while the response stays linear)."""
    r = (cal.motion or {}).get("response")
    if not isinstance(r, dict) or not isinstance(r.get("actuators"), dict):
        raise BadSession(f"{session.folder}: the calibration was not fitted from motion (no actuator_response): a "
                         "stream without settled holds is read through the response calibrate fitted to it")
    spec = cal.spec
    rmodel = ResponseModel(r["kind"], r["reference"], spec.n_u, bool(r.get("delays")),
                           bool(r.get("rate_limit")) and r["reference"] == "step")
    theta = np.zeros(rmodel.size)
    theta[0] = float(r["shift_s"]["value"])
    for j, c in enumerate(spec.control_names):
        if c not in r["actuators"]:
            raise BadSession(f"{session.folder}: the calibration's actuator_response has no actuator {c!r}")
        for blk in rmodel.blocks:
            theta[rmodel.index(blk, j)] = float(r["actuators"][c][blk]["value"])
    check_motion_session(session)
    win = stream_windows(session, raw_samples=0)
    T, U = session.command_t, session.commands
    X = projected_positions(win.proj, rmodel, theta, T, U, win.sample_t)
    names = list(session.marker_names)
    poses = PoseSet(platform=spec.name, controls=X, markers=win.Y, marker_names=names, t=win.t,
                    n_samples=win.n_eff,
                    description=None if session.description is None else str(session.description),
                    length_unit=session.length_unit, moving_link=session.moving_link, source=str(session.folder),
                    extras={"node": np.arange(len(win.t)), "elapsed": win.t - win.t[0]})
    problem = CalibrationProblem(spec, poses)
    order = [cal.marker_names.index(n) for n in names if n in cal.marker_names]
    if len(order) != len(names):
        raise BadSession(f"{session.folder}: markers {sorted(set(names) - set(cal.marker_names))} are not the "
                         "calibration's")
    correction = _curvature_correction(spec, problem.model, cal.td, matrix_from_rotvec(cal.mocap_rotvec),
                                       cal.mocap_translation, cal.marker_positions[order], win, X, lambda a, b: (
                                           actuator_positions(rmodel, theta, T, U, win.sample_t[a:b])),
                                       problem.point_links)
    poses.markers = win.Y - correction
    return poses, LocalResponseTerm(rmodel, T, U, list(spec.control_names), theta, _steps(rmodel, theta), None,
                                    win.proj, win.sample_t)


def without_response(cal: Calibration, session: Session) -> Calibration:
    """``cal`` (a fit that carried :func:`motion_stream`'s response as a term) with the response
    out of its terms and in its ``motion`` (calibration.yaml's ``actuator_response``) at the
    values fitted, as calibrate_motion leaves its own: settled poses need no response. ``cal``
    itself where it carries none."""
    k = next((i for i, t in enumerate(cal.terms) if isinstance(t, ResponseTerm)), None)
    if k is None:
        return cal
    term = cal.terms[k]
    held = [h["name"] for h in cal.identifiability.get("held_at_nominal", [])]
    one = replace(cal, terms=[term], theta=[cal.theta[k]], theta_std=[cal.theta_std[k]])
    response = _response_report(term.model, cal.spec, one, held,
                                session.command_t, session.commands, term.model.kind, term.model.reference)
    keep = [i for i in range(len(cal.terms)) if i != k]
    return replace(cal, terms=[cal.terms[i] for i in keep], theta=[cal.theta[i] for i in keep],
                   theta_std=[cal.theta_std[i] for i in keep], motion={**(cal.motion or {}), "response": response})


def _response_report(rmodel: ResponseModel, spec: PlatformSpec, cal: Calibration, held: list[str], T: np.ndarray,
                     U: np.ndarray, kind: str, reference: str) -> dict:
    """The fitted response as the report gives it: per actuator each parameter with its std or
    'held_at_start' (held by identifiability), a delay's lag (what the markers fix), a streamed
    rate limit's share of the log's steps it cuts ('does_not_bind' where none); the shift."""
    theta, theta_std = np.asarray(cal.theta[0], float), np.asarray(cal.theta_std[0], float)
    par = rmodel.split(theta)
    sd = rmodel.split(np.where(np.isfinite(theta_std), theta_std, np.nan))
    per = {}
    for j, c in enumerate(spec.control_names):
        entry = {}
        for blk in rmodel.blocks:
            name = f"{blk}.{c}"
            held_here = f"term.actuator_response.{name}" in held
            entry[blk] = {"value": float(par[blk][j]), "std": None if held_here or not np.isfinite(sd[blk][j])
                          else float(sd[blk][j]), "status": "held_at_start" if held_here else "estimated"}
        if rmodel.delays:
            entry["lag_s"] = {"value": float(lags(rmodel, theta)[j]), "note": "shift + delay_s: what the markers fix"}
        if rmodel.slewed:  # a limit above every step the log asks is not seen: a lower bound, said so
            need = np.abs(np.diff(U[:, j])) / np.diff(T)
            entry["rate"]["binds_share"] = float(np.mean(need > par["rate"][j])) if len(need) else 0.0
            if entry["rate"]["binds_share"] == 0:
                entry["rate"].update(status="does_not_bind", std=None, note=(
                    f"above the log's fastest step over its interval ({float(need.max()) if len(need) else 0.0:.4g} "
                    "per s): the limit is not seen"))
        per[c] = entry
    shift_held = "term.actuator_response.shift_s" in held
    shift = {"value": float(par["shift_s"]), "std": None if shift_held or not np.isfinite(sd["shift_s"])
             else float(sd["shift_s"]), "status": "held_at_start" if shift_held else "estimated",
             "note": "the motion capture's clock minus the commands', with the stand's common delay"}
    return {"kind": kind, "reference": reference,
            "units": "s for times; controls' internal units (m for length controls) per s for rates",
            "delays": bool(rmodel.delays), "rate_limit": bool(rmodel.reference == "profile" or rmodel.slewed),
            "shift_s": shift, "actuators": per}


def _steps(rmodel: ResponseModel, theta: np.ndarray) -> np.ndarray:
    """Finite-difference steps: 1e-4 s for the shift and the delays, 1e-4 relative for the rest."""
    h = 1e-4 * np.maximum(np.abs(np.asarray(theta, float)), 1e-2)
    h[0] = 1e-4
    if rmodel.delays:
        h[[rmodel.index("delay_s", j) for j in range(rmodel.n_u)]] = 1e-4
    return h
