"""`gibench new-method NAME [--dir PATH]`: write a ready plugin package for a new method
(bench.kit.scaffold), then say how to install, check and run it."""
from __future__ import annotations

from pathlib import Path

from bench.kit.scaffold import write_package


def add_parser(sub) -> None:
    p = sub.add_parser("new-method", help="write a ready plugin package for a new method (outside this tree)")
    p.add_argument("name", help="the method's name: its entry point and Python package (lower-case, digits, _)")
    p.add_argument("--dir", default=None, metavar="PATH",
                   help="the package's folder, absent or empty (default: ./gibench-NAME)")
    p.set_defaults(func=main)


def main(args) -> int:
    directory = Path(args.dir) if args.dir else Path(f"gibench-{args.name}")
    written = write_package(args.name, directory)
    for path in written:
        print(f"wrote {path}")
    print(f"next: pip install -e {directory}   then   gibench check-method {args.name}   then   "
          f"gibench run --methods direct,{args.name}   (the guide: docs/method_guide.md)")
    return 0
