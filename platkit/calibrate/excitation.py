"""Excitation trajectories for calibration from motion: D-optimal over a Fourier family within
the drives' limits, and how long a session must be for a target accuracy. The information and
the prediction below serve the via-point sweeps too (:mod:`platkit.calibrate.sweeps`).

The family (as in dynamic identification): each actuator j follows a periodic Fourier series of
base frequency f0 = 1 / ``period_s`` with H harmonics,

    u_j(t) = u0_j + A_j w(t) s_j(t),   s_j(t) = sum_k a_jk sin(2 pi k f0 t) + b_jk cos(2 pi k f0 t),

around the neutral controls u0, with s_j scaled to unit largest magnitude over a period, and a
raised-cosine window w(t) that starts and ends the session at rest on the neutral controls.
The amplitude A_j is the largest that keeps, on every command (streamed at ``command_rate_hz``),
the control inside its stroke box (:class:`Limits`: the stroke less ``margin`` at both ends),
its rate (first difference of the commands) within ``rate`` and its acceleration (second
difference) within ``accel``; every command is then checked reachable (forward kinematics on the
stand's branch, inside the coordinates' bounds) and all amplitudes shrink together until it is.
The window lasts long enough for the limits to hold while it rises.

A stand whose pose space is free (a cable robot) takes the family per pose coordinate about its
neutral pose, the commands their inverse kinematics (:mod:`platkit.calibrate.trajectories`).

The information is that of the model `platkit calibrate` fits to a stream
(:mod:`platkit.calibrate.motion`): :class:`~platkit.calibrate.problem.CalibrationProblem` with
the actuators' response as a :class:`~platkit.calibrate.motion.ResponseTerm` (a step reference,
second-order response, one clock shift), evaluated at the nominal geometry, the default marker
layout and a starting response (time constant TAU0_S, damping ZETA0, no shift: motion.py's).
Its columns are the stand's free parameters, the motion-capture frame, the markers and the
response; the directions no pose ever fixes (gauges: the null space of the same model's settled
Jacobian over the stand's reference poses) are left out. The criterion is log det of the
information per sample in the identifiable subspace plus RESPONSE_WEIGHT times log det of the
response's part left after the geometry's (its Schur complement: how well the response is told
apart from the geometry), with fixed column scales (differences of it are independent of the
scales and the basis). The information is counted from the stream's slow
part: each window of SLOW_WINDOW_S keeps what polynomials of degree SLOW_DEGREE in time fit of its
Jacobian (the motion, not the commands' transients under the noise).

The design maximises that criterion over the coefficients (a, b) by a (1+1) evolution strategy
with the one-fifth success rule, from a random multisine (random phases, amplitude 1/sqrt(k)):
the start is the random multisine of the same duration and limits that the design is compared
with.

Prediction, for white marker noise ``sigma`` (m, per coordinate and sample): calibrate fits every
sample with a marker seen from the second command on, so the information of a session of duration
D at motion-capture rate R is n(D) = (D - the first command interval) R (share seen) times the
information per sample, and the covariance sigma^2 / n(D) times its inverse. The predicted error
is the RMS over the stand's reference poses and the markers of the 3-D standard deviation of the
predicted marker positions (gauge-free: the error `calibrate` makes predicting settled poses),
the parameters' standard deviations those of the minimum-norm solution; one session's error
scatters about it, and its 90th percentile over sessions (the parameters' error drawn from their
predicted covariance, QUANTILE_DRAWS draws) is said beside it. The session length for a target is
the shortest D whose 90th percentile meets it (the error falls as 1 / sqrt(D)); a target
that needs more than LONGEST_S is refused (NotIdentifiable, one line saying what LONGEST_S gives).
"""
from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from platkit.calibrate.motion import TAU0_S, ZETA0, ResponseTerm
from platkit.calibrate.plan import idle_controls, marker_links, pin_held, reference_poses_for
from platkit.calibrate.problem import CalibrationProblem
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.solve import blas_threads
from platkit.calibrate.trajectories import (
    FourierFamily,
    Limits,
    Scaler,
    trajectory,
)
from platkit.errors import BadInput, NotIdentifiable
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec, controls_from_si
from platkit.poses import PoseSet

