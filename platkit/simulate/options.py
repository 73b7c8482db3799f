"""The choices of an additive simulation, grouped by what they decide.

    PlanOptions        which commands are sent: the plan and how many poses
    TruthOptions       the true stand: how far from nominal, its hidden effects, its markers
    RecordingOptions   how it is recorded: motion-capture rate, noise, occlusion, markers and
                       rigid bodies, how long each command is held, the length unit of the files
    SimulationOptions  the three above, the seed, and raw stream or settled poses, the IMU hook,
                       the settling options, the description file's name

:func:`platkit.simulate.simulate` takes a SimulationOptions, or the flat keywords it always took
(:class:`SimulateKeywords`, each one a field of one of the groups; :func:`options_from_keywords`
maps them), so ``simulate(spec, seed=1, noise_mm=0.1)`` and
``simulate(spec, SimulationOptions(seed=1, recording=RecordingOptions(noise_mm=0.1)))`` are the
same simulation.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np

from platkit.errors import BadInput
from platkit.model import length_scale
from platkit.settle import SettleOptions
from platkit.terms import ModelTerm

__all__ = ["PlanOptions", "TruthOptions", "RecordingOptions", "SimulationOptions", "SimulateKeywords",
           "options_from_keywords"]


@dataclass(frozen=True)
class PlanOptions:
    """The commands sent. ``plan``: 'grid' (snake-ordered grid, about ``n_poses`` points),
    'random', a plan.csv path, a Plan, or an (N, n_u) array of controls in internal units."""

    plan: Any = "grid"
    n_poses: int = 80


@dataclass(frozen=True, eq=False)  # eq=False: markers is an array
class TruthOptions:
    """The true stand behind the session.

    perturbation: scale of the parameter errors drawn around the nominal stand (1: a few mm or
        mrad). terms: [(ModelTerm, theta)] hidden effects with their true parameters; effects:
        [(name, size or None)] effects by name from the effect library (platkit.simulate.effects),
        built on the plan's command rows. markers: (M, 3) m marker positions on the moving part,
        or None to draw ``RecordingOptions.n_markers`` of them.
    """

    perturbation: float = 1.0
    terms: Sequence[tuple[ModelTerm, Any]] = ()
    effects: Sequence[tuple[str, float | None]] = ()
    markers: np.ndarray | None = None


@dataclass(frozen=True)
class RecordingOptions:
    """How the motion is recorded.

    mocap_rate_hz: motion-capture rate (Hz). noise_mm: marker noise per coordinate (mm);
    occlusion: fraction of samples occluded, in [0, 0.5). n_markers: markers on the moving part
    (M1, M2, ...; ignored when TruthOptions.markers is given). n_base_markers: markers fixed on
    the base (B1, B2, ...), which pin the base-to-mocap transform. n_bodies: rigid bodies
    measured in 6 DOF on the moving part (T1, T2, ...), each sample with per-axis noise
    body_noise_mm on its origin and body_noise_deg on its orientation. hold_s: how long the
    stand holds each command after arriving (s). length_unit: the unit of the files ('mm', 'm').
    """

    mocap_rate_hz: float = 100.0
    noise_mm: float = 0.2
    occlusion: float = 0.02
    n_markers: int = 5
    n_base_markers: int = 0
    n_bodies: int = 0
    body_noise_mm: float = 0.1
    body_noise_deg: float = 0.05
    hold_s: float = 1.5
    length_unit: str = "mm"

    def check(self) -> None:
        """BadInput for a unit, noise or occlusion out of range."""
        length_scale(self.length_unit)
        if self.noise_mm < 0 or not 0 <= self.occlusion < 0.5:
            raise BadInput("noise must be >= 0 and occlusion in [0, 0.5)")


@dataclass(frozen=True)
class SimulationOptions:
    """Everything an additive simulation is drawn from.

    seed: the random stream of the whole session. raw: simulate the motion-capture stream and
    settle it (realistic); False draws settled poses directly. imu: optional callable
    ``imu(trajectory, rng) -> dict(t=(J,), gyr=(J, 3), acc=(J, 3)[, entry])`` that adds an
    inertial stream (raw only), e.g. :func:`platkit.inertial.simulate.imu_for_trajectory`.
    settle: options of the settling of the raw stream. description: the description file's
    name, recorded with the poses.
    """

    seed: int = 0
    plan: PlanOptions = field(default_factory=PlanOptions)
    truth: TruthOptions = field(default_factory=TruthOptions)
    recording: RecordingOptions = field(default_factory=RecordingOptions)
    raw: bool = True
    imu: Callable | None = None
    settle: SettleOptions | None = None
    description: str | None = None


class SimulateKeywords(TypedDict, total=False):
    """The flat keywords of :func:`platkit.simulate.simulate`, each a field of one group."""

    seed: int
    n_poses: int
    plan: Any
    noise_mm: float
    occlusion: float
    n_markers: int
    raw: bool
    terms: Sequence[tuple[ModelTerm, Any]]
    effects: Sequence[tuple[str, float | None]]
    mocap_rate_hz: float
    hold_s: float
    length_unit: str
    imu: Callable | None
    perturbation: float
    markers: np.ndarray | None
    settle_options: SettleOptions | None
    description: str | None
    n_base_markers: int
    n_bodies: int
    body_noise_mm: float
    body_noise_deg: float


#: which group each flat keyword belongs to ('' for SimulationOptions itself), and its field there
KEYWORD_FIELDS: dict[str, tuple[str, str]] = {
    "seed": ("", "seed"), "raw": ("", "raw"), "imu": ("", "imu"), "settle_options": ("", "settle"),
    "description": ("", "description"),
    **{k: ("plan", k) for k in ("plan", "n_poses")},
    **{k: ("truth", k) for k in ("perturbation", "terms", "effects", "markers")},
    **{f.name: ("recording", f.name) for f in dataclasses.fields(RecordingOptions)},
}


def options_from_keywords(base: SimulationOptions | None = None, **keywords: Any) -> SimulationOptions:
    """``base`` (default: the defaults) with the flat keywords of :func:`simulate` applied;
    TypeError naming an unknown keyword, as a Python call does."""
    base = SimulationOptions() if base is None else base
    unknown = sorted(set(keywords) - set(KEYWORD_FIELDS))
    if unknown:
        raise TypeError(f"simulate() got an unexpected keyword argument {unknown[0]!r}")
    top: dict[str, Any] = {}
    groups: dict[str, dict[str, Any]] = {"plan": {}, "truth": {}, "recording": {}}
    for key, value in keywords.items():
        group, name = KEYWORD_FIELDS[key]
        (groups[group] if group else top)[name] = value
    for group, changes in groups.items():
        if changes:
            top[group] = dataclasses.replace(getattr(base, group), **changes)
    return dataclasses.replace(base, **top)
