"""Small simulated sessions the calibration tests share: the urdf stand's default arm seen by three
markers (closed-form forward kinematics: fast), and a one-joint turntable URDF."""
from __future__ import annotations

import numpy as np

from platkit.geometry import matrix_from_quat, matrix_from_rotvec
from platkit.kinematics import PlatformModel
from platkit.model import PlatformSpec
from platkit.poses import PoseSet

#: a one-joint turntable: its markers' turn about one axis leaves the transform's turn about it a gauge
TURNTABLE = """<?xml version="1.0"?>
<robot name="turntable">
  <link name="base"/><link name="table"/>
  <joint name="spin" type="revolute"><parent link="base"/><child link="table"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
</robot>
"""


def arm_poses(arm: PlatformSpec, seed: int, n: int) -> PoseSet:
    """``n`` settled poses of ``arm`` (the urdf stand) drawn with ``seed``: its offsets and origins
    1 mm off nominal, commands within 60 % of each stroke, three markers, a fixed transform,
    0.2 mm white noise."""
    rng = np.random.default_rng(seed)
    td = arm.nominal_td().copy()
    for i, p in enumerate(arm.parameters):
        if p.group in ("offset", "origin"):
            td[i] += 1e-3 * rng.normal()
    lo, hi = arm.control_bounds()
    U = rng.uniform(0.6 * lo, 0.6 * hi, (n, arm.n_u))
    fb = PlatformModel(arm).forward_batch(U, td, strict=False)
    m = rng.normal(0, 0.15, (3, 3))
    Y = (fb.X[:, None] + np.einsum("nab,mb->nma", matrix_from_quat(fb.q), m)) @ matrix_from_rotvec([0.3, -0.2, 1.0]).T
    Y = Y + [0.2, -0.4, 1.0] + rng.normal(0, 2e-4, Y.shape)
    return PoseSet(arm.name, U, Y, ["M1", "M2", "M3"], length_unit="mm", source="simulated")