__all__ = ["MotionInformation", "ExcitationDesign", "ExcitationPlan", "design_excitation", "samples_fitted",
           "session_length_for", "predict_trajectory", "trajectory_information", "plan_excitation",
           "write_commands_csv"]

#: the information a stream gives is counted from its slow part: in each window of SLOW_WINDOW_S,
#: what polynomials of degree SLOW_DEGREE in time fit (the motion, not the commands' transients
#: under the noise; calibrate reduces a stream so); WINDOW_SAMPLES samples a window
SLOW_WINDOW_S, SLOW_DEGREE, WINDOW_SAMPLES = 0.5, 2, 8
#: the criterion's weight on the response's information left after the geometry's: a fit from
#: motion needs the response told apart from the geometry (on the physical simulator a design for
#: log det alone left fits that took a wrong clock shift, docs/planning.md)
RESPONSE_WEIGHT = 2.0
#: windows per period the design evaluates
DESIGN_WINDOWS = 40
#: commands before the period the design evaluates (s): the response starts at rest before them
LEAD_S = 2.0
#: the evolution strategy: starting step (relative to the coefficients' norm), its bounds
STEP0, STEP_MIN, STEP_MAX = 0.3, 0.01, 1.0
#: the 90th percentile of a session's error: from this many draws of the parameters' error, fixed seed
QUANTILE_DRAWS, QUANTILE_SEED = 4000, 20261
#: the longest session the target search considers (s)
LONGEST_S = 3600.0


