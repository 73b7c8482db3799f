"""Physics the effect library does not hold, for the tests that diagnosis says `unexplained` of it
and the proofs (benchmarks/diagnosis_proof_physical.py): known to the physical simulator only,
never to diagnose's library. A test passes it to the simulator through a plugin host of its own
(``simulate_physics(..., library=library_with(OutsideEffect(name, cls)))``); the proof benchmark,
whose Dask workers build their own simulations, lets the simulator's lookup play it:

    from outside_plugins.outside_physics import with_outside_physics   # tests/ on the path
    with_outside_physics()          # platkit.simulate.physics now plays 'plate_flex', 'frame_wobble'
"""
from __future__ import annotations

import numpy as np

import platkit.simulate.physics as physics_module
from platkit.effects import EffectPhysics

#: physics the effect library does not hold (known to the simulator only, once with_outside_physics ran)
OUTSIDE = ["plate_flex", "frame_wobble"]

class PlateFlex(EffectPhysics):
    """The marker plate is not rigid: as the stand leaves its neutral command, each marker moves
    along the moving frame's z by ``size`` mm times its own sign and share, times the squared
    distance of the command in force from neutral (half strokes). No library effect moves the
    markers against each other with the pose."""

    effect = "plate_flex"

    def __init__(self, size: float, rng: np.random.Generator, plan):
        self.amplitude_m = size * 1e-3
        self.share = rng.choice([-1.0, 1.0], len(plan.marker_names)) * rng.uniform(0.5, 1.0, len(plan.marker_names))
        lo, hi = plan.spec.control_bounds()
        self.mid, self.half = 0.5 * (lo + hi), 0.5 * (hi - lo)

    def parameters(self):
        return {"amplitude_m": self.amplitude_m, "share": self.share.tolist()}

    def marker_offsets(self, t, plan):
        seg = np.searchsorted(plan.command_t, t, side="right") - 1
        u = np.where(seg[:, None] >= 0, plan.commands[np.maximum(seg, 0)], plan.start[None])
        reach = np.mean(((u - self.mid) / self.half) ** 2, axis=1)
        out = np.zeros((len(t), len(self.share), 3))
        out[:, :, 2] = self.amplitude_m * reach[:, None] * self.share[None]
        return out


class FrameWobble(EffectPhysics):
    """Every marker sways with time along one direction of the moving frame, ``size`` mm times
    sin(2 pi t / T), T drawn in 40-120 s (an air-conditioning cycle swinging the marker mount):
    periodic in time, where the library's drifts are monotone and its slips are steps."""

    effect = "frame_wobble"

    def __init__(self, size: float, rng: np.random.Generator, plan):
        self.amplitude_m = size * 1e-3
        self.period_s = float(rng.uniform(40.0, 120.0))
        self.phase = float(rng.uniform(0, 2 * np.pi))
        d = rng.normal(size=3)
        self.direction = d / np.linalg.norm(d)

    def parameters(self):
        return {"amplitude_m": self.amplitude_m, "period_s": self.period_s, "direction": self.direction.tolist()}

    def marker_offsets(self, t, plan):
        wave = self.amplitude_m * np.sin(2 * np.pi * np.asarray(t) / self.period_s + self.phase)
        return np.broadcast_to(wave[:, None, None] * self.direction[None, None], (len(t), len(plan.marker_names), 3)).copy()


#: the out-of-library physics by name (what with_outside_physics lets the simulator play)
OUTSIDE_PHYSICS = {"plate_flex": PlateFlex, "frame_wobble": FrameWobble}


class OutsideEffect:
    """Known to the simulator of this benchmark only: diagnose's library never sees it."""

    def __init__(self, name: str, cls):
        self.name, self.cls = name, cls

    def physics(self, spec, size, rng, plan):
        return self.cls(1.0 if size is None else size, rng, plan)


def with_outside_physics() -> None:
    """Let the simulator (only: platkit.simulate.physics's own lookup) play the out-of-library physics.
    Called in every task, since a Dask worker process does not run this module's top level."""
    if getattr(physics_module, "_proof_outside", False):
        return
    library = physics_module.effect_library
    outside = {name: OutsideEffect(name, cls) for name, cls in OUTSIDE_PHYSICS.items()}
    physics_module.effect_library = lambda: {**library(), **outside}
    physics_module._proof_outside = True
