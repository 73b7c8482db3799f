"""Rigid registration of the measured points to the stand's frames: the start of every fit.

Given the frames the points ride on at some td (rotations R, positions X, from forward
kinematics) and the measured points Y, find the base-to-mocap transform (A, b) and each point's
position m on its frame such that Y_ni ~ A (X_n + R_n m_i) + b, without any other unknown: the
rotation A first, from the relative motions (hand-eye calibration, AX = XB), then markers and
transform alternately by linear least squares and Kabsch, gross outliers left out.
:meth:`platkit.calibrate.problem.CalibrationProblem.initial_registration` puts the result in the
problem's unknown vector.

Both steps are pure functions of their arrays, and a model selection starts each of its candidate
models from the same poses at the same nominal parameters: within :func:`kept_registrations` (a
selection), :func:`registered` keeps the last few results by the exact bytes of their inputs and
returns a copy of a result again for the same inputs, bit for bit what computing it again gives;
outside it, or once the selection is over, it computes every registration. :func:`kept` is that
memo for any pure step of a selection's start (the gauge analysis and the registration-only fit
of :mod:`platkit.calibrate.stages` use it too), each kind of result in its own few places, keyed
by :func:`digest` of everything the step reads.
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np

from platkit.calibrate.robust import REJECT_K, robust_sigma
from platkit.geometry import matrix_from_rotvec, rigid_fit, rotvec_from_matrix

#: the results kept while a selection runs, by (kind, their inputs' digest); registrations: its two
#: pose sets (all poses, and the cleaned ones its candidates share), with room for a selection
#: inside another
_KEPT: OrderedDict[tuple[str, bytes], Any] = OrderedDict()
_KEEP = 4
_LOCK = threading.Lock()
_OPEN = [0]  # the kept_registrations contexts open (in any thread)
T = TypeVar("T")
#: a moving frame's path is a line where its second principal spread is under this share of its
#: first; the rotation about the line is then tried in PATH_TURNS steps (:func:`initial_rotations`)
PATH_LINE_SHARE, PATH_TURNS = 0.05, 24


@contextmanager
def kept_registrations() -> Iterator[None]:
    """Registrations (:func:`registered`) and the other results of :func:`kept` are kept while
    this is open; forgotten when the last one open closes."""
    with _LOCK:
        _OPEN[0] += 1
    try:
        yield
    finally:
        with _LOCK:
            _OPEN[0] -= 1
            if _OPEN[0] == 0:
                _KEPT.clear()


def digest(*parts) -> bytes:
    """A digest of ``parts``: of each array its dtype, shape and bytes, of anything else its type
    and repr (equal inputs, equal keys; an array and a list of its numbers differ)."""
    h = hashlib.blake2b(digest_size=32)
    for a in parts:
        if isinstance(a, np.ndarray):
            a = np.ascontiguousarray(a)
            h.update(f"array{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(f"{type(a).__name__}:{a!r};".encode())
    return h.digest()


def kept(kind: str, key: bytes, compute: Callable[[], T], copy: Callable[[T], T], keep: int = _KEEP) -> T:
    """``compute()``, or within :func:`kept_registrations` the result kept for ``key`` under
    ``kind`` where there is one: ``copy`` of it, so that no caller writes into what is kept. The
    ``keep`` last results of a kind are kept. ``key`` must say everything ``compute`` reads
    (:func:`digest` of it); an exception is not kept (the next call computes again)."""
    if not _OPEN[0]:
        return compute()
    with _LOCK:
        got = _KEPT.get((kind, key))
        if got is not None:
            _KEPT.move_to_end((kind, key))
    if got is None:
        got = copy(compute())
        with _LOCK:
            if _OPEN[0]:
                _KEPT[(kind, key)] = got
                mine = [k for k in _KEPT if k[0] == kind]  # oldest first
                for k in mine[:max(0, len(mine) - keep)]:
                    del _KEPT[k]
    return copy(got)


def _copies(arrays: tuple) -> tuple:
    return tuple(a.copy() for a in arrays)


def registered(R, X, Y, vis, rotation_from: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`best_registration` from the :func:`initial_rotations` of ``rotation_from`` (its (R, X,
    Y, vis)), each point on its frame (R (N, P, 3, 3), X (N, P, 3)): (A, b, m); within
    :func:`kept_registrations`, copies of a kept result where the same inputs were registered
    before (the module docstring)."""
    return kept("registration", digest(R, X, Y, vis, *rotation_from),
                lambda: best_registration(R, X, Y, vis, initial_rotations(*rotation_from)), _copies)


