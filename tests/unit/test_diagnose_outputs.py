"""diagnose: outputs in the session's unit; a bad --out is refused before any work."""

from platkit.cli import main
from platkit.diagnose.report import _length_unit


def test_length_parameters_are_shown_in_the_session_unit():
    assert _length_unit("m", "mm") == (1e-3, "mm")
    assert _length_unit("m/s", "mm") == (1e-3, "mm/s")
    assert _length_unit("rad", "mm") == (1.0, "rad")
    assert _length_unit("m", "m") == (1.0, "m")


def test_out_that_is_a_file_is_refused_before_computing(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    cal = tmp_path / "calibration.yaml"
    cal.write_text("platform: stewart\n")
    rc = main(["diagnose", str(tmp_path / "no-session"), "--calibration", str(cal), "--out", str(afile)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "is a file" in err and len(err.splitlines()) == 1
    assert afile.read_text() == "x"
