"""imu.csv reading: every bad input is one line naming file, line and column, or a stated repair."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.errors import BadSession
from platkit.io.imu import IMU_COLUMNS, check_stream, read_imu_csv, saturation_mask, write_imu_csv

HEADER = ",".join(IMU_COLUMNS)


def _rows(n=50, dt=0.01):
    t = np.arange(n) * dt
    rng = np.random.default_rng(0)
    gyr = rng.normal(0, 0.01, (n, 3))
    acc = np.column_stack([rng.normal(0, 0.05, n), rng.normal(0, 0.05, n), 9.81 + rng.normal(0, 0.05, n)])
    return t, gyr, acc


def _write(tmp_path, lines):
    p = tmp_path / "imu.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


def _lines(t, gyr, acc):
    return [HEADER] + [",".join(f"{v:.9g}" for v in [a, *g, *c]) for a, g, c in zip(t, gyr, acc)]


def test_round_trip(tmp_path):
    t, gyr, acc = _rows()
    write_imu_csv(tmp_path / "imu.csv", t, gyr, acc)
    s = read_imu_csv(tmp_path / "imu.csv")
    assert np.allclose(s.t, t) and np.allclose(s.gyr, gyr) and np.allclose(s.acc, acc)
    assert s.repairs == [] and not s.saturated.any()
    assert s.rate_hz == pytest.approx(100.0)


def test_missing_column_names_it(tmp_path):
    t, gyr, acc = _rows()
    lines = _lines(t, gyr, acc)
    lines = [",".join(c.split(",")[:6]) for c in lines]  # drop acc_z
    with pytest.raises(BadSession, match=r"imu\.csv: line 1: missing column 'acc_z'") as exc:
        read_imu_csv(_write(tmp_path, lines))
    assert "\n" not in str(exc.value)


def test_text_in_a_number_cell_names_line_and_column(tmp_path):
    t, gyr, acc = _rows()
    lines = _lines(t, gyr, acc)
    cells = lines[3].split(",")
    cells[4] = "abc"
    lines[3] = ",".join(cells)
    with pytest.raises(BadSession, match=r"line 4, column 'acc_x': expected a number, got 'abc'"):
        read_imu_csv(_write(tmp_path, lines))


def test_time_going_back_is_an_error(tmp_path):
    t, gyr, acc = _rows()
    t[10] = t[8]
    with pytest.raises(BadSession, match=r"line 12, column 't': time goes back"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr, acc)))


def test_repeated_time_is_an_error(tmp_path):
    t, gyr, acc = _rows()
    t[10] = t[9]
    with pytest.raises(BadSession, match=r"line 12, column 't': time repeats"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr, acc)))


def test_missing_time_is_an_error(tmp_path):
    t, gyr, acc = _rows()
    lines = _lines(t, gyr, acc)
    lines[5] = "," + lines[5].split(",", 1)[1]
    with pytest.raises(BadSession, match=r"line 6, column 't': missing time"):
        read_imu_csv(_write(tmp_path, lines))


def test_short_nan_run_is_interpolated_and_reported(tmp_path):
    t, gyr, acc = _rows()
    truth = gyr[20:23, 1].copy()
    lines = _lines(t, gyr, acc)
    for i in (21, 22):  # data rows 21, 22 -> lines 23, 24
        cells = lines[i + 1].split(",")
        cells[2] = "nan" if i == 21 else ""
        lines[i + 1] = ",".join(cells)
    s = read_imu_csv(_write(tmp_path, lines))
    assert len(s.repairs) == 1 and "'gyr_y': 2 missing values" in s.repairs[0] and "line 23" in s.repairs[0]
    expected = np.interp(t[21:23], [t[20], t[23]], [gyr[20, 1], gyr[23, 1]])
    assert np.allclose(s.gyr[21:23, 1], expected)
    assert s.gyr[20, 1] == pytest.approx(truth[0])


def test_long_nan_run_is_an_error(tmp_path):
    t, gyr, acc = _rows()
    acc[10:20, 2] = np.nan
    with pytest.raises(BadSession, match=r"line 12, column 'acc_z': 10 missing values"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr, acc)).__str__(), max_repair_s=0.05)


def test_nan_at_the_start_cannot_be_interpolated(tmp_path):
    t, gyr, acc = _rows()
    gyr[0, 0] = np.nan
    with pytest.raises(BadSession, match=r"line 2, column 'gyr_x': missing value at the start"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr, acc)))


def test_short_gap_is_filled_and_reported(tmp_path):
    t, gyr, acc = _rows()
    keep = np.ones(len(t), bool)
    keep[[30, 31]] = False
    s = read_imu_csv(_write(tmp_path, _lines(t[keep], gyr[keep], acc[keep])))
    assert s.n == len(t)
    assert np.allclose(s.t, t)
    assert any("short time gaps" in r and "2 linearly interpolated samples" in r for r in s.repairs)


def test_long_gap_is_an_error(tmp_path):
    t, gyr, acc = _rows()
    keep = np.ones(len(t), bool)
    keep[20:30] = False
    with pytest.raises(BadSession, match=r"line 22, column 't': a gap of 0.11 s"):
        read_imu_csv(_write(tmp_path, _lines(t[keep], gyr[keep], acc[keep])))


def test_clipping_plateau_is_flagged_and_reported():
    t, gyr, acc = _rows()
    gyr[10:15, 0] = 8.7  # a plateau at the largest magnitude: clipping
    s = check_stream(t, gyr, acc, "x.csv")
    assert s.saturated[10:15, 0].all() and s.saturated[:, 0].sum() == 5
    assert not s.saturated[:, 1:].any()
    assert any("5 samples of gyr_x at the sensor's clipping limit" in w for w in s.warnings())


def test_single_peak_is_not_saturation():
    t, gyr, acc = _rows()
    gyr[10, 0] = 8.7
    assert not saturation_mask(np.column_stack([gyr, acc])).any()


def test_declared_range_flags_samples():
    t, gyr, acc = _rows()
    acc[5, 2] = 16 * 9.81
    mask = saturation_mask(np.column_stack([gyr, acc]), acc_range=16 * 9.81)
    assert mask[5, 5] and mask.sum() == 1


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(BadSession, match="file not found"):
        read_imu_csv(tmp_path / "nope.csv")
    (tmp_path / "e.csv").write_text("")
    with pytest.raises(BadSession, match="empty file"):
        read_imu_csv(tmp_path / "e.csv")


def test_broad_reader_bad_files(tmp_path):
    """The BROAD reader lives with the tests' real-data readers (it needs h5py, which platkit does not)."""
    import h5py
    from real_data.broad import read_broad

    p = tmp_path / "t.hdf5"
    with h5py.File(p, "w") as f:
        f["imu_gyr"] = np.zeros((10, 3))
        f["imu_acc"] = np.zeros((10, 3))
        f["opt_quat"] = np.zeros((10, 4))
        f.attrs["sampling_rate"] = 100.0
    with pytest.raises(BadSession, match=r"t\.hdf5: missing dataset 'movement'"):
        read_broad(p)
    with h5py.File(p, "a") as f:
        f["movement"] = np.zeros(10, bool)
        f["imu_gyr"][3, 1] = np.nan
    with pytest.raises(BadSession, match=r"dataset 'imu_gyr', sample 3, axis 1: not a finite number"):
        read_broad(p)
    (tmp_path / "x.hdf5").write_text("not hdf5")
    with pytest.raises(BadSession, match="not an HDF5 file"):
        read_broad(tmp_path / "x.hdf5")
    import platkit.io.imu

    assert not hasattr(platkit.io.imu, "read_broad")


