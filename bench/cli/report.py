"""`gibench report RUN`: the static HTML report of a run folder (or of a stress run)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from bench.run.manifest import record_phase


def add_parser(sub) -> None:
    p = sub.add_parser("report", help="build the HTML report of a run")
    p.add_argument("run", help="run folder (e.g. runs/latest)")
    p.add_argument("--out", default=None)
    p.set_defaults(func=main)


def main(args) -> int:
    run_dir = Path(args.run)
    if not any((run_dir / f).is_file() for f in ("results.csv", "results.parquet", "stress.csv")):
        print(f"gibench: {run_dir} is not a run folder (no results.csv or stress.csv)", file=sys.stderr)
        return 2
    try:
        from reports import build_report   # optional: without it the quick summary stands in
    except ImportError:
        from bench.analysis.summary import write_summary
        _, path = write_summary(run_dir)
    else:
        t0 = time.perf_counter()
        path = build_report(run_dir, Path(args.out) if args.out else None)
        record_phase(run_dir, "report", time.perf_counter() - t0)
    print(f"report: {path}")
    return 0
