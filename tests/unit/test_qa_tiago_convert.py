"""`tests/real_data/tiago.py convert`: a missing CSV is named as such (before: 'URDF not
found (pass urdf=...)', about a file the user never gave)."""
import pytest
from real_data import tiago

from platkit.errors import BadInput


def test_a_missing_csv_is_named(tmp_path):
    with pytest.raises(BadInput, match=r"nope\.csv: static-postures CSV not found"):
        tiago.convert(tmp_path / "nope.csv", tmp_path / "out")


def test_a_missing_urdf_says_where_it_was_looked_for(tmp_path):
    csv = tmp_path / "postures.csv"
    csv.write_text("anything\n")
    with pytest.raises(BadInput, match=r"URDF not found \(it is looked for beside the CSV; give another with --urdf"):
        tiago.convert(csv, tmp_path / "out")
    assert not (tmp_path / "out").exists()
