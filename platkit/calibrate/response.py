"""How a stand's actuators follow their command log in time: the response the motion model fits.

Each actuator j follows a reference r_j(t) built from the command log (times T_i on the
commands clock, values u_i), through a linear response that starts at rest:

- reference ``step``: r_j holds each command until the next (commands streamed at a steady
  rate, a motion-cue or path follower); ``profile``: each command starts a trapezoidal velocity
  profile (rate limit ``rate_j``, acceleration limit ``accel_j``) from where the previous one
  stood when it was cut (a point-to-point drive moving between holds);
- response ``first_order``: tau_j x' + x = r; ``second_order``: x'' + 2 zeta_j w_j x' + w_j^2 x =
  w_j^2 r with w_j = 1 / tau_j (damping zeta_j; 1 critically damped, below 1 an overshoot); a
  second-order response may name actuators that follow the first order all the same (the kind
  chosen per actuator, :mod:`platkit.calibrate.motion_kind`);
- one time shift s (the motion capture's clock minus the commands', with the stand's common
  delay: from the markers alone the two are one number): a sample stamped t sees the actuators
  at t - s on the commands clock;
- with ``delays``: each actuator's own pure delay d_j beyond the shift (actuator j at
  t - s - d_j). The markers see only s + d_j per actuator: a constant added to every d_j and
  taken from s changes nothing, so one of the n_u + 1 is held (calibrate's identifiability says
  which) and the totals s + d_j are what the data fix (:func:`lags`);
- with ``rate_limit`` on a step reference: each actuator's speed limit ``rate_j``: the
  reference slews towards each command at rate_j from where it stood when the command came
  (a trapezoid of infinite acceleration, cut by the next command), then the linear response.
  A profile reference has its rate limit already (``rate``, with ``accel``).

A step reference is integrated exactly at any time: the state at each command instant by the
exact zero-order-hold recursion (a linear filter when the commands come at a steady rate), then
the free response from there to each sample. A profile reference, and a rate-limited step
reference (a slew: a profile of infinite acceleration), is a polynomial of degree at most two in
time between its breakpoints (each command's rising, cruising and falling phases and its hold,
cut by the next command): it is integrated exactly too, each piece's response its particular
polynomial plus the free response from the state where the piece begins (the states carried
from piece to piece, one step per piece), read at each sample. Before the first command every
actuator rests on it (a profile's: where the caller says it rests).
Internal units throughout (m for length controls).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from platkit.errors import BadInput

__all__ = ["ResponseModel", "REFERENCES", "KINDS", "actuator_positions", "trapezoid_reference", "slew_reference",
           "lags"]

REFERENCES = ("step", "profile")
KINDS = ("first_order", "second_order")
#: command intervals equal to this (s) are one steady rate (the files keep microseconds)
STEADY_TOL_S = 2e-6
#: the smallest time constant and damping the response takes (a parameter pushed below is clipped;
#: a time constant enters as its magnitude, :meth:`ResponseModel.positive`)
TAU_MIN_S, ZETA_MIN = 1e-3, 0.05


@dataclass
class ResponseModel:
    """Which response (``kind``) after which reference (``reference``), for ``n_u`` actuators;
    ``delays``: each actuator's own pure delay beyond the shift; ``rate_limit``: a step
    reference slewed at each actuator's rate limit (a profile reference has one always);
    ``first``: with kind ``second_order``, the actuators that follow a first-order response all
    the same (no damping of their own: a response chosen per actuator).

    theta (the fitted vector): [shift_s, tau_s (n_u), damping (one per second-order actuator, in
    actuator order) for second_order, rate (n_u) for a profile reference or a rate-limited step
    one, accel (n_u) for a profile reference, delay_s (n_u) with ``delays``]."""

    kind: str
    reference: str
    n_u: int
    delays: bool = False
    rate_limit: bool = False
    first: tuple[int, ...] = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise BadInput(f"actuator response: kind must be one of {', '.join(KINDS)}, not {self.kind!r}")
        if self.reference not in REFERENCES:
            raise BadInput(f"actuator response: reference must be one of {', '.join(REFERENCES)}, "
                           f"not {self.reference!r}")
        self.first = tuple(sorted({int(j) for j in self.first}))
        if self.first and (self.kind != "second_order" or not all(0 <= j < self.n_u for j in self.first)):
            raise BadInput("actuator response: first-order actuators are named within a second-order response, "
                           f"by index below {self.n_u}")
        self._layout = [(b, j) for b in self.blocks for j in range(self.n_u) if b != "damping" or self.is_second(j)]
        self._where = {key: 1 + k for k, key in enumerate(self._layout)}

    def is_second(self, j: int) -> bool:
        """Whether actuator j follows the second-order response (it has a damping)."""
        return self.kind == "second_order" and j not in self.first

    @property
    def kinds(self) -> list[str]:
        """Each actuator's response, 'first_order' or 'second_order'."""
        return ["second_order" if self.is_second(j) else "first_order" for j in range(self.n_u)]

    @property
    def kind_label(self) -> str:
        """The response's kind in one word: the actuators' kind where they share one
        ('first_order', 'second_order'), 'per_actuator' where they differ."""
        kinds = set(self.kinds)
        return kinds.pop() if len(kinds) == 1 else "per_actuator"

    @property
    def blocks(self) -> list[str]:
        out = ["tau_s"]
        if self.kind == "second_order":
            out.append("damping")
        if self.reference == "profile":
            out += ["rate", "accel"]
        elif self.rate_limit:
            out.append("rate")
        if self.delays:
            out.append("delay_s")
        return out

    def has(self, block: str, j: int) -> bool:
        """Whether actuator j has a parameter of ``block`` (a first-order one has no damping)."""
        return (block, j) in self._where

    @property
    def slewed(self) -> bool:
        """A step reference slewed at a rate limit."""
        return self.reference == "step" and self.rate_limit

    @property
    def size(self) -> int:
        return 1 + len(self._layout)

    def names(self, control_names: list[str]) -> list[str]:
        return ["shift_s"] + [f"{b}.{control_names[j]}" for b, j in self._layout]

    def split(self, theta) -> dict[str, np.ndarray]:
        """{'shift_s': float array (), block: (n_u,)} of theta; a first-order actuator's damping
        is NaN; each time constant as its magnitude (a time constant enters the response as
        |tau|: :meth:`positive`)."""
        theta = np.asarray(theta, float)
        out = {"shift_s": theta[0]}
        for b in self.blocks:
            v = np.full(self.n_u, np.nan)
            for j in range(self.n_u):
                if (b, j) in self._where:
                    v[j] = theta[self._where[(b, j)]]
            out[b] = np.abs(v) if b == "tau_s" else v
        return out

    def positive(self, theta) -> np.ndarray:
        """``theta`` with each time constant as its magnitude: the same response. A time constant
        enters the response as |tau| (floored at TAU_MIN_S), so the response is even in it and a
        fit without bounds that steps past zero finds the same response on the positive side
        (where it entered clipped, the response was flat below the floor: a step past zero
        stopped there, at a negative time constant); a fit's result is written with its
        magnitude."""
        out = np.asarray(theta, float).copy()
        k = [self._where[("tau_s", j)] for j in range(self.n_u)]
        out[k] = np.abs(out[k])
        return out

    def index(self, block: str, j: int) -> int:
        return self._where[(block, j)]

    def actuator_of(self, k: int) -> int | None:
        """The actuator theta[k] belongs to (None: the shift, shared by all)."""
        return None if k == 0 else self._layout[k - 1][1]


