"""`gibench bisect GOOD BAD --scenes ... --methods ...`: the first commit of a step between two commits.

GOOD and BAD are run first; the step to find is, as `asv find` does it, the largest rise between
them among the series of their history (bench.history: time relative to the machine, or an
error), above the thresholds (two runs cannot measure their own noise, so no test decides it:
the user says a step is there). Then the
commits of the ancestry path GOOD..BAD are bisected: each probe is run, and lands on the side whose
fitted level its value is nearer (on the series' scale: log time, or the error), until the first
commit at the new level is found. Every run goes to `--out` (one folder per commit and
repetition), so the bisection's runs are a history of their own.

Each probed commit is checked out as a git worktree (`git worktree add --detach`, removed at the
end) and benchmarked by `python -m bench.cli run` in a child process whose PYTHONPATH is that
worktree: the throw-away environment is the worktree plus this interpreter's installed packages.
Chosen over a venv per commit (`python -m venv --system-site-packages` + `pip install --no-deps
--no-build-isolation -e`): a venv made from a venv's interpreter sees the *base* interpreter's
site-packages, not the project environment's (moderngl, pandas, mitsuba: checked here), so it
would need them installed again, and the editable install costs seconds per probe for nothing the run uses. The
limit: method entry points are those of the installed gibench, so a commit that adds a method
(or a dependency) between GOOD and BAD needs that method installed to be probed. The runs pass
`--force` (a row cache hit has no timing of its own) and `--workers` / `--scheduler` through.

This module runs the benchmark (in child processes) and so belongs with the command line, not
with bench.history, which only reads run folders.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.cli import options
from bench.cli.gate import error_columns
from bench.history import build_history
from bench.history.load import git, git_repository, resolve_commit
from bench.history.presentation import short


def add_parser(sub) -> None:
    p = sub.add_parser("bisect", help="find the first commit of a step between GOOD and BAD (runs each probe)")
    p.add_argument("good", help="a commit before the step")
    p.add_argument("bad", help="a commit after the step (GOOD must be its ancestor)")
    p.add_argument("--scenes", type=options.scene_list, required=True)
    p.add_argument("--methods", type=options.method_list, required=True)
    p.add_argument("--views", type=options.view_list, default=None)
    p.add_argument("--res", type=options.resolution, default=options.DEFAULT_RESOLUTION)
    p.add_argument("--frames", type=options.int_in(*options.FRAMES_RANGE), default=3)
    p.add_argument("--error-frames", type=options.int_in(*options.ERROR_FRAMES_RANGE), default=None, metavar="K")
    p.add_argument("--timing-budget", type=options.float_in(*options.TIMING_BUDGET_RANGE_S), default=None,
                   metavar="SECONDS")
    p.add_argument("--no-reference", action="store_true", help="time only (no references, no error series)")
    p.add_argument("--defaults-only", action="store_true", help="each method at its defaults only")
    p.add_argument("--repeat", type=options.int_in(1, 20), default=1, help="runs per probed commit (default 1)")
    p.add_argument("--workers", type=options.workers, default=None, metavar="N")
    p.add_argument("--scheduler", type=options.non_empty, default=None, metavar="ADDRESS")
    p.add_argument("--repo", type=options.non_empty, default=".", metavar="DIR",
                   help="the git repository (default: the current folder's)")
    p.add_argument("--out", type=options.non_empty, default=None, metavar="DIR",
                   help="where the runs go (default runs/bisect-<timestamp>)")
    p.add_argument("--relative-to", default=None, metavar="METHOD")
    p.add_argument("--metric", type=error_columns, default=None, metavar="COLUMN[,COLUMN...]")
    p.add_argument("--time-threshold", type=options.float_in(0.0, 100.0), default=0.10)
    p.add_argument("--error-threshold", type=options.float_in(0.0, 100.0), default=0.05)
    p.add_argument("--alpha", type=options.float_in(0.0, 1.0, low_open=True, high_open=True), default=0.05)
    p.set_defaults(func=main)


def run_arguments(args, out: Path) -> list[str]:
    """The `gibench run` command line of one probe."""
    argv = ["run", "--scenes", ",".join(args.scenes), "--methods", ",".join(args.methods),
            "--res", f"{args.res[0]}x{args.res[1]}", "--frames", str(args.frames), "--out", str(out), "--force",
            "--no-progress"]
    for flag, value in (("--views", ",".join(args.views) if args.views else None),
                        ("--error-frames", args.error_frames), ("--timing-budget", args.timing_budget),
                        ("--workers", args.workers), ("--scheduler", args.scheduler)):
        if value is not None:
            argv += [flag, str(value)]
    argv += ["--no-reference"] if args.no_reference else []
    argv += ["--defaults-only"] if args.defaults_only else []
    return argv


class Prober:
    """Runs the benchmark at commits, each in its own worktree (removed by `close`)."""

    def __init__(self, repo: Path, out: Path, args, log):
        self.repo, self.out, self.args, self.log = repo, out, args, log
        self.trees = Path(tempfile.mkdtemp(prefix="gibench-bisect-"))
        self.runs: dict = {}   # commit -> [run folders]

    def run(self, commit: str) -> list[Path]:
        if commit in self.runs:
            return self.runs[commit]
        tree = self.trees / commit[:12]
        git(self.repo, "worktree", "add", "--detach", str(tree), commit)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree)] + [p for p in os.environ.get(
            "PYTHONPATH", "").split(os.pathsep) if p and Path(p).resolve() != Path(__file__).resolve().parents[2]]))
        folders = []
        for repetition in range(self.args.repeat):
            folder = self.out / f"{len(self.runs):02d}-{commit[:10]}" / f"run{repetition}"
            t0 = time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "bench.cli", *run_arguments(self.args, folder)], cwd=tree,
                                  env=env, capture_output=True, text=True, check=False)
            if done.returncode != 0:   # 1: every row failed, 2: bad input at that commit
                tail = " ".join((done.stderr.strip().splitlines() or ["no message"])[-1].split())
                raise ValueError(f"the run at {short(commit)} failed (exit {done.returncode}): {tail}")
            self.log(f"gibench bisect: ran {short(commit)} in {time.perf_counter() - t0:.1f} s -> {folder}")
            folders.append(folder)
        self.runs[commit] = folders
        return folders

    def close(self) -> None:
        for tree in sorted(self.trees.iterdir()):
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=self.repo, capture_output=True,
                           check=False)
        subprocess.run(["git", "worktree", "prune"], cwd=self.repo, capture_output=True, check=False)
        try:
            self.trees.rmdir()
        except OSError:
            pass


def _history(prober: Prober, repo: Path, args):
    folders = [f for runs in prober.runs.values() for f in runs]
    return build_history(folders, repo=repo, relative_to=args.relative_to, metrics=args.metric,
                         time_threshold=args.time_threshold, error_threshold=args.error_threshold, alpha=args.alpha)


def _value_at(history, target, commit: str) -> float:
    for series in history.series:
        if (series.kind, series.metric, series.row, series.machine) == target:
            for point in series.points:
                if point.commit == commit:
                    return point.value
    raise ValueError(f"the run at {short(commit)} has no value for the step's series: cannot place it")


def largest_rise(history, good: str, bad: str, args) -> tuple:
    """The key of the series that rose most from GOOD to BAD beyond its threshold (log time relative
    to the machine; an error's relative change); ValueError when none did."""
    best, best_rise = None, 0.0
    for series in history.series:
        if series.kind == "machine":
            continue
        key = (series.kind, series.metric, series.row, series.machine)
        try:
            before, after = _value_at(history, key, good), _value_at(history, key, bad)
        except ValueError:
            continue
        if series.log_scale:
            rise, enough = after - before, math.exp(after - before) > 1 + args.time_threshold
        else:
            rise = (after - before) / before if before > 0 else (math.inf if after > before else 0.0)
            enough = rise > args.error_threshold
        if enough and rise > best_rise:
            best, best_rise = key, rise
    if best is None:
        raise ValueError(f"no series rose from {short(good)} to {short(bad)} beyond the thresholds "
                         f"(time {args.time_threshold:.0%}, error {args.error_threshold:.0%})")
    return best


def _label(history, key) -> str:
    return next(s.row_label for s in history.series if (s.kind, s.metric, s.row, s.machine) == key)


def bisect(repo: Path, good: str, bad: str, args, log=print) -> tuple[str, list]:
    """(first commit of the step, [(commit, value, side)]) between ancestor `good` and `bad`."""
    candidates = git(repo, "rev-list", "--ancestry-path", "--reverse", f"{good}..{bad}").split()
    out = Path(args.out) if args.out else Path("runs") / time.strftime("bisect-%Y%m%d-%H%M%S")
    prober = Prober(repo, out.resolve(), args, log)
    try:
        prober.run(good)
        prober.run(bad)
        history = _history(prober, repo, args)
        key = largest_rise(history, good, bad, args)
        log(f"gibench bisect: looking for the rise of {key[1]} of {_label(history, key)}")
        probes = []
        low, high = -1, len(candidates) - 1   # candidates[high] is at the new level; low at the old (GOOD)
        while high - low > 1:
            middle = (low + high) // 2
            commit = candidates[middle]
            prober.run(commit)
            history = _history(prober, repo, args)   # levels again: the machine index moves as runs are added
            value, old_level, new_level = (_value_at(history, key, c) for c in (commit, good, bad))
            at_new = abs(value - new_level) < abs(value - old_level)
            probes.append((commit, value, "new level" if at_new else "old level"))
            log(f"gibench bisect: {short(commit)}: {'new' if at_new else 'old'} level")
            if at_new:
                high = middle
            else:
                low = middle
        return candidates[high], probes
    finally:
        prober.close()


def main(args) -> int:
    options.one_cluster(args.workers, args.scheduler)
    if not options.known_methods(args.methods):
        return 2
    repo = git_repository(Path(args.repo))
    if repo is None:
        options.refuse(f"--repo {args.repo} is not in a git repository")
    good, bad = resolve_commit(repo, args.good), resolve_commit(repo, args.bad)
    for name, sha in ((args.good, good), (args.bad, bad)):
        if sha is None:
            options.refuse(f"unknown commit {name!r} in {repo}")
    if good == bad:
        options.refuse(f"GOOD and BAD are the same commit ({short(good)})")
    if subprocess.run(["git", "merge-base", "--is-ancestor", good, bad], cwd=repo, check=False).returncode != 0:
        options.refuse(f"GOOD {args.good} ({short(good)}) is not an ancestor of BAD {args.bad} ({short(bad)})")
    first, probes = bisect(repo, good, bad, args, log=lambda m: print(m, file=sys.stderr))
    subject = git(repo, "log", "-1", "--format=%s", first).strip()
    for commit, value, side in probes:
        print(f"probe {short(commit)}: {side} ({value:.4g})")
    print(f"first commit of the step: {first} {subject}")
    return 0
