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
   commands.csv); after the fit kept (4.-6.), markers off by more than MISFIT_RATIO times their own
   noise (on a tree, and by more than MISFIT_ABSOLUTE_M) say that the log does not explain the
   motion (commands missing: a log sparser than the motion, or another recording's),
   MotionUnexplained (a BadSession) naming commands.csv;
2. the samples: every sample from the second command on (the stand's place before the first is
   not logged) up to the end of a command log cut in motion, the set fixed at the response's
   start (3.) (:mod:`platkit.calibrate.motion_log_end`), reduced without losing what they say of
   the geometry (:func:`stream_windows`):
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
   starting response's controls (rigid alignment) on the stream's slowest windows (there the
   controls reached are the command in force whatever the response), each sample's pose by
   Kabsch, the actuators' travel by inverse kinematics at the nominal geometry, and the response
   fitted to that travel alone (a grid over the shift, then least squares): an actuator that
   moved too little to show its response keeps the start; then the first command's transient
   left out (:mod:`platkit.calibrate.motion_transient`: the stand's state before the first
   command is not logged, so the samples from the second command on whose residuals are gross
   at the start, and those after until that bound has decayed to the markers' noise at the
   slowest response, do not drive the fit; counted and said);
4. the full fit with :func:`calibrate` and the response as a term; the term leaves the
   calibration afterwards (calibration.yaml keeps it as ``actuator_response``; prediction of
   settled poses needs no response);
5. the curvature correction taken again at the fit (stand, frame, markers, response) and the fit
   repeated from it while the correction moves the nodes by more than CORRECTION_SHARE of their
   own noise (at most CORRECTION_REFITS times): taken at the start, its error is first order in
   the start's, which on a fast stream exceeds the nodes' noise;
6. the response's kind (unless the caller names it): 3-5 run with the first order, the second
   order tried from that fit and kept per actuator where the data determine it and at all where
   the whole fit's information criterion says so and the fast content is not lost
   (:mod:`platkit.calibrate.motion_kind`); an actuator whose fitted response is degenerate is
   said (report and warning). The second order is fitted from two starts that keep the first
   order's lag, the fit of lower information criterion kept: its time constants halved at the
   first order's shift, and the shift and time constants taken again from the actuators' travel
   at the first order's fit (:func:`~platkit.calibrate.motion_start.travel_start`): a first
   order's shift takes the second order's apparent dead time, and from the first start
   alone the fit can stop at an overdamped optimum that keeps it.
"""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy import sparse

from platkit.calibrate.estimate import MISFIT_ABSOLUTE_M, calibrate, marker_noise_floor
from platkit.calibrate.motion_bodies import bodies_at_samples, say_bodies
from platkit.calibrate.motion_kind import (
    DAMPING_MAX,
    Z_DETERMINED,
    fast_content,
    fit_progress,
    held_names,
    information,
    kind_verdict,
    known_samples,
    response_from_report,
    response_report,
    second_order_kept,
    theta_by_name,
)
from platkit.calibrate.motion_log_end import RULE, log_end_at, say_past_log
from platkit.calibrate.motion_start import TAU0_S, ZETA0, fd_steps, marker_points, response_start, travel_start
from platkit.calibrate.motion_transient import say_transient, start_transient
from platkit.calibrate.problem import CalibrationProblem, Progress
from platkit.calibrate.response import KINDS, TAU_MIN_S, ResponseModel, actuator_positions, lags
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
from platkit.errors import BadInput, BadSession, NotIdentifiable
from platkit.geometry import matrix_from_rotvec
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["LocalResponseTerm", "MotionUnexplained", "ResponseTerm", "calibrate_motion",
           "motion_poses", "motion_stream", "without_response"]


class MotionUnexplained(BadSession):
    """The fitted motion model leaves the markers off by more than the misfit rule allows: the
    command log does not explain the stream (or the model did not find the stand)."""

#: windows per block of the curvature correction
CORRECTION_BLOCK = 32
#: a fit whose RMS is this many times the markers' own 3-D noise (from the distances between
#: markers on one link) does not describe the stream: the command log does not say where the stand
#: was sent (on a tree, only above MISFIT_ABSOLUTE_M besides: unmodelled sag is not a wrong log)
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
    physical_misfit = True  # the actuators lag one another: a cable robot's rows miss while it moves

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
        # actuator_positions' cache of this log: a profile's (or a slewed step's) reference as
        # pieces and the response's state at each; a plain step reference keeps none (what it would keep, each
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
        self.start_transient: dict | None = None  # motion_stream's: the first command's transient left out
        self.past_the_log: dict | None = None  # motion_stream's: the samples past the end of a log cut in motion

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


#: the options of every fit of one stream (platkit.calibrate.estimate.calibrate's)
_FitOptions = dict


def calibrate_motion(session: Session, spec: PlatformSpec, *, kind: str = "auto", free=None,
                     robust: bool = True, window_s: float = WINDOW_S, nodes: int = NODES,
                     raw_samples: int = RAW_SAMPLES, progress: Progress | None = None,
                     platform_options: dict | None = None, ridge_m: float = 0.0,
                     reason: str = "", delays: bool = False, rate_limit: bool = False,
                     noise_floor_m: float | None = None) -> tuple[Calibration, PoseSet]:
    """Calibrate ``spec`` from the whole stream of ``session`` (module docstring). Returns the
    calibration (its ``motion`` says which samples served, how they were reduced, and the fitted
    response with its uncertainty) and the pose set of the nodes fitted. ``kind``: the actuators'
    response, 'first_order', 'second_order', or 'auto' (the default: chosen from the data, per
    actuator, :mod:`platkit.calibrate.motion_kind`; the report's ``motion.response.choice`` says
    which and why). ``reason``: why the motion model serves (said in the report). ``delays``:
    each actuator's own pure delay beyond the shift; ``rate_limit``: a streamed log's actuators
    each with a speed limit, started at the log's fastest step (a profile has its rate limit
    always) (platkit.calibrate.response). ``noise_floor_m``: the markers' own noise per axis (m) the
    misfit rule (1.) compares with, where the caller knows it and the distances between the markers
    cannot tell it (points computed from one rigid body: platkit.calibrate.motion_points)."""
    t0 = time.perf_counter()
    if kind not in ("auto",) + KINDS:
        raise BadInput(f"actuator response: kind must be auto or one of {', '.join(KINDS)}, not {kind!r}")
    reference = check_motion_session(session)
    win = stream_windows(session, window_s, nodes, raw_samples)
    if len(win.t) < 20:
        raise BadSession(f"{session.markers_source}: only {len(win.t)} poses from the samples with markers seen "
                         "after the second command; calibrating from motion needs the stand moving under the markers")
    opts: _FitOptions = {"free": free, "robust": robust, "progress": progress, "platform_options": platform_options,
                         "ridge_m": ridge_m, "row_block": ROW_BLOCK}
    rmodel = ResponseModel("first_order" if kind == "auto" else kind, reference, spec.n_u, delays, rate_limit)
    theta_start, start, geom = response_start(session, spec, rmodel, win)
    end_t = log_end_at(session, rmodel, theta_start)  # the samples past the end of a log cut in motion
    if end_t is not None:
        win = stream_windows(session, window_s, nodes, raw_samples, end_t=end_t)
    transient = start_transient(session, spec, rmodel, theta_start, geom, win.first, start, win.end)
    if transient["n_samples"]:  # the first command's transient left out (its samples counted)
        win = stream_windows(session, window_s, nodes, raw_samples, start_t=transient["until_s"], end_t=end_t)
    cal, poses = _fit_stream(session, spec, rmodel, win, theta_start, start, geom, opts)
    sample_dt = float(np.median(np.diff(session.marker_t)))
    choice: dict = {"asked": kind, "rule": "named by the caller"}
    if kind == "auto":
        rmodel, cal, poses, choice = _choose_kind(session, spec, rmodel, win, cal, poses, start, geom[:2], opts,
                                                  sample_dt)
    # the misfit rule: the markers' own 3-D noise from the distances between markers on one link;
    # on a tree (markers on several links) the misfit must also exceed MISFIT_ABSOLUTE_M: the rigid
    # model leaves the loads' sag through the chains unmodelled (physics that diagnose names, which
    # may be several times the noise), while a log that does not drive the stand leaves centimetres
    floor = np.sqrt(3) * (marker_noise_floor(poses) if noise_floor_m is None else noise_floor_m)
    limit = MISFIT_RATIO * floor
    if len(set(poses.marker_links.values())) > 1:
        limit = max(limit, MISFIT_ABSOLUTE_M)
    if np.isfinite(floor) and floor > 0 and cal.rms_after > limit:
        raise MotionUnexplained(f"{session.folder / 'commands.csv'}: the command log does not explain the motion in "
                         f"{session.markers_source}: after the fit the markers are off by {1e3 * cal.rms_after:.3g} mm "
                         f"RMS, {cal.rms_after / floor:.0f} times their own noise: commands are missing (a log "
                         "sparser than the motion) or the log is another recording's")
    held = [h["name"] for h in cal.identifiability.get("held_at_nominal", [])]  # in identifiability's order
    response = response_report(rmodel, spec, cal, session.command_t, session.commands, sample_dt)
    response["choice"] = choice
    cal.motion = {
        "used": "motion",
        "why": reason or "calibrated from the whole stream",
        "response": response,
        "samples": {"n_stream": win.n_stream, "n_used": win.n_used, "n_kept_raw": win.n_raw, "n_unseen": win.n_unseen,
                    "n_before_second_command": win.n_before, "n_in_start_transient": win.n_start_transient,
                    "start_transient": transient, "n_past_the_log": win.n_past_log, "log_end_s": end_t,
                    "n_in_short_windows": win.n_short,
                    "n_marker_observations_left_out": win.n_left_out,
                    "n_windows": win.n_windows, "n_raw_windows": win.n_raw_windows, "window_s": win.window_s,
                    "n_fitted": int(len(win.t)), "n_fitted_rejected_as_outliers": int(cal.n_rejected),
                    "rule": f"every sample from the second command on (but the first command's transient: "
                            f"start_transient) up to the end of a command log cut in motion (log_end_s, the motion "
                            f"capture's clock, {RULE}), in windows of {win.window_s:.3g} s; in each, "
                            f"every marker coordinate fitted by a polynomial of degree {win.nodes - 1} in time and "
                            f"kept at {win.nodes} Gauss-Legendre nodes, weighted by the samples it stands for (a "
                            f"marker seen in under {MIN_SEEN_SHARE:.0%} of a window's samples left out there); "
                            f"{win.n_raw_windows} whole windows evenly spread ({win.n_raw} samples) kept as they are"},
        "held": [n for n in held if n.startswith("term.actuator_response.")],
        "time_s": time.perf_counter() - t0,
    }
    say_bodies(session, win, cal)  # nothing dropped silently: the body samples used, and the others
    say_transient(transient, cal)
    say_past_log(session, win.n_past_log, end_t, cal)
    for c, why in response["not_determined"].items():
        cal.warnings.append(f"actuator {c}: its response is not determined by the stream ({why}); its lag is what "
                            "the data fix (report: motion.response)")
    cal.terms, cal.theta, cal.theta_std = [], [], []  # settled poses need no response
    if progress is not None:
        progress("motion", {"response": cal.motion["response"]})
    if not np.isfinite(cal.rms_after):
        raise NotIdentifiable(f"{session.folder}: the motion model did not fit the stream")
    return cal, poses


def _fit_stream(session: Session, spec: PlatformSpec, rmodel: ResponseModel, win: StreamWindows, theta_start,
                start, geom, opts: _FitOptions, td_start=None) -> tuple[Calibration, PoseSet]:
    """Steps 4 and 5: the nodes' markers corrected for the kinematics' curvature at ``geom``
    (kinematic model, links, td, A, b, markers) and the response ``theta_start``, the full fit
    (from ``td_start``, default nominal), and the correction taken again at the fit (stand, frame,
    markers, response) while it moves the nodes by more than CORRECTION_SHARE of their own noise,
    the fit repeated from there. The calibration keeps the response as its term."""
    T, U = session.command_t, session.commands
    model, links, td0, A, tr, mk = geom
    opts = {**opts, "progress": fit_progress(opts.get("progress"), rmodel)}
    X1 = projected_positions(win.proj, rmodel, theta_start, T, U, win.sample_t, start=start)
    correction = _curvature_correction(spec, model, td0, A, tr, mk, win, X1, lambda a, b: (
        actuator_positions(rmodel, theta_start, T, U, win.sample_t[a:b], start=start)), links)
    term = ResponseTerm(rmodel, T, U, list(spec.control_names), theta_start, fd_steps(rmodel, theta_start), start,
                        win.proj, win.sample_t)
    poses = PoseSet(platform=spec.name, controls=X1, markers=win.Y - correction, marker_names=list(session.marker_names),
                    t=win.t, n_samples=win.n_eff, **bodies_at_samples(session, win),  # body samples, raw and at nodes
                    description=None if session.description is None else str(session.description),
                    length_unit=session.length_unit, moving_link=session.moving_link, source=str(session.folder),
                    extras={"node": np.arange(len(win.t)), "elapsed": win.t - win.t[0]})
    cal = calibrate(poses, spec, terms=[term], td_start=td_start, **opts)
    rms_before = cal.rms_before  # at the start's geometry, as a fit from settled poses says it
    for _ in range(CORRECTION_REFITS):
        theta = np.asarray(cal.theta[0], float)
        X2 = projected_positions(win.proj, rmodel, theta, T, U, win.sample_t, start=start)
        again = _curvature_correction(spec, model, cal.td, matrix_from_rotvec(cal.mocap_rotvec),
                                      cal.mocap_translation, cal.marker_positions, win, X2, lambda a, b, th=theta: (
                                          actuator_positions(rmodel, th, T, U, win.sample_t[a:b], start=start)), links)
        node = win.n_eff > 1.0  # the windows' nodes (a raw sample has no correction)
        moved = (again - correction)[node] * np.sqrt(win.n_eff[node])[:, None] / cal.noise_sigma
        if not (np.isfinite(cal.noise_sigma) and cal.noise_sigma > 0 and moved.size
                and np.sqrt(np.mean(moved ** 2)) > CORRECTION_SHARE):
            break
        correction = again
        term = ResponseTerm(rmodel, T, U, list(spec.control_names), theta, fd_steps(rmodel, theta), start, win.proj,
                            win.sample_t)
        poses = replace(poses, controls=X2, markers=win.Y - correction)
        cal = calibrate(poses, spec, terms=[term], td_start=cal.td, **opts)
        cal.rms_before = rms_before
    cal.theta[0] = rmodel.positive(cal.theta[0])  # the same response, each time constant positive
    return cal, poses


def _choose_kind(session: Session, spec: PlatformSpec, first: ResponseModel, win: StreamWindows, cal1: Calibration,
                 poses1: PoseSet, start, kin, opts: _FitOptions, sample_dt: float):
    """The response's kind chosen from the data (platkit.calibrate.motion_kind's rules), from the
    first-order fit ``cal1``: the second order tried from it, kept per actuator where determined,
    and kept at all only where better by the whole fit's information criterion without losing the
    fast content. Returns the model, the calibration and poses kept, and the report's ``choice``."""
    names = list(spec.control_names)
    v1 = dict(zip(first.names(names), np.asarray(cal1.theta[0], float)))
    second = ResponseModel("second_order", first.reference, spec.n_u, first.delays, first.rate_limit)
    held1 = held_names(cal1)
    halved = {f"tau_s.{c}": 0.5 * v1[f"tau_s.{c}"] if v1[f"tau_s.{c}"] > 2 * TAU_MIN_S else TAU0_S for c in names
              if f"term.actuator_response.tau_s.{c}" not in held1}  # one the markers do not see stays at its start
    th2 = theta_by_name(second, names, halved, v1, default=ZETA0)  # the same lag (2 zeta tau) at low frequency

    def at(cal):
        return (*kin, cal.td, matrix_from_rotvec(cal.mocap_rotvec), cal.mocap_translation, cal.marker_positions)

    n_ref = 3 * int(cal1.n_observations)
    # two starts of the first order's lag (its shift kept, or taken again from the travel at its fit):
    # the second order's fit is not convex in the shift's share of the lag; the lower BIC kept
    th2t = travel_start(session, spec, second, th2, (*at(cal1), first, np.asarray(cal1.theta[0], float)), win, start)
    cal2, poses2 = min((_fit_stream(session, spec, second, win, th, start, at(cal1), opts, td_start=cal1.td)
                        for th in (th2, th2t)), key=lambda fit: information(fit[0], n_ref))
    moved = np.ptp(session.commands, axis=0) > 0
    keep, why = second_order_kept(second, spec, cal2, sample_dt, moved)
    bic1 = information(cal1, n_ref)
    choice: dict = {"asked": "auto", "first_order_actuators": why,
                    "rule": (f"first order fitted; second order tried from it and kept for an actuator whose time "
                             f"constant and damping are each determined (over {Z_DETERMINED:g} standard deviations) and "
                             f"physical (damping at most {DAMPING_MAX:g}), and at all only where the whole fit's "
                             "information criterion (BIC) is lower than the first order's and the fit leaves the "
                             "stream's fast content no worse (what a smooth static effect left out cannot buy), on the "
                             "samples whose commands the log holds"),
                    "bic": {"first_order": bic1}}
    if not keep[moved].any():
        choice["why"] = "first order: no actuator's second-order response is determined by the stream"
        return first, cal1, poses1, choice
    rmodel, cal, poses = second, cal2, poses2
    if not keep[moved].all():  # some keep the second order: the others refitted as first order within it
        rmodel = ResponseModel("second_order", first.reference, spec.n_u, first.delays, first.rate_limit,
                               tuple(np.nonzero(~keep)[0]))
        v2 = dict(zip(second.names(names), np.asarray(cal2.theta[0], float)))
        own = {f"tau_s.{c}": v1[f"tau_s.{c}"] for j, c in enumerate(names) if not keep[j]}
        th = theta_by_name(rmodel, names, own, v2)
        cal, poses = _fit_stream(session, spec, rmodel, win, th, start, at(cal2), opts, td_start=cal2.td)
    label = "second_order" if keep[moved].all() else "per_actuator"
    bic2 = information(cal, n_ref)
    choice["bic"][label] = bic2
    added = sum(1 for j, c in enumerate(names) if rmodel.has("damping", j)
                and f"term.actuator_response.damping.{c}" not in held_names(cal))
    known = np.ones(len(win.t), bool)
    if first.reference == "step":  # a profile's last command is a hold's target: at rest
        known = known_samples(win.t, session.command_t, session.commands, np.concatenate(
            [lags(first, np.asarray(cal1.theta[0], float)), lags(rmodel, np.asarray(cal.theta[0], float))]))
    unknown = int(np.sum(~known & np.all(win.n_eff <= 1.0, axis=1)))  # the samples kept as samples past the log
    better, figures, said = kind_verdict(fast_content([cal1, cal], win, known), added, (bic1, bic2), label, unknown)
    choice.update(said)
    if not better:
        choice["why"] = (f"first order: the second order for {', '.join(c for j, c in enumerate(names) if keep[j])} "
                         f"is determined but not better ({figures})")
        return first, cal1, poses1, choice
    choice["why"] = (f"{label.replace('_', ' ')}: second order for "
                     f"{', '.join(c for j, c in enumerate(names) if keep[j] and moved[j])}, better ({figures})")
    cal.rms_before = cal1.rms_before  # at the start's geometry, as the first fit said it
    return rmodel, cal, poses, choice


