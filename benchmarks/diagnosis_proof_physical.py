"""Proof of settling and diagnosis on sessions platkit's model terms did not make.

Every session comes from the time-domain simulator (platkit.simulate.physics): actuators that
approach their commands through their own damped responses, effects played out where their
physics acts, nuisances (hold, drive tuning, white and correlated noise, occlusion bursts,
latency, clock offset) drawn per session. The session goes through platkit as a user runs it,
in-process through the CLI: ``platkit calibrate``, ``platkit diagnose``, ``platkit predict``
with the geometric and with the diagnosed calibration. Scored against the truth's settled poses
(truth_settled.csv) of HELD-OUT commands: every fifth command (rows 2, 7, 12, ...) keeps its place in
commands.csv (the history of the others is the real one) but its stretch of markers.csv is cut out
(a gap in the recording), so neither calibration nor diagnosis sees it. A marker slip is a
recording artefact whose calibration predicts the marker's new place (spec, section 3): with one in
the truth, held-out commands are scored from the slip on (all rows are in the JSON line too).

Cells per stand: clean; each effect at a clear and a weak size; pairs. Sizes: the RMS a
noise-free geometric calibration of the truth's settled poses leaves (what the geometry cannot
absorb) is 0.2 mm (clear) or 0.06 mm (weak), at most 5 times that in raw marker motion (an
effect left below 10% is 'absorbed'); a slow actuator (settling_lag) has a time constant of
0.15 (clear) or 0.1 (weak) of the hold, which leaves the record short of rest by about 1e-4 to
1e-3 of the last step. base_tilt turns everything rigidly: the motion capture alone cannot
separate it from its own placement (no finding is the right answer).

Per session one JSON line: what was hidden, what was named, held-out RMS against the truth
before (geometric) and after (diagnosed), dropped holds, and the settle bias alone: platkit's
settled markers minus the true settled markers, projected on the direction of the last step and
averaged over markers, per pose; printed as its mean in units of its spread over the poses (the
averaging noise of one settled pose), with the t statistic, beside a reference that knows nothing of
settling (the mean of the last second of each hold, timed by the truth).

Seeds: ``--seed-base`` (default 880000, a range no development run used); session k of a cell
has seed base + 1000 * stand index + 10 * cell index + k, the indices those of the plan the
options make (``--stands``, ``--kinds``, ``--effects``): each session's line prints its seed, and
``--seeds`` with the same options runs those sessions alone.

Every session is one task of platkit's batch engine (platkit.batch, Dask): an embedded local
cluster of ``--jobs`` workers (default one per core), or an existing one (``--scheduler ADDRESS``
or PLATKIT_DASK_SCHEDULER); ``--serial`` runs them in a loop in this process (the same lines but
for time_s). Each session's JSON line is appended to ``--json`` as it finishes, and a re-run
with the same file skips the sessions it already holds (a session lost with its worker is not
written, so a re-run runs it).

    .venv/bin/python benchmarks/diagnosis_proof_physical.py --smoke                # a few minutes
    .venv/bin/python benchmarks/diagnosis_proof_physical.py --sessions-per-cell 3 --json run.jsonl
    .venv/bin/python benchmarks/diagnosis_proof_physical.py --summarise run.jsonl
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import itertools
import json
import shutil
import sys
import tempfile
import time
import warnings
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from platkit.calibrate.estimate import calibrate
from platkit.cli import main as platkit_main
from platkit.effects import with_history
from platkit.errors import BadInput, PlatkitError
from platkit.io.jsonout import plain
from platkit.io.session import load_session
from platkit.plugins import get_platform
from platkit.poses import PoseSet
from platkit.settle import settle
from platkit.simulate.physics import simulate_physics, write_physical_session

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the case runner, the protocol, outside physics
from batch_cases import add_engine_options, run_cases  # noqa: E402
from outside_plugins.outside_physics import OUTSIDE, with_outside_physics  # noqa: E402
from proof_protocol import blank_held_out, held_out_rows  # noqa: E402

EFFECTS = ["backlash", "compliance", "thermal_drift", "cyclic_error", "scale_nonlinearity", "settling_lag",
           "marker_slip", "base_tilt"]
PAIRS = [("backlash", "thermal_drift"), ("cyclic_error", "marker_slip"), ("scale_nonlinearity", "settling_lag")]
STANDS = ["stewart", "psvr", "rotary"]
CLEAR_MM, WEAK_MM = 0.2, 0.06
#: a slow actuator's time constant as a share of the hold
LAG_SHARE = {"clear": 0.15, "weak": 0.1}
ABSORBED = 0.1
UNSEPARABLE = {"base_tilt"}

def _truth_poses(sim) -> PoseSet:
    """The truth's settled poses as a PoseSet (noise-free)."""
    return with_history(PoseSet(sim.spec.name, sim.commands, sim.settled_markers, list(sim.marker_names),
                                t=sim.command_t, length_unit=sim.length_unit, source="truth"), sim.spec)


