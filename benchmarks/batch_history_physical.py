"""A static stewart stand's history from the physical (time-domain) simulator: 8 months of one stand
2 mm off its drawing (every joint coordinate and leg offset, drawn from the seed), each month a
recorded stream of its own (``platkit simulate --physics``: settling, latency, correlated noise,
occlusion, a frame and markers of its own), settled and calibrated with the drawing in each
session's own gauge (as a batch did before issue 27) and in the batch's (platkit.batch.gauge);
the history test on both. Every change flagged is false.

    cd $(mktemp -d) && /path/to/.venv/bin/python /path/to/benchmarks/batch_history_physical.py [SEED ...]

(default seed 7300; run in an empty folder: it writes true.yaml, stewart.yaml and stand/.)
"""
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from platkit.batch.gauge import common_parameterisation
from platkit.batch.history import stand_history
from platkit.calibrate.estimate import calibrate
from platkit.commands.calibrate import load_for_calibration
from platkit.plugins import get_platform

PK = str(Path(sys.executable).with_name("platkit"))
REPO = Path(__file__).resolve().parents[1]


def run(base: int) -> None:
    text = (REPO / "descriptions" / "stewart.yaml").read_text()
    rng = np.random.default_rng(base)

    def jitter(m):
        vals = [float(x) + rng.normal(0, 2.0) for x in m.group(2).split(",")]
        return f"{m.group(1)}[{', '.join(f'{v:.4f}' for v in vals)}]"
    true = re.sub(r"((?:base|platform)_joint: )\[([^\]]*)\]", jitter, text)
    true = re.sub(r"offset: 0\.0", lambda m: f"offset: {rng.normal(0, 2.0):.4f}", true)
    Path("true.yaml").write_text(true)
    Path("stewart.yaml").write_text(text)
    t0 = time.time()
    for m in range(8):
        subprocess.run([PK, "simulate", "--platform", "stewart", "--description", "true.yaml", "--perturbation", "0",
                        "--physics", "--seed", str(base + m), "--poses", "20", "--plan", "random",
                        "--out", f"stand/month{m + 1:02d}"], check=True, capture_output=True)
    print(f"simulated in {time.time() - t0:.0f} s", flush=True)
    spec = get_platform("stewart", "stewart.yaml")
    param = common_parameterisation(spec)
    rows = {"own gauge": [], "batch gauge": []}
    for m in range(8):
        poses, _, _ = load_for_calibration(f"stand/month{m + 1:02d}", "stewart", "stewart.yaml", quiet=True)
        for label, free in (("own gauge", None), ("batch gauge", param.free)):
            cal = calibrate(poses, spec, free=free)
            rows[label].append({n: {k: p[k] for k in ("value", "std", "nominal", "unit", "status")}
                                for n, p in cal.to_dict()["parameters"].items()})
    for label, tables in rows.items():
        h = stand_history([f"month{m + 1:02d}" for m in range(8)], tables, [None] * 8)
        held = {tuple(sorted(n for n, p in t.items() if p["status"] != "estimated")) for t in tables}
        print(f"{label}: {len(h['changes'])} changes flagged, {len(held)} held sets, k {h['dispersion_k']:.2f};",
              ", ".join(f"{c['parameter']} {c['session']} {c['change']:+.2f} mm" for c in h["changes"][:6]), flush=True)
    print(f"{time.time() - t0:.0f} s in all")


if __name__ == "__main__":
    for seed in [int(x) for x in sys.argv[1:]] or [7300]:
        print(f"seed {seed}", flush=True)
        subprocess.run(["rm", "-rf", "stand"], check=True)
        run(seed)
