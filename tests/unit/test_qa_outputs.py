"""Output paths from a user's point of view: a bad --out is bad input (exit 2, one line, found
before any work), written files get ordinary permissions, and stderr carries no solver chatter."""
import os
import stat

import pytest

from platkit.cli import main
from platkit.errors import BadInput
from platkit.io.atomic import atomic_output_dir, atomic_write_text, check_output_dir, check_output_file


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("platkit: error: ")
    assert "Traceback" not in err[0] and "Error:" not in err[0].split("error:", 1)[1]
    return err[0]


def test_atomic_write_text_gives_the_permissions_of_a_plain_open(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / "a.csv", "x\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.csv").stat().st_mode) == 0o644


def test_output_checks_name_the_file_in_the_way(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    with pytest.raises(BadInput, match="is a file"):
        check_output_dir(afile)
    with pytest.raises(BadInput, match=r"afile is a file, so no folder"):
        check_output_dir(afile / "sub")
    with pytest.raises(BadInput, match="is a folder"):
        check_output_file(tmp_path)
    with pytest.raises(BadInput, match=r"afile is a file, so no folder"):
        check_output_file(afile / "x.csv")
    with pytest.raises(BadInput):
        with atomic_output_dir(afile):
            pass
    assert afile.read_text() == "keep me"
    assert check_output_dir(tmp_path / "new" / "dir") == tmp_path / "new" / "dir"


def test_predict_into_a_folder_is_bad_input(tmp_path, capsys):
    commands = tmp_path / "commands.csv"
    commands.write_text("A,B,C\n2047.2,2047.2,2047.2\n")
    rc = main(["predict", "--calibration", str(tmp_path / "missing.yaml"), "--commands", str(commands),
               "--out", str(tmp_path)])
    assert rc == 2
    assert "is a folder; expected a file name" in _one_error_line(capsys)


def test_calibrate_into_a_file_is_bad_input_and_leaves_the_file(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    rc = main(["calibrate", "--platform", "psvr", "--quiet", "--out", str(afile)])
    assert rc == 2
    assert "is a file; expected a folder" in _one_error_line(capsys)
    assert afile.read_text() == "keep me"
    rc = main(["calibrate", "--platform", "psvr", "--quiet", "--out", str(afile / "sub")])
    assert rc == 2
    assert "afile is a file" in _one_error_line(capsys)


@pytest.mark.parametrize("argv", [
    ["workspace", "--platform", "psvr", "--no-plots", "--out", "{f}"],
    ["admissible", "--platform", "psvr", "--out", "{f}"],
    ["plan", "--platform", "psvr", "--grid", "3", "--out", "{f}/plan.csv"],
])
def test_other_verbs_refuse_a_file_as_output_folder(tmp_path, capsys, argv):
    afile = tmp_path / "afile"
    afile.write_text("keep me")
    rc = main([a.replace("{f}", str(afile)) for a in argv])
    assert rc == 2
    assert "is a file" in _one_error_line(capsys)
    assert afile.read_text() == "keep me"


def test_an_os_error_is_one_line_and_exit_2(monkeypatch, capsys):
    import platkit.commands.plugins as verb

    def refuse(args):
        raise PermissionError(13, "Permission denied", "/root/out.csv")

    monkeypatch.setattr(verb, "run", refuse)
    assert main(["plugins"]) == 2
    assert _one_error_line(capsys) == "platkit: error: /root/out.csv: Permission denied"


def test_workspace_of_psvr_keeps_stderr_clean(tmp_path, capfd):
    assert main(["workspace", "--platform", "psvr", "--no-plots", "--out", str(tmp_path / "ws")]) == 0
    err = capfd.readouterr().err
    assert "CasADi" not in err and "WARNING" not in err, err


def test_a_reader_that_stops_early_is_no_error(monkeypatch, capfd):
    import platkit.commands.plugins as verb

    def reader_gone(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(verb, "run", reader_gone)
    assert main(["plugins"]) == 0
    assert capfd.readouterr().err == ""


def test_version(capsys):
    from platkit import __version__

    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"platkit {__version__}"


def test_vectors_may_start_with_a_negative_number(capsys):
    """`--u -10,20` (before: argparse's "expected one argument", exit 2)."""
    import json

    assert main(["fk", "--platform", "rotary", "--u", "-10,20", "--json"]) == 0
    fk = json.loads(capsys.readouterr().out)
    assert fk["yaw"] == pytest.approx(-0.17453292519943295) and fk["pitch"] == pytest.approx(0.3490658503988659)
    assert main(["ik", "--platform", "stewart", "--pose", "-100,-5,3147,-0.1,0,0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["platform"] == "stewart"


def test_join_negative_values_leaves_everything_else_alone():
    from platkit.cli import join_negative_values

    argv = ["fk", "--platform", "rotary", "--u", "-10,20", "--json", "--guess=-1,2", "--unit", "mm", "-h"]
    assert join_negative_values(argv) == ["fk", "--platform", "rotary", "--u=-10,20", "--json", "--guess=-1,2",
                                          "--unit", "mm", "-h"]


def test_a_reader_that_stops_early_is_no_error_in_a_real_process():
    """The process's own stdout, whose reader is gone before platkit writes: exit 0, nothing on
    stderr (neither from the verb nor from the flush at exit)."""
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", "import sys; from platkit.cli import main; sys.exit(main())",
                              "describe", "--platform", "stewart"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    child.stdout.close()  # the reader stops before the first line
    err = child.stderr.read().decode()
    assert child.wait(timeout=60) == 0 and err == "", err
