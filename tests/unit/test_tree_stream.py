"""Streams of a tree (issue 24, the twin in time): `platkit simulate` writes a tree's raw stream
(the additive route with holds; --physics with holds or streamed commands), every marker on its
own tracked link and the mapping in session.yaml, a joint that moves no marker streamed too; and
`platkit calibrate` fits the whole tree from it in one fit, settled or from motion, to each link's
noise floor; `plan --motion`'s per-link prediction agrees with what the fit from motion achieves.

The tree is written here: a torso yaw, a head yaw that moves no marker, two 2-joint arms, both
tool links tracked."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from platkit.calibrate.estimate import predict_markers
from platkit.calibrate.motion import TAU0_S
from platkit.calibrate.plan import reference_poses_for
from platkit.calibrate.problem import link_frames
from platkit.cli import main
from platkit.io.calibration import read_calibration
from platkit.plugins import get_platform

LINKS = "right_tcp,left_tcp"
URDF = """<?xml version="1.0"?>
<robot name="small_tree">
  <link name="base_link"/><link name="torso"/><link name="head"/>
  <link name="r1"/><link name="r2"/><link name="right_tcp"/><link name="l1"/><link name="l2"/><link name="left_tcp"/>
  <joint name="torso_yaw" type="revolute"><parent link="base_link"/><child link="torso"/>
    <origin xyz="0 0 0.4"/><axis xyz="0 0 1"/><limit lower="-1.2" upper="1.2" effort="100" velocity="1"/></joint>
  <joint name="head_yaw" type="revolute"><parent link="torso"/><child link="head"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
  <joint name="r1_joint" type="revolute"><parent link="torso"/><child link="r1"/>
    <origin xyz="0 -0.25 0.2" rpy="0.1 0 0"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="50" velocity="1"/></joint>
  <joint name="r2_joint" type="revolute"><parent link="r1"/><child link="r2"/>
    <origin xyz="0 0 -0.3"/><axis xyz="1 0 0"/><limit lower="-1.2" upper="1.2" effort="50" velocity="1"/></joint>
  <joint name="r_tcp" type="fixed"><parent link="r2"/><child link="right_tcp"/><origin xyz="0 0 -0.2"/></joint>
  <joint name="l1_joint" type="revolute"><parent link="torso"/><child link="l1"/>
    <origin xyz="0 0.25 0.2" rpy="-0.1 0 0"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="50" velocity="1"/></joint>
  <joint name="l2_joint" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 -0.3"/><axis xyz="1 0 0"/><limit lower="-1.2" upper="1.2" effort="50" velocity="1"/></joint>
  <joint name="l_tcp" type="fixed"><parent link="l2"/><child link="left_tcp"/><origin xyz="0 0 -0.2"/></joint>
