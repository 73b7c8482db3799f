"""Rigid bodies measured in 6 DOF: rotation algebra, averaging, and the weight of rotation against position.

A body T is measured as its frame's origin (m) and orientation (unit quaternion qw, qx, qy, qz),
both in the motion-capture frame. Its placement on the moving part (origin p_T, m, and rotation
vector phi_T, rad, in the moving frame) is unknown and calibrated like a marker's position.
The estimator (:class:`platkit.calibrate.problem.CalibrationProblem`) gives each body two
residual channels of three numbers: the origin's error (m, like a marker), and the rotation vector
of R_meas^T R_pred scaled by rho = sigma_position / sigma_rotation (m/rad), so that both channels
are metres of equal noise. rho is declared in session.yaml (``rigid_body_noise: {position_mm,
rotation_deg}``) or estimated from the residuals after a first fit (:func:`estimate_rho`).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from platkit.geometry import matrix_from_quat, quat_from_matrix, rotvec_from_matrix, skew
from platkit.io.calibration import Calibration
from platkit.io.session import Session
from platkit.poses import PoseSet

#: rho (m/rad) before anything is known: a mocap body's 0.1 mm per 1 mrad (0.057 deg)
DEFAULT_RHO_M_PER_RAD = 0.1
#: length (m) of the virtual axes that give a body's frame three points for the initial registration
AXIS_LENGTH_M = 0.1
#: Median of the 3-D error norm of isotropic Gaussian noise, in units of the per-axis sigma.
_MAXWELL_MEDIAN = 1.5381722


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad, angle in [0, pi], of rotation matrices (..., 3, 3)."""
    q = quat_from_matrix(R)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    k = np.where(s < 1e-12, 2.0, angle / np.where(s < 1e-12, 1.0, s))
    return q[..., 1:] * k[..., None]