def _rms_mm(a, b) -> float:
    d = np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1)
    return float(np.sqrt(np.nanmean(d**2)) * 1e3)


def sized_effects(spec, seed: int, n: int, effects: list[tuple[str, str]]) -> tuple[list[tuple[str, float]], list]:
    """[(name, size)] scaled so that each leaves CLEAR_MM / WEAK_MM after a noise-free geometric
    calibration of the truth's settled poses; and per effect (left share, raw mm, left mm)."""
    if not effects:
        return [], []
    base = simulate_physics(spec, seed=seed, n_poses=n, plan="random")
    out, info = [], []
    for name, strength in effects:
        if name == "settling_lag":
            out.append((name, LAG_SHARE[strength]))
            info.append({"effect": name, "left_share": 1.0})
            continue
        unit = simulate_physics(spec, seed=seed, n_poses=n, plan="random", effects=[(name, 1.0)])
        raw = _rms_mm(unit.settled_markers, base.settled_markers)
        if raw < 1e-9:
            raise PlatkitError(f"{name} does nothing on the {spec.name} stand's settled poses")
        left = calibrate(_truth_poses(unit), spec, robust=False).rms_after * 1e3
        target = CLEAR_MM if strength == "clear" else WEAK_MM
        per_unit = max(left, raw / 5)
        out.append((name, target / per_unit))
        info.append({"effect": name, "left_share": left / raw, "raw_mm_per_unit": raw, "left_mm_per_unit": left})
    return out, info


