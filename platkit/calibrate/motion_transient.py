"""The first command's transient at a stream's start, left out of a calibration from motion
(:mod:`platkit.calibrate.motion`, step 3).

The response model starts every actuator at rest on the first command (:mod:`platkit.calibrate.
response`): where the stand was before it is not logged. Where it rested elsewhere, the stand's
motion after the first command is the model's plus the free response from that unknown state;
the samples that free response still moves are not the model's, and they must not drive the fit
(a gross transient drags the robust fit's first, unweighted pass). The rule
(:func:`start_transient`), at the response's start (the nominal geometry, the frame and markers
registered, the response fitted to the travel):

1. each sample's residual: the RMS over its markers seen of the model's markers minus the
   measured; the stream's scale m: their median over samples spread evenly over the stream;
2. the start's gross span: read in runs of RUN samples from the second command on, the samples
   up to the first run whose median residual is within GROSS times m (the outlier bound of
   3-D errors, REJECT_K robust sigmas); where the first run is within it, nothing is left out;
3. the tail: where the residuals stop being gross the transient is still up to GROSS m, and it
   decays at least as fast as the slowest response of the actuators the stream moves (a first
   order's time constant tau; a second order's tau max(2 zeta, 1 / zeta), the larger of its lag
   and its envelope); the samples are left out until that bound has fallen to TAIL_NOISE_SHARE
   of the markers' own 3-D noise (from the distances between markers on one link; the scale m
   where no link carries two markers): what is left of the transient then adds at most
   TAIL_NOISE_SHARE squared to a sample's noise variance;
4. at most MAX_SHARE of the stream: a start gross for longer is not a transient the response
   explains; it is said and nothing is left out (the fit's outlier rule and misfit check judge).

The samples left out are counted and said (report ``motion.samples.start_transient``, a warning,
the summary line).
"""
from __future__ import annotations

import numpy as np

from platkit.calibrate.estimate import pair_noise
from platkit.calibrate.motion_start import marker_points
from platkit.calibrate.response import ResponseModel, actuator_positions
from platkit.calibrate.robust import MAXWELL_MEDIAN, REJECT_K
from platkit.io.session import Session
from platkit.model import PlatformSpec

__all__ = ["GROSS", "MAX_SHARE", "RUN", "SCALE_SAMPLES", "TAIL_NOISE_SHARE", "noise_3d", "say_transient", "settle_time_s",
           "start_transient"]

#: a residual beyond GROSS times the stream's median is gross (the 3-D outlier bound: REJECT_K
#: robust sigmas, the median of a 3-D error being MAXWELL_MEDIAN sigmas)
GROSS = REJECT_K / MAXWELL_MEDIAN
#: the start's residuals are read in runs of RUN samples (one sample's outlier ends no span)
RUN = 5
#: the stream's residual scale from at most SCALE_SAMPLES samples spread evenly over it
SCALE_SAMPLES = 600
#: the most of the stream's samples a start transient may span
MAX_SHARE = 0.25
#: the tail lasts until the transient's bound is this share of the markers' 3-D noise (a tenth:
#: at most 1 % of a sample's noise variance left to the transient)
TAIL_NOISE_SHARE = 0.1


def settle_time_s(rmodel: ResponseModel, theta, moved: np.ndarray) -> float:
    """The slowest decay time (s) of the free response among the actuators ``moved`` (n_u,)
    bool: a first order's tau; a second order's tau max(2 zeta, 1 / zeta) (its lag 2 zeta tau
    bounds its slow pole's time constant when overdamped; 1 / zeta its envelope's when not)."""
    par = rmodel.split(theta)
    out = 0.0
    for j in np.nonzero(moved)[0]:
        tau = float(par["tau_s"][j])
        if rmodel.is_second(j):
            zeta = max(float(par["damping"][j]), 1e-3)
            tau *= max(2.0 * zeta, 1.0 / zeta)
        out = max(out, tau)
    return out


def noise_3d(Y: np.ndarray, links) -> float:
    """The markers' own 3-D noise RMS (m) from samples Y (K, M, 3): sqrt(3) times the per-axis
    noise of the distances between markers on one link (:func:`platkit.calibrate.estimate.
    pair_noise`; ``links`` (M,), None: one body). NaN where no link carries two markers seen
    together in three samples."""
    return float(np.sqrt(3) * pair_noise(Y, links))


def _residuals(session: Session, spec: PlatformSpec, rmodel: ResponseModel, theta, geom, k: np.ndarray,
               start=None) -> np.ndarray:
    """(len(k),) each sample's RMS marker residual (m) at the geometry ``geom`` (kinematic model,
    links, td, A, b, markers) and the response ``theta``; NaN where no marker is seen."""
    model, links, td, A, b, mk = geom
    X = actuator_positions(rmodel, theta, session.command_t, session.commands, session.marker_t[k], start=start)
    P = marker_points(spec, model, td, mk, links, X) @ A.T + b
    d2 = np.sum((P - session.markers[k]) ** 2, axis=2)
    with np.errstate(invalid="ignore"):
        out = np.sqrt(np.nanmean(np.where(np.isfinite(d2), d2, np.nan), axis=1))
    return out


