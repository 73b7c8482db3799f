"""examples/platkit-cable, a cable robot written the natural way (one residual row per cable,
eight rows for six pose coordinates) as an outside plugin: installed with pip into a folder of
its own, found through its entry point, it passes its own tests (the conformance suite among
them) and goes through simulate (platkit's own plan, drawn in pose space), calibrate and predict:
every one of 200 fresh commands inside the workspace is predicted, within 0.02 mm RMS of an
independent least-squares truth. Its outside physics (cable elasticity, pulley radius) are effects
it registers itself; its own tests plant them and diagnose them.

pip builds the package with build isolation, as for the tutorial's hexapod.
"""
import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from example_plugins import install_example, run_platkit

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "platkit-cable"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    return install_example(tmp_path_factory, "platkit-cable", "platkit_cable", "cable.yaml")


def _platkit(env, *args):
    return run_platkit(env, *args, timeout=300)


def test_the_installed_stand_is_found_and_passes_its_tests(installed):
    tmp, env = installed
    res = _platkit(env, "plugins", "--json")
    assert res.returncode == 0, res.stderr
    stands = {s["name"]: s for s in json.loads(res.stdout)["platforms"]}
    assert stands["cable"]["package"] == "platkit-cable 0.1.0"
    res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(EXAMPLE / "tests")],
                         capture_output=True, text=True, env=env, cwd=tmp, timeout=300)
    assert res.returncode == 0 and "10 passed" in res.stdout, res.stdout[-3000:]
    # its outside physics, registered through the effect hook, can be planted by simulate
    res = _platkit(env, "simulate", "--help")
    assert res.returncode == 0, res.stderr
    text = " ".join(res.stdout.split())
    assert "cable_elasticity: the largest stretch of a cable over the commands, in mm" in text
    assert "pulley_radius: the pulleys' radius, in mm" in text


