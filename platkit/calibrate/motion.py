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
are central differences per actuator (each parameter moves one actuator, or all for the shift).

Procedure (:func:`calibrate_motion`):
1. checks: markers and at least three commands, on two clocks that overlap (BadSession naming
   commands.csv); after the fit (4.), markers off by more than MISFIT_RATIO times their own
   noise say that the log does not explain the motion (commands missing: a log sparser than the
   motion, or another recording's), BadSession naming commands.csv;
2. the samples: every sample with a marker seen, from the second command on (the stand's place
   before the first is not logged), decimated evenly to at most ``max_samples``;
3. the response's start: the markers registered at the commanded controls (rigid alignment),
   each sample's pose by Kabsch, the actuators' travel by inverse kinematics at the nominal
   geometry, and the response fitted to that travel alone (a grid over the shift, then
   least squares): an actuator that moved too little to show its response keeps the start;
4. the full fit with :func:`calibrate` and the response as a term; the term leaves the
   calibration afterwards (calibration.yaml keeps it as ``actuator_response``; prediction of
   settled poses needs no response).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from platkit.calibrate.estimate import calibrate, marker_noise_floor
from platkit.calibrate.problem import CalibrationProblem, Progress
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.errors import BadSession, ComputationFailed, NotIdentifiable
from platkit.geometry import matrix_from_rotvec, quat_from_matrix, rigid_fit
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

__all__ = ["ResponseTerm", "calibrate_motion", "motion_samples", "check_motion_session", "STREAMED_MAX_S"]

#: a command log whose median interval is at most this (s) is streamed (step reference); longer
#: intervals are point-to-point moves between holds (profile reference)
STREAMED_MAX_S = 0.25
#: samples fitted at most (decimated evenly), and used to start the response; rounds of the start;
#: samples before the first command that say where a profile's actuators rest
MAX_SAMPLES, START_SAMPLES, START_ROUNDS, PRE_SAMPLES = 4000, 600, 2, 50
#: starting response: time constant (s), damping; a profile's rate and acceleration from the
#: stroke (a full stroke in STROKE_TIME_S, the rate reached in ACCEL_TIME_S)
TAU0_S, ZETA0, STROKE_TIME_S, ACCEL_TIME_S = 0.05, 1.0, 4.0, 0.25
#: a fit whose RMS is this many times the markers' own 3-D noise (from the distances between
#: them) does not describe the stream: the command log does not say where the stand was sent
MISFIT_RATIO = 5.0
#: in a streamed log, an interval this many times the median is a gap; markers moving more than
#: GAP_MOVE_M (m) in its second half, long after any response, mean commands are missing there
GAP_FACTOR, GAP_MOVE_M = 10.0, 1e-3
#: the two clocks must share at least this part of the shorter file's span
OVERLAP_SHARE = 0.5
#: the shifts (s) tried to start the response
SHIFT_GRID_S = np.arange(-0.5, 0.5001, 0.01)


class ResponseTerm(ModelTerm):
    """The actuators' response as a model term: control offset = the controls reached at each
    sample (``poses.t``, motion-capture clock) minus ``poses.controls``."""

    def __init__(self, model: ResponseModel, T: np.ndarray, U: np.ndarray, control_names: list[str],
                 theta0: np.ndarray, steps: np.ndarray, start: np.ndarray | None = None):
        units = []
        for name in model.names(control_names):
            block = name.split(".")[0]
            units.append({"shift_s": "s", "tau_s": "s", "damping": "1", "rate": "unit/s",
                          "accel": "unit/s^2"}[block])
        super().__init__("actuator_response", model.names(control_names), np.asarray(theta0, float).copy(), units,
                         {"kind": model.kind, "reference": model.reference})
        self.model, self.T, self.U, self.steps, self.start = model, T, U, np.asarray(steps, float), start
        self._cache: tuple | None = None

    def reached(self, theta, t) -> np.ndarray:
        key = (np.asarray(theta, float).tobytes(), id(t), len(t))
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        x = actuator_positions(self.model, theta, self.T, self.U, t, start=self.start)
        self._cache = (key, x)
        return x

    def control_offset(self, theta, poses: PoseSet, n_u: int) -> np.ndarray:
        return self.reached(theta, poses.t) - poses.controls

    def offset_jacobians(self, theta, poses: PoseSet, n_u: int, fk_q, fk_X):
        theta = np.asarray(theta, float)
        N, K = poses.n_poses, len(theta)
        d_u = np.zeros((N, n_u, K))
        for k in range(K):
            h = self.steps[k]
            up, dn = theta.copy(), theta.copy()
            up[k] += h
            dn[k] -= h
            j = self.model.actuator_of(k)
            if j is None:
                d_u[:, :, k] = (actuator_positions(self.model, up, self.T, self.U, poses.t, start=self.start)
                                - actuator_positions(self.model, dn, self.T, self.U, poses.t, start=self.start)) / (2 * h)
            else:
                d_u[:, j, k] = (actuator_positions(self.model, up, self.T, self.U, poses.t, only=j, start=self.start)
                                - actuator_positions(self.model, dn, self.T, self.U, poses.t, only=j, start=self.start)
                                ) / (2 * h)
        return d_u, np.zeros((N, 6, K)), np.zeros((N, poses.n_markers, 3, K))


@dataclass
class MotionSamples:
    """The samples a motion calibration fits: indices into the stream, and what was left out."""

    index: np.ndarray
    n_stream: int
    n_unseen: int
    n_before: int
    stride: int


def check_motion_session(session: Session) -> str:
    """The reference the command log calls for ('step': streamed, 'profile': holds), after the
    checks: markers and commands present, on clocks that overlap. BadSession naming the file
    otherwise."""
    cmd_file = session.folder / "commands.csv"
    mk_file = session.markers_source or session.folder / "markers.csv"
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
    c = np.nanmean(Y, axis=1) if Y.shape[1] else np.zeros((len(tm), 3))
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


def motion_samples(session: Session, reference: str, max_samples: int = MAX_SAMPLES) -> MotionSamples:
    """The stream's samples to fit: a marker seen, after the second command is sent (the stand's
    place before the first is not logged; a profile's first move starts from it), evenly
    decimated to at most ``max_samples``."""
    tm, Y = session.marker_t, session.markers
    seen = np.isfinite(Y).all(axis=2).any(axis=1)
    start = session.command_t[1] + (0.0 if reference == "step" else 0.0)
    after = tm >= start
    cand = np.nonzero(seen & after)[0]
    stride = max(1, int(np.ceil(len(cand) / max(max_samples, 1))))
    return MotionSamples(cand[::stride], len(tm), int((~seen).sum()), int((seen & ~after).sum()), stride)


def _starting_theta(model: ResponseModel, spec: PlatformSpec) -> np.ndarray:
    span = np.array([c.upper - c.lower for c in spec.controls], float)
    span = np.where(np.isfinite(span) & (span > 0), span, 1.0)
    th = [np.zeros(1), np.full(model.n_u, TAU0_S)]
    if model.kind == "second_order":
        th.append(np.full(model.n_u, ZETA0))
    if model.reference == "profile":
        th += [span / STROKE_TIME_S, span / STROKE_TIME_S / ACCEL_TIME_S]
    return np.concatenate(th)


def _lower_upper(model: ResponseModel, theta0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = np.full(model.size, 1e-9)
    hi = np.full(model.size, np.inf)
    lo[0], hi[0] = -5.0, 5.0
    for j in range(model.n_u):
        lo[model.index("tau_s", j)], hi[model.index("tau_s", j)] = 2e-3, 20.0
        if model.kind == "second_order":
            lo[model.index("damping", j)], hi[model.index("damping", j)] = 0.2, 5.0
    return lo, hi


def _travel(spec: PlatformSpec, model: PlatformModel, td, A, b, mk, Y: np.ndarray, guess_u: np.ndarray):
    """The actuators' travel (K, n_u) at each sample by inverse kinematics of the pose the markers
    give (Kabsch of the marker layout ``mk`` onto the sample, in the base frame); NaN rows where
    fewer than three markers are seen or the pose is out of reach."""
    K = len(Y)
    out = np.full((K, spec.n_u), np.nan)
    Yb = (Y - b) @ A  # base frame: A^T (y - b)
    for k in range(K):
        vis = np.isfinite(Yb[k]).all(axis=1)
        if vis.sum() < 3:
            continue
        R, X = rigid_fit(mk[vis], Yb[k, vis])
        try:
            out[k] = model.inverse(quat_from_matrix(R), X, td, strict=False, guess=guess_u[k])
        except ComputationFailed:  # a pose out of reach is left out (NaN)
            continue
    return out


def _fit_response_to_travel(rmodel: ResponseModel, theta0, T, U, t, travel, steps, start=None):
    """The response fitted to the actuators' travel alone: the shift by a grid (each actuator's best,
    their median), then each actuator's least squares (soft L1) with a shift of its own, the shift
    at the median of theirs, and each actuator's again with it held. Actuators that never move
    keep theta0."""
    ok = np.isfinite(travel).all(axis=1)
    t, travel = t[ok], travel[ok]
    if len(t) < 10:
        return np.asarray(theta0, float)
    theta = np.asarray(theta0, float).copy()
    theta[0] = 0.0  # every shift at once: the response at the shifted times
    shifted = (t[None, :] - SHIFT_GRID_S[:, None]).ravel()
    X = actuator_positions(rmodel, theta, T, U, shifted, start=start).reshape(len(SHIFT_GRID_S), len(t), -1)
    # each actuator's best shift, the median over them (a slow actuator's lag is not the clock's)
    moved = np.ptp(U, axis=0) > 0
    best = SHIFT_GRID_S[np.argmin(np.sum((X - travel[None]) ** 2, axis=1), axis=0)]
    theta[0] = float(np.median(best[moved])) if moved.any() else 0.0
    lo, hi = _lower_upper(rmodel, theta)
    theta = np.clip(theta, lo + 1e-12, hi - 1e-12)
    shifts = []
    for own_shift in (True, False):  # each actuator with a shift of its own, then all at their median
        for j in range(rmodel.n_u):  # the damping held (the full fit frees it)
            ks = ([0] if own_shift else []) + [rmodel.index(b, j) for b in rmodel.blocks if b != "damping"]
            scale = max(float(np.ptp(travel[:, j])), 1e-9)
            if not np.ptp(U[:, j]) > 0:
                continue

            def res(x, j=j, ks=ks, scale=scale):
                th = theta.copy()
                th[ks] = x
                return (actuator_positions(rmodel, th, T, U, t, only=j, start=start) - travel[:, j]) / scale

            sol = least_squares(res, theta[ks], bounds=(lo[ks], hi[ks]), loss="soft_l1", f_scale=0.01,
                                x_scale=np.maximum(steps[ks] * 1e3, 1e-6), max_nfev=20)
            if own_shift:
                shifts.append(float(sol.x[0]))
                theta[ks[1:]] = sol.x[1:]
            else:
                theta[ks] = sol.x
        if own_shift and shifts:
            theta[0] = float(np.median(shifts))
    return theta


def calibrate_motion(session: Session, spec: PlatformSpec, *, kind: str = "second_order", free=None,
                     robust: bool = True, max_samples: int = MAX_SAMPLES, progress: Progress | None = None,
                     platform_options: dict | None = None, ridge_m: float = 0.0, reason: str = "") -> tuple[Calibration, PoseSet]:
    """Calibrate ``spec`` from the whole stream of ``session`` (module docstring). Returns the
    calibration (its ``motion`` says which samples served and the fitted response with its
    uncertainty) and the pose set of the samples fitted. ``reason``: why the motion model serves
    (said in the report)."""
    t0 = time.perf_counter()
    reference = check_motion_session(session)
    rmodel = ResponseModel(kind, reference, spec.n_u)
    chosen = motion_samples(session, reference, max_samples)
    idx = chosen.index
    if len(idx) < 20:
        raise BadSession(f"{session.markers_source}: only {len(idx)} samples with markers seen after the second "
                         "command; calibrating from motion needs the stand moving under the markers")
    T, U = session.command_t, session.commands
    t = session.marker_t[idx]
    Y = session.markers[idx]
    theta0 = _starting_theta(rmodel, spec)
    steps = _steps(rmodel, theta0)
    # 3. the response's start from the actuators' travel at the nominal geometry, twice (the
    # second registration at the controls the first response gives); a profile's actuators rest
    # before the first command where the samples before it put them
    theta_start, start = theta0, None
    sub = np.unique(np.linspace(0, len(idx) - 1, min(len(idx), START_SAMPLES)).astype(int))
    seen = np.isfinite(session.markers).all(axis=2).sum(axis=1) >= 3
    pre = np.nonzero(seen & (session.marker_t < T[0]))[0][-PRE_SAMPLES:]
    for _ in range(START_ROUNDS):
        X0 = actuator_positions(rmodel, theta_start, T, U, t, start=start)
        poses0 = PoseSet(platform=spec.name, controls=X0, markers=Y, marker_names=list(session.marker_names), t=t,
                         length_unit=session.length_unit, source=str(session.folder))
        problem = CalibrationProblem(spec, poses0)
        z = problem.initial_registration(spec.nominal_td())
        _, w, tr, mk, _ = problem.split(z)
        A = matrix_from_rotvec(w)
        travel = _travel(spec, problem.model, spec.nominal_td(), A, tr, mk, Y[sub], X0[sub])
        if reference == "profile" and len(pre):
            before = _travel(spec, problem.model, spec.nominal_td(), A, tr, mk, session.markers[pre],
                             np.repeat(U[:1], len(pre), axis=0))
            if np.isfinite(before).all(axis=1).any():
                start = np.nanmedian(before, axis=0)
        theta_start = _fit_response_to_travel(rmodel, theta_start, T, U, t[sub], travel, steps, start)
    steps = _steps(rmodel, theta_start)
    # 4. the full fit
    term = ResponseTerm(rmodel, T, U, list(spec.control_names), theta_start, steps, start)
    X1 = actuator_positions(rmodel, theta_start, T, U, t, start=start)
    poses = PoseSet(platform=spec.name, controls=X1, markers=Y, marker_names=list(session.marker_names), t=t,
                    description=None if session.description is None else str(session.description),
                    length_unit=session.length_unit, moving_link=session.moving_link, source=str(session.folder),
                    extras={"row": idx, "elapsed": t - t[0]})
    cal = calibrate(poses, spec, terms=[term], free=free, robust=robust, progress=progress,
                    platform_options=platform_options, ridge_m=ridge_m)
    floor = np.sqrt(3) * marker_noise_floor(poses)
    if np.isfinite(floor) and floor > 0 and cal.rms_after > MISFIT_RATIO * floor:
        raise BadSession(f"{session.folder / 'commands.csv'}: the command log does not explain the motion in "
                         f"{session.markers_source}: after the fit the markers are off by {1e3 * cal.rms_after:.3g} mm "
                         f"RMS, {cal.rms_after / floor:.0f} times their own noise: commands are missing (a log "
                         "sparser than the motion) or the log is another recording's")
    theta, theta_std = np.asarray(cal.theta[0], float), np.asarray(cal.theta_std[0], float)
    held = [h["name"] for h in cal.identifiability.get("held_at_nominal", [])]
    par = rmodel.split(theta)
    sd = rmodel.split(np.where(np.isfinite(theta_std), theta_std, np.nan))
    per = {}
    for j, c in enumerate(spec.control_names):
        entry = {}
        for b in rmodel.blocks:
            name = f"{b}.{c}"
            held_here = f"term.actuator_response.{name}" in held
            entry[b] = {"value": float(par[b][j]), "std": None if held_here or not np.isfinite(sd[b][j])
                        else float(sd[b][j]), "status": "held_at_start" if held_here else "estimated"}
        per[c] = entry
    shift_held = "term.actuator_response.shift_s" in held
    cal.motion = {
        "used": "motion",
        "why": reason or "calibrated from the whole stream",
        "response": {"kind": kind, "reference": reference, "units": "s for times; controls' internal units "
                     "(m for length controls) per s for rates",
                     "shift_s": {"value": float(par["shift_s"]), "std": None if shift_held or not np.isfinite(
                         sd["shift_s"]) else float(sd["shift_s"]), "status": "held_at_start" if shift_held else "estimated",
                         "note": "the motion capture's clock minus the commands', with the stand's common delay"},
                     "actuators": per},
        "samples": {"n_stream": chosen.n_stream, "n_fitted": int(len(idx)), "stride": chosen.stride,
                    "n_unseen": chosen.n_unseen, "n_before_second_command": chosen.n_before,
                    "n_rejected_as_outliers": int(cal.n_rejected),
                    "rule": "every sample with a marker seen from the second command on, one in every "
                            f"{chosen.stride}"},
        "held": [n for n in held if n.startswith("term.actuator_response.")],
        "time_s": time.perf_counter() - t0,
    }
    cal.terms, cal.theta, cal.theta_std = [], [], []  # settled poses need no response
    if progress is not None:
        progress("motion", {"response": cal.motion["response"]})
    if not np.isfinite(cal.rms_after):
        raise NotIdentifiable(f"{session.folder}: the motion model did not fit the stream")
    return cal, poses


def _steps(rmodel: ResponseModel, theta: np.ndarray) -> np.ndarray:
    """Central-difference steps: 1e-4 s for the shift, 1e-4 relative for the rest."""
    h = 1e-4 * np.maximum(np.abs(np.asarray(theta, float)), 1e-2)
    h[0] = 1e-4
    return h
