"""Rigid bodies in diagnosis: each body measured in 6 DOF enters as three points rigidly attached
to it, so that every step of diagnosis (noise floor, probes, location tests, K-fold errors,
held-out errors in length units, the worst marker) reads it as it reads markers.

A body T becomes the points ``T.o`` (its origin), ``T.x`` and ``T.y`` (the tips of its x and y axes
at :data:`LEVER_M`), :func:`platkit.bodies.body_frame_points`: the points the settling search of a
stream of bodies alone already reads. They ride on the body's link, their places on it composed from
the body's placement in the calibration diagnosed (:func:`point_calibration`), and the calibration
diagnosis writes carries the body again, its placement read back from the three fitted points
(:func:`body_calibration`), so that ``platkit predict`` reads it on the session with bodies.

Each point's noise per coordinate enters the noise floor (:func:`platkit.diagnose.floor.noise_floor`,
``settling['point_sigma_m']``): measured on the stream (the settling search's estimator on the
stream's points, an origin and the tips apart), else from the declared ``body_noise`` (the origin:
the position noise; a tip: that and the rotation noise over the lever, two of its three coordinates
moved by a turn); each settled point averages its body's ``n_body_samples``. The floor reads the
three as the one 6-DOF measurement they are: a body pose counts 6 observations, and its points'
errors are correlated (platkit.diagnose.floor.pose_noise).

The three points are one 6-DOF measurement, their errors correlated: the score test that screens
candidate terms reads each body at each pose as its position and turn (:func:`screen_system`), not
as nine independent coordinates.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from platkit.bodies import (
    AXIS_LENGTH_M,
    FRAME_POINT_SUFFIXES,
    bodies_from_points,
    body_frame_points,
    frame_point_indices,
    frame_point_names,
    rotation_sigma,
)
from platkit.calibrate.motion_points import point_sigmas
from platkit.errors import BadInput
from platkit.geometry import matrix_from_rotvec
from platkit.io.calibration import Calibration
from platkit.poses import PoseSet

#: the lever (m) of a body's axis points: body_frame_points', so that a stream's settling noise is theirs
LEVER_M = AXIS_LENGTH_M
#: the points in the body's frame (3, 3) m, in FRAME_POINT_SUFFIXES' order (platkit.bodies)
_IN_BODY = np.array([[0.0, 0.0, 0.0], [LEVER_M, 0.0, 0.0], [0.0, LEVER_M, 0.0]])
#: the Levi-Civita symbol: (w x v)_i = eps_ijk w_j v_k, so w x v is the matrix eps_ijk v_k acting on w
_LEVI_CIVITA = np.zeros((3, 3, 3))
for _i, _j, _k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_i, _j, _k], _LEVI_CIVITA[_i, _k, _j] = 1.0, -1.0


def on_bodies(findings, body_names: list[str]) -> None:
    """Each finding located at a body's point (``where['marker']``, e.g. ``T1.x``) also names the
    body (``where['rigid_body']``), in place."""
    owner = {p: b for b in body_names for p in frame_point_names(b)}
    for f in findings:
        body = owner.get(f.where.get("marker"))
        if body is not None:
            f.where = {**f.where, "rigid_body": body}


def as_points(poses: PoseSet, stream: np.ndarray | None = None, source: str = "") -> PoseSet:
    """``poses`` with each rigid body replaced by its three points (after the markers, body by
    body, in FRAME_POINT_SUFFIXES' order); ``poses`` itself when it has no body. Each point is seen where its
    body was and averages its body's samples (n_samples: the markers' then the bodies' counts;
    None where either is unknown); on a tree it rides on its body's link. ``stream``: the
    recording's body samples (K, B, 7) whose noise the points carry (:func:`platkit.calibrate.motion_points.point_sigmas`; NaN,
    unknown, without it and without declared noise), or None. A marker already named like a point
    is bad input (``source`` names the session)."""
    if not poses.n_bodies:
        return poses
    names = [n for b in poses.body_names for n in frame_point_names(b)]
    clash = sorted(set(names) & set(poses.marker_names))
    if clash:
        raise BadInput(f"{source or poses.source}: marker {clash[0]!r} has the name diagnosis gives a point of "
                       "a rigid body; rename the marker")
    pts = body_frame_points(np.asarray(poses.bodies, float))
    N, M = poses.n_poses, poses.n_markers
    counts = None
    if poses.n_body_samples is not None and (M == 0 or poses.n_samples is not None):
        nb = np.repeat(np.asarray(poses.n_body_samples, float), len(FRAME_POINT_SUFFIXES), axis=1)
        counts = nb if M == 0 else np.concatenate([np.asarray(poses.n_samples, float), nb], axis=1)
    extras = dict(poses.extras)
    if "marker_std" in extras:  # the spread over each hold: a body's is not recorded
        extras["marker_std"] = np.concatenate([np.asarray(extras["marker_std"], float),
                                               np.full((N, len(names)), np.nan)], axis=1)
    if "held_markers" in extras:  # where the stream was at the end of each hold: the bodies as averaged
        extras["held_markers"] = np.concatenate([np.asarray(extras["held_markers"], float), pts], axis=1)
    links = dict(poses.marker_links)
    if links:
        for b in poses.body_names:
            if b in links:
                links.update(dict.fromkeys(frame_point_names(b), links[b]))
    settling = dict(poses.settling)
    # a body's noise neither measured nor declared is unknown (NaN: no noise floor), not the markers'
    # measured on the stream where there is one, else declared (the floor judges the data)
    measured = stream is not None and len(stream) >= 3 and np.asarray(stream).shape[1] == poses.n_bodies
    sig = point_sigmas(poses.body_names, {} if measured else poses.body_noise, stream)[0] or dict.fromkeys(
        names, float("nan"))
    settling["point_sigma_m"] = {**settling.get("point_sigma_m", {}), **sig}
    return PoseSet(
        platform=poses.platform, controls=poses.controls, markers=np.concatenate([poses.markers, pts], axis=1),
        marker_names=[*poses.marker_names, *names], description=poses.description, base_markers=poses.base_markers,
        t=poses.t, n_samples=counts, length_unit=poses.length_unit,
        moving_link=links if isinstance(poses.moving_link, dict) else poses.moving_link, source=poses.source,
        dropped=list(poses.dropped), extras=extras, settling=settling, marker_links=links)


def point_calibration(cal: Calibration) -> Calibration:
    """``cal`` with each rigid body replaced by its three points, placed on its link where the
    body's placement puts them (position + R(rotation_vector) times the point in the body's frame),
    their std from the body's (a tip per coordinate: the origin's, and the turns about the body's
    two axes across it over the lever, their variance spread evenly over the three coordinates
    since where it falls depends on the orientation: the rule
    :func:`platkit.bodies.placement_from_point_fit` reads back, so a placement's std comes back as
    it went); ``cal`` itself without bodies."""
    if not cal.body_names:
        return cal
    R = matrix_from_rotvec(np.asarray(cal.body_rotvecs, float))  # (B, 3, 3) body -> link
    P = np.asarray(cal.body_positions, float)[:, None, :] + np.einsum("bij,kj->bki", R, _IN_BODY)  # (B, 3, 3)
    sd = np.asarray(cal.body_std, float)
    lr2 = (LEVER_M * sd[:, 3:]) ** 2  # (B, 3): a turn about an axis moves a tip across it
    tip_x = np.sqrt(sd[:, :3] ** 2 + (lr2[:, 1:2] + lr2[:, 2:3]) / 3.0)  # turns about y and z
    tip_y = np.sqrt(sd[:, :3] ** 2 + (lr2[:, 0:1] + lr2[:, 2:3]) / 3.0)  # turns about x and z
    S = np.stack([sd[:, :3], tip_x, tip_y], axis=1)
    names = [n for b in cal.body_names for n in frame_point_names(b)]
    links = dict(cal.marker_links)
    if links:
        for b in cal.body_names:
            links.update(dict.fromkeys(frame_point_names(b), links[b]))
    return replace(cal, marker_names=[*cal.marker_names, *names],
                   marker_positions=np.concatenate([np.asarray(cal.marker_positions, float).reshape(-1, 3),
                                                    P.reshape(-1, 3)]),
                   marker_std=np.concatenate([np.asarray(cal.marker_std, float).reshape(-1, 3), S.reshape(-1, 3)]),
                   n_markers=len(cal.marker_names) + len(names), body_names=[], body_positions=np.zeros((0, 3)),
                   body_rotvecs=np.zeros((0, 3)), body_std=np.zeros((0, 6)), marker_links=links)


def body_calibration(fitted: Calibration, given: Calibration) -> Calibration:
    """The calibration diagnosis writes for a session with rigid bodies: ``fitted`` (over the
    bodies' points) with each body of ``given`` (the calibration diagnosed) carried again, its
    placement read back from its three fitted points
    (:func:`platkit.bodies.bodies_from_points`), its rotation weight (rho) ``given``'s; a body whose
    points ``fitted`` lacks keeps ``given``'s placement (where nothing changed the model, platkit
    diagnose writes the calibration given as it was read, not this)."""
    if not given.body_names:
        return fitted
    return bodies_from_points(fitted, list(given.body_names), given.body_rho, given.body_rho_source, given=given)


def point_map(pts: np.ndarray) -> np.ndarray:
    """(n, 9, 6) the map from a rigid body's small move (its position p and turn w) to the errors
    of its three points ``pts`` (n, 3, 3: origin, x tip, y tip at each pose): p at every point, and
    w x v at a tip, v its lever from the origin."""
    A = np.zeros((len(pts), 9, 6))
    A[:, :, :3] = np.tile(np.eye(3), (3, 1))
    for k in (1, 2):  # w x v, a matrix acting on w
        A[:, 3 * k:3 * k + 3, 3:] = np.einsum("ijk,nk->nij", _LEVI_CIVITA, pts[:, k] - pts[:, 0])
    return A


def n_measured(marker_names: list[str], seen: np.ndarray) -> int:
    """How many numbers the seen points ``seen`` (N, M) measure: 3 a marker; 6 a rigid body's three
    points (:func:`as_points`) seen together at a pose, its position and turn (:func:`screen_system`),
    not their 9 coordinates, which are correlated and of rank 6."""
    n = 3 * int(np.sum(seen))
    for io, ix, iy in frame_point_indices(list(marker_names)).values():
        n -= 3 * int(np.sum(seen[:, io] & seen[:, ix] & seen[:, iy]))
    return n


def _body_triples(poses: PoseSet) -> list[tuple[int, int, int, float, float]]:
    """(index of T.o, T.x, T.y among the markers, sigma_p m, sigma_r rad) of each body read as its
    three points (:func:`as_points`) whose noise is known: sigma_p the origin's per coordinate,
    sigma_r from a tip's excess over it (a turn moves two of its three coordinates, over the lever:
    the rule of :func:`platkit.calibrate.motion_points.point_sigmas`)."""
    own = (poses.settling or {}).get("point_sigma_m") or {}
    out = []
    for body, (io, ix, iy) in frame_point_indices(list(poses.marker_names)).items():
        pts = frame_point_names(body)
        if not all(p in own for p in pts):
            continue
        sp, st = float(own[pts[0]]), float(np.sqrt(0.5 * (own[pts[1]] ** 2 + own[pts[2]] ** 2)))
        sr = float(rotation_sigma(sp, st))
        if np.isfinite(sp) and np.isfinite(sr) and sp > 0 and sr > 0:
            out.append((io, ix, iy, sp, sr))
    return out


def _weighted_rows(J: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``nan_to_num(J) * w[:, None]`` written into ``J`` (rows (n, P) gathered for the purpose, a
    copy owned by the caller), element by element the same numbers as the expression, without its
    two temporaries as large as J (a tree's screen: 5,400 x 607)."""
    if not np.isfinite(J).all():
        np.nan_to_num(J, copy=False)
    J *= w[:, None]
    return J


