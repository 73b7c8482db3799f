"""The ``platkit`` command: parse, call the library, print. Exit 0 ok, 1 failed, 2 bad input."""
from __future__ import annotations

import argparse
import importlib
import os
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




def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
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
