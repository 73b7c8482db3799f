"""The ``platkit`` command: parse, call the library, print. Exit 0 ok, 1 failed, 2 bad input."""
from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import traceback

from platkit import __version__
from platkit.errors import PlatkitError

#: verb modules under platkit.commands, in the order `platkit --help` lists them
COMMANDS = ["plugins", "describe", "fk", "ik", "admissible", "workspace", "calibrate", "predict", "diagnose", "track", "simulate", "plan", "orient"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="platkit", description="Kinematics, calibration and diagnosis of motion platforms")
    parser.add_argument("--debug", action="store_true", help="show the traceback on errors")
    parser.add_argument("--version", action="version", version=f"platkit {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"platkit.commands.{name}")
        p = module.add_parser(sub)
        p.set_defaults(_run=module.run)
        p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help="show the traceback on errors")
    return parser




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


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = join_negative_values(list(sys.argv[1:] if argv is None else argv))
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse already printed one line; bad usage is bad input
        return 2 if exc.code not in (0, None) else 0
    debug = getattr(args, "debug", False)
    try:
        return int(args._run(args) or 0)
    except PlatkitError as exc:
        if debug:
            traceback.print_exc()
        print(f"platkit: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # the reader stopped early (`platkit describe ... | head`): not an error
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so the flush at exit does not complain again
        return 0
    except OSError as exc:  # a path the system refused (permissions, a file where a folder must be)
        if debug:
            traceback.print_exc()
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"platkit: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("platkit: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an unexpected failure is a failed computation, said in one line
        if debug:
            traceback.print_exc()
        print(f"platkit: error: {exc.__class__.__name__}: {exc} (run with --debug for the traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
