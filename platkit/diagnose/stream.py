"""Streams without holds in a diagnosis: the windowed poses a calibration from motion sees in a
stream (:func:`platkit.calibrate.motion.motion_stream`), for the session diagnosed and for a
held-out one, with the noise their floor needs.

- The session diagnosed (:func:`training_stream`): its windows' nodes at the controls the
  calibrated response reaches there, the calibration carrying that response as a term
  (:class:`platkit.calibrate.motion.LocalResponseTerm`) that every fit of the diagnosis frees again.
- A held-out stream (:func:`heldout_stream`, :func:`score_heldout_stream`): its windows cut once,
  by the calibration given (fitted on the other session: nothing of the held-out stream is fitted),
  and each model scored reads the held-out controls through its own response (the geometric
  model's, refitted with the geometry; the diagnosed model's, refitted with its effects), so an
  effect that changes the fitted response is judged with it, as it would predict a new recording;
  where a model carries no response (a session with holds diagnosed), the calibration's.
- The samples left out of both (motion_stream's rules, said in the line each stream's reading
  warns): the first command's transient, and the samples past the end of a command log cut in
  motion, read through the calibration's response (platkit.calibrate.stream.past_log_end).
- The direction of each actuator's last move at each windowed pose (``extras['direction']``, what
  a history effect such as backlash reads; :func:`stream_direction`): from the command log through
  the actuator's response lag, the same rule for both streams, never from the fitted controls.
- What a play (backlash) reads at each windowed pose (``extras['play']``, ``['play_path']``,
  ``['play_weight']``; :func:`stream_play`): the play's memory of the drives' positions (the
  response's, at the calibration's values: the drive the play sits in overshoots and lags its
  commands) at the first sample the pose's window weighs, those positions at its samples and the
  weights; the term carries the play through them and weighs it as the controls are.
- The noise of each channel per coordinate (``settling['point_sigma_m']``, read by
  :func:`platkit.diagnose.floor.noise_floor`): a marker's measured on the stream
  (platkit.settle.estimate_noise, marker by marker: session.yaml declares no marker noise); a rigid
  body's points measured on the body stream (:func:`platkit.calibrate.motion_points.point_sigmas`),
  else declared (``rigid_body_noise``): the floor judges the data, as for settled poses
  (:func:`platkit.diagnose.bodies.as_points`); calibrate weighs by the declared noise first.
- What the location tests can say of windowed poses (:func:`nodes_share_noise`): neighbouring nodes
  share the motion capture's coloured noise, so structure in time or over near commands is evidence
  of a lack of fit only where held-out prediction sees it too.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse

from platkit.bodies import AXIS_LENGTH_M, frame_point_names
from platkit.calibrate.motion import LocalResponseTerm, ResponseTerm, motion_stream
from platkit.calibrate.motion_points import bodies_alone, point_session, point_sigmas
from platkit.calibrate.response import actuator_positions
from platkit.calibrate.stream import NODES, PROJ_SAMPLES, commanded_direction, response_lag
from platkit.diagnose.bodies import as_points, point_calibration
from platkit.diagnose.evidence import _score_heldout
from platkit.effects import with_history
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.model import PlatformSpec
from platkit.notices import warn
from platkit.play import play_cut, play_memory
from platkit.poses import PoseSet
from platkit.settle import estimate_noise

__all__ = ["HeldoutStream", "heldout_stream", "marker_sigmas", "nodes_share_noise", "read_through", "score_heldout_stream",
           "stream_direction", "stream_play", "stream_poses", "stream_why", "training_stream", "windows_of",
           "STREAM_PLAY_DEPTH"]

#: the most turning points of a drive's positions a stream's play remembers at each pose
#: (platkit.play.play_memory's depth; the poses where it bit are counted and said)
STREAM_PLAY_DEPTH = 32


def marker_sigmas(session: Session) -> dict[str, float]:
    """{marker: noise sigma per coordinate of one sample (m)} measured on ``session``'s marker
    stream (K, M, 3), each marker apart (platkit.settle.estimate_noise: the median absolute second
    difference); {} with under three samples."""
    Y = None if session.markers is None else np.asarray(session.markers, float)
    if Y is None or len(Y) < 3:
        return {}
    return {n: float(estimate_noise(Y[:, m:m + 1])) for m, n in enumerate(session.marker_names)}


def nodes_share_noise(poses: PoseSet) -> bool:
    """True for a stream's windowed poses (their nodes in ``extras['node']``, as
    :func:`platkit.calibrate.motion.motion_stream` makes them): three nodes per window of about a
    second share the motion capture's coloured noise (a part correlated over tenths of a second,
    which a window's fit does not average as it averages white noise, and which the sample-to-sample
    noise the floor is built from does not see), so the location tests in time and over near
    commands (Ljung-Box, runs, the neighbour tests) find structure in the residuals of a model that
    is right. On such poses, structure the tests find is a lack of fit only where the geometric
    model predicts held-out poses beyond ``lack_of_fit_factor`` times the noise floor, as beside a
    modelled effect (platkit.diagnose.search.Search.structure_left, platkit.diagnose.lack_of_fit).
    False for settled poses: each hold's own samples, seconds apart, and the tests read them as
    they are."""
    return "node" in poses.extras


def _rms_mm(sig: dict[str, float]) -> str:
    return f"{np.sqrt(np.mean(np.square(list(sig.values())))) * 1e3:.3g} mm per axis RMS"


def stream_poses(folder, session: Session, cal: Calibration) -> tuple[PoseSet, LocalResponseTerm, str]:
    """``session``'s stream as the windowed poses ``cal``'s response reads (motion_stream), each
    channel's noise in ``settling['point_sigma_m']`` (module docstring), the response as a term at
    ``cal``'s values, and the clause that says where the noise came from. A stream of rigid bodies
    alone is read as calibrate read it: each body as its three points, ``cal``'s bodies as those
    points; beside markers, a body's three points follow the markers."""
    if bodies_alone(session):  # measured on the stream first: the floor judges the data
        sig, source = point_sigmas(session.body_names, {}, session.bodies)
        if not sig:
            sig, source = point_sigmas(session.body_names, session.body_noise)
        poses, term = motion_stream(point_session(session), point_calibration(cal))
        noise = (f"the points' noise {source} ({_rms_mm(sig)})" if sig
                 else "the points' noise unknown (neither declared nor measurable: no noise floor)")
    else:
        sig = marker_sigmas(session)
        poses, term = motion_stream(session, cal)
        noise = f"the markers' noise measured on the stream ({_rms_mm(sig)})" if sig else "the markers' noise unknown"
        if poses.n_bodies:  # measured on the body stream, else declared (as_points' rule)
            measured = session.bodies is not None and len(session.bodies) >= 3
            poses = as_points(poses, session.bodies, str(folder))
            noise += f", the bodies' points' {'measured on the stream' if measured else 'declared'}"
    poses.settling = {**(poses.settling or {}),
                      "point_sigma_m": {**sig, **((poses.settling or {}).get("point_sigma_m") or {})}}
    memory, path, weight = stream_play(term, np.asarray(poses.extras["node"], int))
    cut = play_cut(memory).any(axis=1)
    if cut.any():
        warn(f"{folder}: {int(cut.sum())} of {poses.n_poses} windowed poses carry more than {STREAM_PLAY_DEPTH} "
             "nested reversals of a drive's positions: a play wider than the oldest kept swing reads that swing's turn")
    poses.extras = {**poses.extras, "direction": stream_direction(session, term, cal.spec, np.asarray(poses.t, float)),
                    "play": memory, "play_path": path, "play_weight": weight}
    return poses, term, noise


