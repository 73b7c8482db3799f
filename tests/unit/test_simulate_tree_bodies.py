"""Rigid bodies on a simulated tree (issue 24): `platkit simulate --rigid-bodies N` on a tree places
body b on tracked link b mod L (the markers' rule), maps it in session.yaml's moving_link, and
`platkit calibrate` reads it back: each body's placement on its link agrees with the truth's
(distances to the markers on the same link, which no choice of the link's frame changes), the fit
at the noise. The physical simulator's bodies: test_simulate_physics_bodies.py.

The tree is tests/data/trees/two_arm_torso.urdf, both hands tracked."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from platkit.cli import main

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
BASE = ["simulate", "--platform", "urdf", "--description", str(URDF), "--moving-link", "right_tcp,left_tcp",
        "--seed", "31"]


def test_bodies_on_a_simulated_tree_are_calibrated_back(tmp_path):
    folder, out = tmp_path / "sim", tmp_path / "cal"
    assert main(BASE + ["--rigid-bodies", "2", "--poses-only", "--out", str(folder)]) == 0
    session = yaml.safe_load((folder / "session.yaml").read_text())
    mapping = session["moving_link"]
    assert session["rigid_bodies"] == ["T1", "T2"]
    assert mapping["T1"] == "right_tcp" and mapping["T2"] == "left_tcp"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(out)]) == 0
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    cal = yaml.safe_load((out / "calibration.yaml").read_text())
    assert cal["residual"]["rms_after"] < truth["marker_noise_m"] * 1e3
    bodies = cal["rigid_bodies"]["bodies"]
    for body in ("T1", "T2"):
        assert bodies[body]["link"] == mapping[body]
        mine = [m for m, link in mapping.items() if link == mapping[body] and m.startswith("M")]
        true_o = np.array(truth["rigid_bodies"][body]["position"]) * 1e3  # mm, as calibration.yaml
        fit_o = np.array(bodies[body]["position"])
        for m in mine:
            d_true = np.linalg.norm(true_o - np.array(truth["markers"][m]) * 1e3)
            d_fit = np.linalg.norm(fit_o - np.array(cal["markers"][m]["position"]))
            assert abs(d_fit - d_true) < 0.05, (body, m, d_fit, d_true)  # mm


def test_a_negative_body_count_is_refused_in_one_line(tmp_path, capsys):
    assert main(BASE + ["--physics", "--rigid-bodies", "-1", "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--rigid-bodies must be 0 or more, got -1" in err[0]


class _Drawn:
    """A generator whose first draws are given (the joint a hidden effect was first drawn at)."""

    def __init__(self, first, rng):
        self.first, self.rng = list(first), rng

    def integers(self, *args, **kwargs):
        return self.first.pop(0) if self.first else self.rng.integers(*args, **kwargs)

    def choice(self, options, *args, **kwargs):
        return self.first.pop(0) if self.first else self.rng.choice(options, *args, **kwargs)

    def __getattr__(self, name):
        return getattr(self.rng, name)


def test_a_simulated_hidden_effect_is_planted_where_a_marker_can_show_it():
    """On a tree, a hidden effect drawn at a joint that moves no tracked link (the head) is drawn
    again among the joints that move one: the markers could never show it (hq found a simulated
    compliance at an untracked leg of Unitree's B1). Drawn at a seen joint, it stays there."""
    from platkit.effects import planted, seen_controls
    from platkit.plugins import effect_library, get_platform
    from platkit.poses import PoseSet

    spec = get_platform("urdf", URDF, moving_link={"right_tcp": "right_tcp", "left_tcp": "left_tcp"})
    head = spec.control_names.index("head_yaw")
    seen = seen_controls(spec)
    assert not seen[head] and seen.sum() == spec.n_u - 1
    rng = np.random.default_rng(26200)
    arm = spec.control_names.index("right_2_joint")
    assert planted(spec, rng, arm, list(range(spec.n_u)), "backlash") == arm
    assert seen[planted(spec, rng, head, list(range(spec.n_u)), "backlash")]
    library = effect_library()
    U = np.random.default_rng(26200).uniform(-0.5, 0.5, (20, spec.n_u))
    commands = PoseSet(spec.name, U, np.zeros((20, 0, 3)), [])
    term, _ = library["backlash"].simulation_term(spec, None, _Drawn([head], rng), commands)
    assert term.where["actuator"] != "head_yaw"
    loads_head = library["compliance"].simulation_term(spec, None, _Drawn([head], rng), commands)[0]
    assert loads_head.where["actuator"] != "head_yaw"
