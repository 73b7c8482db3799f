"""Diagnosis of a stream without holds against a held-out stream of the same stand.

Each seed simulates one Stewart stream of the physical simulator (platkit simulate --physics
--motion KIND --duration-s D --rate-hz 40 --noise-mm 0.2 --white-noise), clean or with a hidden
effect; the stream is cut in time (tests/stream_split.py) into a training session (the first 70 %
of the command log's span) and a held-out session (the rest): the same stand, not the same
samples. The training session is calibrated from motion (platkit calibrate, its response kind
chosen by BIC unless --response-kind) and diagnosed with --heldout the held-out stream.

    .venv/bin/python benchmarks/diagnose_stream_heldout.py [--seeds 5201 5202 5203] \
        [--effects none backlash:1.0] [--motion path multisine] [--duration-s 30] [--keep DIR]
        [--compare-kinds [auto first-order second-order]] [--first-order-drives] [--log-cut-s S]

Prints one row per seed, motion and effect: the response's kind (calibrate's, and diagnose's
where it chose another), what diagnosis names (the truth's effect and place beside it), the
held-out stream's point RMS before -> after as diagnosis.json gives it (the diagnosis's geometric
model and the diagnosed one, each reading it through its own response), the
noise floor of the training stream's windowed poses and the geometric model's K-fold held-out RMS,
the held-out stream's RMS with calibrate's calibration.yaml and with diagnose's, each file read as
written (its windows and response), and, against the truth, the markers predicted at the held-out part's commands
(truth_settled.csv: where the stand settles at each command, in the log's order) with calibrate's
and with diagnose's calibration.

``--compare-kinds``: no diagnosis; per seed calibrate's own choice of the response's kind (auto:
the kind, the whole fits' BICs, the second order's fast content against the first's) and the
held-out stream's RMS and the truth's with the kind chosen and with each kind named.
``--first-order-drives``: the simulated drives follow first orders of the drawn second order's
lag (2 zeta tau) instead of the drawn second orders (a truth where the second order is false).
``--log-cut-s S``: the training session's command log ends S s before the cut, its markers running
on to the cut (a log that stops while the stand moves: its last S s of samples follow commands the
log does not have).
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from scipy import signal

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from stream_split import settled_commands, settled_error_mm, split_stream  # noqa: E402

from platkit.calibrate.estimate import point_errors  # noqa: E402
from platkit.cli import main  # noqa: E402
from platkit.diagnose.stream import heldout_stream, read_through  # noqa: E402
from platkit.io.calibration import read_calibration  # noqa: E402
from platkit.io.session import load_session  # noqa: E402
from platkit.simulate import actuator  # noqa: E402

TRAIN_SHARE = 0.7
KINDS = ("auto", "first-order", "second-order")


def truth_rms(sim: Path, cal: Path, t_cut: float, work: Path) -> float:
    """RMS (mm, 3-D) of the markers ``cal`` predicts at the held-out part's commands against where
    the true stand settles there (truth_settled.csv)."""
    cmd, out = work / "held_commands.csv", work / "pred.csv"
    rows = settled_commands(sim, [f"L{k}" for k in range(1, 7)], cmd, t_from=t_cut)
    assert main(["predict", "--calibration", str(cal), "--commands", str(cmd), "--out", str(out)]) == 0
    return settled_error_mm(rows, out, [f"M{k}" for k in range(1, 6)])


def stream_rms(cal_path: Path, held: Path) -> float:
    """RMS (mm, 3-D) of the held-out stream's windowed poses predicted by the calibration file
    ``cal_path`` as written (its windows, its response: platkit.diagnose.stream)."""
    cal = read_calibration(str(cal_path))
    h = heldout_stream(held, load_session(held, spec=cal.spec, quiet=True), cal)
    e = point_errors(cal, read_through(h, cal, cal.spec))
    return float(np.sqrt(np.nanmean(e ** 2)) * 1e3)


def first_order_follow(reference: np.ndarray, dt: float, tau_s: np.ndarray, damping: np.ndarray) -> np.ndarray:
    """(K, n_u) each actuator following ``reference`` as a first order of time constant 2 zeta tau
    (the drawn second order's lag at low frequency), exact for a reference held over each step:
    the truth of --first-order-drives."""
    out = np.empty_like(reference)
    for j in range(reference.shape[1]):
        a = float(np.exp(-dt / (2.0 * float(damping[j]) * float(tau_s[j]))))
        x0 = reference[0, j]
        out[:, j] = x0 + signal.lfilter([0.0, 1.0 - a], [1.0, -a], reference[:, j] - x0)
    return out


def compare_kinds(src: Path, train: Path, held: Path, t_cut: float, kinds=KINDS) -> dict:
    """calibrate's choice (--response-kind auto: the kind and the report's choice) and the held-out
    stream's RMS and the truth's with the kind chosen and with each kind named."""
    out: dict = {}
    for kind in kinds:
        cal = src / f"cal_{kind}"
        rc = main(["calibrate", str(train), "--quiet", "--no-report", "--out", str(cal), "--response-kind", kind])
        assert rc == 0 or (cal / "calibration.yaml").is_file()
        doc = yaml.safe_load((cal / "calibration.yaml").read_text())["actuator_response"]["response"]
        out[kind] = {"kind": doc["kind"], "choice": doc.get("choice"), "stream": stream_rms(cal / "calibration.yaml", held),
                     "truth": truth_rms(src / "sim", cal / "calibration.yaml", t_cut, src)}
    return out


def run(root: Path, seed: int, motion: str, effect: str, duration: float, kind: str | None,
        compare: tuple = (), log_cut_s: float = 0.0) -> dict:
    src = root / f"s{seed}_{motion}_{effect.split(':')[0]}"
    args = ["simulate", "--platform", "stewart", "--physics", "--motion", motion, "--duration-s", str(duration),
            "--rate-hz", "40", "--noise-mm", "0.2", "--white-noise", "--seed", str(seed), "--out", str(src / "sim")]
    assert main(args + ([] if effect == "none" else ["--effect", effect])) == 0
    truth = yaml.safe_load((src / "sim" / "truth.yaml").read_text()).get("effects") or []
    train, held = split_stream(src / "sim", src, TRAIN_SHARE, log_cut_s=log_cut_s)
    t_cut = float(next(csv.reader((held / "commands.csv").open().readlines()[1:2]))[0])
    if compare:
        return {"truth": truth, "kinds": compare_kinds(src, train, held, t_cut, compare)}
    rc = main(["calibrate", str(train), "--quiet", "--no-report", "--out", str(src / "cal")]
              + ([] if kind is None else ["--response-kind", kind]))
    assert rc == 0 or (src / "cal" / "calibration.yaml").is_file()
    assert main(["diagnose", str(train), "--calibration", str(src / "cal" / "calibration.yaml"), "--heldout",
                 str(held), "--out", str(src / "diag"), "--quiet", "--no-report"]) == 0
    d = json.loads((src / "diag" / "diagnosis.json").read_text())
    response = " -> ".join(dict.fromkeys(  # calibrate's kind, and diagnose's where it chose another
        yaml.safe_load((src / f / "calibration.yaml").read_text())["actuator_response"]["response"]["kind"]
        for f in ("cal", "diag")))
    return {"truth": [e["effect"] + f" {(e.get('physics') or {}).get('actuator', '')}".rstrip() for e in truth],
            "named": [f["effect"] + f" {f['where'].get('actuator', '')}".rstrip() for f in d["findings"]],
            "heldout": d["heldout_session"], "floor": d["noise_floor"], "cv": d["heldout_rms_geometric"],
            "response": response, "calibrate_rc": rc,
            "files": (stream_rms(src / "cal" / "calibration.yaml", held),
                      stream_rms(src / "diag" / "calibration.yaml", held)),
            "truth_rms": (truth_rms(src / "sim", src / "cal" / "calibration.yaml", t_cut, src),
                          truth_rms(src / "sim", src / "diag" / "calibration.yaml", t_cut, src))}


def main_() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[5201, 5202, 5203])
    ap.add_argument("--effects", nargs="+", default=["none", "backlash:1.0"])
    ap.add_argument("--motion", nargs="+", default=["path", "multisine"])
    ap.add_argument("--duration-s", type=float, default=30.0)
    ap.add_argument("--response-kind", default=None, help="calibrate's --response-kind (default: its own choice)")
    ap.add_argument("--keep", type=Path, default=None, help="keep every seed's folders (sim, train, held, cal, diag) "
                    "under this folder (default: a temporary one)")
    ap.add_argument("--first-order-drives", action="store_true", help="the simulated drives follow as first "
                    "orders of the drawn second order's lag (2 zeta tau), not as the drawn second orders")
    ap.add_argument("--compare-kinds", nargs="*", default=None, choices=KINDS, help="no diagnosis: calibrate's "
                    "choice (auto) and the held-out stream's RMS (and the truth's) with the kind chosen, first-order "
                    "and second-order named (default all three)")
    ap.add_argument("--log-cut-s", type=float, default=0.0, help="the training command log ends this long before "
                    "the cut, its markers running on to it (a log that stops while the stand moves)")
    a = ap.parse_args()
    if a.first_order_drives:
        actuator.follow = first_order_follow  # actuator_motion's follow: the truth's drives
    if a.compare_kinds is not None:
        return compare_rows(a, tuple(a.compare_kinds) or KINDS)
    print("seed motion effect (truth) | response (calibrate's -> diagnose's) | named | "
          "held-out stream rms mm before -> after (windows) | "
          "floor mm | geometric K-fold mm (x floor) | held-out stream mm, the files: calibrate -> diagnose | "
          "held-out commands vs truth mm: calibrate -> diagnose")
    for seed, motion, effect, r in cases(a, a.response_kind):
        h, fl = r["heldout"], r["floor"]
        ratio = f"{r['cv'] / fl:.2g}" if fl else "-"
        print(f"{seed} {motion} {effect} ({', '.join(r['truth']) or 'none'}) | {r['response']}"
              + (f" (calibrate exit {r['calibrate_rc']})" if r["calibrate_rc"] else "")
              + f" | {', '.join(r['named']) or 'nothing'} | {h['rms_before']:.4g} -> {h['rms_after']:.4g}"
              f" ({h['n_poses']}) | {fl if fl is None else format(fl, '.3g')} | {r['cv']:.3g} ({ratio}) | "
              f"{r['files'][0]:.4g} -> {r['files'][1]:.4g} | "
              f"{r['truth_rms'][0]:.4g} -> {r['truth_rms'][1]:.4g}", flush=True)


def cases(a, response_kind, **kw):
    """(seed, motion, effect, run's figures) for every seed, motion and effect asked, each run
    quiet, its folders under --keep or a temporary folder."""
    with contextlib.ExitStack() as stack:
        tmp = a.keep or stack.enter_context(tempfile.TemporaryDirectory())
        for seed in a.seeds:
            for motion in a.motion:
                for effect in a.effects:
                    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                        r = run(Path(tmp), seed, motion, effect, a.duration_s, response_kind, log_cut_s=a.log_cut_s, **kw)
                    yield seed, motion, effect, r


def compare_rows(a, kinds: tuple) -> None:
    """--compare-kinds: one row per seed, motion and effect."""
    print(f"seed motion effect | auto: kind (whole fit's BIC first vs second; the second's fast content worse than "
          f"the first's, noise variances) | "
          f"held-out stream mm {' / '.join(kinds)} | held-out commands vs truth mm {' / '.join(kinds)}")
    for seed, motion, effect, r in cases(a, None, compare=kinds):
        k = r["kinds"]
        ch = (k.get("auto") or {}).get("choice") or {}
        fast = ch.get("fast_content") or {}
        figs = " vs ".join(f"{v:.1f}" for v in (ch.get("bic") or {}).values()) + (
            f"; fast content worse by {fast['worse_in_noise_variances']:.1f}, {fast['allowed']} allowed"
            if fast else "")
        print(f"{seed} {motion} {effect} | {(k.get('auto') or {}).get('kind')} ({figs}) | "
              + " / ".join(f"{k[x]['stream']:.4g}" for x in k) + " | "
              + " / ".join(f"{k[x]['truth']:.4g}" for x in k), flush=True)


if __name__ == "__main__":
    main_()
