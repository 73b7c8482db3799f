"""A rigid body's three points are one 6-DOF measurement (platkit.diagnose.bodies.screen_system).

Diagnosis reads a body as its points T.o, T.x, T.y; their errors share the body's position noise
and its turn, so the score test that screens candidate terms, treating the 9 coordinates as
independent, overstated a term that moves the three points together by about 2.5 times in F and
named weak false effects on clean sessions of bodies alone. The screen reads each body at each
pose as its 6 numbers (position, turn scaled by sigma_p / sigma_r), whose errors are independent.
"""
from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
from bodies_alone import cut_in_time, strip_markers

from platkit.cli import main
from platkit.diagnose.bodies import screen_system
from platkit.diagnose.stats import score_test


def test_a_clean_session_of_a_body_alone_names_nothing(tmp_path):
    """Stewart, settled, seed 618, one body, markers stripped, the first 40 of 60 random commands
    (benchmarks/diagnose_body_slip.py's clean session): the truth has no effect, all three geometry
    groups are free. Reading the points as independent screened a backlash of L1 at F 22 (Holm
    p = 2e-4; held-out 0.036 -> 0.034 mm, paired p = 6e-4) and named it; as one measurement F is 7
    (Holm p = 0.5)."""
    assert main(["simulate", "--platform", "stewart", "--out", str(tmp_path / "sim"), "--seed", "618", "--poses", "60",
                 "--plan", "random", "--rigid-bodies", "1"]) == 0
    whole = strip_markers(tmp_path / "sim", tmp_path / "b")
    t_cmd = [float(r[0]) for r in list(csv.reader((whole / "commands.csv").open()))[1:]]
    train = cut_in_time(whole, tmp_path / "train", t_cmd[40])
    assert main(["calibrate", str(train), "--out", str(tmp_path / "cal"), "--quiet", "--no-report"]) in (0, 3)
    assert main(["diagnose", str(train), "--calibration", str(tmp_path / "cal" / "calibration.yaml"),
                 "--out", str(tmp_path / "diag"), "--quiet", "--no-report"]) == 0
    d = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert d["findings"] == []
    top = d["rounds"][0]["top"]
    assert min(t["p_adjusted"] for t in top) > 0.05


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def test_the_screen_reads_a_body_as_one_measurement_of_independent_errors():
    """Null sessions of one body (sigma_p 0.1 mm, sigma_r 0.05 deg, lever 100 mm) at 40 random
    orientations, the base model the body's rigid motion at each pose drawn as 8 columns, the
    candidate a translation shared by the three points: at the 1% level the screen rejects about
    1% of 400 sessions; the 9 coordinates read as independent reject far more."""
    rng = np.random.default_rng(5)
    N, L, sp, sr = 40, 0.1, 1e-4, np.radians(0.05)
    tip = np.sqrt(sp**2 + 2.0 / 3.0 * (sr * L) ** 2)
    names = ["T1.o", "T1.x", "T1.y"]
    rejected = {"body": 0, "points": 0}
    for _ in range(400):
        Q = np.linalg.qr(rng.normal(size=(N, 3, 3)))[0]
        lever = L * np.stack([Q[:, :, 0], Q[:, :, 1]], axis=1)  # (N, 2, 3) the axis tips from the origin
        markers = np.concatenate([np.zeros((N, 1, 3)), lever], axis=1)
        d, w = rng.normal(size=(N, 3)) * sp, rng.normal(size=(N, 3)) * sr
        e = np.stack([d, d + np.cross(w, lever[:, 0]), d + np.cross(w, lever[:, 1])], axis=1)  # (N, 3, 3)
        J = np.zeros((N, 3, 3, 9))
        for n in range(N):  # 8 base columns: rigid motions of the body; the 9th the candidate
            for c in range(8):
                t, a = rng.normal(size=3), rng.normal(size=3) * 0.01
                J[n, 0, :, c] = t
                J[n, 1:, :, c] = t + np.cross(a, lever[n])
            J[n, :, :, 8] = Q[n, :, 2]
        Jb = J[..., :8].reshape(-1, 8)
        r = e.reshape(-1) - Jb @ np.linalg.lstsq(Jb, e.reshape(-1), rcond=None)[0]
        poses = SimpleNamespace(marker_names=names, markers=markers,
                                settling={"point_sigma_m": dict(zip(names, (sp, tip, tip)))})
        rows_r, rows_J = screen_system(poses, np.ones((N, 3)), r.reshape(N, 3, 3), J)
        for key, (rr, JJ) in {"body": (rows_r, rows_J), "points": (r, J.reshape(-1, 9))}.items():
            p = score_test(rr, JJ[:, :8], JJ[:, 8:], len(rr) - 8)[1]
            rejected[key] += p < 0.01
    assert rejected["body"] <= 12  # 1% of 400 is 4
    assert rejected["points"] >= 20


def test_markers_keep_their_rows():
    """Without bodies, the rows are each seen marker's three coordinates, weighted by sqrt(weight)."""
    rng = np.random.default_rng(1)
    r, J = rng.normal(size=(5, 2, 3)), rng.normal(size=(5, 2, 3, 4))
    r[2, 1] = np.nan
    weights = np.ones((5, 2))
    weights[0, 0] = 4.0
    poses = SimpleNamespace(marker_names=["M1", "M2"], markers=rng.normal(size=(5, 2, 3)), settling={})
    rows_r, rows_J = screen_system(poses, weights, r, J)
    seen = np.isfinite(r).all(axis=2)
    s = np.sqrt(weights)[seen]
    assert np.allclose(rows_r, (r[seen] * s[:, None]).reshape(-1))
    assert np.allclose(rows_J, (J[seen] * s[:, None, None]).reshape(-1, 4))
