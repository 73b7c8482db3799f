"""Real data: PAL TIAGo arm (shared/data/real/tiago) beside FIGAROH 1.0.2.

    .venv/bin/python benchmarks/calibration_tiago.py [--data DIR] [--paper-evaluations N]

First the default of ``platkit calibrate`` (no options: robust loss, the parameter groups chosen by
held-out prediction on the training day), then three fixed model levels. Fitted on the training
day (2021-11-30, 37 postures), scored on the validation day (2021-11-26, 62 postures): the norm
RMSE of point BL in mm, as FIGAROH reports it, beside FIGAROH's three levels.
Rows per level: the four points of the hand body fitted together (platkit's way), point BL alone
(FIGAROH's way, a like-for-like check), and the paper's method (Burlakov et al., four points,
Nelder-Mead budget --paper-evaluations). Plain least squares (no outlier
weighting), as FIGAROH.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data.tiago import FIGAROH, LEVELS, TRAINING, VALIDATION, bl_rmse_mm, convert, default_data_dir, pivot_order  # noqa: E402

from platkit.calibrate.estimate import calibrate  # noqa: E402
from platkit.calibrate.paper import calibrate_paper  # noqa: E402
from platkit.calibrate.selection import select_model  # noqa: E402
from platkit.io.session import load_session  # noqa: E402
from platkit.poses import PoseSet  # noqa: E402
from platkit.settle import load_poses  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--paper-evaluations", type=int, default=2000,
                    help="Nelder-Mead budget of the paper's method (0: leave the paper's rows out)")
    args = ap.parse_args(argv)
    data = Path(args.data) if args.data else default_data_dir()
    with tempfile.TemporaryDirectory() as work:
        sets = {}
        for role, name in (("training", TRAINING), ("validation", VALIDATION)):
            folder = convert(data / name, Path(work) / role)
            s = load_session(folder)
            sets[role] = load_poses(folder, spec=s.spec)
        spec = s.spec
    bl = {k: PoseSet(p.platform, p.controls, p.markers[:, :1], ["BL"], length_unit="m") for k, p in sets.items()}
    t = time.perf_counter()
    cal = select_model(sets["training"], spec, platform_options={"moving_link": spec.moving_frame})
    dt = time.perf_counter() - t
    sel = cal.identifiability["model_selection"]
    print("platkit calibrate, no options (4 points, robust, groups chosen by held-out prediction):")
    print(f"  chose {', '.join(sel['chosen'])} (held: {', '.join(sel['held']) or 'none'}); "
          f"{sum(st == 'estimated' for st in cal.td_status)} joint parameters estimated; {dt:.1f} s")
    for c in sel["candidates"]:
        print(f"    candidate {'+'.join(c['free']):<22} held-out median {c['heldout_median'] * 1e3:5.2f} mm, "
              f"RMS {c['heldout_rms'] * 1e3:5.2f} mm")
    print(f"  BL norm RMSE, mm: train {bl_rmse_mm(cal, sets['training']):.2f}  valid {bl_rmse_mm(cal, sets['validation']):.2f}"
          "   | FIGAROH valid: " + ", ".join(f"{k} {v['validation_mm']:.2f}" for k, v in FIGAROH.items()))
    print()
    print("norm RMSE of point BL, mm (fit on 2021-11-30, validate on 2021-11-26)")
    print(f"{'model':<16} {'fit on':<10} {'unknowns':>8} {'td est.':>7} {'train':>7} {'valid':>7} "
          f"{'FIGAROH n':>9} {'train':>7} {'valid':>7} {'time s':>7}")
    for level, groups in LEVELS.items():
        f = FIGAROH[level]
        runs = [("4 points", sets["training"], sets["validation"]), ("BL alone", bl["training"], bl["validation"])]
        if args.paper_evaluations:
            runs.append(("paper", sets["training"], sets["validation"]))
        for label, train, valid in runs:
            t = time.perf_counter()
            if label == "paper":
                cal = calibrate_paper(train, spec, free=groups, max_evaluations=args.paper_evaluations)
            else:
                cal = calibrate(train, spec, free=groups, robust=False)
            dt = time.perf_counter() - t
            n_td = sum(st == "estimated" for st in cal.td_status)
            print(f"{level:<16} {label:<10} {n_td + 6 + 3 * cal.n_markers:>8d} {n_td:>7d} {bl_rmse_mm(cal, train):>7.2f} "
                  f"{bl_rmse_mm(cal, valid):>7.2f} {f['parameters']:>9d} {f['training_mm']:>7.2f} "
                  f"{f['validation_mm']:>7.2f} {dt:>7.2f}")
    # like for like with FIGAROH's count: BL alone, full geometric, its 30 parameters = the 3 least
    # well fixed of platkit's 33 held at nominal (FIGAROH's QR with an absolute tolerance drops them)
    full = calibrate(bl["training"], spec, free=LEVELS["full_geometric"], robust=False)
    keep = pivot_order(full)[:-3]
    cal = calibrate(bl["training"], spec, free=keep, robust=False)
    f = FIGAROH["full_geometric"]
    print(f"{'full_geometric':<16} {'BL, -3':<10} {len(keep) + 9:>8d} {len(keep):>7d} {bl_rmse_mm(cal, bl['training']):>7.2f} "
          f"{bl_rmse_mm(cal, bl['validation']):>7.2f} {f['parameters']:>9d} {f['training_mm']:>7.2f} {f['validation_mm']:>7.2f}")
    print("unknowns: joint parameters + 6 (base in mocap) + 3 per point; FIGAROH n: its parameter count; "
          "'BL, -3': BL alone with FIGAROH's count (the 3 least well fixed held: " + ", ".join(pivot_order(full)[-3:]) + ")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
