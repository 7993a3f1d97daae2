"""`gibench run`: methods over scenes -> a run folder (results, images, references, manifest)."""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from bench.cli import options
from bench.run import serial
from bench.run.config import RunConfig

STARTED = time.perf_counter()   # the command's start (imports done before it): a --budget counts from here


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
                   help="a first report in minutes: a %d-minute budget (unless --budget) over the default corpus, "
                        "timing budget 0.3 s, references capped at %d spp (unless --reference-spp), %d error frames "
                        "(unless --error-frames)" % (options.QUICK_BUDGET_S // 60, options.QUICK_REFERENCE_SPP,
                                                     options.QUICK_ERROR_FRAMES))
    p.add_argument("--budget", type=options.duration, default=None, metavar="DURATION",
                   help="the run's time budget (90s, 10m, 1h30m; none: no budget): the rows that fit it by the cost plan, every "
                        "method's defaults first, then the ends of the ladders, then their middles; the others "
                        "are recorded as skipped (over budget), and no row starts once the budget is spent")
    p.add_argument("--sequences", type=options.sequence_list, default=None,
                   help="scenes in motion to run after the scenes (comma-separated, all or none; `gibench list "
                        "sequences`): each method at its defaults follows each frame in order, judged against a "
                        "reference per frame (default: " + ",".join(options.DEFAULT_SEQUENCES) + " with the default "
                        "scenes, none with --scenes; --sequences alone runs only the sequences)")
    p.add_argument("--sequence-frames", type=options.int_in(*options.SEQUENCE_FRAMES_RANGE), default=6, metavar="N",
                   help="frames of motion of each sequence (default 6)")
    p.add_argument("--sequence-rest", type=options.int_in(0, options.SEQUENCE_FRAMES_RANGE[1]), default=6, metavar="N",
                   help="frames at rest after the motion, over which a method that reuses earlier frames catches "
                        "up: its lag_frames (default 6)")
    p.add_argument("--sequence-settle", type=options.int_in(0, options.SEQUENCE_FRAMES_RANGE[1]), default=64,
                   metavar="N",
                   help="a row whose error is not back within 10%% of its static level by the last frame renders "
                        "up to N more frames at rest, only to measure its lag_frames (default 64; 0: the lag is "
                        "then a lower bound, lag_frames_at_least)")
    p.add_argument("--plan", action="store_true",
                   help="print the cost plan (rows by scene and method, predicted time per phase, what is "
                        "skipped and why) and stop: nothing is rendered, no run folder is made")
    p.add_argument("--defaults-only", action="store_true",
                   help="run each method at its defaults only (default: its quality ladder, fast -> accurate, "
                        "one time-vs-error curve per method; a method given --param runs those sets instead)")
    p.set_defaults(func=main)


def main(args) -> int:
    methods = args.methods
    if not options.known_methods(methods):
        return 2
    options.one_cluster(args.workers, args.scheduler)
    width, height = args.res
    params = options.param_sets(args.param)
    options.distinct_param_sets(params)
    # the default run (no --scenes) has the default sequences too; --scenes alone runs those scenes only
    sequences = list(args.sequences) if args.sequences is not None else \
        ([] if args.scenes else list(options.DEFAULT_SEQUENCES))
    scenes = args.scenes or ([] if args.sequences else list(options.DEFAULT_SCENES))
    budget = args.timing_budget if args.timing_budget is not None else (0.3 if args.quick else 1.0)
    run_budget = args.budget if args.budget is not None else (options.QUICK_BUDGET_S if args.quick else None)
    run_budget = None if run_budget == math.inf else run_budget   # --budget none
    cfg = RunConfig(scenes=scenes, methods=methods, width=width, height=height, frames=args.frames,
                    warmup=args.warmup, seed=args.seed, out=Path(args.out) if args.out else None, force=args.force,
                    views=args.views, params=params, references=not args.no_reference,
                    reference_spp_cap=args.reference_spp if args.reference_spp is not None else
                    (options.QUICK_REFERENCE_SPP if args.quick else options.REFERENCE_SPP),
                    progress=not args.no_progress, ladders=not args.defaults_only,
                    timing_budget_s=budget if budget > 0 else None, scheduler=args.scheduler, workers=args.workers,
                    shadow_resolution=args.shadow_resolution,
                    error_frames=args.error_frames if args.error_frames is not None else
                    (options.QUICK_ERROR_FRAMES if args.quick else options.ERROR_FRAMES), budget_s=run_budget,
                    sequences=sequences, sequence_frames=args.sequence_frames, sequence_rest=args.sequence_rest,
                    sequence_settle=args.sequence_settle,
                    **({"budget_margin": options.QUICK_BUDGET_MARGIN} if args.quick else {}))
    if args.plan:
        print(serial.plan_only(cfg).table())
        return 0
    df, runner = serial.run(cfg, log=lambda m: print(m, file=sys.stderr), started=STARTED)
    print(runner.summary())
    print(f"results: {runner.run_dir / 'results.csv'}")
    return options.nothing_useful(runner)
