"""The true stand behind a simulated session: parameters drawn near the nominal ones, the
motion capture's placement, and the command plan. Shared by the additive simulator
(platkit.simulate) and the physical one (platkit.simulate.physics)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from platkit.calibrate.plan import Plan, grid_plan_for, random_candidates, read_plan_csv
from platkit.geometry import matrix_from_rpy, transform
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec

__all__ = ["PERTURBATION", "RELATIVE_PERTURBATION", "perturb_parameters", "random_mocap_from_base", "make_plan"]

#: how hard the parameters of a true stand differ from nominal, by unit (1 sigma)
PERTURBATION = {"m": 2e-3, "rad": 2e-3}
RELATIVE_PERTURBATION = 1e-3  # other units: this fraction of the nominal value (or absolute if 0)


def perturb_parameters(spec: PlatformSpec, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """True parameters: nominal + Gaussian errors (2 mm for lengths, 2 mrad for angles, 0.1%
    of the value otherwise), fixed parameters untouched, clipped to the parameters' bounds."""
    td = spec.nominal_td().copy()
    for i, p in enumerate(spec.parameters):
        if not p.free:
            continue
        sd = PERTURBATION.get(p.unit)
        if sd is None:
            sd = RELATIVE_PERTURBATION * (abs(p.nominal) if p.nominal != 0 else 1.0)
        td[i] = np.clip(p.nominal + scale * sd * rng.normal(), p.lower, p.upper)
    return td


def random_mocap_from_base(rng: np.random.Generator, size_m: float, tilt_rad: float = 3e-3) -> np.ndarray:
    """(4, 4) a motion-capture frame: any heading, tilt of ``tilt_rad`` (1 sigma) about x and y,
    offset by about the stand's size ``size_m`` (m)."""
    R = matrix_from_rpy(rng.normal(0, tilt_rad), rng.normal(0, tilt_rad), rng.uniform(-np.pi, np.pi))
    t = rng.uniform(-1, 1, 3) * np.array([2.0, 2.0, 0.5]) * max(size_m, 0.2)
    return transform(R, t)


def make_plan(spec: PlatformSpec, plan: Any, n_poses: int, rng: np.random.Generator, model: PlatformModel,
              length_unit: str) -> tuple[np.ndarray, dict]:
    """(N, n_u) commands in internal units and what the plan was, from ``plan``: 'grid'
    (snake-ordered, about n_poses points), 'random', a Plan, an (N, n_u) array, or a plan.csv
    path in ``length_unit``. Every kind is checked against the strokes once, under platkit.limits'
    policy: a file's rows by the file's reader (named by file, row and column), the others here."""
    if isinstance(plan, Plan):
        return model.check_controls(plan.controls), {"kind": plan.kind, **plan.info}
    if isinstance(plan, np.ndarray):
        return model.check_controls(np.atleast_2d(plan).astype(float)), {"kind": "given"}
    if plan in (None, "grid"):
        p = grid_plan_for(spec, n_poses, model=model)
        return model.check_controls(p.controls), {"kind": "grid", **p.info}
    if plan == "random":
        p = random_candidates(spec, n_poses, rng, model=model)
        return model.check_controls(p.controls), {"kind": "random"}
    path = Path(str(plan))
    return read_plan_csv(path, spec, length_unit), {"kind": "file", "file": str(path)}
