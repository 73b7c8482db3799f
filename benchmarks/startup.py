"""Start-up time of the ``platkit`` command beside importing its heavy dependencies.

    .venv/bin/python benchmarks/startup.py [--repeat 7]

Each row is a fresh process, timed by wall clock from spawn to exit; the rows are run in
turns (one of each, then again) so that a busy machine slows them alike, and the table gives
the minimum and the median of ``--repeat`` runs and the ratio of medians to the reference,
``python -c "import casadi, numpy, scipy"`` (what any platkit verb needs at least in part).
Goal (issue 13): ``platkit --version`` and ``platkit fk`` within 2x of the reference.

Then Ctrl-C: ``platkit fk`` is sent SIGINT at several moments of its start-up and run; every
one must end with one line on stderr and exit status 130 (the row says how many did).
Then a 100-pose calibration with and without its HTML report, beside its estimation time plus
its start-up (goal: within 1.5x). The last rows show which modules a verb imports (``python -X importtime``), the largest first.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PYTHON = sys.executable
#: the console script a user runs (python -m platkit.cli where it is not installed)
SCRIPT = Path(PYTHON).parent / "platkit"
PLATKIT = [str(SCRIPT)] if SCRIPT.is_file() else [PYTHON, "-m", "platkit.cli"]
FK_ARGS = ["fk", "--platform", "stewart", "--u", "4000,4000,4000,4000,4000,4000"]

CASES = [
    ("reference: python -c 'import casadi, numpy, scipy'", [PYTHON, "-c", "import casadi, numpy, scipy"]),
    ("python -c pass (the interpreter alone)", [PYTHON, "-c", "pass"]),
    ("platkit --version", PLATKIT + ["--version"]),
    ("platkit fk --platform stewart --u ...", PLATKIT + FK_ARGS),
    ("platkit describe --platform stewart", PLATKIT + ["describe", "--platform", "stewart"]),
    ("platkit simulate --help", PLATKIT + ["simulate", "--help"]),
    ("platkit --help (every verb's parser)", PLATKIT + ["--help"]),
]
#: platkit's package folder: a traceback frame in it is platkit's own code
PACKAGE = str(Path(__file__).resolve().parent.parent / "platkit") + "/"
#: rows with a goal: within this many times the reference
GOAL = {"platkit --version": 2.0, "platkit fk --platform stewart --u ...": 2.0}


def wall_s(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}): {done.stderr.decode()[-500:]}")
    return t


def interrupt(delay_s: float) -> tuple[int, list[str]]:
    """Start ``platkit fk``, send SIGINT after ``delay_s``; (exit status, stderr lines)."""
    proc = subprocess.Popen(PLATKIT + FK_ARGS, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    time.sleep(delay_s)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate()
    return proc.returncode, err.decode().strip().splitlines()


def top_imports(cmd_args: list[str], n: int = 6) -> list[tuple[float, str]]:
    """The ``n`` top-level imports of a platkit command line that take longest (cumulative ms)."""
    done = subprocess.run([PYTHON, "-X", "importtime", "-m", "platkit.cli"] + cmd_args,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    rows = []
    for line in done.stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cum, name = line[len("import time:"):].split("|")
        if name.startswith(" ") and not name.startswith("  "):  # top level: one space of indent
            try:
                rows.append((int(cum) / 1e3, name.strip()))
            except ValueError:
                continue
    return sorted(rows, reverse=True)[:n]


#: what `platkit calibrate` imports to do its work: its start-up, beside the estimation itself
CALIBRATE_IMPORTS = ("import platkit.commands.calibrate, platkit.calibrate.estimate, platkit.calibrate.selection, "
                     "platkit.settle, platkit.calibrate.report, platkit.io.session")


def calibration(repeat: int) -> None:
    """A 100-pose calibration (simulated settled poses of the stewart stand): wall time with
    and without the HTML report, beside its estimation time (report.json time_s) plus its
    start-up (importing what it uses). Goal: within 1.5x of estimation + start-up."""
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(tmp) / "s100"
        subprocess.run(PLATKIT + ["simulate", "--platform", "stewart", "--poses", "100", "--poses-only", "--seed", "1",
                                  "--out", str(session)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        rows = {"report": [], "no-report": [], "estimation": [], "start-up": []}
        for k in range(max(3, repeat // 2)):
            for label, extra in (("report", []), ("no-report", ["--no-report"])):
                out = Path(tmp) / f"c{k}{label}"
                rows[label].append(wall_s(PLATKIT + ["calibrate", str(session), "--quiet", "--out", str(out)] + extra))
                rep = json.loads((out / "report.json").read_text())
                # the estimation: the fit, or the model selection around it (its time includes the fit)
                rows["estimation"].append(max(rep["time_s"], (rep.get("model_selection") or {}).get("time_s") or 0.0))
            rows["start-up"].append(wall_s([PYTHON, "-c", CALIBRATE_IMPORTS]))
        est, start = statistics.median(rows["estimation"]), statistics.median(rows["start-up"])
        budget = 1.5 * (est + start)
        print(f"calibrate, 100 settled poses (stewart), {len(rows['report'])} runs each: estimation {est:.2f} s "
              f"(report.json: the fit with its model selection), start-up {start:.2f} s (importing what it uses); goal: wall <= 1.5 x their "
              f"sum = {budget:.2f} s")
        for label in ("report", "no-report"):
            med = statistics.median(rows[label])
            print(f"  platkit calibrate{' --no-report' if label == 'no-report' else ''}: wall {med:.2f} s "
                  f"({med / (est + start):.2f} x estimation + start-up): {'met' if med <= budget else 'NOT MET'}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=7, help="runs of each command line")
    ap.add_argument("--no-calibrate", dest="calibrate", action="store_false",
                    help="leave out the 100-pose calibration")
    args = ap.parse_args(argv)
    os.environ.setdefault("MPLBACKEND", "Agg")
    # as installed for a user: byte-code is cached (PYTHONDONTWRITEBYTECODE, set on some
    # development machines, makes every start compile platkit's modules again: ~0.1 s)
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    for _, cmd in CASES:  # warm the file cache and the byte-code
        wall_s(cmd)
    times = {name: [] for name, _ in CASES}
    for _ in range(args.repeat):
        for name, cmd in CASES:
            times[name].append(wall_s(cmd))
    ref = statistics.median(times[CASES[0][0]])
    width = max(len(n) for n, _ in CASES)
    print(f"start-up on {os.cpu_count()} cores, {args.repeat} runs each, wall clock")
    print(f"{'command line':<{width}}  {'min s':>6}  {'median s':>8}  {'x ref':>6}  goal")
    for name, _ in CASES:
        med = statistics.median(times[name])
        goal = GOAL.get(name)
        verdict = "" if goal is None else f"<= {goal:.0f}x: {'met' if med <= goal * ref else 'NOT MET'}"
        print(f"{name:<{width}}  {min(times[name]):>6.3f}  {med:>8.3f}  {med / ref:>6.2f}  {verdict}")

    print()
    delays = [0.0, 0.02, 0.04, 0.06, 0.08, 0.1, 0.12, 0.15, 0.2, 0.3, 0.5]
    counts = {"one line, exit 130": 0, "finished first": 0, "in Python's own start-up": 0, "platkit's fault": 0}
    for d in delays:
        rc, lines = interrupt(d)
        if rc == 130 and lines == ["platkit: interrupted"]:
            counts["one line, exit 130"] += 1
        elif rc == 0 and not lines:
            counts["finished first"] += 1
        elif not any(f'File "{PACKAGE}' in line for line in lines):
            # before any of platkit's own code ran (the interpreter, site, the editable-install
            # finder, the console script importing platkit.cli): Python's handler is still in place
            counts["in Python's own start-up"] += 1
        else:
            counts["platkit's fault"] += 1
            print(f"  Ctrl-C after {d:.2f} s: exit {rc}, stderr {len(lines)} lines: {lines[-3:]}")
    print(f"Ctrl-C during `platkit fk` at {len(delays)} moments ({', '.join(f'{d:g}' for d in delays)} s): "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))

    print()
    if args.calibrate:
        calibration(args.repeat)
        print()
    for label, cmd_args in (("platkit fk", FK_ARGS), ("platkit --version", ["--version"])):
        top = ", ".join(f"{name} {ms:.0f} ms" for ms, name in top_imports(cmd_args))
        print(f"largest imports of {label}: {top}")


if __name__ == "__main__":
    main()
