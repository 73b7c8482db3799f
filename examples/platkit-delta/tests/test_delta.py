"""The stand passes platkit's conformance suite, and its facts hold."""
import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import BadDescription, WrongBranch
from platkit.kinematics import PlatformModel
from platkit.testing import check_platform


def test_conformance():
    report = check_platform(get_platform("delta"))
    assert report["round_trips"] == 20 and report["closed_form_vs_newton"] < 1e-9


def test_the_platform_translates_and_never_rotates():
    spec = get_platform("delta")
    assert spec.neutral_u() == pytest.approx(np.full(3, 0.4), abs=1e-4)
    model = PlatformModel(spec)
    fk = model.forward(np.zeros(3))
    assert fk.q == pytest.approx([1, 0, 0, 0])
    # horizontal upper arms: elbows on a 200 mm circle, the platform joints 165 mm inside them
    assert fk.X == pytest.approx([0.0, 0.0, -np.sqrt(0.25**2 - 0.165**2)], abs=1e-9)
    # one arm lowered swings its elbow in and down: the platform goes down and away from it
    fk1 = model.forward(np.array([0.3, 0.0, 0.0]))
    assert fk1.X[0] < 0 and fk1.X[2] < fk.X[2] and fk1.X[1] == pytest.approx(0.0, abs=1e-12)


def test_the_mirror_above_the_elbows_is_refused():
    model = PlatformModel(get_platform("delta"))
    with pytest.raises(WrongBranch):
        model.forward(np.zeros(3), guess=[0, 0, 0.19])


def test_an_unknown_field_is_named(tmp_path):
    from platkit_delta import DEFAULT_DESCRIPTION

    bad = tmp_path / "typo.yaml"
    bad.write_text(DEFAULT_DESCRIPTION.read_text().replace("forearm: 250.0\n    zero_offset", "forearm: 250.0\n    ofset", 1))
    with pytest.raises(BadDescription, match=r"typo.yaml: unknown field 'arms\[0\].ofset'"):
        get_platform("delta", bad)
