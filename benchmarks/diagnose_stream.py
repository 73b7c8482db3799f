"""Diagnosis of streams without holds on the Stewart physical simulator: clean streams stay clean,
one hidden effect is named at its place, before and after a change to the code (side by side).

Each case simulates one stream (platkit simulate --physics --motion KIND --duration-s D --rate-hz 40
--noise-mm 0.2 --white-noise --rigid-bodies 2 --seed S, and --effect NAME:SIZE or none), takes its
rigid bodies alone (tests/bodies_alone.strip_markers; --with-markers keeps the five markers),
calibrates it from motion (platkit calibrate --response-kind KIND, first order by default: the
kind the tests and the failure this benchmark was written for used) and diagnoses it (platkit
diagnose) with each source tree given: ``--after-src`` (default: the platkit this Python imports)
and optionally ``--before-src`` (a snapshot, e.g. ``git archive HEAD | tar -x -C /tmp/before``),
each run as its own process with that tree first on PYTHONPATH. The simulation and the calibration
are shared by both (made with the after tree).

    .venv/bin/python benchmarks/diagnose_stream.py --before-src /tmp/before [--seeds 5201 5202 5203]
        [--motions multisine path] [--effects none backlash:1 scale_nonlinearity:3 cyclic_error:0.5] [--jobs 2]

A case is right when a clean stream names nothing (no finding, ``unexplained`` included) and a
stream with one effect names exactly that effect at the truth's actuator; a stream with an effect
whose geometric model already predicts held-out poses at the noise floor and names nothing is
counted apart, as absorbed (the geometry takes it on this plan: no finding is the rule there). Prints one row per case
and tree: the names, whether right, the geometric model's held-out RMS -> the final model's, the
noise floor and their ratio; then per tree, how many clean streams stayed clean and how many
effects were named right.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from bodies_alone import strip_markers  # noqa: E402


def _cli(args: list[str], src: str | None, cwd: Path) -> subprocess.CompletedProcess:
    """``platkit ARGS`` in a process of its own with the tree ``src`` first on its path (None: the
    installed platkit), run in ``cwd``: ``python -m`` puts the working folder first on the path,
    so it must not be a checkout."""
    env = dict(os.environ)
    if src:
        src = str(Path(src).resolve())
        env["PYTHONPATH"] = os.pathsep.join([src, str(Path(src) / "plugins"), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "platkit.cli", *args], env=env, capture_output=True, text=True,
                          cwd=cwd)


def _prepare(case: dict, work: Path, opts) -> Path | str:
    """The case's session and calibration (made once, reused): the calibration's path, or why not."""
    name = case["name"]
    sim, sess, cal = work / f"{name}.sim", work / f"{name}.session", work / f"{name}.cal"
    if not (cal / "calibration.yaml").is_file():
        args = ["simulate", "--platform", "stewart", "--physics", "--motion", case["motion"], "--duration-s",
                str(opts.duration_s), "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2",
                "--seed", str(case["seed"]), "--out", str(sim), "--force"]
        if case["effect"] != "none":
            args += ["--effect", case["effect"]]
        r = _cli(args, opts.after_src, work)
        if r.returncode != 0:
            return f"simulate failed: {r.stderr.strip().splitlines()[-1:]}"
        if not sess.exists():
            if opts.with_markers:
                sess = sim
            else:
                strip_markers(sim, sess)
        r = _cli(["calibrate", str(sess), "--quiet", "--no-report", "--response-kind", opts.response_kind,
                  "--out", str(cal)], opts.after_src, work)
        if r.returncode not in (0, 3):
            return f"calibrate failed: {r.stderr.strip().splitlines()[-1:]}"
    return cal / "calibration.yaml"


def _truth(case: dict, work: Path) -> tuple[str, str] | None:
    """(effect, actuator) the simulator hid, or None for a clean stream."""
    if case["effect"] == "none":
        return None
    eff = yaml.safe_load((work / f"{case['name']}.sim" / "truth.yaml").read_text())["effects"][0]
    return eff["effect"], str(eff["physics"].get("actuator", ""))


def _diagnose(case: dict, work: Path, cal: Path, tag: str, src: str | None, opts) -> dict:
    out = work / f"{case['name']}.diag_{tag}"
    sess = work / f"{case['name']}.sim" if opts.with_markers else work / f"{case['name']}.session"
    shutil.rmtree(out, ignore_errors=True)
    r = _cli(["diagnose", str(sess), "--calibration", str(cal), "--out", str(out), "--quiet", "--no-report"], src, work)
    if r.returncode != 0 or not (out / "diagnosis.json").is_file():
        return {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    d = json.loads((out / "diagnosis.json").read_text())
    found = [(f["effect"], str(f["where"].get("actuator", f["where"].get("marker", "")))) for f in d["findings"]]
    named = [f for f in d["findings"] if f.get("effect") != "unexplained"]
    # the final model's held-out RMS: the last named (the lowest), else the geometric model's
    final = min(f["heldout_rms_after"] for f in named) if named else d.get("heldout_rms_geometric")
    truth = _truth(case, work)
    right = (not found) if truth is None else found == [truth]
    # an effect the geometry absorbs on this plan leaves nothing to find: no finding is right there
    absorbed = truth is not None and not found and bool(d.get("at_noise_floor"))
    return {"found": found, "right": right, "absorbed": absorbed, "before": d.get("heldout_rms_geometric"), "after": final,
            "floor": d.get("noise_floor"), "response": [r.get("kept") for r in d.get("rounds", [])
                                                         if r.get("round") == "response"]}


def _run(case: dict, work: Path, trees: list[tuple[str, str | None]], opts) -> dict:
    cal = _prepare(case, work, opts)
    if isinstance(cal, str):
        return {**case, "error": cal}
    res = {tag: _diagnose(case, work, cal, tag, src, opts) for tag, src in trees}
    return {**case, "truth": _truth(case, work), **res}


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5201, 5202, 5203])
    ap.add_argument("--motions", nargs="+", default=["multisine", "path"])
    ap.add_argument("--effects", nargs="+", default=["none", "backlash:1", "scale_nonlinearity:3", "cyclic_error:0.5"])
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--response-kind", default="first-order")
    ap.add_argument("--with-markers", action="store_true", help="keep the five markers beside the bodies")
    ap.add_argument("--before-src", default=None, help="a source tree to diagnose with besides (the reference)")
    ap.add_argument("--after-src", default=None, help="the source tree under test (default: this Python's platkit)")
    ap.add_argument("--work", default=None, help="folder for the sessions (reused where already there)")
    ap.add_argument("--jobs", type=int, default=1)
    opts = ap.parse_args()
    work = Path(opts.work or f"/tmp/diagnose_stream_{os.getpid()}")
    work.mkdir(parents=True, exist_ok=True)
    trees = ([("before", opts.before_src)] if opts.before_src else []) + [("after", opts.after_src)]
    cases = [{"seed": s, "motion": m, "effect": e, "name": f"{m}_{s}_{e.replace(':', '_')}"}
             for m in opts.motions for e in opts.effects for s in opts.seeds]
    with ThreadPoolExecutor(max(1, opts.jobs)) as pool:
        results = list(pool.map(lambda c: _run(c, work, trees, opts), cases))
    print(f"Stewart physical simulator, streams of {opts.duration_s:g} s at 40 Hz, 0.2 mm white noise, "
          f"{'five markers and ' if opts.with_markers else ''}two rigid bodies"
          f"{'' if opts.with_markers else ' alone'}, response {opts.response_kind}; held-out RMS in mm")
    print("| seed | motion | truth | tree | named | right | held-out geometric -> final | floor | final / floor |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in results:
        if "error" in r:
            print(f"| {r['seed']} | {r['motion']} | {r['effect']} | - | {r['error']} | no | | | |")
            continue
        truth = "clean" if r["truth"] is None else f"{r['truth'][0]} {r['truth'][1]}"
        for tag, _ in trees:
            x = r[tag]
            if "error" in x:
                print(f"| {r['seed']} | {r['motion']} | {truth} | {tag} | {x['error']} | no | | | |")
                continue
            names = ", ".join(f"{e} {w}".strip() for e, w in x["found"]) or "nothing"
            verdict = "yes" if x["right"] else "absorbed" if x["absorbed"] else "NO"
            ratio = x["after"] / x["floor"] if x["after"] and x["floor"] else None
            print(f"| {r['seed']} | {r['motion']} | {truth} | {tag} | {names} | {verdict} | "
                  f"{_fmt(x['before'])} -> {_fmt(x['after'])} | {_fmt(x['floor'])} | "
                  f"{'-' if ratio is None else f'{ratio:.2f}'} |")
    for tag, _ in trees:
        ok = [r for r in results if tag in r and "error" not in r[tag]]
        clean = [r for r in ok if r["truth"] is None]
        eff = [r for r in ok if r["truth"] is not None]
        wrong = [r for r in eff if not r[tag]["right"] and r[tag]["found"]]
        print(f"{tag}: clean streams clean {sum(r[tag]['right'] for r in clean)}/{len(clean)}, effects named right "
              f"{sum(r[tag]['right'] for r in eff)}/{len(eff)}, absorbed by the geometry (at the noise floor, nothing "
              f"named) {sum(r[tag]['absorbed'] for r in eff)}, a wrong name or unexplained {len(wrong)}, missed "
              f"above the floor {len(eff) - sum(r[tag]['right'] or r[tag]['absorbed'] for r in eff) - len(wrong)} "
              f"(cases that failed to run: {len(results) - len(ok)})")


if __name__ == "__main__":
    main()
