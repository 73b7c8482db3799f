"""Compliance in a slow stream of a tree: `platkit calibrate` then `platkit diagnose` (no options
beyond --no-selection) on the raw stream of an elastic tree (platkit.simulate.elastic_stream).

The tree: tests/data/trees/two_arm_torso.urdf with its inertias, both hands tracked (3 markers
each, 0.1 mm white noise per sample at 50 Hz), the head commanded too; per seed, the true robot's
joint origins moved (0.5 mm, 1 mrad RMS) and every recorded joint's zero offset (2 mrad), the
torso pitch and the right shoulder elastic (2e-4 and 4e-4 rad/(N m)); 30 random held commands
(1.5 s min-jerk moves, 2 s holds). Prints per seed the largest sag (the elastic robot against the
rigid true one at rest), the holds settled, the effects named with their joints, the places named
scored against the truth (:func:`scored`: right, false, planted but missed), and diagnose's
held-out RMS (its cross-validation over the settled poses, mm) before (geometry) and after.

``--no-holds``: the same tree streamed without holds instead (simulate_elastic_motion: a slow
multisine of every recorded joint, 0.03-0.2 Hz, ``--duration`` s, each drive a first-order lag of
20 ms behind its step-held commands, the motion capture's clock 30 ms behind), calibrated from
motion, diagnosed on the stream with ``--heldout`` a session of the same set-up (the seed's markers
and mocap transform, noise of its own) with ``--poses`` held commands, settled. Prints per seed the
effects named (scored the same way) and, per hand, the held-out session's RMS (mm, 3-D, over its markers) with the
calibration from motion (rigid) and after diagnosis.

    .venv/bin/python benchmarks/tree_stream_compliance.py [--seeds 2900101,2900102,2900103]
    .venv/bin/python benchmarks/tree_stream_compliance.py --no-holds --seeds 2900201,2900202,2900203
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from platkit.cli import main as cli
from platkit.simulate.elastic_stream import (
    simulate_elastic_motion,
    simulate_elastic_stream,
    slow_multisine,
    write_elastic_stream,
)
from platkit.simulate.elastic_tree import ElasticTruth

URDF = Path(__file__).resolve().parents[1] / "tests" / "data" / "trees" / "two_arm_torso.urdf"
JOINTS = ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint", "right_3_joint", "left_1_joint",
          "left_2_joint", "left_3_joint"]
LIMIT = dict(zip(JOINTS, [1.5, 0.5, 1.0, 2.0, 1.5, 2.0, 2.0, 1.5, 2.0]))
MARKERS = {f"R{k}": "right_tcp" for k in (1, 2, 3)} | {f"L{k}": "left_tcp" for k in (1, 2, 3)}
ELASTIC = {"torso_pitch": 2e-4, "right_1_joint": 4e-4}
#: a joint of the every-joint compliance term names its place where its compliance is this many
#: standard deviations from zero
NAMED_SIGMA = 3.0


def named_places(findings: list[dict]) -> list[tuple[str, str]]:
    """(effect, joint) of every place a finding names: one per finding (its actuator or joint);
    for the every-joint compliance term each joint whose compliance is NAMED_SIGMA from zero and
    each bend told apart in it (``bending_<joint>``: link bending there). ``unexplained`` names no
    place."""
    out: list[tuple[str, str]] = []
    for f in findings:
        w = f["where"]
        if f["effect"] == "unexplained":
            continue
        if "joints" in w and "actuators" in w:
            joint_of = dict(zip(w["actuators"], w["joints"]))
            for name, par in f["parameters"].items():
                if name.startswith("bending_"):
                    place = ("link_bending", name[len("bending_"):].removesuffix("_u").removesuffix("_v"))
                elif name.startswith("compliance_") and par.get("std") and abs(par["value"]) > NAMED_SIGMA * par["std"]:
                    place = (f["effect"], joint_of[name[len("compliance_"):]])
                else:
                    continue
                if place not in out:
                    out.append(place)
        else:
            out.append((f["effect"], str(w.get("actuator") or w.get("joint") or "")))
    return out


def listed(findings: list[dict]) -> str:
    """Each finding's effect and the joints (or the actuator or joint) it names."""
    out = []
    for f in findings:
        w = f["where"]
        out.append(f"{f['effect']} ({', '.join(w.get('joints') or [str(w.get('actuator') or w.get('joint'))])})")
    return "; ".join(out) or "none"