def lags(model: ResponseModel, theta) -> np.ndarray:
    """(n_u,) each actuator's whole time lag s + d_j (s; the shift alone without ``delays``): what
    the markers fix, whichever of the shift and the delays was held."""
    par = model.split(theta)
    d = par["delay_s"] if "delay_s" in par else np.zeros(model.n_u)
    return float(par["shift_s"]) + np.asarray(d, float)


def slew_reference(s: np.ndarray, T: np.ndarray, u: np.ndarray, rate: float, start: float | None = None,
                   seg: np.ndarray | None = None) -> np.ndarray:
    """One actuator's rate-limited step reference at commands-clock times ``s`` (K,): from each
    command u_i (sent at T_i) it moves at ``rate`` from where it stood towards u_i, and stands
    there once reached, until the next command; before T_0 it rests at ``start`` (default u_0).
    ``seg``: the command in force at each of ``s``, when the caller has it."""
    v = max(float(rate), 1e-12)
    origin = _slew_origins(T, u, v, start)
    if seg is None:
        seg = np.searchsorted(T, s, side="right") - 1
    i = np.maximum(seg, 0)
    d = u[i] - origin[i]
    moved = np.minimum(np.abs(d), v * np.maximum(s - T[i], 0.0))
    return np.where(seg < 0, origin[0], origin[i] + np.sign(d) * moved)


