"""The batch engine: whole tasks (one session, one Monte-Carlo draw) on a dask.distributed cluster.

    with cluster(workers=2) as client:                  # an embedded LocalCluster, or
    with cluster(scheduler="tcp://host:8786") as client: # an existing one (or PLATKIT_DASK_SCHEDULER)
        outcomes = run_tasks(client, fn, tasks, on_outcome=write_it, progress=show)

Each task is ``fn(*task.args)`` run on a worker inside :func:`guarded`, which turns any error
into a failed :class:`Outcome` with one line saying why, so a failed task never stops the
others. :func:`run_tasks` hands every outcome to ``on_outcome`` in this process as it finishes
(that is where results are written, atomically), once per task: a worker that dies in the
middle has its tasks run again elsewhere by the scheduler, and a result that arrives twice is
taken once. Dask is an optional extra (``pip install "platkit[batch]"``): importing this
module works without it, and :func:`require_dask` says how to install it.
"""
from __future__ import annotations

import contextlib
import logging
import os
import socket
import sys
import time
import traceback
import warnings as warnings_module
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from platkit.errors import BadInput, PlatkitError

try:  # an optional extra: everything else in platkit works without it
    import dask
    from dask.distributed import Client, LocalCluster, as_completed
except ImportError:  # pragma: no cover - exercised in environments without the extra
    dask = Client = LocalCluster = as_completed = None

__all__ = ["SCHEDULER_ENV", "INSTALL_HINT", "Task", "Outcome", "require_dask", "have_dask", "cluster", "guarded",
           "run_tasks", "default_workers"]

#: environment variable naming an existing Dask scheduler (same as --scheduler ADDRESS)
SCHEDULER_ENV = "PLATKIT_DASK_SCHEDULER"
#: Dask settings of the embedded cluster: no sampling profiler, no GIL monitor
QUIET_CONFIG = {"distributed.worker.profile.enabled": False, "distributed.admin.system-monitor.gil.enabled": False}
INSTALL_HINT = 'pip install "platkit[batch]" (or: pip install "dask[distributed]>=2024.1")'


@dataclass(frozen=True)
class Task:
    """One whole unit of work: ``key`` names it (unique in a run: a session's name, ``draw-0042``);
    ``args`` are the task function's arguments (picklable: paths, names, numbers, arrays)."""

    key: str
    args: tuple = ()


@dataclass
class Outcome:
    """What became of a task. ``value`` is the function's return value when ``ok``; else
    ``error`` is one line (``kind`` is 'bad input', 'failed' or 'lost' for a task whose workers
    kept dying). ``seconds`` is the time the function ran; ``worker`` where (host:pid)."""

    key: str
    ok: bool
    value: Any = None
    error: str = ""
    kind: str = ""
    seconds: float = 0.0
    worker: str = ""
    warnings: list[str] = field(default_factory=list)


def have_dask() -> bool:
    """True when dask.distributed can be imported."""
    return Client is not None


def require_dask(what: str = "platkit batch") -> None:
    """Raise :class:`BadInput` (exit 2) in one line saying how to install the extra."""
    if Client is None:
        raise BadInput(f"{what} needs dask.distributed, which is not installed: {INSTALL_HINT}")


