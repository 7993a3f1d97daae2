"""`gibench gate BASELINE CANDIDATE`: exit 1 on a regression of time or error (bench.gate)."""
from __future__ import annotations

import argparse

from bench.cli import options
from bench.gate import compare_runs
from bench.gate.statistics import check_error_column


def add_parser(sub) -> None:
    p = sub.add_parser("gate", help="compare two runs; non-zero exit on a regression")
    p.add_argument("baseline", help="run folder, or comma-separated run folders (repetitions; timing needs >= 3)")
    p.add_argument("candidate", help="run folder, or comma-separated run folders (interleave them with the baseline's)")
    p.add_argument("--time-threshold", type=options.float_in(0.0, 100.0), default=0.10)
    p.add_argument("--error-threshold", type=options.float_in(0.0, 100.0), default=0.05)
    p.add_argument("--alpha", type=options.float_in(0.0, 1.0, low_open=True, high_open=True), default=0.05)
    p.add_argument("--compare-changed-versions", action="store_true",
                   help="also compare rows whose method version changed (a PR editing a method), marked 'method changed'")
    p.add_argument("--relative-to", default=None, metavar="METHOD",
                   help="gate times relative to METHOD's time on the same view in the same run (cancels machine load)")
    p.add_argument("--correction", choices=("holm", "bh"), default="holm",
                   help="multiple-testing correction over rows: holm (family-wise error, default) or bh (FDR)")
    p.add_argument("--min-runs", type=options.int_in(2, 1000), default=3, help="runs per side needed to test timing (default 3, >= 2)")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="compare a run that did not finish (interrupted or still running) instead of refusing it; "
                        "the verdict says so")
    p.add_argument("--metric", type=error_columns, default=None, metavar="COLUMN[,COLUMN...]",
                   help="gate errors on these columns only (any error column: mse.indirect, relmse.combined, "
                        "bias2.indirect, variance.indirect, ...; default: every error column both sides have)")
    p.set_defaults(func=main)


def error_columns(text: str) -> list[str]:
    """--metric: comma-separated error columns (bench.gate.statistics.check_error_column)."""
    items = options.csv(text)
    if not items:
        raise argparse.ArgumentTypeError("no error column given")
    try:
        return [check_error_column(item) for item in items]
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def main(args) -> int:
    result = compare_runs(options.csv(args.baseline), options.csv(args.candidate), time_threshold=args.time_threshold,
                          error_threshold=args.error_threshold, alpha=args.alpha,
                          compare_changed_versions=args.compare_changed_versions, relative_to=args.relative_to,
                          correction=args.correction, min_runs=args.min_runs,
                          allow_incomplete=args.allow_incomplete, metrics=args.metric)
    print(result.markdown())
    return result.exit_code