def _slew_origins(T: np.ndarray, u: np.ndarray, v: float, start: float | None) -> np.ndarray:
    """Where each command's slew (at rate v) starts: where the last one stood when it was cut (a
    plain loop over the commands)."""
    N = len(T)
    origin = np.empty(N)
    origin[0] = float(u[0]) if start is None else float(start)
    span = np.diff(T)
    for i in range(N - 1):
        d = float(u[i] - origin[i])
        step = v * float(span[i])
        origin[i + 1] = u[i] if abs(d) <= step else origin[i] + math.copysign(step, d)
    return origin


def trapezoid_reference(s: np.ndarray, T: np.ndarray, u: np.ndarray, rate: float, accel: float,
                        start: float | None = None, seg: np.ndarray | None = None) -> np.ndarray:
    """One actuator's profile reference at commands-clock times ``s`` (K,): each command u_i (sent
    at T_i) starts a trapezoidal profile (rate, accel) from where the last one stood when it was
    cut; before T_0 it rests at ``start`` (default u_0). ``seg``: the command in force at each of
    ``s`` (searchsorted of T, right, minus 1), when the caller has it."""
    v, a = max(float(rate), 1e-12), max(float(accel), 1e-12)
    origin = _profile_origins(T, u, v, a, start)
    if seg is None:
        seg = np.searchsorted(T, s, side="right") - 1
    out = np.where(seg < 0, origin[0], u[np.maximum(seg, 0)]).astype(float)
    # a profile that has ended stands on its command: only the times within a move are computed
    length = _phases(np.abs(u - origin), v, a)[1]
    k = np.nonzero((seg >= 0) & (s - T[np.maximum(seg, 0)] < length[np.maximum(seg, 0)]))[0]
    i = seg[k]
    d = u[i] - origin[i]
    out[k] = origin[i] + np.sign(d) * _covered(s[k] - T[i], np.abs(d), v, a)
    return out


def _profile_origins(T: np.ndarray, u: np.ndarray, v: float, a: float, start: float | None) -> np.ndarray:
    """Where each command's trapezoidal profile starts: where the last one stood when it was cut
    (a few hundred holds: a plain loop)."""
    N = len(T)
    origin = np.empty(N)
    pos = float(u[0]) if start is None else float(start)
    span = np.diff(T)
    for i in range(N):
        origin[i] = pos
        if i + 1 < N:
            d = float(u[i] - pos)
            pos = pos + float(np.sign(d)) * _covered_one(float(span[i]), abs(d), v, a)
    return origin


def _phases(d: np.ndarray, v: float, a: float) -> tuple[np.ndarray, np.ndarray]:
    """The trapezoid over distances ``d`` >= 0 at rate v and acceleration a: (the time its rising
    phase lasts, the time it ends); a triangle where d < v^2 / a (the rate never reached)."""
    tri = d < v * v / a
    ta = np.where(tri, np.sqrt(d / a), v / a)
    return ta, np.where(tri, 2 * ta, d / v + v / a)


