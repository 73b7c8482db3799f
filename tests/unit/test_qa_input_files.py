"""Input files a careless or hostile hand wrote (issue 11 item 6): a YAML alias bomb, a typo in a
description's field, a simulation aimed at a folder that already holds a session. Each is one line
naming the file or option, exit 2, and nothing written."""
import time
from pathlib import Path

import pytest

from platkit.cli import main

DESCRIPTIONS = Path(__file__).resolve().parents[2] / "descriptions"
U_STEWART = "4044.9,4044.9,4044.9,4044.9,4044.9,4044.9"


def _error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def _bomb(levels: int = 9) -> str:
    """notes: nine-fold aliases nested ``levels`` deep (9**levels strings from ~300 bytes)."""
    lines = ["notes:", '  - &a0 ["x","x","x","x","x","x","x","x","x"]']
    for k in range(1, levels + 1):
        lines.append(f"  - &a{k} [" + ",".join([f"*a{k - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def test_a_yaml_alias_bomb_in_session_notes_is_refused_at_once(tmp_path, capsys):
    session = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--poses", "6"]) == 0
    capsys.readouterr()
    text = (session / "session.yaml").read_text()
    kept = [line for line in text.splitlines(keepends=True) if not line.startswith("notes:")]
    (session / "session.yaml").write_text("".join(kept) + _bomb())
    started = time.perf_counter()
    assert main(["calibrate", str(session), "--out", str(tmp_path / "out"), "--no-report"]) == 2
    assert time.perf_counter() - started < 10
    line = _error(capsys)
    assert "session.yaml" in line and "aliases" in line
    assert not (tmp_path / "out").exists()


def test_a_yaml_alias_bomb_in_a_description_is_refused(tmp_path, capsys):
    text = (DESCRIPTIONS / "stewart.yaml").read_text() + _bomb()
    (tmp_path / "d.yaml").write_text(text)
    assert main(["fk", "--platform", "stewart", "--description", str(tmp_path / "d.yaml"), "--u", U_STEWART]) == 2
    assert "d.yaml" in _error(capsys)


def test_a_few_harmless_aliases_still_load(tmp_path, capsys):
    text = (DESCRIPTIONS / "stewart.yaml").read_text()
    text = text.replace("stroke: [3295.0, 4795.0]", "stroke: *s", 5).replace("stroke: *s", "stroke: &s [3295.0, 4795.0]", 1)
    assert "&s" in text and "*s" in text
    (tmp_path / "d.yaml").write_text(text)
    assert main(["fk", "--platform", "stewart", "--description", str(tmp_path / "d.yaml"), "--u", U_STEWART]) == 0


@pytest.mark.parametrize("stand, good, typo, field", [
    ("stewart", "    offset: 0.0", "    ofset: 0.0", "legs[0].ofset' (did you mean 'offset'?)"),
    ("stewart", "workspace_limits:", "workspace_limit:", "workspace_limit' (did you mean 'workspace_limits'?)"),
    ("psvr", "rod_length:", "rod_lenght:", "rod_lenght' (did you mean 'rod_length'?)"),
    ("psvr", "    zero_count:", "    zero_cont:", "motors[0].zero_cont' (did you mean 'zero_count'?)"),
])
def test_a_typo_in_a_description_field_is_named(tmp_path, capsys, stand, good, typo, field):
    text = (DESCRIPTIONS / f"{stand}.yaml").read_text()
    assert good in text
    (tmp_path / "d.yaml").write_text(text.replace(good, typo, 1))
    assert main(["describe", "--platform", stand, "--description", str(tmp_path / "d.yaml")]) == 2
    line = _error(capsys)
    assert "d.yaml" in line and f"unknown field '{field}" in line


def test_simulate_into_a_folder_holding_a_session_is_refused_unless_forced(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "5", "--poses-only"]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "6", "--poses-only", "--seed", "3"]) == 2
    line = _error(capsys)
    assert "--out" in line and "already holds" in line and "--force" in line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main(["simulate", "--platform", "psvr", "--out", str(out), "--poses", "6", "--poses-only", "--seed", "3",
                 "--force"]) == 0
    assert "--force: writing over" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir()} != before


def test_simulate_into_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    assert main(["simulate", "--platform", "psvr", "--out", str(tmp_path / "f"), "--poses", "5"]) == 2
    assert "is a file" in _error(capsys)


@pytest.mark.parametrize("when", ["2026-02-30", "2026-03-01T25:00:00"])
def test_a_date_that_names_no_day_is_one_line_naming_the_field(tmp_path, capsys, when):
    """YAML builds an unquoted date itself: a day or hour that does not exist is bad input in every
    verb (exit 2, one line with the file, line and field), not a failed computation."""
    session = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--poses", "6", "--poses-only"]) == 0
    capsys.readouterr()
    with open(session / "session.yaml", "a") as f:
        f.write(f"date: {when}\n")
    assert main(["calibrate", str(session), "--out", str(tmp_path / "out"), "--no-report"]) == 2
    line = _error(capsys)
    assert "session.yaml: field 'date': not a valid date" in line and f"{when}' on line " in line
    assert not (tmp_path / "out").exists()


def test_a_date_that_is_no_iso_date_is_refused_by_every_verb_not_only_by_batch(tmp_path, capsys):
    """session.yaml's ``date`` is checked when the session is read, as every other field is."""
    session = tmp_path / "s"
    assert main(["simulate", "--platform", "stewart", "--out", str(session), "--poses", "6", "--poses-only"]) == 0
    capsys.readouterr()
    with open(session / "session.yaml", "a") as f:
        f.write("date: March the first\n")
    assert main(["calibrate", str(session), "--out", str(tmp_path / "out"), "--no-report"]) == 2
    assert "session.yaml: field 'date': expected an ISO date or date-time" in _error(capsys)
    assert not (tmp_path / "out").exists()
