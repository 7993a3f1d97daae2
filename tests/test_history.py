"""Regression history (bench.history, `gibench history`, `gibench bisect`, the dashboard).

The step detection on synthetic series (a step at its index with its size; none in pure noise),
the rung a row ran as declared, error series, the package's import rule, and end to end: a small
git repository of the project whose third commit slows `direct` (40 ms of CPU work in its render:
a sleep would not slow down under load as the other methods do), run at
each commit (tiny runs), whose history reports exactly that step, `--check` exiting 1 there and 0
one commit earlier, and `gibench bisect` finding the commit. The dashboard is opened in headless
Chromium when GIBENCH_BROWSER=1.
"""
from __future__ import annotations

import datetime as _dt
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pytest

from bench.history.changes import build_history, detect_changes
from bench.history.load import HistoryRun, row_rung
from bench.history.series import error_series
from bench.history.steps import (
    PENALTY,
    detect_steps,
    segment_costs,
    solve_potts,
    weighted_median,
)

ROOT = Path(__file__).resolve().parents[1]
ENV = {"DRJIT_LIBLLVM_PATH": os.environ.get("DRJIT_LIBLLVM_PATH", "/usr/lib/x86_64-linux-gnu/libLLVM-19.so")}
METHODS = "direct,ir_unshadowed,manylights"
RUN_ARGS = ["--scenes", "cornell_spot", "--methods", METHODS, "--defaults-only", "--res", "32x24", "--frames", "3",
            "--error-frames", "1", "--no-reference", "--timing-budget", "0.2"]


# ---------------------------------------------------------------------------- the step detection
def test_a_step_is_found_at_its_index_with_its_size():
    rng = np.random.default_rng(3)
    values = np.r_[rng.normal(0.0, 0.1, 12), rng.normal(0.5, 0.1, 9)]
    steps = detect_steps(values, np.full(values.size, 0.1))
    assert len(steps) == 1
    step = steps[0]
    assert (step.before_index, step.after_index) == (11, 12)
    low, high = step.interval()
    assert low < 0.5 < high and abs(step.size - 0.5) < 0.15
    assert step.p_up < 1e-6 and step.p_down > 0.5


def test_a_single_newest_point_far_off_is_a_step_of_its_own():
    values = np.r_[np.zeros(5), 2.0]
    steps = detect_steps(values, np.full(6, 0.1))
    assert [(s.before_index, s.after_index) for s in steps] == [(4, 5)]


def test_pure_noise_has_no_step():
    """Series of pure noise of known sigma: the fit stays flat in at least 99% of them (PENALTY's
    calibration), and the history's detection reports none of them."""
    from bench.history.series import Point, Series
    rng = np.random.default_rng(7)
    with_steps, all_series = 0, []
    for trial in range(120):
        values = rng.normal(0.0, 1.0, int(rng.integers(3, 30)))
        with_steps += bool(detect_steps(values, np.ones(values.size), PENALTY))
        all_series.append(Series("error", "relmse.indirect", ("s", "v", str(trial), "{}", 0, 8, 8), points=[
            Point(i, f"c{i}", 10.0 + v, 1.0, 10.0 + v) for i, v in enumerate(values)]))
    assert with_steps <= 1
    assert detect_changes(all_series) == []


def test_segment_costs_are_those_of_the_weighted_median():
    rng = np.random.default_rng(5)
    values, weights = rng.normal(0.0, 1.0, 9), rng.uniform(0.5, 2.0, 9)
    weights[:4] = 1.0   # equal weights: even-length segments take the mean of the two middle values
    cost, level = segment_costs(values, weights)
    for left in range(9):
        for right in range(left, 9):
            m = weighted_median(values[left:right + 1], weights[left:right + 1])
            assert level[left, right] == pytest.approx(m)
            assert cost[left, right] == pytest.approx(np.sum(weights[left:right + 1] *
                                                             np.abs(values[left:right + 1] - m)))


def test_the_fit_is_one_level_per_segment():
    segments = solve_potts([1.0, 1.0, 1.0, 3.0, 3.0], [0.01] * 5)
    assert [(s.start, s.stop, s.level) for s in segments] == [(0, 3, 1.0), (3, 5, 3.0)]
    with pytest.raises(ValueError, match="sigmas"):
        solve_potts([1.0, 2.0], [0.1, 0.0])


# ---------------------------------------------------------------------------- rungs, errors
def _manifest(defaults: dict, ladder: list, params=None) -> dict:
    return {"arguments": {"ladders": True, "params": params or {}},
            "methods": {"m": {"defaults": defaults, "ladder": ladder}}}