def best_registration(R, X, Y, vis, starts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`register` from each rotation of ``starts`` (:func:`initial_rotations`), the one whose
    points lie nearest their measurements (the median distance over the points seen): the data
    choose between starts that the conditioning of the relative motions cannot. One start: its
    registration."""
    best = register(R, X, Y, vis, starts[0])
    if len(starts) == 1:
        return best
    best_d = _median_distance(R, X, Y, vis, best)
    for A0 in starts[1:]:  # the first of equally near ones kept
        got = register(R, X, Y, vis, A0)
        med = _median_distance(R, X, Y, vis, got)
        if med < best_d:
            best, best_d = got, med
    return best


def _median_distance(R, X, Y, vis, registration) -> float:
    """The median distance of the points seen from their measurements under ``registration`` (A, b,
    m), inf where none is seen."""
    A, b, mk = registration
    d = _distances(X + np.einsum("nmab,mb->nma", R, mk), A, b, Y, vis)[vis]
    return float(np.median(d)) if d.size else np.inf


def register(R, X, Y, vis, A) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A (3, 3), b (3,), m (M, 3)): the transform and the points' positions on their frames,
    from the rotation ``A`` by six rounds of markers by least squares then transform by Kabsch, the
    points beyond REJECT_K robust sigma of the last round left out of the next. R (N, M, 3, 3) and
    X (N, M, 3): each point's frame; Y (N, M, 3) measured, ``vis`` (N, M) where seen."""
    keep = vis.copy()
    for _ in range(6):
        mk, b = markers_given_rotation(A, R, X, Y, keep)
        pts = X + np.einsum("nmab,mb->nma", R, mk)
        d = _distances(pts, A, b, Y, vis)
        sigma = robust_sigma(d[vis])
        keep = vis & (d <= max(REJECT_K * sigma, 1e-12))
        A, b = rigid_fit(pts[keep], Y[keep])
    mk, b = markers_given_rotation(A, R, X, Y, keep)
    return A, b, mk


def _distances(pts, A, b, Y, vis) -> np.ndarray:
    """(N, M) each point's distance from its measurement, the points ``pts`` (N, M, 3) in the base
    frame carried by (A, b) into the mocap frame; 0-filled measurements where not seen."""
    return np.linalg.norm(pts @ A.T + b - np.where(vis[..., None], Y, 0.0), axis=2)


def initial_rotation(R, X, Y, vis) -> np.ndarray:
    """The first of :func:`initial_rotations`: the hand-eye rotation where the relative motions fix
    it, else the one from the moving frame's path."""
    return initial_rotations(R, X, Y, vis)[0]


def initial_rotations(R, X, Y, vis) -> list[np.ndarray]:
    """Starts for the mocap_from_base rotation A from relative motions: Rm_n A = A B_n (hand-eye,
    AX = XB), Rm_n the marker cloud's rotation from a reference pose to pose n (Kabsch), B_n the
    model's. A few references are tried and the one whose clouds fit best is kept, and pose pairs
    whose clouds do not fit as a rigid body (a swapped or jumping marker) are left out.

    Where the least singular value of the hand-eye system is under a tenth of the next, its null
    vector alone is the start. Otherwise the rotation that aligns the moving frame's path with the
    markers' centroid path is one start; where that path is a line (its second principal spread
    under PATH_LINE_SHARE of its first) the rotation about the line is not fixed by it, and
    the path's rotation turned about the line in PATH_TURNS steps are starts too; and the hand-eye
    null vector, where the system has one (its next singular value over 1e-3), is a start beside
    them: :func:`best_registration` keeps the registration that fits best. A stand that only tilts
    and heaves (a crank-rod seat mover) has such a path and a hand-eye system near the threshold.
    Where the model's relative rotations all turn about one axis (a planar stand: x, y, yaw), the
    hand-eye system fixes that axis but not the turn about it (noise can make its null vector look
    unique): the hand-eye start turned about the axis in PATH_TURNS steps are starts, beside the
    path's."""
    N = len(R)
    counts = vis.sum(axis=1)
    best_seen = np.nonzero(counts == counts.max())[0]
    refs = best_seen[np.unique(np.linspace(0, len(best_seen) - 1, min(len(best_seen), 5)).astype(int))]
    # a few dozen well-seen poses fix a rotation; more only cost time
    sample = np.unique(np.linspace(0, N - 1, min(N, 60)).astype(int))
    best = None
    for ref in refs:
        rows, misfit = [], []
        for n in sample:
            common = vis[n] & vis[ref]
            if n == ref or common.sum() < 3:
                continue
            Rm, tm = rigid_fit(Y[ref, common], Y[n, common])
            misfit.append(np.sqrt(np.mean(np.sum((Y[ref, common] @ Rm.T + tm - Y[n, common]) ** 2, axis=1))))
            rows.append(np.kron(np.eye(3), Rm) - np.kron((R[n] @ R[ref].T).T, np.eye(3)))
        if len(rows) < 2:
            continue
        misfit = np.array(misfit)
        med = float(np.median(misfit))
        good = misfit <= max(4.5 * med, 1e-12)
        if best is None or med < best[0]:
            best = (med, np.vstack([r for r, g in zip(rows, good) if g]), _single_axis(R, ref, sample))
    starts = []
    if best is not None:
        _, s, Vt = np.linalg.svd(best[1])
        axis = best[2]
        if s[-2] > 1e-3:
            A = Vt[-1].reshape(3, 3, order="F")
            if np.linalg.det(A) < 0:
                A = -A
            U_, _, Vt_ = np.linalg.svd(A)
            starts.append(U_ @ np.diag([1, 1, np.linalg.det(U_ @ Vt_)]) @ Vt_)
            if axis is not None:  # the hand-eye fixes the axis, not the turn about it: every turn a start
                starts += [starts[0] @ matrix_from_rotvec(axis * (2 * np.pi * k / PATH_TURNS)) for k in range(1, PATH_TURNS)]
            elif s[-2] > 10 * s[-1]:
                return starts
    # too little rotation: align the moving frame's path with the markers' centroid path
    full = vis.all(axis=1)
    if full.sum() >= 3:
        A, _ = rigid_fit(X[full], Y[full].mean(axis=1))
        path = [A]
        _, spread, Vp = np.linalg.svd(X[full] - X[full].mean(axis=0))
        if spread[0] > 0 and spread[1] < PATH_LINE_SHARE * spread[0]:  # about the line: not fixed
            path += [A @ matrix_from_rotvec(Vp[0] * (2 * np.pi * k / PATH_TURNS)) for k in range(1, PATH_TURNS)]
        return path + starts
    return starts + [np.eye(3)]


def _single_axis(R, ref: int, sample) -> np.ndarray | None:
    """The unit axis (3,) in the moving frame's base coordinates about which every relative
    rotation of the model from pose ``ref`` to the poses ``sample`` turns, where there is one (a
    planar stand: x, y and a turn about z), else None."""
    w = np.array([rotvec_from_matrix(R[n] @ R[ref].T) for n in sample if n != ref])
    w = w[np.linalg.norm(w, axis=1) > 1e-9] if len(w) else w
    if len(w) < 2:
        return None
    _, s, Vt = np.linalg.svd(w)
    return Vt[0] if s[1] <= 1e-9 * s[0] else None


def markers_given_rotation(A, R, X, Y, vis):
    """Linear least squares for marker positions m (M, 3) and translation b given A
    (normal equations; the blocks (A R_n)^T (A R_n) are identities). R (N, M or 1, 3, 3) and
    X (N, M or 1, 3): the frame each marker rides on; R (N, 3, 3) and X (N, 3): one for all."""
    N, M = vis.shape
    R = np.broadcast_to(R[:, None] if R.ndim == 3 else R, (N, M, 3, 3))
    X = np.broadcast_to(X[:, None] if X.ndim == 2 else X, (N, M, 3))
    H = np.zeros((3 * M + 3, 3 * M + 3))
    g = np.zeros(3 * M + 3)
    C = np.einsum("ab,nmbc->nmac", A, R)  # (N, M, 3, 3): d y / d m
    res = Y - X @ A.T  # (N, M, 3)
    for i in range(M):
        v = vis[:, i]
        k = slice(3 * i, 3 * i + 3)
        H[k, k] = v.sum() * np.eye(3)
        Ct = C[v, i].sum(axis=0).T
        H[k, 3 * M:] = Ct
        H[3 * M:, k] = Ct.T
        g[k] = np.einsum("nba,nb->a", C[v, i], res[v, i])
        g[3 * M:] += res[v, i].sum(axis=0)
    H[3 * M:, 3 * M:] = vis.sum() * np.eye(3)
    sol = np.linalg.lstsq(H, g, rcond=None)[0]
    return sol[:3 * M].reshape(M, 3), sol[3 * M:]
