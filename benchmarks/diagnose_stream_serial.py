"""Serial correlation of the paired tests diagnose runs over a stream's windowed poses, and the
size of the held-out stream's test on nulls with that correlation.

Each case simulates one Stewart stream of the physical simulator as benchmarks/diagnose_stream.py
does (platkit simulate --physics --motion KIND --duration-s 30 --rate-hz 40 --noise-mm 0.2
--white-noise --rigid-bodies 2 --seed S [--effect E]; the rigid bodies alone), cuts it in time
(tests/stream_split.py: the first 70 % of the command log's span to train, the rest held out),
calibrates the training part from motion (--response-kind first-order) and diagnoses it with
--heldout the rest. Every paired test the diagnosis runs (platkit.diagnose.stats.
paired_improvement) is recorded with its per-pose errors: the K-fold comparisons on the training
stream's windowed poses (response_kind, search, naming, rounds, geometry, recording) and the held-out
stream's verdict (evidence).

    .venv/bin/python benchmarks/diagnose_stream_serial.py [--seeds 5701 5702] [--motions multisine path]
        [--effects none] [--first-order-drives] [--draws 4000]

Prints, per test's caller, the medians over its tests of the paired differences' autocorrelation in
time order (poses at lags 1-3; window means at lags 1-2); per case, the held-out verdict's p as
over independent poses (the Wilcoxon signed-rank test) and given the windows
(stats.serial_signed_rank); then the size of both tests on synthetic nulls: Gaussian and
Student-t(3) paired differences with the held-out differences' autocorrelation pooled over the
cases (lags 0-11), at 11 and 21 windows of three poses, and AR(1) with rho 0.3 from pose to pose.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy import linalg

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bodies_alone import strip_markers  # noqa: E402
from stream_split import split_stream  # noqa: E402

import platkit.diagnose.stats as stats  # noqa: E402
from platkit.cli import main  # noqa: E402

CALLERS = ("naming", "evidence", "search", "geometry", "rounds", "recording", "response_kind")
NODES = 3  # a stream window's poses (platkit.calibrate.stream.NODES)
LEVELS = (0.05, 0.01, 0.005)
TESTS: list[dict] = []


def _record(caller: str, test):
    def recorded(before, after, windows=None):
        p = test(before, after, windows)
        TESTS.append({"caller": caller, "before": np.asarray(before, float).copy(),
                      "after": np.asarray(after, float).copy(), "windows": windows, "p": p})
        return p
    return recorded


def run_case(seed: int, motion: str, effect: str, work: Path) -> list[dict]:
    """The paired tests of one case's diagnosis (see the module docstring)."""
    start = len(TESTS)
    args = ["simulate", "--platform", "stewart", "--physics", "--motion", motion, "--duration-s", "30", "--rate-hz",
            "40", "--noise-mm", "0.2", "--white-noise", "--rigid-bodies", "2", "--seed", str(seed), "--out",
            str(work / "sim"), "--force"] + ([] if effect == "none" else ["--effect", effect])
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        assert main(args) == 0
        strip_markers(work / "sim", work / "session")
        train, held = split_stream(work / "session", work, 0.7)
        assert main(["calibrate", str(train), "--quiet", "--no-report", "--response-kind", "first-order", "--out",
                     str(work / "cal")]) in (0, 3)
        assert main(["diagnose", str(train), "--calibration", str(work / "cal" / "calibration.yaml"), "--heldout",
                     str(held), "--out", str(work / "diag"), "--quiet", "--no-report"]) == 0
    return TESTS[start:]


def _acf(x: np.ndarray, lags: int) -> np.ndarray:
    x = x - x.mean()
    den = float(x @ x)
    return np.array([float(x[k:] @ x[:len(x) - k]) / den if den > 0 else np.nan for k in range(lags + 1)])


def _rates(p: np.ndarray) -> str:
    return " / ".join(f"{np.mean(p < a):.3f}" for a in LEVELS)


