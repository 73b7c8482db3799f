"""The history of one stand (platkit.batch.history): a step in one parameter is flagged in the
session it happens, nothing else is, and dates from session.yaml order the sessions."""
from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
import yaml

from platkit.batch.history import session_date, stand_history
from platkit.errors import BadInput
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
