"""platkit plugins: the stands installed, and from which package."""
from __future__ import annotations

from platkit.commands.common import print_json
from platkit.plugins import default_host


def add_parser(sub):
    p = sub.add_parser("plugins", help="list the installed stands and effects")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def run(args) -> int:
    host = default_host()
    stands = host.platforms()
    effects = host.effects()
    if args.json:
        print_json({
            "platforms": [{"name": f.name, "title": f.title, "package": f.package,
                           "description_suffixes": list(f.description_suffixes)} for f in stands.values()],
            "effects": sorted(effects),
        })
        return 0
    print("stands:")
    width = max((len(n) for n in stands), default=0)
    for f in stands.values():
        print(f"  {f.name:<{width}}  {f.title}  [{f.package}]")
    if effects:
        print("effects: " + ", ".join(sorted(effects)))
    return 0
