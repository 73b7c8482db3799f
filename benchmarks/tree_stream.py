"""Streams of a tree: calibration of a whole tree from its raw motion-capture stream, per link.

The stand: a URDF tree tracked on several links in one session, the two-arm torso of
tests/data/trees (a torso yaw, a pitch with a mimic-coupled second pitch, a head that moves no
marker and two 3-joint arms, both hands tracked; 9 recorded joints); or, ``--robot talos``, PAL's
Talos (example-robot-data's talos_reduced.urdf, not written here), both grippers tracked, the
torso, head and arms recorded (17 joints; the legs not). Talos streams the simulator's multisine
(`plan --motion --move` on the whole 32-joint Talos: benchmarks/plan_talos_stream.py) (its elbows
and second shoulder joints, which rest on a limit, about mid-stroke) and its errors
are at 200 random commands within half of each stroke about its middle, with no prediction.

Once: `platkit plan --motion` on the tree (design seed --design-seed) gives the streamed commands
and each link's predicted marker error (plan.json's ``prediction.links``, 3-D RMS over the
stand's reference poses). Then for each seed (the physical simulator: the true stand, drives,
latency, clock offset and occlusion bursts drawn from the seed; white marker noise --noise-mm,
as the plan predicts for):
- motion: the plan's commands streamed without holds, calibrated from motion
  (platkit.calibrate.motion, the whole tree in one fit);
- rigid: the same stream with the geometry held at the description (only the base-to-mocap
  transform, the markers and the response fitted: what the nominal stand predicts);
- holds: a session of --poses held random commands on the same true stand, settled and
  calibrated (platkit.settle, platkit.calibrate.estimate).
The error is each calibration's predicted markers against the true stand's at the reference poses
(held out: no fit saw them, nor their noise), 3-D RMS per tracked link, in mm; ``/pred`` is the
motion fit's achieved error over plan's predicted one.

    .venv/bin/python benchmarks/tree_stream.py [--seeds 2900001,2900002,2900003] [--duration-s 60]
        [--robot two_arm|talos]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.plan import reference_poses_for
from platkit.calibrate.problem import link_frames
from platkit.cli import main as platkit_main
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.settle import load_poses
from platkit.simulate.continuous import read_streamed_commands
from platkit.simulate.physics import simulate_physics, write_physical_session

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "tests" / "data" / "trees" / "two_arm_torso.urdf"
LINKS = "right_tcp,left_tcp"
TALOS_LINKS = ["gripper_left_base_link", "gripper_right_base_link"]
TALOS_RECORDED = (["torso_1_joint", "torso_2_joint", "head_1_joint"] + [f"arm_left_{i}_joint" for i in range(1, 8)]
                  + [f"arm_right_{i}_joint" for i in range(1, 8)])


def link_errors(cal, sim, U) -> dict[str, float]:
    """Per tracked link, the RMS (m, 3-D) of the calibration's markers against the true stand's at
    controls U (N, n_u) SI."""
    spec = sim.spec
    R, X = link_frames(spec, sim.td, U)
    k = np.array([spec.tracked_links.index(sim.moving_link[m]) for m in sim.marker_names])
    T = sim.mocap_from_base
    true = (X[:, k] + np.einsum("nmab,mb->nma", R[:, k], sim.marker_body)) @ T[:3, :3].T + T[:3, 3]
    pred, _, _, _ = predict_markers(cal, U)
    d2 = np.sum((pred - true) ** 2, axis=2)
    return {link: float(np.sqrt(np.nanmean(d2[:, k == i]))) for i, link in enumerate(spec.tracked_links)}


def run_seed(spec, urdf: Path, seed: int, motion, rate_hz: float, args, U_test: np.ndarray, tmp: Path):
    """The three calibrations of one seed (module docstring) and each link's error at U_test."""
    kw = {"noise_mm": args.noise_mm, "coloured": False, "n_markers": 3 * len(spec.tracked_links)}
    sim = simulate_physics(spec, seed=seed, motion=motion, command_rate_hz=rate_hz, duration_s=args.duration_s, **kw)
    folder = tmp / f"motion{seed}"
    write_physical_session(sim, folder, description=urdf)
    session = load_session(folder)
    cal_m, _ = calibrate_motion(session, session.spec)
    cal_r, _ = calibrate_motion(session, session.spec, free=[])
    held = simulate_physics(spec, seed=seed, n_poses=args.poses, plan="random", **kw)
    assert np.allclose(held.td, sim.td), "the same seed draws the same true stand"
    hfolder = tmp / f"holds{seed}"
    write_physical_session(held, hfolder, description=urdf)
    cal_h = calibrate(load_poses(hfolder), load_session(hfolder).spec)
    return [link_errors(c, sim, U_test) for c in (cal_r, cal_h, cal_m)], sim, cal_m


