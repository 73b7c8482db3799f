"""The history of one stand (platkit.batch.history): a step in one parameter is flagged in the
session it happens, nothing else is, and dates from session.yaml order the sessions."""
from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
import yaml

from platkit.batch.history import (
    check_one_stand,
    history_order,
    read_maintenance,
    session_date,
    session_when,
    stand_history,
)
from platkit.errors import BadInput, BadSession
from platkit.io.session_yaml import read_session_yaml


def tables(n: int, step_at: int | None, step: float, seed: int = 0) -> list[dict]:
    """n calibrations of 20 parameters with std 0.2 and noise to match; parameter p3 jumps by
    ``step`` from session ``step_at`` on; p7 is held at nominal in every other session."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t = {}
        for j in range(20):
            v = 10.0 * j + 0.2 * rng.normal() + (step if j == 3 and step_at is not None and i >= step_at else 0.0)
            held = j == 7 and i % 2
            t[f"p{j}"] = {"value": v, "std": None if held else 0.2, "nominal": 10.0 * j, "unit": "mm",
                          "status": "held_at_nominal" if held else "estimated"}
        out.append(t)
    return out


def test_a_step_is_flagged_in_the_session_it_happens_and_only_there():
    h = stand_history([f"m{i:02d}" for i in range(12)], tables(12, 7, 2.0), [None] * 12)
    assert [(f["parameter"], f["session"]) for f in h["changes"]] == [("p3", "m07")]
    f = h["changes"][0]
    assert f["change"] == pytest.approx(2.0, abs=0.4) and f["z"] > h["z_critical"]
    assert h["dispersion_k"] == pytest.approx(1.0, abs=0.3)
    assert h["parameters"]["p7"]["value"][1] is None  # held: no value in the history


def test_no_change_no_flag_and_a_small_step_within_the_noise_is_not_flagged():
    assert stand_history([f"m{i}" for i in range(12)], tables(12, None, 0.0, seed=1), [None] * 12)["changes"] == []
    assert stand_history([f"m{i}" for i in range(12)], tables(12, 6, 0.3, seed=2), [None] * 12)["changes"] == []


def test_a_drift_gives_a_trend_with_its_std():
    t = tables(10, None, 0.0, seed=3)
    for i, row in enumerate(t):
        row["p5"]["value"] += 0.1 * i  # 0.1 mm per session, slow
    h = stand_history([f"m{i}" for i in range(10)], t, [None] * 10)
    e = h["parameters"]["p5"]
    assert e["trend_per_step"] == pytest.approx(0.1, abs=3 * e["trend_std"])
    assert 0 < e["trend_std"] < 0.05


def test_dates_come_from_session_yaml(tmp_path):
    for name, date in (("a", "2026-03-01"), ("b", None)):
        (tmp_path / name).mkdir()
        data = {"platform": "rotary", "units": {"length": "mm", "time": "s"}}
        if date:
            data["date"] = date
        (tmp_path / name / "session.yaml").write_text(yaml.safe_dump(data))
    assert session_date(tmp_path / "a") == dt.date(2026, 3, 1)
    assert read_session_yaml(tmp_path / "a")["platform"] == "rotary"  # the verbs accept the field
    assert session_date(tmp_path / "b") is None
    (tmp_path / "a" / "session.yaml").write_text("platform: rotary\ndate: March\n")
    with pytest.raises(BadInput, match="date"):
        session_date(tmp_path / "a")
    h = stand_history(["x", "y", "z"], tables(3, None, 0.0), [dt.date(2026, 1, 1), dt.date(2026, 1, 31), dt.date(2026, 3, 2)])
    assert h["time"] == [0.0, 30.0, 60.0] and h["time_axis"].startswith("days")


def test_sessions_of_one_day_are_ordered_by_time_else_by_folder_name(tmp_path):
    whens = {"b": "2026-03-01T09:30", "a": "2026-03-01T14:00", "c": "2026-03-01", "d": "2026-03-01",
             "e": "2026-02-27"}
    for name, when in whens.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "session.yaml").write_text(f"platform: rotary\ndate: {when}\n")
    names = sorted(whens)
    ws = [session_when(tmp_path / n) for n in names]
    order, axis = history_order(names, ws)
    assert [names[i] for i in order] == ["e", "b", "a", "c", "d"] and axis.startswith("days")
    assert ws[names.index("b")] == dt.datetime(2026, 3, 1, 9, 30)
    # several sessions on one day: a history with a time axis and no singular trend
    ordered = [ws[i] for i in order]
    h = stand_history([names[i] for i in order], tables(5, None, 0.0, seed=4), ordered)
    assert h["time"][:3] == [0.0, pytest.approx(2 + 9.5 / 24), pytest.approx(2 + 14 / 24)]
    assert h["time"][3] == h["time"][4] == 2.0 and h["changes"] == []
    same_day = [dt.date(2026, 3, 1)] * 4
    h = stand_history(list("wxyz"), tables(4, None, 0.0, seed=5), same_day)  # no time spread: no trend
    assert "trend_per_step" not in h["parameters"]["p1"]


def test_an_invalid_date_is_one_line_naming_the_file_and_the_field(tmp_path):
    for text in ("date: 2026-02-30\n", "date: March\n", "date: 2026-13-01T10:00\n"):
        (tmp_path / "session.yaml").write_text("platform: rotary\n" + text)
        with pytest.raises(BadSession) as err:
            session_when(tmp_path)
        assert str(tmp_path / "session.yaml") in str(err.value) and "field 'date'" in str(err.value)
        assert "\n" not in str(err.value)


def test_a_history_follows_one_stand():
    check_one_stand([("stewart", "d1")] * 3, ["m1", "m2", "m3"])
    with pytest.raises(BadInput, match="a history follows one stand: m1 is stewart .* m3 is psvr"):
        check_one_stand([("stewart", "d1"), ("stewart", "d1"), ("psvr", "d2")], ["m1", "m2", "m3"])
    with pytest.raises(BadInput, match="a different description"):
        check_one_stand([("stewart", "d1"), ("stewart", "d2")], ["m1", "m2"])


def test_maintenance_starts_a_new_run_and_is_said(tmp_path):
    dates = [dt.date(2026, m, 1) for m in range(1, 13)]
    log = tmp_path / "maintenance.yaml"
    log.write_text("- {date: 2026-07-01, note: leg L4 replaced}\n- {date: 2026-12-15, note: cleaned}\n")
    events = read_maintenance(log)
    assert [e["note"] for e in events] == ["leg L4 replaced", "cleaned"]
    t = tables(12, 6, 2.0)  # p3 steps at the seventh month, the day of the event
    h = stand_history([f"m{i:02d}" for i in range(12)], t, dates, events=events)
    assert h["changes"] == []  # explained by the event: said, not flagged
    assert h["events"][0] == {"date": "2026-07-01", "note": "leg L4 replaced", "before_session": "m06"}
    assert h["events"][1]["before_session"] is None
    assert h["z"][6][3] is None  # the first session after the event is not tested against those before
    without = stand_history([f"m{i:02d}" for i in range(12)], t, dates)
    assert [(f["parameter"], f["session"]) for f in without["changes"]] == [("p3", "m06")]
    log.write_text("- {date: 2026-07-01}\n")
    with pytest.raises(BadInput, match="maintenance.yaml: event 1: needs a 'date' and a 'note'"):
        read_maintenance(log)
    log.write_text("- {date: July, note: x}\n")
    with pytest.raises(BadInput, match="maintenance.yaml: field 'date' of event '1'"):
        read_maintenance(log)
    with pytest.raises(BadInput, match="placed by date"):
        stand_history(["a", "b"], tables(2, None, 0.0), [None, None], events=events)


def test_parameters_a_session_did_not_identify_are_tested_only_where_identified():
    t = tables(6, None, 0.0, seed=6)
    for i in (2, 3):
        t[i]["p5"].update(std=None, status="held_at_nominal")
    h = stand_history([f"m{i}" for i in range(6)], t, [None] * 6)
    assert h["parameters"]["p5"]["not_identified_in"] == ["m2", "m3"]
    assert h["tested_on"]["not_identified_in"]["p5"] == ["m2", "m3"]
    assert h["z"][2][5] is None and h["z"][4][5] is not None  # m4 against m0, m1


def test_history_refuses_before_any_work_a_bad_date_or_two_stands(tmp_path, capsys):
    from platkit.cli import main

    pytest.importorskip("dask.distributed")
    for name, platform, date in (("m1", "rotary", "2026-01-01"), ("m2", "rotary", "2026-02-30")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "session.yaml").write_text(f"platform: {platform}\nunits: {{length: mm}}\ndate: {date}\n")
    argv = ["batch", "calibrate", str(tmp_path / "m*"), "--history", "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / 'm2' / 'session.yaml'}: field 'date'" in err[0]
    (tmp_path / "m2" / "session.yaml").write_text("platform: psvr\nunits: {length: mm}\ndate: 2026-02-01\n")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a history follows one stand: m1 is rotary" in err[0]
    assert not (tmp_path / "out").exists()  # nothing written
