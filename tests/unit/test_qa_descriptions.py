"""Descriptions and URDF chains from a new user's mistakes: one line naming what is wrong."""
from pathlib import Path

import pytest

from platkit.cli import main

DESCRIPTIONS = Path(__file__).resolve().parents[2] / "descriptions"


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("stand, other, u", [
    ("stewart", "psvr", "4044.9,4044.9,4044.9,4044.9,4044.9,4044.9"),
    ("psvr", "stewart", "2047.2,2047.2,2047.2"),
])
def test_a_description_of_another_stand_is_refused_by_name(tmp_path, capsys, stand, other, u):
    assert main(["fk", "--platform", stand, "--description", str(DESCRIPTIONS / f"{other}.yaml"), "--u", u]) == 2
    assert f"describes {other!r}, not the {stand} stand" in _error(capsys)


def test_stewart_geometry_under_another_platform_name_is_refused(tmp_path, capsys):
    text = (DESCRIPTIONS / "stewart.yaml").read_text().replace("platform: stewart", "platform: psvr")
    (tmp_path / "d.yaml").write_text(text)
    assert main(["fk", "--platform", "stewart", "--description", str(tmp_path / "d.yaml"),
                 "--u", "4044.9,4044.9,4044.9,4044.9,4044.9,4044.9"]) == 2
    assert "field 'platform'" in _error(capsys)


def test_the_own_description_still_loads(capsys):
    assert main(["fk", "--platform", "stewart", "--description", str(DESCRIPTIONS / "stewart.yaml"),
                 "--u", "4044.9,4044.9,4044.9,4044.9,4044.9,4044.9", "--json"]) == 0


def test_a_leaf_as_base_link_says_so(capsys):
    assert main(["fk", "--platform", "urdf", "--base-link", "tool0", "--u", "0,0,0"]) == 2
    line = _error(capsys)
    assert "base_link 'tool0' is a leaf" in line and "the root is 'base_link'" in line
