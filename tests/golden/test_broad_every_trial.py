"""Real data: every BROAD trial in ../shared/data/real/broad is oriented as a user's session, whole
and its opening rest alone (a stationary recording): the plausibility checks of units judge only
where the data can tell, and none of these real recordings is refused."""
from __future__ import annotations

import numpy as np
import pytest
from real_data.broad import DATA, read_broad

from platkit.inertial.orient import orient_session
from platkit.io.imu import write_imu_csv

TRIALS = sorted(DATA.glob("*.hdf5"))


def test_the_trials_are_there():
    assert len(TRIALS) >= 6, f"BROAD trials missing under {DATA}"


@pytest.mark.parametrize("path", TRIALS, ids=[p.stem for p in TRIALS])
def test_every_trial_is_oriented_stationary_part_included(tmp_path, path):
    tr = read_broad(path)
    start = int(np.argmax(tr.movement))
    assert start > 2000  # each trial opens with a rest
    for name, part in (("whole", slice(None)), ("rest", slice(0, start - 300))):
        folder = tmp_path / name
        folder.mkdir()
        (folder / "session.yaml").write_text("platform: none\nunits: {length: m, time: s}\nmarkers: []\n")
        write_imu_csv(folder / "imu.csv", tr.imu.t[part], tr.imu.gyr[part], tr.imu.acc[part])
        result = orient_session(folder)
        assert len(result.q) == len(tr.imu.t[part]) and np.isfinite(result.q).all()