def test_a_rung_is_its_declared_override_so_a_changed_default_stays_in_its_series():
    ladder = [{"n": 4}, {}, {"n": 64, "k": 2}]
    before = _manifest({"n": 16, "k": 2}, ladder)
    after = _manifest({"n": 32, "k": 2}, ladder)   # a commit changed the default n
    assert row_rung({"method": "m", "params": '{"k":2,"n":16}'}, before) == "{}"
    assert row_rung({"method": "m", "params": '{"k":2,"n":32}'}, after) == "{}"
    assert row_rung({"method": "m", "params": '{"k":2.0,"n":64}'}, after) == '{"k":2,"n":64}'
    # a --param set is the declared override; a row of another invocation falls back to the difference
    assert row_rung({"method": "m", "params": '{"k":2,"n":8}'}, _manifest({"n": 16, "k": 2}, ladder,
                                                                            {"m": [{"n": 8}]})) == '{"n":8}'
    assert row_rung({"method": "m", "params": '{"k":3,"n":16}'}, before) == '{"k":3}'
    assert row_rung({"method": "m", "params": "{}", "rung": '{"n":4}'}, before) == '{"n":4}'


def _error_run(commit: str, position: int, value: float) -> HistoryRun:
    row = {"scene": "s", "view": "v", "method": "m", "params": "{}", "seed": 0, "width": 8, "height": 8,
           "status": "ok", "rung": "{}", "relmse.indirect": value, "method_version": "a" * 8}
    return HistoryRun(Path(f"/runs/{commit}"), commit, _dt.datetime(2026, 1, 1 + position, tzinfo=_dt.UTC),
                      "machine", "cpu", [row], Path(f"/runs/{commit}/summary.html"))


def test_error_series_find_a_step_beyond_the_gates_threshold_and_not_below():
    values = [0.10, 0.10, 0.10, 0.13, 0.13]
    runs = [_error_run(f"c{i}", i, v) for i, v in enumerate(values)]
    series = error_series(runs, {f"c{i}": i for i in range(5)})
    assert [s.metric for s in series] == ["relmse.indirect"]
    changes = detect_changes(series)
    assert [(c.verdict, c.commit_before, c.commit_after) for c in changes] == [("regression", "c2", "c3")]
    assert abs(changes[0].change - 0.3) < 1e-9
    small = [_error_run(f"c{i}", i, v) for i, v in enumerate([0.10, 0.10, 0.10, 0.102, 0.102])]
    assert detect_changes(error_series(small, {f"c{i}": i for i in range(5)})) == []


# ---------------------------------------------------------------------------- the import rule
def test_the_history_reads_run_folders_and_never_runs_the_benchmark():
    from tests.test_architecture import _imports, _module_of, _source_files, _violations
    graph = {_module_of(p): _imports(p) for p in _source_files()}
    assert any(m.startswith("bench.history") for m in graph)
    assert _violations(graph, "bench.history", forbidden=("bench.run", "bench.gl", "bench.stress", "bench.cli",
                                                          "methods", "reports")) == []


# ---------------------------------------------------------------------------- end to end
def git_as_author(repo: Path, *args: str) -> str:
    """A git command in a throw-away repository, as a fixed author."""
    return subprocess.run(["git", "-c", "user.name=gibench", "-c", "user.email=gibench@example.invalid", *args],
                          cwd=repo, check=True, capture_output=True, text=True).stdout.strip()


def copy_project(repo: Path) -> None:
    """The project as it is in this checkout (uncommitted files too) into a new git repository, one commit."""
    repo.mkdir(parents=True)
    files = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "bench", "methods",
                            "reference", "reports", "pyproject.toml"], cwd=ROOT, check=True, capture_output=True,
                           text=True).stdout.split()
    for name in files:
        if not (ROOT / name).is_file():
            continue
        target = repo / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes((ROOT / name).read_bytes())
    git_as_author(repo, "init", "-q")
    git_as_author(repo, "add", "-A")
    git_as_author(repo, "commit", "-qm", "base")


def run_at(repo: Path, out: Path, cache: Path) -> None:
    """`gibench run` (RUN_ARGS) of the code checked out in `repo` into `out`."""
    env = dict(os.environ, PYTHONPATH=str(repo), GIBENCH_CACHE_DIR=str(cache), **ENV)
    out.parent.mkdir(parents=True, exist_ok=True)
    done = subprocess.run([sys.executable, "-m", "bench.cli", "run", *RUN_ARGS, "--force", "--no-progress",
                           "--out", str(out)], cwd=out.parent, env=env, capture_output=True, text=True, timeout=300,
                          check=False)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.fixture(scope="module")
def project_history(tmp_path_factory):
    """(repo, [commits], {commit: run folder}): base, a no-op, the slow `direct`, a no-op; one run each."""
    root = tmp_path_factory.mktemp("history")
    repo = root / "repo"
    copy_project(repo)
    (repo / "NOTES.txt").write_text("unchanged code\n")
    git_as_author(repo, "add", "-A")
    git_as_author(repo, "commit", "-qm", "a change that changes nothing")
    method = repo / "methods" / "direct" / "method.py"
    text = method.read_text()
    # CPU work, not a sleep: load slows it as it slows every method, so the machine index holds
    busy = ("        import time\n        start = time.process_time()\n"
            "        while time.process_time() - start < 0.04:\n            pass\n")
    slowed = re.sub(r"(    def render\(self, frame, prof\)[^\n]*\n)", lambda m: m.group(1) + busy, text, count=1)
    assert slowed != text
    method.write_text(slowed)
    git_as_author(repo, "commit", "-qam", "slow direct down")
    (repo / "NOTES.txt").write_text("still unchanged code\n")
    git_as_author(repo, "commit", "-qam", "another change that changes nothing")
    commits = git_as_author(repo, "rev-list", "--reverse", "HEAD").split()
    runs = {}
    for i, commit in enumerate(commits):
        git_as_author(repo, "checkout", "-q", commit)
        runs[commit] = root / "runs" / f"{i}-{commit[:8]}"
        run_at(repo, runs[commit], root / "cache")
    git_as_author(repo, "checkout", "-q", commits[-1])
    git_as_author(repo, "checkout", "-q", "-B", "main")
    return repo, commits, runs


