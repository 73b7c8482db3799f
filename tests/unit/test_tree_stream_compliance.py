"""Compliance in a slow stream of a tree (issue 24): the elastic tree moved slowly through held
commands (platkit.simulate.elastic_stream) is quasi-static at every sample; `platkit calibrate`
settles its raw stream as one tree, and `platkit diagnose` on it names compliance and takes the
fit to the noise.

The tree is tests/data/trees/two_arm_torso.urdf (with inertias): elastic torso pitch and right
shoulder, both hands tracked, the head (which moves no marker) commanded too."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

import platkit.io.session as session_module
from platkit.cli import main
from platkit.simulate.elastic_stream import (
    commanded,
    simulate_elastic_motion,
    simulate_elastic_stream,
    slow_multisine,
    write_elastic_stream,
)
from platkit.simulate.elastic_tree import ElasticTruth, equilibrium, true_urdf
from platkit.tree_loads import TreeLoads

URDF = Path(__file__).resolve().parents[1] / "data" / "trees" / "two_arm_torso.urdf"
JOINTS = ["torso_yaw", "torso_pitch", "head_yaw", "right_1_joint", "right_2_joint", "right_3_joint", "left_1_joint",
          "left_2_joint", "left_3_joint"]
LIMIT = dict(zip(JOINTS, [1.5, 0.5, 1.0, 2.0, 1.5, 2.0, 2.0, 1.5, 2.0]))
MARKERS = {f"R{k}": "right_tcp" for k in (1, 2, 3)} | {f"L{k}": "left_tcp" for k in (1, 2, 3)}
ELASTIC = {"torso_pitch": 2e-4, "right_1_joint": 4e-4}  # rad/(N m)


def truth_and_commands(seed: int, n: int):
    rng = np.random.default_rng(seed)
    truth = ElasticTruth(joint_compliance=dict(ELASTIC),
                         origin_error={j: (rng.normal(0, 0.5e-3, 3), rng.normal(0, 1e-3, 3)) for j in JOINTS},
                         offset={j: float(rng.normal(0, 2e-3)) for j in JOINTS})
    U = np.column_stack([rng.uniform(-0.6 * LIMIT[j], 0.6 * LIMIT[j], n) for j in JOINTS])
    return truth, U


def test_the_slow_stream_is_the_static_equilibrium_at_every_sample(tmp_path):
    """Without noise, a sample in the middle of a move (between the solved ones) is where the
    tree's own equilibrium at that instant's commands puts it, to well under a micrometre; the end
    of a hold is the settled truth."""
    truth, U = truth_and_commands(3, 3)
    sim = simulate_elastic_stream(URDF, truth, U, JOINTS, MARKERS, seed=7, noise_mm=0.0, workdir=tmp_path)
    assert np.max(np.abs(sim.settled - sim.rigid)) > 2e-3  # the sag is millimetres
    T = TreeLoads(true_urdf(URDF, truth, tmp_path / "check.urdf"))
    k = np.zeros(len(T.joints))
    for n, c in ELASTIC.items():
        k[T.index[n]] = c
    offset = np.array([truth.offset.get(n, 0.0) for n in JOINTS])
    mid = np.nonzero((sim.marker_t > sim.command_t[1] + 0.3) & (sim.marker_t < sim.command_t[1] + 1.2))[0]
    mid = mid[mid % 5 != 0][:4]  # samples the stream interpolated
    Q = equilibrium(T, T.configuration(JOINTS, commanded(sim.command_t, U, np.zeros(len(JOINTS)), 1.5,
                                                         sim.marker_t[mid]) - offset), k)
    o, R = T.link_placements(Q, "right_tcp")
    seen = sim.markers[mid, 0] @ sim.mocap_from_base[:3, :3] - sim.mocap_from_base[:3, :3].T @ sim.mocap_from_base[:3, 3]
    place = np.einsum("nba,nb->na", R, seen - o)  # R1's place on its link, read back at each sample
    assert np.ptp(place, axis=0).max() < 1e-6


def test_diagnose_names_compliance_in_a_slow_stream_of_a_tree(tmp_path):
    truth, U = truth_and_commands(5, 30)
    sim = simulate_elastic_stream(URDF, truth, U, JOINTS, MARKERS, seed=1005, workdir=tmp_path)
    folder = write_elastic_stream(sim, URDF, tmp_path / "s")
    session = yaml.safe_load((folder / "session.yaml").read_text())
    assert session["moving_link"] == MARKERS
    assert (folder / "commands.csv").read_text().splitlines()[0] == "t," + ",".join(JOINTS)
    cal = tmp_path / "cal"
    assert main(["calibrate", str(folder), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    assert main(["diagnose", str(folder), "--calibration", str(cal / "calibration.yaml"), "--out",
                 str(tmp_path / "diag"), "--quiet"]) == 0
    d = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert d["n_poses"] == 30  # every hold settled
    named = [f for f in d["findings"] if f["effect"] == "compliance"]
    assert named, d["findings"]
    joints = {j for f in named for j in f["where"].get("joints", [f["where"].get("joint")])}
    assert joints & {"torso_pitch", "torso_pitch_2", "right_1_joint"}
    assert d["rms_final"] < 0.2 * d["rms_geometric"]


def test_without_holds_every_sample_is_the_equilibrium_at_the_drives_positions(tmp_path):
    """Streamed without holds (a slow multisine, each drive a first-order lag behind its step-held
    commands, the motion capture's clock behind): without noise, every sample, solved or splined,
    is where the tree's own equilibrium at the drives' positions of that instant puts it."""
    truth, _ = truth_and_commands(3, 1)
    tc, U = slow_multisine(np.array([0.6 * LIMIT[j] for j in JOINTS]), 8.0, 50.0, np.random.default_rng(4),
                           ramp_s=2.0)
    assert np.allclose(U[0], 0) and np.allclose(U[-1], 0, atol=1e-9) and np.abs(U).max(axis=0).min() > 0.1
    sim = simulate_elastic_motion(URDF, truth, tc, U, JOINTS, MARKERS, seed=7, noise_mm=0.0, tau_s=0.05, delay_s=0.03,
                                  workdir=tmp_path)
    assert not (np.diff(sim.commands, axis=0) == 0).all(axis=1).any()  # no hold: every command moves
    T = TreeLoads(true_urdf(URDF, truth, tmp_path / "check.urdf"))
    k = np.zeros(len(T.joints))
    for n, c in ELASTIC.items():
        k[T.index[n]] = c
    offset = np.array([truth.offset.get(n, 0.0) for n in JOINTS])
    pick = np.array([101, 102, 203, 254, 307])  # solved (every fifth) and splined samples, moving
    # the drives' positions by their first-order lag, integrated finely here (not the module's recursion)
    fine = np.arange(0.0, sim.marker_t[pick].max(), 1e-4)
    x = np.zeros((len(fine), len(JOINTS)))
    step = U[np.clip(np.searchsorted(tc, fine, side="right") - 1, 0, None)]
    for i in range(1, len(fine)):
        x[i] = x[i - 1] + (step[i - 1] - x[i - 1]) * (1 - np.exp(-1e-4 / 0.05))
    drives = np.array([x[np.searchsorted(fine, t - 0.03 - 1e-9)] for t in sim.marker_t[pick]])
    Q = equilibrium(T, T.configuration(JOINTS, drives - offset), k)
    o, R = T.link_placements(Q, "right_tcp")
    A, b = sim.mocap_from_base[:3, :3], sim.mocap_from_base[:3, 3]
    place = np.einsum("nba,nb->na", R, (sim.markers[pick, 0] - b) @ A - o)
    assert np.ptp(place, axis=0).max() < 5e-6  # the fine integration's own error, on a marker ~1 m out
    assert np.max(np.abs(sim.settled - sim.rigid)) > 1e-3
    assert len(sim.settled) == len(tc)
    folder = write_elastic_stream(sim, URDF, tmp_path / "m")
    assert yaml.safe_load((folder / "truth.yaml").read_text())["holds"] is False
    assert len((folder / "commands.csv").read_text().splitlines()) == len(tc) + 1


def test_diagnose_a_stream_without_holds_calibrated_from_motion(tmp_path, monkeypatch):
    """A tree streamed without holds is calibrated from motion; `platkit diagnose` reads the
    stream as the windows' nodes through the calibrated response (it refused before: no settled
    pose), the response fitted again with every effect tried (held as calibrated, the lags had
    absorbed part of the sag and compliance was not named); compliance is named at the elastic
    joints and the held-out session of the same set-up (held commands, settled) falls below a
    fifth; the calibration written keeps the response refitted as actuator_response, no term.
    Each session's files are read once (the stream's settling fails, then it is read as a stream
    from the session already loaded)."""
    truth, U = truth_and_commands(5, 12)
    tc, C = slow_multisine(np.array([0.6 * LIMIT[j] for j in JOINTS]), 20.0, 50.0, np.random.default_rng(55),
                           ramp_s=2.0)
    sim = simulate_elastic_motion(URDF, truth, tc, C, JOINTS, MARKERS, seed=1005, noise_seed=2005, workdir=tmp_path)
    write_elastic_stream(sim, URDF, tmp_path / "m")
    held = simulate_elastic_stream(URDF, truth, U, JOINTS, MARKERS, seed=1005, workdir=tmp_path)
    write_elastic_stream(held, URDF, tmp_path / "h")
    cal = tmp_path / "cal"
    assert main(["calibrate", str(tmp_path / "m"), "--quiet", "--no-report", "--no-selection", "--out", str(cal)]) == 0
    assert "actuator_response" in yaml.safe_load((cal / "calibration.yaml").read_text())  # from motion
    reads: list[str] = []
    load = session_module.load_session
    monkeypatch.setattr(session_module, "load_session", lambda folder, *a, **k: reads.append(str(folder)) or load(
        folder, *a, **k))
    assert main(["diagnose", str(tmp_path / "m"), "--calibration", str(cal / "calibration.yaml"), "--heldout",
                 str(tmp_path / "h"), "--out", str(tmp_path / "diag"), "--quiet"]) == 0
    assert sorted(reads) == sorted([str(tmp_path / "m"), str(tmp_path / "h")])
    d = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert 40 <= d["n_poses"] <= 80  # ~3 nodes a second of the stream after its second command
    assert d["rounds"][0]["top"][0]["effect"] == "compliance", d["rounds"][0]["top"]
    named = [f for f in d["findings"] if f["effect"] == "compliance"]
    assert named, d["findings"]
    assert {j for f in named for j in f["where"].get("joints", [f["where"].get("joint")])} >= {"torso_pitch",
                                                                                             "right_1_joint"}
    h = d["heldout_session"]
    assert h["n_poses"] == 12 and h["rms_after"] < 0.2 * h["rms_before"]
    written = yaml.safe_load((tmp_path / "diag" / "calibration.yaml").read_text())
    assert "actuator_response" in written and all(t["effect"] != "actuator_response" for t in written["terms"])
