"""Reading session folders: every field checked, SI inside, one-line errors naming file/row/column."""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from platkit.settle import load_poses
from platkit.cli import main
from platkit.errors import BadSession
from platkit.io.session import example_session, load_session
from platkit.io.table import read_table
from platkit.plugins import get_platform
from platkit.simulate import simulate, write_session


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory, stewart):
    sim = simulate(stewart, seed=5, n_poses=8, mocap_rate_hz=30, hold_s=1.2)
    return write_session(sim, tmp_path_factory.mktemp("s") / "session"), sim


def _copy(src: Path, tmp_path: Path) -> Path:
    dst = tmp_path / "copy"
    shutil.copytree(src, dst)
    return dst


def _edit(path: Path, old: str, new: str, count: int = 1) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, count))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _error(folder, **kw) -> str:
    with pytest.raises(BadSession) as info:
        load_session(folder, **kw)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def test_round_trip_in_si(session_dir, stewart):
    folder, sim = session_dir
    s = load_session(folder)
    assert s.platform == "stewart" and s.length_unit == "mm" and s.time_unit == "s"
    np.testing.assert_allclose(s.commands, sim.commands, atol=1e-7)  # files keep 0.001 mm
    assert np.all((s.commands > 3.2) & (s.commands < 4.9))  # metres inside
    np.testing.assert_allclose(s.marker_t, sim.marker_t, atol=1e-6)
    np.testing.assert_allclose(s.markers, sim.markers, atol=1e-9, equal_nan=True)
    assert s.markers.shape == (len(sim.marker_t), 5, 3)
    assert np.isnan(s.markers).any(), "the simulated stream has occluded samples"


def test_metres_and_millimetres_read_the_same(tmp_path, stewart):
    sim_m = simulate(stewart, seed=5, n_poses=4, raw=False, length_unit="m")
    a = load_poses(write_session(sim_m, tmp_path / "m", poses_only=True))
    sim_mm = simulate(stewart, seed=5, n_poses=4, raw=False, length_unit="mm")
    b = load_poses(write_session(sim_mm, tmp_path / "mm", poses_only=True))
    np.testing.assert_allclose(a.controls, b.controls, atol=2e-6)
    np.testing.assert_allclose(a.markers, b.markers, atol=2e-6, equal_nan=True)
    assert a.length_unit == "m" and b.length_unit == "mm"


def test_milliseconds_are_converted(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "time: s", "time: ms")
    for name in ("commands.csv", "markers.csv"):
        lines = _lines(folder / name)
        out = [lines[0]]
        for line in lines[1:]:
            cells = line.split(",")
            out.append(",".join([f"{float(cells[0]) * 1000:.3f}"] + cells[1:]))
        (folder / name).write_text("\n".join(out) + "\n")
    s = load_session(folder)
    np.testing.assert_allclose(s.marker_t, session_dir[1].marker_t, atol=1e-6)
    np.testing.assert_allclose(s.command_t, session_dir[1].command_t, atol=1e-6)


def test_missing_units_is_an_error(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "units:\n  length: mm\n  time: s\n", "")
    assert "missing field 'units'" in _error(folder)


@pytest.mark.parametrize("old,new,expect", [
    ("length: mm", "length: cm", "units.length"),
    ("time: s", "time: min", "units.time"),
    ("mocap_rate_hz: 30.0", "mocap_rate_hz: fast", "mocap_rate_hz"),
    ("notes:", "note:", "unknown field 'note'"),
    ("markers:\n- M1", "markers:\n- M1\n- M1", "more than once"),
])
def test_session_yaml_fields_are_checked(session_dir, tmp_path, old, new, expect):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", old, new)
    msg = _error(folder)
    assert "session.yaml" in msg and expect in msg


