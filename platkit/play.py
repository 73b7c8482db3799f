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


def play_memory(x: np.ndarray, at: np.ndarray, depth: int = PLAY_DEPTH) -> np.ndarray:
    """(N, n_u, L, 3) what a play (deadband) of any half width h needs of the commands x (T, n_u)
    up to each row's place ``at`` (N,) in them (:func:`play_offset` reads it): the play's turning
    points z_0 (the row's command), z_1, ... back in time, alternating, each swing |z_l - z_(l-1)|
    wider than the one after it (a command at or beyond z_(l+1) wipes out z_l and z_(l+1)). The
    output is z_(l-1) + h sign(z_l - z_(l-1)) for the first swing wider than 2h; where none is, it
    still holds the first command. Entries (swing, its sign, z_(l-1)), NaN swings unused; the last
    (x_0, highest, lowest). At most ``depth`` are kept: the oldest then stands for all wider (its
    swing infinite: :func:`play_cut` counts the rows where that bit)."""
    x, at = np.atleast_2d(np.asarray(x, float)), np.asarray(at, int)
    want = np.zeros(len(x), bool)
    want[at] = True
    runs: list[dict[int, np.ndarray]] = [{} for _ in range(x.shape[1])]
    for i in range(x.shape[1]):
        S: list[float] = []
        lost = False
        for k, v in enumerate(x[:, i].tolist()):
            if not S or v != S[-1]:
                S.append(v)
            while len(S) >= 3:
                if (S[-2] - S[-3]) * (S[-1] - S[-2]) > 0:  # S[-2] on the way: no turning point
                    del S[-2]
                elif abs(S[-1] - S[-2]) >= abs(S[-2] - S[-3]):  # S[-3] wiped out, S[-2] with it if older remain
                    del S[-3:-1 if len(S) >= 4 else -2]
                else:
                    break
            lost = lost or len(S) > depth + 1
            del S[:-depth - 1]
            if not want[k]:
                continue
            z = np.array(S[::-1])
            runs[i][k] = np.column_stack([np.abs(np.diff(z)), np.sign(np.diff(z)), z[:-1]])
            if lost and len(z) > 1:
                runs[i][k][-1, 0] = np.inf
    L = max([1] + [len(r) for i in range(x.shape[1]) for r in (runs[i][k] for k in at)])
    out = np.full((len(at), x.shape[1], L + 1, 3), np.nan)
    for i in range(x.shape[1]):
        for n, k in enumerate(at):
            out[n, i, :len(runs[i][k])] = runs[i][k]
        out[:, i, -1] = np.column_stack([np.full(len(at), x[0, i] if len(x) else np.nan),
                                         np.maximum.accumulate(x[:, i])[at], np.minimum.accumulate(x[:, i])[at]])
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
