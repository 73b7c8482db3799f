"""A humanoid's upper body streamed from `plan --motion --move`: plan, simulate, calibrate, per hand.

The stand: PAL's Talos (example-robot-data's talos_reduced.urdf, not written here) as the whole
URDF tree, every joint a control (32: torso, head, both arms and grippers, both legs), both
grippers tracked. A user calibrating the upper body moves the torso and arms alone:

1. `platkit plan --motion --move 'torso_*,arm_*'` designs the stream (the via-point sweep, --duration-s
   s, acceleration --max-accel rad/s^2, the URDF's velocities); commands.csv carries every joint,
   the head, grippers and legs held at their home in every row (a knee, whose zero is its limit,
   at mid-stroke); plan.json predicts each hand's marker error;
2. per seed, `platkit simulate --physics --motion commands.csv` streams it on a true stand drawn from
   the seed (drives, latency, clock offset, occlusion bursts; white noise --noise-mm);
3. `platkit calibrate` of that stream (calibration from motion: the whole tree in one fit).

The error: the calibration's predicted markers against the true stand's (truth.yaml) at 200
held-out random commands, the torso and arms within half of each stroke about its middle, the
others at the plan's home (as benchmarks/tree_stream.py --robot talos scores the simulator's
multisine), 3-D RMS per hand, mm; beside it plan's prediction (3-D RMS over its reference poses
with the held joints held) and docs/trees.md's figures for the simulator's multisine (0.020-0.029
mm) and 40 settled commands (0.009-0.011 mm) on seeds 2900011-2900012.

    .venv/bin/python benchmarks/plan_talos_stream.py [--seeds 2900021,2900022] [--duration-s 60]
        [--response-kinds auto,second-order] [--keep DIR [--reuse]]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.plan import pin_held, reference_poses_for
from platkit.calibrate.problem import link_frames
from platkit.cli import main as platkit_main
from platkit.io.calibration import read_calibration
from platkit.plugins import get_platform

LINKS = ["gripper_left_base_link", "gripper_right_base_link"]
MOVE = "torso_*,arm_*"
#: docs/trees.md, Talos, seeds 2900011-2900012: the simulator's multisine, and 40 settled commands (mm)
REFERENCE = {"multisine": (0.0205, 0.0292), "holds": (0.0092, 0.0110)}


def talos_urdf() -> Path:
    root = Path(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data"))
    return root / "robots" / "talos_data" / "robots" / "talos_reduced.urdf"


def cli(*argv: str) -> None:
    code = platkit_main(list(argv))
    if code != 0:
        raise SystemExit(f"platkit {argv[0]} failed ({code})")


def held_out(spec, report: dict, n: int = 200) -> np.ndarray:
    """(n, n_u) the held-out commands: the moved joints uniform within half of each stroke about its
    middle (seed 0), the held ones at plan's home (plan.json's 'held')."""
    lo, hi = spec.control_bounds()
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    U = np.random.default_rng(0).uniform(mid - 0.5 * half, mid + 0.5 * half, (n, spec.n_u))
    for name, value in report["held"].items():
        U[:, spec.control_names.index(name)] = value
    return U


def link_errors(spec, truth: dict, cal, U: np.ndarray) -> dict[str, float]:
    """Per tracked link, the 3-D RMS (m) of the calibration's markers against the true stand's."""
    td = np.array([truth["parameters"][n]["value"] for n in spec.parameter_names])
    R, X = link_frames(spec, td, U)
    names = list(cal.marker_names)
    k = np.array([spec.tracked_links.index(truth["marker_links"][m]) for m in names])
    S = np.array([truth["markers"][m] for m in names])
    T = np.array(truth["mocap_from_base"])
    true = (X[:, k] + np.einsum("nmab,mb->nma", R[:, k], S)) @ T[:3, :3].T + T[:3, 3]
    pred, _, _, _ = predict_markers(cal, U)
    d2 = np.sum((pred - true) ** 2, axis=2)
    return {link: float(np.sqrt(np.nanmean(d2[:, k == i]))) for i, link in enumerate(spec.tracked_links)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="2900021,2900022")
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--max-accel", type=float, default=2.0)
    ap.add_argument("--noise-mm", type=float, default=0.2)
    ap.add_argument("--design-seed", type=int, default=0)
    ap.add_argument("--response-kinds", default="auto",
                    help="calibrate's --response-kind, comma-separated: each calibrates the same stream (e.g. "
                         "auto,second-order: the kind chosen from the data against the second order forced)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the plan, sessions (truth.yaml) and calibrations in this folder (created)")
    ap.add_argument("--reuse", action="store_true",
                    help="with --keep: the plan and each seed's session already kept there are read back, not made "
                         "again (the same design seed, duration and noise; calibrations are always made again)")
    args = ap.parse_args()
    if args.reuse and args.keep is None:
        ap.error("--reuse reads back what --keep kept: name the folder with --keep")
    urdf = talos_urdf()
    stand = ["--platform", "urdf", "--description", str(urdf), "--moving-link", ",".join(LINKS)]
    spec = get_platform("urdf", urdf, moving_link={n: n for n in LINKS})
    with tempfile.TemporaryDirectory() as scratch:
        tmp = Path(scratch) if args.keep is None else args.keep
        tmp.mkdir(parents=True, exist_ok=True)
        plan_csv = tmp / "plan" / "commands.csv"
        t0 = time.perf_counter()
        if not (args.reuse and plan_csv.exists()):
            cli("plan", *stand, "--motion", "--move", MOVE, "--max-accel", str(args.max_accel), "--duration-s",
                str(args.duration_s), "--noise-mm", str(args.noise_mm), "--seed", str(args.design_seed), "--quiet",
                "--out", str(plan_csv))
        report = json.loads(plan_csv.with_suffix(".json").read_text())
        predicted = {k: v["marker_rms_m"] for k, v in report["prediction"]["links"].items()}
        header = plan_csv.read_text().splitlines()[0].split(",")[1:]
        C = np.loadtxt(plan_csv, delimiter=",", skiprows=1)[:, 1:]
        still = [n for j, n in enumerate(header) if np.ptp(C[:, j]) == 0]
        print(f"talos_reduced.urdf: {spec.n_u} joints, all in commands.csv ({len(header)} columns); plan --motion "
              f"--move '{MOVE}': {len(C)} commands ({time.perf_counter() - t0:.0f} s), {len(still)} joints never "
              f"move ({', '.join(still)}); noise {args.noise_mm:g} mm white", flush=True)
        U_test = held_out(spec, report)
        held = np.array([n in report["held"] for n in spec.control_names])
        values = np.array([report["held"].get(n, 0.0) for n in spec.control_names])
        U_ref, _ = pin_held(spec, *reference_poses_for(spec), (held, values))
        print("held-out 3-D RMS marker error, mm, per hand: plan --motion --move stream calibrated (at plan's "
              "reference poses, the held joints held) | plan's "
              f"prediction | docs/trees.md: simulator's multisine {REFERENCE['multisine'][0]:.3f}-"
              f"{REFERENCE['multisine'][1]:.3f}, 40 settled {REFERENCE['holds'][0]:.3f}-{REFERENCE['holds'][1]:.3f}")
        achieved = []
        for seed in (int(s) for s in args.seeds.split(",")):
            t1 = time.perf_counter()
            session, out = tmp / f"s{seed}", tmp / f"c{seed}"
            if not (args.reuse and (session / "truth.yaml").exists()):
                cli("simulate", *stand, "--physics", "--motion", str(plan_csv), "--seed", str(seed), "--noise-mm",
                    str(args.noise_mm), "--white-noise", "--markers", "6", "--out", str(session))
            truth = yaml.safe_load((session / "truth.yaml").read_text())
            for kind in args.response_kinds.split(","):
                t2 = time.perf_counter()
                cli("calibrate", str(session), "--response-kind", kind, "--quiet", "--no-report", "--out",
                    str(out.with_name(f"{out.name}-{kind}")))
                cal = read_calibration(out.with_name(f"{out.name}-{kind}") / "calibration.yaml")
                errors = link_errors(spec, truth, cal, U_test)
                at_ref = link_errors(spec, truth, cal, U_ref)
                r = cal.motion["response"]
                shift = r["shift_s"]["value"]
                left = cal.motion["samples"].get("n_in_start_transient", 0)  # the first command's transient
                print(f"seed {seed} [{kind}: {r['kind']}, {sum(e.get('kind') == 'second_order' for e in r['actuators'].values())}"
                      f" second order; not determined: {', '.join(r.get('not_determined') or []) or 'none'}] "
                      f"(simulation {t2 - t1:.0f} s, calibration {time.perf_counter() - t2:.0f} s; fitted clock shift "
                      f"{1e3 * shift:.1f} ms, true {1e3 * truth['nuisances']['markers_time_minus_exposure_time_s']:.1f} ms; "
                      f"{left} samples of the first command's transient left out, "
                      f"{cal.motion['samples']['n_fitted_rejected_as_outliers']} observations rejected)",
                      flush=True)
                for link in spec.tracked_links:
                    achieved.append(errors[link])
                    ratio = [1e3 * errors[link] / r for r in REFERENCE["multisine"]]
                    print(f"  {link:>24}: {1e3 * errors[link]:8.4f} ({1e3 * at_ref[link]:.4f}) | "
                          f"{1e3 * predicted[link]:8.4f} | x{errors[link] / predicted[link]:.2f} of plan's | "
                          f"x{ratio[1]:.2f}-x{ratio[0]:.2f} of the multisine's", flush=True)
                t1 = time.perf_counter()
        print(f"over {len(achieved)} hands x seeds: {1e3 * min(achieved):.4f}-{1e3 * max(achieved):.4f} mm")


if __name__ == "__main__":
    main()
