"""`gibench run`: methods over scenes -> a run folder (results, images, references, manifest)."""
from __future__ import annotations

import sys
from pathlib import Path

from bench.cli import options
from bench.protocol.registry import MethodLoadError, load_method
from bench.run import serial
from bench.run.config import RunConfig


def add_parser(sub) -> None:
    p = sub.add_parser("run", help="run methods over scenes")
    options.add_run_options(p, None)
    p.add_argument("--param", action="append", type=options.param_item,
                   help="METHOD.NAME=VALUE[,VALUE...] (repeatable, once per parameter; lists make a grid)")
    p.add_argument("--timing-budget", type=options.float_in(*options.TIMING_BUDGET_RANGE_S), default=None,
                   metavar="SECONDS",
                   help="calibrated timing: after --frames frames, time more until the median's 95%% interval is "
                        "within 5%% or SECONDS of frames are spent (default 1.0, 0.3 with --quick; 0: exactly --frames)")
    p.add_argument("--workers", type=options.workers, default=None, metavar="N",
                   help="run rows and references as Dask tasks on a local cluster of N processes (timed rows "
                        "still one at a time per machine)")
    p.add_argument("--scheduler", type=options.non_empty, default=None, metavar="ADDRESS",
                   help="run rows and references on an existing dask.distributed cluster (tcp://host:8786)")
    p.add_argument("--quick", action="store_true",
                   help="a first report in minutes: scenes " + ",".join(options.QUICK_SCENES)
                        + " (unless --scenes), the fastest and the default rung of each ladder, timing budget 0.3 s, "
                        "references capped at %d spp (unless --reference-spp), %d error frames (unless --error-frames)"
                        % (options.QUICK_REFERENCE_SPP, options.QUICK_ERROR_FRAMES))
    p.add_argument("--defaults-only", action="store_true",
                   help="run each method at its defaults only (default: its quality ladder, fast -> accurate, "
                        "one time-vs-error curve per method; a method given --param runs those sets instead)")
    p.set_defaults(func=main)


def quick_rungs(methods: list[str], params: dict) -> dict:
    """--quick: the fastest rung and the defaults of each ladder (a two-point curve), unless --param sets them."""
    out = dict(params)
    for m in methods:
        if m in out:
            continue
        try:
            ladder = load_method(m).ladder
        except MethodLoadError:
            continue
        if ladder:
            out[m] = [dict(ladder[0])] + ([{}] if dict(ladder[0]) else [])
    return out


def main(args) -> int:
    methods = args.methods
    if not options.known_methods(methods):
        return 2
    options.one_cluster(args.workers, args.scheduler)
    width, height = args.res
    params = options.param_sets(args.param)
    options.distinct_param_sets(params)
    scenes = args.scenes or list(options.QUICK_SCENES if args.quick else options.DEFAULT_SCENES)
    budget = args.timing_budget if args.timing_budget is not None else (0.3 if args.quick else 1.0)
    if args.quick and not args.defaults_only:
        params = quick_rungs(methods, params)
    cfg = RunConfig(scenes=scenes, methods=methods, width=width, height=height, frames=args.frames,
                    warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None, force=args.force,
                    views=args.views, params=params, references=not args.no_reference,
                    reference_spp_cap=args.reference_spp if args.reference_spp is not None else
                    (options.QUICK_REFERENCE_SPP if args.quick else options.REFERENCE_SPP),
                    progress=not args.no_progress, ladders=not args.defaults_only,
                    timing_budget_s=budget if budget > 0 else None, scheduler=args.scheduler, workers=args.workers,
                    shadow_resolution=args.shadow_resolution,
                    error_frames=args.error_frames if args.error_frames is not None else
                    (options.QUICK_ERROR_FRAMES if args.quick else options.ERROR_FRAMES))
    df, runner = serial.run(cfg, log=lambda m: print(m, file=sys.stderr))
    print(runner.summary())
    print(f"results: {runner.run_dir / 'results.csv'}")
    return options.nothing_useful(runner)