def _covered_one(s: float, d: float, v: float, a: float) -> float:
    """:func:`_covered` for one time and distance (plain floats)."""
    ta = math.sqrt(d / a) if d < v * v / a else v / a
    T = 2 * ta if d < v * v / a else d / v + v / a
    s = max(s, 0.0)
    if s <= ta:
        return 0.5 * a * s * s
    if s <= T - ta:
        return 0.5 * a * ta * ta + a * ta * (s - ta)
    return d - 0.5 * a * (T - s) ** 2 if s < T else d


def _covered(s, d, v, a):
    """Distance covered after time s >= 0 by the trapezoid over distance d >= 0 (broadcast; a time
    below 0 counts as 0): each time's expression evaluated for its own phase alone."""
    s, d = np.broadcast_arrays(np.clip(np.asarray(s, float), 0.0, None), np.asarray(d, float))
    shape, s, d = s.shape, s.reshape(-1), d.reshape(-1)
    ta, end = _phases(d, v, a)
    out = d.copy()
    rising = s <= ta
    cruise = ~rising & (s <= end - ta)
    falling = ~rising & ~cruise & (s < end)
    out[rising] = 0.5 * a * s[rising] ** 2
    t, c = ta[cruise], a * ta[cruise]
    out[cruise] = 0.5 * a * t ** 2 + c * (s[cruise] - t)
    r = np.maximum(end[falling] - s[falling], 0.0)
    out[falling] = out[falling] - 0.5 * a * r ** 2
    return out.reshape(shape)


def _free(tau_s: np.ndarray, e0: np.ndarray, v0: np.ndarray, tau: float, zeta: float):
    """Free response of x'' + 2 zeta w x' + w^2 x = 0 (w = 1/tau) after ``tau_s`` from (e0, v0):
    (position, velocity), broadcast."""
    w = 1.0 / tau
    g = w * w * (zeta * zeta - 1.0)
    a = zeta * w
    if abs(g) < 1e-12 * w * w:  # critically damped
        ex = np.exp(-a * tau_s)
        C, S = ex, ex * tau_s
    elif g > 0:
        b = np.sqrt(g)
        e1, e2 = np.exp((b - a) * tau_s), np.exp(-(a + b) * tau_s)
        C, S = 0.5 * (e1 + e2), 0.5 * (e1 - e2) / b
    else:
        b = np.sqrt(-g)
        ex = np.exp(-a * tau_s)
        C, S = ex * np.cos(b * tau_s), ex * np.sin(b * tau_s) / b
    return e0 * C + (v0 + a * e0) * S, v0 * C - (w * w * e0 + a * v0) * S


