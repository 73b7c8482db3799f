"""Calibration from motion of a stream of rigid bodies alone (no markers): each body read as three
points fixed to it, calibrated from motion as markers are (:mod:`platkit.calibrate.motion`), and
the calibration written with the body again.

A body T becomes the points ``T.o`` (its origin), ``T.x`` and ``T.y`` (the tips of its x and y axes
at :data:`platkit.bodies.AXIS_LENGTH_M`), :func:`platkit.bodies.body_frame_points`, sample by sample;
on a tree they ride on the body's link. The points are seen exactly where the body is, so the
stream's windows, the response's start and the first command's transient are found from them as
from markers. The fit over the points is read back into each body's placement
(:func:`platkit.bodies.placement_from_point_fit`: origin; axes by Gram-Schmidt; the position std the
origin's, the rotation std the tips' beyond the origin's over the lever).

The points' noise per coordinate (:func:`point_sigmas`): declared (``rigid_body_noise``: the origin
sigma_p, a tip sqrt(sigma_p^2 + 2/3 (sigma_r L)^2), a turn moving two of its three coordinates),
else measured on the stream (platkit.settle.estimate_noise on the origins, and on the tips apart).
The misfit rule of calibrate_motion (the fit's RMS against MISFIT_RATIO times the markers' own noise)
compares with their RMS per axis: the distances between one body's points are rigid by
construction, so the markers' floor from pair distances (marker_noise_floor) reads about 0 there
and would refuse every fit. The bodies' rotation weight (rho): the declared one, else sigma_p over
the tips' rotation noise, as measured.

Nothing dropped silently: the body samples used and not, per body and cause, in the report
(``motion.samples.rigid_bodies``, :func:`platkit.calibrate.motion_bodies.say_bodies`), and what was
done in ``motion.bodies_as_points`` and a warning.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from platkit.bodies import AXIS_LENGTH_M, bodies_from_points, body_frame_points, frame_point_names, rotation_sigma
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_bodies import say_bodies
from platkit.calibrate.stream import NODES, RAW_SAMPLES, WINDOW_S, stream_windows
from platkit.errors import BadSession
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.model import PlatformSpec
from platkit.poses import PoseSet
from platkit.settle import estimate_noise

__all__ = ["bodies_alone", "calibrate_motion_bodies", "point_session", "point_sigmas"]

#: what was done, said in the report (motion.bodies_as_points.rule)
RULE = ("no markers: each rigid body read as three points fixed to it (its origin <body>.o and the tips of its x and "
        f"y axes at {AXIS_LENGTH_M:g} m, <body>.x and <body>.y), calibrated from motion as markers, and its placement "
        "read back from the three fitted points (origin; axes by Gram-Schmidt; position std the origin's, rotation "
        "std the tips' beyond the origin's over the lever); the misfit rule compares with the points' own noise "
        "(declared rigid_body_noise, else measured on the stream), not with the distances between them (rigid by "
        "construction)")


def bodies_alone(session: Session) -> bool:
    """Whether ``session`` streams rigid bodies and no markers (calibrated through :func:`calibrate_motion_bodies`)."""
    return bool(session.body_names) and not session.marker_names and session.bodies is not None


def point_session(session: Session) -> Session:
    """``session`` with each rigid body as three markers (module docstring) and no body; on a tree
    each point on its body's link. BadSession where a base marker has a point's name."""
    names = [n for b in session.body_names for n in frame_point_names(b)]
    clash = sorted(set(names) & set(session.base_marker_names or []))
    if clash:
        raise BadSession(f"{session.folder / 'session.yaml'}: base marker {clash[0]!r} has the name a point of a rigid "
                         "body takes when the bodies alone are calibrated from motion; rename the base marker")
    link = session.moving_link
    if isinstance(link, dict):
        link = {**{k: v for k, v in link.items() if k not in session.body_names},
                **{p: link[b] for b in session.body_names if b in link for p in frame_point_names(b)}}
    return replace(session, markers=body_frame_points(np.asarray(session.bodies, float)), marker_names=names,
                   bodies=None, body_names=[], body_noise={}, moving_link=link)


def point_sigmas(body_names: list[str], body_noise: dict,
                 stream: np.ndarray | None = None) -> tuple[dict[str, float], str]:
    """{point: noise sigma per coordinate of one sample (m)} of the bodies' points and where it
    comes from: 'declared' from ``body_noise`` ({'position_m', 'rotation_rad'}: the origin sigma_p,
    a tip sqrt(sigma_p^2 + 2/3 (sigma_r L)^2), a turn moving two of its three coordinates); else
    'measured' on ``stream`` (K >= 3, B, 7), the body samples, by platkit.settle.estimate_noise (the
    origins, and the tips apart); ({}, 'unknown') with neither. A caller that trusts the stream
    over the declaration passes no ``body_noise`` where it has a stream."""
    out: dict[str, float] = {}
    if body_noise:
        sp, sr = float(body_noise["position_m"]), float(body_noise["rotation_rad"])
        tip = float(np.sqrt(sp ** 2 + 2.0 / 3.0 * (sr * AXIS_LENGTH_M) ** 2))
        for b in body_names:
            out.update(zip(frame_point_names(b), (sp, tip, tip)))
        return out, "declared"
    if stream is None or len(stream) < 3 or np.asarray(stream).shape[1] != len(body_names):
        return out, "unknown"
    pts = body_frame_points(np.asarray(stream, float))
    for k, b in enumerate(body_names):
        o, tips = estimate_noise(pts[:, 3 * k:3 * k + 1]), estimate_noise(pts[:, 3 * k + 1:3 * k + 3])
        out.update(zip(frame_point_names(b), (o, tips, tips)))
    return out, "measured"


def _rho(body_names: list[str], sigmas: dict[str, float]) -> float:
    """The bodies' rotation weight (m/rad) from their points' noise: the origins' over the tips'
    rotation noise (the tip's variance beyond the origin's, a turn moving two of its three
    coordinates, over the lever), the median over the bodies; NaN where a tip is no noisier."""
    sp = np.array([sigmas[frame_point_names(b)[0]] for b in body_names])
    st = np.array([sigmas[frame_point_names(b)[1]] for b in body_names])
    sr = rotation_sigma(sp, st)
    return float(np.median(sp / sr)) if np.all(sr > 0) else float("nan")


def calibrate_motion_bodies(session: Session, spec: PlatformSpec, **options) -> tuple[Calibration, PoseSet]:
    """Calibrate ``spec`` from the whole stream of ``session``, rigid bodies and no markers
    (module docstring), with calibrate_motion's ``options``. Returns the calibration with the
    bodies (its ``motion.bodies_as_points`` says how they were read, ``motion.samples.rigid_bodies``
    which body samples served) and the pose set of the nodes fitted (the bodies' points as markers)."""
    if not bodies_alone(session):
        raise BadSession(f"{session.folder / 'session.yaml'}: calibrating rigid bodies alone from motion needs a stream "
                         "of rigid bodies and no markers")
    points = point_session(session)
    sigmas, source = point_sigmas(session.body_names, session.body_noise, session.bodies)
    floor = float(np.sqrt(np.mean(np.square(list(sigmas.values())))))
    cal, poses = calibrate_motion(points, spec, noise_floor_m=floor, **options)
    transient = cal.motion["samples"].get("start_transient") or {}
    win = stream_windows(points, options.get("window_s", WINDOW_S), options.get("nodes", NODES),
                         options.get("raw_samples", RAW_SAMPLES),
                         start_t=transient.get("until_s") if transient.get("n_samples") else None,
                         end_t=cal.motion["samples"].get("log_end_s"))
    cal = bodies_from_points(cal, session.body_names, _rho(session.body_names, sigmas),
                             "declared" if source == "declared" else "estimated")
    say_bodies(session, win, cal)  # the body samples used, and the others, per body and cause
    names = [n for b in session.body_names for n in frame_point_names(b)]
    cal.motion["bodies_as_points"] = {
        "bodies": list(session.body_names), "points": names, "lever_m": AXIS_LENGTH_M,
        "point_sigma_m": sigmas, "noise_source": source, "noise_floor_m": floor, "rule": RULE}
    cal.warnings.append(
        f"no markers: rigid bodies {', '.join(session.body_names)} read as {len(names)} points (origin and two axis "
        f"tips at {AXIS_LENGTH_M:g} m each) and calibrated from motion as markers; their noise {source} "
        f"({1e3 * floor:.3g} mm per axis RMS), the placements read back from the fitted points "
        "(report: motion.bodies_as_points)")
    return cal, poses