@pytest.mark.gl
def test_history_reports_exactly_the_slowed_method_at_its_commit(project_history, tmp_path):
    repo, commits, runs = project_history
    history = build_history([runs[c] for c in commits], repo=repo)
    assert history.ordered_by == "git ancestry" and history.commits == commits
    # machine-wide steps (other jobs' load on a shared machine) may come and go: they are no method's
    method_changes = [c for c in history.changes if not c.machine_wide]
    found = [(c.verdict, c.series.row[2], c.series.metric, c.commit_before, c.commit_after) for c in method_changes]
    assert found == [("regression", "direct", "frame_ms", commits[1], commits[2])], history.text()
    change = method_changes[0]
    assert change.commits_between == 1 and change.interval[0] > 1.5
    assert any("method version changed" in n for n in change.notes)

    from bench.cli import main
    assert main(["history", *map(str, (runs[c] for c in commits[:3])), "--repo", str(repo), "--check"]) == 1
    assert main(["history", *map(str, (runs[c] for c in commits[:2])), "--repo", str(repo), "--check"]) == 0
    out = tmp_path / "dashboard"
    assert main(["history", "--store", str(next(iter(runs.values())).parent), "--repo", str(repo),
                 "--out", str(out), "--format", "markdown"]) == 0
    for name in ("index.html", "regressions.html", "regressions.md", "regressions.txt"):
        assert (out / name).is_file()
    assert commits[2][:10] in (out / "regressions.md").read_text()


@pytest.mark.gl
def test_bisect_finds_the_commit(project_history, tmp_path, capsys, monkeypatch):
    repo, commits, _ = project_history
    monkeypatch.setenv("GIBENCH_CACHE_DIR", str(tmp_path / "cache"))
    for key, value in ENV.items():
        monkeypatch.setenv(key, value)
    from bench.cli import main
    assert main(["bisect", commits[0], commits[-1], "--repo", str(repo), *RUN_ARGS, "--out", str(tmp_path / "b")]) == 0
    assert f"first commit of the step: {commits[2]}" in capsys.readouterr().out
    assert git_as_author(repo, "worktree", "list").count("\n") == 0   # the probes' worktrees are gone
    with pytest.raises(SystemExit) as exc:
        main(["bisect", commits[-1], commits[0], "--repo", str(repo), "--scenes", "cornell_spot",
              "--methods", "direct"])
    assert exc.value.code == 2
    assert "is not an ancestor of BAD" in capsys.readouterr().err


def test_bad_input_is_one_line(tmp_path, capsys):
    from bench.cli import main
    assert main(["history", str(tmp_path / "missing")]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    with pytest.raises(SystemExit):
        main(["history"])
    assert "give run folders or --store DIR" in capsys.readouterr().err
    assert main(["history", "--store", str(tmp_path)]) == 2
    assert "holds no run folder" in capsys.readouterr().err


@pytest.mark.browser
@pytest.mark.gl
def test_dashboard_in_browser(project_history, tmp_path):
    if os.environ.get("GIBENCH_BROWSER") != "1":
        pytest.skip("browser tests run with GIBENCH_BROWSER=1")
    from reports.history import build_dashboard
    from tests.test_report import report_page
    repo, commits, runs = project_history
    index = build_dashboard(build_history([runs[c] for c in commits], repo=repo), tmp_path / "site")
    for page_name in ("index.html", "regressions.html"):
        with report_page(index.parent / page_name) as (page, errors):
            hrefs = page.eval_on_selector_all(   # an SVG link's href is not a string: resolve its attribute
                "a[href]", "links => links.map(a => new URL(a.getAttribute('href'), document.baseURI).href)")
            if page_name == "index.html":
                assert page.evaluate("GIBENCH.graphs") == page.eval_on_selector_all("svg.graph", "g => g.length") >= 4
                assert page.eval_on_selector_all("svg.graph line.step.regression", "l => l.length") == 1
                assert page.eval_on_selector_all("svg.graph circle", "c => c.length") >= 4 * len(commits)
            else:
                assert page.eval_on_selector_all("li.regression", "l => l.length") == 1
            assert errors == []
        for href in hrefs:
            target = Path(unquote(href.split("#", 1)[0].removeprefix("file://")))
            assert target.exists(), href
