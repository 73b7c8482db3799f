"""One module per CLI verb: each has ``add_parser(subparsers)`` and ``run(args) -> int``.

cli.py lists them in COMMANDS; a verb's module parses its own options and calls the library.
"""