def null_sizes(acf: np.ndarray, draws: int) -> None:
    """Rejection rates at LEVELS of both tests on the synthetic nulls (module docstring)."""
    rng = np.random.default_rng(0)
    print(f"synthetic nulls, {draws} draws each: rejected at {' / '.join(f'{a:g}' for a in LEVELS)}")
    print("| null | windows | as independent poses | given the windows |")
    print("|---|---|---|---|")
    for n_w in (11, 21):
        n = NODES * n_w
        windows = np.arange(n) // NODES
        r = np.zeros(n)
        r[:len(acf)] = acf[:n]
        ev, V = np.linalg.eigh(linalg.toeplitz(r))
        root = V * np.sqrt(np.maximum(ev, 0.0))
        ar_root = np.linalg.cholesky(linalg.toeplitz(0.3 ** np.arange(n)))
        for name, mix, tails in (("held-out ACF, Gaussian", root, False), ("held-out ACF, Student-t(3)", root, True),
                                 ("AR(1) rho 0.3", ar_root, False)):
            ds = [mix @ (rng.standard_t(3, n) / np.sqrt(3.0) if tails else rng.standard_normal(n)) for _ in range(draws)]
            p = np.array([(stats.paired_improvement(d, 0 * d), stats.paired_improvement(d, 0 * d, windows)) for d in ds])
            print(f"| {name} | {n_w} | {_rates(p[:, 0])} | {_rates(p[:, 1])} |")


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[5701, 5702, 5703])
    ap.add_argument("--motions", nargs="+", default=["multisine", "path"])
    ap.add_argument("--effects", nargs="+", default=["none"])
    ap.add_argument("--first-order-drives", action="store_true", help="the simulated drives follow first orders "
                    "(benchmarks/diagnose_stream_heldout.py's --first-order-drives)")
    ap.add_argument("--draws", type=int, default=4000)
    a = ap.parse_args()
    if a.first_order_drives:
        from diagnose_stream_heldout import first_order_follow

        from platkit.simulate import actuator
        actuator.follow = first_order_follow
    for caller in CALLERS:
        module = importlib.import_module(f"platkit.diagnose.{caller}")
        module.paired_improvement = _record(caller, stats.paired_improvement)  # type: ignore[attr-defined]
    acf_by: dict[str, list] = defaultdict(list)
    heldout_acf = []
    print("| seed | motion | effect | held-out poses | held-out p as independent poses | given the windows |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in a.seeds:
            for motion in a.motions:
                for effect in a.effects:
                    work = Path(tmp) / f"{motion}_{seed}_{effect.replace(':', '_')}"
                    for t in run_case(seed, motion, effect, work):
                        d = t["before"] - t["after"]
                        if not np.isfinite(d).all() or not d.any() or len(d) % NODES:
                            continue
                        means = d.reshape(-1, NODES).mean(axis=1)
                        acf_by[t["caller"]].append(np.concatenate([_acf(d, 3)[1:], _acf(means, 2)[1:]]))
                        if t["caller"] == "evidence":
                            heldout_acf.append(_acf(d, 11))
                            print(f"| {seed} | {motion} | {effect} | {len(d)} | "
                                  f"{stats.paired_improvement(t['before'], t['after']):.2g} | {t['p']:.2g} |")
    print("\npaired differences' autocorrelation in time order, medians over the tests")
    print("| caller | tests | poses lag 1 | lag 2 | lag 3 | window means lag 1 | lag 2 |")
    print("|---|---|---|---|---|---|---|")
    for caller, rows in acf_by.items():
        m = np.nanmedian(np.array(rows), axis=0)
        print(f"| {caller} | {len(rows)} | " + " | ".join(f"{x:+.2f}" for x in m) + " |")
    if heldout_acf:
        acf = np.mean(heldout_acf, axis=0)
        print(f"\nheld-out differences' ACF pooled over {len(heldout_acf)} tests, lags 0-11: "
              + " ".join(f"{x:.3f}" for x in acf))
        null_sizes(acf, a.draws)


if __name__ == "__main__":
    main_()