# ---------------------------------------------------------------------------- units (issue 11 item 6)
def _tilting(seconds=40.0, rate=100.0, seed=0):
    """A sensor tilting +-10 deg about x and y, at rest for the first 5 s: (t, gyr rad/s, acc m/s^2)."""
    from platkit.geometry import quat_from_rpy
    from platkit.inertial.simulate import imu_from_motion

    t = np.arange(0.0, seconds, 1.0 / rate)
    on = t > 5.0
    q = quat_from_rpy(0.17 * np.sin(2 * np.pi * 0.1 * t) * on, 0.17 * np.sin(2 * np.pi * 0.07 * t) * on, 0.0 * t)
    sim = imu_from_motion(t, q, np.zeros((len(t), 3)), bias=[0.002, -0.001, 0.0, 0.05, 0.0, -0.03],
                          noise=(0.002, 0.02), rng=np.random.default_rng(seed))
    return t, sim["gyr"], sim["acc"]


def test_a_stream_in_the_spec_units_is_read(tmp_path):
    t, gyr, acc = _tilting()
    s = read_imu_csv(_write(tmp_path, _lines(t, gyr, acc)), declared_rate_hz=100.0)
    assert s.n == len(t) and s.repairs == []


def test_a_gyro_in_deg_per_s_is_refused(tmp_path):
    t, gyr, acc = _tilting()
    with pytest.raises(BadSession, match=r"imu\.csv: columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro turns the accelerometer's "
                                         r"gravity 5\d\.?\d* times too fast for rad/s \(that is deg/s"):
        read_imu_csv(_write(tmp_path, _lines(t, np.degrees(gyr), acc)))
    # faster than any gyro's range in rad/s: named without the accelerometer
    gyr2 = gyr.copy()
    gyr2[100:200, 2] = 50.0
    with pytest.raises(BadSession, match=r"columns 'gyr_x', 'gyr_y', 'gyr_z': the gyro reads up to 50.*expected rad/s"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr2, acc)))


