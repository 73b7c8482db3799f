"""Orientation estimators on the six BROAD trials in ../shared/data/real/broad (gyro + accelerometer),
and what `platkit orient` costs per sample against the vqf package (issue 13's goal: within 2x).

Scored as the BROAD benchmark scores (README beside the data): inclination RMSE over the samples
with movement == 1, degrees, the truth's NaN samples skipped (tests/real_data/broad.py).
Estimators:

  platkit          platkit's causal estimator (platkit.inertial.estimator.estimate_platkit: the vqf
                   package's VQF.updateBatch behind platkit's checks)
  platkit-offline  platkit's offline estimator (estimate_offline: vqf.offlineVQF behind the checks)
  orient           `platkit orient SESSION` as a user runs it, the library call (orient_session,
                   default method): the trial written as a session's imu.csv, read, checked (units,
                   gaps), gyro bias from the first rest, offline estimator, report
  paper            Burlakov et al. 2018: low pass, Poisson integration, case A and case B
                   corrections; gyro bias from the trial's initial rest
  paper-A          the same with case A only
  gyro-only        Poisson integration, bias from the initial rest, no accelerometer after the start
  VQF              vqf.VQF 2.1 defaults, causal, called directly            (PyPI vqf)
  VQF-offline      vqf.offlineVQF defaults, called directly                  (PyPI vqf)
  Madgwick         ahrs.filters.Madgwick, default IMU gain 0.033            (PyPI ahrs)

Time per sample: the best of ``--repeats`` runs per trial (one process, one thread), summed over
the trials, divided by their samples; the ratios are taken in the same run.

Run:  .venv/bin/python benchmarks/orientation_broad.py [--data DIR] [--only NAME,...] [--repeats 3]
Takes about a minute on one core (the paper's filters run sample by sample in Python).
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data.broad import DATA, read_broad  # noqa: E402

from platkit.inertial.calibration import gyro_bias_at_rest  # noqa: E402
from platkit.inertial.estimator import estimate_offline, estimate_platkit  # noqa: E402
from platkit.inertial.orient import orient_session  # noqa: E402
from platkit.inertial.paper import PaperParams, estimate_paper  # noqa: E402
from platkit.io.imu import write_imu_csv  # noqa: E402

DEFAULT_DATA = str(DATA)


def run_vqf(tr):
    from vqf import VQF

    out = VQF(1.0 / tr.rate_hz).updateBatch(np.ascontiguousarray(tr.imu.gyr), np.ascontiguousarray(tr.imu.acc))
    return out["quat6D"]


def run_vqf_offline(tr):
    from vqf import offlineVQF

    return offlineVQF(np.ascontiguousarray(tr.imu.gyr), np.ascontiguousarray(tr.imu.acc), None, 1.0 / tr.rate_hz)["quat6D"]


def run_madgwick(tr):
    from ahrs.filters import Madgwick

    return Madgwick(gyr=tr.imu.gyr, acc=tr.imu.acc, frequency=tr.rate_hz).Q


def _paper(tr, **kw):
    bias = gyro_bias_at_rest(tr.imu)
    return estimate_paper(tr.imu, PaperParams(gyro_bias=tuple(bias), **kw)).q


class _Session:
    """The trial as a session folder (session.yaml, imu.csv), written once, outside the timing."""

    def __init__(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.folders: dict[str, Path] = {}

    def folder(self, tr) -> Path:
        if tr.name not in self.folders:
            f = Path(self.tmp.name) / tr.name
            f.mkdir()
            (f / "session.yaml").write_text(f"platform: none\nunits: {{length: m, time: s}}\nmarkers: []\n"
                                            f"imu: {{rate_hz: {tr.rate_hz:.6f}, frame: imu}}\n")
            write_imu_csv(f / "imu.csv", tr.imu.t, tr.imu.gyr, tr.imu.acc)
            self.folders[tr.name] = f
        return self.folders[tr.name]


SESSIONS = _Session()


def run_orient(tr):
    return orient_session(SESSIONS.folder(tr)).q


ESTIMATORS = {
    "platkit": lambda tr: estimate_platkit(tr.imu).q,
    "platkit-offline": lambda tr: estimate_offline(tr.imu).q,
    "orient": run_orient,
    "paper": lambda tr: _paper(tr),
    "paper-A": lambda tr: _paper(tr, case_b=False),
    "gyro-only": lambda tr: _paper(tr, case_a=False, case_b=False),
    "VQF": run_vqf,
    "VQF-offline": run_vqf_offline,
    "Madgwick": run_madgwick,
}


#: (ours, the reference) per-sample time ratios printed at the end
RATIOS = [("platkit", "VQF"), ("platkit-offline", "VQF-offline"), ("orient", "VQF-offline")]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA)
    ap.add_argument("--only", default=None, help="comma-separated estimator names")
    ap.add_argument("--repeats", type=int, default=3, help="runs per trial and estimator; the best is timed")
    args = ap.parse_args(argv)
    names = list(ESTIMATORS) if not args.only else args.only.split(",")
    files = sorted(glob.glob(os.path.join(args.data, "*.hdf5")))
    if not files:
        print(f"no BROAD trials in {args.data}", file=sys.stderr)
        return 2
    table = {n: [] for n in names}
    seconds = {n: 0.0 for n in names}
    trials, samples = [], 0
    for f in files:
        tr = read_broad(f)
        trials.append(tr.name)
        samples += tr.imu.n
        if "orient" in names:
            SESSIONS.folder(tr)
        for n in names:
            best = float("inf")
            for _ in range(max(1, args.repeats if n not in ("paper", "paper-A", "gyro-only", "Madgwick") else 1)):
                t0 = time.perf_counter()
                q = ESTIMATORS[n](tr)
                best = min(best, time.perf_counter() - t0)
            seconds[n] += best
            table[n].append(tr.score(q))
        print(f"  {tr.name}: " + ", ".join(f"{n} {table[n][-1]:.3f}" for n in names), file=sys.stderr, flush=True)
    width = max(len(t) for t in trials)
    print("inclination RMSE over movement == 1, deg")
    print(f"{'trial':<{width}} " + " ".join(f"{n:>15}" for n in names))
    for i, t in enumerate(trials):
        print(f"{t:<{width}} " + " ".join(f"{table[n][i]:15.3f}" for n in names))
    print(f"{'mean':<{width}} " + " ".join(f"{np.mean(table[n]):15.3f}" for n in names))
    print(f"{'us/sample':<{width}} " + " ".join(f"{1e6 * seconds[n] / samples:15.3f}" for n in names))
    print(f"per-sample time over {samples} samples ({len(trials)} trials), best of {args.repeats} runs:")
    for ours, ref in RATIOS:
        if ours in names and ref in names:
            r = seconds[ours] / seconds[ref]
            print(f"  {ours:<16} {1e6 * seconds[ours] / samples:8.3f} us  vs {ref:<12} {1e6 * seconds[ref] / samples:8.3f} us"
                  f"  ratio {r:6.2f}  ({'within' if r <= 2.0 else 'beyond'} 2x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
