"""`gibench list methods|scenes|sequences`."""
from __future__ import annotations

from bench.model.corpus import list_scenes
from bench.model.corpus.sequences import FRAMES, SEQUENCES
from bench.protocol.registry import MethodLoadError, entry_point_target, list_methods, load_method


def add_parser(sub) -> None:
    p = sub.add_parser("list", help="list methods, scenes or sequences (scenes in motion)")
    p.add_argument("what", choices=("methods", "scenes", "sequences"))
    p.add_argument("-v", "--verbose", action="store_true", help="methods: import each to show its summary")
    p.set_defaults(func=main)


def main(args) -> int:
    if args.what == "methods":
        for name in list_methods():
            if args.verbose:
                try:
                    print(f"{name:16s} {load_method(name).summary}")
                except MethodLoadError as exc:
                    print(f"{name:16s} (fails to load: {exc})")
            else:
                print(f"{name:16s} {entry_point_target(name)}")
        return 0
    if args.what == "sequences":
        for seq in SEQUENCES.values():
            print(f"{seq.name:26s} {seq.scene:14s} moves {seq.moves:9s} {FRAMES} frames  {seq.purpose}")
        return 0
    for entry in list_scenes():
        print(f"{entry.name:18s} {entry.triangle_count:>10,d} tris  {entry.purpose}")
    return 0
