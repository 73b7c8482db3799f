"""The workspace routines on every route: closed-form inverse, generic (p, u) with F = 0, and
serial chains through their closed-form forward kinematics."""
import json
from dataclasses import replace

import numpy as np
import pytest

from platkit import get_platform
from platkit.cli import main
from platkit.commands import workspace as workspace_command
from platkit.errors import BadInput
from platkit.kinematics import PlatformModel
from platkit.workspace import control_corners, coordinate_ranges, corner_envelope, translational_envelope
from tests.unit.test_forward_bounds import pan_tilt


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


def test_an_orientation_only_stand_reports_its_orientation_range(capsys, monkeypatch, tmp_path):
    """A pan-tilt head (yaw, pitch; its centre fixed): the workspace gives each pose coordinate's
    range over the poses the stand takes, in the text, workspace.json and coordinates.csv, and
    says that the origin does not move instead of a table of zeros."""
    spec = pan_tilt()  # pan +-2.6 rad, tilt +-1.0 rad; yaw within +-2.8, pitch within +-1.3
    ranges = coordinate_ranges(PlatformModel(spec))
    assert [r.name for r in ranges] == ["yaw", "pitch"]
    np.testing.assert_allclose([[r.lower.value, r.upper.value] for r in ranges], [[-2.6, 2.6], [-1.0, 1.0]], atol=1e-7)
    assert ranges[0].upper.active == ["pan"] and ranges[1].lower.active == ["tilt"]
    monkeypatch.setattr(workspace_command, "platform_from_args", lambda args: spec)
    out = tmp_path / "ws"
    assert main(["workspace", "--platform", "any", "--out", str(out), "--no-plots"]) == 0
    text = capsys.readouterr().out
    assert "pan-tilt: the origin does not move (x, y, z = 0.0, 0.0, 0.0 mm" in text
    assert "x min" not in text
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines() if line.startswith(("yaw (deg)", "pitch (deg)"))}
    assert rows == {"yaw": ["(deg)", "0.0", "-149.0", "149.0"], "pitch": ["(deg)", "0.0", "-57.3", "57.3"]}
    saved = json.loads((out / "workspace.json").read_text())["coordinates"]
    assert saved["yaw"]["unit"] == "rad" and abs(saved["yaw"]["max"] - 2.6) < 1e-7 and abs(saved["pitch"]["range"] - 2.0) < 1e-7
    lines = (out / "coordinates.csv").read_text().splitlines()
    assert lines[0] == "coordinate,unit,neutral,min,max,range"
    assert lines[1:] == ["yaw,rad,0.000000,-2.600000,2.600000,5.200000", "pitch,rad,0.000000,-1.000000,1.000000,2.000000"]