def right_jacobian(phi: np.ndarray) -> np.ndarray:
    """Right Jacobian of SO(3) (..., 3, 3): exp(phi + d) = exp(phi) exp(J_r(phi) d) to first order."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th ** 2 / 24.0, (1.0 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0 - th ** 2 / 120.0, (t - np.sin(t)) / t ** 3)
    return np.eye(3) - a * K + b * (K @ K)


def right_jacobian_inv(phi: np.ndarray) -> np.ndarray:
    """Inverse of :func:`right_jacobian` (..., 3, 3): log(exp(phi) exp(d)) = phi + J_r^-1(phi) d."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    K = skew(phi)
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    c = np.where(small, 1.0 / 12.0 + th ** 2 / 720.0, 1.0 / t ** 2 - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    return np.eye(3) + 0.5 * K + c * (K @ K)


def quat_mean(q: np.ndarray) -> np.ndarray:
    """Mean orientation (4,) of unit quaternions q (K, 4) (qw, qx, qy, qz): the principal eigenvector of
    sum q q^T (Markley's mean, blind to each sample's sign), returned with qw >= 0."""
    q = np.asarray(q, float)
    _, V = np.linalg.eigh(q.T @ q)
    m = V[:, -1]
    return m if m[0] >= 0 else -m


def average_body(samples: np.ndarray) -> tuple[np.ndarray, int]:
    """Settled body pose (7,) from samples (K, 7) (x, y, z m; qw, qx, qy, qz): positions averaged
    like a marker's, orientations by :func:`quat_mean`; rows with any NaN (occluded) are left out.
    Returns (pose, number of samples averaged); all NaN and 0 when none was seen."""
    samples = np.asarray(samples, float)
    seen = np.all(np.isfinite(samples), axis=1)
    if not seen.any():
        return np.full(7, np.nan), 0
    s = samples[seen]
    return np.concatenate([s[:, :3].mean(axis=0), quat_mean(s[:, 3:])]), int(seen.sum())


def declared_rho(body_noise: dict) -> float | None:
    """rho (m/rad) from a PoseSet's declared body noise ({'position_m', 'rotation_rad'}), or None."""
    if not body_noise:
        return None
    return float(body_noise["position_m"]) / float(body_noise["rotation_rad"])


def estimate_rho(pos_residuals: np.ndarray, rot_residuals: np.ndarray) -> float | None:
    """rho = sigma_position / sigma_rotation (m/rad) from the residuals of a fit: each sigma robustly
    (median of the 3-D norms over the Maxwell median), over the rows given.

    pos_residuals (K, 3) m, rot_residuals (K, 3) rad (unscaled). None when either is too small to
    say anything (fewer than 3 rows, or a zero scale).
    """
    p = np.linalg.norm(pos_residuals, axis=-1)
    r = np.linalg.norm(rot_residuals, axis=-1)
    p, r = p[np.isfinite(p)], r[np.isfinite(r)]
    if p.size < 3 or r.size < 3:
        return None
    sp, sr = np.median(p) / _MAXWELL_MEDIAN, np.median(r) / _MAXWELL_MEDIAN
    if not (sp > 0 and sr > 0):
        return None
    return float(sp / sr)


def body_frame_points(bodies: np.ndarray) -> np.ndarray:
    """Three points of each body's frame (N, 3 B, 3) m: its origin and the tips of its x and y axes at
    AXIS_LENGTH_M, for a registration that only knows points. bodies (N, B, 7); NaN stays NaN."""
    N, B, _ = bodies.shape
    seen = np.all(np.isfinite(bodies), axis=2)
    R = matrix_from_quat(np.where(seen[..., None], bodies[..., 3:], np.array([1.0, 0, 0, 0])))
    o = bodies[..., :3]
    pts = np.stack([o, o + AXIS_LENGTH_M * R[..., :, 0], o + AXIS_LENGTH_M * R[..., :, 1]], axis=2)
    pts[~seen] = np.nan
    return pts.reshape(N, 3 * B, 3)


def placement_from_frame_points(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body placements from the fitted frame points (B, 3, 3) of :func:`body_frame_points`:
    origins (B, 3) m and rotations (B, 3, 3) (Gram-Schmidt of the two axes)."""
    o = points[:, 0]
    x = points[:, 1] - o
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = points[:, 2] - o
    y -= np.sum(x * y, axis=1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return o, np.stack([x, y, np.cross(x, y)], axis=2)


#: the suffixes of a body's three frame points as named points (``<body>.o``, ``<body>.x``,
#: ``<body>.y``): its origin and the tips of its x and y axes, :func:`body_frame_points`' order
FRAME_POINT_SUFFIXES = ("o", "x", "y")


def frame_point_names(body: str) -> list[str]:
    """The names of ``body``'s three frame points as markers: ``<body>.o``, ``<body>.x``, ``<body>.y``."""
    return [f"{body}.{s}" for s in FRAME_POINT_SUFFIXES]


def frame_point_indices(marker_names: list[str]) -> dict[str, list[int]]:
    """Body name -> the indices of its three frame points ``<body>.o``, ``<body>.x``, ``<body>.y``
    (:func:`frame_point_names`, in that order) among ``marker_names``, for each body whose three
    points are all there, in first-seen order."""
    index = {n: i for i, n in enumerate(marker_names)}
    out: dict[str, list[int]] = {}
    for n in marker_names:
        body, dot, suffix = n.rpartition(".")
        if dot and suffix == FRAME_POINT_SUFFIXES[0] and body not in out:
            names = frame_point_names(body)
            if all(p in index for p in names):
                out[body] = [index[p] for p in names]
    return out


def rotation_sigma(sigma_origin, sigma_tip):
    """A body's rotation noise per axis (rad) from its frame points' noise per coordinate (m): the
    tips' variance beyond the origin's, a turn about an axis moving two of a tip's three
    coordinates (1.5 times that variance), over the lever :data:`AXIS_LENGTH_M`; 0 where a tip is
    no noisier than the origin. Arrays broadcast."""
    extra = np.maximum(np.square(sigma_tip) - np.square(sigma_origin), 0.0)
    return np.sqrt(1.5 * extra) / AXIS_LENGTH_M


def placement_from_point_fit(points: np.ndarray, std: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A body's placement read back from its three frame points fitted as free points (3, 3) m and
    their std (3, 3) m: origin (3,), rotation vector (3,) (:func:`placement_from_frame_points`) and
    std (6,): the origin's per axis, and the rotation's the tips' variance beyond the origin's
    (mean over the tips' coordinates) over the lever, one number for the three axes (a turn about
    one axis moves two of a tip's three coordinates: 1.5 times that variance; the points' fitted
    correlations are not kept)."""
    o, R = placement_from_frame_points(np.asarray(points, float)[None])
    s = np.asarray(std, float)
    turn = rotation_sigma(np.sqrt(np.mean(s[0] ** 2)), np.sqrt(np.mean(s[1:] ** 2)))
    return o[0], rotvec_from_matrix(R[0]), np.concatenate([s[0], np.full(3, float(turn))])


def bodies_from_points(fitted: Calibration, body_names: list[str], rho: float, rho_source: str,
                       given: Calibration | None = None) -> Calibration:
    """``fitted`` (a fit over each body's three frame points as markers) with the bodies
    ``body_names`` carried again and their points out of the markers: each placement read back from
    its three fitted points (:func:`placement_from_point_fit`), each body on the link its origin
    point rides on (else ``given``'s link for it), the rotation weight ``rho`` with its source
    ('declared' or 'estimated'). A body whose three points ``fitted`` lacks keeps ``given``'s
    placement and std; without ``given`` that is a ValueError (a caller's mistake, not bad input)."""
    index = {n: k for k, n in enumerate(fitted.marker_names)}
    mpos, mstd = np.asarray(fitted.marker_positions, float), np.asarray(fitted.marker_std, float)
    B = len(body_names)
    if given is None:
        pos, rot, std = np.zeros((B, 3)), np.zeros((B, 3)), np.zeros((B, 6))
    else:
        at = [given.body_names.index(b) for b in body_names]
        pos, rot, std = (np.array(given.body_positions, float)[at], np.array(given.body_rotvecs, float)[at],
                         np.array(given.body_std, float)[at])
    links = dict(fitted.marker_links)
    body_links = {}
    for b, body in enumerate(body_names):
        names = frame_point_names(body)
        rows = [index.get(n) for n in names]
        if any(r is None for r in rows):
            if given is None:
                raise ValueError(f"the fit has no point {names[rows.index(None)]!r} of rigid body {body!r}")
        else:
            pos[b], rot[b], std[b] = placement_from_point_fit(mpos[rows], mstd[rows])
        link = links.get(names[0]) or (given.marker_links.get(body) if given is not None else None)
        if link is not None:
            body_links[body] = link
    points = {n for body in body_names for n in frame_point_names(body)}
    keep = [k for k, n in enumerate(fitted.marker_names) if n not in points]
    links = {k: v for k, v in links.items() if k not in points}
    links.update(body_links)
    return replace(fitted, marker_names=[fitted.marker_names[k] for k in keep],
                   marker_positions=mpos[keep].reshape(-1, 3), marker_std=mstd[keep].reshape(-1, 3),
                   n_markers=len(keep), body_names=list(body_names), body_positions=pos, body_rotvecs=rot,
                   body_std=std, body_rho=rho, body_rho_source=rho_source, marker_links=links)


# ---------------------------------------------------------------------------- settled poses

#: name stem of the points that stand for a body's frame in the settling search of a body-only stream
_FRAME_POINT = "{body}~{k}"


def stream_for_settling(session: Session) -> Session:
    """The session whose stream the settling search reads: ``session`` itself, or, for a stream
    of rigid bodies without markers, a copy whose markers are three points of each body's frame
    (:func:`body_frame_points`), so that a turn shows as motion like a translation."""
    if session.bodies is None or session.marker_names:
        return session
    names = [_FRAME_POINT.format(body=b, k=k) for b in session.body_names for k in range(3)]
    return replace(session, markers=body_frame_points(session.bodies), marker_names=names)


def with_settled_bodies(session: Session, poses: PoseSet) -> PoseSet:
    """``poses`` (settled by platkit.settle, or read from poses.csv) with the session's rigid bodies.

    From poses.csv the bodies are taken as they are. From a stream, each kept pose averages the
    body samples inside its settled window (extras 'window_start'/'window_end'; positions by
    the mean, orientations by :func:`quat_mean`, see :func:`average_body`); a pose whose window is
    unknown (extrapolated to rest) leaves its bodies unseen, and that count is said in
    ``poses.settling['bodies']``. Points that stood for the bodies in the search are removed.
    """
    if not session.body_names:
        return poses
    B = len(session.body_names)
    if session.poses is not None and session.bodies is None:
        bodies, counts, note = session.poses["bodies"], session.poses["n_body_samples"], ""
    else:
        t, stream = session.marker_t, session.bodies
        ws, we = poses.extras["window_start"], poses.extras["window_end"]
        bodies = np.full((poses.n_poses, B, 7), np.nan)
        counts = np.zeros((poses.n_poses, B))
        for n in range(poses.n_poses):
            if not (np.isfinite(ws[n]) and np.isfinite(we[n])):
                continue
            a, b = np.searchsorted(t, ws[n], side="left"), np.searchsorted(t, we[n], side="right")
            for k in range(B):
                bodies[n, k], counts[n, k] = average_body(stream[a:b, k])
        no_window = int(np.sum(~(np.isfinite(ws) & np.isfinite(we))))
        unseen = int(np.sum(counts == 0))
        note = (f"{unseen} settled body poses with no sample" + (f" ({no_window} poses extrapolated to rest have no "
                "window to average the bodies over)" if no_window else "")) if unseen else ""
    if not session.marker_names:  # the frame points were only for the search
        poses.markers, poses.marker_names, poses.n_samples = np.zeros((poses.n_poses, 0, 3)), [], None
        for key in ("marker_std", "held_markers"):
            poses.extras.pop(key, None)
    poses.bodies, poses.body_names, poses.n_body_samples = bodies, list(session.body_names), counts
    poses.body_noise = dict(session.body_noise)
    if note:
        poses.settling = {**poses.settling, "bodies": note}
    return poses


#: a body with more than this share of its orientations rejected as outliers is refused: its
#: orientations do not follow the stand's motion (most often a quaternion written in another order)
ROTATION_REJECTED_SHARE = 0.5
#: ... when read in another order they follow it within this (rad, median), and that order is named
ORDER_AGREEMENT_RAD = 0.05
#: the orders a recorder writes a quaternion in, as indices into the four columns qw,qx,qy,qz read as
#: written: the quaternion w,x,y,z they hold is ``q[..., idx]``
QUATERNION_ORDERS = {"x,y,z,w (scalar last)": [3, 0, 1, 2]}


def orientation_spread(measured: np.ndarray, predicted: np.ndarray) -> float:
    """How well measured orientations follow predicted ones up to one fixed rotation (a body's
    placement): the median angle (rad) of each pose's rotation predicted -> measured about their
    mean. measured, predicted (K, 4) unit quaternions (w, x, y, z); NaN with no row."""
    if not len(measured):
        return float("nan")
    D = np.einsum("nba,nbc->nac", matrix_from_quat(predicted), matrix_from_quat(measured))  # R_pred^T R_meas
    mean = matrix_from_quat(quat_mean(quat_from_matrix(D)))
    return float(np.median(np.linalg.norm(log_so3(np.einsum("ba,nbc->nac", mean, D)), axis=-1)))


def rotation_refusal(body: str, source: str, measured: np.ndarray, predicted: np.ndarray, n_rejected: int,
                     n_seen: int) -> str:
    """The line that refuses a body whose orientations were rejected en masse, naming the likely
    cause: the order of its quaternion columns where another order follows the fit's motion
    (within ORDER_AGREEMENT_RAD), else a body whose orientation does not follow the stand.
    measured, predicted (K, 4): the body's orientations as read and as the fit predicts them."""
    head = (f"{source}: rigid body {body!r}: {n_rejected} of its {n_seen} orientations rejected as outliers: they "
            "do not follow the stand's motion")
    as_written = orientation_spread(measured, predicted)
    for order, idx in QUATERNION_ORDERS.items():
        other = orientation_spread(measured[:, idx], predicted)
        if other <= ORDER_AGREEMENT_RAD and other < 0.2 * as_written:
            return (f"{head} as written (qw,qx,qy,qz: {np.degrees(as_written):.3g} deg median), but read as {order} "
                    f"they do ({np.degrees(other):.2g} deg): the columns {body}_qw,{body}_qx,{body}_qy,{body}_qz "
                    f"hold {order.split(' ')[0]}; write them as qw,qx,qy,qz (the spec's order)")
    return (f"{head} ({np.degrees(as_written):.3g} deg median from the fit's rotation, in any column order): check "
            f"that the columns {body}_qw..{body}_qz hold the body's orientation as qw,qx,qy,qz and that the body "
            "rides the moving part")
