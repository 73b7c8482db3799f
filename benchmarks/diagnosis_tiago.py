"""Real data: `platkit diagnose` on the PAL TIAGo arm (shared/data/real/tiago).

    .venv/bin/python benchmarks/diagnosis_tiago.py [--data DIR] [--no-robust]

As a user would: `platkit calibrate` of the training day (2021-11-30, 37 postures), once with no
options and once with the full geometric model (`--free offset,origin`, FIGAROH's), then `platkit
diagnose` of each calibration with the validation day (2021-11-26, 62 postures) as its held-out
recording (scored, never used to choose). Prints the findings and the norm RMSE of point BL on the
validation day, as FIGAROH reports it, from the calibration before and after diagnosis (the
calibration.yaml each writes, through the same prediction `platkit predict` uses).

Two protocols, side by side:
- as is: the training day's model, its base-to-mocap transform and marker places included, predicts
  the validation day (FIGAROH's validation figures are computed so: its base frame and tool
  parameters come from the training fit, nothing is re-estimated on the validation day);
- re-registered (platkit.calibrate.reregister, `platkit diagnose --heldout-register K`): K
  consecutive validation poses re-fit the set-up (the transform; "+ places": the marker places too),
  every geometric and effect parameter held; the other poses are scored; the blocks rotate so that
  every pose is scored ("spread": each block's K poses taken across the day, `--register-spread`).
  A different protocol: it uses K poses of the validation day. The paired p says whether the
  diagnosed model beats the rigid one once both are re-registered (one-sided Wilcoxon over the
  poses).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data.tiago import FIGAROH, TRAINING, VALIDATION, bl_rmse_mm, convert, default_data_dir  # noqa: E402

from platkit.calibrate.reregister import rotated_scores  # noqa: E402
from platkit.cli import main as cli  # noqa: E402
from platkit.diagnose.stats import paired_improvement  # noqa: E402
from platkit.io.calibration import read_calibration  # noqa: E402
from platkit.settle import load_poses  # noqa: E402

CASES = (("platkit calibrate, no options", []), ("platkit calibrate --free offset,origin", ["--free", "offset,origin"]))
BLOCKS = (5, 10, 15, 31)


def registered_table(before, after, poses, robust: bool = True) -> list[str]:
    """Lines: validation-day BL (mm) of the rigid and the diagnosed calibration, as is and
    re-registered on K poses (transform; transform and marker places), with the paired p (BL's
    per-pose errors, one-sided: the diagnosed smaller)."""
    lines = [f"    {'protocol':<38}{'rigid':>8}{'diagnosed':>11}{'paired p':>10}"]
    as_is = (bl_rmse_mm(before, poses), bl_rmse_mm(after, poses))
    lines.append(f"    {'as is (FIGAROH protocol)':<38}{as_is[0]:>8.2f}{as_is[1]:>11.2f}{'':>10}")
    for spread, markers in ((False, False), (False, True), (True, False), (True, True)):
        for k in BLOCKS:
            a = rotated_scores(before, poses, k, markers, robust=robust, spread=spread)
            b = rotated_scores(after, poses, k, markers, robust=robust, spread=spread)
            p = paired_improvement(a.sq[:, a.names.index("BL")], b.sq[:, b.names.index("BL")])
            label = f"re-registered on {k}" + (" spread" if spread else "") + (" + places" if markers else "")
            lines.append(f"    {label:<38}{1e3 * a.rms_of('BL'):>8.2f}{1e3 * b.rms_of('BL'):>11.2f}{p:>10.2g}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None, help="the TIAGo folder (default: shared/data/real/tiago beside the checkout)")
    ap.add_argument("--no-robust", action="store_true", help="re-register by plain least squares (default: gross "
                                                              "outliers left out, as calibrate does)")
    args = ap.parse_args()
    data = Path(args.data) if args.data else default_data_dir()
    with tempfile.TemporaryDirectory(prefix="platkit-tiago-") as tmp:
        root = Path(tmp)
        train = convert(data / TRAINING, root / "train")
        valid = convert(data / VALIDATION, root / "valid")
        print(f"validation-day norm RMSE of point BL, mm (FIGAROH full_geometric: "
              f"{FIGAROH['full_geometric']['validation_mm']:.2f})")
        for k, (label, free) in enumerate(CASES):
            out = root / f"case{k}"
            t0 = time.perf_counter()
            if cli(["calibrate", str(train), *free, "--out", str(out / "cal"), "--quiet", "--no-report"]):
                raise SystemExit(f"{label}: calibrate failed")
            t1 = time.perf_counter()
            if cli(["diagnose", str(train), "--calibration", str(out / "cal" / "calibration.yaml"), "--heldout",
                    str(valid), "--out", str(out / "diag"), "--quiet"]):
                raise SystemExit(f"{label}: diagnose failed")
            t2 = time.perf_counter()
            d = json.loads((out / "diag" / "diagnosis.json").read_text())
            before = read_calibration(out / "cal" / "calibration.yaml")
            after = read_calibration(out / "diag" / "calibration.yaml")
            poses = load_poses(valid, spec=before.spec)
            names = ", ".join(f"{f['effect']} ({f['where'].get('actuator') or f['where']})" for f in d["findings"])
            h = d.get("heldout_session") or {}
            print(f"{label}:\n  findings: {names or 'none'}\n  BL {bl_rmse_mm(before, poses):.2f} -> "
                  f"{bl_rmse_mm(after, poses):.2f} mm; all four points, RMS {1e3 * h.get('rms_before', float('nan')):.2f} "
                  f"-> {1e3 * h.get('rms_after', float('nan')):.2f} mm (paired p = {h.get('p_improvement', float('nan')):.2g}); "
                  f"calibrate {t1 - t0:.1f} s, diagnose {t2 - t1:.1f} s", flush=True)
            print("\n".join(registered_table(before, after, poses, robust=not args.no_robust)), flush=True)


if __name__ == "__main__":
    main()
