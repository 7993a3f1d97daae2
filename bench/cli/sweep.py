"""`gibench sweep`: a run across each method's quality knobs: time-vs-error curves, Pareto fronts."""
from __future__ import annotations

import sys
from pathlib import Path

from bench.cli import options
from bench.run import sweep


def add_parser(sub) -> None:
    p = sub.add_parser("sweep", help="run methods across their quality knobs: time-vs-error curves, Pareto fronts")
    options.add_run_options(p, ",".join(options.DEFAULT_SCENES))
    p.set_defaults(func=main)


def main(args) -> int:
    methods = args.methods
    if not options.known_methods(methods):
        return 2
    width, height = args.res
    table, pareto, runner = sweep.run_sweep(
        args.scenes, methods, log=lambda m: print(m, file=sys.stderr), width=width, height=height,
        frames=args.frames, warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None,
        force=args.force, views=args.views, references=not args.no_reference,
        reference_spp_cap=args.reference_spp if args.reference_spp is not None else options.REFERENCE_SPP,
        progress=not args.no_progress,
        shadow_resolution=args.shadow_resolution,
        error_frames=args.error_frames if args.error_frames is not None else options.ERROR_FRAMES)
    print(runner.summary())
    print(f"{len(table)} sweep points, {len(pareto)} on the Pareto fronts")
    print(f"sweep: {runner.run_dir / 'sweep.csv'}")
    print(f"pareto: {runner.run_dir / 'pareto.csv'}")
    return options.nothing_useful(runner)
