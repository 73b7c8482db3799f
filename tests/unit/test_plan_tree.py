"""`platkit plan` on a tree (issue 24): plan.json and the printed report give every tracked link's
predicted marker error and how many of the directions its markers see the plan excites, beside
the whole figures; joints that move no tracked link keep their neutral command; the per-link
prediction agrees with what calibration achieves held out on a seeded simulation.

The tree is tests/data/trees/two_arm_torso.urdf (a torso yaw and pitch, a head that moves no
marker, two 3-joint arms)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from platkit.calibrate import plan as pl
from platkit.calibrate.estimate import calibrate, predict_markers
from platkit.cli import main
from platkit.plugins import get_platform
from platkit.simulate import simulate

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
LINKS = ["right_tcp", "left_tcp"]


@pytest.fixture(scope="module")
def spec():
    return get_platform("urdf", URDF, moving_link={k: k for k in LINKS})


def test_plan_cli_gives_each_link_its_figures_and_holds_the_head(tmp_path, capsys):
    out = tmp_path / "plan.csv"
    assert main(["plan", "--platform", "urdf", "--description", str(URDF), "--moving-link", ",".join(LINKS),
                 "--optimal", "25", "--candidates", "150", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    report = json.loads(out.with_suffix(".json").read_text())
    assert report["markers"] == 6 and report["marker_links"] == LINKS * 3  # 3 per tracked link by default
    for key in ("plan", "baseline"):
        d = report[key]
        assert d["predicted_marker_rms_m"] > 0 and set(d["links"]) == set(LINKS)  # the whole figure kept
        per = d["links"]
        for link in LINKS:
            assert per[link]["markers"] == 3 and per[link]["identifiable"]
            assert per[link]["predicted_marker_rms_m"] > 0 and per[link]["predicted_marker_max_m"] <= d["predicted_marker_max_m"]
            assert 0 < per[link]["plan_rank"] == per[link]["identifiable_rank"]
        # the whole RMS is the links' RMS pooled over their markers
        pooled = np.sqrt(sum(per[k]["markers"] * per[k]["predicted_marker_rms_m"] ** 2 for k in LINKS) / 6)
        assert pooled == pytest.approx(d["predicted_marker_rms_m"], rel=1e-9)
    for link in LINKS:
        assert f"  {link}: 3 markers" in printed and "predicted marker RMS" in printed.split(f"  {link}:")[1]
    header = out.read_text().splitlines()[0].split(",")
    head = np.loadtxt(out, delimiter=",", skiprows=1)[:, header.index("head_yaw")]
    assert np.all(head == 0.0)  # the head moves no marker: held at its neutral command
    assert np.ptp(np.loadtxt(out, delimiter=",", skiprows=1)[:, header.index("left_1_joint")]) > 0.5


def test_a_plan_that_leaves_one_arm_still_says_which_link_is_not_identified(spec):
    rng = np.random.default_rng(4)
    cand = pl.random_candidates(spec, 40, rng, hold_idle=True)
    U = cand.controls.copy()
    left = [spec.control_names.index(n) for n in ("left_1_joint", "left_2_joint", "left_3_joint")]
    U[:, left] = 0.2  # the left arm never moves
    info = pl.evaluate_plan(spec, pl.Plan(U, "given", {}), 1e-4, n_markers=6)
    assert not info["identifiable"]
    assert info["links"]["right_tcp"]["identifiable"]
    assert not info["links"]["left_tcp"]["identifiable"]
    assert info["links"]["left_tcp"]["plan_rank"] < info["links"]["left_tcp"]["identifiable_rank"]
    assert info["links"]["left_tcp"]["predicted_marker_rms_m"] is None


def test_controls_moving_each_link(spec):
    moving = pl.controls_moving_links(spec)
    names = np.array(spec.control_names)
    assert list(names[moving["right_tcp"]]) == ["torso_yaw", "torso_pitch", "right_1_joint", "right_2_joint",
                                                 "right_3_joint"]
    assert list(names[pl.idle_controls(spec)]) == ["head_yaw"]


def test_per_link_prediction_agrees_with_the_heldout_error_of_a_seeded_calibration(spec):
    """Plan 40 poses D-optimally, simulate them on a true stand drawn from seed 2024 (settled poses,
    0.1 mm per coordinate, one sample each), calibrate as `platkit calibrate` does, and score each
    hand's markers on the reference poses the prediction is over: achieved / predicted within
    [0.5, 2] on each link (3-D: sqrt(3) x plan's per-coordinate figure)."""
    sigma = 1e-4
    markers = pl.default_marker_layout(spec, 6, np.random.default_rng(0))
    plan, _ = pl.optimal_plan(spec, 40, 200, np.random.default_rng(0), sigma, markers=markers)
    common = dict(seed=2024, raw=False, occlusion=0.0, n_markers=6, markers=markers, hold_s=1.5, mocap_rate_hz=2 / 1.5)
    sim = simulate(spec, plan=plan.controls, n_poses=len(plan.controls), noise_mm=0.1, **common)
    ref = pl.reference_poses(spec)
    truth = simulate(spec, plan=ref.controls, n_poses=len(ref.controls), noise_mm=0.0, **common)
    assert np.allclose(sim.truth.td, truth.truth.td)  # the same true stand
    cal = calibrate(sim.poses, spec)
    predicted, _, _, ok = predict_markers(cal, ref.controls, truth.poses)
    err = np.linalg.norm(predicted - truth.poses.markers, axis=2)[np.asarray(ok, bool)]
    links = np.array(pl.marker_links(spec, 6))
    for link in LINKS:
        achieved = np.sqrt(np.mean(err[:, links == link] ** 2))
        expected = np.sqrt(3) * plan.info["links"][link]["predicted_marker_rms_m"]
        assert 0.5 < achieved / expected < 2.0, (link, achieved, expected)


def test_plan_motion_on_a_tree_whose_elbow_rests_at_a_limit(tmp_path, capsys):
    """`plan --motion` on the tree, with right_2_joint's stroke [0, 1.5] (its zero, the neutral, a
    limit, as Talos' elbows): once refused ('leaves the neutral controls outside the strokes'), and
    on a tree singular (every marker on the first link, the head's response unseen). Now: the
    elbow homed at the middle of its box, the head held at neutral, the prediction per link."""
    text = URDF.read_text()
    old = '<origin xyz="0 0 -0.25"/><axis xyz="1 0 0"/><limit lower="-1.5" upper="1.5" effort="50" velocity="1"/>'
    assert text.count(old) == 2  # right_2_joint's, then left_2_joint's
    urdf = tmp_path / "elbow.urdf"
    urdf.write_text(text.replace(old, old.replace('lower="-1.5"', 'lower="0"'), 1))
    out = tmp_path / "session" / "commands.csv"
    assert main(["plan", "--platform", "urdf", "--description", str(urdf), "--moving-link", ",".join(LINKS),
                 "--motion", "--max-accel", "2", "--duration-s", "25", "--quiet", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    report = json.loads(out.with_suffix(".json").read_text())
    assert "right_2_joint" in report["limits"]["source"]["home"] and "head_yaw" in report["limits"]["source"]["held"]
    header = out.read_text().splitlines()[0].split(",")
    U = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.all(U[:, header.index("head_yaw")] == 0.0)
    elbow = U[:, header.index("right_2_joint")]
    assert elbow[0] == pytest.approx(0.75) and elbow[-1] == pytest.approx(0.75)  # home: the middle of [0.15, 1.35]
    assert np.all((elbow >= 0.15 - 1e-9) & (elbow <= 1.35 + 1e-9))
    assert report["stroke_share"][header.index("head_yaw") - 1] is None
    pred = report["prediction"]
    per = pred["links"]
    assert set(per) == set(LINKS) and all(per[k]["markers"] == 3 and per[k]["marker_rms_m"] > 0 for k in LINKS)
    pooled = np.sqrt(sum(per[k]["marker_rms_m"] ** 2 for k in LINKS) / 2)
    assert pooled == pytest.approx(pred["marker_rms_m"], rel=1e-6)
    assert not any(n.startswith("response.") and n.endswith(".head_yaw") for n in pred["parameter_std"])
    for link in LINKS:
        assert f"  {link}: 3 markers; predicted marker error" in printed


def test_monte_carlo_draw_of_a_tree_scores_each_link(spec):
    """plan --monte-carlo on a tree: the stand options keep the mapping (the comma-separated
    --moving-link was passed on as one link name and refused), and each draw scores every tracked
    link's markers; the summary gives their quantiles."""
    import argparse

    from platkit.batch.montecarlo import draw, options_key, summarise_draws
    from platkit.commands.plan import stand_options

    options = stand_options(argparse.Namespace(base_link=None, moving_link=" right_tcp, left_tcp"))
    assert options == {"moving_link": {"right_tcp": "right_tcp", "left_tcp": "left_tcp"}}
    markers = pl.default_marker_layout(spec, 6, np.random.default_rng(0))
    plan, _ = pl.optimal_plan(spec, 24, 80, np.random.default_rng(1), 1e-4, markers=markers)
    r = draw("urdf", str(URDF), options_key(options), plan.controls, markers, 7, 0.1)
    per = r["heldout_rms_m_links"]
    assert set(per) == set(LINKS) and all(0 < v < 5 * r["heldout_rms_m"] for v in per.values())
    assert np.sqrt(np.mean([v ** 2 for v in per.values()])) == pytest.approx(r["heldout_rms_m"], rel=1e-9)
    summary = summarise_draws([r, r], [p.unit for p in spec.parameters])
    assert summary["heldout_rms_mm_links"]["left_tcp"]["median"] == pytest.approx(per["left_tcp"] * 1e3)
