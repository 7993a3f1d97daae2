"""What each method redoes when a scene moves, and what it costs (issue #25).

Renders every method at its defaults through the three corpus sequences (bench.run.sequence:
one instance follows the frames in order, the work a motion invalidates redone inside the
frame) and prints, per method and kind of motion, the median `update_ms` (the redo) and
`frame_ms` of the frames that moved, beside the median frame at rest (nothing redone).

    PYTHONPATH=. python -m studies.motion_costs [--res 160x90] [--frames 4] [--rest 2]

manylights runs with max_triangles=20000 (on sponza it would sum 66k triangles per pixel: skipped).
"""
from __future__ import annotations

import argparse
import statistics

from bench.gl import create_context
from bench.model.corpus.sequences import SEQUENCES, load_sequence
from bench.protocol.method import SkipRow
from bench.protocol.registry import load_method
from bench.run.config import auto_shadow_resolution
from bench.run.sequence import run_sequence

METHODS = ("direct", "ir_unshadowed", "ir_shadowed", "manylights", "flc", "ssdo", "dss", "val_clustered", "pbgi",
           "visibility_gates")
OVERRIDES = {"manylights": {"max_triangles": 20000}}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="160x90")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--rest", type=int, default=2)
    ap.add_argument("--methods", default=",".join(METHODS))
    args = ap.parse_args()
    w, h = (int(v) for v in args.res.split("x"))
    ctx = create_context()
    print(f"{'method':17s} {'sequence':26s} {'moves':9s} {'update ms':>10s} {'moved frame ms':>15s} {'rest frame ms':>14s}")
    for method in args.methods.split(","):
        cls = load_method(method)
        for name, entry in SEQUENCES.items():
            seq = load_sequence(name, args.frames, args.rest)
            try:
                r = run_sequence(ctx, cls, seq, "main", w, h, OVERRIDES.get(method, {}),
                                 shadow_resolution=auto_shadow_resolution(w, h))
            except SkipRow as exc:
                print(f"{method:17s} {name:26s} {entry.moves:9s} skipped: {exc}")
                continue
            moved = [f for f in r.frames[1:] if f.changes]
            rest = [f for f in r.frames[1:] if not f.changes]
            med = lambda fs, a: statistics.median(getattr(f, a) for f in fs) if fs else float("nan")  # noqa: E731
            print(f"{method:17s} {name:26s} {entry.moves:9s} {med(moved, 'update_ms'):10.1f} "
                  f"{med(moved, 'frame_ms'):15.1f} {med(rest, 'frame_ms'):14.1f}", flush=True)


if __name__ == "__main__":
    main()
