"""The markers' own noise on a tree and the refusal of a command log that does not explain the motion.

platkit.calibrate.estimate.marker_noise_floor takes the spread of the distances between markers on
one link; over every pair (as before) a tree's pairs across links read the motion. Prints, per
stream, the 3-D floor both ways over the stream's samples, then calibrate_motion's RMS after the
fit, as a multiple of the per-link floor, or the refusal:

- ``small``: tests/unit/test_tree_stream.py's tree (physical simulator, multisine 20 s, 0.1 mm
  white noise), seed 41 with its own log, with seed 42's log, and with every second command
  (first-order response);
- ``talos``: benchmarks/tree_stream.py's Talos (40 s, 0.2 mm), seed 2900011 with its own log and
  with 2900012's;
- ``elastic``: the elastic two-arm torso streamed without holds (platkit.simulate.elastic_stream):
  tests/unit/test_tree_stream_compliance.py's 20 s stream and benchmarks/tree_stream_compliance.py
  --no-holds' stream of seed 2900301 (40 s): unmodelled sag, calibrated (default response kind);
- ``stewart``: a single-link Stewart (tests/unit/test_calibrate_motion.py's stream, seed 4101,
  24 s), its own log and one in two and one in four commands kept.

    .venv/bin/python benchmarks/tree_noise_floor.py [--parts small,talos,elastic,stewart]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate.estimate import marker_noise_floor, pair_noise
from platkit.calibrate.motion import calibrate_motion
from platkit.errors import BadSession
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.elastic_stream import simulate_elastic_motion, slow_multisine, write_elastic_stream
from platkit.simulate.physics import simulate_physics, write_physical_session

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "benchmarks"), str(ROOT)]
from tree_stream import talos  # noqa: E402
from tree_stream_compliance import drawn  # noqa: E402

from tests.unit.test_tree_stream import URDF as SMALL_URDF  # noqa: E402
from tests.unit.test_tree_stream import stand  # noqa: E402
from tests.unit.test_tree_stream_compliance import JOINTS, LIMIT, MARKERS, truth_and_commands  # noqa: E402
from tests.unit.test_tree_stream_compliance import URDF as ELASTIC_URDF  # noqa: E402


def floors(folder: Path) -> str:
    """The 3-D floor over the stream's samples, every pair and per link, mm."""
    s = load_session(folder)
    mapping = yaml.safe_load((folder / "session.yaml").read_text()).get("moving_link")
    links = [mapping[n] for n in s.marker_names] if isinstance(mapping, dict) else None
    every, per = (1e3 * np.sqrt(3) * pair_noise(s.markers, ls) for ls in (None, links))
    return f"floor 3-D over the samples: every pair {every:.4g} mm, per link {per:.4g} mm"


def fitted(name: str, session, kind: str) -> None:
    t0 = time.perf_counter()
    try:
        cal, poses = calibrate_motion(session, session.spec, kind=kind)
    except BadSession as exc:
        said = str(exc).split(": after the fit ")[-1].split(": commands")[0]
        print(f"  {name}: refused ({said}) [{time.perf_counter() - t0:.0f} s]", flush=True)
        return
    floor = np.sqrt(3) * marker_noise_floor(poses)
    print(f"  {name}: calibrated, rms_after {1e3 * cal.rms_after:.4g} mm, {cal.rms_after / floor:.2g} times the "
          f"per-link floor of the nodes ({1e3 * floor:.4g} mm) [{time.perf_counter() - t0:.0f} s]", flush=True)


def logs(name: str, own, other, kind: str = "first_order", thinned: tuple[int, ...] = ()) -> None:
    fitted(f"{name}, its own log", own, kind)
    if other is not None:
        n = min(len(own.command_t), len(other.command_t))
        fitted(f"{name}, another seed's log", dataclasses.replace(own, command_t=own.command_t[:n],
                                                                  commands=other.commands[:n]), kind)
    for k in thinned:
        fitted(f"{name}, one command in {k} kept", dataclasses.replace(own, command_t=own.command_t[::k],
                                                                       commands=own.commands[::k]), kind)


def physical(spec, seeds, tmp: Path, urdf: Path | None, **kw):
    out = []
    for seed in seeds:
        sim = simulate_physics(spec, seed=seed, motion="multisine", **kw)
        folder = tmp / f"s{seed}"
        write_physical_session(sim, folder, description=urdf)
        out.append(folder)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parts", default="small,talos,elastic,stewart")
    parts = ap.parse_args().parts.split(",")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        if "small" in parts:
            urdf = tmp / "small_tree.urdf"
            urdf.write_text(SMALL_URDF)
            a, b = physical(stand(urdf), (41, 42), tmp / "small", urdf, duration_s=20.0, n_markers=6, noise_mm=0.1,
                            coloured=False)
            print(f"small tree, seed 41: {floors(a)}", flush=True)
            logs("small tree seed 41", load_session(a), load_session(b), thinned=(2,))
        if "talos" in parts:
            urdf, spec = talos()
            a, b = physical(spec, (2900011, 2900012), tmp / "talos", urdf, duration_s=40.0, command_rate_hz=20.0,
                            n_markers=6, noise_mm=0.2, coloured=False)
            print(f"Talos, seed 2900011: {floors(a)}", flush=True)
            logs("Talos seed 2900011", load_session(a), load_session(b))
        if "elastic" in parts:
            amplitude = np.array([0.6 * LIMIT[j] for j in JOINTS])
            truth, _ = truth_and_commands(5, 12)
            tc, C = slow_multisine(amplitude, 20.0, 50.0, np.random.default_rng(55), ramp_s=2.0)
            runs = [("elastic tree, the unit test's stream", truth, tc, C, 1005, 2005, {})]
            rng = np.random.default_rng(2900301)
            truth, _ = drawn(rng, 12)
            tc, C = slow_multisine(amplitude, 40.0, 50.0, rng)
            runs.append(("elastic tree, seed 2900301", truth, tc, C, 2901301, 2902301, {"tau_s": 0.02, "delay_s": 0.03}))
            for k, (name, truth, tc, C, seed, noise_seed, kw) in enumerate(runs):
                work = tmp / f"elastic{k}"
                work.mkdir()
                sim = simulate_elastic_motion(ELASTIC_URDF, truth, tc, C, JOINTS, MARKERS, seed=seed,
                                              noise_seed=noise_seed, workdir=work, **kw)
                folder = write_elastic_stream(sim, ELASTIC_URDF, work / "m")
                print(f"{name}: largest sag {1e3 * np.abs(sim.settled - sim.rigid).max():.3g} mm; {floors(folder)}",
                      flush=True)
                logs(name, load_session(folder), None, kind="auto")
        if "stewart" in parts:
            (a,) = physical(get_platform("stewart"), (4101,), tmp / "stewart", None, duration_s=24.0,
                            mocap_rate_hz=50.0)
            print(f"Stewart (one link), seed 4101: {floors(a)}", flush=True)
            logs("Stewart seed 4101", load_session(a), None, thinned=(2, 4))


if __name__ == "__main__":
    main()
