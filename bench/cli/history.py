"""`gibench history RUNS... | --store DIR`: every method's time and error over commits, the steps in
them (bench.history), a static dashboard (reports/history.py); `--check` exits 1 when the newest
commit starts a regression (the CI form)."""
from __future__ import annotations

from pathlib import Path

from bench.cli import options
from bench.cli.gate import error_columns
from bench.history import build_history
from bench.history.load import git_repository, store_run_folders


def add_parser(sub) -> None:
    p = sub.add_parser("history", help="time and error over commits: change points, dashboard, --check for CI")
    p.add_argument("runs", nargs="*", help="run folders (or give --store)")
    p.add_argument("--store", type=options.non_empty, default=None, metavar="DIR",
                   help="read every run folder below DIR (runs/, a CI artefact store)")
    p.add_argument("--repo", type=options.non_empty, default=None, metavar="DIR",
                   help="git repository to order the commits by ancestry (default: the one holding the first run "
                        "folder; without one, commits are ordered by date)")
    p.add_argument("--out", type=options.non_empty, default=None, metavar="DIR",
                   help="write the dashboard (index.html, regressions.html, regressions.md, regressions.txt) into DIR")
    p.add_argument("--format", choices=("text", "markdown"), default="text", help="what to print (default text)")
    p.add_argument("--check", action="store_true", help="exit 1 when the newest commit starts a regression")
    p.add_argument("--relative-to", default=None, metavar="METHOD",
                   help="take times relative to METHOD's on the same view in the same run (default: relative to "
                        "the run's machine index, the median over its rows)")
    p.add_argument("--metric", type=error_columns, default=None, metavar="COLUMN[,COLUMN...]",
                   help="error series of these columns only (default: every error column)")
    p.add_argument("--time-threshold", type=options.float_in(0.0, 100.0), default=0.10,
                   help="a timing step is a regression above this relative change (default 0.10, the gate's)")
    p.add_argument("--error-threshold", type=options.float_in(0.0, 100.0), default=0.05,
                   help="an error step is a regression above this relative change (default 0.05, the gate's)")
    p.add_argument("--alpha", type=options.float_in(0.0, 1.0, low_open=True, high_open=True), default=0.05,
                   help="significance of a step after Holm's correction over every step of the history")
    p.set_defaults(func=main)


def history_paths(runs, store) -> list[Path]:
    """The run folders: those given, or those found below --store (not both, at least one)."""
    if runs and store:
        options.refuse("give run folders or --store DIR, not both")
    if not runs and not store:
        options.refuse("give run folders or --store DIR")
    return store_run_folders(Path(store)) if store else [Path(r) for r in runs]


def main(args) -> int:
    paths = history_paths(args.runs, args.store)
    repo = None
    if args.repo:
        repo = git_repository(Path(args.repo))
        if repo is None:
            options.refuse(f"--repo {args.repo} is not in a git repository")
    history = build_history(paths, repo=repo, relative_to=args.relative_to, metrics=args.metric,
                            time_threshold=args.time_threshold, error_threshold=args.error_threshold, alpha=args.alpha)
    print(history.markdown() if args.format == "markdown" else history.text(), end="")
    if args.out:
        # the report package (matplotlib, Jinja2) is imported only when a dashboard is asked for
        from reports.history import build_dashboard
        print(f"dashboard: {build_dashboard(history, Path(args.out))}")
    return history.check_exit_code if args.check else 0
