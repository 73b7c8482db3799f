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
