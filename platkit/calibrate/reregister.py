"""Re-registration: a calibration used in another motion-capture set-up.

The base-to-mocap transform (and, on a marker body mounted again, the markers' places on their
links) belongs to a set-up: the cameras' calibration, where the robot stands, how the marker body
sits on the hand. The stand's geometry and its physics (td, the model terms) do not. Re-registering
a calibration to a new session estimates only the set-up from that session's poses, every other
parameter held as the calibration has it:

    y_ni = A (X_ni + R_ni (m_i + dm_ni)) + b

with the tracked links' frames R, X and the terms' marker offsets dm predicted by the calibration
(``platkit.calibrate.estimate``), unknowns A (a rotation), b and, with ``markers=True``, the
places m. A rigid body's origin counts as one more point (its orientation is not fitted; its
placement is held, or its origin re-estimated with the markers). The fit: closed form (Kabsch)
for the transform alone, then scipy.optimize.least_squares (Levenberg-Marquardt, the exact
Jacobian) over every unknown, gross outliers (beyond REJECT_K robust sigma, calibrate's rejection
rule) left out, counted, and the rest fitted again, until the points left out stay the same
(calibrate's Huber rounds are not run: docs/calibration.md says what they would change). The
poses must fix the unknowns: the Jacobian, rotations scaled by the points' spread, must have full
rank (relative singular value above DEFAULT_REL_TOL); else bad input in one line (a transform
needs three points off a line; marker places need the link to turn about two axes).
:func:`check_registration` makes these checks for every block without fitting.

Scoring by rotation (:func:`rotated_scores`): blocks of K consecutive poses, in recording order,
re-register in turn (the last block wraps to the first poses), the session's other poses are
scored under each; a pose's error is the mean square over the blocks it was scored in. Every
pose is scored, never by a registration that saw it. Spread blocks take their K poses across the
recording instead (as a registration set chosen to span the workspace would be).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from platkit.bodies import right_jacobian
from platkit.calibrate.estimate import _predicted_frames, calibration_links
from platkit.calibrate.identifiability import DEFAULT_REL_TOL
from platkit.calibrate.robust import REJECT_K, robust_sigma
from platkit.effects import with_history
from platkit.errors import BadInput
from platkit.geometry import matrix_from_rotvec, rigid_fit, rotvec_from_matrix, skew
from platkit.io.calibration import Calibration
from platkit.kinematics import PlatformModel
from platkit.model import length_scale
from platkit.poses import PoseSet

#: least_squares' tolerances: relative change of the unknowns (m, or rad times the spread) and of the cost
_XTOL, _FTOL = 1e-12, 1e-14


@dataclass(frozen=True)
class SessionPoints:
    """A session's points against a calibration: P (N, C, 3) m, each point's base-frame position
    with its place on the link at zero (the link's origin, plus the terms' marker offset turned
    into the base frame); Rk (N, C, 3, 3) each point's link rotation; Y (N, C, 3) m measured in
    the mocap frame; seen (N, C) where measured and predicted. C = the calibration's markers, then
    its rigid bodies' origins; ``names`` the C names."""

    P: np.ndarray
    Rk: np.ndarray
    Y: np.ndarray
    seen: np.ndarray
    names: list[str]


@dataclass(frozen=True)
class Registration:
    """A set-up fitted on some poses: the transform mocap_from_base (``rotvec`` rad, ``translation``
    m, their ``std`` (6,)), the points' places on their links (C, 3) m (the calibration's where
    held), ``rms`` (m) of the fit on the poses used, ``n_poses`` used, ``n_rejected`` points left
    out as outliers, ``markers`` whether the places were fitted."""

    rotvec: np.ndarray
    translation: np.ndarray
    std: np.ndarray
    places: np.ndarray
    rms: float
    n_poses: int
    n_points: int
    n_rejected: int
    markers: bool

    def apply(self, cal: Calibration) -> Calibration:
        """``cal`` with this set-up: its transform and (fitted) places; every other value as it was."""
        M = len(cal.marker_names)
        out = replace(cal, mocap_rotvec=self.rotvec.copy(), mocap_translation=self.translation.copy(),
                      mocap_std=self.std.copy(), fit=None)
        if self.markers:
            out = replace(out, marker_positions=self.places[:M].copy(), marker_std=np.full((M, 3), np.nan),
                          body_positions=self.places[M:].copy())
        return out

    def shift(self, cal: Calibration) -> tuple[float, float]:
        """(rad, m): the turn and the move of this transform from ``cal``'s, at the base frame's origin."""
        turn = matrix_from_rotvec(self.rotvec) @ matrix_from_rotvec(cal.mocap_rotvec).T
        return float(np.linalg.norm(rotvec_from_matrix(turn))), float(np.linalg.norm(self.translation
                                                                                     - cal.mocap_translation))

    def to_dict(self, cal: Calibration) -> dict:
        """What a report shows, in ``cal``'s length unit (angles in rad)."""
        s = length_scale(cal.length_unit)
        turn, move = self.shift(cal)
        return {"rotation_vector": [float(x) for x in self.rotvec],
                "translation": [float(x / s) for x in self.translation],
                "std_rotation_vector": [_num(x) for x in self.std[:3]],
                "std_translation": [_num(x / s) for x in self.std[3:]],
                "turn_from_calibration_rad": turn, "move_from_calibration": move / s,
                "rms_on_registration_poses": self.rms / s, "n_poses": self.n_poses,
                "n_rejected_as_outliers": self.n_rejected, "marker_places_refitted": self.markers,
                "unit": cal.length_unit}


