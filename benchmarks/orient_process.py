"""``platkit orient`` on the real BROAD trials, whole processes, beside the reference (issue 28).

    .venv/bin/python benchmarks/orient_process.py [--data DIR] [--repeat 3] [--only 02,07]

Each BROAD trial (../shared/data/real/broad/*.hdf5) is written once, untimed, as an IMU-only
session (session.yaml, imu.csv of 53,000-59,000 rows at 285.7 Hz). Then, each a fresh process:

  ours       ``platkit orient SESSION --out DIR``: reading and checking imu.csv, the gyro bias at
             the first rest, vqf's offline filter behind platkit's checks, orientation.csv,
             report.json, report.html
  reference  ``python -c``: numpy.loadtxt of imu.csv + ``vqf.offlineVQF`` (loading the CSV plus
             the vqf package's offline filter, the least a script does for the same result)
  pandas     the same with pandas.read_csv for the loading (a second reference, shown for scale)

The three are run in turns and the best of ``--repeat`` kept, wall-clock and CPU (user + system
of the child; the machine is shared, CPU seconds are what load inflates least). Goal: ours at
most 3x the reference.
"""
from __future__ import annotations

import argparse
import glob
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data.broad import DATA, read_broad  # noqa: E402

from platkit.io.imu import write_imu_csv  # noqa: E402

PYTHON = sys.executable
SCRIPT = Path(PYTHON).parent / "platkit"
PLATKIT = [str(SCRIPT)] if SCRIPT.is_file() else [PYTHON, "-m", "platkit.cli"]

REF = """import sys, numpy as np
from vqf import offlineVQF
d = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1)
offlineVQF(np.ascontiguousarray(d[:, 1:4]), np.ascontiguousarray(d[:, 4:7]), None, float(np.median(np.diff(d[:, 0]))))
"""
REF_PANDAS = """import sys, numpy as np, pandas
from vqf import offlineVQF
d = pandas.read_csv(sys.argv[1]).to_numpy()
offlineVQF(np.ascontiguousarray(d[:, 1:4]), np.ascontiguousarray(d[:, 4:7]), None, float(np.median(np.diff(d[:, 0]))))
"""


def timed(cmd: list[str]) -> tuple[float, float]:
    """(wall s, CPU s of the child) of one process."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = os.times()
    return wall, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", default=None, help="comma-separated prefixes of the trials to run")
    args = ap.parse_args(argv)
    paths = sorted(glob.glob(os.path.join(args.data, "*.hdf5")))
    if args.only:
        paths = [p for p in paths if any(Path(p).name.startswith(o) for o in args.only.split(","))]
    if not paths:
        print(f"no BROAD trials (*.hdf5) in {args.data}", file=sys.stderr)
        return 2
    print(f"{'trial':<44} {'rows':>6}  {'ours wall/CPU s':>15}  {'ref wall/CPU s':>14}  {'pandas wall/CPU s':>17}"
          f"  {'ratio wall':>10}  {'ratio CPU':>9}")
    totals = np.zeros((3, 2))
    with tempfile.TemporaryDirectory() as tmp:
        for path in paths:
            tr = read_broad(path)
            folder = Path(tmp) / tr.name
            folder.mkdir()
            (folder / "session.yaml").write_text(f"platform: none\nunits: {{length: m, time: s}}\nmarkers: []\n"
                                                 f"imu: {{rate_hz: {tr.rate_hz:.6f}, frame: imu}}\n")
            write_imu_csv(folder / "imu.csv", tr.imu.t, tr.imu.gyr, tr.imu.acc)
            out = Path(tmp) / "out"
            cases = [PLATKIT + ["orient", str(folder), "--out", str(out)],
                     [PYTHON, "-c", REF, str(folder / "imu.csv")],
                     [PYTHON, "-c", REF_PANDAS, str(folder / "imu.csv")]]
            best = np.full((3, 2), np.inf)
            for _ in range(args.repeat):
                for i, cmd in enumerate(cases):
                    shutil.rmtree(out, ignore_errors=True)
                    best[i] = np.minimum(best[i], timed(cmd))
            totals += best
            print(f"{tr.name:<44} {len(tr.imu.t):>6}  {best[0, 0]:6.2f} / {best[0, 1]:5.2f}  "
                  f"{best[1, 0]:6.2f} / {best[1, 1]:5.2f}  {best[2, 0]:7.2f} / {best[2, 1]:6.2f}"
                  f"  {best[0, 0] / best[1, 0]:9.2f}x  {best[0, 1] / best[1, 1]:8.2f}x")
    print(f"{'all trials':<44} {'':>6}  {totals[0, 0]:6.2f} / {totals[0, 1]:5.2f}  "
          f"{totals[1, 0]:6.2f} / {totals[1, 1]:5.2f}  {totals[2, 0]:7.2f} / {totals[2, 1]:6.2f}"
          f"  {totals[0, 0] / totals[1, 0]:9.2f}x  {totals[0, 1] / totals[1, 1]:8.2f}x")
    r = totals[0] / totals[1]
    print(f"ours / reference (numpy.loadtxt + vqf.offlineVQF): wall {r[0]:.2f}x, CPU {r[1]:.2f}x; "
          f"goal at most 3x: {'met' if max(r) <= 3.0 else 'NOT MET'}")
    r = totals[0] / totals[2]
    print(f"ours / pandas.read_csv + vqf.offlineVQF: wall {r[0]:.2f}x, CPU {r[1]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
