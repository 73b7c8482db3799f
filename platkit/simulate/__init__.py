"""Simulated calibration sessions for any registered stand, with a known truth.

Two simulators. :func:`simulate` is the additive one (fast, the default of ``platkit simulate``;
platkit.simulate.additive): hidden effects are the model terms diagnosis fits, added to the
controls, the pose or the markers. :func:`platkit.simulate.physics.simulate_physics`
(``--physics``) plays the stand's physics out in time instead (docs/simulation.md). Both take
effects by name from the effect library (platkit.simulate.effects): one implementation per
effect, its plugin's. Hidden effects also enter as model terms (platkit.terms.ModelTerm) with
their true parameters: ``terms=[(term, theta), ...]``.

    sim = simulate(spec, seed=1, n_poses=60)           # in memory: sim.poses, sim.truth
    sim = simulate(spec, SimulationOptions(seed=1, plan=PlanOptions(n_poses=60)))   # the same
    simulate_session(spec, "out/session", seed=1)      # a session folder with truth.yaml

The modules: options (what a simulation is drawn from, grouped: PlanOptions, TruthOptions,
RecordingOptions, SimulationOptions), additive (:func:`simulate` and its steps), results
(Simulation, Truth, Trajectory), write (:func:`write_session`), physics (the time-domain
simulator), and the pieces both share (stand, effects, files, actuator, nuisance, rigid_bodies).

Only the PlatformSpec / PlatformModel API is used: nothing here knows a particular stand.
"""
from __future__ import annotations

from pathlib import Path

from platkit.model import PlatformSpec
from platkit.plugins import get_platform
from platkit.simulate.additive import (
    _commands_poseset,  # noqa: F401 - the tests build commands with it
    simulate,
)
from platkit.simulate.options import (
    PlanOptions,
    RecordingOptions,
    SimulateKeywords,
    SimulationOptions,
    TruthOptions,
    options_from_keywords,
)
from platkit.simulate.physics import PhysicalSession, simulate_physics, write_physical_session
from platkit.simulate.results import Simulation, Trajectory, Truth
from platkit.simulate.stand import perturb_parameters, random_mocap_from_base
from platkit.simulate.write import write_session

__all__ = ["Truth", "Simulation", "Trajectory", "simulate", "simulate_session", "write_session", "perturb_parameters",
           "random_mocap_from_base", "PhysicalSession", "simulate_physics", "write_physical_session",
           "SimulationOptions", "PlanOptions", "TruthOptions", "RecordingOptions", "SimulateKeywords",
           "options_from_keywords"]


def simulate_session(spec: PlatformSpec | str, out: str | Path, *, poses_only: bool = False,
                     description: str | Path | None = None, moving_link: str | None = None,
                     base_link: str | None = None, **kwargs) -> Path:
    """Simulate (see :func:`simulate`) and write a session folder; returns its path. ``spec``
    may be a stand name (built with ``description`` and the link options)."""
    if isinstance(spec, str):
        options = {k: v for k, v in (("moving_link", moving_link), ("base_link", base_link)) if v is not None}
        spec = get_platform(spec, description, **options)
    if poses_only:
        kwargs["raw"] = False
    sim = simulate(spec, description=None if description is None else Path(description).name, **kwargs)
    return write_session(sim, out, poses_only=poses_only, description=description, moving_link=moving_link,
                         base_link=base_link)
