"""A humanoid upper body that bends under its own weight: default `platkit calibrate`, then
`platkit diagnose`, on settled poses from the elastic tree simulator (platkit.simulate.elastic_tree).

    .venv/bin/python benchmarks/trees_humanoid.py [--seeds 1] [--poses 300 --heldout 200] [--bare] [--later N]

The robot: PAL's Talos (example-robot-data's talos_reduced.urdf, with its inertias: a public
description not written here), legs removed, grippers fixed, both 7-joint arms and the head on a
torso whose last joint is coupled to the one before it as a URDF mimic joint (torso_3_joint, half
of torso_2_joint's pitch, 10 cm above it). The true robot, drawn per seed: origin errors (0.5 mm,
1 mrad RMS), zero offsets (2 mrad RMS), elastic torso and shoulder/elbow joints (the coupled one
too) and bending links at the torso and the shoulders (stiffer one way than the other by up to
25%: the effect fits one compliance for both), three markers on each hand, mocap noise
0.1 mm. The calibration sees the nominal URDF (``--bare``: with every inertia stripped).

Per seed and hand, the held-out mean marker error (mm, against the recorded noisy markers) of:
the rigid calibration, the calibration diagnose writes, and the true elastic model itself (the
noise floor); plus the effects diagnose names, and the places they name scored against the truth
(:func:`named_places`, :func:`right`: a joint of the every-joint compliance term counts where its
compliance is 3 standard deviations from zero; a link bending told apart from a joint's compliance
within that term, ``bending_<joint>``, counts as link bending at that joint). ``--later N``: also a
later session of the same robot, N new poses drawn from a stream of their own (the same truth,
markers and mocap; the first session's poses and noise unchanged), predicted by both calibrations
and never seen by calibrate or diagnose. ``--keep DIR`` keeps each seed's folders.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from platkit.cli import main as cli  # noqa: E402
from platkit.simulate.elastic_tree import (  # noqa: E402
    ElasticTruth,
    simulate_elastic_tree,
    write_elastic_session,
)

ROBOTS = Path(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data")) / "robots"
HANDS = {"left": "arm_left_7_link", "right": "arm_right_7_link"}
ARMS = [f"arm_{s}_{i}_joint" for s in ("left", "right") for i in range(1, 8)]
RECORDED = ["torso_1_joint", "torso_2_joint", "head_1_joint", "head_2_joint", *ARMS]
ELASTIC = ["torso_1_joint", "torso_2_joint", "torso_3_joint"] + [f"arm_{s}_{i}_joint" for s in ("left", "right")
                                                                  for i in (1, 2, 4)]
BENT = ["torso_2_joint", "arm_left_2_joint", "arm_right_2_joint"]


def upper_body(out: Path, bare: bool = False) -> Path:
    """Talos's upper body with the coupled torso joint (see the module docstring)."""
    tree = ET.parse(ROBOTS / "talos_data/robots/talos_reduced.urdf")
    robot = tree.getroot()
    for tag in ("transmission", "gazebo"):
        for e in robot.findall(tag):
            robot.remove(e)
    for j in robot.findall("joint"):
        for m in j.findall("mimic"):
            j.remove(m)
        if j.get("name").startswith("gripper_") and j.get("type") != "fixed":
            j.set("type", "fixed")
    legs = {j.find("child").get("link") for j in robot.findall("joint") if j.get("name").startswith("leg_")}
    for j in robot.findall("joint"):
        if j.get("name").startswith("leg_"):
            robot.remove(j)
    for link in robot.findall("link"):
        if link.get("name") in legs:
            robot.remove(link)
    # torso_3: a pitch coupled to torso_2's, 10 cm above it, carrying what torso_2_link carried
    for j in robot.findall("joint"):
        if j.find("parent").get("link") == "torso_2_link":
            j.find("parent").set("link", "torso_3_link")
            o = j.find("origin")
            xyz = np.array([float(v) for v in (o.get("xyz") or "0 0 0").split()]) - [0, 0, 0.1]
            o.set("xyz", " ".join(f"{v:.6g}" for v in xyz))
    ET.SubElement(robot, "link", name="torso_3_link")
    tj = ET.SubElement(robot, "joint", name="torso_3_joint", type="revolute")
    ET.SubElement(tj, "parent", link="torso_2_link")
    ET.SubElement(tj, "child", link="torso_3_link")
    ET.SubElement(tj, "origin", xyz="0 0 0.1", rpy="0 0 0")
    ET.SubElement(tj, "axis", xyz="0 1 0")
    ET.SubElement(tj, "limit", lower="-1", upper="1", effort="100", velocity="1")
    ET.SubElement(tj, "mimic", joint="torso_2_joint", multiplier="0.5", offset="0")
    if bare:
        for link in robot.findall("link"):
            for e in link.findall("inertial"):
                link.remove(e)
    for link in robot.findall("link"):
        for tag in ("visual", "collision"):
            for e in link.findall(tag):
                link.remove(e)
    tree.write(out)
    return out


