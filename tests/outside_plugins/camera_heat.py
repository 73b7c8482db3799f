"""An outside recording artefact: one marker's image drifts as the motion-capture camera warms up.

The marker does not move on the platform: the camera that sees it does, a little, as it heats
(a marker near the camera's own warm housing, say). Its apparent offset follows the camera's
temperature, which rises from switch-on towards its steady value with the time constant TAU_S:

    marker m seen at  x_m + d (1 - exp(-t / TAU_S)),   t the time since the session's first command

so ``recording`` is True: diagnosis fits d so that the geometry sees corrected data, and the
stand's calibration leaves the term out (the marker stays where it is on the platform)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import Effect, SizeHelp, history, stored_number, stored_where
from platkit.hookspecs import hookimpl
from platkit.terms import ModelTerm

#: the camera's warm-up time constant, s
TAU_S = 60.0


def warmth(t: np.ndarray) -> np.ndarray:
    """The camera's warm-up at times ``t`` (s since the first command): 0 at switch-on, -> 1."""
    return 1.0 - np.exp(-np.asarray(t, float) / TAU_S)


@dataclass
class CameraHeatTerm(ModelTerm):
    marker: int = 0

    def marker_offset(self, theta, poses, *args):
        out = np.zeros((poses.n_poses, poses.n_markers, 3))
        out[:, self.marker] = warmth(history(poses, "elapsed"))[:, None] * np.asarray(theta, float)[None, :3]
        return out


class CameraHeat(Effect):
    name = "camera_heat"
    summary = "a marker's image drifts as the motion-capture camera warms up"
    recording = True
    simulation_size = SizeHelp("the drift of a random marker's image once the camera is warm", "mm")

    def term(self, marker_name: str, m: int) -> CameraHeatTerm:
        return CameraHeatTerm(self.name, ["dx", "dy", "dz"], np.zeros(3), ["m"] * 3,
                              {"marker": str(marker_name), "marker_index": int(m), "tau_s": TAU_S}, marker=int(m))

    def candidates(self, spec, poses, residuals=None):
        return [self.term(name, m) for m, name in enumerate(poses.marker_names)]

    def regressor(self, term, spec, poses):
        return warmth(history(poses, "elapsed"))

    def regressor_label(self, term):
        return f"the camera's warm-up, 1 - exp(-t / {TAU_S:g} s)"

    def from_dict(self, data, spec=None):
        where = stored_where(data)
        return self.term(str(where.get("marker", "")), int(stored_number(where, "marker_index", self.name)))

    def correction(self, where, unwritten=None):
        return (f"in the data: marker {where.get('marker')}'s image drifting with the camera's warm-up is fitted; "
                "calibration.yaml leaves it out (the marker stays where it is on the platform)")

    def simulation_term(self, spec, size, rng, commands):
        m = int(rng.integers(commands.n_markers))
        d = rng.normal(size=3)
        d *= (1.0 if size is None else float(size)) * 1e-3 / np.linalg.norm(d)
        return self.term(commands.marker_names[m], m), d


@hookimpl
def platkit_register_effects():
    return [CameraHeat()]