def stream_play(term: LocalResponseTerm, node: np.ndarray,
                depth: int = STREAM_PLAY_DEPTH) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a play (platkit.play.play_offset) reads at a stream's nodes ``node`` (P,), each as
    its row of the response's projection (``term.proj``, the window's fit in time) weighs the
    samples, from S the most samples a row spans: the play's memory of the drives' positions from
    the stream's first sample to the row's first (platkit.play.play_memory, at most ``depth``
    turning points) (P, n_u, L, 3), the positions at the row's samples (P, n_u, S) (past its last,
    the last again) and their weights (P, S) (0 there). The positions are the response's at the
    calibration's values (``term.initial``), evaluated PROJ_SAMPLES samples at a time."""
    proj = sparse.csr_matrix(term.proj)[np.asarray(node, int)]
    ip, ix = proj.indptr, proj.indices
    rows = np.repeat(np.arange(proj.shape[0]), np.diff(ip))
    c0 = np.full(proj.shape[0], ix.max(initial=0) if len(ix) else 0)
    c1 = np.zeros(proj.shape[0], int)
    np.minimum.at(c0, rows, ix)
    np.maximum.at(c1, rows, ix)
    c1 = np.maximum(c0, c1)
    S = int((c1 - c0).max(initial=0)) + 1
    sample_t = np.asarray(term.sample_t, float)[:int(c1.max(initial=0)) + 1]
    X = np.concatenate([actuator_positions(term.model, term.initial, term.T, term.U, sample_t[a:a + PROJ_SAMPLES],
                                           start=term.start) for a in range(0, len(sample_t), PROJ_SAMPLES)])
    weight = np.zeros((proj.shape[0], S))
    np.add.at(weight, (rows, ix - c0[rows]), proj.data)
    at = np.minimum(c0[:, None] + np.arange(S)[None, :], c1[:, None])
    return play_memory(X, c0, depth), np.moveaxis(X[at], 2, 1), weight


