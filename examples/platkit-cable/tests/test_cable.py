"""The stand passes platkit's conformance suite, and its facts hold: eight cables for six pose
coordinates, least-squares forward kinematics with each cable's misfit, refusal beyond the
declared stretch naming the cables."""
import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import BadDescription, OutOfWorkspace
from platkit.kinematics import PlatformModel
from platkit.testing import check_platform


def test_conformance():
    report = check_platform(get_platform("cable"))
    assert report["round_trips"] == 20 and report["free_space"] == "pose" and report["free_space_taken"] == 1.0


def test_stretched_cables_give_the_least_squares_pose_and_its_misfit():
    spec = get_platform("cable")
    model = PlatformModel(spec)
    u0 = spec.neutral_u()
    exact = model.forward(u0)
    assert exact.X == pytest.approx([0.0, 0.0, 1.5], abs=1e-12) and np.max(np.abs(exact.misfit)) < 1e-12
    stretch = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0, 1.0, -1.0]) * 2e-3  # 2 mm each, no pose fits
    fk = model.forward(u0 + stretch)
    # the weighted least-squares pose: the rows' misfit is orthogonal to the pose Jacobian's columns
    r, Jp = (np.asarray(a) for a in model.F_jac(u0 + stretch, spec.nominal_td(), fk.p)[:2])
    r = r.ravel()
    assert np.allclose(r, fk.misfit, atol=1e-15) and np.max(np.abs(Jp.T @ r)) < 1e-12
    assert 0 < fk.misfit_ratio < 1 and np.max(np.abs(fk.misfit)) > 1e-4


def test_a_misfit_beyond_the_stretch_is_refused_naming_the_cables():
    spec = get_platform("cable")
    u = spec.neutral_u().copy()
    u[2] += 0.1  # c3 100 mm longer: the least-squares pose spreads it over the cables
    with pytest.raises(OutOfWorkspace, match=r"no pose within the stand's plausible misfit: cable c8 misses by 16.6\d mm "
                                             r"\(plausible 10\), .* \(6 of 8 rows beyond\)") as err:
        PlatformModel(spec).forward(u)
    assert "\n" not in str(err.value)
    u[2] -= 0.05  # 50 mm: every cable within its 10 mm stretch at the least-squares pose
    assert 0.5 < PlatformModel(spec).forward(u).misfit_ratio < 1


def test_a_start_upside_down_still_finds_the_upright_platform():
    spec = get_platform("cable")
    model = PlatformModel(spec)
    u = model.inverse(*model.pose([0.3, -0.2, 1.8, 0.1, -0.05, 0.2]))
    fk = model.forward(u, guess=[0.0, 0.0, 1.5, np.pi, 0.0, 0.0], restarts=True)
    assert fk.on_branch and fk.p == pytest.approx([0.3, -0.2, 1.8, 0.1, -0.05, 0.2], abs=1e-9)


def test_an_unknown_field_is_named(tmp_path):
    from platkit_cable import DEFAULT_DESCRIPTION

    bad = tmp_path / "typo.yaml"
    bad.write_text(DEFAULT_DESCRIPTION.read_text().replace("stretch: 10.0", "strech: 10.0", 1))
    with pytest.raises(BadDescription, match=r"typo.yaml: unknown field 'strech' \(did you mean 'stretch'\?\)"):
        get_platform("cable", bad)