def motion_poses(session: Session, cal: Calibration) -> PoseSet:
    """:func:`motion_stream`'s poses alone (the response held as calibrated)."""
    return motion_stream(session, cal)[0]


def motion_stream(session: Session, cal: Calibration) -> tuple[PoseSet, LocalResponseTerm]:
    """The poses a calibration from motion (``cal``: its ``motion``, calibration.yaml's
    ``actuator_response``) sees in ``session``'s stream: the stream's windows as calibrate_motion
    cuts them, every window reduced to its nodes (none kept as raw samples: those served the
    response's timing, held here), each node at the controls the calibrated response reached there and its markers
    corrected for the kinematics' curvature at the calibration's geometry, frame and markers, a
    rigid body's samples reduced to the nodes as calibrate_motion reduces them; the response held
    as calibrated. What a diagnosis of a stream without holds reads in place of
    settled poses. A profile reference's actuators rest on the first command before it (the rest
    calibrate_motion read from the samples before it is not kept). The first command's transient
    is left out by calibrate_motion's rule at the calibration's geometry and response
    (:mod:`platkit.calibrate.motion_transient`; the term's ``start_transient`` says what), and so
    are those past the end of a log cut in motion (:func:`log_end_at`, the term's ``past_the_log``). Returns the poses and the
    response as a term at the calibration's values (its control offset zero there), which a fit
    that carries it frees again, as calibrate_motion did (:class:`LocalResponseTerm`: the same
    response, its Jacobian reused while the response stays linear)."""
    r = (cal.motion or {}).get("response")
    if not isinstance(r, dict) or not isinstance(r.get("actuators"), dict):
        raise BadSession(f"{session.folder}: the calibration was not fitted from motion (no actuator_response): a "
                         "stream without settled holds is read through the response calibrate fitted to it")
    spec = cal.spec
    try:
        rmodel, theta = response_from_report(r, spec, str(session.folder))
    except ValueError as exc:
        raise BadSession(str(exc)) from None
    check_motion_session(session)
    names = list(session.marker_names)
    order = [cal.marker_names.index(n) for n in names if n in cal.marker_names]
    if len(order) != len(names):
        raise BadSession(f"{session.folder}: markers {sorted(set(names) - set(cal.marker_names))} are not the "
                         "calibration's")
    T, U = session.command_t, session.commands
    A, b, mk = matrix_from_rotvec(cal.mocap_rotvec), cal.mocap_translation, cal.marker_positions[order]
    end_t = log_end_at(session, rmodel, theta)  # past a log cut in motion: left out
    win = stream_windows(session, raw_samples=0, end_t=end_t)
    X, poses = _node_poses(session, spec, rmodel, theta, win)
    problem = CalibrationProblem(spec, poses)
    # the first command's transient left out as calibrate_motion leaves it, at the calibration
    transient = start_transient(session, spec, rmodel, theta, (problem.model, problem.point_links, cal.td, A, b, mk),
                                win.first, end=win.end)
    if transient["n_samples"]:
        win = stream_windows(session, raw_samples=0, start_t=transient["until_s"], end_t=end_t)
        X, poses = _node_poses(session, spec, rmodel, theta, win)
    correction = _curvature_correction(spec, problem.model, cal.td, A, b, mk, win, X, lambda i, j: (
        actuator_positions(rmodel, theta, T, U, win.sample_t[i:j])), problem.point_links)
    poses.markers = win.Y - correction
    term = LocalResponseTerm(rmodel, T, U, list(spec.control_names), theta, fd_steps(rmodel, theta), None, win.proj,
                             win.sample_t)
    term.start_transient = transient
    term.past_the_log = {"n_samples": win.n_past_log, "log_end_s": end_t}
    return poses, term


