"""BLAS threads against the machine's other work: each workload with BLAS's own thread count (one
per core) and with platkit's rule (one thread, platkit._threads), on the machine as it is and with
busy processes beside it, as ratios; the outputs of the two compared.

    .venv/bin/python benchmarks/blas_threads.py [--repeat 2] [--busy 2] [--workloads tree,stewart,tiago,floor,gram]
                                                [--before DIR]

Workloads, each a fresh process as a user runs it:
- tree: PAL's Talos, 20 joints, both hands, 300 settled poses (benchmarks/trees_speed.py's
  session, seed 1): ``platkit calibrate`` then ``platkit diagnose``, each timed;
- stewart: ``platkit simulate --platform stewart --seed 1`` (80 poses), calibrate then diagnose;
- tiago: FIGAROH's TIAGo golden session (benchmarks/diagnosis_speed.py), calibrate then diagnose
  with the validation day held out;
- floor: the diagnosis's design floor (platkit.diagnose.floor.noise_floor with a K-fold refit) at
  the tree's sizes, 300 poses x 6 markers x 3 by 120 parameters, 5 folds, 20 calls in a loop;
- gram: one large product, X' X of 20,000 x 400 (where threads could pay), 20 in a loop.

Variants: ``default``: PLATKIT_BLAS_THREADS=0, platkit holds nothing (BLAS's own count
everywhere); ``one``: no variable set, platkit's rule; with ``--before DIR`` (a checkout of the
code before the rule, e.g. ``git worktree add --detach DIR <commit>``) also ``before``: that
code with no variable set (its LM runs and approach fits on one thread, the rest BLAS's own).
No OPENBLAS_NUM_THREADS / OMP_NUM_THREADS / ... is passed to any of them.

Load: ``idle`` is the machine as it is (its load average printed: other people's work counts);
``loaded`` adds ``--busy`` processes that spin (``while True: pass``), started before and ended
after each loaded turn. In each turn the variants run in rotated order, so that a swing of the
machine's other work falls on all alike; the table gives each variant's median wall seconds over
``--repeat`` turns and the ratios default / one and before / one (above 1: the rule is faster).

Outputs: calibration.yaml and diagnosis.json of each variant against ``one``'s of the same turn:
``identical`` (the same bytes), ``same but timings`` (only the run's own time_s and the output
folder named in them differ) or the largest absolute and relative difference of their numbers.
Run it from a checkout no one edits while it runs (``git worktree add``): every variant but
``before`` imports platkit from this file's checkout.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the other benchmarks: trees_speed, diagnosis_speed
sys.path.insert(0, str(HERE.parent / "tests"))  # reference_robots, real_data

THREAD_VARIABLES = ("PLATKIT_BLAS_THREADS", "OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS",
                    "MKL_NUM_THREADS", "BLIS_NUM_THREADS")

FLOOR = """
import time, numpy as np
from platkit.diagnose.floor import noise_floor
from platkit.poses import PoseSet
rng = np.random.default_rng(3)
N, M, P = 300, 6, 120
poses = PoseSet("stewart", np.zeros((N, 6)), rng.normal(size=(N, M, 3)), [f"M{k}" for k in range(M)],
                n_samples=np.full((N, M), 40.0), settling={"sigma_m": 1e-4})
refit = (rng.normal(size=(N, M, 3, P)), np.ones((N, M)), np.ones((N, M)), 5)
noise_floor(poses, P, refit)
t = time.perf_counter()
for _ in range(20):
    f = noise_floor(poses, P, refit)
print(time.perf_counter() - t, repr(f))
"""

GRAM = """
import time, numpy as np
try:
    from platkit._threads import blas_threads
except ImportError:  # the code before the rule: no block
    import contextlib
    blas_threads = lambda n=1: contextlib.nullcontext()
X = np.random.default_rng(4).normal(size=(20000, 400))
with blas_threads(1):
    G = X.T @ X
    t = time.perf_counter()
    for _ in range(20):
        G = X.T @ X
    print(time.perf_counter() - t, repr(float(G.sum())))
"""


def environment(variant: str, before: Path | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARIABLES}
    if variant == "default":
        env["PLATKIT_BLAS_THREADS"] = "0"
    if variant == "before":
        env["PYTHONPATH"] = str(before)
    else:
        env["PYTHONPATH"] = str(HERE.parent)
    return env


def run(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    """(wall s, standard output) of one command, which must succeed."""
    t = time.perf_counter()
    # run outside the repository: `python -m` puts the working folder first on the path
    done = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True, timeout=900, cwd=tempfile.gettempdir())
    return time.perf_counter() - t, done.stdout


def prepare(names: list[str], root: Path) -> dict[str, tuple[list[str], list[str]]]:
    """Each verb workload's (calibrate arguments, diagnose arguments without --calibration/--out)."""
    out = {}
    if "tree" in names:
        from reference_robots import example_robot_urdf
        from trees_speed import HANDS, TREE_JOINTS, session

        from platkit.plugins import get_platform

        urdf = example_robot_urdf("talos_data/robots/talos_reduced.urdf")
        mapping = {f"{h}{k}": link for h, link in HANDS.items() for k in range(1, 4)}
        spec = get_platform("urdf", urdf, moving_link=mapping, joints=TREE_JOINTS)
        folder = session(root / "tree", urdf, spec, mapping, 300, 1, {"moving_link": mapping})
        out["tree"] = (["calibrate", str(folder), "--no-report"], ["diagnose", str(folder)])
    for name in ("stewart", "tiago"):
        if name in names:
            import diagnosis_speed

            out[name] = diagnosis_speed.prepare(name, root)
    return out


