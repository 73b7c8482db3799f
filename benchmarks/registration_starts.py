"""The registration's start on stands whose moving frame only tilts and heaves (psvr), beside a
reference checkout.

    .venv/bin/python benchmarks/registration_starts.py [--seeds 5591 5592] [--motion path multisine]
        [--duration-s 60] [--reference DIR] [--keep DIR]

Each seed and motion simulates one psvr stream without holds in the physical simulator
(``platkit simulate --platform psvr --physics --motion M --duration-s D --seed S``: a crank-rod seat
mover whose platform heaves and tilts, so its path is a vertical line), then ``platkit calibrate``
on it. Printed per session: how many of calibrate's registrations found the hand-eye system under
its threshold and chose among several starts (``platkit.calibrate.registration.initial_rotations``),
how many of those kept a start other than the first (what the code before the choice took),
calibrate's outcome and RMS, and the truth's RMS: the markers the calibration predicts at every
command against where the true stand settles there (truth_settled.csv), 3-D, mm.

``--reference DIR``: the same calibrate with the ``platkit`` package found in DIR first (PYTHONPATH
DIR:DIR/plugins, e.g. ``git archive REV | tar -x -C DIR``), in a process of its own, printed beside.
Both run in a clean environment (no BLAS variables) so that the two see the same kernels.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from stream_split import settled_commands, settled_error_mm  # noqa: E402

SPY = r"""
import json, sys
import numpy as np
import platkit.calibrate.registration as RG
n = {"registrations": 0, "several_starts": 0, "other_start": 0}
best = getattr(RG, "best_registration", None)
if best is not None:
    def spy(R, X, Y, vis, starts):
        n["registrations"] += 1
        got = best(R, X, Y, vis, starts)
        if len(starts) > 1:
            n["several_starts"] += 1
            n["other_start"] += not np.allclose(RG.register(R, X, Y, vis, starts[0])[0], got[0])
        return got
    RG.best_registration = spy
from platkit.cli import main
try:
    rc = main(sys.argv[1:])
except SystemExit as e:
    rc = e.code
print("SPY" + json.dumps(dict(n, rc=rc, has_choice=best is not None)), file=sys.stderr)
"""


def _run(code_dir: Path, args: list[str]) -> tuple[dict, str]:
    """platkit's command line with the package in ``code_dir``, clean environment: (spy counts, stderr)."""
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": f"{code_dir}:{code_dir}/plugins",
           "HOME": os.environ.get("HOME", "/tmp")}
    # -P: the working folder is not put first on the path (a checkout there would win over code_dir)
    p = subprocess.run([sys.executable, "-P", "-c", SPY, *args], env=env, capture_output=True, text=True)
    line = [x for x in p.stderr.splitlines() if x.startswith("SPY")]
    return (json.loads(line[-1][3:]) if line else {"rc": p.returncode}), p.stderr


def truth_rms(code_dir: Path, session: Path, cal: Path, work: Path) -> float:
    """RMS (mm, 3-D) of the markers ``cal`` predicts at every command against where the true stand
    settles there (truth_settled.csv)."""
    cmd, out = work / "commands_settled.csv", work / "predicted.csv"
    rows = settled_commands(session, ["A", "B", "C"], cmd)
    got, err = _run(code_dir, ["predict", "--calibration", str(cal / "calibration.yaml"), "--commands", str(cmd),
                               "--out", str(out)])
    if got.get("rc") != 0:
        raise SystemExit(f"predict failed: {err.strip().splitlines()[-1:]}")
    return settled_error_mm(rows, out, sorted({k[:-2] for k in rows[0] if k.endswith("_x")}))


def one(code_dir: Path, session: Path, work: Path) -> dict:
    cal = work / "cal"
    got, err = _run(code_dir, ["calibrate", str(session), "--out", str(cal), "--no-report", "--quiet"])
    if got.get("rc") != 0:
        last = [x for x in err.splitlines() if x.startswith("platkit: error")]
        return dict(got, outcome=(last[-1][len("platkit: error: "):] if last else "failed")[:90])
    rep = json.loads((cal / "report.json").read_text())
    return dict(got, outcome="calibrated", rms=rep["rms_after"], truth=truth_rms(code_dir, session, cal, work))


def _said(r: dict) -> str:
    starts = (f"{r.get('several_starts', 0)} of {r.get('registrations', 0)} chose, {r.get('other_start', 0)} another"
              if r.get("has_choice") else "one start (no choice)")
    if r["outcome"] != "calibrated":
        return f"{starts}; REFUSED: {r['outcome']}"
    return f"{starts}; rms {r['rms']:.4f} mm, truth {r['truth']:.4f} mm"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5591, 5592])
    ap.add_argument("--motion", nargs="+", default=["path", "multisine"])
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--reference", type=Path, default=None, help="a checkout to run side by side (its platkit first)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the sessions and calibrations here")
    a = ap.parse_args()
    if a.reference is not None:
        a.reference = a.reference.resolve()
    base = (a.keep or Path(tempfile.mkdtemp(prefix="platkit-registration-"))).resolve()
    rows = []
    for seed in a.seeds:
        for motion in a.motion:
            work = base / f"{seed}-{motion}"
            session = work / "session"
            if not (session / "markers.csv").exists():
                got, err = _run(ROOT, ["simulate", "--platform", "psvr", "--physics", "--motion", motion, "--duration-s",
                                       str(a.duration_s), "--seed", str(seed), "--out", str(session), "--force"])
                if got.get("rc") != 0:
                    said = [x for x in err.splitlines() if x.startswith("platkit: error")] or err.strip().splitlines()[-1:]
                    raise SystemExit(f"simulate failed for seed {seed} {motion}: {said}")
            ours = one(ROOT, session, work / "ours")
            ref = one(a.reference, session, work / "reference") if a.reference else None
            rows.append((seed, motion, ours, ref))
            print(f"{seed} {motion:9s} ours: {_said(ours)}" + (f" | reference: {_said(ref)}" if ref else ""), flush=True)
    chose = sum(r[2].get("other_start", 0) > 0 for r in rows)
    refused = sum(r[2]["outcome"] != "calibrated" for r in rows)
    line = f"{len(rows)} sessions: {chose} kept another start somewhere; ours refused {refused}"
    if a.reference:
        line += f", the reference refused {sum(r[3]['outcome'] != 'calibrated' for r in rows)}"
        same = [r for r in rows if r[2]["outcome"] == r[3]["outcome"] == "calibrated"]
        worse = [r for r in same if r[2]["truth"] > 1.01 * r[3]["truth"]]
        line += f"; of {len(same)} both calibrated, ours predicts the truth worse (> 1 %) on {len(worse)}"
    print(line)
    if a.keep is None:
        print(f"(sessions in {base})")


if __name__ == "__main__":
    main()
