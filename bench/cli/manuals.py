"""`gibench manuals [--write]`: check (or regenerate) every method's parameter tables against its
`Param` declarations (bench.protocol.manual); exit 1 when one is out of date."""
from __future__ import annotations

import sys

from bench.cli import options
from bench.protocol import manual
from bench.protocol.registry import list_methods, load_method


def add_parser(sub) -> None:
    p = sub.add_parser("manuals", help="check the methods' parameter tables against their declarations")
    p.add_argument("--methods", type=options.method_list, default=None, help="comma-separated (default: every registered method)")
    p.add_argument("--write", action="store_true", help="regenerate the tables between their markers")
    p.set_defaults(func=main)


def main(args) -> int:
    methods = args.methods or list_methods()
    if not options.known_methods(methods):
        return 2
    problems = []
    for name in methods:
        cls = load_method(name)
        if args.write:
            for path in manual.write(cls):
                print(f"updated {path}")
        problems += manual.check(cls)
    for line in problems:
        print(f"gibench: {line}", file=sys.stderr)
    return 1 if problems else 0
