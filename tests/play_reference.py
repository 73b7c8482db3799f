"""platkit.play.play_memory as f34c969 wrote it, the stack of turning points walked over every
sample: the reference the faster walk (3b34037) is held to, to the bit (shared by
tests/unit/test_play_memory_exact.py and benchmarks/play_memory_speed.py)."""
from __future__ import annotations

import numpy as np


def full_walk(x: np.ndarray, at: np.ndarray, depth: int = 200) -> np.ndarray:
    """play_memory as f34c969 wrote it: the stack walked over every sample."""
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