def start_transient(session: Session, spec: PlatformSpec, rmodel: ResponseModel, theta, geom, first: int,
                    start=None, end: int | None = None) -> dict:
    """The samples the first command's transient spans, from sample ``first`` (the first at or after
    the second command) on, before sample ``end`` (the first past the end of a log cut in motion,
    :func:`platkit.calibrate.stream.past_log_end`; None: the stream's end) (module docstring's
    rule), at the response ``theta`` and the geometry
    ``geom`` (kinematic model, each marker's link, td, A, b, markers). Returns the report's
    ``start_transient``: ``until_s`` (motion-capture clock; None: nothing left out), ``n_samples``
    left out (samples with a marker seen), the residual scale, the gross span's end and the tail
    (s), and the rule; ``said``: why nothing was left out where a gross start was not taken."""
    tm = session.marker_t
    seen = np.isfinite(session.markers).all(axis=2).any(axis=1)
    cand = first + np.nonzero(seen[first:end])[0]
    out: dict = {"until_s": None, "n_samples": 0, "rule": _rule()}
    if len(cand) < 2 * RUN:
        return out
    spread = cand[np.unique(np.linspace(0, len(cand) - 1, min(len(cand), SCALE_SAMPLES)).astype(int))]
    scale = float(np.nanmedian(_residuals(session, spec, rmodel, theta, geom, spread, start)))
    out["residual_scale_m"] = scale
    if not np.isfinite(scale) or scale <= 0:
        return out
    limit = int(MAX_SHARE * len(cand))
    end = None
    for a in range(0, limit, 8 * RUN):  # a block of runs at a time
        r = _residuals(session, spec, rmodel, theta, geom, cand[a:min(a + 8 * RUN, limit + RUN)], start)
        for i in range(0, len(r) - RUN + 1, RUN):
            if np.nanmedian(r[i:i + RUN]) <= GROSS * scale:
                end = a + i
                break
        if end is not None:
            break
    if end is None:
        out["said"] = (f"the stream's first {MAX_SHARE:.0%} of samples are all off by more than {GROSS:.3g} times "
                       "its median residual: not a start transient the response explains; nothing left out")
        return out
    if end == 0:
        return out
    moved = np.ptp(session.commands, axis=0) > 0
    tau = settle_time_s(rmodel, theta, moved)
    mk_links = geom[1]
    Y = session.markers[spread]
    noise = noise_3d(Y, mk_links)
    floor = noise if np.isfinite(noise) and 0 < noise < GROSS * scale else scale
    tail = tau * float(np.log(GROSS * scale / (TAIL_NOISE_SHARE * floor)))
    until = float(tm[cand[end]]) + tail
    n = int(np.sum(tm[cand] < until))
    if n > limit:
        out["said"] = (f"the first command's transient would span {n} of the stream's {len(cand)} samples, more than "
                       f"{MAX_SHARE:.0%}: not a start transient the response explains; nothing left out")
        return out
    out.update({"until_s": until, "n_samples": n, "gross_until_s": float(tm[cand[end]]), "tail_s": tail,
                "settle_tau_s": tau, "noise_3d_m": noise, "from_s": float(tm[cand[0]])})
    return out


def _rule() -> str:
    return (f"the stand's state before the first command is not logged: from the second command on, the samples "
            f"whose residual at the response's start (runs of {RUN}, median) is over {GROSS:.3g} times the stream's "
            "median residual are the first command's transient, and so are those after, until that bound has "
            f"decayed to {TAIL_NOISE_SHARE:g} of the markers' own 3-D noise at the slowest response of the actuators "
            "moved; at most "
            f"{MAX_SHARE:.0%} of the stream")


def say_transient(transient: dict, cal) -> None:
    """The first command's transient said in ``cal``'s warnings: the samples left out, or why a
    gross start was not taken for it; nothing where the stream starts on the first command."""
    if transient.get("n_samples"):
        cal.warnings.append(
            f"the stream's first {transient['until_s'] - transient['from_s']:.3g} s from the second command "
            f"({transient['n_samples']} samples) left out of the fit: the stand's state before the first command is "
            "not logged and the first command's transient spans them (its residuals over "
            f"{GROSS:.3g} times the stream's median until {transient['gross_until_s']:.3f} s, then "
            f"{transient['tail_s']:.3g} s for it to decay to {TAIL_NOISE_SHARE:g} of the markers' noise) "
            "(report: motion.samples.start_transient)")
    elif transient.get("said"):
        cal.warnings.append(f"the stream's start: {transient['said']} (report: motion.samples.start_transient)")
