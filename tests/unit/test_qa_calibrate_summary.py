"""`platkit calibrate` says the held-out errors it computed, and warns when a --validate session
cannot be in the same motion-capture frame (before: silent, the 1 m error only in report.json)."""
import csv
import shutil

from platkit.cli import main
from platkit.io.session import example_session


def _shifted_copy(src, dst, dx_mm):
    shutil.copytree(src, dst)
    with open(src / "markers.csv") as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    for row in rows[1:]:
        for j, name in enumerate(header):
            if name.endswith("_x") and row[j] not in ("", "nan"):
                row[j] = f"{float(row[j]) + dx_mm:.3f}"
    with open(dst / "markers.csv", "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    return dst


def test_validate_in_the_same_frame_is_reported_without_warning(tmp_path, capsys):
    session = example_session("psvr")
    # what is said is read (the next test renders a --validate report.html)
    assert main(["calibrate", str(session), "--validate", str(session), "--folds", "2", "--quiet", "--no-report",
                 "--out", str(tmp_path / "cal")]) == 0
    captured = capsys.readouterr()
    assert "2-fold held-out rms" in captured.out and "second session (40 poses) rms" in captured.out
    assert "warning" not in captured.err


def test_validate_in_another_frame_warns(tmp_path, capsys):
    session = example_session("psvr")
    other = _shifted_copy(session, tmp_path / "moved", 1000.0)
    assert main(["calibrate", str(session), "--validate", str(other), "--quiet", "--out", str(tmp_path / "cal")]) == 0
    captured = capsys.readouterr()
    assert "second session (40 poses) rms" in captured.out
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "same motion-capture frame" in err[0], err