def stream_direction(session: Session, term: LocalResponseTerm, spec: PlatformSpec, t: np.ndarray) -> np.ndarray:
    """(N, n_u) a history effect's 'direction' at a stream's windowed poses (times ``t``, the
    motion-capture clock): each actuator's last move read from ``session``'s command log through its
    response lag (platkit.calibrate.stream.response_lag: its time lag and its response's delay on a
    ramp) at the response ``term`` carries (the calibration given's, for every model scored), a
    move counting where the commands travel more than platkit.calibrate.stream.DIRECTION_TRAVEL of
    the actuator's stroke (the log's span where the spec gives none) from the last turning point
    (:func:`platkit.calibrate.stream.commanded_direction`); not from the controls the response
    reaches at the windows (whose overshoot after the last command would turn it). The same rule
    for the stream diagnosed and a held-out one."""
    U = np.asarray(session.commands, float)
    lo, hi = spec.control_bounds()
    stroke = np.where(np.isfinite(hi - lo) & (hi > lo), hi - lo, np.ptp(U, axis=0) + 1e-300)
    return commanded_direction(np.asarray(session.command_t, float), U, t, response_lag(term.model, term.initial),
                               stroke)


def _say_bodies(folder, session: Session) -> None:
    """The one line that says a stream's rigid bodies were read as three points each."""
    if not session.body_names:
        return
    said = ", ".join(f"{b} as " + "/".join(frame_point_names(b)) for b in session.body_names)
    if bodies_alone(session):
        warn(f"{folder}: no markers: rigid bodies {', '.join(session.body_names)} diagnosed as three points each "
             f"({said}; origin and axis tips at {AXIS_LENGTH_M * 1e3:g} mm), the stream's windows read from them as "
             "calibrate read them")
    else:
        warn(f"{folder}: rigid bodies diagnosed as three points each, origin and axis tips at "
             f"{AXIS_LENGTH_M * 1e3:g} mm ({said})")


def _transient(term: LocalResponseTerm) -> str:
    """The samples motion_stream left out, in a clause (empty where none): the first command's
    transient, and those past the end of a log cut in motion."""
    left = (term.start_transient or {}).get("n_samples", 0)  # platkit.calibrate.motion_transient's rule
    past = (term.past_the_log or {}).get("n_samples", 0)  # platkit.calibrate.stream.past_log_end's rule
    return ((f"; {left} samples of the first command's transient left out (the stand's state before the first "
             "command is not logged)" if left else "")
            + (f"; {past} samples past the end of the command log left out (it ends in motion: the commands they "
               "follow are not logged)" if past else ""))


def stream_why(settling: dict | None) -> str:
    """Why a session is read as a stream, in words that are true of it, from the settle search's
    refusal (platkit.settle.HoldsNeverSettle.settling): 'no settled holds' where at most one
    settled (a stream, whose last command's hold alone may settle), else 'too few settled holds: '
    and the refusal's reason (e.g. '53 of 120 holds settled; 43 never did (actuator B still moving,
    ...), and only 34 of those extrapolate to rest (80% needed)')."""
    s = settling or {}
    if int(s.get("n_settled") or 0) <= 1:
        return "no settled holds"
    return "too few settled holds: " + str(s.get("reason") or f"{int(s['n_settled'])} of {s.get('n_commands')} settled")


def training_stream(folder, session: Session, cal: Calibration,
                    why: str = "no settled holds") -> tuple[PoseSet, Calibration]:
    """The stream of the session diagnosed (``session``: as read before its settling failed) as
    :func:`stream_poses` reads it, said (``why``: why the stream, :func:`stream_why`), and ``cal`` with the response as a term
    (:class:`LocalResponseTerm`: its Jacobian reused while the response stays linear): every fit of
    the diagnosis frees it again with the geometry, so that an effect and the response are told
    apart by the data."""
    poses, term, noise = stream_poses(folder, session, cal)
    _say_bodies(folder, session)
    warn(f"{folder}: {why}: diagnosed on the stream's {poses.n_poses} windowed poses through the "
         f"calibration's actuator response, fitted again with every effect tried; {noise}" + _transient(term))
    return poses, replace(cal, terms=[*cal.terms, term], theta=[*cal.theta, term.initial.copy()],
                          theta_std=[*cal.theta_std, np.full(len(term.initial), np.nan)])


