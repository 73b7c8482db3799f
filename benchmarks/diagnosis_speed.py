"""`platkit diagnose` beside the `platkit calibrate` it starts from, on real and simulated sessions.

    .venv/bin/python benchmarks/diagnosis_speed.py [--repeat 3] [--cases tiago,stewart] [--profile]

tiago: the golden session of tests/golden/test_diagnose_tiago.py (FIGAROH's TIAGo static
postures, shared/data/real/tiago: training day, 37 postures): ``calibrate --free offset,origin``,
then ``diagnose --heldout`` the validation day. stewart: ``platkit simulate --platform stewart
--seed 1`` (a raw session, 80 poses), its default ``calibrate``, then ``diagnose``.

Each command is a fresh process as a user runs it; the two run in turns (``--repeat`` times) so
that a busy machine slows them alike. The table gives the median wall time, the median CPU
time of the process (what load does not inflate; the machine is shared) and the ratio of
diagnose to calibrate, both ways. Goal (issue 13): diagnose at most 2x the calibration.

``--profile``: where one diagnosis spends its time (cProfile in this process, CPU seconds,
cumulative, platkit's own functions and the imports), so that what remains can be read: the
refits through the calibrate layer (platkit.calibrate.solve / problem), the diagnosis's own
work, its report, and start-up.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the real-data readers: tests/real_data

from real_data import tiago  # noqa: E402

PYTHON = sys.executable
SCRIPT = Path(PYTHON).parent / "platkit"
PLATKIT = [str(SCRIPT)] if SCRIPT.is_file() else [PYTHON, "-m", "platkit.cli"]
GOAL = 2.0


def run(cmd: list[str]) -> tuple[float, float]:
    """(wall s, CPU s of the child) of one command, which must succeed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def prepare(case: str, root: Path) -> tuple[list[str], list[str]]:
    """(calibrate arguments, diagnose arguments without --calibration/--out) of a case."""
    if case == "tiago":
        data = tiago.default_data_dir()
        train = tiago.convert(data / tiago.TRAINING, root / "train")
        valid = tiago.convert(data / tiago.VALIDATION, root / "valid")
        return ["calibrate", str(train), "--free", "offset,origin"], ["diagnose", str(train), "--heldout", str(valid)]
    if case == "stewart":
        session = root / "stewart"
        subprocess.run(PLATKIT + ["simulate", "--platform", "stewart", "--seed", "1", "--out", str(session)], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        return ["calibrate", str(session)], ["diagnose", str(session)]
    raise SystemExit(f"unknown case {case!r}: tiago or stewart")


def profile(diagnose_args: list[str]) -> None:
    from platkit.cli import main

    prof = cProfile.Profile(time.process_time)
    prof.enable()
    main(diagnose_args)
    prof.disable()
    buf = io.StringIO()
    stats = pstats.Stats(prof, stream=buf)
    total = sum(v[2] for v in stats.stats.values())  # own times: the whole run
    stats.sort_stats("cumulative").print_stats(r"platkit/(calibrate/(solve|problem|estimate)|diagnose|cli|commands)", 25)
    print(f"  profile of one diagnosis ({total:.2f} s CPU in all), cumulative CPU s of platkit's functions:")
    for line in buf.getvalue().splitlines():
        if line.strip() and "/" in line:
            print("   ", line.strip()[:160])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--cases", default="tiago,stewart")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args(argv)
    print(f"load average at the start: {os.getloadavg()[0]:.1f} (2-core machine shared with other work)")
    print(f"  {'session':<8} {'command':<10} {'wall s':>7} {'CPU s':>7}   goal: diagnose <= {GOAL:g} x calibrate")
    for case in args.cases.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            root = Path(tmp)
            cal_args, diag_args = prepare(case, root)
            cal_out, diag_out = root / "cal", root / "diag"
            cal_cmd = PLATKIT + cal_args + ["--out", str(cal_out), "--quiet"]
            diag_cmd = PLATKIT + diag_args + ["--calibration", str(cal_out / "calibration.yaml"), "--out", str(diag_out),
                                              "--quiet"]
            run(cal_cmd)  # warm: the stand's compiled functions found or made, files cached by the system
            rows: dict[str, list[tuple[float, float]]] = {"calibrate": [], "diagnose": []}
            for _ in range(args.repeat):
                rows["calibrate"].append(run(cal_cmd))
                rows["diagnose"].append(run(diag_cmd))
            med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for k, v in rows.items()}
            for k, (w, c) in med.items():
                print(f"  {case:<8} {k:<10} {w:7.2f} {c:7.2f}")
            rw, rc = med["diagnose"][0] / med["calibrate"][0], med["diagnose"][1] / med["calibrate"][1]
            print(f"  {case:<8} ratio      {rw:7.2f} {rc:7.2f}   {'met' if max(rw, rc) <= GOAL else 'NOT MET'} "
                  f"(load {os.getloadavg()[0]:.1f})")
            if args.profile:
                profile(diag_args[:1] + diag_args[1:] + ["--calibration", str(cal_out / "calibration.yaml"),
                                                         "--out", str(root / "diag_profiled"), "--quiet"])


if __name__ == "__main__":
    main()