def _step_one(t: np.ndarray, T: np.ndarray, u: np.ndarray, tau: float, zeta: float | None,
              seg: np.ndarray | None = None) -> np.ndarray:
    """One actuator after a step reference, exactly, at commands-clock times t (K,); ``seg``: the
    command in force at each of t (searchsorted of T, right, minus 1), when the caller has it."""
    N = len(T)
    p = np.empty(N)
    v = np.zeros(N)
    p[0] = u[0]
    span = np.diff(T)
    steady = N > 2 and float(np.ptp(span)) <= STEADY_TOL_S
    if zeta is None:  # first order: p_(i+1) = u_i + (p_i - u_i) exp(-span / tau)
        if steady:
            a = float(np.exp(-span[0] / tau))
            p[1:] = u[0] + signal.lfilter([1.0 - a], [1.0, -a], u[:-1] - u[0])
        else:
            a = np.exp(-span / tau)
            for i in range(N - 1):
                p[i + 1] = u[i] + (p[i] - u[i]) * a[i]
    elif steady:  # the state recursion over a steady interval is one linear filter per output
        h = float(span[0])
        pp, pv = _free(np.array(h), np.array(1.0), np.array(0.0), tau, zeta)
        vp, vv = _free(np.array(h), np.array(0.0), np.array(1.0), tau, zeta)
        Phi = np.array([[float(pp), float(vp)], [float(pv), float(vv)]])
        Gam = (np.eye(2) - Phi)[:, 0]
        # c (zI - Phi)^-1 Gam = c [[z - Phi22, Phi12], [Phi21, z - Phi11]] Gam / (z^2 - tr z + det)
        den = [1.0, -float(np.trace(Phi)), float(np.linalg.det(Phi))]
        adj0 = np.array([[-Phi[1, 1], Phi[0, 1]], [Phi[1, 0], -Phi[0, 0]]]) @ Gam
        x = u - u[0]  # the state at T_i from the commands before it (a strictly proper filter)
        for row, out in ((0, p), (1, v)):
            num = [0.0, float(Gam[row]), float(adj0[row])]
            out[:] = signal.lfilter(num, den, x) + (u[0] if row == 0 else 0.0)
    else:
        for i in range(N - 1):
            e, vel = _free(np.array(span[i]), np.array(p[i] - u[i]), np.array(v[i]), tau, zeta)
            p[i + 1], v[i + 1] = u[i] + float(e), float(vel)
    if seg is None:
        seg = np.searchsorted(T, t, side="right") - 1
    out = np.full(len(t), float(u[0]))
    ok = seg >= 0
    i = seg[ok]
    s = t[ok] - T[i]
    if zeta is None:
        out[ok] = u[i] + (p[i] - u[i]) * np.exp(-s / tau)
    else:
        out[ok] = u[i] + _free(s, p[i] - u[i], v[i], tau, zeta)[0]
    return out


def _reference_pieces(T: np.ndarray, u: np.ndarray, rate: float, accel: float | None,
                      start: float) -> tuple[np.ndarray, np.ndarray]:
    """A profile reference (``accel`` None: a slew at ``rate`` alone) less ``start``, as pieces:
    (b (M,), c (M, 3)), piece k from b[k] (b increasing, b[0] = T_0) to b[k + 1] (the last for
    ever) reading r(b[k] + s) - start = c[k, 0] + c[k, 1] s + c[k, 2] s^2. The pieces are each
    command's phases (a profile's rising, cruising, falling and hold; a slew's ramp and hold)
    that last a while before the next command, as :func:`trapezoid_reference` and
    :func:`slew_reference` read them (the same origins)."""
    N, v = len(T), max(float(rate), 1e-12)
    zero = np.zeros(N)
    if accel is None:
        o = _slew_origins(T, u, v, start)
        sg, d = np.sign(u - o), np.abs(u - o)
        begin = np.stack([zero, d / v], 1)
        c = np.stack([np.stack([o, u], 1), np.stack([sg * v, zero], 1), np.zeros((N, 2))], 2)
    else:
        a = max(float(accel), 1e-12)
        o = _profile_origins(T, u, v, a, start)
        sg, d = np.sign(u - o), np.abs(u - o)
        ta, end = _phases(d, v, a)
        half, top = 0.5 * a * ta * ta, sg * a * ta
        begin = np.stack([zero, ta, end - ta, end], 1)
        c = np.stack([np.stack([o, o + sg * half, o + sg * (d - half), u], 1),
                      np.stack([zero, top, top, zero], 1),
                      np.stack([0.5 * a * sg, zero, -0.5 * a * sg, zero], 1)], 2)
    until = np.minimum(np.append(begin[:, 1:], np.full((N, 1), np.inf), 1), np.append(np.diff(T), np.inf)[:, None])
    keep = begin < until  # a phase that ends before it begins, or begins after the next command, is none
    c[:, :, 0] -= start
    return (T[:, None] + begin)[keep], c[keep]


