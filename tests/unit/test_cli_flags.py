"""Library errors name the parameter ('free: ...'); the command line says the option that set it
('--free: ...', platkit.cli.as_flag); a message that only begins with an option's word is left."""
import pytest

from platkit.calibrate.estimate import calibrate
from platkit.cli import as_flag, main
from platkit.errors import BadInput
from platkit.plugins import get_platform
from platkit.simulate import simulate


def test_a_parameter_is_said_as_the_option_given():
    assert as_flag("free: nope is neither a parameter", ["calibrate", "--free", "nope"]) == \
        "--free: nope is neither a parameter"
    assert as_flag("folds: 9 is more than the 6 poses", ["calibrate", "--folds=9"]) == "--folds: 9 is more than the 6 poses"
    assert as_flag("max_effects: 0, use 1 or more", ["diagnose", "--max-effects", "0"]) == "--max-effects: 0, use 1 or more"
    assert as_flag("link 'tool0' did not reach its target", ["track", "--link", "tool0"]) == \
        "link 'tool0' did not reach its target"
    # not given on the command line, or not a parameter's name: unchanged
    assert as_flag("free: nope is neither a parameter", ["calibrate"]) == "free: nope is neither a parameter"
    assert as_flag("/tmp/x.csv: row 3", ["calibrate", "--free", "a"]) == "/tmp/x.csv: row 3"


def test_the_library_names_the_parameter_and_the_cli_the_flag(tmp_path, capsys):
    spec = get_platform("stewart")
    poses = simulate(spec, seed=2, n_poses=12, raw=False).poses
    with pytest.raises(BadInput, match="^free: nope is neither a parameter nor a group of the stewart stand"):
        calibrate(poses, spec, free=["nope"])
    assert main(["calibrate", "--platform", "stewart", "--free", "nope", "--out", str(tmp_path / "cal"), "--quiet"]) == 2
    assert "platkit: error: --free: nope is neither a parameter nor a group of the stewart stand" in capsys.readouterr().err


def test_python_dash_m_platkit_is_the_command_line(tmp_path):
    """``python -m platkit`` runs the same command line as the ``platkit`` script: its version, and
    its exit status for bad input (2, one error line)."""
    import subprocess
    import sys

    import platkit

    run = [sys.executable, "-m", "platkit"]
    out = subprocess.run([*run, "--version"], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert out.returncode == 0 and platkit.__version__ in out.stdout + out.stderr
    bad = subprocess.run([*run, "fk", "--platform", "nosuch", "--u", "0"], capture_output=True, text=True,
                         cwd=tmp_path, timeout=120)
    assert bad.returncode == 2 and bad.stderr.count("platkit: error:") == 1 and "nosuch" in bad.stderr