def _node_poses(session: Session, spec: PlatformSpec, rmodel: ResponseModel, theta, win: StreamWindows):
    """The controls reached at the windows' nodes under ``theta`` and the nodes as poses (their
    markers as fitted, before the curvature correction; the rigid bodies' samples reduced to the
    nodes, :func:`platkit.calibrate.motion_bodies.bodies_at_samples`)."""
    X = projected_positions(win.proj, rmodel, theta, session.command_t, session.commands, win.sample_t)
    return X, PoseSet(platform=spec.name, controls=X, markers=win.Y, marker_names=list(session.marker_names), t=win.t,
                      n_samples=win.n_eff, **bodies_at_samples(session, win),
                      description=None if session.description is None else str(session.description),
                      length_unit=session.length_unit, moving_link=session.moving_link, source=str(session.folder),
                      extras={"node": np.arange(len(win.t)), "elapsed": win.t - win.t[0]})


def without_response(cal: Calibration, session: Session) -> Calibration:
    """``cal`` (a fit that carried :func:`motion_stream`'s response as a term) with the response
    out of its terms and in its ``motion`` (calibration.yaml's ``actuator_response``) at the
    values fitted, as calibrate_motion leaves its own: settled poses need no response. ``cal``
    itself where it carries none."""
    k = next((i for i, t in enumerate(cal.terms) if isinstance(t, ResponseTerm)), None)
    if k is None:
        return cal
    term = cal.terms[k]
    one = replace(cal, terms=[term], theta=[cal.theta[k]], theta_std=[cal.theta_std[k]])
    response = response_report(term.model, cal.spec, one, session.command_t, session.commands,
                               float(np.median(np.diff(session.marker_t))))
    if "choice" in ((cal.motion or {}).get("response") or {}):  # the kind as calibrate chose it
        response["choice"] = cal.motion["response"]["choice"]
    keep = [i for i in range(len(cal.terms)) if i != k]
    return replace(cal, terms=[cal.terms[i] for i in keep], theta=[cal.theta[i] for i in keep],
                   theta_std=[cal.theta_std[i] for i in keep], motion={**(cal.motion or {}), "response": response})
