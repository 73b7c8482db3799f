"""platkit batch: a fleet calibration serial vs on the local Dask cluster with 1, 2, ... workers,
and the engine's per-task overhead against a bare loop.

    .venv/bin/python benchmarks/batch_scaling.py [--sessions 200] [--platform stewart] [--poses 20]
                                                 [--workers 1,2] [--tiny 400]

1. ``--sessions`` simulated sessions (settled poses, seeds 1..N) are calibrated with the same task
   function platkit batch uses (platkit.commands.batch.run_verb, i.e. the calibrate verb's own
   run, in one parameterisation as ``platkit batch calibrate --no-selection`` runs it: the stand's
   default free parameters less the batch's gauge): in a bare loop in this
   process (serial), then as Dask tasks on an embedded LocalCluster of each ``--workers`` count
   (default 1 and 2; counts above the cores this process may use are capped, and said). Wall
   times, their ratio to the serial loop beside the ideal (the worker count), and each cluster's
   start-up time. Every session's calibration.yaml must be the same every way (checked).
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

from platkit.batch.engine import Task, capped_workers, cluster, guarded, run_tasks
from platkit.batch.gauge import common_parameterisation
from platkit.batch.store import find_sessions
from platkit.commands.batch import default_options, run_verb
from platkit.plugins import get_platform
from platkit.simulate import simulate_session


def options_for(platform: str) -> dict:
    """platkit calibrate's options as platkit batch calibrate --no-selection runs them: its parser's
    defaults, with the stand's default free parameters less the batch's gauge (one parameterisation)."""
    free = common_parameterisation(get_platform(platform)).free
    return default_options("calibrate", "--free", ",".join(free), "--no-report")


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
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated (default 1,2)")
    ap.add_argument("--tiny", type=int, default=400)
    args = ap.parse_args()
    counts = []
    for w in (int(x) for x in args.workers.split(",")):
        n, said = capped_workers(w)
        if said:
            print(said)
        if n not in counts:
            counts.append(n)
    with tempfile.TemporaryDirectory(prefix="platkit-batch-bench-") as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        for i in range(args.sessions):
            simulate_session(args.platform, root / "fleet" / f"unit{i + 1:04d}", seed=i + 1, n_poses=args.poses,
                             poses_only=True)
        refs = find_sessions(str(root / "fleet" / "*"))
        print(f"{args.sessions} {args.platform} sessions of {args.poses} settled poses simulated in "
              f"{time.perf_counter() - t0:.1f} s; {load()} on {os.cpu_count()} cores "
              f"({len(os.sched_getaffinity(0))} for this process)", flush=True)

        options = options_for(args.platform)
        tasks = [Task(r.name, ("calibrate", options, str(r.path), r.name)) for r in refs]
        guarded(run_verb, *tasks[0].args)  # warm-up, untimed
        t0, c0 = time.perf_counter(), cpu_s()
        serial = {t.key: guarded(run_verb, *t.args) for t in tasks}
        t_serial, c_serial = time.perf_counter() - t0, cpu_s() - c0
        print(f"serial loop done in {t_serial:.1f} s; {load()}", flush=True)
        assert all(v["ok"] for v in serial.values()), [v["error"] for v in serial.values() if not v["ok"]][:3]
        runs = []
        for workers in counts:
            t0 = time.perf_counter()
            with cluster(workers=workers) as client:
                client.wait_for_workers(workers)
                # warm-up, untimed: every worker imports and builds what a calibration uses
                client.run(guarded, run_verb, *tasks[0].args)
                t_start = time.perf_counter() - t0
                t1, c1, w1 = time.perf_counter(), cpu_s(), workers_cpu_s(client)
                outcomes = run_tasks(client, run_verb, tasks)
                t_cluster = time.perf_counter() - t1
                c_here, c_workers = cpu_s() - c1, workers_cpu_s(client) - w1
            print(f"{workers} worker(s) done in {t_cluster:.1f} s; {load()}", flush=True)
            assert all(o.ok for o in outcomes), [o.error for o in outcomes if not o.ok][:3]
            differ = [o.key for o in outcomes if untimed(yaml.safe_load(o.value["files"]["calibration.yaml"]))
                      != untimed(yaml.safe_load(serial[o.key]["value"]["files"]["calibration.yaml"]))]
            runs.append((workers, t_cluster, t_start, c_here, c_workers, differ))
        print(f"\n1. batch calibration of {args.sessions} sessions (the stand's default free parameters less the gauge)")
        print(f"   serial bare loop, one process        {t_serial:8.1f} s   {t_serial / args.sessions:.2f} s/session, "
              f"CPU {c_serial / args.sessions:.2f} s/session")
        for workers, t_cluster, t_start, c_here, c_workers, differ in runs:
            same = "calibration.yaml all the same as serial" if not differ else f"{len(differ)} calibration.yaml DIFFER"
            print(f"   Dask LocalCluster, {workers} worker(s) x 1 thread {t_cluster:6.1f} s   serial / cluster "
                  f"{t_serial / t_cluster:.2f} (ideal {workers}; {t_serial / (t_cluster + t_start):.2f} with the "
                  f"{t_start:.1f} s start-up); CPU per session: workers {c_workers / args.sessions:.2f} s + scheduler and "
                  f"client {c_here / args.sessions * 1e3:.0f} ms; {same}")
        t_serial_per = t_serial / args.sessions

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
          f"({(t_engine - t_loop) / n / t_serial_per:.1%} of one calibration above)")
    print(f"   CPU per task: bare loop {c_loop / n * 1e3:.1f} ms; engine: worker {c_worker / n * 1e3:.1f} ms + scheduler and "
          f"client {c_here / n * 1e3:.1f} ms")
    print(f"   {load()}")


if __name__ == "__main__":
    main()
