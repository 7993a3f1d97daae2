"""How often the history's step detection raises a false alarm: runs of unchanged code under
background load (issue #26: "goal: no alarm").

A throw-away git repository of the project (tests/test_history.py's `copy_project`) gets N commits
that change no code (empty commits); each is run with the end-to-end test's tiny arguments
(cornell_spot 32x24, direct + ir_unshadowed + manylights at their defaults, no references), and
about half of the runs, chosen at random, with background load: --load-processes processes spinning
on the CPU for the whole run (the machine is also shared with whatever else runs on it). Then:

* alarms of the whole history: the method regressions and improvements `gibench history` reports
  over the N commits (machine-wide steps are counted apart: they are what load is);
* alarms of `--check` as CI would run it after each commit: for k = 2..N, whether the history of
  the first k commits has its newest commit starting a regression.

    python -m studies.history_false_alarms [--runs 10] [--load-processes 1] [--out /tmp/history-false-alarms]

prints the figures and writes them to OUT/false_alarms.json, the runs to OUT/runs.
"""
from __future__ import annotations

import argparse
import json
import random
import subprocess
import sys
import time
from pathlib import Path

from bench.history import build_history
from tests.test_history import copy_project, git_as_author, run_at

LOAD_PROCESSES = 1   # default: of the machine's 2 cores, the other stays for the run (and the machine's other jobs)


def spin() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m studies.history_false_alarms",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path("/tmp/history-false-alarms"))
    parser.add_argument("--seed", type=int, default=26)
    parser.add_argument("--load-processes", type=int, default=LOAD_PROCESSES, help="CPU spinners during a loaded run")
    args = parser.parse_args(argv)
    out = args.out
    if out.exists():
        raise SystemExit(f"{out} exists: give a new --out")
    repo = out / "repo"
    copy_project(repo)
    chooser = random.Random(args.seed)
    loaded, runs = [], []
    t0 = time.perf_counter()
    for i in range(args.runs):
        if i:
            git_as_author(repo, "commit", "-q", "--allow-empty", "-m", f"unchanged code {i}")
        commit = git_as_author(repo, "rev-parse", "HEAD")
        under_load = chooser.random() < 0.5
        spinners = [spin() for _ in range(args.load_processes)] if under_load else []
        try:
            folder = out / "runs" / f"{i:02d}-{commit[:8]}"
            run_at(repo, folder, out / "cache")
        finally:
            for process in spinners:
                process.kill()
                process.wait()
        loaded.append(under_load)
        runs.append(folder)
        print(f"run {i}: {commit[:10]} {'under load' if under_load else 'no added load'}", file=sys.stderr)
    history = build_history(runs, repo=repo)
    method_alarms = [c for c in history.changes if not c.machine_wide]
    machine_steps = [c for c in history.changes if c.machine_wide]
    check_alarms = [k for k in range(2, args.runs + 1)
                    if build_history(runs[:k], repo=repo).check_exit_code != 0]
    result = {"runs": args.runs, "under_load": loaded, "load_processes": args.load_processes,
              "series": len(history.series),
              "method_alarms": [f"{c.series.label}: {c.verdict}" for c in method_alarms],
              "machine_wide_steps": len(machine_steps), "check_alarms_at": check_alarms,
              "check_evaluations": args.runs - 1, "seconds": round(time.perf_counter() - t0, 1)}
    (out / "false_alarms.json").write_text(json.dumps(result, indent=1))
    print(history.text())
    print(f"method alarms over the history: {len(method_alarms)} in {len(history.series)} series; machine-wide steps: "
          f"{len(machine_steps)}; --check alarms: {len(check_alarms)} of {args.runs - 1} evaluations")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
