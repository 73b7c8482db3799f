"""Experiment design: snake grids, feasibility, the identification Jacobian, D-optimal choice."""
from __future__ import annotations

import json

import numpy as np
import pytest

from platkit.calibrate import plan as pl
from platkit.cli import main
from platkit.errors import BadInput
from platkit.geometry import matrix_from_quat
from platkit.kinematics import PlatformModel
from platkit.plugins import get_platform


@pytest.fixture(scope="module")
def stewart():
    return get_platform("stewart")


@pytest.mark.parametrize("counts", [[3, 3], [2, 3, 4], [4]])
def test_snake_order_is_a_hamiltonian_path(counts):
    idx = pl.snake_order(counts)
    assert len(idx) == np.prod(counts)
    assert len({tuple(r) for r in idx}) == len(idx)  # every point once
    steps = np.abs(np.diff(idx, axis=0))
    assert np.all(steps.sum(axis=1) == 1)  # neighbours on the grid graph


def test_grid_covers_the_box_in_snake_order(stewart):
    U = pl.grid_points(stewart, 3, margin=0.1)
    lo, hi = pl.control_box(stewart, 0.1)
    assert U.shape == (729, 6)
    np.testing.assert_allclose(U.min(axis=0), lo)
    np.testing.assert_allclose(U.max(axis=0), hi)
    moved = np.sum(np.abs(np.diff(U, axis=0)) > 1e-12, axis=1)
    assert np.all(moved == 1)


def test_infeasible_controls_are_dropped(stewart):
    model = PlatformModel(stewart)
    good = stewart.neutral_u()
    far = good.copy()
    far[0] = 20.0  # a leg longer than any assembly allows (the others hold the platform near neutral)
    ok, P = pl.feasible(stewart, np.vstack([good, far, good + 0.05]), model=model)
    assert ok.tolist() == [True, False, True]
    psvr = get_platform("psvr")
    plan = pl.grid_plan(psvr, 5, margin=0.0)
    assert plan.info["grid_points"] == 125
    assert len(plan.controls) + plan.info["infeasible_dropped"] == 125
    fb = PlatformModel(psvr).forward_batch(plan.controls)
    assert np.all(fb.converged & fb.on_branch)


def test_grid_plan_for_a_pose_count(stewart):
    plan = pl.grid_plan_for(stewart, 50)
    assert len(plan.controls) == 50 and plan.info["points_per_control"] == 2


def test_identification_jacobian_against_finite_differences():
    spec = get_platform("psvr")
    model = PlatformModel(spec)
    rng = np.random.default_rng(0)
    markers = pl.default_marker_layout(spec, 4, rng)
    cand = pl.random_candidates(spec, 3, rng, model=model)
    ij = pl.identification_jacobian(spec, cand.controls, markers, model=model)
    td0 = spec.nominal_td()

    def marker_positions(td, S):
        fb = model.forward_batch(cand.controls, td=td, guess=cand.poses)
        R = matrix_from_quat(fb.q)
        return (fb.X[:, None, :] + np.einsum("kij,mj->kmi", R, S)).reshape(len(cand.controls), -1)

    n_td = ij.n_td
    for k in range(n_td):
        h = 1e-6 * max(1.0, abs(td0[k]))
        e = np.zeros_like(td0)
        e[k] = h
        fd = (marker_positions(td0 + e, markers) - marker_positions(td0 - e, markers)) / (2 * h)
        np.testing.assert_allclose(ij.J[:, :, k], fd, atol=1e-6 * max(1.0, np.abs(fd).max()), err_msg=ij.names[k])
    # marker position columns: d m / d s = R
    h = 1e-6
    S = markers.copy()
    S[2, 1] += h
    fd = (marker_positions(td0, S) - marker_positions(td0, markers)) / h
    np.testing.assert_allclose(ij.J[:, :, ij.names.index("marker3_y")], fd, atol=1e-6)


def test_stewart_has_twelve_never_identifiable_directions(stewart):
    rng = np.random.default_rng(1)
    model = PlatformModel(stewart)
    cand = pl.random_candidates(stewart, 60, rng, model=model)
    markers = pl.default_marker_layout(stewart, 5, rng)
    ij = pl.identification_jacobian(stewart, cand.controls, markers, P=cand.poses, model=model)
    info = pl.plan_uncertainty(ij.J, ij.J, 1e-4, ij.names, ij.units)
    # 42 + 6 + 15 parameters; the base frame against the mocap frame (6) and the moving frame
    # against the markers (6) are choices, not measurable
    assert info["n_parameters"] == 63 and info["never_identifiable"] == 12
    assert info["identifiable"]
    twice = pl.plan_uncertainty(ij.J, ij.J, 2e-4, ij.names, ij.units)
    assert np.isclose(twice["predicted_marker_rms_m"], 2 * info["predicted_marker_rms_m"])
    # too few poses cannot identify everything
    few = pl.plan_uncertainty(ij.J[:2], ij.J, 1e-4, ij.names, ij.units)
    assert not few["identifiable"] and few["plan_rank"] < few["identifiable_rank"]


