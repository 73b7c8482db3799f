"""The default size of a simulated effect on one control (platkit.effects.control_size): its number
counts mm on a length control and mrad on a revolute joint (a URDF stand's control in radians);
a stand's own unit (the rotary rig's degrees) takes it as given. `platkit simulate --effect
compliance` on a URDF arm with no size once deflected its joints by a whole radian."""
from __future__ import annotations

import numpy as np
import pytest

from platkit.effects import control_size
from platkit.plugins import get_platform
from platkit.simulate import simulate


def _term(sim, effect):
    (found,) = [(t, theta) for t, theta in sim.truth.terms if t.effect == effect]
    return found


def test_control_size_default_per_unit():
    urdf, stewart, rotary = get_platform("urdf"), get_platform("stewart"), get_platform("rotary")
    assert [c.unit for c in urdf.controls] == ["rad"] * 3
    assert control_size(urdf, 0, None, 1.0) == pytest.approx(1e-3)  # 1 mrad
    assert control_size(urdf, 0, 0.02, 1.0) == pytest.approx(0.02)  # a given size: the control's unit
    assert control_size(stewart, 0, None, 1.0) == pytest.approx(1e-3)  # 1 mm
    assert control_size(stewart, 0, 2.0, 1.0) == pytest.approx(2e-3)
    assert rotary.controls[0].unit == "deg" and control_size(rotary, 0, None, 1.0) == 1.0


def test_urdf_backlash_and_cyclic_error_default_to_a_real_joints_size():
    spec = get_platform("urdf")
    sim = simulate(spec, seed=1, n_poses=20, raw=False, effects=[("backlash", None), ("cyclic_error", None)])
    _, half_play = _term(sim, "backlash")
    assert half_play[0] == pytest.approx(0.5e-3)  # a full play of 1 mrad
    _, ab = _term(sim, "cyclic_error")
    assert np.hypot(*ab[:2]) == pytest.approx(0.3e-3, rel=1e-6)  # 0.3 mrad amplitude


def test_urdf_compliance_with_no_size_moves_the_markers_by_a_fraction_of_a_millimetre():
    spec = get_platform("urdf")
    clean = simulate(spec, seed=2, n_poses=30, raw=False, noise_mm=0.0, occlusion=0.0)
    bent = simulate(spec, seed=2, n_poses=30, raw=False, noise_mm=0.0, occlusion=0.0, effects=[("compliance", None)])
    shift = np.linalg.norm(bent.poses.markers - clean.poses.markers, axis=2)
    assert 0.05e-3 < np.max(shift) < 3e-3  # the largest deflection 1 mrad at the arm's reach
