"""The play (a deadband) of half width h over a sequence of inputs in order, y_k = clamp(y_(k-1),
u_k - h, u_k + h), y before the first input = the first: what backlash is, one operator for every
reader. :func:`play_memory` keeps, at chosen rows, what the play of any h needs of the inputs up to
there (the turning points that are not yet wiped out); :func:`play_offset` reads the output less the
input from it at a given h, and carries it on through later inputs where a caller gives them (a
stream's samples). The settled sessions' commands (platkit.effects.with_history, platkit.settle),
``platkit predict``'s and a stream's modelled drive positions (platkit.diagnose.stream) all go
through these two.
"""
from __future__ import annotations

import numpy as np

__all__ = ["PLAY_DEPTH", "play_cut", "play_memory", "play_offset"]

#: the most turning points of one actuator's inputs a play remembers (:func:`play_memory`)
PLAY_DEPTH = 200


#: a column's monotone runs are skipped (:func:`play_memory`) where every value is 0 or of magnitude in
#: [2**-400, 2**400]: there no difference of two distinct values nor product of two differences is 0 or
#: out of range, so each of the walk's tests reads the exact sign it stands for
_SKIP_MAGNITUDE = (2.0 ** -400, 2.0 ** 400)


def play_memory(x: np.ndarray, at: np.ndarray, depth: int = PLAY_DEPTH) -> np.ndarray:
    """(N, n_u, L, 3) what a play (deadband) of any half width h needs of the commands x (T, n_u)
    up to each row's place ``at`` (N,) in them (:func:`play_offset` reads it): the play's turning
    points z_0 (the row's command), z_1, ... back in time, alternating, each swing |z_l - z_(l-1)|
    wider than the one after it (a command at or beyond z_(l+1) wipes out z_l and z_(l+1)). The
    output is z_(l-1) + h sign(z_l - z_(l-1)) for the first swing wider than 2h; where none is, it
    still holds the first command. Entries (swing, its sign, z_(l-1)), NaN swings unused; the last
    (x_0, highest, lowest). At most ``depth`` are kept: the oldest then stands for all wider (its
    swing infinite: :func:`play_cut` counts the rows where that bit).

    The stack of turning points is walked over fewer samples, with the same result to the bit
    (:func:`_walk`)."""
    x, at = np.atleast_2d(np.asarray(x, float)), np.asarray(at, int)
    if len(at) and (at.min() < 0 or at.max() >= len(x)):
        raise IndexError(f"play_memory: row {int(at.min() if at.min() < 0 else at.max())} asked of {len(x)} commands")
    walks = [_walk(x[:, i], at, depth) for i in range(x.shape[1])]
    L = max([1] + [len(z) - 1 for stacks, _, _ in walks for z in stacks])
    out = np.full((len(at), x.shape[1], L + 1, 3), np.nan)
    for i, (stacks, lost, row) in enumerate(walks):
        if len(at):
            out[:, i, :L] = _entries(stacks, lost, L)[row]
        out[:, i, -1] = np.column_stack([np.full(len(at), x[0, i] if len(x) else np.nan),
                                         np.maximum.accumulate(x[:, i])[at], np.minimum.accumulate(x[:, i])[at]])
    return out