</robot>
"""


@pytest.fixture(scope="module")
def urdf(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("tree") / "small_tree.urdf"
    path.write_text(URDF)
    return path


def stand(urdf):
    return get_platform("urdf", urdf, moving_link={n: n for n in LINKS.split(",")})


def truth_of(folder: Path, spec):
    """(td, mocap_from_base, markers (M, 3) on their links, link index of each) from the folder's
    truth.yaml and session.yaml."""
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    session = yaml.safe_load((folder / "session.yaml").read_text())
    td = np.array([truth["parameters"][n]["value"] for n in spec.parameter_names])
    names = session["markers"]
    S = np.array([truth["markers"][n] for n in names])
    links = np.array([spec.tracked_links.index(session["moving_link"][n]) for n in names])
    return td, np.array(truth["mocap_from_base"]), S, links


def link_errors(folder: Path, cal_folder: Path, spec, U) -> dict[str, float]:
    """Per tracked link, the 3-D RMS (m) of the calibration's markers against the true stand's at
    controls U (held out: no fit saw them)."""
    td, T, S, k = truth_of(folder, spec)
    R, X = link_frames(spec, td, U)
    true = (X[:, k] + np.einsum("nmab,mb->nma", R[:, k], S)) @ T[:3, :3].T + T[:3, 3]
    cal = read_calibration(cal_folder / "calibration.yaml")
    pred, _, _, _ = predict_markers(cal, U)
    d2 = np.sum((pred - true) ** 2, axis=2)
    return {link: float(np.sqrt(np.mean(d2[:, k == i]))) for i, link in enumerate(spec.tracked_links)}


def simulate(urdf, out, *extra):
    return main(["simulate", "--platform", "urdf", "--description", str(urdf), "--moving-link", LINKS,
                 "--out", str(out), *extra])


def test_a_streamed_tree_is_calibrated_from_motion_as_plan_predicts_each_link(urdf, tmp_path, capsys):
    """plan --motion on the tree, streamed through the physical simulator (no holds), calibrated
    from motion: each link's held-out error near plan's prediction for it (within a factor 3),
    the description off by millimetres; every joint streamed, the head's too (its response, which no
    marker sees, held at the start)."""
    spec = stand(urdf)
    plan = tmp_path / "plan" / "commands.csv"
    assert main(["plan", "--platform", "urdf", "--description", str(urdf), "--moving-link", LINKS, "--motion",
                 "--max-accel", "2", "--duration-s", "30", "--noise-mm", "0.2", "--quiet", "--out", str(plan)]) == 0
    predicted = json.loads(plan.with_suffix(".json").read_text())["prediction"]["links"]
    folder = tmp_path / "sim"
    assert simulate(urdf, folder, "--physics", "--motion", str(plan), "--seed", "41", "--noise-mm", "0.2",
                    "--white-noise") == 0
    session = yaml.safe_load((folder / "session.yaml").read_text())
    assert session["moving_link"] == {"M1": "right_tcp", "M2": "left_tcp", "M3": "right_tcp", "M4": "left_tcp",
                                      "M5": "right_tcp", "M6": "left_tcp"}
    header = (folder / "commands.csv").read_text().splitlines()[0].split(",")
    assert header == ["t", "torso_yaw", "head_yaw", "r1_joint", "r2_joint", "l1_joint", "l2_joint"]
    # the markers follow their own links: the truth's settled markers are each link's at rest
    td, T, S, k = truth_of(folder, spec)
    settled = np.genfromtxt(folder / "truth_settled.csv", delimiter=",", names=True)
    U = np.column_stack([settled[n] for n in spec.control_names])[::50]
    R, X = link_frames(spec, td, U)
    want = ((X[:, k] + np.einsum("nmab,mb->nma", R[:, k], S)) @ T[:3, :3].T + T[:3, 3]) * 1e3
    got = np.stack([np.column_stack([settled[f"M{m + 1}_{a}"] for a in "xyz"]) for m in range(6)], axis=1)[::50]
    assert np.max(np.abs(got - want)) < 1e-3  # mm: the file's digits
    capsys.readouterr()
    cal = tmp_path / "cal"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    said = capsys.readouterr()
    assert "calibrated from the whole stream" in said.err
    assert "from motion" in said.out and "slowest head_yaw" not in said.out  # the slowest one seen
    # the head moves no marker: its response is not seen, kept at the start and said
    head = json.loads((cal / "report.json").read_text())["motion"]["response"]["actuators"]["head_yaw"]
    assert head["tau_s"] == {"value": TAU0_S, "std": None, "status": "held_at_start"}
    U_ref, _ = reference_poses_for(spec)
    achieved = link_errors(folder, cal, spec, U_ref)
    # the description misses by millimetres (the fit's start: frame and markers fitted, geometry nominal)
    assert read_calibration(cal / "calibration.yaml").rms_before > 1e-3
    for link in spec.tracked_links:
        ratio = achieved[link] / predicted[link]["marker_rms_m"]
        assert 1 / 3 < ratio < 3, (link, achieved[link], predicted[link])


def test_a_tree_stream_with_holds_settles_and_fits_every_link(urdf, tmp_path):
    """The additive simulator's raw stream of a tree (holds, base markers beside the links'
    markers) and the physical one's: settled by calibrate and fitted in one fit to each link's
    noise floor on held-out commands."""
    spec = stand(urdf)
    rng = np.random.default_rng(5)
    lo, hi = spec.control_bounds()
    U = rng.uniform(0.7 * lo, 0.7 * hi, (200, spec.n_u))
    for name, extra in (("additive", ["--poses", "30", "--base-markers", "3", "--noise-mm", "0.1"]),
                        ("physics", ["--physics", "--poses", "30", "--noise-mm", "0.1", "--white-noise"])):
        folder, cal = tmp_path / name, tmp_path / f"{name}_cal"
        assert simulate(urdf, folder, "--seed", "43", *extra) == 0
        assert sorted(yaml.safe_load((folder / "session.yaml").read_text())["moving_link"].values()) == \
            ["left_tcp"] * 3 + ["right_tcp"] * 3
        assert (folder / "markers.csv").exists() and not (folder / "poses.csv").exists()
        assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
        errors = link_errors(folder, cal, spec, U)
        # 0.1 mm per axis and sample, averaged over a hold's samples: tens of um at most per link
        assert all(e < 0.06e-3 for e in errors.values()), (name, errors)


def test_what_a_simulated_tree_still_refuses_is_one_line(urdf, tmp_path, capsys):
    assert simulate(urdf, tmp_path / "a", "--physics", "--rigid-bodies", "-1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rigid-bodies must be 0 or more, got -1" in err[0]
    assert not (tmp_path / "a").exists() or not any((tmp_path / "a").iterdir())


def test_a_joint_resting_on_a_limit_is_streamed_about_mid_stroke(urdf, tmp_path):
    """The simulator's continuous motion moves a joint whose zero is its lower limit (as Talos'
    elbows) about the middle of its stroke, from and back to rest at zero within its limits and the
    drives' limits, and says so; the others keep their neutral as the centre."""
    from platkit.simulate.physics import simulate_physics

    bent = tmp_path / "bent.urdf"
    bent.write_text(urdf.read_text().replace('<limit lower="-1.2" upper="1.2" effort="50" velocity="1"/></joint>\n'
                                             '  <joint name="r_tcp"',
                                             '<limit lower="0" upper="2.4" effort="50" velocity="1"/></joint>\n'
                                             '  <joint name="r_tcp"'))
    spec = stand(bent)
    j = spec.control_names.index("r2_joint")
    assert spec.neutral_u()[j] == 0.0 and spec.control_bounds()[0][j] == 0.0
    sim = simulate_physics(spec, seed=3, motion="multisine", duration_s=40, n_markers=6)
    assert sim.plan_info["about_mid_stroke"] == ["r2_joint"]
    U = sim.commands
    assert np.ptp(U[:, j]) > 0.5 and U[0, j] == 0.0 and abs(U[-1, j]) < 1e-9 and U[:, j].min() >= 0.0
    assert abs(np.median(U[:, j]) - 1.2) < 0.3  # about mid-stroke
    rate, accel = sim.nuisances.response.rate[j], sim.nuisances.response.accel[j]
    assert np.abs(np.diff(U[:, j])).max() * 20 <= rate and np.abs(np.diff(U[:, j], 2)).max() * 400 <= accel