def limits(path: Path) -> dict[str, tuple[float, float]]:
    out = {}
    for j in ET.parse(path).getroot().findall("joint"):
        lim = j.find("limit")
        if lim is not None and j.get("type") == "revolute":
            out[j.get("name")] = (float(lim.get("lower")), float(lim.get("upper")))
    return out


def draw(seed: int, nominal: Path, n: int) -> tuple[ElasticTruth, np.ndarray]:
    rng = np.random.default_rng(seed)
    lim = limits(nominal)
    moving = [j for j in lim]
    truth = ElasticTruth(
        joint_compliance={j: float(rng.uniform(0.5, 1.5) * 1e-4) for j in ELASTIC},
        bending={j: (float(k), float(k * rng.uniform(0.8, 1.25))) for j in BENT
                 for k in [rng.uniform(0.3, 1.0) * 1e-4]},
        origin_error={j: (rng.normal(0, 0.5e-3, 3), rng.normal(0, 1e-3, 3)) for j in moving},
        offset={j: float(rng.normal(0, 2e-3)) for j in RECORDED})
    return truth, commands(rng, lim, n)


def later_commands(seed: int, nominal: Path, n: int) -> np.ndarray:
    """The poses of a later session of the same robot: drawn like the first session's, from a
    stream of their own (the truth, the markers and the mocap as they were)."""
    return commands(np.random.default_rng([seed, 2]), limits(nominal), n)


def commands(rng: np.random.Generator, lim: dict[str, tuple[float, float]], n: int) -> np.ndarray:
    cmd = np.zeros((n, len(RECORDED)))
    for i, j in enumerate(RECORDED):
        lo, hi = lim[j]
        share = 0.35 if j.startswith(("torso", "head")) else 0.6
        mid, half = (lo + hi) / 2, (hi - lo) / 2 * share
        cmd[:, i] = rng.uniform(mid - half, mid + half, n)
    return cmd


def predicted(cal: Path, commands: np.ndarray, names: list[str], work: Path) -> dict[str, np.ndarray]:
    csv = work / "commands.csv"
    csv.write_text("\n".join([",".join(["t", *RECORDED])] + [",".join([f"{k}.0", *(f"{v:.10g}" for v in row)])
                                                            for k, row in enumerate(commands)]) + "\n")
    out = work / "predicted.csv"
    if cli(["predict", "--calibration", str(cal), "--commands", str(csv), "--out", str(out)]):
        raise SystemExit(f"predict failed on {cal}")
    data = np.genfromtxt(out, delimiter=",", names=True)
    return {n: np.stack([data[f"{n}_x"], data[f"{n}_y"], data[f"{n}_z"]], axis=1) for n in names}


def per_hand(pred: dict[str, np.ndarray], recorded: np.ndarray, sim) -> dict[str, float]:
    out = {}
    for hand, link in HANDS.items():
        errs = [np.linalg.norm(pred[n] - 1e3 * recorded[:, m], axis=1)
                for m, (n, lk) in enumerate(zip(sim.marker_names, sim.marker_links)) if lk == link]
        out[hand] = float(np.mean(errs))
    return out


#: link bending named at these joints is at the place of the true bending at the key: torso_2_joint's
#: origin is torso_1_joint's (a link of zero length), so a bend before torso_2 is one after torso_1
SAME_PLACE = {"torso_2_joint": {"torso_1_joint"}}
#: a fitted parameter counts as named when it is this many of its standard deviations from zero
NAMED_SIGMA = 3.0