#: keys whose values are the run's own timings, not its results
TIMINGS = {"time_s"}


def numbers(a, b) -> tuple[float, float]:
    """(largest absolute, largest relative difference) between the numbers of two parsed documents
    of one shape, timings (TIMINGS) left out; (inf, inf) where their shapes or words differ."""
    differ = (float("inf"), float("inf"))
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return differ
        found = [numbers(a[k], b[k]) for k in a if k not in TIMINGS]
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return differ
        found = [numbers(x, y) for x, y in zip(a, b)]
    elif isinstance(a, bool) or isinstance(b, bool) or not isinstance(a, (int, float)) or not isinstance(b, (int, float)):
        return (0.0, 0.0) if a == b else differ
    else:
        d = abs(float(a) - float(b))
        return d, d / max(abs(float(a)), abs(float(b)), 1e-300)
    return max((x for x, _ in found), default=0.0), max((r for _, r in found), default=0.0)


def compare(a: Path, b: Path, a_out: Path, b_out: Path) -> str:
    """'identical' (the same bytes), 'same but timings' (and the output folders named in them), the
    largest differences of the numbers, or 'differ in words or shape'."""
    if a.read_bytes() == b.read_bytes():
        return "identical"
    load = json.loads if a.suffix == ".json" else yaml.safe_load
    d, r = numbers(load(a.read_text().replace(str(a_out), "OUT")), load(b.read_text().replace(str(b_out), "OUT")))
    if d == 0.0:
        return "same but timings"
    return f"max |diff| {d:.2g}, relative {r:.2g}" if d < float("inf") else "differ in words or shape"


def busy(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.kill()
        p.wait()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--busy", type=int, default=2, help="spinning processes beside the loaded turns")
    ap.add_argument("--workloads", default="tree,stewart,tiago,floor,gram")
    ap.add_argument("--before", type=Path, default=None, help="a checkout of the code before the rule")
    args = ap.parse_args(argv)
    names = args.workloads.split(",")
    variants = ["default", "one"] + (["before"] if args.before is not None else [])
    times: dict[tuple[str, str, str], list[float]] = {}
    same: dict[tuple[str, str, str], set[str]] = {}
    loads: dict[str, list[float]] = {"idle": [], "loaded": []}
    platkit = [sys.executable, "-m", "platkit.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        verbs = prepare(names, root)
        for turn in range(args.repeat):
            for load in ("idle", "loaded"):
                procs = busy(args.busy) if load == "loaded" else []
                try:
                    time.sleep(1.0 if procs else 0.0)
                    loads[load].append(os.getloadavg()[0])
                    for w in names:
                        order = variants[turn % len(variants):] + variants[:turn % len(variants)]
                        for v in order:
                            env = environment(v, args.before)
                            out = root / f"{w}_{v}_{load}_{turn}"
                            if w in verbs:
                                cal, diag = verbs[w]
                                tc, _ = run(platkit + cal + ["--out", str(out / "cal"), "--quiet"], env)
                                td, _ = run(platkit + diag + ["--calibration", str(out / "cal" / "calibration.yaml"),
                                                              "--out", str(out / "diag"), "--quiet"], env)
                                times.setdefault((w + " calibrate", v, load), []).append(tc)
                                times.setdefault((w + " diagnose", v, load), []).append(td)
                            else:
                                _, text = run([sys.executable, "-c", FLOOR if w == "floor" else GRAM], env)
                                seconds, value = text.split()
                                times.setdefault((w, v, load), []).append(float(seconds))
                                out.mkdir(parents=True)
                                (out / "value.json").write_text(json.dumps(float(value)))
                        for v in variants:
                            if v == "one":
                                continue
                            a, b = root / f"{w}_{v}_{load}_{turn}", root / f"{w}_one_{load}_{turn}"
                            files = (["cal/calibration.yaml", "diag/diagnosis.json", "diag/calibration.yaml"]
                                     if w in verbs else ["value.json"])
                            for f in files:
                                same.setdefault((w, v, f), set()).add(compare(a / f, b / f, a, b))
                        print(f"  turn {turn + 1}/{args.repeat} {load} {w} done (load {os.getloadavg()[0]:.1f})",
                              file=sys.stderr, flush=True)
                finally:
                    stop(procs)
    idle, loaded = statistics.mean(loads["idle"]), statistics.mean(loads["loaded"])
    print(f"wall seconds, median of {args.repeat} turns; load average: idle turns {idle:.1f}, loaded turns "
          f"{loaded:.1f} ({args.busy} spinning processes beside; {os.cpu_count()} cores)")
    head = f"{'workload':<20}" + "".join(f" {load + ' ' + v:>13}" for load in ("idle", "loaded") for v in variants)
    ratios = [f"{load} {v}/one" for load in ("idle", "loaded") for v in variants if v != "one"]
    print(head + "".join(f" {r:>18}" for r in ratios))
    for w in dict.fromkeys(k[0] for k in times):
        med = {(v, load): statistics.median(times[(w, v, load)]) for v in variants for load in ("idle", "loaded")}
        cells = "".join(f" {med[(v, load)]:13.3f}" for load in ("idle", "loaded") for v in variants)
        rs = "".join(f" {med[(v, load)] / med[('one', load)]:18.2f}" for load in ("idle", "loaded") for v in variants
                     if v != "one")
        print(f"{w:<20}{cells}{rs}")
    print("outputs against one's of the same turn and load:")
    for (w, v, f), said in same.items():
        print(f"  {w:<8} {v:<8} {f:<22} {', '.join(sorted(said))}")


if __name__ == "__main__":
    main()
