"""Speed of a tree session against one chain (issue 24's speed goal): `platkit calibrate` (and,
with --diagnose, `platkit diagnose`) on a tree of 20 recorded joints, both hands tracked, against
the same on one 9-joint chain of the same robot (torso and one arm), the same number of poses.

    .venv/bin/python benchmarks/trees_speed.py [--poses 300] [--diagnose] [--seed 1] [--repeat 1]

The robot: PAL's Talos (example-robot-data's talos_reduced.urdf, a public description not written
here). The tree: base_link to both grippers; recorded joints: the torso (2), the head (2), both
arms (14) and both grippers (2); three markers on each hand. The chain: base_link to the left
gripper (torso and left arm), the left hand's three markers. Settled poses with rigid geometric
errors (offsets 2 mrad, origins 0.5 mm / 1 mrad RMS) and 0.1 mm mocap noise, written as
poses.csv sessions and run through the command line in this process. Prints each verb's CPU
time, per pose, and the tree / chain ratio (the goal: within 2x per pose). ``--repeat N``: the
verbs N times on the same sessions, chain and tree in turn, each verb's least CPU time of the N
(on a machine shared with other work, the CPU time of one run swings by a third with the load
the other processes put on the same cores); the later runs find the stands' observation functions
built and loaded in this process, so the least is a warm process's time, both sides alike; each
run's own total tree / chain ratio is printed after the table (the spread the least hides).
``--keep DIR``: the sessions and every run's outputs are written under DIR (new or empty) and
kept, to compare two versions' outputs (calibration.yaml, report.json, diagnosis.json); without
it, a temporary folder.
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate.problem import link_frames
from platkit.cli import main
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.plugins import get_platform

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference_robots import example_robot_urdf  # noqa: E402  (tests/: the finder of example-robot-data)

HANDS = {"L": "gripper_left_base_link", "R": "gripper_right_base_link"}
TREE_JOINTS = (["torso_1_joint", "torso_2_joint", "head_1_joint", "head_2_joint"]
               + [f"arm_left_{i}_joint" for i in range(1, 8)] + [f"arm_right_{i}_joint" for i in range(1, 8)]
               + ["gripper_left_joint", "gripper_right_joint"])


def session(folder: Path, urdf: Path, spec, mapping: dict, n: int, seed: int, options: dict) -> Path:
    rng = np.random.default_rng(seed)
    lo, hi = spec.control_bounds()
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    U = rng.uniform(mid - 0.6 * half, mid + 0.6 * half, size=(n, spec.n_u))
    td = spec.nominal_td().copy()
    for i, p in enumerate(spec.parameters):
        if p.group == "offset":
            td[i] += rng.normal(0.0, 2e-3)
        elif p.group == "origin":
            td[i] += rng.normal(0.0, 5e-4 if p.unit == "m" else 1e-3)
    tracked = spec.tracked_links or [spec.moving_frame]
    if spec.link_poses is not None:
        R, X = link_frames(spec, td, U)
    else:
        q, Xc = (np.asarray(a).T for a in spec.forward.map(n)(U.T, td))
        R, X = matrix_from_quat(q)[:, None], Xc[:, None]
    A, t = matrix_from_rotvec([0.05, 0.1, -1.2]), np.array([0.3, -1.0, 0.9])
    local = {m: rng.normal(0.0, 0.05, 3) for m in mapping}
    Y = np.stack([(X[:, tracked.index(link)] + R[:, tracked.index(link)] @ local[m]) @ A.T + t
                  for m, link in mapping.items()], axis=1)
    Y += rng.normal(0.0, 1e-4, Y.shape)
    folder.mkdir(parents=True)
    (folder / "session.yaml").write_text(yaml.safe_dump({
        "platform": "urdf", "description": str(urdf), "units": {"length": "mm", "time": "s"},
        "markers": list(mapping), **options}, sort_keys=False))
    head = ["t", *spec.control_names] + [f"{m}_{a}" for m in mapping for a in "xyz"]
    rows = [[2.0 * k, *U[k], *(Y[k].ravel() * 1e3)] for k in range(n)]
    (folder / "poses.csv").write_text(",".join(head) + "\n" + "\n".join(",".join(format(v, ".12g") for v in r)
                                                                       for r in rows) + "\n")
    return folder


def timed(argv: list[str]) -> float:
    """CPU seconds of one verb: this process's and its children's (the C compiler of the observation
    functions); wall time on a shared machine says more of the others' load than of the verb."""

    def cpu() -> float:
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system

    t0 = cpu()
    rc = main(argv)
    if rc != 0:
        raise SystemExit(f"{' '.join(argv)}: exit {rc}")
    return cpu() - t0


