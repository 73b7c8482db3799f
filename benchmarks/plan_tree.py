"""`platkit plan` on a tree, per tracked link: the predicted marker error of each hand against what
calibration achieves on held-out poses (issue 24: plan works per link).

    .venv/bin/python benchmarks/plan_tree.py [--poses 60] [--seeds 1,2,3] [--noise-mm 0.1] [--markers N]

The robot: PAL's Talos (example-robot-data's talos_reduced.urdf, a public description not written
here), both grippers tracked, every actuated joint below base_link a control (the legs and head
move no marker: plan holds them at neutral). The plan: `plan --optimal N` (D-optimal from 500
random candidates, seed 0, 3 markers per hand in plan's default layout; --markers N: N in all,
marker k on hand k mod 2, so that the hands' predictions differ). Each seed draws a true
stand around the description as `platkit simulate` does (2 mm, 2 mrad per parameter, a random
motion-capture frame), simulates the plan as settled poses with the plan's markers and the given
noise per coordinate of a settled pose, calibrates as `platkit calibrate` does by default (model
selection included), and scores each hand on the stand's reference poses (the poses plan's
prediction is over; noise-free): held-out = RMS over those poses and the hand's markers of
|predicted - true marker position| (3-D). Printed beside plan's prediction for the hand (3-D:
sqrt(3) x the per-coordinate figure plan.json gives), and the ratio achieved / predicted.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from platkit.calibrate import plan as pl
from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.plugins import get_platform
from platkit.simulate import simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from reference_robots import example_robot_urdf  # noqa: E402  (tests/: the finder of example-robot-data)

HANDS = ("gripper_left_base_link", "gripper_right_base_link")
HOLD_S = 1.5


def heldout_per_link(spec, controls, markers, seed: int, noise_mm: float) -> tuple[dict, dict]:
    """(achieved held-out 3-D RMS per link, m; the calibration's summary) of one seeded true stand."""
    common = dict(seed=seed, raw=False, occlusion=0.0, n_markers=len(markers), markers=np.asarray(markers, float),
                  hold_s=HOLD_S, mocap_rate_hz=2.0 / HOLD_S)  # one sample per settled pose: noise_mm is a pose's
    sim = simulate(spec, plan=np.asarray(controls, float), n_poses=len(controls), noise_mm=noise_mm, **common)
    ref = pl.reference_poses(spec)
    truth = simulate(spec, plan=ref.controls, n_poses=len(ref.controls), noise_mm=0.0, **common)
    assert np.allclose(sim.truth.td, truth.truth.td) and np.allclose(sim.truth.markers, truth.truth.markers)
    cal = calibrate(sim.poses, spec)
    predicted, _, _, ok = predict_markers(cal, ref.controls, truth.poses)
    err = np.linalg.norm(predicted - truth.poses.markers, axis=2)[np.asarray(ok, bool)]
    links = np.array(pl.marker_links(spec, len(markers)))
    out = {link: float(np.sqrt(np.mean(err[:, links == link] ** 2))) for link in dict.fromkeys(links)}
    return out, {"fit_rms_m": float(cal.rms_after), "converged": bool(cal.converged), "heldout_poses": int(np.sum(ok))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=60)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--noise-mm", type=float, default=0.1)
    ap.add_argument("--markers", type=int, default=None, help="markers in all (default: plan's, 3 per hand)")
    args = ap.parse_args(argv)
    urdf = example_robot_urdf("talos_data/robots/talos_reduced.urdf")
    spec = get_platform("urdf", urdf, moving_link={h: h for h in HANDS})
    n_markers = pl.default_marker_count(spec) if args.markers is None else args.markers
    markers = pl.default_marker_layout(spec, n_markers, np.random.default_rng(0))
    plan, _ = pl.optimal_plan(spec, args.poses, 500, np.random.default_rng(0), args.noise_mm * 1e-3, markers=markers)
    pred = {link: d["predicted_marker_rms_m"] * np.sqrt(3) for link, d in plan.info["links"].items()}
    print(f"Talos, both hands: {spec.n_u} controls, {spec.n_td} parameters; plan --optimal {args.poses}, "
          f"{len(markers)} markers, {args.noise_mm:g} mm per coordinate of a settled pose")
    print(f"predicted (3-D RMS over the reference poses): whole {plan.info['predicted_marker_rms_m'] * np.sqrt(3) * 1e3:.4f} mm; "
          + ", ".join(f"{k} {v * 1e3:.4f} mm" for k, v in pred.items()))
    print(f"{'seed':>6} " + " ".join(f"{h[:22]:>24} {'/pred':>6}" for h in pred) + f" {'fit rms mm':>11}")
    ratios = []
    for seed in (int(s) for s in args.seeds.split(",")):
        got, info = heldout_per_link(spec, plan.controls, markers, seed, args.noise_mm)
        r = {k: got[k] / pred[k] for k in pred}
        ratios.append(list(r.values()))
        print(f"{seed:>6} " + " ".join(f"{got[k] * 1e3:>21.4f} mm {r[k]:>6.2f}" for k in pred)
              + f" {info['fit_rms_m'] * 1e3:>11.4f}" + ("" if info["converged"] else " (not converged)"))
    R = np.array(ratios)
    print(f"achieved / predicted per hand: median {np.median(R):.2f}, range {R.min():.2f} to {R.max():.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
