"""Diagnosis of a joint that sags under its gravity load, from a default calibration whose free
joint scale stood in for the sag: once the compliance is named and the geometry's selection made
again holds the scale, the final calibration holds it at nominal, not at the value it took
standing in for the sag (issue 24)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from platkit.calibrate.selection import select_model
from platkit.diagnose import Options, diagnose
from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit_effects import Compliance

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"


def test_a_scale_held_after_the_sag_is_named_is_held_at_nominal():
    spec = get_platform("urdf", URDF, moving_link="right_tcp")
    i = spec.control_names.index("right_2_joint")
    rng = np.random.default_rng(11)
    lo, hi = spec.control_bounds()
    U = rng.uniform(0.9 * lo, 0.9 * hi, size=(60, spec.n_u))
    U[:, i] = rng.uniform(-0.5, 0.5, size=60)
    blank = PoseSet("urdf", U, np.zeros((60, 3, 3)), ["M1", "M2", "M3"])
    sag = Compliance().term(spec, i)
    tau = sag.control_offset(np.array([1.0]), blank, spec.n_u)[:, i]
    c = -0.02 / np.abs(tau).max()  # 20 mrad at the largest load
    U_true = U + sag.control_offset(np.array([c]), blank, spec.n_u)
    q, X = (np.asarray(a) for a in spec.forward.map(len(U))(U_true.T, spec.nominal_td()))
    R = matrix_from_quat(q.T)
    m = np.array([[0.03, 0, 0], [0, 0.03, 0.01], [0, 0, 0.04]])
    A = matrix_from_rotvec([0.1, -0.2, 0.3])
    Y = (X.T[:, None, :] + np.einsum("nab,mb->nma", R, m)) @ A.T + np.array([1.0, 0.5, -0.2])
    Y += rng.normal(0.0, 3e-5, Y.shape)
    poses = PoseSet("urdf", U, Y, ["M1", "M2", "M3"])
    plain = select_model(poses, spec)
    j = spec.parameter_names.index("right_2_joint.scale")
    assert "scale" in plain.identifiability["model_selection"]["chosen"] and abs(plain.td[j] - 1.0) > 0.002
    d = diagnose(spec, poses, Options(max_effects=1), library={"compliance": Compliance()}, start=plain)
    assert [(f.effect, f.where.get("actuator")) for f in d.findings] == [("compliance", "right_2_joint")]
    assert any("geometry_reselected" in r for r in d.rounds)
    assert d.calibration.td_status[j] != "estimated" and d.calibration.td[j] == spec.nominal_td()[j]
    theta = d.calibration.theta[0][0]
    assert abs(theta - c) < 0.05 * abs(c)
