"""`gibench stress`: the numerical stability stress suite (bench.stress); exit 1 when a row fails."""
from __future__ import annotations

import sys
from pathlib import Path

from bench.cli import options
from bench.stress.isolate import CASE_TIMEOUT_S
from bench.stress.suite import FAMILIES, STRESS_SCENES, StressConfig, run_stress, summary_text


def add_parser(sub) -> None:
    p = sub.add_parser("stress", help="numerical stability stress suite: perturbed scenes, parameter extremes, fuzzing")
    p.add_argument("--scenes", type=options.scene_list, default=None,
                   help="corpus names or .toml scene files, comma-separated "
                        "(default: the procedural scenes of bench.stress.suite.STRESS_SCENES)")
    p.add_argument("--methods", type=options.method_list, default=",".join(options.DEFAULT_METHODS))
    p.add_argument("--views", type=options.view_list, default=None,
                   help="camera to perturb, first found per scene (default: main)")
    p.add_argument("--res", type=options.resolution, default=None, help="WxH (default 64x48; 32x24 with --quick)")
    p.add_argument("--quick", action="store_true", help="the CI subset: few perturbations, 32x24, 16 spp references")
    p.add_argument("--seed", type=options.seed, default=0)
    p.add_argument("--out", type=options.non_empty, default=None,
                   help="run folder (default runs/stress-<timestamp>)")
    p.add_argument("--no-reference", action="store_true", help="skip the Mitsuba references (no reference rows, no error)")
    p.add_argument("--reference-spp", type=options.reference_spp, default=None,
                   help="reference samples per pixel (default 64; 16 with --quick)")
    p.add_argument("--isolate", choices=("none", "params", "all"), default=None,
                   help="cases run in a child process with a timeout (default: params; none with --quick)")
    p.add_argument("--timeout", type=options.float_in(*options.CASE_TIMEOUT_RANGE_S, low_open=True),
                   default=CASE_TIMEOUT_S, help="seconds per isolated case (default %g)" % CASE_TIMEOUT_S)
    p.add_argument("--fuzz-examples", type=options.int_in(*options.FUZZ_EXAMPLES_RANGE), default=None,
                   help="hypothesis examples (default 500; 50 with --quick)")
    p.add_argument("--only", type=options.name_list("family", choices=FAMILIES), default=None,
                   help="perturbation families, comma-separated (default: all of " + ",".join(FAMILIES) + ")")
    p.set_defaults(func=main)


def main(args) -> int:
    methods = args.methods
    if not options.known_methods(methods):
        return 2
    width, height = args.res if args.res else (None, None)
    cfg = StressConfig(scenes=args.scenes or list(STRESS_SCENES), methods=methods, width=width, height=height,
                       quick=args.quick, out=Path(args.out) if args.out else None, seed=args.seed, views=args.views,
                       references=not args.no_reference, reference_spp=args.reference_spp, isolate=args.isolate,
                       case_timeout=args.timeout, fuzz_examples=args.fuzz_examples, families=args.only)
    df, suite = run_stress(cfg, log=lambda m: print(m, file=sys.stderr))
    print(summary_text(df))
    print(f"stress table: {suite.run_dir / 'stress.csv'}")
    try:
        from reports.stress import build_stress_report   # optional: the table stands without the page
    except ImportError:
        return 1 if (df["verdict"] == "fail").any() else 0
    print(f"stress report: {build_stress_report(suite.run_dir)}")
    return 1 if (df["verdict"] == "fail").any() else 0