def _walk(v: np.ndarray, at: np.ndarray, depth: int) -> tuple[list[list[float]], list[bool], np.ndarray]:
    """The stack of turning points of the inputs ``v`` (T,) (newest first) after each of the rows
    ``at`` (N,), whether the depth had cut it by then, and of each row its stack's index.

    The stack takes each sample v in turn: pushed (if it differs from the top); then, while three
    or more remain, the middle of the top three deleted if it lies on the way, the two below the top
    if the top's swing is as wide as theirs (the oldest alone if only three), then the bottom cut to
    ``depth`` + 1 (``lost`` from then on). Walked over fewer samples, exactly:

    - Of a run of equal samples only the first: the top is always the last sample (only points below
      it are deleted), so an equal one pushes nothing and the stack, stable, stays as it was.
    - A run strictly between the runs before and after it (inside a strictly monotone stretch),
      unless a row is asked there, is skipped where the stack before the stretch holds at most
      ``depth`` points. Walked, its sample d is pushed, then deleted at once as on the way by the
      next sample t, further the same way (the top pair always points the way of the last move,
      wipe-outs included). Before that, d made the moves t makes without it, in the same order and
      no others: t pops the top as on the way exactly when d did (the same way from it), and every
      pair below that d wiped out t wipes out too (the top's swing |t - z| only grows as t goes
      further, rounding being monotone), the len-3 rule alike; t then goes on from where d stopped.
      So t leaves the same stack, d skipped or walked, and d's own stack, at most one point longer
      than before the stretch, never meets the depth cut nor sets ``lost``. Where the stack is full
      (depth + 1 points) the stretch is walked sample by sample.
    - Those signs are exact where every value is 0 or of magnitude in _SKIP_MAGNITUDE; a column with
      any other value (NaN, inf, subnormal) or a depth below 1 is walked run by run."""
    if not len(v) or not len(at):
        return [], [], np.zeros(len(at), int)
    start = np.flatnonzero(np.r_[True, v[1:] != v[:-1]])
    d = v[start]
    keep = np.ones(len(d), bool)
    a = np.abs(d)
    if depth >= 1 and np.all((a == 0) | ((a >= _SKIP_MAGNITUDE[0]) & (a <= _SKIP_MAGNITUDE[1]))):
        up = d[1:] > d[:-1]
        keep[1:-1] = up[1:] != up[:-1]
    run = np.searchsorted(start, at, side="right") - 1
    keep[run] = True
    asked = np.zeros(len(d), bool)
    asked[run] = True
    kept = np.flatnonzero(keep)
    S: list[float] = []
    lost, prev = False, -1
    stacks: list[list[float]] = []
    losts: list[bool] = []
    slot = np.zeros(len(d), int)
    for j, u_j, ask in zip(kept.tolist(), d[kept].tolist(), asked[kept].tolist()):
        for u in (d[prev + 1:j + 1].tolist() if len(S) > depth and j > prev + 1 else (u_j,)):
            S.append(u)  # differs from the top: a run from the run before it, a stretch's end from its start
            while len(S) >= 3:
                if (S[-2] - S[-3]) * (S[-1] - S[-2]) > 0:  # S[-2] on the way: no turning point
                    del S[-2]
                elif abs(S[-1] - S[-2]) >= abs(S[-2] - S[-3]):  # S[-3] wiped out, S[-2] with it if older remain
                    del S[-3:-1 if len(S) >= 4 else -2]
                else:
                    break
            lost = lost or len(S) > depth + 1
            del S[:-depth - 1]
        prev = j
        if ask:
            slot[j] = len(stacks)
            stacks.append(S[::-1])
            losts.append(lost)
    return stacks, losts, slot[run]


def _entries(stacks: list[list[float]], lost: list[bool], L: int) -> np.ndarray:
    """(len(stacks), L, 3) :func:`play_memory`'s entries of stacks z (newest first): (|z_l - z_(l-1)|,
    its sign, z_(l-1)) for l = 1 .. len(z) - 1, the last swing infinite where ``lost``, NaN past them."""
    n = np.array([len(z) for z in stacks])
    Z = np.full((len(stacks), L + 1), np.nan)
    Z[np.repeat(np.arange(len(stacks)), n), np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)] = \
        [u for z in stacks for u in z]
    step = Z[:, 1:] - Z[:, :-1]
    used = np.arange(L)[None, :] < (n - 1)[:, None]
    out = np.where(used[..., None], np.stack([np.abs(step), np.sign(step), Z[:, :-1]], axis=-1), np.nan)
    cut = np.flatnonzero(np.array(lost) & (n > 1))
    out[cut, n[cut] - 2, 0] = np.inf
    return out


def play_cut(memory: np.ndarray) -> np.ndarray:
    """(N, n_u) True where a :func:`play_memory` row lost turning points to its depth (a play wider
    than its oldest kept swing reads that swing's turn)."""
    return np.isinf(memory[..., :-1, 0]).any(axis=-1)


def play_offset(memory: np.ndarray, controls: np.ndarray, h: float, weight: np.ndarray | None = None) -> np.ndarray:
    """(N,) y_k - u_k of a play y_k = clamp(y_(k-1), u_k - h, u_k + h) over the session's commands (y
    before the first = the first), half width ``h`` >= 0, from one actuator's ``memory`` (N, L, 3)
    (:func:`play_memory`) at rows whose commands are ``controls`` (N,).

    ``controls`` (N, S) with ``weight`` (N, S): the inputs from each memory's row on (the first its
    own), the output carried through them by the same clamp, and sum_s weight (y_s - u_s) (a
    stream's node, the samples its window's fit weighs as it weighs the controls)."""
    start = memory[:, -1]
    found = np.nan_to_num(memory[:, :-1, 0], nan=-1.0) > 2 * h
    first = np.argmax(found, axis=1)
    pick = memory[np.arange(len(memory)), first]
    held = np.where(start[:, 0] < start[:, 1] - h, start[:, 1] - h, np.minimum(start[:, 0], start[:, 2] + h))
    y = np.where(found.any(axis=1), pick[:, 2] + pick[:, 1] * h, held)
    if weight is None:
        return y - controls
    u, w = np.asarray(controls, float), np.asarray(weight, float)
    out = w[:, 0] * (y - u[:, 0])
    for s in range(1, u.shape[1]):
        y = np.clip(y, u[:, s] - h, u[:, s] + h)
        out += w[:, s] * (y - u[:, s])
    return out