def main_(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--diagnose", action="store_true", help="also time platkit diagnose")
    ap.add_argument("--repeat", type=int, default=1, help="run the verbs N times, keep each one's least CPU time")
    ap.add_argument("--keep", type=Path, default=None, help="write the sessions and outputs under this new folder, kept")
    args = ap.parse_args(argv)
    urdf = example_robot_urdf("talos_data/robots/talos_reduced.urdf")
    tree_map = {f"{h}{k}": link for h, link in HANDS.items() for k in range(1, 4)}
    chain_map = {f"L{k}": HANDS["L"] for k in range(1, 4)}
    tree = get_platform("urdf", urdf, moving_link=tree_map, joints=TREE_JOINTS)
    chain = get_platform("urdf", urdf, moving_link=HANDS["L"])
    print(f"tree: {tree.n_u} joints, {tree.n_td} parameters; chain: {chain.n_u} joints, {chain.n_td} parameters; "
          f"{args.poses} poses", flush=True)
    out: dict[str, dict[str, float]] = {}
    runs: list[dict[str, float]] = []  # each run's total CPU seconds per side: the spread beside the least
    load_before = os.getloadavg()[0]
    if args.keep is not None and args.keep.exists() and any(args.keep.iterdir()):
        raise SystemExit(f"--keep {args.keep}: not empty")
    with (contextlib.nullcontext(str(args.keep)) if args.keep is not None else tempfile.TemporaryDirectory()) as tmp:
        root = Path(tmp)
        stands = (("chain", chain, chain_map, {"moving_link": HANDS["L"]}),
                  ("tree", tree, tree_map, {"moving_link": tree_map}))
        folders = {name: session(root / name, urdf, spec, mapping, args.poses, args.seed, options)
                   for name, spec, mapping, options in stands}
        for k in range(max(1, args.repeat)):
            runs.append({})
            for name, folder in folders.items():
                cal, diag = root / f"{name}_cal{k}", root / f"{name}_diag{k}"
                got = {"calibrate": timed(["calibrate", str(folder), "--quiet", "--no-report", "--out", str(cal)])}
                if args.diagnose:
                    got["diagnose"] = timed(["diagnose", str(folder), "--calibration", str(cal / "calibration.yaml"),
                                             "--quiet", "--out", str(diag)])
                out[name] = {verb: min(s, out.get(name, {}).get(verb, s)) for verb, s in got.items()}
                runs[-1][name] = sum(got.values())
    print("CPU seconds of each verb, its compiler's included"
          + (f"; the least of {args.repeat} runs" if args.repeat > 1 else "")
          + f"; load average {load_before:.2f} before, {os.getloadavg()[0]:.2f} after (the machine's other work)")
    print(f"{'verb':<10} {'chain s':>9} {'tree s':>9} {'chain ms/pose':>14} {'tree ms/pose':>13} {'tree/chain':>11}")
    for verb in out["chain"]:
        c, t = out["chain"][verb], out["tree"][verb]
        print(f"{verb:<10} {c:9.2f} {t:9.2f} {1e3 * c / args.poses:14.2f} {1e3 * t / args.poses:13.2f} {t / c:11.2f}")
    c, t = sum(out["chain"].values()), sum(out["tree"].values())
    print(f"{'total':<10} {c:9.2f} {t:9.2f} {1e3 * c / args.poses:14.2f} {1e3 * t / args.poses:13.2f} {t / c:11.2f}")
    if len(runs) > 1:  # the spread: each run's own tree / chain (the first pays the process's start)
        print("each run's total tree/chain: " + ", ".join(f"{r['tree'] / r['chain']:.2f}" for r in runs))
    return 0


if __name__ == "__main__":
    sys.exit(main_())
