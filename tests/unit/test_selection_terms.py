"""The geometry's model selection made again beside accepted physics (issue 24,
selection.reselect_geometry): a joint sagging under its load as c sin(angle) is taken by a free
joint scale when the model has no such physics; with the physics as a model term, the scale
predicts nothing more and is held."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from platkit.calibrate.selection import reselect_geometry, select_model
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.terms import ModelTerm

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
SAG = 0.02  # rad of deflection per unit sin(angle)


@dataclass
class Sag(ModelTerm):
    """Deflection of a joint by theta sin(its angle), as gravity would bend it."""

    index: int = 0

    def control_offset(self, theta, poses, n_u):
        out = np.zeros((poses.n_poses, n_u))
        out[:, self.index] = theta[0] * np.sin(poses.controls[:, self.index])
        return out


def test_a_scale_standing_in_for_sag_is_held_once_the_sag_is_modelled():
    spec = get_platform("urdf", URDF, moving_link="right_tcp")
    i = spec.control_names.index("right_2_joint")
    rng = np.random.default_rng(7)
    lo, hi = spec.control_bounds()
    U = rng.uniform(0.9 * lo, 0.9 * hi, size=(60, spec.n_u))
    U[:, i] = rng.uniform(-0.5, 0.5, size=60)  # where the sag is nearly linear in the angle
    td = spec.nominal_td().copy()
    for k, p in enumerate(spec.parameters):
        if p.group == "origin":
            td[k] += rng.normal(0.0, 5e-4)
    U_true = U.copy()
    U_true[:, i] += SAG * np.sin(U[:, i])
    q, X = (np.asarray(a) for a in spec.forward.map(len(U))(U_true.T, td))
    R = matrix_from_quat(q.T)
    m = np.array([[0.03, 0, 0], [0, 0.03, 0.01], [0, 0, 0.04]])
    A = matrix_from_rotvec([0.1, -0.2, 0.3])
    Y = (X.T[:, None, :] + np.einsum("nab,mb->nma", R, m)) @ A.T + np.array([1.0, 0.5, -0.2])
    Y += rng.normal(0.0, 3e-5, Y.shape)
    poses = PoseSet("urdf", U, Y, ["M1", "M2", "M3"])
    plain = select_model(poses, spec)
    assert "scale" in plain.identifiability["model_selection"]["chosen"]
    j = spec.parameter_names.index("right_2_joint.scale")
    assert plain.td[j] > 1.01  # the scale took the sag
    term = Sag("compliance", ["sag"], np.zeros(1), ["rad"], {"actuator": "right_2_joint"}, index=i)
    again = reselect_geometry(poses, spec, [term])
    sel = again.identifiability["model_selection"]
    assert "scale" not in sel["chosen"] and sel["beside_terms"] == ["compliance"]
    assert abs(again.theta[0][0] - SAG) < 4 * again.theta_std[0][0] + 1e-4
