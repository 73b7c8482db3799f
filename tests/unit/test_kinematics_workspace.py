"""The workspace routines on every route: closed-form inverse, generic (p, u) with F = 0, and
serial chains through their closed-form forward kinematics."""
from dataclasses import replace

import numpy as np
import pytest

from platkit import get_platform
from platkit.errors import BadInput
from platkit.kinematics import PlatformModel
from platkit.workspace import control_corners, corner_envelope, translational_envelope


@pytest.fixture(scope="module")
def stewart():
    return PlatformModel(get_platform("stewart"))


def test_corners_enumerate_every_stroke_end(stewart):
    U = control_corners(stewart)
    lo, hi = stewart.spec.control_bounds()
    assert U.shape == (64, 6) and len({tuple(u) for u in U}) == 64
    assert np.all((U == lo) | (U == hi))
    assert np.all(U[0] == lo) and np.all(U[-1] == hi)


def test_generic_route_agrees_with_the_closed_form_inverse(stewart):
    """Without the stand's inverse the search runs over (p, u) with F = 0 as constraints."""
    generic = PlatformModel(replace(stewart.spec, inverse=None))
    a = translational_envelope(stewart, "fixed")
    b = translational_envelope(generic, "fixed")
    assert "F = 0" in b.solver and "closed-form inverse" in a.solver
    np.testing.assert_allclose(b.lower, a.lower, atol=1e-6)
    np.testing.assert_allclose(b.upper, a.upper, atol=1e-6)
    for e in b.extremes:  # the controls found satisfy the constraints and their strokes
        q, X = generic.pose(e.p)
        np.testing.assert_allclose(stewart.inverse(q, X, strict=False), e.u, atol=1e-7)


def test_fixed_orientation_extremes_keep_the_neutral_orientation(stewart):
    env = translational_envelope(stewart, "fixed")
    for e in env.extremes:
        np.testing.assert_allclose(e.p[3:], 0.0, atol=1e-12)
    assert env.get("x", "max").value > stewart.pose(stewart.spec.neutral_p())[1][0] + 1.0


@pytest.mark.parametrize("name", ["psvr", "rotary", "urdf"])
def test_other_stands_get_a_workspace(name):
    model = PlatformModel(get_platform(name))
    corners = corner_envelope(model)
    assert corners.converged.all()
    free = translational_envelope(model, "free")
    # the free envelope reaches at least as far as every corner pose (a corner is feasible)
    assert np.all(free.lower <= corners.lower + 1e-6) and np.all(free.upper >= corners.upper - 1e-6)
    fixed = translational_envelope(model, "fixed")
    assert np.all(fixed.lower >= free.lower - 1e-6) and np.all(fixed.upper <= free.upper + 1e-6)


def test_bad_orientation_word(stewart):
    with pytest.raises(BadInput, match="'fixed' or 'free'"):
        translational_envelope(stewart, "level")
