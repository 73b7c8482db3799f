"""Via-point sweeps: an excitation for calibration from motion that covers the whole stroke at the
drives' full speed, without holds.

The via points are the poses a hold-based D-optimal plan would hold (:func:`platkit.calibrate.plan.d_optimal`
over the identification Jacobian of random reachable candidates inside the stroke box less the
margin, half of them drawn towards the box's faces), visited in nearest-neighbour order from the
neutral controls and back. Consecutive points are joined by a straight line in control space
travelled by one trapezoidal velocity profile shared by every actuator (synchronised): its rate
and acceleration are the largest that keep each actuator within its own limits, so the actuator
with the longest move relative to its limits moves time-optimally and the others proportionally
slower. A move ends at rest on its via point and the next starts at once (no hold): the stand
passes through each via point at zero speed, decelerating into it and accelerating out of it.
Commands are that profile sampled every 1 / ``command_rate_hz`` s; the first difference of a
sampled profile is the mean of its speed over the interval and the second the mean of its
acceleration over two, so sampling keeps every command within the limits the profile keeps.

The number of via points is the largest whose tour (out from the neutral controls, through every
point, back to them) fits the session; a session longer than a tour of MAX_VIAS points goes
back and forth over that tour (every move one of the tour's) while the next point and the way
back to neutral fit. A move whose straight line leaves the reachable workspace goes through
the neutral controls instead (counted); every command is checked reachable and within the box,
rate and acceleration (:func:`platkit.calibrate.trajectories.limit_violations`).

A stand whose pose space is free (a cable robot: ``Limits.space``) draws its candidates in the pose
box less the margin (each pose coordinate as each control above), keeps those whose inverse
kinematics lies inside the stroke box and is reachable, and joins the via points by straight lines
in pose space, the commands their inverse kinematics: each move's one trapezoidal profile along the
line has the largest rate v and acceleration a with every actuator's |du/ds| v within its rate
and |du/ds| a + |d2u/ds2| v^2 within its acceleration (the line's largest slopes and curvatures,
u(s) sampled at LINE_SAMPLES points and taken with a share POSE_LIMIT_SHARE of the limits for what
the samples miss).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from platkit.calibrate.plan import _Subspace, d_optimal, feasible, identification_jacobian, nearest_neighbour_order
from platkit.calibrate.trajectories import Limits, home_controls, limit_violations
from platkit.errors import BadInput, NotIdentifiable
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec

__all__ = ["ViaDesign", "design_via", "via_trajectory", "move_duration", "pose_move"]

#: distinct via points at most (a longer session repeats the tour); candidates drawn per via point
#: (at least MIN_CANDIDATES); share of the candidates drawn towards the box's faces (each control
#: from a Beta(FACE_BETA, FACE_BETA) over the box, the rest uniform)
MAX_VIAS, CANDIDATES_PER_VIA, MIN_CANDIDATES, FACE_SHARE, FACE_BETA = 60, 12, 400, 0.5, 0.3
#: the fewest via points a sweep has
MIN_VIAS = 2
#: a pose-free stand's moves: points along each line where the commands' slopes are taken, and the share
#: of the drives' limits its profile uses (what the points miss between them)
LINE_SAMPLES, POSE_LIMIT_SHARE = 65, 0.9


def move_duration(d: np.ndarray, rate: np.ndarray, accel: np.ndarray) -> tuple[float, float, float]:
    """(duration s, rate, acceleration) of the synchronised move by ``d`` (n_u,): the share of the
    move covered follows one trapezoidal profile (unit length) whose rate and acceleration are the
    largest keeping every actuator within ``rate`` and ``accel``."""
    d = np.abs(np.asarray(d, float))
    moving = d > 0
    if not moving.any():
        return 0.0, math.inf, math.inf
    v = float(np.min(rate[moving] / d[moving]))
    a = float(np.min(accel[moving] / d[moving]))
    if v * v >= a:  # triangular: the rate is never reached
        return 2.0 * math.sqrt(1.0 / a), v, a
    return 1.0 / v + v / a, v, a


def _covered(s: np.ndarray, T: float, v: float, a: float) -> np.ndarray:
    """Share (0..1) of a unit move covered s s after it starts (trapezoidal profile of duration T)."""
    ta = min(v / a, 0.5 * T)
    vp = a * ta
    s = np.clip(s, 0.0, T)
    acc = 0.5 * a * s ** 2
    cruise = 0.5 * a * ta ** 2 + vp * (s - ta)
    dec = 1.0 - 0.5 * a * (T - s) ** 2
    return np.where(s <= ta, acc, np.where(s <= T - ta, cruise, dec))


def pose_move(a: np.ndarray, b: np.ndarray, limits: Limits, model, td) -> tuple[float, float, float]:
    """(duration s, rate, acceleration) of a pose-free stand's move along the straight pose line
    from ``a`` to ``b`` (n_p each; module docstring); inf where the line has no inverse somewhere."""
    assert limits.space is not None
    s = np.linspace(0.0, 1.0, LINE_SAMPLES)
    U = limits.space.controls(a + s[:, None] * (b - a), model, td)
    if not np.all(np.isfinite(U)):
        return math.inf, 0.0, 0.0
    h = s[1] - s[0]
    d1 = np.abs(np.gradient(U, h, axis=0)).max(axis=0)
    d2 = np.abs(np.diff(U, 2, axis=0)).max(axis=0) / h ** 2 if len(U) > 2 else np.zeros(U.shape[1])
    moving = d1 > 0
    if not moving.any():
        return 0.0, math.inf, math.inf
    rate, accel = POSE_LIMIT_SHARE * limits.rate, POSE_LIMIT_SHARE * limits.accel
    v = float(np.min(rate[moving] / d1[moving]))
    curved = d2 > 0
    if curved.any():  # at most half of each acceleration limit goes to the line's curvature
        v = min(v, float(np.min(np.sqrt(0.5 * accel[curved] / d2[curved]))))
    a_ = float(np.min((accel[moving] - d2[moving] * v * v) / d1[moving]))
    if v * v >= a_:
        return 2.0 * math.sqrt(1.0 / a_), v, a_
    return 1.0 / v + v / a_, v, a_


def _move(a: np.ndarray, b: np.ndarray, limits: Limits, model, td) -> tuple[float, float, float]:
    """The move from path point ``a`` to ``b``: synchronised in controls, or along a pose line."""
    if limits.space is None:
        return move_duration(b - a, limits.rate, limits.accel)
    return pose_move(a, b, limits, model, td)


def via_trajectory(path: np.ndarray, limits: Limits, command_rate_hz: float, model=None,
                   td=None) -> tuple[np.ndarray, np.ndarray]:
    """(U (N, n_u) commands every 1/command_rate_hz s, knots (len(path),) s when each point is
    reached): the points ``path`` (P, n_u) joined by synchronised trapezoidal moves (module
    docstring), the last command at rest on the last point; a pose-free stand's (``limits.space``):
    the poses ``path`` (P, n_p) joined along pose lines, the commands their inverse kinematics at
    ``td`` of ``model``."""
    path = np.asarray(path, float)
    T = np.zeros(len(path))
    prof = []
    for i in range(1, len(path)):
        dur, v, a = _move(path[i - 1], path[i], limits, model, td)
        T[i] = T[i - 1] + dur
        prof.append((dur, v, a))
    n = int(math.ceil(T[-1] * command_rate_hz - 1e-9)) + 1
    t = np.arange(n) / command_rate_hz
    seg = np.clip(np.searchsorted(T, t, side="right") - 1, 0, len(path) - 2)
    U = np.repeat(path[-1][None], n, axis=0)
    for i in range(len(path) - 1):
        k = np.nonzero((seg == i) & (t < T[-1]))[0]
        dur, v, a = prof[i]
        if len(k) and dur > 0:
            U[k] = path[i] + _covered(t[k] - T[i], dur, v, a)[:, None] * (path[i + 1] - path[i])
    if limits.space is not None:
        U = limits.space.controls(U, model, td)
    return U, T


def tour_duration(path: np.ndarray, limits: Limits, model=None, td=None) -> float:
    return float(sum(_move(a, b, limits, model, td)[0] for a, b in zip(path[:-1], path[1:])))


@dataclass
class ViaDesign:
    """A via-point sweep: ``vias`` (K, n_u) the distinct points in tour order, ``path`` (P, n_u) every
    point the commands pass through (neutral first and last; repeats and detours included), what
    the design counted (candidates, detours through neutral, tours). A pose-free stand's points are
    poses (n_p each; ``info['space']`` 'pose')."""

    vias: np.ndarray
    path: np.ndarray
    info: dict = field(default_factory=dict)


def _candidates(spec: PlatformSpec, limits: Limits, n: int, rng: np.random.Generator, model, td) -> tuple:
    """(U (n, n_u), P (n, n_p), drawn, points (n, n_u or n_p) in the plan's space: the controls, or a
    pose-free stand's poses drawn)."""
    space = limits.space
    lo, hi = (limits.lower, limits.upper) if space is None else (space.lower, space.upper)
    dim = len(lo)
    U_out, P_out, X_out, drawn = [], [], [], 0
    while sum(len(u) for u in U_out) < n:
        if drawn > 50 * n:
            raise NotIdentifiable(f"{spec.name}: fewer than {n} random " + ("commands inside the strokes" if space is None
                                  else "poses inside the pose box") + " less the margin are reachable; try a smaller --margin")
        k = max(2 * n, 64)
        face = rng.uniform(size=k) < FACE_SHARE
        x = np.where(face[:, None], rng.beta(FACE_BETA, FACE_BETA, (k, dim)), rng.uniform(size=(k, dim)))
        X = lo + x * (hi - lo)
        drawn += k
        if space is None:
            U = X
            ok, P = feasible(spec, U, td, model)
        else:  # a pose-free stand: the poses' inverse kinematics, inside the stroke box and reachable
            U = space.controls(X, model, td)
            inside = np.all(np.isfinite(U), axis=1)
            inside[inside] = np.all((U[inside] >= limits.lower) & (U[inside] <= limits.upper), axis=1)
            ok = np.zeros(k, bool)
            P = np.full((k, spec.n_p), np.nan)
            if inside.any():
                ok[inside], P[inside] = feasible(spec, U[inside], td, model)
        U_out.append(U[ok])
        P_out.append(P[ok])
        X_out.append(X[ok])
    return np.vstack(U_out)[:n], np.vstack(P_out)[:n], drawn, np.vstack(X_out)[:n]


def _tour(spec: PlatformSpec, vias: np.ndarray, u0: np.ndarray, limits: Limits, model, td) -> np.ndarray:
    """Home, the via points in nearest-neighbour order of their commands, home (points in the plan's
    space)."""
    if limits.space is None:
        order = nearest_neighbour_order(vias, spec, u0)
    else:
        order = nearest_neighbour_order(limits.space.controls(vias, model, td), spec,
                                        limits.space.controls(u0, model, td)[0])
    return np.vstack([u0[None], vias[order], u0[None]])


def _repair(spec: PlatformSpec, path: np.ndarray, limits: Limits, command_rate_hz: float, model, td,
            u0: np.ndarray) -> tuple[np.ndarray, int]:
    """The path with every move whose commands leave the reachable workspace replaced by two moves
    through the home point; (path, detours). NotIdentifiable where a detour fails too."""
    out, detours = [path[0]], 0
    for b in path[1:]:
        a = out[-1]
        U, _ = via_trajectory(np.vstack([a, b]), limits, command_rate_hz, model, td)
        ok, _ = feasible(spec, U, td, model)
        if not ok.all():
            U1, _ = via_trajectory(np.vstack([a, u0, b]), limits, command_rate_hz, model, td)
            ok1, _ = feasible(spec, U1, td, model)
            if not ok1.all():
                raise NotIdentifiable(f"{spec.name}: a move between via points leaves the reachable workspace, "
                                      "through the neutral controls too; try a larger --margin")
            out.append(u0)
            detours += 1
        out.append(b)
    return np.vstack(out), detours


def _fill(spec: PlatformSpec, tour: np.ndarray, limits: Limits, duration_s: float, command_rate_hz: float, model, td,
          u0: np.ndarray) -> tuple[np.ndarray, float, int]:
    """(path, tours, detours of the way back): from the neutral controls over the tour's points
    (``tour``: neutral, points, neutral; its moves reachable) forth and back, every move one of the
    tour's, while the next point and the way back to neutral from it fit in ``duration_s``; then
    back to neutral (through it detoured where the straight way leaves the workspace)."""
    pts = tour[1:-1]
    k = len(pts)
    order = np.concatenate([np.arange(k), np.arange(k - 2, 0, -1)]) if k > 1 else np.zeros(1, int)
    out, t, i = [u0], 0.0, 0
    while True:
        p = pts[order[i % len(order)]]
        step = _move(out[-1], p, limits, model, td)[0]
        back = _move(p, u0, limits, model, td)[0]
        if t + step + back > duration_s:
            break
        out.append(p)
        t += step
        i += 1
    while True:
        last, detours = _repair(spec, np.vstack([out[-1], u0]), limits, command_rate_hz, model, td, u0)
        path = np.vstack(out[:-1] + list(last))
        if tour_duration(path, limits, model, td) <= duration_s or len(out) <= 2:
            return path, i / max(k, 1), detours
        out.pop()
        i -= 1


_RANKED: dict = {}


def _ranked(spec: PlatformSpec, U_c: np.ndarray, P_c: np.ndarray, markers: np.ndarray, td: np.ndarray,
            model) -> tuple[np.ndarray, np.ndarray]:
    """(the D-optimal MAX_VIAS of the candidates, their reduced identification Jacobians), kept for
    the same stand, candidates, markers and parameters (a design redone at another length)."""
    key = (spec.name, U_c.tobytes(), np.asarray(markers, float).tobytes(), td.tobytes())
    hit = _RANKED.get(key)
    if hit is None:
        ij = identification_jacobian(spec, U_c, markers, td=td, P=P_c, model=model)
        Jr = _Subspace(ij.J).reduce(ij.J)
        ranked = d_optimal(Jr, MAX_VIAS)
        if len(_RANKED) >= 8:
            _RANKED.pop(next(iter(_RANKED)))
        _RANKED[key] = hit = (ranked, Jr[ranked])
    return hit


def design_via(spec: PlatformSpec, limits: Limits, markers: np.ndarray, duration_s: float, command_rate_hz: float,
               rng: np.random.Generator, model: PlatformModel | None = None, td=None,
               d_optimal_choice: bool = True) -> ViaDesign:
    """The via-point sweep of ``duration_s`` s at most (module docstring): D-optimal via points
    (``d_optimal_choice`` False: the candidates in the order drawn, a random sweep to compare with)
    as many as fit, in tour order, repeated while a whole tour fits."""
    model = model or PlatformModel(spec)
    td = spec.nominal_td() if td is None else np.asarray(td, float)
    if not (duration_s > 0 and math.isfinite(duration_s)):
        raise BadInput(f"duration_s: must be a positive number of seconds, got {duration_s:g}")
    u0 = home_controls(spec, limits) if limits.space is None else limits.space.home  # in the plan's space
    n_cand = max(MIN_CANDIDATES, CANDIDATES_PER_VIA * MAX_VIAS)
    U_c, P_c, drawn, X_c = _candidates(spec, limits, n_cand, rng, model, td)
    if limits.space is None:
        near = X_c[np.argsort([move_duration(u - u0, limits.rate, limits.accel)[0] for u in U_c])[:MIN_VIAS]]
    else:  # by the commands' largest share of their strokes (the pose moves' own durations cost more)
        span = limits.upper - limits.lower
        home_u = limits.space.controls(u0, model, td)[0]
        near = X_c[np.argsort(np.max(np.abs(U_c - home_u) / np.where(span > 0, span, 1.0), axis=1))[:MIN_VIAS]]
    shortest = _tour(spec, near, u0, limits, model, td)
    if tour_duration(shortest, limits, model, td) > duration_s:  # not even the candidates nearest neutral fit
        raise NotIdentifiable(f"{spec.name}: a sweep through {MIN_VIAS} via points and back takes at least "
                              f"{tour_duration(shortest, limits, model, td):.1f} s within the rate and acceleration "
                              f"limits, over the {duration_s:g} s session; try a longer session (--duration-s "
                              f"{math.ceil(tour_duration(shortest, limits, model, td)):g} or more)")
    if d_optimal_choice:  # the D-optimal set of MAX_VIAS; a shorter sweep takes a D-optimal subset of it
        ranked, J_ranked = _ranked(spec, U_c, P_c, markers, td, model)
    else:
        ranked = np.arange(MAX_VIAS)

    def choose(k: int) -> np.ndarray:
        if not d_optimal_choice or k == MAX_VIAS:
            return X_c[ranked[:k]]
        return X_c[ranked[d_optimal(J_ranked, k)]]

    def fits(k: int) -> tuple[bool, np.ndarray, int]:
        path, detours = _repair(spec, _tour(spec, choose(k), u0, limits, model, td), limits, command_rate_hz, model,
                                td, u0)
        return tour_duration(path, limits, model, td) <= duration_s, path, detours

    ok, best, detours = fits(MIN_VIAS)
    if not ok:
        raise NotIdentifiable(f"{spec.name}: a sweep through {MIN_VIAS} via points and back takes "
                              f"{tour_duration(best, limits, model, td):.1f} s within the rate and acceleration limits, "
                              f"over the {duration_s:g} s session; try a longer session (--duration-s "
                              f"{math.ceil(tour_duration(best, limits, model, td)):g} or more)")
    lo_k, hi_k = MIN_VIAS, MAX_VIAS + 1
    while hi_k - lo_k > 1:  # the most via points whose tour fits (its duration grows with them, nearly monotone)
        mid = (lo_k + hi_k) // 2
        ok, p, d = fits(mid)
        if ok:
            lo_k, best, detours = mid, p, d
        else:
            hi_k = mid
    path, tours = best, 1.0
    if lo_k == MAX_VIAS:  # a longer session goes back and forth over the tour
        path, tours, back = _fill(spec, best, limits, duration_s, command_rate_hz, model, td, u0)
        detours = int(round(detours * tours)) + back
    U, _ = via_trajectory(path, limits, command_rate_hz, model, td)
    bad = limit_violations(U, command_rate_hz, limits)
    if bad["box"] or bad["rate"] or bad["accel"]:  # the profile keeps them by construction: a bug if not
        raise NotIdentifiable(f"{spec.name}: the via-point sweep breaks its limits ({bad})")
    vias = best[1:-1][np.any(best[1:-1] != u0, axis=1)]
    return ViaDesign(vias, path, {"candidates": int(len(U_c)), "candidates_drawn": int(drawn),
                                  "via_points": int(len(vias)), "tours": round(float(tours), 3), "detours": int(detours),
                                  "choice": "d_optimal" if d_optimal_choice else "random",
                                  **({} if limits.space is None else {"space": "pose"})})
