"""platkit batch: calibrate, diagnose or orient every session a pattern matches, on a Dask cluster.

    platkit batch calibrate 'fleet/*' --out fleet_cal --folds 5
    platkit batch diagnose 'fleet/*' --calibration 'fleet_cal/sessions/{name}/calibration.yaml' --out fleet_diag
    platkit batch calibrate 'stand7/month*' --out stand7_history --history

Each session is one task: the single verb's own ``run`` with the options given here, into its
own folder under OUT/sessions/, written whole as it finishes. A failed session is reported and the
others go on. A re-run skips a session done with the same inputs (its files, the files its options
name) and options, redoes one whose fingerprint changed, and --redo redoes all. The cluster is an
embedded local one (one worker per core) unless --scheduler or PLATKIT_DASK_SCHEDULER names one;
the sessions' paths must be readable by its workers.

batch calibrate (--method lsq) calibrates every session in one parameterisation, so that their
parameters compare (platkit.batch.gauge): the free parameters are those of --free, of
--reference CALIBRATION (its estimated ones), of the stand's default (--no-selection), or by
default the union of the groups held-out selection chooses in each session (a first round of
tasks); the gauge among them is held at nominal in every session. OUT/parameterisation.json says
which and why.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import os
import sys
import tempfile
import time
from pathlib import Path

from platkit.errors import BadInput
from platkit.notices import collecting

#: verbs a batch runs, each through its module platkit.commands.<verb>
VERBS = ("calibrate", "diagnose", "orient")
#: options of the batch itself (the rest are the verb's and go to every session)
BATCH_KEYS = ("command", "batch_verb", "_run", "debug", "scheduler", "workers", "history", "session", "out", "quiet",
              "redo", "dashboard", "task_timeout", "reference", "maintenance")
#: options naming files: made absolute (workers may run elsewhere), and may hold {name}, {folder}, {session}
PATH_KEYS = ("calibration", "imu_calibration", "description", "heldout", "validate")


def add_parser(sub):
    p = sub.add_parser("batch", help="calibrate, diagnose or orient every session a pattern matches, on a local or "
                                     "remote Dask cluster (fleet summary, history of a stand)",
                       description="\n\n".join(__doc__.split("\n\n")[1:3]), formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = p.add_subparsers(dest="batch_verb", metavar="VERB")
    verbs.required = True
    for verb in VERBS:
        module = importlib.import_module(f"platkit.commands.{verb}")
        vp = module.add_parser(verbs)
        vp.description = (f"platkit {verb} on every session SESSION matches (a shell pattern such as 'fleet/*', "
                          f"quoted; ** descends), into OUT/sessions/<name>/ with a fleet summary in OUT. A path option "
                          "may name the session: {name} (its name in the batch), {folder} (its folder's name), "
                          "{session} (its path).")
        vp.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="an existing Dask scheduler, e.g. tcp://host:8786 (default: $PLATKIT_DASK_SCHEDULER, "
                             "else an embedded local cluster)")
        vp.add_argument("--workers", type=int, default=None,
                        help="worker processes of the embedded cluster (default: one per core; at most the cores "
                             "this process may use, said when capped)")
        vp.add_argument("--dashboard", action="store_true",
                        help="serve the embedded cluster's Dask dashboard (its address is printed; needs bokeh)")
        vp.add_argument("--task-timeout", type=float, default=None, metavar="SECONDS",
                        help="stop a session that runs longer than this (a failed session, 'timed out'; default none)")
        vp.add_argument("--redo", action="store_true",
                        help="redo every session, even those done before with the same inputs and options")
        with contextlib.suppress(argparse.ArgumentError):  # calibrate and diagnose have their own
            vp.add_argument("--quiet", action="store_true", help="no progress on stderr")
        if verb == "calibrate":
            vp.add_argument("--history", action="store_true",
                            help="the sessions are one stand over time (dates from session.yaml, else the folder "
                                 "order): each parameter's trend, and changes larger than the uncertainties explain "
                                 "(history.csv, history.json, history.html)")
            vp.add_argument("--reference", default=None, metavar="CALIBRATION",
                            help="a calibration.yaml whose estimated parameters every session estimates (one "
                                 "parameterisation for the batch; default: the groups selection chooses over the "
                                 "sessions)")
            vp.add_argument("--maintenance", default=None, metavar="FILE",
                            help="--history: maintenance events, a YAML list of {date, note} (default: "
                                 "maintenance.yaml in the sessions' common folder, where there is one)")
    return p


def verb_options(args) -> dict:
    """The verb's own options from the parsed batch arguments (a plain mapping, as batch.json
    records it): path options made absolute unless they hold a {placeholder}."""
    options = {k: v for k, v in vars(args).items() if k not in BATCH_KEYS}
    for key in PATH_KEYS:
        v = options.get(key)
        if isinstance(v, str) and "{" not in v:
            options[key] = str(Path(v).resolve())
    return options


def default_options(verb: str, *argv: str) -> dict:
    """The verb's options as its parser gives them for ``argv`` (default: none given), in the
    form run_verb takes: what a library caller (a benchmark, a test) passes for one session."""
    parser = argparse.ArgumentParser(prog="platkit")
    sub = parser.add_subparsers(dest="command")
    add_parser(sub)
    extra = ["--out", "unused", "--calibration", "unused"] if verb == "diagnose" else ["--out", "unused"]
    return verb_options(parser.parse_args(["batch", verb, "unused", *extra, *argv]))


def session_options(options: dict, session: str, name: str) -> dict:
    """``options`` with {name}, {folder} and {session} filled in for one session (then made absolute)."""
    out = dict(options)
    for key in PATH_KEYS:
        v = out.get(key)
        if isinstance(v, str) and "{" in v:
            try:
                filled = v.format(name=name, folder=Path(session).name, session=session)
            except (KeyError, IndexError, ValueError) as exc:
                raise BadInput(f"--{key.replace('_', '-')} {v}: use only {{name}}, {{folder}} or {{session}} ({exc})") from None
            out[key] = str(Path(filled).resolve())
    return out


def run_verb(verb: str, options: dict, session: str, name: str, scratch: str | None = None) -> dict:
    """One session through ``platkit.commands.<verb>.run`` (on a worker): the options as the
    verb's parser gave them, the session, a private --out in ``scratch`` (the batch's scratch
    folder where the worker sees it, else the worker's temporary directory). Returns the files
    written ({relative path: bytes}), the line the verb printed, and its warnings (stderr lines)."""
    module = importlib.import_module(f"platkit.commands.{verb}")
    ns = argparse.Namespace(**session_options(options, session, name))
    ns.session = session
    ns.quiet = True
    where = scratch if scratch and os.path.isdir(scratch) else None
    with tempfile.TemporaryDirectory(prefix="platkit-batch-task-", dir=where) as tmp:
        ns.out = str(Path(tmp) / "out")
        said, warned = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(warned), collecting():
            code = module.run(ns)
        if code:
            raise BadInput(f"platkit {verb} exited {code}: {warned.getvalue().strip() or said.getvalue().strip()}")
        root = Path(ns.out)
        files = {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
    return {"files": files, "line": said.getvalue().strip(), "out": ns.out,
            "warnings": [line for line in warned.getvalue().splitlines() if line.strip()]}


def select_groups(options: dict, session: str, name: str) -> dict:
    """The groups held-out selection chooses for one session (on a worker), as ``platkit
    calibrate`` would choose them: {"chosen": [group, ...]}. A session calibrate fits from motion
    (its holds never settle, any was extrapolated to rest, or it has none) chooses none, as
    calibrate's motion path does not: {"chosen": None, "motion": why}. Run for ``--method lsq``
    only (the paper's method has no selection and no motion path)."""
    from platkit.calibrate.selection import select_model
    from platkit.commands.calibrate import load_for_calibration
    from platkit.model import length_scale
    from platkit.settle import HoldsNeverSettle, NeverSettles

    opts = session_options(options, session, name)
    try:
        with contextlib.redirect_stderr(io.StringIO()):
            poses, spec, popts = load_for_calibration(session, opts.get("platform"), opts.get("description"),
                                                      quiet=True, stream_if_extrapolated=True)
    except (HoldsNeverSettle, NeverSettles) as exc:
        return {"chosen": None, "motion": exc.settling.get("reason") or str(exc)}
    ridge = 0.0 if opts.get("prior_strength") is None else opts["prior_strength"] * length_scale(poses.length_unit)
    cal = select_model(poses, spec, robust=not opts.get("no_robust"), platform_options=popts, ridge_m=ridge)
    return {"chosen": list(cal.identifiability["model_selection"]["chosen"])}


def _option_files(options: dict, session: str, name: str) -> dict[str, str]:
    filled = session_options(options, session, name)
    return {k: filled[k] for k in PATH_KEYS if isinstance(filled.get(k), str)}


def _stand_identity(ref, platform: str | None, description: str | None, by_description: bool = True) -> tuple[str, str]:
    """(stand name, description) a session is calibrated with: the command line's, else its
    session.yaml's (the description by its contents, so copies of one file agree). Read leniently:
    a session.yaml the verb will refuse fails as that session's task, not the batch."""
    import hashlib

    from platkit.errors import PlatkitError
    from platkit.io.description import load_yaml

    try:
        y = load_yaml(ref.path / "session.yaml", error=BadInput)
    except (PlatkitError, ValueError):
        y = {}
    name = platform or str(y.get("platform") or "(none)")
    if not by_description:
        return name, ""
    desc = description or y.get("description")
    if not desc:
        return name, "its default description"
    path = Path(desc) if Path(desc).is_absolute() else ref.path / desc
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    except OSError:
        return name, f"description {path} (unreadable)"
    return name, f"description {path.name} {digest}"


def _parameterisation(args, options: dict, sessions, batch, client_for, say):
    """The batch's parameterisation (platkit.batch.gauge) and the options every session runs with."""
    import json

    from platkit.batch.engine import Task, run_tasks
    from platkit.batch.gauge import common_parameterisation, reference_free
    from platkit.batch.store import fingerprint
    from platkit.errors import PlatkitError
    from platkit.io.atomic import atomic_write_text
    from platkit.io.jsonout import dumps
    from platkit.io.session import load_session

    spec, first_error = None, None
    for ref in sessions:  # the stand, from the first session that reads (one that does not fails as its task)
        try:
            with contextlib.redirect_stderr(io.StringIO()):
                spec = load_session(ref.path, platform=args.platform, description=options.get("description"),
                                    quiet=True).spec
            break
        except PlatkitError as exc:
            first_error = first_error or exc
    if spec is None:
        raise first_error
    free: list[str] | None
    if args.reference is not None:
        free = reference_free(args.reference, spec)
        how = f"the parameters {args.reference} estimated (--reference)"
    elif args.free is not None:
        free = [] if args.free.strip().lower() == "none" else [f.strip() for f in args.free.split(",") if f.strip()]
        how = f"--free {args.free}"
    elif args.no_selection:
        free, how = None, "the stand's default free parameters (--no-selection)"
    else:
        # held-out selection in every session, then the union of the groups chosen: the parameterisation must
        # hold what any session needs
        cache_path = batch.out / "selection.json"
        cache = json.loads(cache_path.read_text(encoding="utf-8")) if cache_path.is_file() else {}
        prints = {r.name: fingerprint(r.path, options, _option_files(options, str(r.path), r.name)) for r in sessions}
        todo = [r for r in sessions if args.redo or (cache.get(r.name) or {}).get("fingerprint") != prints[r.name]]
        if todo:
            say(f"choosing the free groups: held-out selection in {len(todo)} sessions "
                f"({len(sessions) - len(todo)} known from before)")
            outcomes = run_tasks(client_for(), select_groups, [Task(r.name, (options, str(r.path), r.name)) for r in todo],
                                 timeout=args.task_timeout)
            bad = [o for o in outcomes if not o.ok]
            if bad:  # such a session fails again as its task, and is said there
                say(f"{len(bad)} sessions left out of the choice of groups: their selection failed (first: "
                    f"{bad[0].key}: {bad[0].error})")
            for o in outcomes:
                if o.ok:
                    cache[o.key] = {"fingerprint": prints[o.key], **o.value}
            if not any(r.name in cache for r in sessions):
                raise BadInput(f"held-out selection failed in every session (first: {bad[0].key}: {bad[0].error}); "
                               "choose the groups with --free or --reference")
            batch.start()
            atomic_write_text(cache_path, dumps(cache, indent=2) + "\n")
        free, how = _union_of_chosen(spec, sessions, cache, say)
    param = common_parameterisation(spec, free, how)
    batch.start()
    atomic_write_text(batch.out / "parameterisation.json", dumps(param.to_dict(), indent=2) + "\n")
    say(f"one parameterisation for every session: {len(param.free)} parameters free ({how})"
        + (f"; {len(param.gauge)} held at nominal in every session, a gauge: {', '.join(param.gauge)}"
           if param.gauge else ""))
    return {**options, "free": ",".join(param.free) if param.free else "none", "no_selection": False}, param


def _union_of_chosen(spec, sessions, cache: dict, say) -> tuple[list[str] | None, str]:
    """The free groups of a batch's parameterisation, and how they were chosen: the union of the
    groups held-out selection chose in the sessions ``cache`` holds. Sessions calibrated from motion
    choose none (said, counted) and take the others' choice; where every session is, the stand's
    default free parameters (what ``platkit calibrate``'s motion path frees)."""
    from platkit.calibrate.selection import parameter_groups

    known = [r for r in sessions if r.name in cache]
    motion = [r for r in known if cache[r.name].get("chosen") is None]
    choosers = [r for r in known if cache[r.name].get("chosen") is not None]
    if motion:
        say(f"{len(motion)} of {len(sessions)} sessions are calibrated from motion, which chooses no groups "
            f"(first: {motion[0].name}: {cache[motion[0].name].get('motion')})"
            + ("; they take the others' choice" if choosers else ""))
    if not choosers:
        return None, (f"the stand's default free parameters: all {len(motion)} sessions are calibrated from motion, "
                      "which chooses no groups")
    groups = list(parameter_groups(spec))
    chosen = {g for r in choosers for g in cache[r.name]["chosen"]}
    free = [g for g in groups if g in chosen]
    counts = {g: sum(g in cache[r.name]["chosen"] for r in choosers) for g in free}
    return free, ("the union of the groups held-out selection chose in each session (" +
                  ", ".join(f"{g} in {c} of {len(sessions)}" for g, c in counts.items()) + ")")


def run(args) -> int:
    """platkit batch VERB: the arguments and the matched sessions checked before any work, the
    sessions not done before (by fingerprint) run on the cluster, the fleet summary written (with
    --history, the stand's history too), one line said; 1 where a session failed."""
    from platkit.batch.engine import require_dask
    from platkit.batch.fleet import write_summary
    from platkit.batch.store import BatchFolder, match_sessions
    from platkit.io.atomic import check_output_dir

    require_dask()
    verb = args.batch_verb
    history = getattr(args, "history", False)
    _check_arguments(args, verb, history)
    check_output_dir(args.out)
    sessions, skipped = match_sessions(args.session)
    options = verb_options(args)
    events = _check_sessions(args, verb, history, sessions, options)
    batch = BatchFolder(args.out, verb, options)
    say = (lambda line: None) if args.quiet else (lambda line: print(f"batch: {line}", file=sys.stderr, flush=True))
    if skipped:
        print(f"platkit: warning: {len(skipped)} matched folders hold no session.yaml and are not sessions "
              f"(first: {skipped[0]})", file=sys.stderr)
    start = time.perf_counter()
    todo, why, failed = _run_sessions(args, verb, sessions, options, batch, say, start)
    batch.start()
    summary, written = write_summary(verb, sessions, batch)
    if history:
        written += _write_history(sessions, batch, events)
    return _said(verb, sessions, summary, written, todo, why, failed, batch, start)


def _check_arguments(args, verb: str, history: bool) -> None:
    """The batch's own options, each bad one refused before any work (BadInput naming it)."""
    from platkit.batch.engine import SCHEDULER_ENV

    if args.session is None:
        raise BadInput(f"platkit batch {verb}: give SESSION, a pattern of session folders such as 'fleet/*'")
    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers {args.workers}: use 1 or more")
    if args.workers is not None and (args.scheduler or os.environ.get(SCHEDULER_ENV)):
        raise BadInput(f"--workers applies to the embedded cluster; the scheduler at "
                       f"{args.scheduler or os.environ.get(SCHEDULER_ENV)} has its own workers")
    if args.task_timeout is not None and not args.task_timeout > 0:
        raise BadInput(f"--task-timeout {args.task_timeout}: use a positive number of seconds")
    reference = getattr(args, "reference", None)
    if reference is not None:
        if args.method != "lsq":
            raise BadInput("--reference applies to --method lsq")
        if args.free is not None or args.no_selection:
            raise BadInput("--reference decides the free parameters: leave out --free and --no-selection")
        if not Path(reference).is_file():
            raise BadInput(f"--reference {reference}: file not found")
    if getattr(args, "maintenance", None) is not None and not history:
        raise BadInput("--maintenance applies to --history")


def _check_sessions(args, verb: str, history: bool, sessions, options: dict) -> list[dict]:
    """What the matched sessions must agree on, checked before any work: the path options'
    placeholders, every session's date (a bad one names its file and field), with --history one
    stand in date order and its maintenance events (returned), and for batch calibrate one stand."""
    from platkit.batch.history import (
        MAINTENANCE_FILE,
        check_one_stand,
        history_order,
        read_maintenance,
        session_when,
    )

    for ref in sessions[:1]:  # a bad placeholder is bad input before any work
        session_options(options, str(ref.path), ref.name)
    whens = [session_when(r.path) for r in sessions]
    events: list[dict] = []
    if history:
        history_order([r.name for r in sessions], whens)
        check_one_stand([_stand_identity(r, args.platform, options.get("description")) for r in sessions],
                        [r.name for r in sessions])
        log = args.maintenance
        if log is None:
            beside = Path(os.path.commonpath([str(r.path.parent) for r in sessions])) / MAINTENANCE_FILE
            log = str(beside) if beside.is_file() else None
        elif not Path(log).is_file():
            raise BadInput(f"--maintenance {log}: file not found")
        events = read_maintenance(log) if log else []
    elif verb == "calibrate" and args.method == "lsq":
        stands = {_stand_identity(r, args.platform, None, by_description=False)[0] for r in sessions}
        if len(stands) > 1:
            raise BadInput(f"the sessions are of {len(stands)} stands ({', '.join(sorted(stands))}); a batch "
                           "calibrate compares one stand's parameters: run one batch per stand")
    return events


def _run_sessions(args, verb: str, sessions, options: dict, batch, say, start: float):
    """The sessions to run (a changed fingerprint, or --redo) run on the cluster, each written into
    ``batch`` as it finishes; batch calibrate first settles the batch's parameterisation. The
    cluster starts only where there is work for it; an interrupt or SIGTERM stops it and removes
    the scratch folder. Returns (the sessions run, Counter of why they ran, the failed outcomes)."""
    from collections import Counter

    from platkit.batch.engine import Task, cluster, progress_line, run_tasks, scratch_folder, terminate_as_interrupt
    from platkit.batch.store import fingerprint, why_redo

    failed = []
    with terminate_as_interrupt(), scratch_folder() as scratch, contextlib.ExitStack() as stack:
        clients: list = []

        def client_for():
            if not clients:
                clients.append(stack.enter_context(cluster(args.scheduler, args.workers, args.dashboard, say)))
            return clients[0]

        task_options = options
        if verb == "calibrate" and args.method == "lsq":
            task_options, _ = _parameterisation(args, options, sessions, batch, client_for, say)
        prints = {r.name: fingerprint(r.path, task_options, _option_files(task_options, str(r.path), r.name))
                  for r in sessions}
        reasons = {r.name: why_redo(batch.record(r.name), prints[r.name], args.redo) for r in sessions}
        todo = [r for r in sessions if reasons[r.name]]
        why = Counter(reasons[r.name] for r in todo)
        say(f"{len(sessions)} sessions, {len(sessions) - len(todo)} done before with these inputs and options, "
            f"{len(todo)} to run" + (f" ({', '.join(f'{n} {w}' for w, n in why.items())})" if todo else ""))

        def keep(outcome) -> None:
            ref = next(r for r in todo if r.name == outcome.key)
            record = {"session": str(ref.path), "verb": verb, "ok": outcome.ok, "seconds": outcome.seconds,
                      "worker": outcome.worker, "fingerprint": prints[ref.name], "ran_because": reasons[ref.name]}
            if outcome.ok:
                batch.write_session(outcome.key, outcome.value["files"],
                                    {**record, "line": outcome.value["line"].replace(outcome.value["out"],
                                                                                     str(batch.sessions / outcome.key)),
                                     "warnings": outcome.value["warnings"] + outcome.warnings})
            else:
                batch.write_failure(outcome.key, {**record, "error": outcome.error, "kind": outcome.kind})

        if todo:
            outcomes = run_tasks(client_for(), run_verb,
                                 [Task(r.name, (verb, task_options, str(r.path), r.name, scratch)) for r in todo],
                                 on_outcome=keep, progress=None if args.quiet else progress_line("batch", start=start),
                                 timeout=args.task_timeout)
            failed = [o for o in outcomes if not o.ok]
    return todo, why, failed


def _write_history(sessions, batch, events: list[dict]) -> list[Path]:
    """The stand's history written into ``batch`` (platkit.batch.history), its maintenance events,
    changes and parameters tested only where identified said on stdout; returns the files written."""
    from platkit.batch.history import write_history

    hist, written = write_history(sessions, batch, events=events)
    for ev in hist["events"]:
        print(f"maintenance: {ev['date']} {ev['note']}" + (f" (before {ev['before_session']}: a new run of agreeing "
                                                            f"sessions starts there)" if ev["before_session"] else ""))
    for flag in hist["changes"]:
        print(f"change: {flag['parameter']} in {flag['session']} by {flag['change']:+.4g} {flag['unit']} "
              f"({flag['z']:+.1f} sigma)")
    partly = hist["tested_on"]["not_identified_in"]
    if partly:
        print(f"history: {len(partly)} parameters not identified in some sessions, tested only between those that "
              f"identify them: " + "; ".join(f"{p} (not in {', '.join(v)})" for p, v in list(partly.items())[:5])
              + (" ..." if len(partly) > 5 else ""))
    return written


def _said(verb: str, sessions, summary: dict, written: list, todo, why, failed, batch, start: float) -> int:
    """The batch's one line on stdout (sessions done, from before, run and why, failed, time, files
    written), each failure on stderr; the exit status: 1 where a session failed, else 0."""
    c = summary["counts"]
    ran = f", {len(todo)} run: " + ", ".join(f"{n} {w}" for w, n in why.items()) if todo else ""
    print(f"batch {verb}: {c['ok']} of {len(sessions)} sessions done ({len(sessions) - len(todo)} from before{ran}), "
          f"{c['failed']} failed, in {time.perf_counter() - start:.1f} s; wrote {', '.join(str(p) for p in written)}")
    for o in failed:
        print(f"platkit: error: {o.key}: {o.error}", file=sys.stderr)
    if c["failed"]:
        print(f"platkit: {c['failed']} sessions failed (listed in {batch.failed}); run the same command again to "
              "retry them", file=sys.stderr)
        return 1
    return 0
