"""Nuisances of a recording, drawn per session from its seed and written to its truth.

Nothing here is a property of the stand: how long each command is held, how the actuators'
drives are tuned (time constants, damping, rate and acceleration limits), how noisy the motion
capture is and with what colour (white plus a correlated first-order part per marker
coordinate), bursts of occlusion, the motion capture's latency and the offset between the
command logger's clock and the motion capture's.

    nuisances = draw_nuisances(spec, np.random.default_rng([seed, 11]))
    nuisances.to_dict()         # what truth.yaml records

Every field can be fixed by the caller (``draw_nuisances(..., hold_s=2.5, noise_mm=0.2)``);
the rest are drawn. SI inside (m, s); names say where a unit is not SI.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from platkit.calibrate.plan_information import planning_bounds
from platkit.errors import BadInput
from platkit.model import PlatformSpec
from platkit.simulate.actuator import ActuatorResponse

__all__ = ["Nuisances", "draw_nuisances", "occlusion_mask", "coloured_noise"]

#: ranges the draws come from (uniform): hold after arrival (s), actuator time constant (s),
#: damping, time for a full stroke at the rate limit (s), time to reach the rate (s), white and
#: correlated noise (mm, per coordinate and sample), correlation time (s), occluded share,
#: mean burst (s), latency (s), clock offset (s)
RANGES = {
    "hold_s": (2.0, 3.0),
    "tau_s": (0.04, 0.09),
    "damping": (1.0, 1.3),
    "damping_overshoot": (0.55, 0.8),
    "stroke_time_s": (3.0, 5.0),
    "accel_time_s": (0.15, 0.35),
    "noise_mm": (0.1, 0.25),
    "coloured_share": (0.05, 0.4),
    "correlation_s": (0.03, 0.3),
    "occlusion": (0.0, 0.03),
    "burst_s": (0.05, 0.3),
    "latency_s": (0.0, 0.02),
    "clock_offset_s": (-0.15, 0.15),
}


@dataclass
class Nuisances:
    """One session's nuisances (SI).

    hold_s: typical hold after arrival (s); hold_jitter: relative jitter of each hold;
    response: the actuators' :class:`ActuatorResponse`; noise_m: white marker noise per
    coordinate and sample (m); coloured_m: standard deviation of the correlated part (m) with
    correlation time correlation_s (s); occlusion: share of samples occluded, in bursts of mean
    length burst_s (s); latency_s: the motion capture stamps a sample this long after its
    exposure; clock_offset_s: markers.csv's clock minus commands.csv's.
    """

    hold_s: float
    hold_jitter: float
    response: ActuatorResponse
    noise_m: float
    coloured_m: float
    correlation_s: float
    occlusion: float
    burst_s: float
    latency_s: float
    clock_offset_s: float
    control_names: list[str] = field(default_factory=list)

    @property
    def time_shift_s(self) -> float:
        """markers.csv's time of a sample minus the commands clock's time of its exposure."""
        return self.latency_s + self.clock_offset_s

    def to_dict(self) -> dict:
        return {
            "hold_s": float(self.hold_s),
            "hold_jitter": float(self.hold_jitter),
            "actuators": self.response.to_dict(self.control_names),
            "marker_noise_white_m": float(self.noise_m),
            "marker_noise_coloured_m": float(self.coloured_m),
            "marker_noise_correlation_s": float(self.correlation_s),
            "occlusion": float(self.occlusion),
            "occlusion_burst_s": float(self.burst_s),
            "mocap_latency_s": float(self.latency_s),
            "clock_offset_s": float(self.clock_offset_s),
            "markers_time_minus_exposure_time_s": float(self.time_shift_s),
        }


def _draw(rng, key, fixed):
    lo, hi = RANGES[key]
    return float(rng.uniform(lo, hi)) if fixed is None else float(fixed)


def draw_nuisances(spec: PlatformSpec, rng: np.random.Generator, *, hold_s: float | None = None,
                   noise_mm: float | None = None, occlusion: float | None = None, overshoot: bool = False,
                   latency_s: float | None = None, clock_offset_s: float | None = None,
                   coloured: bool = True) -> Nuisances:
    """A session's nuisances: every field given is kept, the others drawn from ``rng`` in
    :data:`RANGES`. ``overshoot``: damping drawn below 1 (the drives overshoot their commands);
    ``coloured``: False leaves only white noise."""
    n = spec.n_u
    lo, hi = planning_bounds(spec)  # a control without a finite stroke: one turn either way, as it is planned
    span = hi - lo
    # every draw is made, fixed or not, so fixing one field leaves the others as they were
    draws = {k: rng.uniform(*RANGES[k], size=n) for k in ("tau_s", "stroke_time_s", "accel_time_s")}
    draws["damping"] = rng.uniform(*RANGES["damping_overshoot" if overshoot else "damping"], size=n)
    rate = span / draws["stroke_time_s"]
    response = ActuatorResponse(tau_s=draws["tau_s"], damping=draws["damping"], rate=rate,
                                accel=rate / draws["accel_time_s"])
    values = {k: _draw(rng, k, None) for k in ("hold_s", "noise_mm", "coloured_share", "correlation_s", "occlusion",
                                             "burst_s", "latency_s", "clock_offset_s")}
    hold = values["hold_s"] if hold_s is None else float(hold_s)
    noise = values["noise_mm"] if noise_mm is None else float(noise_mm)
    occ = values["occlusion"] if occlusion is None else float(occlusion)
    if not hold > 0:
        raise BadInput(f"hold must be positive, got {hold:g} s")
    if not noise >= 0:
        raise BadInput(f"marker noise must be 0 or more, got {noise:g} mm")
    if not 0 <= occ < 0.5:
        raise BadInput(f"occlusion must be a fraction in [0, 0.5), got {occ:g}")
    return Nuisances(
        hold_s=hold, hold_jitter=0.05, response=response, noise_m=noise * 1e-3,
        coloured_m=(values["coloured_share"] * noise * 1e-3) if coloured else 0.0,
        correlation_s=values["correlation_s"], occlusion=occ, burst_s=values["burst_s"],
        latency_s=values["latency_s"] if latency_s is None else float(latency_s),
        clock_offset_s=values["clock_offset_s"] if clock_offset_s is None else float(clock_offset_s),
        control_names=list(spec.control_names))


def occlusion_mask(rng: np.random.Generator, K: int, M: int, fraction: float, mean_burst: int) -> np.ndarray:
    """(K, M) True where occluded: per marker, alternating visible and occluded runs with
    geometric lengths, occluded runs of mean ``mean_burst`` samples, about ``fraction`` of all."""
    out = np.zeros((K, M), bool)
    if fraction <= 0 or K == 0:
        return out
    mean_burst = max(int(mean_burst), 1)
    mean_visible = mean_burst * (1 - fraction) / fraction
    for m in range(M):
        k = int(rng.geometric(1.0 / (mean_visible + 1)))
        while k < K:
            length = int(rng.geometric(1.0 / mean_burst))
            out[k:k + length, m] = True
            k += length + int(rng.geometric(1.0 / (mean_visible + 1)))
    return out


def coloured_noise(rng: np.random.Generator, shape: tuple[int, ...], dt: float, sigma: float,
                   correlation_s: float) -> np.ndarray:
    """First-order (AR(1)) noise along axis 0 of ``shape``: stationary standard deviation
    ``sigma`` from the first sample on, correlation exp(-lag / correlation_s)."""
    if sigma <= 0:
        return np.zeros(shape)
    a = float(np.exp(-dt / correlation_s))
    e = rng.normal(size=shape) * sigma * np.sqrt(1 - a * a)
    e[0] = rng.normal(size=shape[1:]) * sigma  # x_0 from the stationary law; x_k = a x_(k-1) + e_k
    return lfilter([1.0], [1.0, -a], e, axis=0)
