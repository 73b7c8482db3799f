"""base_tilt: the stand's base not level in the world, the pose turned about the base x and y axes."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from platkit.effects import Effect, SizeHelp
from platkit.kinematics import platform_model
from platkit.terms import ModelTerm
from platkit_effects.physics import BaseTiltPhysics


@dataclass
class BaseTiltTerm(ModelTerm):
    def level_tilt(self, theta):
        return np.asarray(theta, float)[:2]

    def pose_offset(self, theta, poses, fk_q, fk_X):
        w = np.array([theta[0], theta[1], 0.0])
        out = np.zeros((poses.n_poses, 6))
        out[:, :3] = np.cross(w[None, :], fk_X)
        out[:, 3:] = w
        return out


class BaseTilt(Effect):
    name = "base_tilt"
    summary = "the base, or the mocap vertical, tilted against the model's"
    simulation_size = SizeHelp("the tilt, about a random horizontal axis", "mrad")
    physics_size = SizeHelp("the tilt of the base against the level world, about a random horizontal axis", "mrad")

    def term(self):
        return BaseTiltTerm(self.name, ["tilt_x", "tilt_y"], np.zeros(2), ["rad", "rad"], {"frame": "base"})

    def candidates(self, spec, poses, residuals=None):
        return [self.term()]

    def regressor(self, term, spec, poses):
        z = platform_model(spec).forward_batch(poses.controls, strict=False).X[:, 2]
        return z - np.mean(z)

    def regressor_label(self, term):
        return "height of the moving frame above its mean (m)"

    def from_dict(self, data, spec=None):
        return self.term()

    def simulation_term(self, spec, size, rng, commands):
        a = rng.uniform(0, 2 * np.pi)
        return self.term(), (2.0 if size is None else float(size)) * 1e-3 * np.array([np.cos(a), np.sin(a)])

    def physics(self, spec, size, rng, plan):
        a = rng.uniform(0, 2 * np.pi)
        return BaseTiltPhysics((2.0 if size is None else float(size)) * 1e-3 * np.array([np.cos(a), np.sin(a)]))