def test_an_accelerometer_in_g_is_refused(tmp_path):
    t, gyr, acc = _tilting()
    with pytest.raises(BadSession, match=r"imu\.csv: columns 'acc_x', 'acc_y', 'acc_z': the accelerometer's median "
                                         r"magnitude is 0\.99\d* \(that is g: multiply by 9\.80665\); expected m/s\^2"):
        read_imu_csv(_write(tmp_path, _lines(t, gyr, acc / 9.80665)))


def test_times_in_ms_declared_s_are_refused(tmp_path):
    t, gyr, acc = _tilting()
    path = _write(tmp_path, _lines(t * 1000.0, gyr, acc))
    with pytest.raises(BadSession, match=r"imu\.csv: column 't': the median time step is 10 s \(0\.1 Hz\) but session\.yaml "
                                         r"declares the IMU at rate_hz 100.*look like milliseconds"):
        read_imu_csv(path, declared_rate_hz=100.0)
    with pytest.raises(BadSession, match=r"column 't': the median time step is 10 s \(0\.1 Hz\), expected seconds"):
        read_imu_csv(path)
    # declared in ms, the same file is right
    assert read_imu_csv(path, time_scale=1e-3, declared_rate_hz=100.0).rate_hz == pytest.approx(100.0)


@pytest.mark.parametrize("what", ["deg/s", "g", "ms"])
def test_orient_stops_with_one_line_on_wrong_units(tmp_path, capsys, what):
    """Today's failure: exit 0 and an all-NaN orientation.csv. Now exit 2, one line, nothing written."""
    from platkit.cli import main

    t, gyr, acc = _tilting(seconds=20.0)
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "session.yaml").write_text("platform: none\nunits: {length: m, time: s}\nmarkers: []\n"
                                         "imu: {rate_hz: 100, frame: imu}\n")
    if what == "deg/s":
        gyr = np.degrees(gyr)
    elif what == "g":
        acc = acc / 9.80665
    else:
        t = t * 1000.0
    (folder / "imu.csv").write_text("\n".join(_lines(t, gyr, acc)) + "\n")
    assert main(["orient", str(folder), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "imu.csv" in err[0]
    assert {"deg/s": "gyr_x", "g": "acc_x", "ms": "column 't'"}[what] in err[0]
    assert not (tmp_path / "o").exists()


def test_a_cut_or_merged_line_is_named_and_a_blank_line_skipped(tmp_path):
    """The fast reader hands anything irregular to the cell-by-cell one, which names the line."""
    t, gyr, acc = _rows()
    lines = _lines(t, gyr, acc)
    cut = list(lines)
    cut[5] = ",".join(cut[5].split(",")[:6])
    with pytest.raises(BadSession, match=r"imu\.csv: line 6: 6 cells, expected 7 like the header"):
        read_imu_csv(_write(tmp_path, cut))
    merged = list(lines)
    merged[7] = merged[7] + ",1.0"
    with pytest.raises(BadSession, match=r"imu\.csv: line 8: 8 cells, expected 7 like the header"):
        read_imu_csv(_write(tmp_path, merged))
    blank = lines[:10] + [""] + lines[10:]
    s = read_imu_csv(_write(tmp_path, blank))
    assert s.n == len(t) and np.allclose(s.acc, acc)
