"""Samples of a stand's free space: the box every point of which the stand takes.

A stand declares it (``PlatformSpec.free_space``): 'controls' (the strokes: any command is
reachable, as for a hexapod's legs) or 'pose' (the coordinates' bounds: any pose there is
reachable, while independent commands are almost never consistent, as for a cable robot's
lengths). Samples of a pose-free stand are drawn as poses and mapped through inverse kinematics;
a pose is kept when its controls lie inside their strokes and the stand is on its branch there.

Also the start library of forward kinematics (:func:`library_poses`): poses on the branch with
their nominal controls, spread over the free space.
"""
from __future__ import annotations

import itertools

import numpy as np

from platkit.errors import BadInput, NotIdentifiable, PlatkitError


def pose_box(spec, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The coordinates' bounds (n_p,) shrunk by ``margin`` of each range at both ends;
    BadInput naming the coordinates without finite bounds."""
    lo, hi = spec.coordinate_bounds()
    bad = [c.name for c, a, b in zip(spec.coordinates, lo, hi) if not (np.isfinite(a) and np.isfinite(b) and a < b)]
    if bad:
        raise BadInput(f"stand {spec.name!r}: coordinates {bad} have no finite bounds; its pose box cannot be sampled")
    span = hi - lo
    return lo + margin * span, hi - margin * span


def pose_grid(spec, n: int, margin: float = 0.0) -> np.ndarray:
    """Every combination of ``n`` evenly spaced values per coordinate over the pose box:
    (n**n_p, n_p), the last coordinate running fastest."""
    if n < 2:
        raise BadInput(f"a pose grid needs at least 2 values per coordinate, got {n}")
    lo, hi = pose_box(spec, margin)
    return np.array(list(itertools.product(*[np.linspace(a, b, n) for a, b in zip(lo, hi)])), dtype=float)


def nominal_inverse(model, P: np.ndarray, td: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse kinematics of poses P (N, n_p) at parameters td: the controls U (N, n_u; NaN rows
    where there is no solution) and the poses' orientations q (N, 4) and positions X (N, 3). The
    stand's closed-form inverse batched where it has one, else the model's inverse from the
    neutral controls pose by pose."""
    spec = model.spec
    N = P.shape[0]
    q, X = (np.asarray(a).T for a in spec.pose.map(N)(P.T))
    if spec.inverse is not None:
        return np.asarray(spec.inverse.map(N)(td, q.T, X.T)).T, q, X
    U = np.full((N, spec.n_u), np.nan)
    for k in range(N):
        try:
            U[k] = model.inverse(q[k], X[k], td, strict=False)
        except PlatkitError:
            pass  # no solution: a NaN row
    return U, q, X


def controls_of_poses(model, P: np.ndarray, td=None) -> dict[str, np.ndarray]:
    """Nominal inverse kinematics of poses P (N, n_p): ``controls`` (N, n_u; NaN where there is
    no solution) and ``ok`` (N,) bool: a solution inside the strokes with the stand on its
    branch. The stand's closed-form inverse batched where it has one, else pose by pose."""
    spec = model.spec
    P = np.atleast_2d(np.asarray(P, float))
    N = P.shape[0]
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    if N == 0:
        return {"controls": np.zeros((0, spec.n_u)), "ok": np.zeros(0, bool)}
    U, q, X = nominal_inverse(model, P, td)
    ok = np.all(np.isfinite(U), axis=1)
    Us = np.where(ok[:, None], U, spec.neutral_u())
    r = np.asarray(spec.residual.map(N)(Us.T, td, q.T, X.T)).T
    ok &= np.linalg.norm(r, axis=1) <= 1e-8
    lo, hi = spec.control_bounds()
    ok &= np.all((Us >= lo - 1e-12) & (Us <= hi + 1e-12), axis=1)
    if spec.branch is not None:
        g = np.asarray(spec.branch.map(N)(Us.T, td, q.T, X.T)).T
        ok &= np.all(g > 0, axis=1)
    U[~np.all(np.isfinite(U), axis=1)] = np.nan
    return {"controls": U, "ok": ok}


def sample_poses(model, n: int, rng: np.random.Generator, margin: float = 0.0, td=None,
                 max_rounds: int = 50) -> tuple[np.ndarray, np.ndarray, int]:
    """``n`` poses drawn uniformly from the pose box (shrunk by ``margin``) that the stand takes
    (:func:`controls_of_poses`), with their controls: (P (n, n_p), U (n, n_u), drawn). ``drawn``
    counts every pose drawn, the rejected ones included. PlatkitError (not identifiable) naming
    the stand when fewer than ``n`` are found after ``max_rounds`` rounds."""
    spec = model.spec
    lo, hi = pose_box(spec, margin)
    P_out, U_out, drawn = [], [], 0
    for _ in range(max_rounds):
        if sum(len(p) for p in P_out) >= n:
            break
        P = rng.uniform(lo, hi, size=(max(2 * n, 16), spec.n_p))
        drawn += len(P)
        res = controls_of_poses(model, P, td)
        P_out.append(P[res["ok"]])
        U_out.append(res["controls"][res["ok"]])
    P = np.vstack(P_out)[:n] if P_out else np.zeros((0, spec.n_p))
    U = np.vstack(U_out)[:n] if U_out else np.zeros((0, spec.n_u))
    if len(P) < n:
        raise NotIdentifiable(f"{spec.name}: only {len(P)} of {drawn} poses drawn in the pose box have controls "
                              f"inside the strokes on the stand's branch, fewer than {n}")
    return P, U, drawn


def library_poses(model, size: int) -> tuple[np.ndarray, np.ndarray]:
    """(P (K, n_p), U (K, n_u)) with K <= ``size``: poses on the stand's branch with their
    nominal controls inside the strokes, spread over its free space (a pose grid mapped through
    inverse kinematics for a pose-free stand or a stand whose strokes are not all finite, else
    the converged forward images of a control grid)."""
    spec = model.spec
    empty = (np.zeros((0, spec.n_p)), np.zeros((0, spec.n_u)))
    lo_u, hi_u = spec.control_bounds()
    lo_p, hi_p = spec.coordinate_bounds()
    controls_box = bool(np.all(np.isfinite(lo_u) & np.isfinite(hi_u)))
    pose_box_ok = bool(np.all(np.isfinite(lo_p) & np.isfinite(hi_p) & (lo_p < hi_p)))
    if spec.pose_free or (not controls_box and pose_box_ok):
        k = max(2, int(np.floor(size ** (1.0 / spec.n_p) + 1e-9)))
        P = pose_grid(spec, k, margin=0.5 / k)
        res = controls_of_poses(model, P)
        return P[res["ok"]], res["controls"][res["ok"]]
    if not controls_box:
        return empty
    k = max(2, int(np.floor(size ** (1.0 / spec.n_u) + 1e-9)))
    if k ** spec.n_u > 4 * size:
        return empty
    span = hi_u - lo_u
    axes = [np.linspace(a + 0.5 * s / k, b - 0.5 * s / k, k) for a, b, s in zip(lo_u, hi_u, span)]
    U = np.array(list(itertools.product(*axes)), dtype=float)
    fb = model.forward_batch(U, restarts=False)
    keep = fb.converged & fb.on_branch & np.all(np.isfinite(fb.p), axis=1)
    P, U = fb.p[keep], U[keep]
    return _within_from_neighbours(model, P, U, span), U


#: most rounds of :func:`_within_from_neighbours` (each reaches one grid step further)
NEIGHBOUR_ROUNDS = 8


def _within_from_neighbours(model, P: np.ndarray, U: np.ndarray, span: np.ndarray) -> np.ndarray:
    """The start library's poses P (K, n_p) (controls U (K, n_u)) with each pose beyond the
    coordinates' bounds solved again from the pose within them whose controls are nearest
    (stroke-scaled), round after round while that brings more within: a pose beyond the bounds
    (Newton from the neutral pose jumped to another solution the pose map holds, a gimbal turned
    over) stays only where no start within them lands within them. A copy."""
    P = P.copy()
    inside = model.within_bounds(P)
    for _ in range(NEIGHBOUR_ROUNDS):
        far, near = np.nonzero(~inside)[0], np.nonzero(inside)[0]
        if not far.size or not near.size:
            break
        d = np.sum(((U[far, None, :] - U[None, near, :]) / span) ** 2, axis=2)
        fb = model.forward_batch(U[far], guess=P[near[np.argmin(d, axis=1)]], restarts=False)
        ok = fb.converged & fb.on_branch & np.all(np.isfinite(fb.p), axis=1)
        ok[ok] = model.within_bounds(fb.p[ok])
        if not ok.any():
            break
        P[far[ok]] = fb.p[ok]
        inside[far[ok]] = True
    return P
