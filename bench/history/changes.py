"""The change points of a history: every series' steps (bench.history.steps), tested, adjusted over
the whole history, classified, and placed between two commits."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from bench.gate.statistics import adjust_p_values, error_check
from bench.history.load import (
    HistoryRun,
    git,
    git_repository,
    has_commits,
    load_history_runs,
    order_runs,
)
from bench.history.series import Series, error_series, timing_series
from bench.history.steps import PENALTY, solve_potts, steps_between


@dataclass
class Change:
    """A step of one series between two commits: the last at the old level, the first at the new."""
    series: Series
    verdict: str               # "regression", "improvement", or for a machine series "machine slower"/"machine faster"
    before_index: int          # into series.points
    after_index: int
    level_before: float        # the fitted levels, in the series' own units (ms, factor or error)
    level_after: float
    change: float              # ratio (time, machine) or relative change (error) after/before
    interval: tuple            # its 95% interval, same form
    p_value: float             # adjusted (Holm) over every series of the history
    commits_between: int | None = None   # commits in (before, after], when the repository is at hand
    notes: list = field(default_factory=list)   # what else changed at the step (method version, scene...)
    rows: list = field(default_factory=list)    # the rows the step affects (a machine-wide step: every timed row)

    @property
    def commit_before(self) -> str:
        return self.series.points[self.before_index].commit

    @property
    def commit_after(self) -> str:
        return self.series.points[self.after_index].commit

    @property
    def machine_wide(self) -> bool:
        return self.series.kind == "machine"

    def change_text(self) -> str:
        lo, hi = self.interval
        if self.series.log_scale:
            return f"x{self.change:.3g} (95% x{lo:.3g}..x{hi:.3g})"
        return f"{self.change:+.1%} (95% {lo:+.1%}..{hi:+.1%})"


@dataclass
class History:
    """What `build_history` found; `text()` / `markdown()` are the list, `check_exit_code` the CI form."""
    runs: list
    commits: list              # oldest first
    ordered_by: str
    series: list
    changes: list
    notes: list = field(default_factory=list)
    relative_to: str | None = None
    repo: Path | None = None

    @property
    def newest_commit(self) -> str | None:
        return self.commits[-1] if self.commits else None

    def regressions(self) -> list:
        return [c for c in self.changes if c.verdict == "regression"]

    def starting_at(self, commit: str) -> list:
        """Regressions whose new level starts at `commit` (machine-wide steps are not regressions)."""
        return [c for c in self.regressions() if c.commit_after == commit]

    @property
    def check_exit_code(self) -> int:
        """1 when the newest commit starts a regression, else 0."""
        return 1 if self.newest_commit and self.starting_at(self.newest_commit) else 0

    def by_commit(self) -> list:
        """[(commit, [changes])] newest first: every change grouped by the commit that starts it."""
        rank = {c: i for i, c in enumerate(self.commits)}
        groups: dict = {}
        for change in self.changes:
            groups.setdefault(change.commit_after, []).append(change)
        order = sorted(groups, key=lambda c: -rank[c])
        return [(c, sorted(groups[c], key=lambda x: (not x.machine_wide, x.verdict != "regression", x.series.label)))
                for c in order]

    def text(self) -> str:
        from bench.history.presentation import history_text
        return history_text(self)

    def markdown(self) -> str:
        from bench.history.presentation import history_markdown
        return history_markdown(self)


def _step_notes(series: Series, before: int, after: int) -> list:
    """What changed between the two points besides the measurement."""
    a, b = series.points[before].facts, series.points[after].facts
    out = []
    for key, what in (("method_version", "method version"), ("scene_hash", "scene content"),
                      ("params", "resolved parameters"), ("references", "references")):
        if a.get(key) and b.get(key) and a[key] != b[key]:
            shown = (lambda v: v[:8]) if key in ("method_version", "scene_hash") else (lambda v: v)
            out.append(f"{what} changed ({shown(a[key])} -> {shown(b[key])})")
    return out


def _classify(series: Series, step, p_value: float, time_threshold: float, error_threshold: float,
              alpha: float) -> tuple:
    """(verdict or None, change, interval) of a tested step."""
    lo, hi = step.interval()
    if series.log_scale:
        ratio = math.exp(step.size)
        interval = (math.exp(lo), math.exp(hi))
        verdict = None
        if p_value < alpha and ratio > 1 + time_threshold:
            verdict = "machine slower" if series.kind == "machine" else "regression"
        elif p_value < alpha and ratio < 1 / (1 + time_threshold):
            verdict = "machine faster" if series.kind == "machine" else "improvement"
        return verdict, ratio, interval
    before, after = step.level_before, step.level_after
    relative = (after - before) / before if before > 0 else math.inf if after > before else 0.0
    interval = ((lo / before, hi / before) if before > 0 else (math.nan, math.nan))
    verdict = error_check(series.metric.split(".", 1)[0], before, after, error_threshold, 1.96 * step.standard_error)
    return (verdict if p_value < alpha else None), relative, interval


def detect_changes(series_list: list, time_threshold: float = 0.10, error_threshold: float = 0.05,
                   alpha: float = 0.05, penalty: float = PENALTY, repo: Path | None = None) -> list[Change]:
    """Every series' steps, their p-values adjusted together (Holm, over every series tested), kept
    when they pass the thresholds (the gate's, for time and error)."""
    candidates, tested = [], 0
    for series in series_list:
        if len(series.points) < 2:
            continue
        tested += 1
        series.segments = solve_potts([p.value for p in series.points], [p.sigma for p in series.points], penalty)
        for step in steps_between(series.segments):
            candidates.append((series, step, min(step.p_up, step.p_down)))
    # Holm over every series tested, not only over the steps the fit proposed: the fit picks the
    # split that best separates the levels, so a proposed step's own p-value is small by construction
    # (a series without a proposed step counts as a test with p = 1)
    family = [c[2] for c in candidates] + [1.0] * max(tested - len(candidates), 0)
    adjusted = adjust_p_values(family, "holm")[:len(candidates)] if candidates else []
    changes = []
    for (series, step, _), p_value in zip(candidates, adjusted):
        verdict, change, interval = _classify(series, step, float(p_value), time_threshold, error_threshold, alpha)
        if verdict is None:
            continue
        found = Change(series, verdict, step.before_index, step.after_index,
                       _shown(series, step.level_before), _shown(series, step.level_after), change, interval,
                       float(p_value), notes=_step_notes(series, step.before_index, step.after_index))
        found.rows = _rows_affected(found, series_list)
        if repo is not None:
            found.commits_between = _count_commits(repo, found.commit_before, found.commit_after)
        changes.append(found)
    return changes


def _rows_affected(change: Change, series_list: list) -> list:
    """A row series' own row; for a machine-wide step, every timed row of that machine measured on
    both sides of it."""
    if not change.machine_wide:
        return [change.series.row_label]
    before = change.series.points[change.before_index].position
    after = change.series.points[change.after_index].position
    return sorted(s.row_label for s in series_list if s.kind == "time" and s.machine == change.series.machine
                  and any(p.position <= before for p in s.points) and any(p.position >= after for p in s.points))


def _shown(series: Series, level: float) -> float:
    return math.exp(level) if series.log_scale else level


def _count_commits(repo: Path, before: str, after: str) -> int | None:
    strip = lambda c: c.removesuffix("-dirty")
    try:
        return int(git(repo, "rev-list", "--count", f"{strip(before)}..{strip(after)}").strip())
    except ValueError:
        return None


def build_history(paths, repo: Path | None = None, relative_to: str | None = None, metrics=None,
                  time_threshold: float = 0.10, error_threshold: float = 0.05, alpha: float = 0.05,
                  penalty: float = PENALTY) -> History:
    """The history of the run folders `paths`: commits ordered (git ancestry in `repo`, else in the
    repository of the first run folder or of this gibench when it has every commit, else by date),
    series built, change points found."""
    notes: list = []
    runs: list[HistoryRun] = load_history_runs(paths, notes)
    if not runs:
        raise ValueError("history: no finished run with a git commit among the run folders given")
    if relative_to is not None and not any(str(r.get("method")) == relative_to for run in runs for r in run.rows):
        raise ValueError(f"--relative-to {relative_to}: no run of the history has a row of method '{relative_to}'")
    if repo is None:   # the run folders' repository, else this gibench's (the one that records commits)
        candidates = [git_repository(Path(runs[0].path).resolve()), git_repository(Path(__file__).resolve().parent)]
        repo = next((r for r in candidates if r is not None and has_commits(r, runs)), None)
    commits, ordered_by = order_runs(runs, repo, notes)
    if ordered_by == "date":
        repo = None
    position = {c: i for i, c in enumerate(commits)}
    series = timing_series(runs, position, relative_to, notes) + error_series(runs, position, metrics)
    changes = detect_changes(series, time_threshold, error_threshold, alpha, penalty, repo)
    return History(runs, commits, ordered_by, series, changes, notes, relative_to, repo)
