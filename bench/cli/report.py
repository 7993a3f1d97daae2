"""`gibench report RUN`: the static HTML report of a run folder (or of a stress run).

The report reads the run and writes only its output folder (`--out`, default `<run>/report`):
a run folder may be read-only, or another run's; its manifest is never touched. An output
folder that cannot be written is bad input, found before any work.
"""
from __future__ import annotations

import sys
from pathlib import Path

from bench.cli import options
from bench.protocol.results import run_progress
from bench.run.plan import prepare_run_dir


def add_parser(sub) -> None:
    p = sub.add_parser("report", help="build the HTML report of a run")
    p.add_argument("run", help="run folder (e.g. runs/latest)")
    p.add_argument("--out", type=options.non_empty, default=None, help="output folder (default RUN/report)")
    p.set_defaults(func=main)


def writable_folder(out_dir: Path, given: bool) -> None:
    """Create `out_dir` and check that it takes files; ValueError (one line) when it does not."""
    try:
        prepare_run_dir(out_dir)
    except ValueError:
        if given:
            raise
        raise ValueError(f"cannot write the report to {out_dir} (a read-only run folder?); give --out DIR") from None


def main(args) -> int:
    run_dir = Path(args.run)
    if not any((run_dir / f).is_file() for f in ("results.csv", "results.parquet", "stress.csv")):
        progress = run_progress(run_dir)
        why = f"no rows yet, {progress.describe()}" if not progress.complete else "no results.csv or stress.csv"
        print(f"gibench: {run_dir} is not a run folder with rows ({why})", file=sys.stderr)
        return 2
    try:
        from reports import build_report   # optional: without it the quick summary stands in
    except ImportError:
        from bench.analysis.summary import write_summary
        _, path = write_summary(run_dir)
    else:
        is_stress = (run_dir / "stress.csv").is_file() and not (run_dir / "results.csv").is_file()
        out_dir = Path(args.out) if args.out else (run_dir if is_stress else run_dir / "report")
        writable_folder(out_dir, given=bool(args.out))
        path = build_report(run_dir, out_dir)
    print(f"report: {path}")
    return 0