def screen_system(poses: PoseSet, weights: np.ndarray, r: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a least-squares system over seen observations with independent errors of one
    variance: (r (n,), J (n, P)) from residuals ``r`` (N, M, 3) m and their Jacobian ``J`` (N, M, 3, P),
    each marker's three coordinates weighted by sqrt(``weights``) (N, M), where seen.

    A body's three points (:func:`as_points`) are one 6-DOF measurement, not three markers: their
    errors are e_o = d, e_x = d + L w x u_x, e_y = d + L w x u_y (d the position noise, sigma_p per
    coordinate; w the turn, sigma_r per axis; u the body's axes seen at the pose), correlated and
    of rank 6. So at each pose where all three are seen their 9 coordinates become the 6 of the
    measurement, least squares through that map, the turn scaled by sigma_p / sigma_r (m): six
    rows of independent errors of variance sigma_p^2, each weighted by the origin's weight. A body
    whose noise is unknown keeps its three points' rows."""
    keep = (weights > 0) & np.all(np.isfinite(r), axis=2)
    sw = np.sqrt(np.where(keep, weights, 0.0))[:, :, None]
    rw = np.nan_to_num(r) * sw
    P = J.shape[-1]
    rows_r, rows_J = [], []
    own = np.zeros(r.shape[1], bool)
    for io, ix, iy, sp, sr in _body_triples(poses):
        own[[io, ix, iy]] = True
        whole = keep[:, io] & keep[:, ix] & keep[:, iy]
        pts = np.asarray(poses.markers, float)[whole][:, [io, ix, iy]]  # (n, 3, 3)
        W = np.linalg.pinv(point_map(pts))  # (n, 6, 9)
        W[:, 3:] *= sp / sr
        rows_r.append(np.einsum("nij,nj->ni", W, rw[whole][:, [io, ix, iy]].reshape(-1, 9)).reshape(-1))
        Jp = _weighted_rows(J[whole][:, [io, ix, iy]].reshape(-1, P), np.repeat(sw[whole][:, [io, ix, iy]].reshape(-1), 3))
        rows_J.append(np.einsum("nij,njp->nip", W, Jp.reshape(len(pts), 9, -1)).reshape(-1, P))
    rest = keep & ~own[None, :]
    rows = np.repeat(rest.reshape(-1), 3)
    r_all = np.concatenate([rw.reshape(-1)[rows], *rows_r])
    J_all = _weighted_rows(J.reshape(-1, P)[rows], np.repeat(sw.reshape(-1)[rest.reshape(-1)], 3))
    if rows_J:
        J_all = np.concatenate([J_all, *rows_J])
    return r_all, J_all