def _cli(args: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = platkit_main(args)
    lines = [x for x in (err.getvalue() + out.getvalue()).splitlines() if x.strip()]
    return rc, (lines[-1] if rc and lines else "")


def _predicted_markers(path: Path, names: list[str]) -> np.ndarray:
    rows = list(csv.DictReader(path.open()))
    return np.array([[[float(r[f"{m}_{a}"] or "nan") for a in "xyz"] for m in names] for r in rows]) * 1e-3


def _along_last_step(markers: np.ndarray, rows: np.ndarray, truth: np.ndarray) -> dict:
    """Settled markers (n, M, 3) of command ``rows`` minus the truth's, projected on the
    direction of each marker's last step and averaged over the markers: mean, spread (mm)."""
    prev = np.vstack([truth[:1], truth[:-1]])
    step = truth - prev  # (N, M, 3)
    unit = step / np.maximum(np.linalg.norm(step, axis=2, keepdims=True), 1e-15)
    moved = np.linalg.norm(step[rows], axis=2).min(axis=1) > 1e-5
    proj = np.nanmean(np.sum((markers - truth[rows]) * unit[rows], axis=2), axis=1)[moved] * 1e3
    proj = proj[np.isfinite(proj)]
    if proj.size < 3:
        return {"n": int(proj.size)}
    mean, sd = float(np.mean(proj)), float(np.std(proj, ddof=1))
    return {"n": int(proj.size), "mean_mm": mean, "spread_mm": sd, "in_noise_units": mean / sd,
            "t": mean / (sd / np.sqrt(proj.size))}


def settle_bias(folder: Path, sim) -> dict:
    """platkit's settled markers against the truth's along the last step (see _along_last_step),
    beside a reference that knows nothing of settling: the mean of the last second of each hold."""
    te = sim.marker_t - sim.nuisances.time_shift_s
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a hold cut out for held-out has no samples
        last = np.array([np.nanmean(sim.markers[(te >= e - 1.0) & (te < e)], axis=0) for e in sim.hold_end_t])
    kept = np.setdiff1d(np.arange(len(sim.commands)), held_out_rows(len(sim.commands)))
    reference = _along_last_step(last[kept], kept, sim.settled_markers)
    try:
        poses, _ = settle(load_session(folder))
    except PlatkitError as exc:
        return {"error": str(exc), "reference_last_second": reference}
    rows = np.asarray(poses.extras["row"], int)
    return {**_along_last_step(poses.markers, rows, sim.settled_markers), "dropped": len(poses.dropped),
            "reference_last_second": reference}


def run_case(case: dict) -> dict:
    t0 = time.perf_counter()
    try:
        out = _run_case(case)
    except (PlatkitError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        out = {**case, "error": f"{type(exc).__name__}: {exc}"}
    out["time_s"] = time.perf_counter() - t0
    return out


def failed_row(case: dict, error: str, seconds: float) -> dict:
    """The line of a session whose run raised past run_case (or was lost with its worker)."""
    return {**case, "error": error, "time_s": seconds}


def _run_case(case: dict) -> dict:
    with_outside_physics()
    spec = get_platform(case["stand"])
    seed, n = case["seed"], case["commands"]
    try:
        effects, info = sized_effects(spec, seed, n, [tuple(e) for e in case["effects"]])
    except BadInput as exc:  # the effect cannot exist on this stand (compliance without a load)
        return {**case, "not_applicable": str(exc)}
    sim = simulate_physics(spec, seed=seed, n_poses=n, plan="random", effects=effects, coloured=case["coloured"])
    rows = held_out_rows(len(sim.commands))
    work = Path(tempfile.mkdtemp(prefix="platkit-proof-"))
    try:
        sess = write_physical_session(sim, work / "session")
        blanked = blank_held_out(sess, sim, rows)
        result = {**case, "sizes": [[n_, float(s)] for n_, s in effects], "sizing": info,
                  "truth_physics": [{"effect": name, **plain(p.parameters())} for name, p in sim.physics],
                  "left_share": min([x["left_share"] for x in info], default=1.0),
                  "nuisances": sim.nuisances.to_dict(), "held_out": int(len(rows)), "blanked_samples": blanked}
        result["absorbed"] = bool(case["effects"]) and result["left_share"] < ABSORBED
        result["settle"] = settle_bias(sess, sim)
        rc, msg = _cli(["calibrate", str(sess), "--out", str(work / "cal")])
        if rc:
            return {**result, "error": f"calibrate exit {rc}: {msg}"}
        report = json.loads((work / "cal" / "report.json").read_text())
        result["calibrate"] = {k: report.get(k) for k in ("n_poses", "rms_after", "converged")}
        result["calibrate"]["dropped"] = report.get("dropped") or report.get("n_dropped")
        rc, msg = _cli(["diagnose", str(sess), "--calibration", str(work / "cal" / "calibration.yaml"),
                        "--out", str(work / "diag")])
        if rc:
            return {**result, "error": f"diagnose exit {rc}: {msg}"}
        diag = json.loads((work / "diag" / "diagnosis.json").read_text())
        result["named"] = [f["effect"] for f in diag["findings"]]
        result["diagnosis"] = {k: diag.get(k) for k in ("noise_floor", "heldout_rms_geometric", "at_noise_floor")}
        result["findings"] = [{k: f.get(k) for k in ("effect", "where", "heldout_rms_before", "heldout_rms_after",
                                                              "p_heldout", "p_screen", "separability", "alternatives")}
                              for f in diag["findings"]]
        result["neighbours"] = [r["tests"] for r in diag["rounds"] if r.get("round") == "neighbours"]
        # a slip is a recording artefact: the calibration predicts the marker's new place (spec section 3),
        # so held-out commands are scored from the slip on (the place before it is history)
        slips = [p["time_s"] for p in result["truth_physics"] if p["effect"] == "marker_slip"]
        scored = rows[sim.hold_end_t[rows] > max(slips)] if slips else rows
        result["scored_rows"] = int(len(scored))
        heldout = {}
        for label, cal in (("before", work / "cal" / "calibration.yaml"), ("after", work / "diag" / "calibration.yaml")):
            pred = work / f"pred_{label}.csv"
            rc, msg = _cli(["predict", "--calibration", str(cal), "--commands", str(sess / "commands.csv"),
                            "--out", str(pred)])
            if rc:
                return {**result, "error": f"predict ({label}) exit {rc}: {msg}"}
            P = _predicted_markers(pred, sim.marker_names)
            heldout[label] = _rms_mm(P[scored], sim.settled_markers[scored])
            if slips:
                heldout[label + "_all_rows"] = _rms_mm(P[rows], sim.settled_markers[rows])
        result["heldout_truth_rms_before_mm"] = heldout["before"]
        result["heldout_truth_rms_after_mm"] = heldout["after"]
        if slips:
            result["heldout_all_rows_mm"] = [heldout["before_all_rows"], heldout["after_all_rows"]]
        return result
    finally:
        shutil.rmtree(work, ignore_errors=True)


def plan_cases(stands, per_cell: int, seed_base: int, commands: int, kinds: set[str], only: set[str] | None,
               coloured: bool = True):
    cases = []
    for s_i, stand in enumerate(stands):
        cells = []
        if "clean" in kinds:
            cells.append(("clean", [], "none"))
        for e in EFFECTS:
            for strength in ("clear", "weak"):
                if strength in kinds and (only is None or e in only):
                    cells.append((strength, [(e, strength)], e))
        if "pair" in kinds:
            for a, b in PAIRS:
                if only is None or {a, b} & only:
                    cells.append(("pair", [(a, "clear"), (b, "clear")], f"{a}+{b}"))
        if "outside" in kinds:  # after the other cells: their seeds stay what they were
            for e in OUTSIDE:
                for strength in ("clear", "weak"):
                    if only is None or e in only:
                        cells.append(("outside", [(e, strength)], e))
        for c_i, (kind, effects, truth) in enumerate(cells):
            for k in range(per_cell):
                cases.append({"stand": stand, "seed": seed_base + 1000 * s_i + 10 * c_i + k, "kind": kind,
                              "effects": effects, "truth": truth, "commands": commands, "coloured": coloured})
    return cases


# ---------------------------------------------------------------------------- the tables
def summarise(results: list[dict]) -> str:
    lines = [f"not applicable: {r['truth']} on {r['stand']} ({r['not_applicable']})"
             for r in results if r.get("not_applicable")]
    results = [r for r in results if not r.get("not_applicable")]
    errors = [r for r in results if r.get("error")]
    for r in errors:
        lines.append(f"ERROR {r['stand']} {r['truth']} ({r['kind']}, seed {r['seed']}): {r['error'][:300]}")
    ok = [r for r in results if not r.get("error")]
    lines.append(f"{len(results)} sessions, {len(errors)} without a diagnosis (errors above)")
    # a slow actuator may stop calibration: right when the refusal names it
    lag = [r for r in errors if "settling_lag" in r["truth"] and r.get("truth_physics")]
    for r in lag:
        slow = [p["actuator"] for p in r["truth_physics"] if p["effect"] == "settling_lag"]
        r["refusal_names_slow_actuator"] = bool(slow) and f"actuator {slow[0]} still moving" in r["error"]
    if lag:
        lines.append(f"slow actuator (settling_lag) refused by calibrate, naming it: "
                     f"{sum(r['refusal_names_slow_actuator'] for r in lag)}/{len(lag)}")

    def right(r):
        if r["kind"] == "outside":  # physics the library does not hold: said to be unexplained, nothing else
            return set(r["named"]) == {"unexplained"}
        want = set(r["truth"].split("+")) if r["truth"] != "none" else set()
        return set(r["named"]) == want

    def right_or_alternative(r):
        """Named right with, for each finding, its name or one of the alternatives diagnosis said
        it could not tell apart from it on the session's plan."""
        if r["kind"] == "outside":
            return right(r)
        want = set(r["truth"].split("+")) if r["truth"] != "none" else set()
        choices = [[f["effect"]] + [a["effect"] for a in (f.get("alternatives") or [])] for f in r.get("findings", [])]
        return any(set(pick) == want for pick in itertools.product(*choices))

    confusion: dict[str, Counter] = defaultdict(Counter)
    for r in ok:
        confusion[f"{r['truth']} ({r['kind']})"]["+".join(r["named"]) or "none"] += 1
    lines.append("named (rows: truth; counts of what diagnosis named)")
    for row in sorted(confusion):
        lines.append(f"  {row:42s} " + ", ".join(f"{k}: {v}" for k, v in confusion[row].most_common()))
    for kind in ("clear", "weak", "pair", "outside"):
        rs = [r for r in ok if r["kind"] == kind and r["truth"] not in UNSEPARABLE and not r.get("absorbed")]
        if rs:
            lines.append(f"{kind}: named right {sum(map(right, rs))}/{len(rs)}")
            told = [r for r in rs if not right(r) and right_or_alternative(r)]
            if told:
                lines.append(f"{kind}: right among the alternatives diagnosis said it could not tell apart, not named "
                             f"first: {len(told)} (" + ", ".join(f"{r['stand']} {r['seed']}" for r in told) + ")")
    for strength in ("clear", "weak"):
        rs = [r for r in ok if r["kind"] == "outside" and r["effects"][0][1] == strength]
        if rs:
            by_neighbours = sum(any("alike" in (f.get("where") or {}) for f in r.get("findings", [])) for r in rs)
            lines.append(f"outside, {strength}: named right {sum(map(right, rs))}/{len(rs)}; with no finding "
                         f"{sum(not r['named'] for r in rs)}; said unexplained by the neighbour tests {by_neighbours}")
    tilt = [r for r in ok if r["truth"] in UNSEPARABLE]
    if tilt:
        lines.append(f"base_tilt (not separable from the mocap placement): no finding in "
                     f"{sum(not r['named'] for r in tilt)}/{len(tilt)}")
    absorbed = [r for r in ok if r.get("absorbed")]
    if absorbed:
        lines.append(f"absorbed by the geometry: no wrong name in "
                     f"{sum(set(r['named']) <= set(r['truth'].split('+')) for r in absorbed)}/{len(absorbed)}"
                     + "".join(f"; {r['stand']} {r['truth']} seed {r['seed']}: {'+'.join(r['named'])}"
                               + (" (the truth among the alternatives said)" if right_or_alternative(r) else "")
                               for r in absorbed if not set(r["named"]) <= set(r["truth"].split("+"))))
    clean = [r for r in ok if r["kind"] == "clean"]
    if clean:
        lines.append(f"clean sessions with a finding: {sum(bool(r['named']) for r in clean)}/{len(clean)}"
                     + "".join(f"; {r['stand']} seed {r['seed']}: {'+'.join(r['named'])}" for r in clean if r["named"]))
    worse = [r for r in ok if r["named"] and r["heldout_truth_rms_after_mm"] > r["heldout_truth_rms_before_mm"] * 1.01]
    with_findings = [r for r in ok if r["named"]]
    lines.append(f"sessions where the accepted findings made held-out worse (> 1%): {len(worse)}/{len(with_findings)}"
                 + "".join(f"; {r['stand']} {r['truth']} -> {'+'.join(r['named'])} {r['heldout_truth_rms_before_mm']:.3f}"
                           f"->{r['heldout_truth_rms_after_mm']:.3f} mm" for r in worse))
    rs = [r for r in ok if r["kind"] in ("clear", "weak", "pair") and right(r) and r["truth"] not in UNSEPARABLE]
    if rs:
        b = np.array([r["heldout_truth_rms_before_mm"] for r in rs])
        a = np.array([r["heldout_truth_rms_after_mm"] for r in rs])
        lines.append(f"held-out RMS against the true settled markers, sessions named right: median {np.median(b):.3f} -> "
                     f"{np.median(a):.3f} mm (median reduction {100 * np.median(1 - a / b):.0f}%)")
    if clean:
        b = np.array([r["heldout_truth_rms_before_mm"] for r in clean])
        a = np.array([r["heldout_truth_rms_after_mm"] for r in clean])
        lines.append(f"held-out RMS, clean sessions: median {np.median(b):.4f} (geometric) -> {np.median(a):.4f} mm "
                     "(diagnosed)")
    lines.append("settle bias along the last step (platkit's settled markers minus the true settled ones):")
    for stand in sorted({r["stand"] for r in results}):
        for label, pick in (("clean", lambda r: r["kind"] == "clean"),
                            ("all but a slow actuator", lambda r: "settling_lag" not in r["truth"])):
            ss = [r["settle"] for r in results if r["stand"] == stand and pick(r) and "mean_mm" in r.get("settle", {})]
            if ss:
                m = np.array([s["mean_mm"] for s in ss])
                u = np.array([s["in_noise_units"] for s in ss])
                t = np.array([s["t"] for s in ss])
                ref = [s["reference_last_second"] for s in ss if "in_noise_units" in s.get("reference_last_second", {})]
                ref_text = (f"; reference (mean of each hold's last second) {np.mean([x['in_noise_units'] for x in ref]):+.3f}"
                            if ref else "")
                lines.append(f"  {stand:8s} {label:24s} n={len(ss):3d}  mean {np.mean(m) * 1e3:+.2f} um  "
                             f"= {np.mean(u):+.3f} +- {np.std(u, ddof=1) / np.sqrt(len(u)) if len(u) > 1 else np.nan:.3f} "
                             f"averaging noise (range {u.min():+.2f}..{u.max():+.2f}); "
                             f"t median {np.median(t):+.1f}{ref_text}")
        fails = [r for r in results if r["stand"] == stand and "error" in r.get("settle", {})]
        if fails:
            lines.append(f"  {stand:8s} settle failed in {len(fails)} sessions: {fails[0]['settle']['error'][:200]}")
    lines.append(f"time: {sum(r.get('time_s', 0) for r in results):.0f} s over {len(results)} sessions")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--stands", default=",".join(STANDS))
    ap.add_argument("--sessions-per-cell", type=int, default=3)
    ap.add_argument("--seed-base", type=int, default=880000, help="first seed (default 880000: never used in development)")
    ap.add_argument("--commands", type=int, default=120, help="commands per session (default 120)")
    ap.add_argument("--kinds", default="clean,clear,weak,pair,outside",
                    help="cells: clean, clear, weak, pair, outside (physics the effect library does not hold, at a "
                         "clear and a weak size: right when said 'unexplained' and nothing else)")
    ap.add_argument("--effects", default=None, help="only cells with these effects (comma-separated)")
    ap.add_argument("--seeds", default=None,
                    help="only the sessions with these seeds (comma-separated) of the plan the other options make: "
                         "a session's seed is its place in that plan, so give the --stands, --kinds, --effects and "
                         "--seed-base of the run that printed it")
    ap.add_argument("--smoke", action="store_true",
                    help="a smoke run: one session per cell, 40 commands, the clean and the clear backlash cell of "
                         "every stand")
    ap.add_argument("--white-noise", action="store_true",
                    help="marker noise white only (default: white plus a correlated part, drawn per session)")
    add_engine_options(ap)  # --jobs N, --scheduler ADDRESS, --serial
    ap.add_argument("--json", default=None,
                    help="append one JSON line per session here, as each finishes; a re-run skips the sessions it holds")
    ap.add_argument("--summarise", default=None, metavar="JSONL", help="only print the tables of a saved run")
    args = ap.parse_args(argv)
    if args.summarise:
        with open(args.summarise) as fh:
            print(summarise([json.loads(line) for line in fh if line.strip()]))
        return 0
    if args.smoke:
        args.sessions_per_cell, args.commands, args.kinds, args.effects = 1, 40, "clean,clear", "backlash"
    only = set(args.effects.split(",")) if args.effects else None
    cases = plan_cases(args.stands.split(","), args.sessions_per_cell, args.seed_base, args.commands,
                       set(args.kinds.split(",")), only, coloured=not args.white_noise)
    if args.seeds:
        try:
            wanted = {int(x) for x in args.seeds.split(",") if x.strip()}
        except ValueError:
            print(f"diagnosis_proof_physical: --seeds {args.seeds}: give whole numbers, comma-separated", file=sys.stderr)
            return 2
        missing = sorted(wanted - {c["seed"] for c in cases})
        if missing:
            print(f"diagnosis_proof_physical: --seeds: {', '.join(map(str, missing))} not in the plan of these "
                  f"--stands, --kinds, --effects and --seed-base", file=sys.stderr)
            return 2
        cases = [c for c in cases if c["seed"] in wanted]
    print(f"{len(cases)} sessions, seeds from {args.seed_base}, {args.commands} commands each", flush=True)

    def show(r):
        if r.get("not_applicable"):
            print(f"  {r['stand']:8s} {r['seed']} {r['truth']:34s} {r['kind']:6s} not applicable: "
                  f"{r['not_applicable'][:120]}")
            return
        if r.get("error"):
            print(f"  {r['stand']:8s} {r['seed']} {r['truth']:34s} {r['kind']:6s} ERROR {r['error'][:160]}", flush=True)
            return
        s = r.get("settle", {})
        print(f"  {r['stand']:8s} {r['seed']} {r['truth']:34s} {r['kind']:6s} -> {'+'.join(r['named']) or 'none':28s} "
              f"held-out "
              f"{r['heldout_truth_rms_before_mm']:.3f} -> {r['heldout_truth_rms_after_mm']:.3f} mm; settle bias "
              f"{s.get('in_noise_units', float('nan')):+.2f} noise ({r['time_s']:.0f} s)", flush=True)

    try:
        results = run_cases(run_case, cases, jobs=args.jobs, scheduler=args.scheduler, serial=args.serial,
                            json_path=args.json, failed_row=failed_row, show=show)
    except BadInput as exc:
        print(f"diagnosis_proof_physical: {exc}", file=sys.stderr)
        return 2
    print(summarise(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
