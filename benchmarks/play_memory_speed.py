"""platkit.play.play_memory against the walk over every sample it replaced (f34c969, kept
verbatim in tests/play_reference.py): CPU time as a ratio old / new, and whether the memories are the same to the bit.

On a 10-minute 250 Hz stream (``--stream`` and ``--calibration``): the drives' modelled
positions that platkit.diagnose.stream.stream_poses hands to play_memory (captured from one run),
play_memory alone on them, and stream_poses' CPU with the old operator put in its place and with
the new. On ``--random`` random sequences (plateaus, repeated values, random walks, smooth swings
with noise, nested swings shrinking and growing; depths 1 to 200; rows asked in any order, with
repeats): identity, and the total time as a ratio.

The stream of docs/diagnosis-streams.md (seed 5609) and its calibration, from the repository:

    platkit simulate --platform stewart --physics --motion multisine --duration-s 600 --rate-hz 250 \\
        --noise-mm 0.2 --white-noise --seed 5609 --effect backlash:1.0 --out sim
    (tests/stream_split.py) split_stream(Path("sim"), Path("part"), 0.1)
    platkit calibrate part/train --quiet --no-report --out cal

    .venv/bin/python benchmarks/play_memory_speed.py [--stream sim --calibration cal/calibration.yaml]
        [--random 1000] [--seed 20000] [--repeat 3]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import platkit.diagnose.stream as diagnose_stream
from platkit.io.calibration import read_calibration
from platkit.io.session import load_session
from platkit.play import play_memory

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from play_reference import full_walk as old_play_memory  # noqa: E402
from play_reference import random_column, same_bits  # noqa: E402


def _random_cases(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, int]]:
    rng = np.random.default_rng(seed)
    cases = []
    for _ in range(n):
        T = int(rng.integers(1, 3000))
        x = np.column_stack([random_column(rng, T) for _ in range(int(rng.integers(1, 7)))])
        at = rng.integers(0, T, int(rng.integers(0, 40)))
        cases.append((x, at, int(rng.choice([1, 2, 3, 4, 6, 10, 32, 200]))))
    return cases


def _cpu(f, repeat: int) -> float:
    """the least CPU seconds of ``repeat`` calls of f"""
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        f()
        best = min(best, time.process_time() - t0)
    return best


def stream(folder: Path, calibration: Path, repeat: int) -> None:
    cal = read_calibration(str(calibration))
    session = load_session(folder, spec=cal.spec, quiet=True)
    seen: list[tuple[np.ndarray, np.ndarray, int]] = []

    def capture(x, at, depth):
        seen.append((x, at, depth))
        return play_memory(x, at, depth)

    diagnose_stream.play_memory = capture
    diagnose_stream.stream_poses(folder, session, cal)
    x, at, depth = seen[0]
    print(f"stream {folder}: positions {x.shape[0]} samples x {x.shape[1]} drives, {len(at)} rows, depth {depth}")
    same = same_bits(old_play_memory(x, at, depth), play_memory(x, at, depth))
    t_old = _cpu(lambda: old_play_memory(x, at, depth), repeat)
    t_new = _cpu(lambda: play_memory(x, at, depth), repeat)
    print(f"  play_memory alone: old {t_old:.3f} s, new {t_new:.4f} s CPU: old / new {t_old / t_new:.1f}x; "
          f"the same to the bit: {same}")
    times = {"old": np.inf, "new": np.inf}
    for _ in range(repeat):  # in turn, each at its least
        for name, f in (("old", old_play_memory), ("new", play_memory)):
            diagnose_stream.play_memory = f
            times[name] = min(times[name], _cpu(lambda: diagnose_stream.stream_poses(folder, session, cal), 1))
    diagnose_stream.play_memory = play_memory
    print(f"  stream_poses: old {times['old']:.2f} s, new {times['new']:.2f} s CPU: old / new "
          f"{times['old'] / times['new']:.2f}x")


def random_sequences(n: int, seed: int) -> None:
    cases = _random_cases(n, seed)
    old = [old_play_memory(*c) for c in cases]
    wrong = [k for k, (c, m) in enumerate(zip(cases, old)) if not same_bits(m, play_memory(*c))]
    cut = sum(bool(np.isinf(m[..., 0]).any()) for m in old)
    t_old = _cpu(lambda: [old_play_memory(*c) for c in cases], 1)
    t_new = _cpu(lambda: [play_memory(*c) for c in cases], 1)
    print(f"random sequences (seed {seed}): {n}, the depth cut in {cut}; different from the old: {len(wrong)}"
          f"{' ' + str(wrong[:10]) if wrong else ''}; old / new {t_old / t_new:.1f}x ({t_old:.2f} / {t_new:.3f} s)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stream", type=Path, help="a stream's session folder (with --calibration)")
    ap.add_argument("--calibration", type=Path, help="its calibration.yaml")
    ap.add_argument("--random", type=int, default=1000, help="random sequences (default 1000)")
    ap.add_argument("--seed", type=int, default=20000, help="of the random sequences (default 20000)")
    ap.add_argument("--repeat", type=int, default=3, help="timings, each the least of this many (default 3)")
    a = ap.parse_args()
    if a.stream is not None:
        if a.calibration is None:
            ap.error("--stream needs --calibration")
        stream(a.stream, a.calibration, a.repeat)
    if a.random:
        random_sequences(a.random, a.seed)


if __name__ == "__main__":
    main()
