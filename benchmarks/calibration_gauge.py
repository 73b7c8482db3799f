"""Stands whose moving part never turns: calibrated under the gauge convention, against the truth.

    .venv/bin/python benchmarks/calibration_gauge.py [--stands gantry,delta] [--seeds 0,1,2] [--poses 50]

The delta is the outside plugin in examples/platkit-delta: install it first
(``pip install ./examples/platkit-delta``, or put ``examples/platkit-delta/src`` and a folder with
its installed metadata on PYTHONPATH); without it the delta row says it is not installed.

Per stand and seed: ``platkit simulate --poses-only`` (0.2 mm marker noise per axis, settled over
the simulated holds, the stand's default grid plan), :func:`calibrate` with every parameter free,
then at 200 new commands (10-90% of each stroke, a fixed seed) the RMS 3-D error of the predicted
markers against the noise-free truth (truth.yaml), beside the fit's own RMS (the settled poses'
noise floor) and the nominal stand after the best rigid registration (``free=[]``). Printed: one
line per run, then the RMS over the seeds.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml

from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.cli import main
from platkit.errors import UnknownPlatform
from platkit.geometry import matrix_from_quat
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform
from platkit.settle import load_poses

GANTRY = Path(__file__).resolve().parents[1] / "descriptions" / "gantry_xyz.urdf"
STANDS = {"gantry": ("urdf", str(GANTRY)), "delta": ("delta", None)}


def one_run(name: str, description: str | None, seed: int, n_poses: int, folder: Path) -> dict:
    args = ["simulate", "--platform", name, "--out", str(folder), "--poses", str(n_poses), "--poses-only",
            "--seed", str(seed), "--noise-mm", "0.2"]
    if description:
        args += ["--description", description]
    if main(args) != 0:
        raise SystemExit(f"simulate failed for {name} seed {seed}")
    spec = get_platform(name, description) if description else get_platform(name)
    poses = load_poses(folder, spec=spec)
    cal = calibrate(poses, spec)
    nominal = calibrate(poses, spec, free=[])
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    td = np.array([truth["parameters"].get(p.name, {"value": p.nominal})["value"] for p in spec.parameters])
    rng = np.random.default_rng(1000 + seed)
    lo, hi = spec.control_bounds()
    U = lo + rng.uniform(0.1, 0.9, (200, spec.n_u)) * (hi - lo)
    fb = PlatformModel(spec).forward_batch(U, td=td, strict=False)
    S = np.array([truth["markers"][m] for m in sorted(truth["markers"])])
    T = np.array(truth["mocap_from_base"])
    Y = (fb.X[:, None] + np.einsum("nij,mj->nmi", matrix_from_quat(fb.q), S)) @ T[:3, :3].T + T[:3, 3]
    out = {"fit_rms_mm": cal.rms_after * 1e3, "gauge": cal.identifiability["gauge"]["dimensions"]}
    for key, c in (("heldout_mm", cal), ("nominal_mm", nominal)):
        pred, _, _, ok = predict_markers(c, U)
        keep = ok & fb.converged & fb.on_branch
        out[key] = float(np.sqrt(np.mean(np.sum((pred[keep] - Y[keep]) ** 2, axis=2)))) * 1e3
    return out


def main_cli() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stands", default="gantry,delta")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--poses", type=int, default=50)
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(",")]
    for stand in a.stands.split(","):
        name, description = STANDS[stand]
        try:
            get_platform(name, description) if description else get_platform(name)
        except UnknownPlatform:
            print(f"{stand}: not installed (see the docstring)")
            continue
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                r = one_run(name, description, seed, a.poses, Path(tmp) / f"s{seed}")
                rows.append(r)
                print(f"{stand} seed {seed}: fit rms {r['fit_rms_mm']:.4f} mm; new commands against the truth "
                      f"{r['heldout_mm']:.4f} mm (nominal stand, registered: {r['nominal_mm']:.3f} mm); "
                      f"{r['gauge']} gauge directions", flush=True)
        rms = {k: float(np.sqrt(np.mean([r[k] ** 2 for r in rows]))) for k in ("fit_rms_mm", "heldout_mm", "nominal_mm")}
        print(f"{stand}: RMS over {len(rows)} seeds: fit {rms['fit_rms_mm']:.4f} mm, against the truth "
              f"{rms['heldout_mm']:.4f} mm = {rms['heldout_mm'] / rms['fit_rms_mm']:.2f} x the fit's noise floor, "
              f"nominal {rms['nominal_mm']:.3f} mm")


if __name__ == "__main__":
    main_cli()