def named_places(findings: list[dict]) -> list[tuple[str, str]]:
    """(effect, joint) of every place a finding names: one per finding, and for a term of many
    joints (compliance of every loaded joint) each joint whose compliance is NAMED_SIGMA from zero
    (its estimated mass moments, on a URDF without inertias, name no place)."""
    out = []
    for f in findings:
        w = f["where"]
        if "joints" in w:  # compliance_<actuator>, then the link bending told apart from one: bending_<joint>[_u|_v]
            joint_of = dict(zip(w["actuators"], w["joints"]))
            for name, par in f["parameters"].items():
                if not (par.get("std") and abs(par["value"]) > NAMED_SIGMA * par["std"]):
                    continue
                if name.startswith("mass_moments_"):  # the tree's mass moments, estimated: no place
                    continue
                if name.startswith("bending_"):
                    place = ("link_bending", name[len("bending_"):].removesuffix("_u").removesuffix("_v"))
                else:
                    place = (f["effect"], joint_of[name[len("compliance_"):]])
                if place not in out:
                    out.append(place)
        else:
            out.append((f["effect"], str(w.get("actuator") or w.get("joint") or "")))
    return out


def right(effect: str, joint: str) -> bool | None:
    """Whether a named place is a true one (None: an effect this benchmark does not plant)."""
    if effect == "compliance":
        return joint in ELASTIC
    if effect == "link_bending":
        return joint in BENT or any(joint in SAME_PLACE.get(b, ()) for b in BENT)
    return False


def run(seed: int, n_fit: int, n_held: int, bare: bool, root: Path, n_later: int = 0) -> dict:
    nominal = upper_body(root / "talos_upper.urdf")
    model_urdf = upper_body(root / "talos_upper_bare.urdf", bare=True) if bare else nominal
    truth, cmd = draw(seed, nominal, n_fit + n_held)
    # a later session's poses after the first's: the simulator draws the noise row by row, so the
    # first session's poses and noise are the same with or without them
    cmd = np.vstack([cmd, later_commands(seed, nominal, n_later)])
    markers = {f"{h[0].upper()}{k}": link for h, link in HANDS.items() for k in range(1, 4)}
    sim = simulate_elastic_tree(nominal, truth, cmd, RECORDED, markers, seed=seed + 1000, workdir=root)
    fit, held = np.arange(n_fit), np.arange(n_fit, n_fit + n_held)
    moving = dict(markers)
    train = write_elastic_session(sim, model_urdf, root / "train", moving, fit)
    test = write_elastic_session(sim, model_urdf, root / "test", moving, held)
    t0 = time.perf_counter()
    if cli(["calibrate", str(train), "--out", str(root / "cal"), "--quiet", "--no-report"]):
        raise SystemExit("calibrate failed")
    t1 = time.perf_counter()
    if cli(["diagnose", str(train), "--calibration", str(root / "cal" / "calibration.yaml"), "--heldout", str(test),
            "--out", str(root / "diag"), "--quiet"]):
        raise SystemExit("diagnose failed")
    t2 = time.perf_counter()
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    rigid, after, floor, unmodelled = scores(root, cmd, held, sim)
    names = "; ".join(f"{f['effect']} ({f['where'].get('actuator') or f['where'].get('joint') or ''})"
                      for f in d["findings"])
    places = named_places(d["findings"])
    good = [p for p in places if right(*p)]
    names += (f"\n  places named: {len(places)}, right {len(good)}"
              f" ({', '.join(f'{e} {j}' for e, j in places if not right(e, j)) or 'none wrong'})")
    for f in d["findings"]:  # the tree's mass moments estimated (no inertias): the data against the prior
        said = f["where"].get("mass_prior") or {}
        if "determined_by_data" in said:
            bad = {**said["negative_masses_kg"], **said["centres_beyond_twice_length_m"]}
            names += (f"\n  mass moments: {said['determined_by_data']} of {len(said['posterior_std'])} combinations "
                      f"determined by the data beyond the prior; "
                      + ("physical" if said["physical"] else f"not physical at {', '.join(bad)}"))
    print(f"seed {seed}{' (no inertias)' if bare else ''}: held-out mean per hand, mm (left / right)\n"
          f"  elastic sag itself (rigid true robot vs elastic): {unmodelled['left']:.2f} / {unmodelled['right']:.2f}\n"
          f"  rigid calibration:     {rigid['left']:.2f} / {rigid['right']:.2f}\n"
          f"  after diagnose:        {after['left']:.2f} / {after['right']:.2f}\n"
          f"  true elastic model:    {floor['left']:.2f} / {floor['right']:.2f} (noise floor)\n"
          f"  findings: {names or 'none'}\n  calibrate {t1 - t0:.0f} s, diagnose {t2 - t1:.0f} s", flush=True)
    out = {"rigid": rigid, "after": after, "places": len(places), "right": len(good)}
    if n_later:
        rigid, after, floor, unmodelled = scores(root, cmd, np.arange(n_fit + n_held, len(cmd)), sim)
        out.update(later_rigid=rigid, later_after=after)
        print(f"  later session ({n_later} new poses, never seen by calibrate or diagnose), mm (left / right):\n"
              f"    elastic sag itself: {unmodelled['left']:.2f} / {unmodelled['right']:.2f}\n"
              f"    rigid calibration:  {rigid['left']:.2f} / {rigid['right']:.2f}\n"
              f"    after diagnose:     {after['left']:.2f} / {after['right']:.2f}\n"
              f"    true elastic model: {floor['left']:.2f} / {floor['right']:.2f} (noise floor)", flush=True)
    return out


