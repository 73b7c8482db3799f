"""Orientation estimators on the six BROAD trials in ../shared/data/real/broad (gyro + accelerometer).

Scored as the BROAD benchmark scores (README beside the data): inclination RMSE over the samples
with movement == 1, degrees, the truth's NaN samples skipped. Estimators:

  platkit          platkit's estimator, causal (platkit.inertial.estimator.estimate_platkit)
  platkit-offline  bias from a forward and a backward pass, inertial-frame accelerometer filtered
                   with zero phase (offline; platkit.inertial.estimator.estimate_offline)
  paper            Burlakov et al. 2018: low pass, Poisson integration, case A and case B
                   corrections; gyro bias from the trial's initial rest
  paper-A          the same with case A only
  gyro-only        Poisson integration, bias from the initial rest, no accelerometer after the start
  VQF              vqf.VQF 2.1 defaults, causal                          (PyPI vqf)
  VQF-offline      vqf.offlineVQF defaults                               (PyPI vqf)
  Madgwick         ahrs.filters.Madgwick, default IMU gain 0.033         (PyPI ahrs)

Run:  .venv/bin/python benchmarks/orientation_broad.py [--data DIR] [--only NAME,...]
Takes about two minutes on one core (the platkit and paper filters run sample by sample in Python).
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
import time

import numpy as np

from platkit.inertial.calibration import gyro_bias_at_rest
from platkit.inertial.estimator import estimate_offline, estimate_platkit
from platkit.inertial.metrics import inclination_rmse_deg
from platkit.inertial.paper import PaperParams, estimate_paper
from platkit.io.imu import read_broad

DEFAULT_DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data", "real", "broad")


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


ESTIMATORS = {
    "platkit": lambda tr: estimate_platkit(tr.imu).q,
    "platkit-offline": lambda tr: estimate_offline(tr.imu).q,
    "paper": lambda tr: _paper(tr),
    "paper-A": lambda tr: _paper(tr, case_b=False),
    "gyro-only": lambda tr: _paper(tr, case_a=False, case_b=False),
    "VQF": run_vqf,
    "VQF-offline": run_vqf_offline,
    "Madgwick": run_madgwick,
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=DEFAULT_DATA)
    ap.add_argument("--only", default=None, help="comma-separated estimator names")
    args = ap.parse_args(argv)
    names = list(ESTIMATORS) if not args.only else args.only.split(",")
    files = sorted(glob.glob(os.path.join(args.data, "*.hdf5")))
    if not files:
        print(f"no BROAD trials in {args.data}", file=sys.stderr)
        return 2
    table = {n: [] for n in names}
    seconds = {n: 0.0 for n in names}
    trials = []
    for f in files:
        tr = read_broad(f)
        trials.append(tr.name)
        for n in names:
            t0 = time.perf_counter()
            q = ESTIMATORS[n](tr)
            seconds[n] += time.perf_counter() - t0
            table[n].append(inclination_rmse_deg(q, tr.q_earth_from_imu, tr.movement))
        print(f"  {tr.name}: " + ", ".join(f"{n} {table[n][-1]:.3f}" for n in names), file=sys.stderr, flush=True)
    width = max(len(t) for t in trials)
    print("inclination RMSE over movement == 1, deg")
    print(f"{'trial':<{width}} " + " ".join(f"{n:>13}" for n in names))
    for i, t in enumerate(trials):
        print(f"{t:<{width}} " + " ".join(f"{table[n][i]:13.3f}" for n in names))
    print(f"{'mean':<{width}} " + " ".join(f"{np.mean(table[n]):13.3f}" for n in names))
    print(f"{'seconds':<{width}} " + " ".join(f"{seconds[n]:13.1f}" for n in names))
    return 0


if __name__ == "__main__":
    sys.exit(main())
