"""Regression history: every method's time and error over commits, and the steps in them.

`build_history(run folders)` reads each run folder's manifest (commit, date, machine) and rows
with the gate's loader (bench.gate.load), orders the commits (git ancestry where the repository
is at hand, else the date of each commit's first run), and builds one series per (scene, view,
method, ladder rung as declared, seed, resolution, metric): a rung is its declared override
(`{}` for the defaults), so a changed default is a step of the defaults' series. Timing series
are per machine fingerprint, relative to the machine's state in each run (its index, or
`relative_to`'s time), and each machine's index is a series of its own whose steps are reported
as machine-wide; error series are machine-independent. Each series is fitted with a penalised
piecewise-constant function (bench.history.steps, after asv's step detection); each step has the
commit range where it happened, its size with a 95% interval, an adjusted p-value and the rows it
affects. `History.check_exit_code` is 1 when the newest commit starts a regression.

Modules: `load` (run folders, rungs, machine fingerprints, commit order), `steps` (the fit),
`series` (the points and their noise), `changes` (change points, History), `presentation` (text
and Markdown). The dashboard is reports/history.py; the commands bench/cli/history.py and
bench/cli/bisect.py. This package reads run folders and never runs the benchmark (no bench.run,
bench.gl, methods or reports: tests/test_history.py checks it).
"""
from bench.history.changes import Change, History, build_history

__all__ = ["Change", "History", "build_history"]
