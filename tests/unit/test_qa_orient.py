"""`platkit orient` on inputs a new user gets wrong: a clipped imu.csv and a negative repair span
are bad input with one line (before: a scipy ValueError, exit 1; the span was taken)."""
from platkit.cli import main


def _imu_only_session(folder, n):
    folder.mkdir()
    (folder / "session.yaml").write_text(
        "platform: none\nunits: {length: mm, time: s}\nmarkers: []\nimu: {rate_hz: 100, frame: imu}\n")
    rows = [f"{k * 0.01:.2f},0,0,0,0,0,9.81" for k in range(n)]
    (folder / "imu.csv").write_text("t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n" + "\n".join(rows) + "\n")
    return folder


def _one_line(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_too_few_imu_samples_is_bad_input(tmp_path, capsys):
    session = _imu_only_session(tmp_path / "s", 3)
    assert main(["orient", str(session), "--out", str(tmp_path / "o")]) == 2
    line = _one_line(capsys)
    assert "imu.csv: 3 samples are too few" in line and "at least 10" in line
    assert not (tmp_path / "o").exists()


def test_a_short_still_recording_is_oriented(tmp_path, capsys):
    session = _imu_only_session(tmp_path / "s", 10)
    assert main(["orient", str(session), "--out", str(tmp_path / "o")]) == 0
    assert len((tmp_path / "o" / "orientation.csv").read_text().splitlines()) == 11


def test_a_negative_repair_span_is_bad_input(tmp_path, capsys):
    session = _imu_only_session(tmp_path / "s", 50)
    assert main(["orient", str(session), "--max-repair-s", "-1", "--out", str(tmp_path / "o")]) == 2
    assert "--max-repair-s" in _one_line(capsys)


def test_no_rest_warning_when_the_held_poses_give_the_bias(tmp_path, capsys):
    session = tmp_path / "sim"
    assert main(["simulate", "--platform", "psvr", "--poses", "6", "--seed", "1", "--imu", "--out", str(session)]) == 0
    capsys.readouterr()
    assert main(["orient", str(session), "--out", str(tmp_path / "o")]) == 0
    import json

    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["gyr_bias_source"] == "held poses of the session"
    assert not any("no rest" in w for w in report.get("warnings", []))
    assert "no rest" not in capsys.readouterr().err