def _piece_states(b: np.ndarray, c: np.ndarray, tau: float, zeta: float | None):
    """The response to :func:`_reference_pieces`' pieces from rest (at 0) at b[0]: (p (M, 3),
    e (M,), ev (M,)). On piece k the response is x(b[k] + s) = p[k, 0] + p[k, 1] s + p[k, 2] s^2
    (the particular response to the piece's polynomial: r - alpha r' + (alpha^2 - beta) r'' for
    the response 1 + alpha D + beta D^2) plus the free response (:func:`_free`) from e[k] (and
    rate ev[k], second order) at s = 0; each piece's state is the last one's at its end."""
    alpha, beta = (tau, 0.0) if zeta is None else (2.0 * zeta * tau, tau * tau)
    p = np.stack([c[:, 0] - alpha * c[:, 1] + 2.0 * (alpha * alpha - beta) * c[:, 2],
                  c[:, 1] - 2.0 * alpha * c[:, 2], c[:, 2]], 1)
    L = np.diff(b)
    # where piece k's particular response ends less where piece k + 1's begins (position, rate)
    jump = (p[:-1, 0] + L * (p[:-1, 1] + L * p[:-1, 2]) - p[1:, 0]).tolist()
    e = [-float(p[0, 0])]
    if zeta is None:
        for q, j in zip(np.exp(-L / tau).tolist(), jump):  # the pieces' states: a plain loop over them
            e.append(q * e[-1] + j)
        return p, np.array(e), np.zeros(len(b))
    jump_v = (p[:-1, 1] + 2.0 * L * p[:-1, 2] - p[1:, 1]).tolist()
    pp, pv = _free(L, 1.0, 0.0, tau, zeta)
    vp, vv = _free(L, 0.0, 1.0, tau, zeta)
    ev = [-float(p[0, 1])]
    for a11, a21, a12, a22, j, jv in zip(pp.tolist(), pv.tolist(), vp.tolist(), vv.tolist(), jump, jump_v):
        x0, v0 = e[-1], ev[-1]
        e.append(a11 * x0 + a12 * v0 + j)
        ev.append(a21 * x0 + a22 * v0 + jv)
    return p, np.array(e), np.array(ev)


def _profile_one(t: np.ndarray, T: np.ndarray, u: np.ndarray, tau: float, zeta: float | None, rate: float,
                 accel: float | None, start: float, cache: dict | None = None, key=None) -> np.ndarray:
    """One actuator after a profile reference (``accel`` None: a slewed step reference, rate
    limited alone), exactly, at t: the piece in force at each time, its particular polynomial
    and the free response from its state (:func:`_piece_states`); at ``start`` before T_0. A
    rate, acceleration, time constant or damping that is not finite gives NaN from T_0 on. With
    ``cache``, the pieces and their states are kept under ``key`` (the actuator) and their
    parameters, at most CACHE_ENTRIES of them."""
    out = np.full(len(t), float(start))
    if not all(math.isfinite(x) for x in (rate, tau, 0.0 if accel is None else accel, 0.0 if zeta is None else zeta)):
        out[t >= T[0]] = np.nan
        return out
    skey = ("states", key, rate, accel, start, tau, zeta)
    states = None if cache is None else cache.get(skey)
    if states is None:
        rkey = ("pieces", key, rate, accel, start)
        pieces = None if cache is None else cache.get(rkey)
        if pieces is None:
            pieces = _reference_pieces(T, u, rate, accel, start)
            _keep(cache, rkey, pieces)
        p, e, ev = _piece_states(pieces[0], pieces[1], tau, zeta)
        q = ev if zeta is None else ev + (zeta / tau) * e
        states = (pieces[0], *np.ascontiguousarray(p.T), e, q)
        _keep(cache, skey, states)
    b, p0, p1, p2, e, q = states
    k = _piece_of(b, t)
    ok = k >= 0
    i, s = (k, t - b[k]) if ok.all() else (k[ok], t[ok] - b[k[ok]])
    x = p0[i] + s * (p1[i] + s * p2[i])
    if zeta is None:
        x += e[i] * np.exp(-s / tau)
    else:  # the free response's position (_free's) from each piece's e and q = ev + zeta w e
        w = 1.0 / tau
        a, g = zeta * w, w * w * (zeta * zeta - 1.0)
        if abs(g) < 1e-12 * w * w:  # critically damped
            C = np.exp(-a * s)
            S = C * s
        elif g > 0:
            r = math.sqrt(g)
            e1, e2 = np.exp((r - a) * s), np.exp(-(a + r) * s)
            C, S = 0.5 * (e1 + e2), (0.5 / r) * (e1 - e2)
        else:
            r = math.sqrt(-g)
            ex = np.exp(-a * s)
            C, S = ex * np.cos(r * s), ex * np.sin(r * s) / r
        x += e[i] * C + q[i] * S
    out[ok] = x + start
    return out