def talos() -> tuple[Path, object]:
    """PAL's Talos (example-robot-data's talos_reduced.urdf), both grippers tracked, the torso, head
    and both arms recorded (the legs not: held at zero, no parameters)."""
    root = Path(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data"))
    urdf = root / "robots" / "talos_data" / "robots" / "talos_reduced.urdf"
    spec = get_platform("urdf", urdf, moving_link={n: n for n in TALOS_LINKS}, joints=TALOS_RECORDED)
    return urdf, spec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="2900001,2900002,2900003")
    ap.add_argument("--robot", default="two_arm", choices=["two_arm", "talos"])
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--max-accel", type=float, default=2.0, help="plan --motion's acceleration limit, rad/s^2")
    ap.add_argument("--poses", type=int, default=40, help="held commands of the holds session")
    ap.add_argument("--noise-mm", type=float, default=0.2)
    ap.add_argument("--design-seed", type=int, default=0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.robot == "talos":
            urdf, spec = talos()
            lo, hi = spec.control_bounds()
            mid, half = (lo + hi) / 2, (hi - lo) / 2
            U_test = np.random.default_rng(0).uniform(mid - 0.5 * half, mid + 0.5 * half, (200, spec.n_u))
            motion, rate_hz, predicted = "multisine", 20.0, None
            print(f"talos_reduced.urdf: {spec.n_u} recorded joints, tracked {', '.join(spec.tracked_links)}; the "
                  f"simulator's multisine for {args.duration_s:g} s at 20 commands per s; 200 random commands held "
                  f"out (within half of each stroke about its middle); noise {args.noise_mm:g} mm white", flush=True)
            print(f"held-out 3-D RMS marker error, mm, per link: rigid (geometry held) | holds ({args.poses} settled) "
                  "| motion (no holds)")
        else:
            urdf, links = URDF, LINKS
            spec = get_platform("urdf", urdf, moving_link={n: n for n in links.split(",")})
            U_test, _ = reference_poses_for(spec)
            t0 = time.perf_counter()
            plan_csv = tmp / "plan" / "commands.csv"
            plan_csv.parent.mkdir()
            code = platkit_main(["plan", "--platform", "urdf", "--description", str(urdf), "--moving-link", links,
                                 "--motion", "--max-accel", str(args.max_accel), "--duration-s", str(args.duration_s),
                                 "--noise-mm", str(args.noise_mm), "--seed", str(args.design_seed), "--quiet",
                                 "--out", str(plan_csv)])
            if code != 0:
                raise SystemExit(f"plan --motion failed ({code})")
            report = json.loads(plan_csv.with_suffix(".json").read_text())
            predicted = {k: v["marker_rms_m"] for k, v in report["prediction"]["links"].items()}
            motion, rate_hz = read_streamed_commands(plan_csv, spec, "mm")
            print(f"{urdf.name}: {spec.n_u} recorded joints, tracked {links}; plan --motion {len(motion)} commands "
                  f"at {rate_hz:g} per s ({time.perf_counter() - t0:.0f} s); {len(U_test)} reference poses; noise "
                  f"{args.noise_mm:g} mm white", flush=True)
            print("held-out 3-D RMS marker error at the reference poses, mm, per link: rigid (geometry held) | holds "
                  f"({args.poses} settled) | motion (no holds) | plan's prediction | motion / prediction")
        ratios = []
        for seed in (int(s) for s in args.seeds.split(",")):
            t1 = time.perf_counter()
            (e_r, e_h, e_m), sim, cal_m = run_seed(spec, urdf, seed, motion, rate_hz, args, U_test, tmp)
            print(f"seed {seed} ({time.perf_counter() - t1:.0f} s; fitted clock shift "
                  f"{1e3 * cal_m.motion['response']['shift_s']['value']:.1f} ms, true "
                  f"{1e3 * sim.nuisances.time_shift_s:.1f} ms)", flush=True)
            for link in spec.tracked_links:
                line = f"  {link:>28}: {1e3 * e_r[link]:8.4f} | {1e3 * e_h[link]:8.4f} | {1e3 * e_m[link]:8.4f}"
                if predicted is not None:
                    ratios.append(e_m[link] / predicted[link])
                    line += f" | {1e3 * predicted[link]:8.4f} | {ratios[-1]:6.2f}"
                print(line, flush=True)
        if ratios:
            print(f"motion / prediction over {len(ratios)} links x seeds: median {np.median(ratios):.2f}, "
                  f"range {min(ratios):.2f} to {max(ratios):.2f}")


if __name__ == "__main__":
    main()