def summary(results: list[dict]) -> str:
    """The goals over the seeds: places named right, the held-out error's median fall per hand,
    hands made worse; the same fall on the later session."""
    def falls(before: str, after: str) -> list[float]:
        return [1 - r[after][h] / r[before][h] for r in results if before in r for h in HANDS]

    right, places = sum(r["right"] for r in results), sum(r["places"] for r in results)
    down = falls("rigid", "after")
    text = (f"over {len(results)} seeds: places named right {right} of {places} ({100 * right / max(places, 1):.0f} %, "
            f"goal 90 %); held-out error down by a median of {100 * np.median(down):.1f} % per hand (goal 80 %), "
            f"{sum(d < 0 for d in down)} hands made worse")
    later = falls("later_rigid", "later_after")
    if later:
        text += (f"; later session: down by a median of {100 * np.median(later):.1f} % per hand, "
                 f"{sum(d < 0 for d in later)} hands made worse")
    return text


def scores(root: Path, cmd: np.ndarray, rows: np.ndarray, sim) -> tuple[dict, dict, dict, dict]:
    """Per hand, the mean marker error (mm) at ``rows`` of the rigid calibration's prediction, of
    diagnose's, of the true elastic model (the noise floor), and of the rigid true robot."""
    rigid = per_hand(predicted(root / "cal" / "calibration.yaml", cmd[rows], sim.marker_names, root), sim.markers[rows], sim)
    after = per_hand(predicted(root / "diag" / "calibration.yaml", cmd[rows], sim.marker_names, root), sim.markers[rows], sim)
    floor = {h: float(np.mean([np.linalg.norm(1e3 * (sim.exact[rows, m] - sim.markers[rows, m]), axis=1)
                               for m, lk in enumerate(sim.marker_links) if lk == link])) for h, link in HANDS.items()}
    unmodelled = {h: float(np.mean([np.linalg.norm(1e3 * (sim.rigid[rows, m] - sim.exact[rows, m]), axis=1)
                                    for m, lk in enumerate(sim.marker_links) if lk == link])) for h, link in HANDS.items()}
    return rigid, after, floor, unmodelled


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[24001])
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--heldout", type=int, default=200)
    ap.add_argument("--bare", action="store_true", help="strip every inertia from the URDF the calibration sees")
    ap.add_argument("--later", type=int, default=0, metavar="N",
                    help="also predict a later session of N new poses of the same robot (its truth, markers and mocap)")
    ap.add_argument("--keep", default=None, help="keep each seed's sessions, calibrations and diagnosis under this folder")
    args = ap.parse_args()
    results = []
    for seed in args.seeds:
        if args.keep:
            root = Path(args.keep) / f"seed{seed}{'_bare' if args.bare else ''}"
            root.mkdir(parents=True, exist_ok=True)
            results.append(run(seed, args.poses, args.heldout, args.bare, root, args.later))
            continue
        with tempfile.TemporaryDirectory(prefix="platkit-trees-") as tmp:
            results.append(run(seed, args.poses, args.heldout, args.bare, Path(tmp), args.later))
    print(summary(results))


if __name__ == "__main__":
    main()
