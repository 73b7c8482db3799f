"""The ``platkit`` command: parse, call the library, print. Exit 0 ok, 1 failed, 2 bad input,
130 interrupted (Ctrl-C).

Start-up cost is what a user waits for on every call, so only the chosen verb's module is
imported (and with it only what that verb uses); the full list of verbs is built for
``platkit --help`` and for a command line that names no known verb.
"""
from __future__ import annotations

import signal
import sys


def _interrupted_while_starting(signum, frame):
    """Ctrl-C before main() has its handlers in place (while the modules below load)."""
    print("platkit: interrupted", file=sys.stderr)
    raise SystemExit(130)


# Started as the `platkit` command (the console script, or python -m platkit.cli): a Ctrl-C while
# the modules below load ends in one line too. Imported as a library, the handler is left alone.
if sys.argv and sys.argv[0].replace("\\", "/").rsplit("/", 1)[-1] in ("platkit", "cli.py") \
        and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # a batch's workers ignore Ctrl-C: left so
    signal.signal(signal.SIGINT, _interrupted_while_starting)

import argparse  # noqa: E402  (below the handler on purpose)
import importlib  # noqa: E402
import keyword  # noqa: E402
import os  # noqa: E402
import re  # noqa: E402

from platkit import __version__  # noqa: E402
from platkit._threads import blas_threads  # noqa: E402
from platkit.errors import PlatkitError  # noqa: E402
from platkit.notices import collecting, units_checked  # noqa: E402

#: verb modules under platkit.commands, in the order `platkit --help` lists them
COMMANDS = ["plugins", "describe", "fk", "ik", "admissible", "workspace", "calibrate", "predict", "diagnose", "track", "simulate", "plan", "orient", "import", "batch"]

def chosen_verb(argv: list[str]) -> str | None:
    """The verb a command line names: its first word that is not one of platkit's own options
    (those take no value), or None. It may be a misspelt verb; the caller checks."""
    for arg in argv:
        if arg == "--":
            return None
        if arg.startswith("-"):
            continue
        return arg
    return None


def build_parser(verbs: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser with the sub-parsers of ``verbs`` (default: every verb in COMMANDS, which
    imports every verb module; give just the chosen one to import only that)."""
    parser = argparse.ArgumentParser(prog="platkit", description="Kinematics, calibration and diagnosis of motion platforms")
    parser.add_argument("--debug", action="store_true", help="show the traceback on errors")
    parser.add_argument("--version", action="version", version=f"platkit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS if verbs is None else verbs:
        # a verb that is a Python keyword (import) lives in a module named with a trailing underscore
        module = importlib.import_module(f"platkit.commands.{name}{'_' if keyword.iskeyword(name) else ''}")
        p = module.add_parser(sub)
        p.set_defaults(_run=module.run)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback on errors")
        p.add_argument("--units-checked", action="store_true", default=False,
                       help="the units of the input files are right as written: plausibility checks of units "
                            "(a gyro in deg/s, an accelerometer in g, times in ms, lengths in m or mm) keep the "
                            "data with a warning instead of refusing it")
    return parser


def parser_for(argv: list[str]) -> argparse.ArgumentParser:
    """The parser a command line needs: the chosen verb's alone; none for a bare ``--version``;
    every verb for ``--help``, for no verb, or for an unknown one (so the error lists them)."""
    verb = chosen_verb(argv)
    before_verb = argv[:argv.index(verb)] if verb is not None else argv
    if verb in COMMANDS and not {"-h", "--help"} & set(before_verb):  # `platkit -h fk`: the list of verbs
        return build_parser([verb])
    if verb is None and "--version" in argv and not {"-h", "--help"} & set(argv):
        return build_parser([])
    return build_parser()


#: a value that starts like a negative number ("-10,20", "-.5", "-1e3")
_NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d)")


def join_negative_values(argv: list[str]) -> list[str]:
    """``--u -10,20`` -> ``--u=-10,20``: argparse takes a value that starts with '-' for an option
    unless it is one plain number, so comma-separated vectors with a negative first entry
    (controls, poses, targets) would fail with "expected one argument"."""
    out, i = [], 0
    while i < len(argv):
        arg = argv[i]
        if arg.startswith("--") and "=" not in arg and i + 1 < len(argv) and _NEGATIVE_VALUE.match(argv[i + 1]):
            out.append(f"{arg}={argv[i + 1]}")
            i += 2
            continue
        out.append(arg)
        i += 1
    return out


def _print_traceback() -> None:
    """--debug: the traceback of the error being handled (traceback imported only then: it
    costs every start-up a few milliseconds)."""
    import traceback

    traceback.print_exc()


def as_flag(message: str, argv: list[str]) -> str:
    """A library error that begins with the name of a parameter and a colon ('free: ...',
    'folds: ...') said as the option the command line set it with ('--free: ...'), where ``argv``
    holds that option; other messages unchanged."""
    head, colon, rest = message.partition(":")
    flag = "--" + head.replace("_", "-")
    given = any(a == flag or a.startswith(flag + "=") for a in argv)
    return f"{flag}:{rest}" if colon and head.isidentifier() and given else message


def _stdout_to_devnull() -> None:
    """After a reader stopped early: the process's own standard output (sys.__stdout__'s file
    descriptor) points at /dev/null, so that the flush at exit does not complain again. A
    standard output another program put in its place (a test harness, a host application) is left
    to it: its descriptor is not the process's to close."""
    if sys.stdout is not sys.__stdout__ or sys.__stdout__ is None:
        return
    try:
        fd = sys.__stdout__.fileno()
    except (OSError, ValueError):  # io.UnsupportedOperation is an OSError and a ValueError
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def main(argv: list[str] | None = None) -> int:
    """Run one command line; the exit status. Ctrl-C at any point, start-up included, ends
    with one line on stderr and 130."""
    argv = join_negative_values(list(sys.argv[1:] if argv is None else argv))
    debug = "--debug" in argv
    try:
        if signal.getsignal(signal.SIGINT) is _interrupted_while_starting:
            # from here on a Ctrl-C is a KeyboardInterrupt, so that outputs being written are undone
            signal.signal(signal.SIGINT, signal.default_int_handler)
        try:
            parser = parser_for(argv)
            args = parser.parse_args(argv)
        except SystemExit as exc:  # argparse already printed one line; bad usage is bad input
            return 2 if exc.code not in (0, None) else 0
        debug = getattr(args, "debug", False)
        with collecting(), units_checked(getattr(args, "units_checked", False)), blas_threads(1):
            # each warning printed once on stderr and kept for the verb's report; --units-checked
            # answers the plausibility checks of units; the verb on one BLAS thread unless the user
            # chose otherwise (platkit._threads: PLATKIT_BLAS_THREADS, OPENBLAS_NUM_THREADS, ...)
            return int(args._run(args) or 0)
    except PlatkitError as exc:
        if debug:
            _print_traceback()
        print(f"platkit: error: {as_flag(str(exc), argv)}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # the reader stopped early (`platkit describe ... | head`): not an error
        _stdout_to_devnull()
        return 0
    except OSError as exc:  # a path the system refused (permissions, a file where a folder must be)
        if debug:
            _print_traceback()
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"platkit: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if debug:
            _print_traceback()
        print("platkit: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an unexpected failure is a failed computation, said in one line
        if debug:
            _print_traceback()
        print(f"platkit: error: {exc.__class__.__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
