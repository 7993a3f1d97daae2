"""`gibench stress`: the numerical stability stress suite (bench.stress); exit 1 when a row fails."""
from __future__ import annotations

import sys
from pathlib import Path

from bench.cli import options
from bench.stress.isolate import CASE_TIMEOUT_S
from bench.stress.suite import STRESS_SCENES, StressConfig, run_stress, summary_text


def add_parser(sub) -> None:
    p = sub.add_parser("stress", help="numerical stability stress suite: perturbed scenes, parameter extremes, fuzzing")
    p.add_argument("--scenes", default=None, help="corpus names or .toml scene files, comma-separated "
                                                  "(default: the procedural scenes of bench.stress.suite.STRESS_SCENES)")
    p.add_argument("--methods", default=",".join(options.DEFAULT_METHODS))
    p.add_argument("--views", default=None, help="camera to perturb, first found per scene (default: main)")
    p.add_argument("--res", type=options.resolution, default=None, help="WxH (default 64x48; 32x24 with --quick)")
    p.add_argument("--quick", action="store_true", help="the CI subset: few perturbations, 32x24, 16 spp references")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="run folder (default runs/stress-<timestamp>)")
    p.add_argument("--no-reference", action="store_true", help="skip the Mitsuba references (no reference rows, no error)")
    p.add_argument("--reference-spp", type=int, default=None, help="reference samples per pixel (default 64; 16 with --quick)")
    p.add_argument("--isolate", choices=("none", "params", "all"), default=None,
                   help="cases run in a child process with a timeout (default: params; none with --quick)")
    p.add_argument("--timeout", type=float, default=CASE_TIMEOUT_S, help="seconds per isolated case")
    p.add_argument("--fuzz-examples", type=int, default=None, help="hypothesis examples (default 500; 50 with --quick)")
    p.add_argument("--only", default=None, help="perturbation families, comma-separated (default: all of "
                                                "determinism,scale,translate,degenerate,grazing,params,invalid,fuzz)")
    p.set_defaults(func=main)


def main(args) -> int:
    methods = options.csv(args.methods)
    if not options.known_methods(methods):
        return 2
    width, height = args.res if args.res else (None, None)
    cfg = StressConfig(scenes=options.csv(args.scenes) if args.scenes else list(STRESS_SCENES), methods=methods,
                       width=width, height=height, quick=args.quick, out=Path(args.out) if args.out else None,
                       seed=args.seed, views=options.csv(args.views) if args.views else None,
                       references=not args.no_reference, reference_spp=args.reference_spp, isolate=args.isolate,
                       case_timeout=args.timeout, fuzz_examples=args.fuzz_examples,
                       families=options.csv(args.only) if args.only else None)
    df, suite = run_stress(cfg, log=lambda m: print(m, file=sys.stderr))
    print(summary_text(df))
    print(f"stress table: {suite.run_dir / 'stress.csv'}")
    try:
        from reports.stress import build_stress_report   # optional: the table stands without the page
    except ImportError:
        return 1 if (df["verdict"] == "fail").any() else 0
    print(f"stress report: {build_stress_report(suite.run_dir)}")
    return 1 if (df["verdict"] == "fail").any() else 0
