"""batch calibrate's choice of free groups where sessions are calibrated from motion (their holds
never settle, too few settled, or none): such a session chooses no groups, as platkit calibrate's
motion path does not, and takes the others' choice; a fleet of them all takes the stand's
defaults, never a refusal (platkit.commands.batch.select_groups, _union_of_chosen)."""
from __future__ import annotations

from types import SimpleNamespace

from platkit.commands.batch import _union_of_chosen, default_options, select_groups
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def test_a_session_without_holds_chooses_no_groups_and_says_why(tmp_path):
    sim = simulate_physics(get_platform("rotary"), seed=4101, motion="multisine", duration_s=8.0, mocap_rate_hz=50.0)
    folder = write_physical_session(sim, tmp_path / "moving")
    out = select_groups(default_options("calibrate"), str(folder), "moving")
    assert out["chosen"] is None
    assert "gave no settled pose" in out["motion"] or "gave a pose" in out["motion"]


def test_sessions_from_motion_take_the_others_choice_or_the_stand_defaults():
    spec = get_platform("rotary")
    said: list[str] = []
    runs = [SimpleNamespace(name=n) for n in ("a", "b", "c")]
    cache = {"a": {"chosen": ["offset"]}, "b": {"chosen": None, "motion": "no holds"},
             "c": {"chosen": ["offset", "origin"]}}
    free, how = _union_of_chosen(spec, runs, cache, said.append)
    assert free == ["offset", "origin"] and "offset in 2 of 3" in how
    assert said and "1 of 3 sessions are calibrated from motion" in said[0] and "b: no holds" in said[0]
    said.clear()
    all_motion = {k: {"chosen": None, "motion": "no holds"} for k in ("a", "b", "c")}
    free, how = _union_of_chosen(spec, runs, all_motion, said.append)
    assert free is None and "default free parameters" in how and "3 of 3" in said[0]