def test_fk_reports_the_misfit_and_wrapped_angles_and_refuses_absurd_lengths(installed):
    tmp, env = installed
    res = _platkit(env, "ik", "--platform", "cable", "--pose", "100,50,1600,0.05,0,0", "--json")
    assert res.returncode == 0, res.stderr
    u = ",".join(f"{v:.1f}" for v in json.loads(res.stdout)["controls"].values())  # rounded: no pose fits exactly
    res = _platkit(env, "fk", "--platform", "cable", "--u", u, "--guess", "0,0,1500,3.1,3.1,3.1", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    angles = [out["coordinates"][k] for k in ("roll", "pitch", "yaw")] + [out[k] for k in ("roll", "pitch", "yaw")]
    assert all(-np.pi < a <= np.pi for a in angles) and out["coordinates"]["roll"] == pytest.approx(0.05, abs=1e-4)
    misfit = out["misfit"]
    assert len(misfit) == 8 and all(0 < abs(m["value"]) < 0.1 and m["plausible"] == 10.0 for m in misfit.values())
    res = _platkit(env, "fk", "--platform", "cable", "--u", ",".join(["1220"] * 8))
    assert res.returncode == 1 and len(res.stderr.strip().splitlines()) == 1
    assert "plausible misfit" in res.stderr and "(8 of 8 rows beyond)" in res.stderr


def _least_squares_truth(truth: dict, U: np.ndarray, P0: np.ndarray) -> tuple[np.ndarray, float]:
    """Markers (N, M, 3) m in the motion-capture frame of the true stand at controls U, by
    scipy's Levenberg-Marquardt on the true geometry (rotation vectors, not platkit's
    coordinates), from the nominal poses P0; and the largest cable misfit (m) it leaves."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    par = truth["parameters"]
    A = np.array([[par[f"A{i + 1}_{c}"]["value"] for c in "xyz"] for i in range(8)])
    B = np.array([[par[f"b{i + 1}_{c}"]["value"] for c in "xyz"] for i in range(8)])
    o = np.array([par[f"o{i + 1}"]["value"] for i in range(8)])
    names = sorted(truth["markers"])
    S = np.array([truth["markers"][m] for m in names])
    T = np.array(truth["mocap_from_base"])
    out, worst = [], 0.0
    for u, p in zip(U, P0):
        def rows(x, u=u):
            return u + o - np.linalg.norm(A - (x[:3] + B @ Rotation.from_rotvec(x[3:]).as_matrix().T), axis=1)

        x0 = np.r_[p[:3], Rotation.from_euler("ZYX", p[[5, 4, 3]]).as_rotvec()]
        sol = least_squares(rows, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        worst = max(worst, float(np.max(np.abs(sol.fun))))
        m = sol.x[:3] + S @ Rotation.from_rotvec(sol.x[3:]).as_matrix().T
        out.append(m @ T[:3, :3].T + T[:3, 3])
    return np.array(out), worst


def test_simulate_calibrate_predict_against_an_independent_truth(installed):
    tmp, env = installed
    session, cal = tmp / "session", tmp / "cal"
    res = _platkit(env, "simulate", "--platform", "cable", "--out", str(session), "--poses-only", "--seed", "5")
    assert res.returncode == 0, res.stderr
    truth = yaml.safe_load((session / "truth.yaml").read_text())
    assert truth["plan"]["space"] == "pose" and truth["plan"]["infeasible_dropped"] == 0
    with open(session / "commands.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 80  # every planned command sent and settled
    res = _platkit(env, "calibrate", str(session), "--quiet", "--out", str(cal))
    assert res.returncode == 0, res.stderr
    assert "RuntimeWarning" not in res.stderr and "Mean of empty slice" not in res.stderr
    report = json.loads((cal / "report.json").read_text())
    assert report["gauge"]["not_excited"] == 0
    # 200 fresh commands inside the workspace: the nominal inverse kinematics of drawn poses
    rng = np.random.default_rng(6)
    desc = yaml.safe_load((EXAMPLE / "src" / "platkit_cable" / "cable.yaml").read_text())
    lo = np.r_[np.array(desc["workspace"]["min"]) * 1e-3, [-np.radians(15)] * 3]
    hi = np.r_[np.array(desc["workspace"]["max"]) * 1e-3, [np.radians(15)] * 3]
    P = rng.uniform(lo, hi, (200, 6))
    code = ("import json, sys, numpy as np\nfrom platkit import get_platform\nfrom platkit.kinematics import PlatformModel\n"
            "m = PlatformModel(get_platform('cable'))\n"
            "print(json.dumps([m.inverse(*m.pose(p)).tolist() for p in json.load(sys.stdin)]))\n")
    res = subprocess.run([sys.executable, "-c", code], input=json.dumps(P.tolist()), capture_output=True, text=True,
                         env=env, timeout=60)
    assert res.returncode == 0, res.stderr
    U = np.array(json.loads(res.stdout))
    with open(tmp / "fresh.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow([f"c{i + 1}" for i in range(8)])
        w.writerows((U * 1e3).tolist())
    res = _platkit(env, "predict", "--calibration", str(cal / "calibration.yaml"), "--commands", str(tmp / "fresh.csv"),
                   "--out", str(tmp / "pred.csv"))
    assert res.returncode == 0, res.stderr
    with open(tmp / "pred.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 200  # every row predicted
    names = sorted(truth["markers"])
    pred = np.array([[[float(r[f"{m}_{a}"]) for a in "xyz"] for m in names] for r in rows]) * 1e-3
    true, worst_misfit = _least_squares_truth(truth, U, P)
    assert 1e-4 < worst_misfit < 0.01  # the true stand misfits the nominal commands, within the stretch
    err = np.linalg.norm(pred - true, axis=2)
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms <= 0.02e-3 < report["rms_before"] * 1e-3 / 10, (rms, report["rms_before"])


def test_simulate_says_how_many_commands_the_true_stand_does_not_reach(installed):
    tmp, env = installed
    session = tmp / "dropped"
    # 3 times the default perturbation: 1 of the 20 planned poses' nominal lengths misfits the true
    # cables beyond their 10 mm stretch (seed 1)
    res = _platkit(env, "simulate", "--platform", "cable", "--out", str(session), "--poses-only", "--poses", "20",
                   "--perturbation", "3", "--seed", "1")
    assert res.returncode == 0, res.stderr
    line = ("1 of 20 planned commands dropped: unreachable with the true geometry (the simulated true stand takes no "
            "pose for them on its branch, within the coordinates' bounds and the rows' plausible misfit); the session "
            "holds the other 19")
    assert res.stderr.strip() == f"simulate: {line}"
    assert yaml.safe_load((session / "session.yaml").read_text())["notes"].endswith(f"; {line}")
    assert yaml.safe_load((session / "truth.yaml").read_text())["plan"]["unreachable_with_true_geometry"] == 1
    with open(session / "commands.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 19
    res = _platkit(env, "simulate", "--platform", "cable", "--out", str(tmp / "clean"), "--poses-only", "--poses", "20",
                   "--seed", "1")
    assert res.returncode == 0 and "dropped" not in res.stderr + res.stdout, res.stderr
    assert "dropped" not in yaml.safe_load((tmp / "clean" / "session.yaml").read_text())["notes"]