def scored(findings: list[dict]) -> str:
    """The places named against the truth: right (compliance at a joint ELASTIC plants: the
    simulator's joint compliance, at torso_pitch its own joint alone), false (any other place or
    effect: the seed plants no link bending, no mimic joint's elasticity, nothing else), missed (a
    planted joint not named)."""
    places = named_places(findings)
    right = [p for p in places if p[0] == "compliance" and p[1] in ELASTIC]
    false = [f"{e} at {j}" for e, j in places if (e, j) not in right]
    missed = [j for j in ELASTIC if ("compliance", j) not in right]
    return (f"right {len(right)}/{len(ELASTIC)}, false {len(false)}" + (f" ({', '.join(false)})" if false else "")
            + (f", missed {', '.join(missed)}" if missed else ""))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="2900101,2900102,2900103")
    ap.add_argument("--poses", type=int, default=30)
    ap.add_argument("--no-holds", action="store_true", help="stream without holds, calibrated from motion")
    ap.add_argument("--duration", type=float, default=40.0, help="--no-holds: the stream's length, s")
    ap.add_argument("--response-kinds", default="auto",
                    help="--no-holds: calibrate's --response-kind, comma-separated: each calibrates and diagnoses the "
                         "same stream (e.g. auto,second-order: the choice against the second order forced)")
    args = ap.parse_args()
    if args.no_holds:
        return no_holds(args)
    print("seed: largest sag mm | holds settled | named (joints) | places named: right, false | diagnose held-out RMS "
          "mm: geometry -> final")
    for seed in (int(s) for s in args.seeds.split(",")):
        rng = np.random.default_rng(seed)
        truth, U = drawn(rng, args.poses)
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
        named = listed(d["findings"])
        final = d["findings"][-1]["heldout_rms_after"] if d["findings"] else d["heldout_rms_geometric"]
        print(f"{seed}: {1e3 * np.abs(sim.settled - sim.rigid).max():.2f} | {d['n_poses']}/{args.poses} | {named} | "
              f"{scored(d['findings'])} | {d['heldout_rms_geometric']:.3f} -> {final:.4f} "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)


def drawn(rng: np.random.Generator, poses: int):
    """The seed's true elastic tree (the planted compliances, origin and offset errors) and ``poses``
    held commands within 0.6 of each joint's limit, drawn from ``rng`` in that order."""
    truth = ElasticTruth(joint_compliance=dict(ELASTIC),
                         origin_error={j: (rng.normal(0, 0.5e-3, 3), rng.normal(0, 1e-3, 3)) for j in JOINTS},
                         offset={j: float(rng.normal(0, 2e-3)) for j in JOINTS})
    return truth, np.column_stack([rng.uniform(-0.6 * LIMIT[j], 0.6 * LIMIT[j], poses) for j in JOINTS])


def no_holds(args) -> None:
    print("seed: largest sag mm | poses diagnosed | named (joints) | places named: right, false | per hand, held-out "
          "session RMS mm: calibrated from motion (rigid) -> diagnosed")
    amplitude = np.array([0.6 * LIMIT[j] for j in JOINTS])
    for seed in (int(s) for s in args.seeds.split(",")):
        rng = np.random.default_rng(seed)
        truth, U = drawn(rng, args.poses)
        tc, C = slow_multisine(amplitude, args.duration, 50.0, rng)
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            t0 = time.perf_counter()
            sim = simulate_elastic_motion(URDF, truth, tc, C, JOINTS, MARKERS, seed=seed + 1000, noise_seed=seed + 2000,
                                          tau_s=0.02, delay_s=0.03, workdir=tmp)
            write_elastic_stream(sim, URDF, tmp / "m")
            held = simulate_elastic_stream(URDF, truth, U, JOINTS, MARKERS, seed=seed + 1000, workdir=tmp)
            write_elastic_stream(held, URDF, tmp / "h")
            sag = 1e3 * np.abs(sim.settled - sim.rigid).max()
            for kind in args.response_kinds.split(","):
                t1 = time.perf_counter()
                cal, diag = tmp / f"cal-{kind}", tmp / f"diag-{kind}"
                if cli(["calibrate", str(tmp / "m"), "--quiet", "--no-report", "--no-selection", "--response-kind",
                        kind, "--out", str(cal)]):
                    raise SystemExit("calibrate failed")
                response = json.loads((cal / "report.json").read_text())["motion"]["response"]
                if cli(["diagnose", str(tmp / "m"), "--calibration", str(cal / "calibration.yaml"), "--heldout",
                        str(tmp / "h"), "--out", str(diag), "--quiet"]):
                    raise SystemExit("diagnose failed")
                d = json.loads((diag / "diagnosis.json").read_text())
                named = listed(d["findings"])
                per = d["heldout_session"]["per_marker"]
                hands = []
                for link in dict.fromkeys(MARKERS.values()):
                    v = np.array([per[m] for m, lk in MARKERS.items() if lk == link])
                    before, after = np.sqrt(np.mean(v**2, axis=0))
                    hands.append(f"{link} {before:.3f} -> {after:.3f}")
                print(f"{seed} [{kind}: {response['kind']}]: {sag:.2f} | {d['n_poses']} | {named} | "
                      f"{scored(d['findings'])} | {'; '.join(hands)} ({time.perf_counter() - t1:.0f} s; simulation "
                      f"{t1 - t0:.0f} s)", flush=True)
                t0 = t1 = time.perf_counter()


if __name__ == "__main__":
    main()
