"""BROAD (Laidig et al. 2021, the Berlin Robust Orientation Estimation Assessment Dataset): reading
a trial and scoring an orientation estimate as the benchmark scores it.

A trial is an HDF5 file with the datasets ``imu_gyr`` (N, 3) rad/s, ``imu_acc`` (N, 3) m/s^2,
``opt_quat`` (N, 4) w x y z (the optical truth, ENU, NaN where the markers were lost),
``movement`` (N,) 0/1 (the samples scored) and the attribute ``sampling_rate`` (Hz). The score:
inclination RMSE over the samples with movement == 1, degrees, the truth's NaN samples skipped.

Used by the BROAD golden tests and benchmarks (orientation_broad.py, orient_process.py); needs h5py
(platkit's ``dev`` extra), which platkit itself does not.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from platkit.errors import BadSession
from platkit.inertial.metrics import inclination_rmse_deg
from platkit.io.imu import ImuStream, saturation_mask
from real_data import SHARED_DATA

#: the trials in ../shared/data/real/broad, beside the repository
DATA = SHARED_DATA / "broad"


@dataclass
class BroadTrial:
    """One BROAD trial: the IMU stream, the optical truth and the scoring mask.

    ``q_earth_from_imu`` (N, 4) w x y z in ENU, NaN where the optical system lost the body;
    ``movement`` (N,) bool: the samples the benchmark scores.
    """

    name: str
    imu: ImuStream
    q_earth_from_imu: np.ndarray
    movement: np.ndarray
    rate_hz: float

    def score(self, q_earth_from_imu: np.ndarray) -> float:
        """The BROAD score of an estimate (N, 4): inclination RMSE over movement == 1, degrees."""
        return inclination_rmse_deg(q_earth_from_imu, self.q_earth_from_imu, self.movement)


def read_broad(path: str | Path) -> BroadTrial:
    """Read a BROAD HDF5 trial (fields imu_gyr, imu_acc, opt_quat, movement, attribute sampling_rate);
    BadSession names the file and the dataset for a missing or inconsistent one."""
    import h5py  # the dev extra; platkit does not need it

    path = Path(path)
    if not path.is_file():
        raise BadSession(f"{path}: file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise BadSession(f"{path}: not an HDF5 file ({exc})") from None
    with f:
        for key in ("imu_gyr", "imu_acc", "opt_quat", "movement"):
            if key not in f:
                raise BadSession(f"{path}: missing dataset {key!r}")
        if "sampling_rate" not in f.attrs:
            raise BadSession(f"{path}: missing attribute 'sampling_rate'")
        rate = float(f.attrs["sampling_rate"])
        gyr = np.asarray(f["imu_gyr"], float)
        acc = np.asarray(f["imu_acc"], float)
        quat = np.asarray(f["opt_quat"], float)
        movement = np.asarray(f["movement"]).astype(bool)
    n = len(gyr)
    if not (acc.shape == gyr.shape == (n, 3) and quat.shape == (n, 4) and movement.shape == (n,)):
        raise BadSession(f"{path}: datasets have inconsistent shapes")
    for key, arr in (("imu_gyr", gyr), ("imu_acc", acc)):
        bad = np.argwhere(~np.isfinite(arr))
        if bad.size:
            raise BadSession(f"{path}: dataset {key!r}, sample {bad[0][0]}, axis {bad[0][1]}: not a finite number")
    t = np.arange(n) / rate
    imu = ImuStream(t, gyr, acc, saturation_mask(np.column_stack([gyr, acc])), [], str(path))
    return BroadTrial(path.stem, imu, quat, movement, rate)
