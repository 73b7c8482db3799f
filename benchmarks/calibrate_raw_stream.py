"""Calibrating a raw motion-capture stream, whole processes, beside the reference (issue 28).

    .venv/bin/python benchmarks/calibrate_raw_stream.py [--session DIR] [--repeat 2]

Ours: ``platkit calibrate RAW --out DIR``, the session as recorded (markers.csv, about 600,000
rows: settling, then the calibration). The reference: what the same result costs without the
settling, ``platkit calibrate POSES --out DIR`` on a folder holding the settled poses of the
same stream (poses.csv, full precision, from ``platkit.settle.load_poses``), plus
``pandas.read_csv`` of the raw markers.csv in a process of its own (reading the stream, the
least any tool does with it). Goal: ours at most 1.5x the reference.

Each row is a fresh process; the three are run in turns (one of each, then again) and the best
of ``--repeat`` is kept, both wall-clock and CPU (user + system of the child: the machine is
shared, and CPU seconds are what load inflates least). Without ``--session`` the stream is
simulated first (stewart, seed 5, 840 commands at 200 Hz: 600,000 rows; about a minute, untimed).
``--before DIR``: a fourth row in the same turns, the same raw calibrate with the ``platkit``
package found in DIR first (PYTHONPATH; e.g. ``git archive REV platkit | tar -x -C DIR``), so that
code before and after a change is timed side by side under the same load. The compiled kernels
(platkit.settle) are compiled into the cache folder before the timing; ``PLATKIT_COMPILE=0``
times the numpy path.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PYTHON = sys.executable
SCRIPT = Path(PYTHON).parent / "platkit"
PLATKIT = [str(SCRIPT)] if SCRIPT.is_file() else [PYTHON, "-m", "platkit.cli"]
ROWS = 600_000


def simulated_stream(folder: Path) -> Path:
    """A stewart stream of ROWS rows: simulated at 200 Hz, cut after ROWS samples (the commands
    that end more than 3 s before the cut kept)."""
    full = folder / "full"
    subprocess.run(PLATKIT + ["simulate", "--platform", "stewart", "--out", str(full), "--seed", "5",
                              "--poses", "860", "--rate-hz", "200"], check=True, stdout=subprocess.DEVNULL)
    raw = folder / "raw"
    raw.mkdir()
    shutil.copy(full / "session.yaml", raw / "session.yaml")
    with open(full / "markers.csv") as src, open(raw / "markers.csv", "w") as dst:
        last = ""
        for i, line in enumerate(src):
            if i > ROWS:
                break
            dst.write(line)
            last = line
    t_last = float(last.split(",")[0])
    lines = (full / "commands.csv").read_text().splitlines()
    keep = [lines[0]] + [x for x in lines[1:] if float(x.split(",")[0]) < t_last - 3.0]
    (raw / "commands.csv").write_text("\n".join(keep) + "\n")
    return raw


def settled_folder(raw: Path, out: Path) -> Path:
    """The settled poses of ``raw`` as a poses.csv session (metres, 17 significant digits)."""
    from platkit.model import controls_from_si
    from platkit.plugins import get_platform
    from platkit.settle import load_poses

    ps = load_poses(raw)
    spec = get_platform(ps.platform)
    out.mkdir()
    yaml_text = (raw / "session.yaml").read_text().replace("length: mm", "length: m")
    (out / "session.yaml").write_text(yaml_text)
    U = controls_from_si(spec, ps.controls, "m")
    header = list(spec.control_names)
    cols = [U]
    for j, name in enumerate(ps.marker_names):
        header += [f"{name}_x", f"{name}_y", f"{name}_z", f"{name}_n"]
        cols += [ps.markers[:, j, :], ps.n_samples[:, j, None]]
    data = np.column_stack(cols)
    rows = [",".join("" if not np.isfinite(v) else repr(float(v)) for v in r) for r in data]
    (out / "poses.csv").write_text(",".join(header) + "\n" + "\n".join(rows) + "\n")
    return out


def timed(cmd: list[str], env: dict | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the child) of one process (``env``: its environment, default ours)."""
    before = os.times()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    wall = time.perf_counter() - t0
    after = os.times()
    return wall, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", default=None, help="a raw session folder (default: simulate one)")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--before", default=None, help="a folder holding an earlier platkit package, timed beside ours")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        raw = Path(args.session) if args.session else simulated_stream(tmp)
        poses = settled_folder(raw, tmp / "poses")
        n_rows = sum(1 for _ in open(raw / "markers.csv")) - 1
        n_poses = sum(1 for _ in open(poses / "poses.csv")) - 1
        cases = {
            "ours: platkit calibrate RAW": PLATKIT + ["calibrate", str(raw), "--out", str(tmp / "o_raw")],
            "platkit calibrate POSES": PLATKIT + ["calibrate", str(poses), "--out", str(tmp / "o_poses")],
            "pandas.read_csv(markers.csv)": [PYTHON, "-c", f"import pandas; pandas.read_csv({str(raw / 'markers.csv')!r})"],
        }
        envs: dict[str, dict | None] = dict.fromkeys(cases)
        if args.before:
            before = str(Path(args.before).resolve())
            if not (Path(before) / "platkit" / "__init__.py").is_file():
                raise SystemExit(f"--before {args.before}: no platkit package there")
            cases["before: platkit calibrate RAW"] = PLATKIT + ["calibrate", str(raw), "--out", str(tmp / "o_raw")]
            envs["before: platkit calibrate RAW"] = dict(os.environ, PYTHONPATH=before)
        from platkit.settle._native import compiled_fits_reason
        why = compiled_fits_reason()  # compiled (and cached) here, not in a timed process
        print(f"settling's compiled kernels: {why or 'in use'}")
        best = {k: [np.inf, np.inf] for k in cases}
        for _ in range(args.repeat):
            for name, cmd in cases.items():
                for o in ("o_raw", "o_poses"):
                    shutil.rmtree(tmp / o, ignore_errors=True)
                w, c = timed(cmd, envs[name])
                best[name] = [min(best[name][0], w), min(best[name][1], c)]
        print(f"raw stream {raw}: {n_rows} rows, {n_poses} settled poses; best of {args.repeat}")
        width = max(map(len, cases))
        print(f"{'process':<{width}}  {'wall s':>7}  {'CPU s':>7}")
        for name in cases:
            print(f"{name:<{width}}  {best[name][0]:7.2f}  {best[name][1]:7.2f}")
        ref = [best["platkit calibrate POSES"][i] + best["pandas.read_csv(markers.csv)"][i] for i in (0, 1)]
        ours = best["ours: platkit calibrate RAW"]
        print(f"{'reference (poses + pandas)':<{width}}  {ref[0]:7.2f}  {ref[1]:7.2f}")
        print(f"ratio ours / reference: wall {ours[0] / ref[0]:.2f}x, CPU {ours[1] / ref[1]:.2f}x (goal <= 1.5x)")
        if args.before:
            was = best["before: platkit calibrate RAW"]
            print(f"ratio before / reference: wall {was[0] / ref[0]:.2f}x, CPU {was[1] / ref[1]:.2f}x")


if __name__ == "__main__":
    main()
