"""Simulator speed: the physical (time-domain) simulator against the additive one, on the same
stand and command count, simulation and writing timed apart; printed as seconds and as ratios.

    .venv/bin/python benchmarks/simulate_speed.py                      # stewart, 240 commands
    .venv/bin/python benchmarks/simulate_speed.py --stand psvr --commands 120
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from platkit.plugins import get_platform
from platkit.simulate import simulate, simulate_physics, write_physical_session, write_session


def best_of(n, f):
    times, out = [], None
    for _ in range(n):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stand", default="stewart")
    ap.add_argument("--commands", type=int, default=240)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)
    spec = get_platform(args.stand)
    n, r = args.commands, args.repeat
    with tempfile.TemporaryDirectory() as tmp:
        t_poses, _ = best_of(r, lambda: simulate(spec, seed=1, n_poses=n, raw=False))
        t_raw, raw = best_of(r, lambda: simulate(spec, seed=1, n_poses=n))
        t_raw_w, _ = best_of(r, lambda: write_session(raw, Path(tempfile.mkdtemp(dir=tmp)) / "s"))
        t_phys, phys = best_of(r, lambda: simulate_physics(spec, seed=1, n_poses=n))
        t_phys_w, _ = best_of(r, lambda: write_physical_session(phys, Path(tempfile.mkdtemp(dir=tmp)) / "s"))
    print(f"{args.stand}, {n} commands (best of {r})")
    print(f"  additive, settled poses drawn directly: {t_poses:8.3f} s")
    print(f"  additive, raw stream (settled by platkit): {t_raw:6.3f} s + {t_raw_w:.3f} s to write "
          f"({len(raw.marker_t)} samples)")
    print(f"  physical, time domain:                 {t_phys:8.3f} s + {t_phys_w:.3f} s to write "
          f"({len(phys.marker_t)} samples, {phys.hold_end_t[-1]:.0f} s of recording)")
    print(f"  ratio physical / additive raw: simulate {t_phys / t_raw:.2f}, write {t_phys_w / t_raw_w:.2f}; "
          f"per sample {t_phys / len(phys.marker_t) / (t_raw / len(raw.marker_t)):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
