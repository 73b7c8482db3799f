"""The stand passes platkit's conformance suite, and its facts hold."""
import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import WrongBranch
from platkit.kinematics import PlatformModel
from platkit.testing import check_platform


def test_conformance():
    report = check_platform(get_platform("hexapod-rss"))
    assert report["round_trips"] == 20 and report["closed_form_vs_newton"] < 1e-9


def test_horns_are_horizontal_at_the_neutral_pose():
    spec = get_platform("hexapod-rss")
    assert spec.neutral_u() == pytest.approx(np.zeros(6), abs=1e-5)
    fk = PlatformModel(spec).forward(np.zeros(6))
    assert fk.X == pytest.approx([0.0, 0.0, 0.17567], abs=1e-5)


def test_the_mirror_below_the_horns_is_refused():
    model = PlatformModel(get_platform("hexapod-rss"))
    with pytest.raises(WrongBranch):
        model.forward(np.zeros(6), guess=[0, 0, -0.17, 0, 0, 0])
