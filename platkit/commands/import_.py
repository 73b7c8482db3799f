"""platkit import: a motion-capture export (Vicon CSV, Qualisys TSV, OptiTrack Motive CSV, C3D, or a
table with another separator or decimal mark) written as a session folder in the spec's format."""
from __future__ import annotations

import sys


def add_parser(sub):
    p = sub.add_parser("import", help="a motion-capture export (Vicon, Qualisys, Motive, C3D, CSV/TSV) as a session folder")
    p.add_argument("file", help="the export: recognised by its content (see --format)")
    p.add_argument("--out", required=True, help="the session folder to write (session.yaml, markers.csv, commands.csv)")
    p.add_argument("--format", default=None, choices=("vicon", "qualisys", "motive", "c3d", "table"),
                   help="the export's format (default: recognised from the file's first line)")
    p.add_argument("--unit", default=None, choices=("mm", "m"),
                   help="the length unit of a plain table (required there); for the vendor formats, which say "
                        "their unit, a check")
    p.add_argument("--platform", default=None, help="the stand's name, for session.yaml (with --commands)")
    p.add_argument("--commands", default=None, help="the command log (commands.csv) to copy into the session")
    p.add_argument("--time-offset-s", type=float, default=0.0,
                   help="added to the export's times to put them on the commands' clock (default 0)")
    return p


def run(args) -> int:
    from platkit.io.atomic import check_output_dir
    from platkit.io.importers import read_recording, write_session

    check_output_dir(args.out)
    rec = read_recording(args.file, args.format, args.unit)
    write_session(rec, args.out, args.platform, args.commands, args.time_offset_s)
    for note in rec.notes:
        print(f"platkit: note: {note}", file=sys.stderr)
    print(f"{rec.summary()} -> {args.out}/markers.csv")
    if args.commands is None:
        print(f"platkit: note: {args.out} has no commands.csv: add the command log and set 'platform' in "
              "session.yaml (or import again with --platform and --commands) before calibrating", file=sys.stderr)
    return 0
