"""Reading a large motion-capture stream (markers.csv) beside pandas.read_csv of the same file.

    .venv/bin/python benchmarks/read_stream.py [--rows 2000000] [--keep DIR]

The file is made here (not kept in the repository): the stewart example session's markers.csv
(5 markers, 16 columns, mm with 3 decimals) repeated with increasing times to ``--rows`` rows,
about 100 MB per million rows. Every reader runs in a fresh process, one at a time; the table gives
its wall time, its peak memory above what the process held before the read (ru_maxrss), and the
ratios: speed relative to pandas.read_csv (goal: at least 0.5) and peak memory relative to the
numeric array (rows x columns x 8 bytes; goal: under 2).

Rows: pandas.read_csv (the reference); platkit.io.table.read_table; load_session of the
folder (the reader plus every check of the stream: times, units, occlusions); the time to the
first progress line on stderr; and a file with one bad cell near its end, for the time to the
one-line error that names its row and column.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
EXAMPLE = HERE.parent / "examples" / "sessions" / "stewart"


def rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def child(what: str, path: str) -> None:
    """Run one reader in this process and print {seconds, peak_bytes, shape} as JSON."""
    import numpy as np
    import pandas

    from platkit.errors import BadSession
    from platkit.io.session import load_session
    from platkit.io.table import read_table

    before = rss_bytes()
    t0 = time.perf_counter()
    shape, message = None, None
    try:
        if what == "pandas":
            shape = pandas.read_csv(path).to_numpy().shape
        elif what == "read_table":
            shape = read_table(Path(path), quiet=True).data.shape
        elif what == "load_session":
            s = load_session(Path(path), quiet=True)
            shape = s.markers.shape
            assert np.isfinite(s.marker_t).all()
        elif what == "load_session_progress":
            print("start", file=sys.stderr, flush=True)
            load_session(Path(path))
    except BadSession as exc:
        message = str(exc)
    seconds = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 - before
    print(json.dumps({"seconds": seconds, "peak_bytes": peak, "shape": shape, "message": message}))


def run_child(what: str, path: Path) -> dict:
    done = subprocess.run([sys.executable, __file__, "--child", what, str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"{what} failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def first_progress_s(folder: Path) -> tuple[float, float, str]:
    """Seconds from the start of the process, and from the call of load_session, to the first
    progress line on stderr; and the line."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, __file__, "--child", "load_session_progress", str(folder)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    proc.stderr.readline()  # "start": load_session is called
    t1 = time.perf_counter()
    line = proc.stderr.readline()
    t2 = time.perf_counter()
    proc.communicate()
    return t2 - t0, t2 - t1, line.strip()


def make_session(folder: Path, rows: int) -> Path:
    """A stewart session whose markers.csv has ``rows`` rows (the example's rows, repeated)."""
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(EXAMPLE / "session.yaml", folder / "session.yaml")
    shutil.copy(EXAMPLE / "commands.csv", folder / "commands.csv")
    lines = (EXAMPLE / "markers.csv").read_text().splitlines()
    header, body = lines[0], [line.split(",", 1)[1] for line in lines[1:] if line.strip()]
    rate = 40.0
    with open(folder / "markers.csv", "w") as fh:
        fh.write(header + "\n")
        step = 100_000
        for start in range(0, rows, step):
            fh.write("".join(f"{i / rate:.6f},{body[i % len(body)]}\n" for i in range(start, min(rows, start + step))))
    return folder


def with_bad_cell(src: Path, dst: Path, row: int) -> tuple[Path, int]:
    """A copy of session ``src`` whose markers.csv has 'x' for M3_y at data row ``row`` (0-based)."""
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(src, dst)
    path = dst / "markers.csv"
    with open(src / "markers.csv", "rb") as fh, open(path, "wb") as out:
        for i, line in enumerate(fh):
            if i == row + 1:
                cells = line.split(b",")
                cells[8] = b"x"
                line = b",".join(cells)
            out.write(line)
    return dst, row


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=2_000_000)
    ap.add_argument("--repeat", type=int, default=3, help="runs of each reader (the best is shown)")
    ap.add_argument("--keep", default=None, help="make the session here and keep it (default: a temporary folder)")
    ap.add_argument("--child", nargs=2, metavar=("WHAT", "PATH"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(*args.child)
        return
    tmp = None if args.keep else tempfile.TemporaryDirectory()
    root = Path(args.keep or tmp.name)
    try:
        folder = root / "big"
        t0 = time.perf_counter()
        if not (folder / "markers.csv").is_file():
            make_session(folder, args.rows)
        path = folder / "markers.csv"
        size = path.stat().st_size
        with open(path, "rb") as fh:
            cols = fh.readline().count(b",") + 1
        n = args.rows
        array = n * cols * 8
        print(f"markers.csv: {n:,} rows x {cols} columns, {size / 1e6:.0f} MB (made in {time.perf_counter() - t0:.1f} s); "
              f"numeric array {array / 1e6:.0f} MB")
        names = {"pandas": "pandas.read_csv (reference)", "read_table": "platkit read_table",
                 "load_session": "platkit load_session (read + checks)"}
        runs = {k: [] for k in names}
        for _ in range(args.repeat):  # in turns, so that a busy machine slows each alike
            runs["pandas"].append(run_child("pandas", path))
            runs["read_table"].append(run_child("read_table", path))
            runs["load_session"].append(run_child("load_session", folder))
        best = {k: min(v, key=lambda r: r["seconds"]) for k, v in runs.items()}
        ref = best["pandas"]
        width = max(len(n) for n in names.values())
        print(f"best of {args.repeat} runs each")
        print(f"{'reader':<{width}}  {'s':>6}  {'speed vs pandas':>15}  {'peak MB':>8}  {'peak / array':>12}")
        for key, name in names.items():
            r = best[key]
            peak = max(x["peak_bytes"] for x in runs[key])
            print(f"{name:<{width}}  {r['seconds']:>6.2f}  {ref['seconds'] / r['seconds']:>15.2f}  {peak / 1e6:>8.0f}  "
                  f"{peak / array:>12.2f}")
        ok_speed = ref["seconds"] / best["load_session"]["seconds"] >= 0.5
        ok_mem = max(x["peak_bytes"] for x in runs["load_session"]) < 2 * array
        print(f"goals for load_session: speed >= 0.5 x pandas: {'met' if ok_speed else 'NOT MET'}; "
              f"peak < 2 x array: {'met' if ok_mem else 'NOT MET'}")
        t_process, t_read, line = first_progress_s(folder)
        print(f"first progress line on stderr {t_read:.2f} s after load_session was called "
              f"({t_process:.2f} s after the process started): {line!r}")
        bad, row = with_bad_cell(folder, root / "bad", n - 1000)
        r = run_child("load_session", bad)
        print(f"bad cell at row {row + 1:,}: error after {r['seconds']:.2f} s: {r['message']}")
    finally:
        if tmp is not None:
            tmp.cleanup()


if __name__ == "__main__":
    main()
