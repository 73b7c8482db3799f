"""Compliance in a slow stream of a tree: `platkit calibrate` then `platkit diagnose` (no options
beyond --no-selection) on the raw stream of an elastic tree (platkit.simulate.elastic_stream).

The tree: tests/data/trees/two_arm_torso.urdf with its inertias, both hands tracked (3 markers
each, 0.1 mm white noise per sample at 50 Hz), the head commanded too; per seed, the true robot's
joint origins moved (0.5 mm, 1 mrad RMS) and every recorded joint's zero offset (2 mrad), the
torso pitch and the right shoulder elastic (2e-4 and 4e-4 rad/(N m)); 30 random held commands
(1.5 s min-jerk moves, 2 s holds). Prints per seed the largest sag (the elastic robot against the
rigid true one at rest), the holds settled, the effects named with their joints, and diagnose's
held-out RMS (its cross-validation over the settled poses, mm) before (geometry) and after.

    .venv/bin/python benchmarks/tree_stream_compliance.py [--seeds 2900101,2900102,2900103]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from platkit.cli import main as cli
from platkit.simulate.elastic_stream import simulate_elastic_stream, write_elastic_stream
from platkit.simulate.elastic_tree import ElasticTruth

URDF = Path(__file__).resolve().parents[1] / "tests" / "data" / "trees" / "two_arm_torso.urdf"
JOINTS = ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint", "right_3_joint", "left_1_joint",
          "left_2_joint", "left_3_joint"]
LIMIT = dict(zip(JOINTS, [1.5, 0.5, 1.0, 2.0, 1.5, 2.0, 2.0, 1.5, 2.0]))
MARKERS = {f"R{k}": "right_tcp" for k in (1, 2, 3)} | {f"L{k}": "left_tcp" for k in (1, 2, 3)}
ELASTIC = {"torso_pitch": 2e-4, "right_1_joint": 4e-4}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="2900101,2900102,2900103")
    ap.add_argument("--poses", type=int, default=30)
    args = ap.parse_args()
    print("seed: largest sag mm | holds settled | named (joints) | diagnose held-out RMS mm: geometry -> final")
    for seed in (int(s) for s in args.seeds.split(",")):
        rng = np.random.default_rng(seed)
        truth = ElasticTruth(joint_compliance=dict(ELASTIC),
                             origin_error={j: (rng.normal(0, 0.5e-3, 3), rng.normal(0, 1e-3, 3)) for j in JOINTS},
                             offset={j: float(rng.normal(0, 2e-3)) for j in JOINTS})
        U = np.column_stack([rng.uniform(-0.6 * LIMIT[j], 0.6 * LIMIT[j], args.poses) for j in JOINTS])
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            t0 = time.perf_counter()
            sim = simulate_elastic_stream(URDF, truth, U, JOINTS, MARKERS, seed=seed + 1000, workdir=tmp)
            folder = write_elastic_stream(sim, URDF, tmp / "s")
            if cli(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(tmp / "cal")]):
                raise SystemExit("calibrate failed")
            if cli(["diagnose", str(folder), "--calibration", str(tmp / "cal" / "calibration.yaml"), "--out",
                    str(tmp / "diag"), "--quiet"]):
                raise SystemExit("diagnose failed")
            d = json.loads((tmp / "diag" / "diagnosis.json").read_text())
        named = "; ".join(f"{f['effect']} ({', '.join(f['where'].get('joints') or [str(f['where'].get('joint'))])})"
                          for f in d["findings"]) or "none"
        final = d["findings"][-1]["heldout_rms_after"] if d["findings"] else d["heldout_rms_geometric"]
        print(f"{seed}: {1e3 * np.abs(sim.settled - sim.rigid).max():.2f} | {d['n_poses']}/{args.poses} | {named} | "
              f"{d['heldout_rms_geometric']:.3f} -> {final:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
