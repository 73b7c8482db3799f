"""platkit batch: a fleet calibration serial vs on the local Dask cluster, and the engine's
per-task overhead against a bare loop.

    .venv/bin/python benchmarks/batch_scaling.py [--sessions 200] [--platform stewart] [--poses 20]
                                                 [--workers N] [--tiny 400]

1. ``--sessions`` simulated sessions (settled poses, seeds 1..N) are calibrated twice with the
   same task function platkit batch uses (platkit.commands.batch.run_verb, i.e. the calibrate
   verb's own run): in a bare loop in this process (serial), and as Dask tasks on an embedded
   LocalCluster of ``--workers`` processes (default: one per core). Wall times, their ratio
   beside the ideal (the worker count), and the cluster's start-up time. Every session's
   calibration.yaml must be the same both ways (checked).
2. Per-task overhead: ``--tiny`` tasks that each do a little numpy work (~0.1 ms), through the engine on a
   one-worker cluster vs a bare loop: (engine - loop) / tasks.

Wall times on a shared machine vary with what else runs; the load average is printed with them,
and CPU seconds (this process: the serial loop, or the scheduler and client; the workers' summed)
beside the wall times, which load does not inflate the same way.
"""
from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from platkit.batch.engine import Task, cluster, default_workers, guarded, run_tasks
from platkit.batch.store import find_sessions
from platkit.commands.batch import default_options, run_verb
from platkit.simulate import simulate_session

#: platkit calibrate's defaults, as its own parser gives them
OPTIONS = default_options("calibrate")


def untimed(obj):
    """``obj`` without its ``time_s`` entries (how long a step took differs from run to run)."""
    if isinstance(obj, dict):
        return {k: untimed(v) for k, v in obj.items() if k != "time_s"}
    if isinstance(obj, list):
        return [untimed(v) for v in obj]
    return obj


def cpu_s() -> float:
    """CPU seconds (user + system) this process has used, all its threads."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def workers_cpu_s(client) -> float:
    """CPU seconds the cluster's worker processes have used, summed."""
    return sum(client.run(cpu_s).values())


def load() -> str:
    """The load averages over 1, 5 and 15 minutes, as uptime prints them."""
    return "load average {:.2f}, {:.2f}, {:.2f}".format(*os.getloadavg())


def tiny(i: int) -> float:
    """A little numpy work (an eigen-decomposition of a 60 x 60 matrix: ~0.1 ms)."""
    a = np.random.default_rng(i).normal(size=(60, 60))
    return float(np.linalg.eigvalsh(a + a.T)[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sessions", type=int, default=200)
    ap.add_argument("--platform", default="stewart")
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--tiny", type=int, default=400)
    args = ap.parse_args()
    workers = args.workers or default_workers()
    with tempfile.TemporaryDirectory(prefix="platkit-batch-bench-") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        for i in range(args.sessions):
            simulate_session(args.platform, root / "fleet" / f"unit{i + 1:04d}", seed=i + 1, n_poses=args.poses,
                             poses_only=True)
        refs = find_sessions(str(root / "fleet" / "*"))
        print(f"{args.sessions} {args.platform} sessions of {args.poses} settled poses simulated in "
              f"{time.perf_counter() - t0:.1f} s; {load()} on {os.cpu_count()} cores")

        tasks = [Task(r.name, ("calibrate", OPTIONS, str(r.path), r.name)) for r in refs]
        t0 = time.perf_counter()
        with cluster(workers=workers) as client:
            client.wait_for_workers(workers)
            # warm-up, untimed: every worker and this process import and build what a calibration uses (so the
            # two sides also load the same code, in a tree others may be editing)
            client.run(guarded, run_verb, *tasks[0].args)  # on every worker
            t_start = time.perf_counter() - t0
            guarded(run_verb, *tasks[0].args)

            t0, c0 = time.perf_counter(), cpu_s()
            serial = {t.key: guarded(run_verb, *t.args) for t in tasks}
            t_serial, c_serial = time.perf_counter() - t0, cpu_s() - c0
            print(f"serial loop done in {t_serial:.1f} s; {load()}", flush=True)
            assert all(v["ok"] for v in serial.values()), [v["error"] for v in serial.values() if not v["ok"]][:3]

            t1, c1, w1 = time.perf_counter(), cpu_s(), workers_cpu_s(client)
            outcomes = run_tasks(client, run_verb, tasks)
            t_cluster = time.perf_counter() - t1
            c_here, c_workers = cpu_s() - c1, workers_cpu_s(client) - w1
            print(f"cluster done in {t_cluster:.1f} s; {load()}", flush=True)
        assert all(o.ok for o in outcomes), [o.error for o in outcomes if not o.ok][:3]
        differ = [o.key for o in outcomes if untimed(yaml.safe_load(o.value["files"]["calibration.yaml"]))
                  != untimed(yaml.safe_load(serial[o.key]["value"]["files"]["calibration.yaml"]))]
        same = ("every calibration.yaml the same both ways, but for times taken" if not differ else
                f"{len(differ)} calibration.yaml DIFFER between the two ways, first {differ[0]}")
        print(f"\n1. batch calibration of {args.sessions} sessions ({same})")
        print(f"   serial bare loop, one process        {t_serial:8.1f} s   {t_serial / args.sessions:.2f} s/session")
        print(f"   Dask LocalCluster, {workers} workers x 1 thread {t_cluster:8.1f} s   (+ {t_start:.1f} s start-up and warm-up)")
        print(f"   ratio serial / cluster               {t_serial / t_cluster:8.2f}     (ideal {workers}; with start-up "
              f"{t_serial / (t_cluster + t_start):.2f})")
        print(f"   CPU per session: serial {c_serial / args.sessions:.2f} s; cluster workers "
              f"{c_workers / args.sessions:.2f} s + scheduler and client {c_here / args.sessions * 1e3:.0f} ms")

    n = args.tiny
    t0, c0 = time.perf_counter(), cpu_s()
    for i in range(n):
        tiny(i)
    t_loop, c_loop = time.perf_counter() - t0, cpu_s() - c0
    with cluster(workers=1) as client:
        client.wait_for_workers(1)
        run_tasks(client, tiny, [Task(f"warm{i}", (i,)) for i in range(5)])
        t0, c0, w0 = time.perf_counter(), cpu_s(), workers_cpu_s(client)
        run_tasks(client, tiny, [Task(f"t{i}", (i,)) for i in range(n)])
        t_engine = time.perf_counter() - t0
        c_here, c_worker = cpu_s() - c0, workers_cpu_s(client) - w0
    print(f"\n2. per-task overhead, {n} tasks of ~{t_loop / n * 1e3:.1f} ms on one worker")
    print(f"   bare loop {t_loop:.2f} s, engine {t_engine:.2f} s: overhead {(t_engine - t_loop) / n * 1e3:.1f} ms per task "
          f"({(t_engine - t_loop) / n / (t_serial / args.sessions):.1%} of one calibration above)")
    print(f"   CPU per task: bare loop {c_loop / n * 1e3:.1f} ms; engine: worker {c_worker / n * 1e3:.1f} ms + scheduler and "
          f"client {c_here / n * 1e3:.1f} ms")
    print(f"   {load()}")


if __name__ == "__main__":
    main()
