"""simulate: each bad option is one line naming the option, exit 2, nothing written."""
import pytest

from platkit.cli import main


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--seed", "-1"], "--seed must be 0 or more"),
        (["--effect", "backlash:-3"], "0 or more"),
        (["--noise-mm", "-0.1"], "--noise-mm must be 0 or more"),
        (["--occlusion", "0.7"], "--occlusion must be a fraction"),
        (["--rate-hz", "0"], "--rate-hz must be positive"),
        (["--hold-s", "-1"], "--hold-s must be positive"),
        (["--plan", "no-such-plan.csv"], "file not found"),
    ],
)
def test_bad_option_is_named(tmp_path, capsys, extra, words):
    out = tmp_path / "s"
    rc = main(["simulate", "--platform", "stewart", "--out", str(out), "--poses", "5", *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert words in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_calibrate_on_a_file_says_it_is_a_file(tmp_path, capsys):
    f = tmp_path / "notasession.csv"
    f.write_text("t\n0\n")
    rc = main(["calibrate", str(f), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "is a file; a session is a folder" in err


def test_nan_control_is_named_as_such(tmp_path, capsys):
    s = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--out", str(s), "--poses", "4", "--poses-only"]) == 0
    lines = (s / "poses.csv").read_text().splitlines()
    cells = lines[2].split(",")
    cells[1] = "nan"
    lines[2] = ",".join(cells)
    (s / "poses.csv").write_text("\n".join(lines) + "\n")
    capsys.readouterr()
    rc = main(["calibrate", str(s), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "row 2" in err and "empty or nan" in err
