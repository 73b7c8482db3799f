"""platkit.play.play_memory as f34c969 wrote it, the stack of turning points walked over every
sample: the reference the faster walk (3b34037) is held to, to the bit (shared by
tests/unit/test_play_memory_exact.py and benchmarks/play_memory_speed.py), with the random
sequences both walk it on."""
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


def random_column(rng: np.random.Generator, T: int) -> np.ndarray:
    """One actuator's T inputs of a random kind: plateaus and repeated values, random walks, smooth
    swings with noise rounded to a few places, nested swings that shrink (deep stacks) or grow,
    values repeated three times, a slow drift with noise of 0, 1e-6 or 1e-3."""
    t = np.arange(T, dtype=float)
    kind = rng.integers(7)
    if kind == 0:
        return rng.integers(-3, 4, T).astype(float)
    if kind == 1:
        return np.cumsum(rng.choice([-1.0, 0.0, 0.0, 1.0, 2.0], T)) * 0.25
    if kind == 2:
        return np.round(np.sin(rng.uniform(0.005, 0.3) * t) + rng.normal(0, 0.02, T), int(rng.integers(1, 5)))
    if kind == 3:
        return np.sin(rng.uniform(0.3, 1.5) * t) * np.exp(-t / rng.uniform(20, 400)) + rng.uniform(-1, 1)
    if kind == 4:
        return np.sin(rng.uniform(0.2, 1.0) * t) * (1 + t) ** rng.uniform(0.2, 1.0)
    if kind == 5:
        return np.repeat(rng.normal(0, 1, T // 3 + 1), 3)[:T]
    return 4 + np.sin(rng.uniform(0.001, 0.02) * t) + rng.normal(0, rng.choice([0, 1e-6, 1e-3]), T)


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two arrays have the same shape and the same bytes (NaN equal to the same NaN)."""
    return a.shape == b.shape and a.tobytes() == b.tobytes()
