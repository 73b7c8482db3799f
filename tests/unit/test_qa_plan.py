"""`platkit plan --optimal N --candidates M` with M < N is bad input in one line (before: M = 0
gave 'ValueError: need at least one array to concatenate', exit 1)."""
import pytest

from platkit.cli import main


@pytest.mark.parametrize("m", ["0", "-3", "5"])
def test_too_few_candidates(tmp_path, capsys, m):
    rc = main(["plan", "--platform", "psvr", "--optimal", "20", "--candidates", m, "--out", str(tmp_path / "p.csv")])
    assert rc == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"platkit: error: --candidates {m}: must be at least --optimal (20)"]
    assert not (tmp_path / "p.csv").exists()


def test_a_negative_seed(tmp_path, capsys):
    """(before: 'ValueError: expected non-negative integer', exit 1)"""
    rc = main(["plan", "--platform", "psvr", "--optimal", "5", "--seed=-1", "--out", str(tmp_path / "p.csv")])
    assert rc == 2
    assert capsys.readouterr().err.strip().splitlines() == ["platkit: error: --seed: must be 0 or more, got -1"]