def default_workers() -> int:
    """Worker processes of the embedded cluster: one per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def cluster(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A dask.distributed Client: connected to ``scheduler`` (an address such as
    ``tcp://10.0.0.5:8786``; default the ``PLATKIT_DASK_SCHEDULER`` environment variable), else
    to an embedded LocalCluster of ``workers`` processes (default one per core) with one thread
    each, closed on exit. An unreachable scheduler is bad input (exit 2)."""
    require_dask()
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address:
        if workers is not None:
            raise BadInput(f"--workers applies to the embedded cluster; the scheduler at {address} has its own workers")
        try:
            client = Client(address, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise BadInput(f"--scheduler {address}: cannot reach a Dask scheduler there ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    n = default_workers() if workers is None else workers
    if n < 1:
        raise BadInput(f"--workers {n}: use 1 or more")
    # one thread per worker: the calibrations are numpy/CasADi-bound, so processes, not threads, scale.
    # Tasks last seconds: Dask's sampling profiler (every 10 ms) and GIL monitor (every 1 ms) would
    # only take CPU from them (measured in benchmarks/batch_scaling.py)
    with dask.config.set(QUIET_CONFIG):
        with warnings_module.catch_warnings():
            # with no dashboard the scheduler still serves health checks over HTTP, on another port when 8787 is
            # taken (another cluster on this machine): not worth a warning
            warnings_module.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
            local = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                 silence_logs=logging.ERROR)
        with local, Client(local) as client:
            yield client


def guarded(fn: Callable, *args) -> dict:
    """Run ``fn(*args)`` on a worker; return a plain dict (ok, value | error, kind, seconds,
    worker, warnings). A platkit error keeps its one-line message; anything else is named with
    its class and the last frame, so a person finds it without the worker's log."""
    start = time.perf_counter()
    where = f"{socket.gethostname()}:{os.getpid()}"
    with warnings_module.catch_warnings(record=True) as caught:
        warnings_module.simplefilter("always")
        try:
            value = fn(*args)
        except PlatkitError as exc:
            return {"ok": False, "error": str(exc), "kind": "bad input" if exc.exit_code == 2 else "failed",
                    "seconds": time.perf_counter() - start, "worker": where, "warnings": _lines(caught)}
        except Exception as exc:  # one failed task must not stop the others: said in one line
            frame = traceback.extract_tb(exc.__traceback__)[-1]
            return {"ok": False, "error": f"{exc.__class__.__name__}: {exc} (at {os.path.basename(frame.filename)}:"
                                          f"{frame.lineno})", "kind": "failed",
                    "seconds": time.perf_counter() - start, "worker": where, "warnings": _lines(caught)}
    return {"ok": True, "value": value, "seconds": time.perf_counter() - start, "worker": where,
            "warnings": _lines(caught)}


def _lines(caught) -> list[str]:
    return sorted({f"{w.category.__name__}: {w.message}" for w in caught})


def run_tasks(client, fn: Callable, tasks: Sequence[Task], on_outcome: Callable[[Outcome], None] | None = None,
              progress: Callable[[Outcome, int, int], None] | None = None, retries: int = 0) -> list[Outcome]:
    """Run ``fn(*task.args)`` for every task on ``client``'s cluster; return the outcomes in the
    order they finished. ``on_outcome(outcome)`` runs here, in this process, as each finishes
    (write its results there); ``progress(outcome, done, total)`` after it. Each task's outcome
    is handed over exactly once. A task whose workers died more often than the scheduler allows
    (``distributed.scheduler.allowed-failures``) is a 'lost' outcome; ``retries`` re-runs a task
    whose function raised something outside :func:`guarded` (none, by default)."""
    require_dask()
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})[0]
        raise BadInput(f"two tasks share the name {dup!r}; every session or draw needs its own")
    run_id = f"{os.getpid()}-{time.time_ns()}"
    futures = {}
    for t in tasks:
        fut = client.submit(guarded, fn, *t.args, key=f"platkit-{t.key}-{run_id}", pure=False, retries=retries)
        futures[fut.key] = (t, fut)
    outcomes: list[Outcome] = []
    seen: set[str] = set()
    for fut in as_completed([f for _, f in futures.values()]):
        task, _ = futures[fut.key]
        if task.key in seen:  # a result is taken once, whatever the scheduler did to get it
            continue
        seen.add(task.key)
        try:
            r = fut.result()
        except Exception as exc:  # KilledWorker and the like: the task itself never finished
            outcome = Outcome(task.key, False, error=f"lost: {exc.__class__.__name__}: {exc}", kind="lost")
        else:
            outcome = Outcome(task.key, bool(r["ok"]), value=r.get("value"), error=r.get("error", ""),
                              kind=r.get("kind", ""), seconds=float(r["seconds"]), worker=r["worker"],
                              warnings=list(r.get("warnings", [])))
        fut.release()
        if on_outcome is not None:
            on_outcome(outcome)
        outcomes.append(outcome)
        if progress is not None:
            progress(outcome, len(outcomes), len(tasks))
    return outcomes


def progress_line(prefix: str, stream=None, start: float | None = None) -> Callable[[Outcome, int, int], None]:
    """A ``progress`` callback printing one line per finished task: count, failures so far,
    the task's time and an estimate of the time left (from the rate so far)."""
    t0 = time.perf_counter() if start is None else start
    failed = [0]

    def show(outcome: Outcome, done: int, total: int) -> None:
        failed[0] += 0 if outcome.ok else 1
        elapsed = time.perf_counter() - t0
        left = elapsed / done * (total - done)
        state = f"{outcome.seconds:.2f} s" if outcome.ok else f"FAILED: {outcome.error}"
        print(f"{prefix}: {done}/{total} done ({failed[0]} failed), {outcome.key} {state}; about {left:.0f} s left",
              file=stream if stream is not None else sys.stderr, flush=True)

    return show
