"""The via-point family of ``platkit plan --motion`` (``--family via``, the default): sweeps through
via points (:mod:`platkit.calibrate.via_points`) predicted with the information of the model
calibrate fits to a stream (:mod:`platkit.calibrate.excitation`), and the session's length for a
target accuracy.

:func:`design_sweep` tries the stroke box less the margin, then boxes scaled about the neutral
controls by each share of VIA_SCALES in turn (slow drives fit few far-apart via points in the
whole box, more in a smaller one), each with D-optimal via points and with random candidates,
and keeps the sweep whose predicted marker error (90th percentile over sessions) is the smallest;
the boxes stop shrinking at the first that predicts worse than the best so far.
:func:`plan_sweep` is :func:`platkit.calibrate.excitation.plan_excitation` for this family.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from platkit.calibrate.excitation import (
    LONGEST_S,
    RESPONSE_WEIGHT,
    ExcitationPlan,
    MotionInformation,
    session_length_for,
    trajectory_information,
)
from platkit.calibrate.trajectories import Limits, home_controls, limit_violations
from platkit.calibrate.via_points import ViaDesign, design_via, via_trajectory
from platkit.errors import NotIdentifiable
from platkit.model import PlatformSpec

__all__ = ["FAMILIES", "VIA_SCALES", "Sweep", "design_sweep", "plan_sweep"]

#: the trajectory families of ``plan --motion``: via-point sweeps (this module), or a Fourier series
#: per control with D-optimal coefficients (:func:`platkit.calibrate.excitation.plan_excitation`)
FAMILIES = ("via", "fourier")

#: the via-point family's boxes: the stroke box less the margin scaled about the neutral controls by
#: each share in turn, while the prediction improves (slow drives: a smaller box fits more via points)
VIA_SCALES = (1.0, 0.7, 0.5, 0.35, 0.25)
#: for a target, a sweep designed shorter that misses it is lengthened by this factor at a time
SHRUNK_STEP = 1.4


@dataclass
class Sweep:
    """A via-point sweep and its prediction: the design, commands U (N, n_u), its length (s), the
    information per sample, the samples fitted, the prediction for the noise given, the share of
    the box its via points were drawn in."""

    design: ViaDesign
    U: np.ndarray
    duration_s: float
    info: np.ndarray
    n_fit: int
    pred: dict
    scale: float

    @property
    def p90(self) -> float:
        return self.pred["marker_rms_p90_m"] if self.pred.get("identifiable") else math.inf


def design_sweep(spec: PlatformSpec, limits: Limits, information: MotionInformation, duration_s: float,
                 command_rate_hz: float, mocap_rate_hz: float, seen: float, sigma_m: float,
                 seed: int) -> tuple[Sweep, Sweep]:
    """(the sweep to stream, the other choice in its box): for each box of VIA_SCALES in turn, the
    sweep through D-optimal via points and the one through random candidates (the same seed,
    length and limits), each predicted; the smallest predicted error (90th percentile) is kept,
    and the boxes stop shrinking when a box predicts worse than the best so far. NotIdentifiable
    (a longer session) where no box fits a sweep in ``duration_s``."""
    u0 = home_controls(spec, limits)
    best: tuple[Sweep, Sweep] | None = None
    error: NotIdentifiable | None = None
    for scale in VIA_SCALES:
        box = Limits(u0 - scale * (u0 - limits.lower), u0 + scale * (limits.upper - u0), limits.rate, limits.accel,
                     limits.source, limits.home, None if limits.space is None else limits.space.scaled(scale))
        pair = []
        for choice in (True, False):
            try:
                design = design_via(spec, box, information.markers, duration_s, command_rate_hz,
                                    np.random.default_rng(seed), information.model, information.td, choice)
            except NotIdentifiable as exc:  # too short for this box: a smaller one may fit
                error = exc
                break
            U, _ = via_trajectory(design.path, box, command_rate_hz, information.model, information.td)
            actual = len(U) / command_rate_hz
            info, n_fit = trajectory_information(information, U, command_rate_hz, actual, mocap_rate_hz, seen)
            pair.append(Sweep(design, U, actual, info, n_fit, information.prediction(info, n_fit, sigma_m), scale))
        if len(pair) < 2:
            continue
        pair.sort(key=lambda sw: sw.p90)
        if best is not None and pair[0].p90 >= best[0].p90:
            break
        best = (pair[0], pair[1])
    if best is None:
        assert error is not None
        raise error
    return best


def plan_sweep(spec: PlatformSpec, limits: Limits, *, command_rate_hz: float, mocap_rate_hz: float, sigma_m: float,
              markers: np.ndarray, rng: np.random.Generator, duration_s: float | None, target_m: float | None,
              seen: float) -> ExcitationPlan:
    """``plan --motion``'s via-point family (:func:`design_sweep`): the sweep of
    ``duration_s`` s at most; for ``target_m`` alone, the sweep of 60 s, then designed again at
    the length its information per sample says the target needs (shorter or longer), lengthened
    until its prediction meets the target (the shortest that met is kept); beside it the other
    choice of via points in its box."""
    information = MotionInformation(spec, markers, limits=limits)
    seed = int(rng.integers(2 ** 31))
    duration = float(duration_s) if duration_s is not None else 60.0
    length: dict | None = None
    met: tuple[Sweep, Sweep] | None = None  # the shortest sweep so far that meets the target
    shrunk = False
    for _ in range(12):
        try:
            chosen, other = design_sweep(spec, limits, information, duration, command_rate_hz, mocap_rate_hz, seen,
                                         sigma_m, seed)
        except NotIdentifiable:  # for a target, a session too short for a sweep is lengthened
            if duration_s is not None or duration >= LONGEST_S:
                raise
            duration = min(LONGEST_S, 2 * duration)
            continue
        if duration_s is not None or target_m is None:
            break
        if chosen.p90 <= target_m:
            if met is None or chosen.duration_s < met[0].duration_s:
                met = (chosen, other)
            length = session_length_for(information, chosen.info, target_m, sigma_m, mocap_rate_hz, seen,
                                        1.0 / command_rate_hz)
            if shrunk or length["duration_s"] >= 0.9 * chosen.duration_s:
                break
            shrunk, duration = True, length["duration_s"]  # shorter suffices by its information: designed again
            continue
        if shrunk:  # a shorter sweep has fewer via points, less information per sample: lengthened step by step
            duration *= SHRUNK_STEP
        else:
            length = session_length_for(information, chosen.info, target_m, sigma_m, mocap_rate_hz, seen,
                                        1.0 / command_rate_hz)
            duration = max(duration * 1.1, length["duration_s"])
        duration = min(LONGEST_S, duration)
        if met is not None and duration >= met[0].duration_s:  # lengthened back to one that met
            break
    if met is not None:
        chosen, other = met
    if target_m is not None and duration_s is None:  # what the sweep written needs, for the report
        try:
            length = session_length_for(information, chosen.info, target_m, sigma_m, mocap_rate_hz, seen,
                                        1.0 / command_rate_hz)
        except NotIdentifiable:
            length = None
    if not chosen.pred["identifiable"]:
        raise NotIdentifiable(f"{spec.name}: the via-point sweep does not identify the parameters (the information "
                              "stays singular); try a longer session (--duration-s)")
    design, U, actual, info, n_fit, pred = (chosen.design, chosen.U, chosen.duration_s, chosen.info, chosen.n_fit,
                                            chosen.pred)
    d_opt, rand = (chosen, other) if design.info["choice"] == "d_optimal" else (other, chosen)
    random_design, info_random, pred_random = rand.design, rand.info, rand.pred
    info_d_optimal, pred_d_optimal = d_opt.info, d_opt.pred
    checked = limit_violations(U, command_rate_hz, limits)
    report = {
        "kind": "excitation",
        "family": {"name": "via", **design.info, "box_share": chosen.scale,
                   "random_via_points": random_design.info["via_points"],
                   "path": design.path.tolist(),
                   "rule": "via points D-optimal over reachable settled poses inside the box (as plan --optimal "
                           "chooses holds; 'choice': random where a sweep through random candidates of the same "
                           "length and limits predicts a smaller error, 90th percentile), visited in "
                           "nearest-neighbour order from the home controls (limits.home: neutral, or the box's middle for a "
                           "control whose neutral is on or past the box) and back, "
                           + ("joined by straight moves in control space on one trapezoidal profile per move at the "
                              "largest rate and acceleration every actuator's limits allow; no holds" if limits.space is None
                              else "drawn as poses in the pose box (a pose-free stand), joined by straight moves in "
                              "pose space, the commands their inverse kinematics, on one trapezoidal profile per move "
                              "within every actuator's limits along the line; no holds")},
        "limits": {"lower": limits.lower.tolist(), "upper": limits.upper.tolist(), "rate": limits.rate.tolist(),
                   "accel": limits.accel.tolist(), "source": limits.source,
                   "units": "controls' internal units (m for length controls), per s and per s^2"},
        "command_rate_hz": float(command_rate_hz), "duration_s": float(actual), "n_commands": int(len(U)),
        "stroke_share": [None if w <= 0 else float(r / w)  # None: a control held (it moves no tracked link)
                         for r, w in zip(np.ptp(U, axis=0), limits.upper - limits.lower)],
        "checked": {k: checked[k] for k in ("box", "rate", "accel", "rate_share", "accel_share")},
        "design": {"criterion": information.criterion(info), "criterion_random": information.criterion(info_random),
                   "criterion_d_optimal": information.criterion(info_d_optimal),
                   "logdet_per_sample": pred["logdet_per_sample"],
                   "logdet_per_sample_random": pred_random["logdet_per_sample"],
                   "rule": "the via points: log det of the settled poses' information (plan --optimal's); the "
                           f"criterion said: the stream's, as the Fourier family's (log det plus {RESPONSE_WEIGHT:g} "
                           "times the response's information left after the geometry's)"},
        "prediction": {"noise_m": float(sigma_m), "mocap_rate_hz": float(mocap_rate_hz), "seen": float(seen),
                       "samples_fitted": int(n_fit), "marker_rms_m": pred["marker_rms_m"],
                       "marker_rms_p90_m": pred["marker_rms_p90_m"],
                       "marker_rms_m_random": pred_random.get("marker_rms_m"),
                       "marker_rms_p90_m_random": pred_random.get("marker_rms_p90_m"),
                       "marker_rms_m_d_optimal": pred_d_optimal.get("marker_rms_m"),
                       "marker_rms_p90_m_d_optimal": pred_d_optimal.get("marker_rms_p90_m"),
                       "random": "a sweep through random reachable candidates, the same duration and limits",
                       "identifiable_rank": int(information.rank), "n_parameters": int(information.n_parameters),
                       "parameter_std": pred["parameter_std"],
                       **({"links": pred["links"]} if "links" in pred else {}),  # a tree: per tracked link
                       "definition": "3-D RMS over the stand's reference poses and the markers of the standard deviation "
                                     "of the calibrated model's marker positions, white marker noise per coordinate and "
                                     "sample, every sample calibrate fits; p90: the 90th percentile over sessions"},
    }
    if target_m is not None:
        report["target"] = {"target_m": float(target_m), "met": bool(pred["marker_rms_p90_m"] <= target_m),
                            "duration_s": float(actual), **({} if length is None else {"samples_needed": length["samples"]})}
    return ExcitationPlan(np.arange(len(U)) / command_rate_hz, U, report)