def test_d_optimal_beats_random_selection():
    spec = get_platform("psvr")
    rng = np.random.default_rng(2)
    plan, baseline = pl.optimal_plan(spec, 30, 150, rng, 1e-4, n_markers=4)
    assert len(plan.controls) == 30 and plan.info["identifiable"] and baseline["identifiable"]
    assert plan.info["logdet"] > baseline["logdet"] + 10.0
    assert plan.info["predicted_marker_rms_m"] < baseline["predicted_marker_rms_m"]


def test_d_optimal_greedy_on_a_known_problem():
    # candidates are rows e_i scaled by i+1: the best 3 of 5 for log det are the 3 largest
    Jr = np.stack([np.eye(5)[i:i + 1] * (i + 1) for i in range(5)])
    assert sorted(pl.d_optimal(Jr, 3).tolist()) == [2, 3, 4]
    with pytest.raises(BadInput):
        pl.d_optimal(Jr, 6)


def test_cli_plan_grid_and_optimal(tmp_path, capsys):
    out = tmp_path / "plans" / "grid.csv"
    assert main(["plan", "--platform", "psvr", "--out", str(out), "--grid", "4"]) == 0
    text = capsys.readouterr().out
    assert "predicted marker RMS" in text
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["plan"]["kind"] == "grid" and report["plan"]["identifiable"]
    spec = get_platform("psvr")
    U = pl.read_plan_csv(out, spec, "mm")
    assert len(U) == report["n_poses"] > 20
    # the plan drives a simulation
    assert main(["simulate", "--platform", "psvr", "--out", str(tmp_path / "s"), "--plan", str(out),
                 "--poses-only"]) == 0
    out2 = tmp_path / "opt.csv"
    assert main(["plan", "--platform", "psvr", "--out", str(out2), "--optimal", "10", "--candidates", "80"]) == 0
    rep = json.loads(out2.with_suffix(".json").read_text())
    assert rep["n_poses"] == 10 and "baseline" in rep
    assert rep["plan"]["predicted_marker_rms_m"] <= rep["baseline"]["predicted_marker_rms_m"]
    assert main(["plan", "--platform", "psvr", "--out", str(tmp_path / "x.csv")]) == 2


def _wrist_urdf(tmp_path):
    """A 3-joint arm whose last joint, a wrist, is continuous."""
    urdf = tmp_path / "wrist.urdf"
    urdf.write_text(
        '<robot name="wrist"><link name="base"/><link name="a"/><link name="b"/><link name="tool"/>'
        '<joint name="j1" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.3"/>'
        '<axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>'
        '<joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0"/>'
        '<axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>'
        '<joint name="w" type="continuous"><parent link="b"/><child link="tool"/><origin xyz="0.2 0 0"/>'
        '<axis xyz="1 0 0"/></joint></robot>')
    return urdf


def test_a_continuous_joint_is_planned_and_simulated_over_one_turn(tmp_path, capsys):
    """A URDF's continuous joint (a wrist, a wheel) has no stroke: plan and simulate draw it over
    one turn either way of its neutral and say so, where they refused the whole stand."""
    stand = ["--platform", "urdf", "--description", str(_wrist_urdf(tmp_path)), "--moving-link", "tool"]
    assert main(["plan", *stand, "--optimal", "12", "--candidates", "60", "--out", str(tmp_path / "p.csv")]) == 0
    U = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)
    assert np.all(np.abs(U[:, -1]) <= 0.8 * np.pi + 1e-9) and np.ptp(U[:, -1]) > 1.0
    said = json.loads((tmp_path / "p.json").read_text())["warnings"]
    assert any("w: no finite stroke" in w and "one turn" in w for w in said)
    assert main(["simulate", *stand, "--poses", "10", "--plan", "random", "--poses-only",
                 "--out", str(tmp_path / "s")]) == 0
    assert "w: no finite stroke" in capsys.readouterr().err


def test_the_physical_simulators_continuous_joint_moves_a_turn_in_a_stroke_time(tmp_path):
    """The physical simulator's drive of a continuous joint covers the turn either way it is
    planned over in its drawn stroke time (3-5 s), as every other drive its stroke: its holds
    settle. (With a stroke of 1 rad it crawled at 0.2 rad/s and 26 of 30 holds of a hand-written
    tree never settled.)"""
    import yaml

    from platkit.io.session import load_session
    from platkit.settle import settle

    out = tmp_path / "s"
    assert main(["simulate", "--platform", "urdf", "--description", str(_wrist_urdf(tmp_path)), "--moving-link", "tool",
                 "--physics", "--poses", "8", "--seed", "26200", "--out", str(out)]) == 0
    truth = yaml.safe_load((out / "truth.yaml").read_text())
    drives = truth["nuisances"]["actuators"]
    assert 2 * np.pi / 5.0 <= drives["w"]["rate_per_s"] <= 2 * np.pi / 3.0
    _, report = settle(load_session(out))
    assert report.n_kept == 8


def test_plan_motion_names_the_joints_that_declare_no_rate(tmp_path, capsys):
    """The URDF declares a velocity for every joint but the continuous wrist (whose <limit> is
    left out): the refusal names that joint, not every control."""
    assert main(["plan", "--platform", "urdf", "--description", str(_wrist_urdf(tmp_path)), "--moving-link", "tool",
                 "--motion", "--max-accel", "2", "--duration-s", "20", "--out", str(tmp_path / "c.csv")]) == 2
    assert "declares no rate limit for w; give the drives' limit" in capsys.readouterr().err
