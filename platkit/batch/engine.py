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
from pathlib import Path
from typing import Any

from platkit.errors import BadInput, PlatkitError

try:  # an optional extra: everything else in platkit works without it
    import dask
    from dask.distributed import Client, LocalCluster, as_completed
except ImportError:  # pragma: no cover - exercised in environments without the extra
    dask = Client = LocalCluster = as_completed = None

__all__ = ["SCHEDULER_ENV", "INSTALL_HINT", "Task", "Outcome", "require_dask", "have_dask", "cluster", "guarded",
           "run_tasks", "default_workers", "capped_workers", "TaskTimeout", "forget_half_imports", "terminate_as_interrupt",
           "scratch_folder"]

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


def capped_workers(workers: int | None) -> tuple[int, str]:
    """Worker processes of the embedded cluster for ``--workers`` (None: one per core), at most
    the cores this process may use (its CPU affinity, else os.cpu_count): more processes than
    cores only share them. Returns the count and, where ``workers`` was capped, one line saying so."""
    cores = default_workers()
    if workers is None:
        return cores, ""
    if workers < 1:
        raise BadInput(f"--workers {workers}: use 1 or more")
    if workers > cores:
        return cores, f"--workers {workers}: this process may use {cores} cores; running {cores} workers"
    return workers, ""


def _ignore_interrupts_in_children():
    """A context in which processes started ignore SIGINT (and keep ignoring it after exec: Python
    installs its Ctrl-C handler only where SIGINT is not ignored). The cluster's workers then
    leave a Ctrl-C at the terminal to this process, which stops them itself, with one line."""
    import signal
    import threading

    @contextlib.contextmanager
    def ctx():
        if threading.current_thread() is not threading.main_thread():
            yield
            return
        before = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, before)

    return ctx()


#: the dashboard of the embedded cluster, where one is asked for (a free port if 8787 is taken)
DASHBOARD_ADDRESS = ":8787"


@contextlib.contextmanager
def cluster(scheduler: str | None = None, workers: int | None = None, dashboard: bool = False,
            say: Callable[[str], None] | None = None) -> Iterator[Any]:
    """A dask.distributed Client: connected to ``scheduler`` (an address such as
    ``tcp://10.0.0.5:8786``; default the ``PLATKIT_DASK_SCHEDULER`` environment variable), else
    to an embedded LocalCluster of ``workers`` processes (default one per core, never more than
    the cores this process may use: :func:`capped_workers`) with one thread each, closed on exit.
    ``dashboard``: the embedded cluster serves Dask's dashboard (needs bokeh); its address is
    handed to ``say``, as is a cap on the workers. The workers ignore Ctrl-C: the caller's
    KeyboardInterrupt closes the cluster (and with it the workers) on its way out. An
    unreachable scheduler is bad input (exit 2)."""
    require_dask()
    say = say or (lambda line: print(f"batch: {line}", file=sys.stderr, flush=True))
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address:
        if workers is not None:
            raise BadInput(f"--workers applies to the embedded cluster; the scheduler at {address} has its own workers")
        if dashboard:
            raise BadInput(f"--dashboard applies to the embedded cluster; the scheduler at {address} serves its own")
        try:
            client = Client(address, timeout="10s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise BadInput(f"--scheduler {address}: cannot reach a Dask scheduler there ({exc})") from None
        try:
            yield client
        finally:
            client.close()
        return
    n, capped = capped_workers(workers)
    if capped:
        say(capped)
    if dashboard:
        try:
            import bokeh  # noqa: F401 - Dask's dashboard is drawn with it
        except ImportError:
            raise BadInput('--dashboard needs bokeh, which is not installed: pip install "bokeh>=3.1"') from None
    # one thread per worker: the calibrations are numpy/CasADi-bound, so processes, not threads, scale.
    # Tasks last seconds: Dask's sampling profiler (every 10 ms) and GIL monitor (every 1 ms) would
    # only take CPU from them (measured in benchmarks/batch_scaling.py)
    with dask.config.set(QUIET_CONFIG):
        with warnings_module.catch_warnings(), _ignore_interrupts_in_children():
            # with no dashboard the scheduler still serves health checks over HTTP, on another port when 8787 is
            # taken (another cluster on this machine): not worth a warning
            warnings_module.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
            local = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                 dashboard_address=DASHBOARD_ADDRESS if dashboard else None,
                                 silence_logs=logging.CRITICAL)
        quiet = logging.getLogger("distributed")
        level = quiet.level
        try:
            with local, Client(local) as client:
                if dashboard:
                    say(f"dashboard at {client.dashboard_link}")
                try:
                    yield client
                except BaseException:
                    # torn down under an interrupt or an error: the scheduler's report of comms closing
                    # under it is expected, and the caller says what happened in one line
                    quiet.setLevel(logging.CRITICAL + 1)
                    raise
        finally:
            quiet.setLevel(level)


class TaskTimeout(Exception):
    """Raised inside a task that ran past its time limit (see :func:`guarded`)."""


def _raise_in(thread_id: int, exc_type: type) -> None:
    import ctypes

    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread_id), ctypes.py_object(exc_type))