def _piece_of(b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The piece in force at each of the times t (searchsorted of b, right, minus 1: -1 before
    b[0]); for times in increasing order, counted by runs from each piece's first time."""
    if len(t) > 1 and bool((t[1:] >= t[:-1]).all()):
        first = np.searchsorted(t, b, side="left")
        return np.repeat(np.arange(-1, len(b)), np.diff(np.concatenate([[0], first, [len(t)]])))
    return np.searchsorted(b, t, side="right") - 1


def _segments(cache: dict | None, T: np.ndarray, s: np.ndarray, shift: float) -> np.ndarray | None:
    """The command in force at each of the times s (= the samples' times minus ``shift``), kept in
    ``cache`` for the same times and shift (None without a cache)."""
    if cache is None or not len(s):
        return None
    key = ("stepseg", shift, len(s), hash(s.tobytes()))
    seg = cache.get(key)
    if seg is None:
        seg = np.searchsorted(T, s, side="right") - 1
        _keep(cache, key, seg)
    return seg


#: entries a cache of :func:`actuator_positions` keeps (the oldest dropped first)
CACHE_ENTRIES = 32


def _keep(cache: dict | None, key, value) -> None:
    if cache is None:
        return
    if len(cache) >= CACHE_ENTRIES:
        cache.pop(next(iter(cache)))  # the oldest
    cache[key] = value


def actuator_positions(model: ResponseModel, theta, T: np.ndarray, U: np.ndarray, t: np.ndarray,
                       only: int | None = None, start: np.ndarray | None = None, cache: dict | None = None) -> np.ndarray:
    """(K, n_u) the actuators' positions at motion-capture times t (K,) from the command log (T (N,)
    s on the commands clock, U (N, n_u)) under the response ``theta`` (see :class:`ResponseModel`).
    ``only``: that actuator's column alone, (K,). ``start`` (n_u,): where a profile's actuators
    rest before the first command (default: on it; a step reference always starts on it).
    ``cache``: a dict the caller keeps between calls on the same log (a profile's reference and
    pieces and their states are reused where only the shift changed, and the pieces where only the response did).
    Actuator j is seen at t - shift - delay_j (:func:`lags`)."""
    par = model.split(theta)
    lag = lags(model, theta)
    t = np.asarray(t, float)
    cols = range(model.n_u) if only is None else [only]
    out = []
    for j in cols:
        s = t - float(lag[j])
        tau = max(float(par["tau_s"][j]), TAU_MIN_S)  # its magnitude (split), floored
        zeta = max(float(par["damping"][j]), ZETA_MIN) if model.is_second(j) else None
        if model.reference == "step" and not model.slewed:
            out.append(_step_one(s, T, U[:, j], tau, zeta, _segments(cache, T, s, float(lag[j]))))
        else:
            accel = float(par["accel"][j]) if model.reference == "profile" else None
            first = float(U[0, j] if start is None or model.reference == "step" else start[j])
            out.append(_profile_one(s, T, U[:, j], tau, zeta, float(par["rate"][j]), accel, first, cache, j))
    return out[0] if only is not None else np.stack(out, axis=1)
