"""The admissible set: membership by inverse kinematics agrees with forward images of the control
box, the psvr's height range has its closed form, the generic route matches the closed form, and
the CLI verb writes its outputs whole."""
import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from platkit import get_platform
from platkit.admissible import admissible_grid, admissible_poses, control_grid, default_axes, plot_boundary, plot_slices, pose_images
from platkit.errors import BadInput
from platkit.kinematics import PlatformModel


@pytest.fixture(scope="module")
def psvr():
    return get_platform("psvr")


@pytest.fixture(scope="module")
def grid(psvr):
    return admissible_grid(psvr, default_axes(psvr, ["alpha", "beta", "h"], 21))


def test_control_grid_covers_the_box(psvr):
    U = control_grid(psvr, 3)
    lo, hi = psvr.control_bounds()
    assert U.shape == (27, 3)
    assert U.min(axis=0) == pytest.approx(lo) and U.max(axis=0) == pytest.approx(hi)


def test_neutral_is_inside_and_every_inside_pose_round_trips(psvr, grid):
    model = PlatformModel(psvr)
    assert admissible_poses(psvr, psvr.neutral_p())["inside"].tolist() == [True]
    assert 0 < grid.inside.sum() < grid.inside.size
    pts = grid.points()
    U = grid.controls[grid.inside]
    lo, hi = psvr.control_bounds()
    assert np.all((U >= lo - 1e-9) & (U <= hi + 1e-9))
    for k in np.linspace(0, len(pts) - 1, 15).astype(int):
        fk = model.forward(U[k], guess=pts[k])
        assert fk.on_branch and fk.p == pytest.approx(pts[k], abs=1e-9)
    # the reasons partition what is out
    reasons = grid.no_solution.astype(int) + grid.outside_stroke + grid.off_branch
    assert np.array_equal(reasons == 1, ~grid.inside) and reasons.max() == 1


def test_forward_images_of_the_control_box_are_admissible(psvr):
    """The set is the image of the control box: FK of interior controls lands inside, IK-tested."""
    lo, hi = psvr.control_bounds()
    inner = replace(psvr, controls=[replace(c, lower=c.lower + 1.0, upper=c.upper - 1.0) for c in psvr.controls])
    P = pose_images(inner, 6)
    assert P.shape == (216, 3)  # every control combination has a forward solution on the branch
    test = admissible_poses(psvr, P)
    assert test["inside"].all()


def test_height_range_at_level_platform_has_the_closed_form(psvr):
    """At alpha = beta = 0 every rod sees the same geometry: h = 150 - r cos a + sqrt(R^2 - (60 - r sin a)^2) mm,
    monotone in a over the stroke, so the admissible heights are its values at the stroke ends."""
    td = psvr.nominal_td()
    a_ends = td[0] * (np.array(psvr.control_bounds())[:, 0] - td[3])
    r, R = td[25], td[24]
    h_ends = 0.150 - r * np.cos(a_ends) + np.sqrt(R**2 - (0.060 - r * np.sin(a_ends)) ** 2)
    hs = np.linspace(0.45, 0.76, 3101)  # 0.1 mm steps
    g = admissible_grid(psvr, {"h": hs}, fixed={"alpha": 0.0, "beta": 0.0})
    lo, hi = g.extent()["h"]
    assert lo == pytest.approx(h_ends[0], abs=1e-4) and hi == pytest.approx(h_ends[1], abs=1e-4)
    assert h_ends * 1000 == pytest.approx([491.9, 715.5], abs=0.1)
    assert g.outside_stroke[hs > hi + 1e-4].any() and g.outside_stroke[hs < lo - 1e-4].any()


def test_generic_newton_route_agrees_with_the_closed_form(psvr):
    axes = {"alpha": np.linspace(-0.2, 0.2, 5), "beta": np.linspace(-0.2, 0.2, 5), "h": np.linspace(0.52, 0.68, 5)}
    closed = admissible_grid(psvr, axes)
    generic = admissible_grid(replace(psvr, inverse=None), axes)
    assert closed.inside.any() and not closed.inside.all()
    assert np.array_equal(closed.inside, generic.inside)
    assert np.allclose(closed.controls[closed.inside], generic.controls[generic.inside], atol=1e-5)


def test_six_dof_stand_sweeps_two_coordinates_with_the_rest_fixed():
    stewart = get_platform("stewart")
    g = admissible_grid(stewart, {"roll": np.linspace(-0.6, 0.6, 13), "pitch": np.linspace(-0.6, 0.6, 13)},
                        fixed={"z": 3.3})
    assert g.fixed["z"] == 3.3 and g.fixed["yaw"] == 0.0
    assert g.inside[6, 6] and not g.inside.all()


def test_bad_coordinates_are_named(psvr):
    with pytest.raises(BadInput, match="no pose coordinate 'gamma'.*alpha, beta, h"):
        admissible_grid(psvr, {"gamma": np.zeros(3)})
    with pytest.raises(BadInput, match="'h' is both swept and fixed"):
        admissible_grid(psvr, {"h": np.ones(3)}, fixed={"h": 0.6})


def test_plots_are_written(psvr, grid, tmp_path):
    sliced = plot_slices(grid, tmp_path / "s.png", 4)
    assert len(sliced) == 4 and all(grid.axes[2][0] <= v <= grid.axes[2][-1] for v in sliced)
    n = plot_boundary(grid, tmp_path / "b.png")
    assert 0 < n < grid.inside.sum()
    for f in ("s.png", "b.png"):
        assert (tmp_path / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "platkit.cli", "admissible", *args], capture_output=True, text=True)


def test_cli_writes_summary_csv_and_plots(tmp_path):
    out = tmp_path / "adm"
    res = _cli("--platform", "psvr", "--out", str(out), "--n", "15")
    assert res.returncode == 0, res.stderr
    summary = json.loads((out / "admissible.json").read_text())
    assert summary["coordinates"] == ["alpha", "beta", "h"] and summary["units"]["h"] == "mm"
    assert summary["n_grid"] == 15**3 and 0 < summary["n_admissible"] < summary["n_grid"]
    assert summary["n_admissible"] + summary["n_no_solution"] + summary["n_outside_stroke"] + summary["n_off_branch"] == 15**3
    lo, hi = summary["extent"]["h"]
    assert 480 < lo < 520 and 690 < hi < 720  # mm
    rows = (out / "admissible.csv").read_text().splitlines()
    assert rows[0] == "alpha,beta,h,A,B,C" and len(rows) == summary["n_admissible"] + 1
    assert {p.name for p in out.iterdir()} == {"admissible.json", "admissible.csv", "admissible_slices.png", "admissible_boundary.png"}


def test_cli_bad_input_writes_nothing(tmp_path):
    out = tmp_path / "adm"
    res = _cli("--platform", "stewart", "--out", str(out))
    assert res.returncode == 2 and "--axes" in res.stderr and len(res.stderr.strip().splitlines()) == 1
    res = _cli("--platform", "psvr", "--out", str(out), "--axes", "alpha,gamma")
    assert res.returncode == 2 and "gamma" in res.stderr
    assert not out.exists()
