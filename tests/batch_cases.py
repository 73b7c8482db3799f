"""Benchmark runs on the batch engine: a list of cases (plain dicts, one session each), one Dask
task per case, one JSON line per result appended to a file as each finishes, and a re-run that
skips the cases the file already holds. The proof benchmarks (benchmarks/diagnosis_proof*.py)
import it from tests/, where tests/unit/test_batch.py tests it without the benchmarks.

    ap = argparse.ArgumentParser(); add_engine_options(ap)          # --jobs, --scheduler, --serial
    rows = run_cases(run_case, cases, args, json_path="run.jsonl", failed_row=row_of_error, show=print_row)

A case is identified by its own fields: a result line holds them (``{**case, ...}``), so a line
whose fields equal a case's is that case done. A case whose function raised past its own
handling is recorded through ``failed_row`` (a line like the benchmark's own error lines); a case
lost with its workers (killed more often than the scheduler allows) is shown and counted but not
written, so a re-run runs it again. ``--serial`` runs the same function in a plain loop in this
process (no Dask needed): the rows must be the same either way but for the times taken.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from platkit.batch.engine import SCHEDULER_ENV, Outcome, Task, cluster, guarded, run_tasks
from platkit.errors import BadInput

__all__ = ["add_engine_options", "case_id", "read_done", "run_cases"]


def add_engine_options(ap: argparse.ArgumentParser) -> None:
    """--jobs N, --scheduler ADDRESS and --serial, as every proof benchmark takes them."""
    ap.add_argument("--jobs", type=int, default=None,
                    help="worker processes of the embedded Dask cluster, one thread each (default: one per core)")
    ap.add_argument("--scheduler", default=None, metavar="ADDRESS",
                    help="an existing Dask scheduler, e.g. tcp://host:8786 (default: $PLATKIT_DASK_SCHEDULER, else "
                         "an embedded local cluster); its workers need platkit installed")
    ap.add_argument("--serial", action="store_true",
                    help="run the cases one after the other in this process, without Dask (the same rows)")


def _plain(obj: Any, default: Callable | None) -> Any:
    """``obj`` as a JSON line would give it back (tuples as lists, numpy values as numbers)."""
    return json.loads(json.dumps(obj, sort_keys=True, default=default))


def case_id(case: dict, default: Callable | None = None) -> str:
    """The case's identity: its fields, as JSON, keys sorted."""
    return json.dumps(_plain(case, default), sort_keys=True)


def read_done(path: str | Path, fields: Sequence[str]) -> tuple[dict[str, dict], int]:
    """The lines of the JSON-lines file ``path`` (none if it does not exist) by the identity of
    the case they hold (``fields`` of the line; the last line of a case wins), and the count of
    lines that hold no case of these fields. A line that is not JSON is bad input naming it."""
    done: dict[str, dict] = {}
    other = 0
    p = Path(path)
    if not p.is_file():
        return done, other
    with p.open(encoding="utf-8") as fh:
        for number, line in enumerate(fh, 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
            except ValueError as exc:
                raise BadInput(f"{p}, line {number}: not a JSON line ({exc}); use another --json") from None
            if not isinstance(row, dict) or any(f not in row for f in fields):
                other += 1
                continue
            done[case_id({f: row[f] for f in fields})] = row
    return done, other


def run_cases(fn: Callable[[dict], dict], cases: Sequence[dict], *, jobs: int | None = None,
              scheduler: str | None = None, serial: bool = False, json_path: str | Path | None = None,
              failed_row: Callable[[dict, str, float], dict], show: Callable[[dict], None] | None = None,
              default: Callable | None = None, stream=None) -> list[dict]:
    """Run ``fn(case)`` for every case not already in ``json_path``: on an embedded LocalCluster
    of ``jobs`` workers (default one per core), on the cluster at ``scheduler`` (or
    $PLATKIT_DASK_SCHEDULER), or with ``serial`` in a loop here. Each new row is appended to
    ``json_path`` (``json.dumps(row, default=default)``, flushed) and handed to ``show`` as it
    finishes, with a progress line on ``stream`` (stderr). Returns every case's row in the order
    of ``cases``: those read back from the file, then run; a lost case's row (``failed_row``
    with 'lost: ...') is returned but not written."""
    stream = sys.stderr if stream is None else stream
    if not serial and jobs is not None:
        if jobs < 1:
            raise BadInput(f"--jobs {jobs}: use 1 or more")
        if scheduler or os.environ.get(SCHEDULER_ENV):
            raise BadInput(f"--jobs applies to the embedded cluster; the scheduler at "
                           f"{scheduler or os.environ.get(SCHEDULER_ENV)} has its own workers")
    fields = sorted({k for c in cases for k in c})
    ids = [case_id(c, default) for c in cases]
    if len(set(ids)) != len(ids):
        raise BadInput("two cases are the same; every case needs its own fields")
    before, other = read_done(json_path, fields) if json_path else ({}, 0)
    rows: dict[str, dict] = {i: before[i] for i in ids if i in before}
    todo = [(i, c) for i, c in zip(ids, cases) if i not in rows]
    note = f" ({other} lines there hold other cases, not of this run)" if other else ""
    print(f"{len(cases)} cases: {len(rows)} already in {json_path}{note}, {len(todo)} to run" if json_path else
          f"{len(cases)} cases to run", file=stream, flush=True)
    sink = open(json_path, "a", encoding="utf-8") if json_path and todo else None
    start = time.perf_counter()
    lost: list[str] = []
    count = [0]
    by_key = {f"case{k:05d}": (i, c) for k, (i, c) in enumerate(todo)}

    def keep(outcome: Outcome) -> None:
        i, case = by_key[outcome.key]
        if outcome.ok:
            row = outcome.value
        else:
            row = failed_row(case, outcome.error, outcome.seconds)
        rows[i] = row
        if outcome.kind == "lost":
            lost.append(outcome.key)
        elif sink is not None:
            sink.write(json.dumps(row, default=default) + "\n")
            sink.flush()
        count[0] += 1
        done = count[0]
        elapsed = time.perf_counter() - start
        state = "LOST with its worker (not written; a re-run runs it again)" if outcome.kind == "lost" else (
            f"{outcome.seconds:.1f} s" if outcome.ok else f"failed: {outcome.error}")
        print(f"[{done}/{len(todo)}] {state}; about {elapsed / done * (len(todo) - done):.0f} s left",
              file=stream, flush=True)
        if show is not None:
            show(row)

    try:
        if serial:
            for key, (_, case) in by_key.items():
                r = guarded(fn, case)
                keep(Outcome(key, bool(r["ok"]), value=r.get("value"), error=r.get("error", ""),
                             kind=r.get("kind", ""), seconds=float(r["seconds"]), worker=r["worker"]))
        elif todo:
            with cluster(scheduler, jobs) as client:
                run_tasks(client, fn, [Task(key, (case,)) for key, (_, case) in by_key.items()], on_outcome=keep)
    finally:
        if sink is not None:
            sink.close()
    if lost:
        print(f"{len(lost)} cases lost with their workers: not written; run the same command again to run them",
              file=stream, flush=True)
    return [rows[i] for i in ids if i in rows]


def hears_ctrl_c() -> None:
    """Run in a child process before platkit starts: SIGINT at its default disposition, as under a
    terminal. A shell that started the test run in the background leaves SIGINT ignored, and a
    program keeps an ignored SIGINT ignored (the Unix rule for background jobs), so a Ctrl-C test
    would then test nothing platkit does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
