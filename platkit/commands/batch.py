"""platkit batch: calibrate, diagnose or orient every session a pattern matches, on a Dask cluster.

    platkit batch calibrate 'fleet/*' --out fleet_cal --folds 5
    platkit batch diagnose 'fleet/*' --calibration 'fleet_cal/sessions/{name}/calibration.yaml' --out fleet_diag
    platkit batch calibrate 'stand7/month*' --out stand7_history --history

Each session is one task: the single verb's own ``run`` with the options given here (so a batch
gives exactly what the verb gives one by one), into its own folder under OUT/sessions/, written
whole as it finishes. A failed session is reported and the others go on; a re-run skips what
is done. The cluster is an embedded local one (one worker per core) unless --scheduler or
PLATKIT_DASK_SCHEDULER names one; the sessions' paths must be readable by its workers.
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
BATCH_KEYS = ("command", "batch_verb", "_run", "debug", "scheduler", "workers", "history", "session", "out", "quiet")
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
                        help="worker processes of the embedded cluster (default: one per core)")
        with contextlib.suppress(argparse.ArgumentError):  # calibrate and diagnose have their own
            vp.add_argument("--quiet", action="store_true", help="no progress on stderr")
        if verb == "calibrate":
            vp.add_argument("--history", action="store_true",
                            help="the sessions are one stand over time (dates from session.yaml, else the folder "
                                 "order): each parameter's trend, and changes larger than the uncertainties explain "
                                 "(history.csv, history.json, history.html)")
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


def run_verb(verb: str, options: dict, session: str, name: str) -> dict:
    """One session through ``platkit.commands.<verb>.run`` (on a worker): the options as the
    verb's parser gave them, the session, a private --out. Returns the files written
    ({relative path: bytes}), the line the verb printed, and its warnings (stderr lines)."""
    module = importlib.import_module(f"platkit.commands.{verb}")
    ns = argparse.Namespace(**session_options(options, session, name))
    ns.session = session
    ns.quiet = True
    with tempfile.TemporaryDirectory(prefix="platkit-batch-") as tmp:
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


def run(args) -> int:
    from platkit.batch.engine import SCHEDULER_ENV, Task, cluster, progress_line, require_dask, run_tasks
    from platkit.batch.fleet import write_summary
    from platkit.batch.store import BatchFolder, match_sessions
    from platkit.io.atomic import check_output_dir

    require_dask()
    verb = args.batch_verb
    if args.session is None:
        raise BadInput(f"platkit batch {verb}: give SESSION, a pattern of session folders such as 'fleet/*'")
    if args.workers is not None and args.workers < 1:
        raise BadInput(f"--workers {args.workers}: use 1 or more")
    if args.workers is not None and (args.scheduler or os.environ.get(SCHEDULER_ENV)):
        raise BadInput(f"--workers applies to the embedded cluster; the scheduler at "
                       f"{args.scheduler or os.environ.get(SCHEDULER_ENV)} has its own workers")
    check_output_dir(args.out)
    sessions, skipped = match_sessions(args.session)
    options = verb_options(args)
    for ref in sessions[:1]:  # a bad placeholder is bad input before any work
        session_options(options, str(ref.path), ref.name)
    batch = BatchFolder(args.out, verb, options)
    todo = [ref for ref in sessions if not batch.done(ref.name)]
    say = (lambda line: None) if args.quiet else (lambda line: print(f"batch: {line}", file=sys.stderr, flush=True))
    say(f"{len(sessions)} sessions, {len(sessions) - len(todo)} already done, {len(todo)} to run")
    if skipped:
        print(f"platkit: warning: {len(skipped)} matched folders hold no session.yaml and are not sessions "
              f"(first: {skipped[0]})", file=sys.stderr)

    def keep(outcome) -> None:
        record = {"session": next(str(r.path) for r in todo if r.name == outcome.key), "verb": verb, "ok": outcome.ok,
                  "seconds": outcome.seconds, "worker": outcome.worker}
        if outcome.ok:
            batch.write_session(outcome.key, outcome.value["files"],
                                {**record, "line": outcome.value["line"].replace(outcome.value["out"],
                                                                                 str(batch.sessions / outcome.key)),
                                 "warnings": outcome.value["warnings"] + outcome.warnings})
        else:
            batch.write_failure(outcome.key, {**record, "error": outcome.error, "kind": outcome.kind})

    start = time.perf_counter()
    failed = []
    if todo:
        with cluster(args.scheduler, args.workers) as client:
            outcomes = run_tasks(client, run_verb, [Task(r.name, (verb, options, str(r.path), r.name)) for r in todo],
                                 on_outcome=keep, progress=None if args.quiet else progress_line("batch", start=start))
        failed = [o for o in outcomes if not o.ok]
    batch.start()
    summary, written = write_summary(verb, sessions, batch)
    if getattr(args, "history", False):
        from platkit.batch.history import write_history

        hist, more = write_history(sessions, batch)
        written += more
        for flag in hist["changes"]:
            print(f"change: {flag['parameter']} in {flag['session']} by {flag['change']:+.4g} {flag['unit']} "
                  f"({flag['z']:+.1f} sigma)")
    c = summary["counts"]
    print(f"batch {verb}: {c['ok']} of {len(sessions)} sessions done ({len(sessions) - len(todo)} from before), "
          f"{c['failed']} failed, in {time.perf_counter() - start:.1f} s; wrote {', '.join(str(p) for p in written)}")
    for o in failed:
        print(f"platkit: error: {o.key}: {o.error}", file=sys.stderr)
    if c["failed"]:
        print(f"platkit: {c['failed']} sessions failed (listed in {batch.failed}); run the same command again to "
              "retry them", file=sys.stderr)
        return 1
    return 0