def _num(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def session_points(cal: Calibration, poses: PoseSet) -> SessionPoints:
    """The calibration's prediction of ``poses`` up to the set-up (:class:`SessionPoints`),
    history- and time-dependent terms read from the whole session's row order. Markers and
    bodies are matched by name; one the session lacks is bad input."""
    missing = [m for m in cal.marker_names if m not in poses.marker_names]
    missing += [b for b in cal.body_names if b not in poses.body_names]
    if missing:
        raise BadInput(f"{poses.source or 'the session'}: has no marker or rigid body {missing[0]!r} of the calibration "
                       f"({', '.join(list(cal.marker_names) + list(cal.body_names))})")
    order = [poses.marker_names.index(m) for m in cal.marker_names]
    sub = PoseSet(poses.platform, poses.controls, poses.markers[:, order], list(cal.marker_names), t=poses.t,
                  length_unit=poses.length_unit, source=poses.source, extras=dict(poses.extras),
                  marker_links=dict(cal.marker_links))
    sub = with_history(sub, cal.spec)
    spec = cal.calibrated_spec()
    R_all, X_all, dm, ok = _predicted_frames(cal, spec, PlatformModel(spec), sub.controls, sub)
    links = np.array(calibration_links(cal), int)
    N = sub.n_poses
    dm = np.concatenate([dm, np.zeros((N, len(cal.body_names), 3))], axis=1)
    Rk, Xk = R_all[:, links], X_all[:, links]
    P = Xk + np.einsum("ncab,ncb->nca", Rk, dm)
    Y = sub.markers
    if cal.body_names:
        Y = np.concatenate([Y, poses.bodies[:, [poses.body_names.index(b) for b in cal.body_names], :3]], axis=1)
    seen = np.isfinite(Y).all(axis=2) & np.isfinite(P).all(axis=2) & ok[:, None]
    return SessionPoints(P=P, Rk=Rk, Y=Y, seen=seen, names=list(cal.marker_names) + list(cal.body_names))


def _places(cal: Calibration) -> np.ndarray:
    return np.concatenate([np.asarray(cal.marker_positions, float).reshape(-1, 3),
                           np.asarray(cal.body_positions, float).reshape(-1, 3)])


def _jacobian(pts_centred, Rk_seen, A, idx_points, C: int, markers: bool, spread: float) -> np.ndarray:
    """(3 n, 6 [+ 3 C]) the residual's derivative in (w spread, db[, places]) at n points, the
    mocap predictions minus their centroid ``pts_centred`` (n, 3): y -> exp([w]) (y - c) + c + db,
    rotation columns scaled by ``spread`` (m) so that every column is a length. Rk_seen (n, 3, 3)
    and idx_points (n,): each point's link rotation and which of the C places it is."""
    n = len(pts_centred)
    cols = 6 + (3 * C if markers else 0)
    J = np.zeros((n, 3, cols))
    J[:, :, :3] = -skew_batch(pts_centred) * spread
    J[:, :, 3:6] = np.eye(3)
    if markers:
        AR = np.einsum("ab,kbc->kac", A, Rk_seen)
        for row, c in enumerate(idx_points):
            J[row, :, 6 + 3 * c:9 + 3 * c] = AR[row]
    return J.reshape(3 * n, cols)


def skew_batch(v: np.ndarray) -> np.ndarray:
    """(K, 3, 3) the cross-product matrices of v (K, 3)."""
    return skew(np.asarray(v, float).reshape(-1, 3))


def _check_fixes(J: np.ndarray, markers: bool, what: str, unknown: str, n_rows: int) -> None:
    """BadInput where the Jacobian J (rotations scaled by the points' spread) has not full rank."""
    s = np.linalg.svd(J, compute_uv=False)
    if J.shape[0] < J.shape[1] or s[-1] <= DEFAULT_REL_TOL * s[0]:
        need = "the link to turn about two different axes among them" if markers else "3 or more points off one line"
        raise BadInput(f"{what}: {n_rows} pose{'s' if n_rows != 1 else ''} cannot fix {unknown} (it needs {need}); "
                       "give more poses")


def _check_seen(seen: np.ndarray, what: str) -> None:
    if seen.sum() < 3:
        raise BadInput(f"{what}: {int(seen.sum())} points seen and predicted; fixing the base-to-mocap transform needs "
                       "3 or more off one line")


def _unknown(markers: bool) -> str:
    return "the base-to-mocap transform" + (" and the marker places" if markers else "")


def _linearised(A, b, places, P, Rk, keep, markers: bool):
    """(J, y, c, spread) at the set-up (A, b, places) on the points ``keep``: the Jacobian of
    :func:`_jacobian` about the predictions' centroid c, the predictions y (n, 3)."""
    idx = np.nonzero(keep)
    y = (P[idx] + np.einsum("kab,kb->ka", Rk[idx], places[idx[1]])) @ A.T + b
    c = y.mean(axis=0)
    spread = float(np.sqrt(np.mean(np.sum((y - c) ** 2, axis=1)))) or 1.0
    return _jacobian(y - c, Rk[idx], A, idx[1], keep.shape[1], markers, 1.0 / spread), y, c, spread


def fit_setup(cal: Calibration, pts: SessionPoints, rows, markers: bool = False, what: str = "the poses",
              robust: bool = True) -> Registration:
    """The set-up (:class:`Registration`) fitted on the poses ``rows`` (indices into ``pts``),
    everything else held at ``cal``'s values; ``robust``: gross outliers left out (else plain
    least squares). BadInput where those poses cannot fix it (``what`` names them in the line)."""
    rows = np.asarray(rows, int)
    start = _places(cal)
    seen = pts.seen[rows]
    Rk, Y, P = pts.Rk[rows], pts.Y[rows], pts.P[rows]
    _check_seen(seen, what)
    A, b = rigid_fit((P + np.einsum("ncab,cb->nca", Rk, start))[seen], Y[seen])
    args = (P, Rk, Y, markers, what, len(rows))

    def distances(A, b, places):
        pred = (P + np.einsum("ncab,cb->nca", Rk, places)) @ A.T + b
        return np.linalg.norm(np.where(seen[..., None], pred - Y, 0.0), axis=2)

    keep = seen
    for _ in range(4):  # fit, then leave out the gross outliers of that fit, until none changes
        A, b, places = _least_squares(A, b, start, keep, *args)
        fitted, d = keep, distances(A, b, places)
        new_keep = seen & (d <= max(REJECT_K * robust_sigma(d[seen]), 1e-12))
        if not robust or np.array_equal(new_keep, keep) or new_keep.sum() < 3:
            break
        keep = new_keep
    return Registration(rotvec=rotvec_from_matrix(A), translation=b,
                        std=_covariance_std(A, b, places, *args[:3], fitted, markers),
                        places=places, rms=float(np.sqrt(np.mean(d[keep] ** 2))), n_poses=len(rows),
                        n_points=int(keep.sum()), n_rejected=int(seen.sum() - keep.sum()), markers=markers)


def _least_squares(A, b, places, keep, P, Rk, Y, markers: bool, what: str, n_rows: int):
    """(A, b, places): least squares (scipy.optimize.least_squares, Levenberg-Marquardt with the
    exact Jacobian) over the transform (and places) on the points ``keep``, from the start given.
    The unknowns: a turn w (times the points' spread) about their centroid c, a move db, the
    places' changes: y -> exp([w]) (y - c) + c + db. BadInput where the Jacobian at the start has
    not full rank."""
    J0, y0, c, spread = _linearised(A, b, places, P, Rk, keep, markers)
    _check_fixes(J0, markers, what, _unknown(markers), n_rows)
    idx = np.nonzero(keep)
    Rk_seen, Y_seen = Rk[idx], Y[idx]
    v0 = y0 - c  # the start's predictions about the centroid; with places fitted they move by A Rk dm
    AR = np.einsum("ab,kbc->kac", A, Rk_seen)

    def state(x):
        turn = matrix_from_rotvec(x[:3] / spread)
        v = v0 + (np.einsum("kab,kb->ka", AR, x[6:].reshape(-1, 3)[idx[1]]) if markers else 0.0)
        return turn, v

    def fun(x):
        turn, v = state(x)
        return (v @ turn.T + c + x[3:6] - Y_seen).ravel()

    def jac(x):
        turn, v = state(x)
        J = J0.reshape(len(v0), 3, -1).copy()
        # SO(3)'s left Jacobian at phi (exp([phi + d]) ~ exp([J d]) exp([phi])) is the right one at -phi
        J[:, :, :3] = -skew_batch(v @ turn.T) @ right_jacobian(-x[:3] / spread) / spread
        if markers:
            TAR = np.einsum("ab,kbc->kac", turn, AR)
            for row, cc in enumerate(idx[1]):
                J[row, :, 6 + 3 * cc:9 + 3 * cc] = TAR[row]
        return J.reshape(J0.shape)

    x = least_squares(fun, np.zeros(J0.shape[1]), jac=jac, method="lm", xtol=_XTOL, ftol=_FTOL).x
    turn = matrix_from_rotvec(x[:3] / spread)
    return turn @ A, turn @ (b - c) + c + x[3:6], places + x[6:].reshape(-1, 3) if markers else places


def _covariance_std(A, b, places, P, Rk, Y, keep, markers: bool) -> np.ndarray:
    """(6,) the standard deviations of (rotation vector, translation) at the set-up fitted on the
    points ``keep``, from the residual's variance and the Jacobian there."""
    J, y, c, spread = _linearised(A, b, places, P, Rk, keep, markers)
    r = (y - Y[np.nonzero(keep)]).ravel()
    dof = max(J.shape[0] - J.shape[1], 1)
    cov_s = float(r @ r) / dof * np.linalg.pinv(J.T @ J)[:6, :6]
    # (w, b) from the unknowns' (w spread, db) about the centroid c: b moves by -[b - c]x w + db
    L = np.zeros((6, 6))
    L[:3, :3] = np.eye(3) / spread
    L[3:, :3] = -skew(b - c) / spread
    L[3:, 3:] = np.eye(3)
    return np.sqrt(np.clip(np.diag(L @ cov_s @ L.T), 0.0, None))


def reregister(cal: Calibration, poses: PoseSet, markers: bool = False,
               robust: bool = True) -> tuple[Calibration, Registration]:
    """``cal`` re-registered to the set-up of ``poses`` (every pose used): the calibration with the
    fitted transform (and places), and the fit's record."""
    pts = session_points(cal, poses)
    reg = fit_setup(cal, pts, np.arange(poses.n_poses), markers,
                    what=f"{poses.source or 'the session'}", robust=robust)
    return reg.apply(cal), reg


def registration_blocks(n_poses: int, k: int, spread: bool = False) -> list[np.ndarray]:
    """The rotation's blocks: runs of k consecutive poses (wrapping from the last pose to the
    first) starting every min(k, N - k) poses, as many (B) as make every pose fall outside one: with
    k <= N / 2 the blocks tile the poses, beyond it the poses left out do. ``spread``: the same
    runs over the poses taken B apart (0, B, 2B, ..., 1, B + 1, ...), so that a block's poses lie
    across the whole recording."""
    step = min(k, n_poses - k)
    blocks = [(np.arange(k) + j * step) % n_poses for j in range(-(-n_poses // step))]
    if not spread:
        return blocks
    order = np.argsort(np.arange(n_poses) % len(blocks), kind="stable")
    return [np.sort(order[b]) for b in blocks]


@dataclass(frozen=True)
class RotatedScore:
    """A calibration scored on a session by rotation (see the module's docstring): ``sq`` (N, C)
    m^2 each pose's and point's mean squared error over the blocks it was scored in (NaN
    unseen), ``registrations`` one per block, ``blocks`` the poses of each, ``names`` the C points."""

    sq: np.ndarray
    registrations: list[Registration]
    blocks: list[np.ndarray]
    names: list[str]

    @property
    def rms(self) -> float:
        """m, over every point and pose scored."""
        return float(np.sqrt(np.nanmean(self.sq)))

    def rms_of(self, name: str) -> float:
        """m, of one point (a marker's name) over the poses where it was scored."""
        return float(np.sqrt(np.nanmean(self.sq[:, self.names.index(name)])))

    def per_pose(self) -> np.ndarray:
        """(N,) m^2 each pose's mean squared error over its points (NaN where none was scored)."""
        ok = np.isfinite(self.sq)
        n = ok.sum(axis=1)
        return np.divide(np.where(ok, self.sq, 0.0).sum(axis=1), n, out=np.full(len(n), np.nan), where=n > 0)


def check_block_size(k: int, n_poses: int, option: str, source: str) -> None:
    """Bad input in one line where ``k`` poses cannot re-register and leave poses to score."""
    if k < 1:
        raise BadInput(f"{option} {k}: give a number of poses, 1 or more")
    if k >= n_poses:
        raise BadInput(f"{option} {k}: {source} has {n_poses} poses; re-registering on {k} leaves none to score "
                       f"(give fewer than {n_poses})")


def _block_label(blk: np.ndarray, n_poses: int, spread: bool) -> str:
    """A block's poses as a line names them (1-based)."""
    if spread:
        return f"poses {', '.join(str(i + 1) for i in blk)}"
    if blk[-1] >= blk[0]:
        return f"poses {blk[0] + 1}-{blk[-1] + 1}"
    return f"poses {blk[0] + 1}-{n_poses} and 1-{blk[-1] + 1}"


def check_registration(cal: Calibration, poses: PoseSet, k: int, markers: bool = False,
                       option: str = "--heldout-register", spread: bool = False) -> None:
    """Bad input in one line where :func:`rotated_scores` would refuse at the start: ``k`` that
    leaves no pose to score, a marker or body of ``cal`` the session lacks, a block whose poses
    cannot fix the set-up (too few points seen, or a Jacobian without full rank). Nothing is
    fitted: the session's points are predicted once and each block's Jacobian taken at ``cal``'s
    own set-up (its rank does not depend on where the transform is)."""
    source = poses.source or "the session"
    check_block_size(k, poses.n_poses, option, source)
    pts = session_points(cal, poses)
    A, b, places = matrix_from_rotvec(cal.mocap_rotvec), np.asarray(cal.mocap_translation, float), _places(cal)
    for blk in registration_blocks(poses.n_poses, k, spread):
        what = f"{option} {k}: {source}, {_block_label(blk, poses.n_poses, spread)}"
        _check_seen(pts.seen[blk], what)
        J = _linearised(A, b, places, pts.P[blk], pts.Rk[blk], pts.seen[blk], markers)[0]
        _check_fixes(J, markers, what, _unknown(markers), len(blk))


def rotated_scores(cal: Calibration, poses: PoseSet, k: int, markers: bool = False,
                   option: str = "--heldout-register", robust: bool = True, spread: bool = False) -> RotatedScore:
    """``cal`` scored on ``poses`` with its set-up re-registered on each block of ``k`` poses
    (consecutive, or ``spread`` across the recording: :func:`registration_blocks`) and the others
    scored (see the module's docstring)."""
    source = poses.source or "the session"
    check_block_size(k, poses.n_poses, option, source)
    pts = session_points(cal, poses)
    N, C = pts.seen.shape
    total = np.zeros((N, C))
    count = np.zeros((N, C))
    regs, blocks = [], registration_blocks(N, k, spread)
    for blk in blocks:
        reg = fit_setup(cal, pts, blk, markers, what=f"{option} {k}: {source}, {_block_label(blk, N, spread)}",
                        robust=robust)
        regs.append(reg)
        score = np.ones(N, bool)
        score[blk] = False
        A = matrix_from_rotvec(reg.rotvec)
        pred = (pts.P + np.einsum("ncab,cb->nca", pts.Rk, reg.places)) @ A.T + reg.translation
        d2 = np.sum((pred - pts.Y) ** 2, axis=2)
        use = pts.seen & score[:, None]
        total[use] += d2[use]
        count[use] += 1
    with np.errstate(invalid="ignore"):
        sq = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return RotatedScore(sq=sq, registrations=regs, blocks=blocks, names=pts.names)


__all__ = ["Registration", "RotatedScore", "SessionPoints", "check_block_size", "check_registration", "fit_setup",
           "registration_blocks", "reregister", "rotated_scores", "session_points"]
