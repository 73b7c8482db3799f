"""A public humanoid not written here (PAL's Talos, example-robot-data's talos_reduced.urdf) as a
tree session (issue 24): both hands tracked, the torso, the head and both arms recorded, the
legs not (held at their zero); one fit, held-out markers within the noise."""
from __future__ import annotations

import numpy as np
from reference_robots import example_robot_urdf

from platkit.calibrate.estimate import calibrate, point_errors
from platkit.calibrate.problem import link_frames
from platkit.geometry import matrix_from_rotvec
from platkit.plugins import get_platform
from platkit.poses import PoseSet

SIGMA = 1e-4  # m per axis
HANDS = {"L": "gripper_left_base_link", "R": "gripper_right_base_link"}
RECORDED = (["torso_1_joint", "torso_2_joint", "head_1_joint"] + [f"arm_left_{i}_joint" for i in range(1, 8)]
            + [f"arm_right_{i}_joint" for i in range(1, 8)])


def test_talos_both_hands_in_one_fit():
    urdf = example_robot_urdf("talos_data/robots/talos_reduced.urdf")
    mapping = {f"{h}{k}": link for h, link in HANDS.items() for k in range(1, 4)}
    spec = get_platform("urdf", urdf, moving_link=mapping, joints=RECORDED)
    assert spec.control_names == RECORDED and spec.tracked_links == [HANDS["L"], HANDS["R"]]
    assert not any(p.name.startswith("leg_") for p in spec.parameters)  # not recorded: no parameters
    rng = np.random.default_rng(2)
    lo, hi = spec.control_bounds()
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    U = rng.uniform(mid - 0.6 * half, mid + 0.6 * half, size=(130, spec.n_u))
    td = spec.nominal_td().copy()
    for i, p in enumerate(spec.parameters):
        if p.group == "offset":
            td[i] += rng.normal(0.0, 2e-3)
        elif p.group == "origin":
            td[i] += rng.normal(0.0, 5e-4 if p.unit == "m" else 1e-3)
    R, X = link_frames(spec, td, U)
    A, t = matrix_from_rotvec([0.05, 0.1, -1.2]), np.array([0.3, -1.0, 0.9])
    cols = []
    for link in mapping.values():
        k = spec.tracked_links.index(link)
        cols.append((X[:, k] + R[:, k] @ rng.normal(0.0, 0.05, 3)) @ A.T + t)
    Y = np.stack(cols, axis=1) + rng.normal(0.0, SIGMA, (len(U), len(mapping), 3))
    poses = PoseSet("urdf", U, Y, list(mapping), moving_link=mapping)
    cal = calibrate(poses.subset(np.arange(80)), spec)
    assert cal.rms_before > 1e-3
    err = point_errors(cal, poses.subset(np.arange(80, 130)))
    for hand in HANDS:
        cols = [j for j, n in enumerate(mapping) if n.startswith(hand)]
        assert np.nanmean(err[:, cols]) < 2.5 * SIGMA, hand  # 1.6 sigma for the noise alone
    status = dict(zip(spec.parameter_names, cal.td_status))
    assert status["head_1_joint.offset"] == "held_at_nominal"