def guarded(fn: Callable, *args, timeout: float | None = None) -> dict:
    """Run ``fn(*args)`` on a worker; return a plain dict (ok, value | error, kind, seconds,
    worker, warnings). A platkit error keeps its one-line message; anything else is named with
    its class and the last frame, so a person finds it without the worker's log. ``timeout``
    (s): past it the task is stopped (a :class:`TaskTimeout` raised in its thread, which takes
    effect at its next Python instruction: a single long call into compiled code ends first) and
    is a failed outcome of kind 'timed out'; the worker goes on with the next task, the
    submodules of an import the stop cut short forgotten (:func:`forget_half_imports`)."""
    import threading

    start = time.perf_counter()
    where = f"{socket.gethostname()}:{os.getpid()}"
    timer = None
    if timeout is not None:
        timer = threading.Timer(timeout, _raise_in, (threading.get_ident(), TaskTimeout))
        timer.daemon = True
        timer.start()
    with warnings_module.catch_warnings(record=True) as caught:
        warnings_module.simplefilter("always")
        try:
            try:
                value = fn(*args)
            finally:
                if timer is not None:
                    timer.cancel()
        except TaskTimeout:
            forget_half_imports()
            return {"ok": False, "error": f"timed out: stopped after {timeout:g} s (--task-timeout)",
                    "kind": "timed out", "seconds": time.perf_counter() - start, "worker": where,
                    "warnings": _lines(caught)}
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


def forget_half_imports() -> None:
    """Drop from ``sys.modules`` every module one of whose packages is not imported. A stop that
    falls inside an import removes the package being imported but not the submodules it had
    imported: they would keep the half-built package in their globals, and the next task on the
    worker, importing the package again over them, would fail on it."""
    names = set(sys.modules)
    for name in [n for n in names if "." in n]:
        parts = name.split(".")
        if any(".".join(parts[:k]) not in names for k in range(1, len(parts))):
            sys.modules.pop(name, None)


def _lines(caught) -> list[str]:
    return sorted({f"{w.category.__name__}: {w.message}" for w in caught})


def run_tasks(client, fn: Callable, tasks: Sequence[Task], on_outcome: Callable[[Outcome], None] | None = None,
              progress: Callable[[Outcome, int, int], None] | None = None, retries: int = 0,
              timeout: float | None = None) -> list[Outcome]:
    """Run ``fn(*task.args)`` for every task on ``client``'s cluster; return the outcomes in the
    order they finished. ``on_outcome(outcome)`` runs here, in this process, as each finishes
    (write its results there); ``progress(outcome, done, total)`` after it. Each task's outcome
    is handed over exactly once. A task whose workers died more often than the scheduler allows
    (``distributed.scheduler.allowed-failures``) is a 'lost' outcome; ``retries`` re-runs a task
    whose function raised something outside :func:`guarded` (none, by default); ``timeout`` (s) stops
    a task that runs longer (:func:`guarded`). Interrupted (Ctrl-C, or SIGTERM turned into one by
    the caller), the tasks not finished are cancelled before the interrupt goes on."""
    require_dask()
    keys = [t.key for t in tasks]
    if len(set(keys)) != len(keys):
        dup = sorted({k for k in keys if keys.count(k) > 1})[0]
        raise BadInput(f"two tasks share the name {dup!r}; every session or draw needs its own")
    run_id = f"{os.getpid()}-{time.time_ns()}"
    futures = {}
    for t in tasks:
        fut = client.submit(guarded, fn, *t.args, timeout=timeout, key=f"platkit-{t.key}-{run_id}", pure=False,
                            retries=retries)
        futures[fut.key] = (t, fut)
    outcomes: list[Outcome] = []
    seen: set[str] = set()
    try:
        _collect(futures, seen, outcomes, on_outcome, progress, len(tasks))
    except BaseException:
        with contextlib.suppress(Exception):
            client.cancel([f for _, f in futures.values()], force=True)
        raise
    return outcomes


def _collect(futures, seen, outcomes, on_outcome, progress, total) -> None:
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
            progress(outcome, len(outcomes), total)


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


@contextlib.contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """Within it, SIGTERM is handled as Ctrl-C (a KeyboardInterrupt in the main thread), so that
    a batch stopped either way closes its cluster, stops its workers, removes its temporary
    folders and leaves no partial output (outputs are written whole or not at all). Outside the
    main thread it does nothing."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    before = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


#: the prefix of a batch's scratch folder in the temporary directory (its process id follows)
SCRATCH_PREFIX = "platkit-batch-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process: alive
        return True
    return True


@contextlib.contextmanager
def scratch_folder() -> Iterator[str]:
    """A folder for the tasks' private outputs (``<tmp>/platkit-batch-<pid>-XXXX``), removed on
    the way out whatever happens (an error, Ctrl-C, SIGTERM under :func:`terminate_as_interrupt`).
    A batch killed outright (SIGKILL) cannot remove its own: the next batch on this machine removes
    every such folder whose process is gone."""
    import shutil
    import tempfile

    root = Path(tempfile.gettempdir())
    for old in root.glob(f"{SCRATCH_PREFIX}*"):
        pid = old.name[len(SCRATCH_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not _alive(int(pid)) and old.is_dir():
            shutil.rmtree(old, ignore_errors=True)
    path = tempfile.mkdtemp(prefix=f"{SCRATCH_PREFIX}{os.getpid()}-")
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