def test_missing_commands_file_is_named(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    (folder / "commands.csv").unlink()
    msg = _error(folder)
    assert "commands.csv" in msg and "not found" in msg


def test_session_for_another_stand_names_the_expected_columns(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "commands.csv")
    lines[0] = "t,A,B,C,L4,L5,L6"
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert "stewart" in msg and "L1" in msg and "'A'" in msg


def test_missing_control_column(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    rows = [",".join(c for j, c in enumerate(line.split(",")) if j != 3) for line in _lines(folder / "commands.csv")]
    (folder / "commands.csv").write_text("\n".join(rows) + "\n")
    msg = _error(folder)
    assert "missing column 'L3'" in msg and "t, L1, L2, L3, L4, L5, L6" in msg


def test_command_outside_stroke_names_row_and_hints_the_unit(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "commands.csv")
    cells = lines[3].split(",")
    cells[2] = "4.0"  # metres in a millimetre file
    lines[3] = ",".join(cells)
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert "commands.csv row 3 (line 4) column 'L2'" in msg
    assert "outside the stroke [3295, 4795] mm" in msg and "fits the stroke in m" in msg


@pytest.mark.parametrize("file", ["commands.csv", "markers.csv"])
@pytest.mark.parametrize("kind", ["duplicated", "earlier"])
def test_bad_timestamps_name_the_row(session_dir, tmp_path, file, kind):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / file)
    t2 = lines[2].split(",")[0]
    cells = lines[3].split(",")
    cells[0] = t2 if kind == "duplicated" else str(float(t2) - 0.001)
    lines[3] = ",".join(cells)
    (folder / file).write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert f"{file} row 3 (line 4) column 't'" in msg and kind in msg


def test_non_numeric_cell_names_row_and_column(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "markers.csv")
    cells = lines[5].split(",")
    cells[4] = "12,5".replace(",", ";")
    lines[5] = ",".join(cells)
    (folder / "markers.csv").write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert "markers.csv row 5 (line 6) column 'M2_x'" in msg and "'12;5'" in msg


def test_infinite_cell_is_named(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "commands.csv")
    cells = lines[2].split(",")
    cells[6] = "inf"
    lines[2] = ",".join(cells)
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    assert "commands.csv row 2 (line 3) column 'L6': expected a finite number, got 'inf'" in _error(folder)


def test_unknown_stand_in_session_yaml(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "platform: stewart", "platform: hexapod9")
    msg = _error(folder)
    assert "session.yaml" in msg and "unknown platform 'hexapod9'" in msg and "stewart" in msg


def test_ragged_row_is_named(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "markers.csv")
    lines[7] = lines[7] + ",1.0"
    (folder / "markers.csv").write_text("\n".join(lines) + "\n")
    assert "markers.csv row 7 (line 8): 17 cells, expected 16" in _error(folder)


def test_undeclared_marker_column(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "- M5\n", "")
    msg = _error(folder)
    assert "'M5_x'" in msg and "does not declare" in msg


def test_declared_marker_without_columns(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "- M5\n", "- M5\n- M6\n")
    assert "missing column 'M6_x'" in _error(folder)


def test_marker_never_seen(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "markers.csv")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        cells[7:10] = ["", "", ""]  # M3
        out.append(",".join(cells))
    (folder / "markers.csv").write_text("\n".join(out) + "\n")
    msg = _error(folder)
    assert "marker 'M3' is never seen" in msg


def test_half_occluded_sample_is_an_error(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    lines = _lines(folder / "markers.csv")
    cells = lines[9].split(",")
    cells[1] = "nan"
    cells[2] = "1.0"
    lines[9] = ",".join(cells)
    (folder / "markers.csv").write_text("\n".join(lines) + "\n")
    assert "row 9 (line 10): marker 'M1' has some of x,y,z empty" in _error(folder)


def test_markers_in_the_wrong_unit(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "length: mm", "length: m")
    # commands are checked first: the leg lengths name the unit mix-up
    assert "fits the stroke in mm" in _error(folder)
    lines = _lines(folder / "commands.csv")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        out.append(",".join([cells[0]] + [f"{float(c) / 1000:.6f}" for c in cells[1:]]))
    (folder / "commands.csv").write_text("\n".join(out) + "\n")
    msg = _error(folder)
    assert "markers.csv row 1 (line 2) column 'M1_x'" in msg and "is the file in mm?" in msg
    # and the other way round: metres in a file that declares mm
    folder2 = tmp_path / "m"
    sim = simulate(get_platform("psvr"), seed=1, n_poses=4, mocap_rate_hz=20, length_unit="m")
    write_session(sim, folder2)
    _edit(folder2 / "session.yaml", "length: m", "length: mm")
    assert "look like metres" in _error(folder2)


def test_platform_mismatch(session_dir):
    assert "for the 'stewart' stand, not 'psvr'" in _error(session_dir[0], platform="psvr")


def test_poses_csv_session(tmp_path, stewart):
    sim = simulate(stewart, seed=2, n_poses=6, raw=False, occlusion=0.3)
    folder = write_session(sim, tmp_path / "p", poses_only=True)
    assert (folder / "poses.csv").is_file() and not (folder / "markers.csv").exists()
    poses = load_poses(folder)
    np.testing.assert_allclose(poses.markers, sim.poses.markers, atol=1e-6, equal_nan=True)
    np.testing.assert_array_equal(poses.n_samples, sim.poses.n_samples)
    np.testing.assert_allclose(poses.t, sim.command_t, atol=1e-4)
    # a sample count that contradicts the position
    lines = _lines(folder / "poses.csv")
    header = lines[0].split(",")
    cells = lines[2].split(",")
    cells[header.index("M2_n")] = "0"
    cells[header.index("M2_x")] = "1.0"
    lines[2] = ",".join(cells)
    (folder / "poses.csv").write_text("\n".join(lines) + "\n")
    msg = _error(folder)
    assert "poses.csv row 2 (line 3) column 'M2_n'" in msg


def test_no_markers_is_a_clear_error(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    (folder / "markers.csv").unlink()
    with pytest.raises(BadSession, match="no markers"):
        load_poses(folder)


def _write_c3d(path: Path, t, xyz_m, labels, unit="mm", units_param=True):
    import ezc3d

    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [round(1.0 / float(np.median(np.diff(t))), 3)]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    scale = {"mm": 1e3, "m": 1.0}[unit]
    pts = np.ones((4, xyz_m.shape[1], xyz_m.shape[0]))
    pts[:3] = np.nan_to_num(xyz_m.transpose(2, 1, 0) * scale)
    c["data"]["points"] = pts
    if units_param:
        c["parameters"]["POINT"]["UNITS"]["value"] = [unit]
    c.write(str(path))
    if not np.isnan(xyz_m).any():
        return
    # occluded samples: residual -1, as motion-capture software writes them
    d = ezc3d.c3d(str(path))
    d["data"]["points"] = pts
    res = np.zeros((1, xyz_m.shape[1], xyz_m.shape[0]))
    res[0][np.isnan(xyz_m).any(axis=2).T] = -1
    d["data"]["meta_points"]["residuals"] = res
    d.write(str(path))


@pytest.mark.parametrize("unit", ["mm", "m"])
def test_c3d_markers_round_trip(session_dir, tmp_path, unit):
    folder = _copy(session_dir[0], tmp_path)
    s = load_session(folder)
    labels = ["Stand:" + m for m in s.marker_names] + ["Other:X9"]
    xyz = np.concatenate([s.markers, np.zeros((len(s.marker_t), 1, 3))], axis=1)
    _write_c3d(folder / "markers.c3d", s.marker_t, xyz, labels, unit=unit)
    (folder / "markers.csv").unlink()
    with open(folder / "session.yaml", "a") as fh:
        fh.write(f"markers_file: markers.c3d\nmarkers_time_offset: {s.marker_t[0]}\n")
    c = load_session(folder)
    np.testing.assert_allclose(c.marker_t, s.marker_t, atol=1e-6)  # the CSV keeps microseconds
    np.testing.assert_allclose(c.markers, s.markers, atol=1e-7, equal_nan=True)
    assert np.isnan(c.markers).sum() == np.isnan(s.markers).sum()
    poses = load_poses(folder)
    assert poses.n_poses == len(s.commands)


def test_c3d_missing_label_is_named(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    s = load_session(folder)
    _write_c3d(folder / "m.c3d", s.marker_t, np.nan_to_num(s.markers[:, :4]), s.marker_names[:4])
    with open(folder / "session.yaml", "a") as fh:
        fh.write("markers_file: m.c3d\n")
    msg = _error(folder)
    assert "m.c3d" in msg and "no point labelled 'M5'" in msg


def test_imu_stream_columns_and_times(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    t = np.arange(0, 2, 0.01)
    rows = ["t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [f"{x:.3f},0.1,0,0,0,0,9.81" for x in t]
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    s = load_session(folder)
    assert s.imu_gyr.shape == (200, 3) and np.allclose(s.imu_acc[:, 2], 9.81)
    assert s.imu_stream.rate_hz == pytest.approx(100.0, rel=1e-9)
    rows[0] = "t,gx,gy,gz,acc_x,acc_y,acc_z"
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    assert "imu.csv: line 1: missing column 'gyr_x'" in _error(folder)


def test_read_table_empty_cells_are_nan(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b\n1,\n nan ,2\n")
    t = read_table(p)
    assert np.isnan(t.data[0, 1]) and np.isnan(t.data[1, 0]) and t.data[1, 1] == 2


def test_example_sessions_ship_with_the_package():
    folder = example_session("stewart")
    assert (folder / "truth.yaml").is_file()
    poses = load_poses(folder)
    assert 60 <= poses.n_poses <= 120 and poses.n_markers == 5
    assert sum(f.stat().st_size for f in folder.iterdir()) < 3e6
    with pytest.raises(BadSession, match="no example session"):
        example_session("no-such-stand")


def test_example_sessions_can_live_elsewhere(tmp_path, monkeypatch, session_dir):
    shutil.copytree(session_dir[0], tmp_path / "stewart")
    monkeypatch.setenv("PLATKIT_EXAMPLES", str(tmp_path))
    assert example_session("stewart") == tmp_path / "stewart"


def test_cli_bad_plan_file_exits_2_with_one_line(tmp_path, capsys):
    plan = tmp_path / "plan.csv"
    plan.write_text("L1,L2,L3,L4,L5,L6\n4000,4000,4000,4000,4000,4000\n4000,4000,x,4000,4000,4000\n")
    code = main(["simulate", "--platform", "stewart", "--out", str(tmp_path / "s"), "--plan", str(plan)])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "plan.csv row 2 (line 3) column 'L3'" in err
    assert not (tmp_path / "s").exists()


# ----------------------------------------------------------------------------- the inertial stream


def _imu_rows(t, gyr_y=None):
    """imu.csv lines of a sensor at rest (noisy: constant columns would look clipped)."""
    rng = np.random.default_rng(0)
    data = np.column_stack([rng.normal(0, 1e-3, (len(t), 3)), rng.normal(0, 5e-3, (len(t), 3))])
    data[:, 5] += 9.81
    if gyr_y is not None:
        data[:, 1] = gyr_y
    return ["t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z"] + [
        f"{x:.4f}," + ",".join(f"{v:.6f}" for v in row) for x, row in zip(t, data)]


def test_imu_short_gaps_are_repaired_and_noted(session_dir, tmp_path):
    """load_session reads imu.csv through the inertial reader: short runs of empty cells and
    short time gaps are interpolated, and the Session says so."""
    folder = _copy(session_dir[0], tmp_path)
    t = np.arange(0, 2, 0.01)
    rows = _imu_rows(t, gyr_y=0.5 * t)
    cells = rows[11].split(",")
    cells[2] = ""  # data row 11: gyr_y empty
    rows[11] = ",".join(cells)
    del rows[51:53]  # data rows 51, 52 missing: a 0.03 s gap in time
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    s = load_session(folder)
    np.testing.assert_allclose(s.imu_t, t, atol=1e-9)  # the gap is filled on the sampling grid
    np.testing.assert_allclose(s.imu_gyr[:, 1], 0.5 * t, atol=1e-6)  # linear data: exact repair
    assert s.imu_stream.t is s.imu_t and len(s.imu_notes) == 2
    assert "'gyr_y': 1 missing values" in s.imu_notes[0] and "line 12" in s.imu_notes[0]
    assert "1 short time gaps" in s.imu_notes[1] and "2 linearly interpolated samples" in s.imu_notes[1]


def test_imu_long_gap_names_file_line_and_column(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    rows = _imu_rows(np.arange(0, 2, 0.01))
    for i in range(31, 41):  # data rows 30..39: 0.1 s of acc_z missing
        rows[i] = rows[i].rsplit(",", 1)[0] + ","
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    msg = _error(folder)
    assert "imu.csv: line 32, column 'acc_z': 10 missing values" in msg
    assert load_session(folder, imu_max_repair_s=0.2).imu_notes  # a longer allowance repairs it


def test_imu_ragged_row_is_an_error(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    rows = _imu_rows(np.arange(0, 1, 0.01))
    rows[6] = rows[6].rsplit(",", 2)[0]  # a cut line: two cells short
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    assert "imu.csv: line 7: 5 cells, expected 7 like the header" in _error(folder)


def test_imu_times_in_milliseconds(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    for name in ("commands.csv", "markers.csv"):
        (folder / name).unlink()
    _edit(folder / "session.yaml", "platform: stewart", "platform: none")
    _edit(folder / "session.yaml", "time: s", "time: ms")
    t_ms = np.arange(0, 2000, 10.0)
    rows = _imu_rows(t_ms)
    del rows[101:104]  # a 40 ms gap: within the 0.05 s that may be repaired, once ms are seconds
    (folder / "imu.csv").write_text("\n".join(rows) + "\n")
    s = load_session(folder)
    np.testing.assert_allclose(s.imu_t, t_ms / 1000.0, atol=1e-9)
    assert s.imu_stream.rate_hz == pytest.approx(100.0, rel=1e-9) and len(s.imu_notes) == 1
    assert "longest 0.04 s" in s.imu_notes[0]  # messages in seconds too


@pytest.mark.parametrize("entry,expect", [
    ("{rate_hz: 200, frame: imu, rate: 3}", "field 'imu' has unknown key 'rate'"),
    ("{rate_hz: -200}", "field 'imu.rate_hz' must be a positive number"),
    ("{rate_hz: 200, gyr_range_rad_s: 0}", "field 'imu.gyr_range_rad_s' must be a positive number"),
    ("{rate_hz: 200, acc_range_m_s2: lots}", "field 'imu.acc_range_m_s2' must be a positive number"),
])
def test_imu_entry_is_checked(session_dir, tmp_path, entry, expect):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "imu: null", f"imu: {entry}")
    (folder / "imu.csv").write_text("\n".join(_imu_rows(np.arange(0, 1, 0.01))) + "\n")
    msg = _error(folder)
    assert "session.yaml" in msg and expect in msg


def test_imu_declared_full_scale_flags_saturation(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "imu: null", "imu: {rate_hz: 100, frame: imu, acc_range_m_s2: 9.8}")
    (folder / "imu.csv").write_text("\n".join(_imu_rows(np.arange(0, 1, 0.01))) + "\n")
    s = load_session(folder)
    assert s.imu_stream.saturated[:, 5].all() and not s.imu_stream.saturated[:, :5].any()
    assert len(s.imu_notes) == 1 and "100 samples of acc_z at the sensor's clipping limit" in s.imu_notes[0]


def test_declared_imu_without_imu_csv(session_dir, tmp_path):
    folder = _copy(session_dir[0], tmp_path)
    _edit(folder / "session.yaml", "imu: null", "imu: {rate_hz: 100, frame: imu}")
    assert "field 'imu' declares an inertial stream" in _error(folder)


# ----------------------------------------------------------------------------- IMU-only recordings


def _imu_only(session_dir, tmp_path, platform="none", keep_commands=False) -> Path:
    """The simulated session turned into an IMU-only recording: platform none, no markers."""
    folder = _copy(session_dir[0], tmp_path)
    (folder / "markers.csv").unlink()
    if not keep_commands:
        (folder / "commands.csv").unlink()
    _edit(folder / "session.yaml", "platform: stewart", f"platform: {platform}")
    (folder / "imu.csv").write_text("\n".join(_imu_rows(np.arange(0, 1, 0.01))) + "\n")
    return folder


@pytest.mark.parametrize("platform", ["none", "None", "NONE", "null", "~"])
def test_platform_none_is_an_imu_only_recording(session_dir, tmp_path, platform):
    s = load_session(_imu_only(session_dir, tmp_path, platform))
    assert s.platform is None and s.spec is None
    assert s.commands is None and s.command_t is None and not s.has_markers
    assert s.imu_gyr.shape == (100, 3)


def test_imu_only_recording_keeps_the_command_times(session_dir, tmp_path):
    """Without a stand the controls mean nothing to check, but the times are read and checked."""
    folder = _imu_only(session_dir, tmp_path, keep_commands=True)
    s = load_session(folder)
    np.testing.assert_allclose(s.command_t, session_dir[1].command_t, atol=1e-6)
    assert s.commands is None
    lines = _lines(folder / "commands.csv")
    lines[3] = lines[2]  # data row 3 repeats the time of row 2
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    assert "commands.csv row 3 (line 4) column 't'" in _error(folder)
    shutil.copy(session_dir[0] / "commands.csv", folder / "commands.csv")
    lines = _lines(folder / "commands.csv")
    lines[2] = lines[2].rsplit(",", 1)[0] + ","
    (folder / "commands.csv").write_text("\n".join(lines) + "\n")
    assert "commands.csv row 2 (line 3) column 'L6': empty" in _error(folder)


def test_imu_only_recording_needs_its_imu_stream(session_dir, tmp_path):
    folder = _imu_only(session_dir, tmp_path)
    (folder / "imu.csv").unlink()
    msg = _error(folder)
    assert "imu.csv: file not found" in msg and "IMU-only recording" in msg


def test_imu_only_recording_read_for_a_stand_names_the_missing_command_log(session_dir, tmp_path):
    msg = _error(_imu_only(session_dir, tmp_path), platform="stewart")
    assert "commands.csv: file not found" in msg and "declares no platform" in msg


def test_calibrate_an_imu_only_recording_says_calibration_needs_a_stand(session_dir, tmp_path, capsys):
    folder = _imu_only(session_dir, tmp_path)
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "calibration needs a stand" in err
    assert main(["calibrate", str(folder), "--platform", "stewart", "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "declares no platform" in err
    # with --validate too: the refusal is the session's, the second session is not read
    assert main(["calibrate", str(folder), "--validate", str(tmp_path / "absent"), "--out", str(tmp_path / "cal")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "calibration needs a stand" in err and "absent" not in err
    assert not (tmp_path / "cal").exists()


# ----------------------------------------------------------------------------- the fast reader (issue 13)


def _table_text(rows: list[list[str]], header=("t", "a", "b")) -> str:
    return ",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n"


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of 4 rows, so that a few rows cross chunk boundaries as millions would; files of
    any size parsed as two halves at once first (as large files are), then in one pass where a
    half does not read cleanly."""
    import platkit.io.table as session_module

    monkeypatch.setattr(session_module, "CHUNK_ROWS", 4)
    monkeypatch.setattr(session_module, "PARALLEL_MIN_BYTES", 0)


@pytest.mark.parametrize("n", [8, 9, 13, 40])
def test_two_halves_read_what_one_pass_reads(tmp_path, small_chunks, monkeypatch, n):
    import platkit.io.table as table_module

    rows = [[f"{i}", "" if i % 5 == 1 else f"{i * 0.5:.3f}", "nan" if i % 7 == 3 else "1.25"] for i in range(n)]
    p = tmp_path / "m.csv"
    p.write_text(_table_text(rows) + "\n\n")  # blank lines after the last row are no rows
    halves = []
    real = table_module._parse_fast

    def spy(*args, **kwargs):
        halves.append(kwargs.get("stop"))
        return real(*args, **kwargs)

    monkeypatch.setattr(table_module, "_parse_fast", spy)
    both = read_table(p).data
    assert len(halves) == 2 and halves[0] is not None and halves[1] is None  # two halves, no second pass
    monkeypatch.setattr(table_module, "PARALLEL_MIN_BYTES", 10**12)
    one = read_table(p).data
    assert both.shape == one.shape == (n, 3)
    assert np.array_equal(both, one, equal_nan=True)


@pytest.mark.parametrize("row", [0, 3, 4, 5, 10])
@pytest.mark.parametrize("cell, expect", [
    ("x", "column 'b': expected a number, got 'x'"),
    ("inf", "column 'b': expected a finite number, got 'inf'"),
    ("1e999", "column 'b': expected a finite number, got '1e999'"),
    ("1;2", "column 'b': expected a number, got '1;2'"),
])
def test_a_bad_cell_is_named_wherever_the_chunks_fall(tmp_path, small_chunks, row, cell, expect):
    rows = [[f"{i}", f"{i * 0.5:.3f}", "1.25"] for i in range(12)]
    rows[row][2] = cell
    p = tmp_path / "m.csv"
    p.write_text(_table_text(rows))
    with pytest.raises(BadSession) as err:
        read_table(p)
    assert str(err.value) == f"{p} row {row + 1} (line {row + 2}) {expect}"


@pytest.mark.parametrize("row", [0, 3, 4, 8])  # not the last: a blank last line is no row
@pytest.mark.parametrize("change, cells", [("drop", 2), ("add", 4), ("blank", 0)])
def test_a_row_with_another_cell_count_is_named(tmp_path, small_chunks, row, change, cells):
    rows = [[f"{i}", "1", "2"] for i in range(10)]
    if change == "drop":
        rows[row] = rows[row][:2]
    elif change == "add":
        rows[row] = rows[row] + ["3"]
    else:
        rows[row] = []
    p = tmp_path / "m.csv"
    p.write_text(_table_text(rows))
    with pytest.raises(BadSession) as err:
        read_table(p)
    assert str(err.value) == f"{p} row {row + 1} (line {row + 2}): {cells} cells, expected 3 like the header"


def test_the_first_problem_in_the_file_is_the_one_told(tmp_path, small_chunks):
    rows = [[f"{i}", "1", "2"] for i in range(12)]
    rows[2][1] = "inf"  # read by the fast parser (a number to it), before a chunk it refuses
    rows[9][2] = "x"
    p = tmp_path / "m.csv"
    p.write_text(_table_text(rows))
    with pytest.raises(BadSession, match=r"row 3 \(line 4\) column 'a': expected a finite number"):
        read_table(p)


def test_fast_reading_gives_what_the_cell_by_cell_reading_gives(tmp_path, small_chunks):
    rng = np.random.default_rng(3)
    values = rng.normal(scale=1e3, size=(11, 3))
    rows = [[f"{v:.17g}" for v in r] for r in values]
    rows[1][1], rows[5][2], rows[6][0], rows[7][1] = "", "nan", "NaN", " 2.5 "
    p = tmp_path / "m.csv"
    p.write_text(_table_text(rows) + "\n\n")  # blank lines at the end are not rows
    t = read_table(p)
    expect = values.copy()
    expect[1, 1] = expect[5, 2] = expect[6, 0] = np.nan
    expect[7, 1] = 2.5
    assert t.header == ["t", "a", "b"] and t.data.shape == (11, 3)
    np.testing.assert_array_equal(t.data, expect)  # bit for bit: both parse to the nearest double
    rows[3][2] = "nAn"  # a spelling only the cell-by-cell reading takes: same table
    p.write_text(_table_text(rows))
    expect[3, 2] = np.nan
    np.testing.assert_array_equal(read_table(p).data, expect)


def test_empty_files_and_headers_are_named(tmp_path):
    p = tmp_path / "m.csv"
    for text, expect in [("", "the file is empty"), ("\n \n", "the file is empty"), ("t,a\n", "no data rows"),
                         ("t,a\n\n\n", "no data rows"), ("t,,a\n1,2,3\n", "header column 2 is empty"),
                         ("t,a,t\n1,2,3\n", "duplicate columns ['t']")]:
        p.write_text(text)
        with pytest.raises(BadSession, match=re.escape(expect)):
            read_table(p)


def test_large_files_show_progress_from_the_start(tmp_path, monkeypatch, capsys):
    import platkit.io.table as session_module

    p = tmp_path / "m.csv"
    p.write_text(_table_text([[f"{i}", "1", "2"] for i in range(50)]))
    read_table(p)
    assert capsys.readouterr().err == ""  # small files read silently
    monkeypatch.setattr(session_module, "PROGRESS_MIN_BYTES", 0)
    read_table(p)
    assert capsys.readouterr().err.splitlines()[0] == f"reading {p}: 0 MB"
    read_table(p, quiet=True)
    assert capsys.readouterr().err == ""


def test_calibrate_reads_the_motion_capture_stream_once(monkeypatch):
    import platkit.io.session as session_module
    from platkit.commands.calibrate import load_for_calibration

    reads = []
    real = session_module.read_table

    def counting(path, *args, **kwargs):
        reads.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(session_module, "read_table", counting)
    poses, spec, _ = load_for_calibration(None, "stewart", None)
    assert reads.count("markers.csv") == 1 and reads.count("commands.csv") == 1
    assert spec.name == "stewart" and len(poses.controls) > 10


def test_a_marker_stream_in_file_order_is_not_copied(tmp_path):
    import platkit.io.session_checks as session_module
    from platkit.io.session_checks import marker_columns
    from platkit.io.table import Table

    header = ["t"] + [c for m in ("A", "B") for c in marker_columns(m)]
    data = np.arange(3 * 7, dtype=float).reshape(3, 7)
    table = Table(tmp_path / "m.csv", header, data.copy())
    xyz = session_module._marker_block(table, ["A", "B"], 1e-3, in_place=True)
    assert np.shares_memory(xyz, table.data)
    np.testing.assert_allclose(xyz, data[:, 1:].reshape(3, 2, 3) * 1e-3)
    swapped = session_module._marker_block(Table(table.path, header, data.copy()), ["B", "A"], 1e-3, in_place=True)
    np.testing.assert_allclose(swapped, data[:, [4, 5, 6, 1, 2, 3]].reshape(3, 2, 3) * 1e-3)


@pytest.mark.parametrize("text", ["a,b\n1,2\n3,4\n", "a,b\n1,2\n3,4", "a,b\n1,2\n3,4\n \n\t\n\n", "a,b\n\n \n",
                                  "a,b\n1,2\n\n3,4\n,\n"])
def test_the_line_count_in_small_blocks_is_the_count_in_one(tmp_path, monkeypatch, text):
    import platkit.io.table as table_module

    p = tmp_path / "c.csv"
    p.write_bytes(text.encode())
    start = len("a,b\n")
    body = text[start:]
    stripped = body.rstrip(" \t\r\n")
    expect_lines = body.count("\n") - body.count("\n", len(stripped)) + 1 if stripped else 0
    for block in (1, 2, 3, 7, 2**20):
        monkeypatch.setattr(table_module, "_COUNT_BYTES", block)
        for split in range(start + 1, len(text) + 1):
            lines, commas, before = table_module._count_body(p, start, split)
            assert (lines, commas if stripped else 0) == (expect_lines, body.count(",") if stripped else 0)
            assert before == (text[start:split].count("\n") if stripped else 0)


def _stream_table(tmp_path, values):
    from platkit.io.table import Table

    names = [f"M{k + 1}" for k in range(values.shape[1])]
    header = ["t"] + [f"{m}_{a}" for m in names for a in "xyz"]
    data = np.concatenate([np.arange(len(values))[:, None] * 0.1, values.reshape(len(values), -1)], axis=1)
    return Table(tmp_path / "markers.csv", header, data), names


@pytest.mark.parametrize("case", ["clean", "never seen", "partial late", "partial and never seen", "metres as mm",
                                  "mm as m", "all empty but one"])
def test_the_one_pass_over_the_markers_checks_as_the_three_passes(tmp_path, monkeypatch, case):
    import platkit.io.session_checks as checks

    rng = np.random.default_rng(5)
    values = rng.uniform(-900, 900, (23, 3, 3))
    unit = "mm"
    values[[2, 9, 17], 1] = np.nan  # occluded samples
    if case in ("never seen", "partial and never seen"):
        values[:, 2] = np.nan
    if case in ("partial late", "partial and never seen"):
        values[19, 0, 1] = np.nan
    if case == "metres as mm":
        values /= 1000
    if case == "mm as m":
        unit = "m"
    if case == "all empty but one":
        values[:] = np.nan
        values[4] = 1.0
    monkeypatch.setattr(checks, "CHECK_BLOCK", 4)
    outcomes = []
    for one_pass in (True, False):
        table, names = _stream_table(tmp_path, values.copy())
        try:
            if one_pass:
                xyz = checks.checked_marker_block(table, names, 1e-3 if unit == "mm" else 1.0, unit)
            else:
                xyz = checks._marker_block(table, names, 1e-3 if unit == "mm" else 1.0, in_place=True)
                checks._check_seen(xyz, names, table.path)
                checks._check_plausible_unit(table, xyz, unit, names)
            outcomes.append(xyz.copy())
        except BadSession as exc:
            outcomes.append(str(exc))
    if isinstance(outcomes[0], str):
        assert outcomes[0] == outcomes[1]
    else:
        assert case in ("clean", "all empty but one") and np.array_equal(outcomes[0], outcomes[1], equal_nan=True)