class MotionInformation:
    """The information per sample of a streamed session about the parameters calibrate fits from
    motion (module docstring), at the nominal geometry.

    ``markers`` (M, 3) m on the moving part (on a tree, marker k on tracked link k mod L, as plan
    places them); ``tau_s``, ``damping`` the assumed response. The response of a control that moves
    no tracked link (a tree's legs and head) is no column: no marker sees it. ``limits``, where
    given: a control whose box is a point (held by the plan, :func:`platkit.calibrate.trajectories.drive_limits`)
    has no response column either, and the reference poses hold it there too (the error is told
    where the session's stand goes: :func:`platkit.calibrate.plan.pin_held`)."""

    def __init__(self, spec: PlatformSpec, markers: np.ndarray, *, tau_s: float = TAU0_S, damping: float = ZETA0,
                 model: PlatformModel | None = None, limits: Limits | None = None):
        self.spec, self.markers = spec, np.asarray(markers, float)
        self.model = model or PlatformModel(spec)
        self.td = spec.nominal_td()
        self.rmodel = ResponseModel("second_order", "step", spec.n_u)
        self.theta = np.concatenate([[0.0], np.full(spec.n_u, tau_s), np.full(spec.n_u, damping)])
        self.steps = 1e-4 * np.maximum(np.abs(self.theta), 1e-2)
        self.steps[0] = 1e-4
        self.M = len(self.markers)
        self.links = marker_links(spec, self.M)
        self.mapping = ({f"M{k + 1}": link for k, link in enumerate(self.links)} if len(set(self.links)) > 1
                        else None)
        held = (np.zeros(spec.n_u, bool) if limits is None else
                np.asarray(limits.lower, float) == np.asarray(limits.upper, float))
        seen_controls = ~idle_controls(spec) & ~held
        self.theta_cols = np.nonzero(np.concatenate([[True]] + [seen_controls] * len(self.rmodel.blocks)))[0]
        free = np.array([p.free for p in spec.parameters], bool)
        self.free = free
        # the settled model over the reference poses: its scales, gauges and the poses the error is told on
        U_ref, P_ref = reference_poses_for(spec, self.model)
        if limits is not None and np.any(held):
            U_ref, P_ref = pin_held(spec, U_ref, P_ref, (held, np.asarray(limits.lower, float)), self.model)
        if len(U_ref) < 3:
            raise NotIdentifiable(f"{spec.name}: fewer than 3 reference poses are reachable")
        self.U_ref = U_ref
        ref = self._problem(U_ref)
        z_static = self._z(ref)
        J_ref = ref.evaluate(z_static).J  # (N, M, 3, n_static)
        self.static_cols = np.concatenate([np.nonzero(free)[0], np.arange(spec.n_td, ref.n_z)])
        self.scale_static = ref.scale[self.static_cols]
        A = J_ref[..., self.static_cols].reshape(-1, len(self.static_cols)) * self.scale_static
        with blas_threads(1):
            _, sv, Vt = np.linalg.svd(np.linalg.qr(A, mode="r"), full_matrices=False)
        rank = int(np.sum(sv > 1e-7 * sv[0]))
        self.V_static = Vt[:rank].T  # (n_static, r): the identifiable directions (scaled)
        self.J_ref = A  # (rows, n_static) scaled
        self.n_theta = len(self.theta_cols)
        self.names = ([p.name for p in spec.parameters if p.free] + ["mocap.rx", "mocap.ry", "mocap.rz", "mocap.x",
                      "mocap.y", "mocap.z"] + [f"marker{k + 1}.{a}" for k in range(self.M) for a in "xyz"]
                      + [f"response.{n}" for n in np.array(self.rmodel.names(spec.control_names))[self.theta_cols]])
        self.units = ([p.unit for p in spec.parameters if p.free] + ["rad"] * 3 + ["m"] * 3 + ["m"] * (3 * self.M)
                      + list(np.array(["s"] + ["s"] * spec.n_u + ["1"] * spec.n_u)[self.theta_cols]))
        self.rank = rank + self.n_theta
        self.n_parameters = len(self.static_cols) + self.n_theta

    def _problem(self, U, t=None, term: ResponseTerm | None = None) -> CalibrationProblem:
        N = len(U)
        poses = PoseSet(platform=self.spec.name, controls=U, markers=np.zeros((N, self.M, 3)),
                        marker_names=[f"M{k + 1}" for k in range(self.M)], t=t, moving_link=self.mapping)
        return CalibrationProblem(self.spec, poses, [] if term is None else [term])

    def _z(self, problem, theta=None):
        z = np.zeros(problem.n_z)
        z[problem.i_td] = self.td
        z[problem.i_m] = self.markers.ravel()
        if theta is not None:
            z[problem.i_theta] = theta
        return z

    def jacobian(self, T: np.ndarray, U: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(K * 3M, n) the scaled Jacobian of the samples at times t (K,) of commands U (N, n_u) sent
        at T (N,), columns (free td, frame, markers, response), in the identifiable basis."""
        X = actuator_positions(self.rmodel, self.theta, T, U, t)
        term = ResponseTerm(self.rmodel, T, U, list(self.spec.control_names), self.theta, self.steps)
        problem = self._problem(X, t, term)
        state = problem.evaluate(self._z(problem, self.theta))
        if not np.all(state.converged):
            raise NotIdentifiable(f"{self.spec.name}: forward kinematics failed at {int((~state.converged).sum())} "
                                  "samples of the excitation")
        cols = np.concatenate([self.static_cols, problem.i_theta.start + self.theta_cols])
        scale = np.concatenate([self.scale_static, np.full(self.n_theta, 1e-3)])
        J = state.J[..., cols].reshape(-1, len(cols)) * scale
        r = self.V_static.shape[1]
        out = np.empty((J.shape[0], r + self.n_theta))
        out[:, :r] = J[:, :len(self.static_cols)] @ self.V_static
        out[:, r:] = J[:, len(self.static_cols):]
        return out

    def per_sample(self, T, U, t) -> np.ndarray:
        """(r, r) the information per sample (unit noise) in the identifiable basis of the samples at
        times t (W, S): W windows of S samples each, every window's information its slow part
        alone (the rows projected on polynomials of degree SLOW_DEGREE in time, per window)."""
        t = np.atleast_2d(np.asarray(t, float))
        W, S = t.shape
        with blas_threads(1):
            J = self.jacobian(T, U, t.ravel())
            J = J.reshape(W, S, -1, J.shape[1])  # (window, sample, coordinate, column)
            info = np.zeros((J.shape[3], J.shape[3]))
            for w in range(W):
                x = 2 * (t[w] - t[w, 0]) / max(float(t[w, -1] - t[w, 0]), 1e-12) - 1
                Q, _ = np.linalg.qr(np.polynomial.legendre.legvander(x, SLOW_DEGREE))
                Jw = np.einsum("sk,scn->kcn", Q, J[w]).reshape(-1, J.shape[3])  # the slow part's coordinates
                info += Jw.T @ Jw
            return info / (W * S)

    def criterion(self, info: np.ndarray) -> float:
        """The design's criterion of an information matrix (r, r): log det of it plus RESPONSE_WEIGHT
        times log det of the response's information left after the geometry's (its Schur
        complement); -inf where either is singular."""
        sign, val = np.linalg.slogdet(info)
        r = self.V_static.shape[1]
        try:
            left = info[r:, r:] - info[r:, :r] @ np.linalg.solve(info[:r, :r], info[:r, r:])
        except np.linalg.LinAlgError:
            return -np.inf
        sign_r, val_r = np.linalg.slogdet(left)
        if sign <= 0 or sign_r <= 0:
            return -np.inf
        return float(val + RESPONSE_WEIGHT * val_r)

    def prediction(self, info_per_sample: np.ndarray, n_samples: float, sigma_m: float) -> dict:
        """The predicted uncertainty of a fit to ``n_samples`` samples with white marker noise
        ``sigma_m`` (module docstring): 'marker_rms_m' (3-D, over the reference poses; its expected
        square's root), 'marker_rms_p90_m' (its 90th percentile over sessions),
        'parameter_std' (SI, minimum-norm solution), 'logdet_per_sample'; on a tree 'links', per tracked
        link its 'markers' and 'marker_rms_m' (the same figure over its own markers)."""
        info = info_per_sample * n_samples
        sign, logdet = np.linalg.slogdet(info_per_sample)
        if sign <= 0 or not np.isfinite(logdet):
            return {"identifiable": False, "logdet_per_sample": None}
        cov_r = sigma_m ** 2 * np.linalg.inv(info)
        r = self.V_static.shape[1]
        V = np.zeros((self.n_parameters, r + self.n_theta))
        V[:len(self.static_cols), :r] = self.V_static
        V[len(self.static_cols):, r:] = np.eye(self.n_theta)
        cov_scaled = V @ cov_r @ V.T
        scale = np.concatenate([self.scale_static, np.full(self.n_theta, 1e-3)])
        std = np.sqrt(np.maximum(np.diag(cov_scaled), 0)) * scale
        c_static = cov_scaled[:len(self.static_cols), :len(self.static_cols)]
        with blas_threads(1):
            # the squared RMS over the reference markers is d^T G d for the parameters' error d ~ N(0, C):
            # a sum of lambda_i z_i^2 over the eigenvalues of C^1/2 G C^1/2
            G = self.J_ref.T @ self.J_ref / (len(self.J_ref) / 3)
            d, Q = np.linalg.eigh(c_static)
            half = (Q * np.sqrt(np.maximum(d, 0))) @ Q.T
            lam = np.maximum(np.linalg.eigvalsh(half @ G @ half), 0)
        draws = np.random.default_rng(QUANTILE_SEED).standard_normal((QUANTILE_DRAWS, len(lam))) ** 2 @ lam
        out = {"identifiable": True, "logdet_per_sample": float(logdet), "marker_rms_m": float(np.sqrt(lam.sum())),
               "marker_rms_p90_m": float(np.sqrt(np.quantile(draws, 0.9))),
               "parameter_std": {n: {"std": float(s), "unit": u} for n, s, u in zip(self.names, std, self.units)}}
        if self.mapping is not None:  # a tree: the same figure over each tracked link's markers
            rows = self.J_ref.reshape(-1, self.M, 3, self.J_ref.shape[1])
            out["links"] = {}
            for link in dict.fromkeys(self.links):
                J_l = rows[:, [lk == link for lk in self.links]].reshape(-1, self.J_ref.shape[1])
                G_l = J_l.T @ J_l / (len(J_l) / 3)
                out["links"][link] = {"markers": self.links.count(link),
                                      "marker_rms_m": float(np.sqrt(max(np.sum(c_static * G_l), 0.0)))}
        return out


def samples_fitted(duration_s: float, mocap_rate_hz: float, seen: float = 1.0, start_s: float = 0.0) -> int:
    """How many samples calibrate fits from a session of ``duration_s`` s at ``mocap_rate_hz``:
    every sample with a marker seen (share ``seen``) after ``start_s``."""
    return int(math.floor(max(0.0, duration_s - start_s) * mocap_rate_hz * seen))


@dataclass
class ExcitationDesign:
    """A designed excitation: the family, its coefficients, the start's, and the criterion of each
    (:meth:`MotionInformation.criterion` of the information per sample) with the evaluations run."""

    family: FourierFamily
    coef: np.ndarray
    start: np.ndarray
    criterion: float
    criterion_start: float
    evaluations: int
    info_per_sample: np.ndarray
    info_start: np.ndarray
    history: list = field(default_factory=list)


def _windows(start: float, end: float, n_windows: int) -> np.ndarray:
    """(W, WINDOW_SAMPLES) sample times: n_windows windows of SLOW_WINDOW_S spread evenly over
    [start, end], each sampled evenly."""
    span = max(end - start - SLOW_WINDOW_S, 0.0)
    W = max(1, min(n_windows, int(span / SLOW_WINDOW_S) + 1))
    a = start + np.arange(W) * (span / W) + 0.5 * (span / W if W > 1 else 0.0)
    return a[:, None] + (np.arange(WINDOW_SAMPLES) + 0.5) * (SLOW_WINDOW_S / WINDOW_SAMPLES)


def _design_samples(family: FourierFamily, command_rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(command times from -LEAD_S over one period, sample windows over the period (W, S))."""
    T = np.arange(-int(round(LEAD_S * command_rate_hz)), int(round(family.period_s * command_rate_hz))) / command_rate_hz
    return T, _windows(0.0, family.period_s, DESIGN_WINDOWS)


def design_excitation(spec: PlatformSpec, family: FourierFamily, limits: Limits, information: MotionInformation,
                      command_rate_hz: float, rng: np.random.Generator, evaluations: int = 150,
                      progress: Callable[[int, int, float], None] | None = None,
                      start: np.ndarray | None = None) -> ExcitationDesign:
    """The D-optimal member of ``family`` within ``limits`` (module docstring): a (1+1) evolution
    strategy over the coefficients from a random multisine (``start``: given coefficients), each
    candidate at the largest amplitudes its limits and reachability allow. ``progress(k, n,
    logdet)`` after each evaluation."""
    if evaluations < 1:
        raise BadInput(f"evaluations: must be at least 1, got {evaluations}")
    model = information.model
    scaler = Scaler(spec, family, limits, command_rate_hz, model, information.td)
    T, t = _design_samples(family, command_rate_hz)
    Tp = (T % family.period_s)

    def score(coef):
        A, _ = scaler.reachable_period(coef)
        peak = np.max(np.abs(family.raw(coef, scaler.t_period)), axis=0)
        U = scaler.commands(family.raw(coef, Tp) / peak * A)
        info = information.per_sample(T, U, t)
        return information.criterion(info), info

    coef = family.random_multisine(rng) if start is None else np.asarray(start, float).reshape(family.n_u, family.harmonics, 2)
    best, info = score(coef)
    first, info0 = best, info
    c0 = coef.copy()
    step = STEP0
    history = [best]
    if progress is not None:
        progress(1, evaluations, best)
    for k in range(1, evaluations):
        norm = np.sqrt(np.mean(coef ** 2))
        trial = coef + step * norm * rng.normal(size=coef.shape)
        try:
            val, tinfo = score(trial)
        except (NotIdentifiable, BadInput):  # a trial the limits leave still or unreachable: rejected
            val, tinfo = -np.inf, None
        if val > best:
            coef, best, info = trial, val, tinfo
            step = min(step * 1.5, STEP_MAX)
        else:
            step = max(step * 1.5 ** -0.25, STEP_MIN)
        history.append(best)
        if progress is not None:
            progress(k + 1, evaluations, best)
    if not np.isfinite(best):
        raise NotIdentifiable(f"{spec.name}: no excitation of the family identifies the {information.rank} identifiable "
                              "directions (the information stays singular)")
    return ExcitationDesign(family, coef, c0, best, first, evaluations, info, info0, history)


def session_length_for(information: MotionInformation, info_per_sample: np.ndarray, target_m: float, sigma_m: float,
                       mocap_rate_hz: float, seen: float = 1.0, start_s: float = 0.0) -> dict:
    """The shortest session (s) whose predicted marker error (3-D RMS, 90th percentile) meets ``target_m`` with white
    noise ``sigma_m``: the samples it needs, the duration at ``mocap_rate_hz`` with share ``seen``
    of samples seen (fitted from ``start_s``). NotIdentifiable where it needs more than LONGEST_S."""
    if not target_m > 0:
        raise BadInput(f"--target-mm must be positive, got {target_m * 1e3:g}")
    one = information.prediction(info_per_sample, 1.0, sigma_m)
    if not one["identifiable"]:
        raise NotIdentifiable("the excitation does not identify the parameters (the information stays singular)")
    need = math.ceil((one["marker_rms_p90_m"] / target_m) ** 2)  # error ~ 1 / sqrt(n)
    duration = start_s + need / (mocap_rate_hz * seen)
    if duration > LONGEST_S:
        best = one["marker_rms_p90_m"] / math.sqrt(samples_fitted(LONGEST_S, mocap_rate_hz, seen, start_s))
        raise NotIdentifiable(f"--target-mm {target_m * 1e3:g}: needs {duration:.0f} s of motion capture at "
                              f"{mocap_rate_hz:g} samples per s with {sigma_m * 1e3:g} mm noise, over {LONGEST_S:.0f} s "
                              f"(which predicts {best * 1e3:.4g} mm): a larger target, more markers, a faster or quieter "
                              "motion capture")
    return {"target_m": float(target_m), "samples": int(need), "duration_s": float(duration)}


@dataclass
class ExcitationPlan:
    """What ``platkit plan --motion`` writes: commands U (N, n_u) internal units sent at t (N,) s,
    and the report (SI)."""

    t: np.ndarray
    controls: np.ndarray
    report: dict


def predict_trajectory(information: MotionInformation, U: np.ndarray, command_rate_hz: float, duration_s: float,
                        mocap_rate_hz: float, seen: float, sigma_m: float) -> tuple[dict, int]:
    """The prediction for the whole trajectory U streamed from t = 0: the samples calibrate fits
    (from the second command on), 4 * DESIGN_WINDOWS windows of them evaluated evenly at most
    (the information per sample, scaled to the samples fitted)."""
    info, n_fit = trajectory_information(information, U, command_rate_hz, duration_s, mocap_rate_hz, seen)
    return information.prediction(info, n_fit, sigma_m), n_fit


def trajectory_information(information: MotionInformation, U: np.ndarray, command_rate_hz: float, duration_s: float,
                           mocap_rate_hz: float, seen: float) -> tuple[np.ndarray, int]:
    """(the information per sample, the samples calibrate fits) of the whole trajectory U streamed
    from t = 0 (:func:`predict_trajectory`)."""
    T = np.arange(len(U)) / command_rate_hz
    start = T[1]
    n_fit = samples_fitted(duration_s, mocap_rate_hz, seen, start)
    if n_fit < 20:
        raise BadInput(f"a session of {duration_s:g} s at {mocap_rate_hz:g} samples per s gives {n_fit} samples; "
                       "calibrating from motion needs at least 20")
    t = _windows(start, duration_s, 4 * DESIGN_WINDOWS)
    return information.per_sample(T, U, t), n_fit


def plan_excitation(spec: PlatformSpec, limits: Limits, *, period_s: float, harmonics: int, command_rate_hz: float,
                    mocap_rate_hz: float, sigma_m: float, markers: np.ndarray, rng: np.random.Generator,
                    duration_s: float | None = None, target_m: float | None = None, evaluations: int = 200,
                    seen: float = 1.0, progress: Callable[[int, int, float], None] | None = None) -> ExcitationPlan:
    """Design the Fourier family's excitation (:func:`design_excitation`; the via-point family's:
    :func:`platkit.calibrate.sweeps.plan_sweep`) and the session: ``duration_s`` as given,
    else the shortest that meets ``target_m`` (:func:`session_length_for`, then lengthened until the
    whole trajectory's prediction meets it), at least 1.25 periods. The report holds the limits,
    the family and its coefficients, the D-criterion of the design and of the random multisine it
    started from, and the predicted errors of both at the same duration and limits."""
    if duration_s is None and target_m is None:
        raise BadInput("give --duration-s S or --target-mm E (or both: the duration is then checked against the target)")
    if not 0 < command_rate_hz <= 1000:
        raise BadInput(f"command_rate_hz: must be in (0, 1000], got {command_rate_hz:g}")
    if not 0 < mocap_rate_hz <= 10000:
        raise BadInput(f"--rate-hz must be in (0, 10000], got {mocap_rate_hz:g}")
    if not sigma_m > 0:
        raise BadInput("--noise-mm must be positive")
    if duration_s is not None and not (duration_s > 0 and math.isfinite(duration_s)):
        raise BadInput(f"duration_s: must be a positive number of seconds, got {duration_s:g}")
    if duration_s is not None and duration_s > LONGEST_S:
        raise BadInput(f"duration_s: {duration_s:g} s, at most {LONGEST_S:g} s")
    series = FourierFamily(period_s, harmonics, spec.n_u if limits.space is None else spec.n_p)
    if harmonics / period_s > 0.25 * command_rate_hz:
        raise BadInput(f"harmonics: {harmonics} of a {period_s:g} s period reach {harmonics / period_s:g} Hz, over a "
                       f"quarter of the command rate ({command_rate_hz:g} per s)")
    information = MotionInformation(spec, markers, limits=limits)
    design = design_excitation(spec, series, limits, information, command_rate_hz, rng, evaluations, progress)
    shortest = 1.25 * period_s
    length: dict | None = None
    if duration_s is None:
        assert target_m is not None
        length = session_length_for(information, design.info_per_sample, target_m, sigma_m, mocap_rate_hz, seen,
                                    1.0 / command_rate_hz)
        duration = max(shortest, length["duration_s"])
    else:
        duration = float(duration_s)
    for _ in range(8):
        U, meta = trajectory(spec, series, design.coef, limits, duration, command_rate_hz, information.model,
                             information.td)
        pred, n_fit = predict_trajectory(information, U, command_rate_hz, duration, mocap_rate_hz, seen, sigma_m)
        if duration_s is not None or target_m is None or pred["marker_rms_p90_m"] <= target_m:
            break
        duration = min(LONGEST_S, duration * max(1.1, (pred["marker_rms_p90_m"] / target_m) ** 2))
    U_random, _ = trajectory(spec, series, design.start, limits, duration, command_rate_hz, information.model,
                             information.td)
    pred_random, _ = predict_trajectory(information, U_random, command_rate_hz, duration, mocap_rate_hz, seen, sigma_m)
    t = np.arange(len(U)) / command_rate_hz
    report = {
        "kind": "excitation",
        "family": {"name": "fourier", "period_s": float(period_s), "base_frequency_hz": 1.0 / period_s,
                   "harmonics": int(harmonics), "coefficients": np.asarray(design.coef).tolist(),
                   "rule": ("u_j(t) = u0_j + A_j w(t) s_j(t)" if limits.space is None else
                            "p_k(t) = p0_k + A_k w(t) s_k(t) per pose coordinate about the neutral pose, the commands its "
                            "inverse kinematics")
                           + ", s_j = sum_k a_jk sin(2 pi k t / period) + b_jk cos(...) "
                           "scaled to unit peak; w a raised-cosine rise and fall of ramp_s"},
        "limits": {"lower": limits.lower.tolist(), "upper": limits.upper.tolist(), "rate": limits.rate.tolist(),
                   "accel": limits.accel.tolist(), "source": limits.source,
                   "units": "controls' internal units (m for length controls), per s and per s^2"},
        "command_rate_hz": float(command_rate_hz), "duration_s": float(t[-1] + 1.0 / command_rate_hz),
        "n_commands": int(len(U)), "ramp_s": meta["ramp_s"], "amplitude": meta["amplitude"],
        "checked": {k: meta[k] for k in ("box", "rate", "accel", "rate_share", "accel_share")},
        "design": {"evaluations": int(design.evaluations), "criterion": design.criterion,
                   "criterion_random": design.criterion_start,
                   "logdet_per_sample": float(np.linalg.slogdet(design.info_per_sample)[1]),
                   "logdet_per_sample_random": float(np.linalg.slogdet(design.info_start)[1]),
                   "rule": "log det of the information per sample in the identifiable subspace (free parameters, "
                           f"frame, markers, response; gauges left out) plus {RESPONSE_WEIGHT:g} times log det of the "
                           "response's information left after the geometry's; fixed column scales"},
        "prediction": {"noise_m": float(sigma_m), "mocap_rate_hz": float(mocap_rate_hz), "seen": float(seen),
                       "samples_fitted": int(n_fit), "marker_rms_m": pred["marker_rms_m"],
                       "marker_rms_p90_m": pred["marker_rms_p90_m"], "marker_rms_m_random": pred_random["marker_rms_m"],
                       "marker_rms_p90_m_random": pred_random["marker_rms_p90_m"],
                       "identifiable_rank": int(information.rank), "n_parameters": int(information.n_parameters),
                       "parameter_std": pred["parameter_std"],
                       **({"links": pred["links"]} if "links" in pred else {}),  # a tree: per tracked link
                       "definition": "3-D RMS over the stand's reference poses and the markers of the standard deviation "
                                     "of the calibrated model's marker positions, white marker noise per coordinate and "
                                     "sample, every sample calibrate fits; p90: the 90th percentile over sessions "
                                     "(the error of the parameters drawn from their predicted covariance)"},
    }
    if target_m is not None:
        report["target"] = {"target_m": float(target_m), "met": bool(pred["marker_rms_p90_m"] <= target_m),
                            "duration_s": report["duration_s"], **({} if length is None else {
                                "samples_needed": length["samples"]})}
    return ExcitationPlan(t, U, report)


def write_commands_csv(path, spec: PlatformSpec, t: np.ndarray, U: np.ndarray, length_unit: str) -> None:
    """commands.csv of the session format: ``t`` (s), then the control columns in the file's units."""
    V = controls_from_si(spec, U, length_unit)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["t"] + list(spec.control_names))
        for ti, row in zip(t, V):
            w.writerow([f"{ti:.6f}"] + [f"{v:.9g}" for v in row])
