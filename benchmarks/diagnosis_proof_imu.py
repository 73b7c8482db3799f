"""Proof of the IMU diagnosis on concealed effects: does it name what was hidden in the IMU, and only that?

Sessions are simulated (platkit.simulate with an IMU on the moving part, raw motion-capture
stream, 60 random commands), calibrated on their own poses (geometric model), and diagnosed by
platkit.diagnose.imu with the calibration's covariance and the parameters it held at nominal
(what `platkit diagnose` does with a session's imu.csv; the pose search is not run here: it sees
nothing of these effects). One concealed IMU effect each:

- ``gyro_bias_drift``: the gyro bias changes linearly in time (a random direction);
- ``imu_misalignment``: the IMU turned against the platform (a random rotation vector);
- ``base_tilt``: the whole stand turned about a random horizontal axis in the level world, as
  `platkit simulate --effect base_tilt` does (the motion capture absorbs it; gravity in the
  model's base frame turns with it);

at a clear and a weak size, on every stand asked for, several seeds; clean sessions; and a pair
(misalignment and tilt). Every sensor also has a constant gyro bias (0.003, -0.002, 0.001) rad/s,
an accelerometer bias (0.05, -0.03, 0.08) m/s^2 and accelerometer scale errors (+0.3%, -0.3%,
+0.2%); noise 0.002 rad/s and 0.02 m/s^2 per sample at 200 Hz.

Sizes are set by what the measurement can see: the same session without the effect (same true
stand, plan and sensor) is diagnosed first, and its smallest detectable size for the effect (the
larger of the effect's floor (its min_size) and the size the Wald test lets through in its
worst direction with every covariance: the noise, the calibration's uncertainty, the frames its
held parameters leave open; `detectable_size` in the tests) makes 'clear' 3 times and 'weak' 1.5
times that.

Every session has its own held-out recording: the same stand and sensor with another random
plan, noise-free. The diagnosed models are scored on it (their named parameters held, only the
constant biases and gravity scales refitted): the gyro's mean rates between holds (deg/s) for a
misalignment and the accelerometer at the holds (m/s^2) for a tilt, against the base model. A
drift is the recording's own and predicts nothing of another: not scored there.

Printed: the confusion table (true effect vs named effects), false findings on clean sessions,
parameter recovery against the truth with its interval (a tilt's against the true tilt, a
misalignment's against the true rotation: the model's own frames are part of the interval), the
held-out error before and after, and the goals (clear named right in >= 95% of sessions, weak in
>= 80%, no finding on >= 95% of clean sessions).

    .venv/bin/python benchmarks/diagnosis_proof_imu.py --quick          # stewart, 1 seed (~1 min, 2 cores)
    .venv/bin/python benchmarks/diagnosis_proof_imu.py --json imu.jsonl            # full: 3 stands, 3 seeds (81 sessions)
    .venv/bin/python benchmarks/diagnosis_proof_imu.py --summarise imu.jsonl       # the tables again
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from platkit.errors import BadInput, PlatkitError

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the case runner: tests/batch_cases.py
from batch_cases import add_engine_options, run_cases  # noqa: E402

DEG = 180.0 / np.pi
N_POSES = 60
GYRO_BIAS = (0.003, -0.002, 0.001)
ACC_BIAS = (0.05, -0.03, 0.08)
ACC_SCALE = (1.003, 0.997, 1.002)
NOISE = (0.002, 0.02)
CLEAR, WEAK = 3.0, 1.5  # times the smallest detectable size
EFFECTS = ["gyro_bias_drift", "imu_misalignment", "base_tilt"]
PAIRS = [("imu_misalignment", "base_tilt")]
#: where the held-out recording scores an effect: gyro (deg/s) or accelerometer (m/s^2)
SCORED = {"imu_misalignment": "gyro", "base_tilt": "accelerometer"}


# ---------------------------------------------------------------------------- one session
def _plan(spec, seed):
    from platkit.simulate import simulate

    return simulate(spec, seed=seed, n_poses=N_POSES, raw=False, plan="random", noise_mm=0.0, occlusion=0.0).commands


def _session(spec, seed, plan, truth: dict, noise=NOISE):
    """Simulate with the concealed IMU effects ``truth`` {effect: SI parameters}."""
    from platkit.geometry import matrix_from_rotvec
    from platkit.inertial.simulate import imu_for_trajectory
    from platkit.plugins import default_host
    from platkit.simulate import simulate

    terms = []
    if "base_tilt" in truth:
        terms.append((default_host().effects()["base_tilt"].term(), np.asarray(truth["base_tilt"], float)))
    hook = imu_for_trajectory(
        bias=list(GYRO_BIAS) + list(ACC_BIAS), scale=[1, 1, 1] + list(ACC_SCALE), noise=noise,
        imu_from_platform=matrix_from_rotvec(truth["imu_misalignment"]) if "imu_misalignment" in truth else None,
        bias_rate=truth.get("gyro_bias_drift"))
    return simulate(spec, seed=seed, n_poses=N_POSES, plan=plan, terms=terms, imu=hook)


def _diagnose(spec, sim, cal=None):
    from platkit.calibrate.estimate import calibrate
    from platkit.diagnose.imu import diagnose_imu, td_covariance
    from platkit.io.imu import ImuStream

    cal = cal or calibrate(sim.poses, spec)
    im = sim.imu
    d = diagnose_imu(spec, cal.td, sim.command_t, sim.commands, ImuStream(im["t"], im["gyr"], im["acc"]),
                     td_cov=td_covariance(cal), td_status=cal.td_status)
    return cal, d


def _detectable(d) -> dict[str, float]:
    """{effect: the smallest size the diagnosis would name (first round), in the tests' unit}."""
    return {r["effect"]: r["detectable_size"] for r in d.tests[0]["candidates"] if "detectable_size" in r}


def _truth_parameters(effect: str, size: float, rng) -> np.ndarray:
    """SI parameters of ``effect`` at ``size`` (the tests' unit) in a random direction."""
    if effect == "base_tilt":
        a = rng.uniform(0, 2 * np.pi)
        return size / DEG * np.array([np.cos(a), np.sin(a)])
    v = rng.normal(size=3)
    v /= np.linalg.norm(v)
    return v * size / (DEG if effect == "imu_misalignment" else DEG * 60.0)


def _heldout(spec, cal, d, test) -> dict[str, list[float]]:
    """RMS on the noise-free held-out recording ``test`` before (base model) and after (the named
    parameters), nuisances refitted: 'gyro' deg/s of the mean rates, 'accelerometer' m/s^2."""
    from platkit.diagnose.imu import segments_from_session, up_in_sensor
    from platkit.geometry import matrix_from_rotvec
    from platkit.inertial.command_aided import command_poses
    from platkit.io.imu import ImuStream
    from platkit.kinematics import PlatformModel
    from platkit.plugins import effect_library

    im = test.imu
    q = command_poses(PlatformModel(spec), test.commands, td=cal.td)
    seg = segments_from_session(ImuStream(im["t"], im["gyr"], im["acc"]), test.command_t, q)
    named = {f["effect"] for f in d.findings}

    def gyro_rms(theta):
        r = seg.y - seg.p @ matrix_from_rotvec(theta).T
        r = r - np.average(r, axis=0, weights=seg.dt)
        return float(np.sqrt(np.mean(r**2))) * DEG

    tilt_effect = effect_library()["imu_base_tilt"]

    def acc_rms(w):
        u = up_in_sensor(seg.holds.R, matrix_from_rotvec(d.acc_final.sensor_rotation), tilt_effect.level_from_base(w))
        r = np.empty_like(u)
        for j in range(3):
            A = np.stack([u[:, j], np.ones(len(u))], axis=1)
            r[:, j] = seg.holds.f[:, j] - A @ np.linalg.lstsq(A, seg.holds.f[:, j], rcond=None)[0]
        return float(np.sqrt(np.mean(r**2)))

    theta = d.final.theta("imu_misalignment") if "imu_misalignment" in named else np.zeros(3)
    w = d.acc_final.theta("imu_base_tilt") if "base_tilt" in named else np.zeros(2)
    return {"gyro": [gyro_rms(np.zeros(3)), gyro_rms(theta)], "accelerometer": [acc_rms(np.zeros(2)), acc_rms(w)]}


def _recovery(effect: str, truth: np.ndarray, finding: dict) -> dict:
    p = finding["parameters"]
    if effect == "base_tilt":
        names, t = ["tilt_x", "tilt_y"], truth * DEG
    elif effect == "imu_misalignment":
        names, t = ["angle_x", "angle_y", "angle_z"], truth * DEG
    else:
        names, t = ["drift_x", "drift_y", "drift_z"], truth * DEG * 60.0
    est = np.array([p[n]["value"] for n in names])
    std = np.array([p[n]["std"] for n in names])
    return {"effect": effect, "truth": t.tolist(), "estimate": est.tolist(), "std": std.tolist(),
            "z": ((est - t) / std).tolist(), "unit": p[names[0]]["unit"]}


def run_case(case: dict) -> dict:
    """One session: size from its clean twin, simulate, diagnose, score. A case whose
    simulation or diagnosis raises is recorded with the message (and counted), not dropped."""
    t0 = time.perf_counter()
    try:
        return {**_run_case(case), "time_s": time.perf_counter() - t0}
    except (PlatkitError, ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return failed_row(case, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)


def failed_row(case: dict, error: str, seconds: float) -> dict:
    """The line of a session that failed: in run_case, past it, or lost with its worker."""
    return {**case, "named": [], "error": error, "time_s": seconds}


def as_json(o):
    """json.dumps' default for a result line: arrays as lists, anything else as its text."""
    return o.tolist() if isinstance(o, np.ndarray) else str(o)


def _run_case(case: dict) -> dict:
    from platkit.plugins import get_platform

    spec = get_platform(case["stand"])
    seed = case["seed"]
    plan = _plan(spec, seed + 31)
    rng = np.random.default_rng(seed + 99)
    truth, sizes = {}, {}
    if case["effects"]:
        twin = _session(spec, seed, plan, {})
        _, dt = _diagnose(spec, twin)
        det = _detectable(dt)
        for e, strength in case["effects"]:
            sizes[e] = det[e] * (CLEAR if strength == "clear" else WEAK)
            truth[e] = _truth_parameters(e, sizes[e], rng)
    sim = _session(spec, seed, plan, truth)
    cal, d = _diagnose(spec, sim)
    test = _session(spec, seed, _plan(spec, seed + 7919), truth, noise=(0.0, 0.0))
    held = _heldout(spec, cal, d, test)
    named = [f["effect"] for f in d.findings]
    recovery = [_recovery(e, truth[e], next(f for f in d.findings if f["effect"] == e)) for e in truth if e in named]
    tilt_row = next((r for r in d.tests[0]["candidates"] if r["effect"] == "base_tilt"), {})
    return {**case, "named": named, "sizes": sizes, "truth_si": {k: v.tolist() for k, v in truth.items()},
            "findings": [{"effect": f["effect"], "parameters": f["parameters"]} for f in d.findings],
            "not_separable": [x["effect"] for x in d.not_separable], "recovery": recovery, "heldout": held,
            "tilt_separability": tilt_row.get("separability"), "frame": d.frame,
            "first_round": {r["effect"]: {k: r.get(k) for k in ("size", "detectable_size", "p_adjusted", "p_heldout",
                                                                "p_beyond_model", "relative_gain")}
                            for r in d.tests[0]["candidates"]}}


# ---------------------------------------------------------------------------- the plan
def plan_cases(stands, seeds: int) -> list[dict]:
    cases = []
    for stand in stands:
        for s in range(seeds):
            seed = 1000 * (1 + s) + 17
            for e in EFFECTS:
                for strength in ("clear", "weak"):
                    cases.append({"stand": stand, "seed": seed, "kind": strength, "effects": [(e, strength)], "truth": e})
            for c in range(2):
                cases.append({"stand": stand, "seed": seed + 500 + c, "kind": "clean", "effects": [], "truth": "none"})
            for a, b in PAIRS:
                cases.append({"stand": stand, "seed": seed, "kind": "pair", "effects": [(a, "clear"), (b, "clear")],
                              "truth": f"{a}+{b}"})
    return cases


# ---------------------------------------------------------------------------- the tables
def summarise(results: list[dict]) -> dict:
    lines, out = [], {}
    errors = [r for r in results if r.get("error")]
    for r in errors:
        lines.append(f"ERROR {r['stand']} {r['truth']} ({r['kind']}, seed {r['seed']}): {r['error']}")
    out["errors"] = len(errors)
    results = [r for r in results if not r.get("error")]
    stands = sorted({r["stand"] for r in results})

    def right(r):
        return sorted(r["named"]) == sorted(e for e, _ in r["effects"])

    # sizes: what 'clear' and 'weak' came to
    sz = defaultdict(list)
    for r in results:
        for e, v in r.get("sizes", {}).items():
            sz[(r["stand"], e, r["kind"])].append(v)
    unit = {"base_tilt": "deg", "imu_misalignment": "deg", "gyro_bias_drift": "deg/s per min"}
    lines.append("sizes (3x / 1.5x the smallest detectable size of the clean twin; median over seeds):")
    for stand in stands:
        lines.append(f"  {stand:8s} " + "; ".join(
            f"{e} clear {np.median(sz[(stand, e, 'clear')]):.3g} weak {np.median(sz[(stand, e, 'weak')]):.3g} {unit[e]}"
            for e in EFFECTS if sz[(stand, e, 'clear')]))
    seps = defaultdict(list)
    frames = defaultdict(list)
    for r in results:
        if r.get("tilt_separability") is not None:
            seps[r["stand"]].append(r["tilt_separability"])
        if r.get("frame"):
            frames[r["stand"]].append(max(r["frame"]["base_tilt_std_deg"]))
    lines.append("tilt separability (min-max): " + ", ".join(f"{s} {min(v):.3f}-{max(v):.3f}" for s, v in sorted(seps.items()))
                 + "; model base frame allowance (1 sigma, deg): "
                 + ", ".join(f"{s} {min(v):.3f}-{max(v):.3f}" for s, v in sorted(frames.items())))
    # confusion: true effect(s) vs the set named
    confusion: dict[str, Counter] = defaultdict(Counter)
    for r in results:
        confusion[f"{r['truth']} ({r['kind']})"]["+".join(sorted(r["named"])) or "none"] += 1
    cols = sorted({k for c in confusion.values() for k in c})
    short = {"gyro_bias_drift": "drift", "imu_misalignment": "misal", "base_tilt": "tilt"}

    def abbrev(c):
        return "+".join(short.get(x, x) for x in c.split("+"))

    lines.append("confusion (rows: truth; columns: named)")
    lines.append(f"{'':42s}" + "".join(f"{abbrev(c):>12s}" for c in cols))
    for row in sorted(confusion):
        lines.append(f"{row:42s}" + "".join(f"{confusion[row].get(c, 0):12d}" for c in cols))
    for kind in ("clear", "weak"):
        rs = [r for r in results if r["kind"] == kind]
        by = defaultdict(list)
        for r in rs:
            by[(r["truth"], r["stand"])].append(right(r))
        total = float(np.mean([right(r) for r in rs])) if rs else float("nan")
        out[f"named_right_{kind}"] = total
        lines.append(f"{kind}: named right (that effect alone) in {sum(right(r) for r in rs)}/{len(rs)} sessions "
                     f"({100 * total:.0f}%); " + ", ".join(f"{e}@{s} {sum(v)}/{len(v)}" for (e, s), v in sorted(by.items())))
    clean = [r for r in results if r["kind"] == "clean"]
    fp = [r for r in clean if r["named"]]
    out["clean_with_a_finding"] = len(fp) / max(len(clean), 1)
    which = ", ".join(f"{r['stand']} seed {r['seed']}: {'+'.join(r['named'])}" for r in fp)
    lines.append(f"clean sessions with any finding: {len(fp)}/{len(clean)}" + (f" ({which})" if fp else ""))
    # what clean sessions show: the largest estimate of each effect against its detectable size
    for e in EFFECTS:
        for st in stands:
            rows = [r["first_round"][e] for r in clean if r["stand"] == st and r.get("first_round", {}).get(e)]
            if not rows:
                continue
            k = int(np.argmax([x["size"] / x["detectable_size"] for x in rows]))
            lines.append(f"  clean {st:8s} {e:17s} largest estimate {rows[k]['size']:.3g} {unit[e]} against a detectable "
                         f"{rows[k]['detectable_size']:.3g}; F test passed (Holm p < 0.01) in "
                         f"{sum(x['p_adjusted'] < 0.01 for x in rows)}/{len(rows)}, held-out test in "
                         f"{sum(x['p_heldout'] < 0.05 and x['relative_gain'] >= 0.02 for x in rows)}/{len(rows)}")
    pairs = [r for r in results if r["kind"] == "pair"]
    out["pairs_right"] = float(np.mean([right(r) for r in pairs])) if pairs else float("nan")
    lines.append(f"pairs (misalignment + tilt, clear) both named and nothing else: {sum(right(r) for r in pairs)}/{len(pairs)}"
                 + "".join(f"; {r['stand']} seed {r['seed']} -> {'+'.join(r['named']) or 'none'}" for r in pairs if not right(r)))
    # parameter recovery
    zs = defaultdict(list)
    errs = defaultdict(list)
    for r in results:
        if r["kind"] == "clean" or not right(r):
            continue
        for rec in r["recovery"]:
            z = np.abs(np.asarray(rec["z"], float))
            zs[(rec["effect"], r["stand"])].append(bool(np.all(z < 2.576)))
            errs[(rec["effect"], r["stand"])].append((float(np.max(np.abs(np.subtract(rec["estimate"], rec["truth"])))),
                                                      rec["std"], rec["unit"]))
    out["recovery_within_99ci"] = float(np.mean([x for v in zs.values() for x in v])) if zs else float("nan")
    lines.append("parameter recovery (sessions named right): every parameter within its 99% interval / largest error "
                 "/ the stds:")
    for (e, s), v in sorted(zs.items()):
        ee = errs[(e, s)]
        stds = [x for e_ in ee for x in e_[1]]
        lines.append(f"  {e:17s} {s:8s} {sum(v)}/{len(v)}; max |error| {max(x[0] for x in ee):.3g}, "
                     f"std {min(stds):.2g}-{max(stds):.2g} {ee[0][2]}")
    # held-out recording
    lines.append("held-out recording (noise-free, another plan; named-right sessions; before -> after, median):")
    for e, where in SCORED.items():
        for s in stands:
            rs = [r for r in results if right(r) and e in [x for x, _ in r["effects"]] and r["stand"] == s]
            if not rs:
                continue
            b = np.array([r["heldout"][where][0] for r in rs])
            a = np.array([r["heldout"][where][1] for r in rs])
            u = "deg/s" if where == "gyro" else "m/s^2"
            lines.append(f"  {e:17s} {s:8s} {where:13s} {np.median(b):.3g} -> {np.median(a):.3g} {u} "
                         f"(largest after {np.max(a):.3g}; {len(rs)} sessions)")
    cl = [r for r in clean if not r["named"]]
    if cl:
        gyro = np.median([r["heldout"]["gyro"][0] for r in cl])
        acc = np.median([r["heldout"]["accelerometer"][0] for r in cl])
        lines.append(f"  clean sessions, nothing named: gyro {gyro:.3g} deg/s, accelerometer {acc:.3g} m/s^2 "
                     "(median, before = after)")
    lines.append("stands: stewart, psvr and rotary all carry an IMU on their moving frame; the psvr never yaws, so a "
                 "tilt shows only through its roll and pitch (the z axis), where the gyro's misalignment estimate "
                 "weighs in as much as the accelerometer's noise")
    lines.append(f"time: {sum(r['time_s'] for r in results + errors):.0f} s over {len(results) + len(errors)} sessions "
                 "(each: its clean twin, the session, the held-out recording)")
    goals = {"clear >= 95%": out.get("named_right_clear", 0) >= 0.95,
             "weak >= 80%": out.get("named_right_weak", 0) >= 0.80,
             "clean: no finding >= 95%": (1 - out["clean_with_a_finding"]) >= 0.95 if clean else False}
    out["goals"] = goals
    lines.append("goals: " + ", ".join(f"{k}: {'met' if v else 'NOT met'}" for k, v in goals.items()))
    out["text"] = "\n".join(lines)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="stewart only, one seed")
    ap.add_argument("--stands", default=None, help="comma-separated stands (default: stewart,psvr,rotary)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per case (default 3; 1 with --quick)")
    add_engine_options(ap)  # --jobs N, --scheduler ADDRESS, --serial
    ap.add_argument("--json", default=None,
                    help="append every case's result here (one JSON line per session, as it ends); a re-run skips "
                         "the sessions it holds")
    ap.add_argument("--summarise", default=None, metavar="JSON", help="only print the tables of a saved run")
    args = ap.parse_args(argv)
    if args.summarise:
        with open(args.summarise) as fh:
            print(summarise([json.loads(line) for line in fh if line.strip()])["text"])
        return 0
    from platkit.plugins import list_platforms

    stands = args.stands.split(",") if args.stands else (["stewart"] if args.quick else ["stewart", "psvr", "rotary"])
    unknown = [s for s in stands if s not in list_platforms()]
    if unknown:
        print(f"unknown stand(s): {', '.join(unknown)}; known: {', '.join(list_platforms())}", file=sys.stderr)
        return 2
    seeds = args.seeds or (1 if args.quick else 3)
    cases = plan_cases(stands, seeds)
    print(f"{len(cases)} sessions on {', '.join(stands)}, {seeds} seed(s)", flush=True)

    def show(r):
        print(f"  {r['stand']:8s} {r['truth']:27s} {r['kind']:6s} seed {r['seed']:5d} -> "
              f"{'+'.join(r['named']) or 'none':28s} {r.get('error', '')}", flush=True)

    try:
        results = run_cases(run_case, cases, jobs=args.jobs, scheduler=args.scheduler, serial=args.serial,
                            json_path=args.json, failed_row=failed_row, show=show, default=as_json)
    except BadInput as exc:
        print(f"diagnosis_proof_imu: {exc}", file=sys.stderr)
        return 2
    print(summarise(results)["text"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
