"""Each fit of a calibration from motion tells its progress the response's kind it fits
(platkit.calibrate.motion_kind.fit_progress), and calibrate's progress lines say that kind
(platkit.commands.calibrate.motion_progress_printer): before, the printer inferred it from the
fit's count of unknowns."""
from __future__ import annotations

import io

from platkit.calibrate.motion import calibrate_motion
from platkit.calibrate.motion_kind import fitted_kind
from platkit.calibrate.response import ResponseModel
from platkit.commands.calibrate import motion_progress_printer
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.simulate.physics import simulate_physics, write_physical_session


def test_each_motion_fit_tells_its_response_kind(tmp_path):
    """An 8 s multisine stream of the stewart stand (seed 4101): the first order fitted, the second
    tried from it twice; every event of each fit carries its kind, and the printer says it."""
    spec = get_platform("stewart")
    sim = simulate_physics(spec, seed=4101, motion="multisine", duration_s=8.0, mocap_rate_hz=50.0)
    write_physical_session(sim, tmp_path / "session")
    session = load_session(tmp_path / "session", quiet=True)
    events: list[tuple[str, dict]] = []
    calibrate_motion(session, session.spec, progress=lambda stage, info: events.append((stage, info)))
    fits = [info for stage, info in events if stage in ("identifiability", "done")]
    assert fits and all("response_kind" in info for info in fits)
    kinds = [info["response_kind"] for stage, info in events if stage == "identifiability"]
    assert kinds[0] == "first_order" and set(kinds[1:]) == {"second_order"}
    out = io.StringIO()
    show = motion_progress_printer("mm", "auto", out)
    for stage, info in events:
        show(stage, info)
    said = [line for line in out.getvalue().splitlines() if " -> " in line]
    assert len(said) == len(kinds)
    assert said[0].startswith("calibrate: fit 1 (first-order response) rms ")
    assert all(f"fit {k + 2} (second-order response) rms " in line for k, line in enumerate(said[1:]))


def test_the_printer_says_the_kind_each_fit_tells():
    """The label follows the event's kind, not its unknowns (here the same for every fit: an
    inference from them called all three first order)."""
    out = io.StringIO()
    show = motion_progress_printer("mm", "auto", out)
    for kind in ("first_order", "per_actuator", "second_order"):
        show("identifiability", {"n_identifiable": 40, "held": ["p0"], "response_kind": kind})
        show("done", {"rms_before": 2e-3, "rms_after": 1e-3, "time_s": 1.0, "response_kind": kind})
    said = [line for line in out.getvalue().splitlines() if " -> " in line]
    assert said == ["calibrate: fit 1 (first-order response) rms 2 -> 1 mm from its own start, in 1.00 s",
                    "calibrate: fit 2 (second-order response for some actuators) rms 2 -> 1 mm from its own start, "
                    "in 1.00 s",
                    "calibrate: fit 3 (second-order response) rms 2 -> 1 mm from its own start, in 1.00 s"]


def test_a_fit_kind_names_the_response_model():
    assert fitted_kind(ResponseModel("first_order", "step", 3)) == "first_order"
    assert fitted_kind(ResponseModel("second_order", "step", 3)) == "second_order"
    assert fitted_kind(ResponseModel("second_order", "step", 3, first=(1,))) == "per_actuator"
