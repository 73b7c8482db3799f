"""Calibration from motion, speed and memory: ten minutes of 120 Hz motion capture, 5 markers.

A streamed multisine session of the stewart stand from the physical simulator (seed 2500001,
drawn nuisances: latency, clock offset, coloured noise, occlusion bursts), calibrated by
platkit.calibrate.motion.calibrate_motion. Prints the fit's CPU time (one core: BLAS held to one
thread) beside the 30 s goal, and the peak traced memory of a second fit (tracemalloc, numpy's
allocations included) beside the stream's marker array
(K x 5 x 3 doubles), as ratios, and the held-out error of every command's settled pose
against the truth. Traced memory counts what the fit allocates through Python and numpy (the
session, loaded before, and the interpreter and libraries are not in it, nor CasADi's own C++
buffers); beside it, where Linux allows, the process's resident memory before the second fit
and its peak during it (VmHWM, reset first through /proc/self/clear_refs): interpreter,
libraries, simulation left-overs and the session included.

    .venv/bin/python benchmarks/calibrate_motion_speed.py [--seed N] [--minutes M]
"""
from __future__ import annotations

import argparse
import re
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import calibrate_motion
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def _rss_mb(field: str) -> float | None:
    """VmRSS or VmHWM of this process in MB (Linux), None elsewhere."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return None
    m = re.search(rf"^{field}:\s+(\d+) kB", text, re.M)
    return int(m.group(1)) / 1e3 if m else None


def _reset_peak_rss() -> bool:
    """Reset the process's peak resident memory to the present (Linux 4.0+)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=2500001)
    ap.add_argument("--minutes", type=float, default=10.0)
    args = ap.parse_args()
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=args.seed, motion="multisine", duration_s=60 * args.minutes, mocap_rate_hz=120.0)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "session"
        write_physical_session(sim, folder)
        session = load_session(folder)
        stream_bytes = session.markers.nbytes
        t0, c0 = time.perf_counter(), time.process_time()
        cal, _ = calibrate_motion(session, session.spec)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        rss0, reset = _rss_mb("VmRSS"), _reset_peak_rss()
        tracemalloc.start()  # memory on a second fit: tracing slows numpy's allocations
        calibrate_motion(session, session.spec)
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        hwm = _rss_mb("VmHWM") if reset else None
    pred, _, _, _ = predict_markers(cal, sim.commands)
    truth = float(np.sqrt(np.nanmean(np.sum((pred - sim.settled_markers) ** 2, axis=2))))
    r = cal.motion["response"]
    taus = np.array([r["actuators"][c]["tau_s"]["value"] for c in spec.control_names])
    smp = cal.motion["samples"]
    print(f"stream: {len(session.marker_t)} samples x {session.markers.shape[1]} markers, "
          f"{stream_bytes / 1e6:.1f} MB; {smp['n_used']} samples used ({smp['n_unseen']} with no marker seen, "
          f"{smp['n_before_second_command']} before the second command, {smp['n_marker_observations_left_out']} "
          f"marker observations left out), fitted as {smp['n_fitted']} poses: {smp['n_windows'] - smp['n_raw_windows']} "
          f"windows of {smp['window_s']:.3g} s at 3 nodes each and {smp['n_kept_raw']} samples kept raw")
    print(f"fit CPU time {cpu:.1f} s against the goal 30 s: ratio {cpu / 30:.2f} (wall {wall:.1f} s on a shared "
          "machine; the fit runs on one core)")
    print(f"peak traced memory {peak / 1e6:.1f} MB against 3x the stream's array {3 * stream_bytes / 1e6:.1f} MB: "
          f"ratio {peak / (3 * stream_bytes):.2f} ({peak / stream_bytes:.2f} times the array)")
    if rss0 is not None and hwm is not None:
        print(f"resident memory of the process: {rss0:.0f} MB before the second fit (interpreter, libraries, "
              f"session, the first fit's result), peak {hwm:.0f} MB during it (+{hwm - rss0:.0f} MB, "
              f"{(hwm - rss0) * 1e6 / stream_bytes:.1f} times the array)")
    print(f"held-out error of the settled poses against the truth {truth * 1e3:.4f} mm; shift "
          f"{r['shift_s']['value']:.4f} s (truth {sim.nuisances.time_shift_s:.4f}); tau/true "
          f"{np.round(taus / sim.response.tau_s, 3).tolist()}")


if __name__ == "__main__":
    main()