@dataclass
class HeldoutStream:
    """A held-out stream's windowed poses (``poses``: at the controls the calibration given
    reaches, its nodes in ``extras['node']``) and the response over its own command log
    (``term``), through which each model scored reads the controls (:func:`read_through`)."""

    poses: PoseSet
    term: LocalResponseTerm


def heldout_stream(folder, session: Session, cal: Calibration, why: str = "no settled holds") -> HeldoutStream:
    """The held-out ``session`` (a stream with too few settled holds) cut into windows by ``cal``, the
    calibration given (its response, geometry, frame and markers: the windows, the first command's
    transient and the curvature correction, the same for every model scored), said in one line
    (``why``: why the stream, :func:`stream_why`)."""
    poses, term, noise = stream_poses(folder, session, cal)
    _say_bodies(folder, session)
    warn(f"{folder}: {why}: the held-out stream scored on its {poses.n_poses} windowed poses, cut by "
         "the calibration given, each model reading the controls through its own actuator response (the geometric "
         f"and the diagnosed model's, each refitted on the session diagnosed; nothing fitted here); {noise}"
         + _transient(term))
    return HeldoutStream(poses, term)


def _response_theta(model: Calibration, held: HeldoutStream) -> tuple[LocalResponseTerm, np.ndarray]:
    """The held-out log's response in the kind ``model`` carries (its ResponseTerm's: a diagnosis may
    choose another kind than the calibration given's) and its parameters, else the calibration's."""
    for term, theta in zip(model.terms, model.theta):
        if isinstance(term, ResponseTerm):
            h = held.term
            own = h if term.model == h.model else LocalResponseTerm(
                term.model, h.T, h.U, list(model.spec.control_names), theta, np.zeros(len(theta)), h.start, h.proj,
                h.sample_t)
            return own, np.asarray(theta, float)
    return held.term, np.asarray(held.term.initial, float)


def read_through(held: HeldoutStream, model: Calibration, spec: PlatformSpec | None = None) -> PoseSet:
    """The held-out windowed poses at the controls ``model``'s response reaches at their nodes,
    without the nodes (a term of the session diagnosed adds no offset to another recording) and
    with the history of these controls (platkit.effects.with_history), the direction of motion
    kept as the held-out stream's command log gives it (:func:`stream_direction`)."""
    p = held.poses
    term, theta = _response_theta(model, held)
    controls = term.reached(theta, p)
    out = p.subset(np.arange(p.n_poses))
    out.controls = np.array(controls, float)
    out.extras = {k: v for k, v in p.extras.items() if k != "node"}
    out.dropped = list(p.dropped)
    return with_history(out, spec)


def windows_of(poses: PoseSet) -> np.ndarray:
    """(N,) each windowed pose's window, numbered in time order: motion_stream keeps every window
    of the stream as its NODES nodes, one after another (platkit.calibrate.stream.stream_windows
    with no raw samples)."""
    return np.asarray(poses.extras["node"], int) // NODES


def score_heldout_stream(base: Calibration, final: Calibration, held: HeldoutStream, spec: PlatformSpec,
                         findings) -> dict:
    """diagnosis.json's ``heldout_session`` of a held-out stream: the point RMS (m) of the
    geometric model ``base`` and the diagnosed ``final``, each reading the controls through its
    own response (:func:`read_through`), per marker, the paired one-sided p over the windowed
    poses, and ``n_poses``; each finding's ``heldout_session_rms_before/after`` set, as for settled
    poses. The paired test is given the poses' windows (:func:`windows_of`): a model's errors at
    neighbouring windows of one stream are correlated (platkit.diagnose.stats.serial_signed_rank),
    where the K-fold comparisons on the stream diagnosed are not (interleaved folds put neighbours
    in different folds: docs/diagnosis-stream-tests.md)."""
    out = _score_heldout(base, final, read_through(held, base, spec), spec, findings,
                         heldout_final=read_through(held, final, spec), windows=windows_of(held.poses))
    return {**out, "windowed": True}
