"""The history's series: one per (scene, view, method, rung, seed, resolution, metric), one point per
commit; timing series per machine, error series across machines.

Timing. A run counts by the median of its frames (the gate's `run_median`: frames of one process
share its load), on a log scale. Load slows every method of a run alike, so each run's times are
taken relative to its machine's state in that run (the gate's `--relative-to` idea): with
`relative_to=METHOD`, that method's time on the same view; otherwise the run's *machine index*,
the median over the run's timed rows of (log time - the row's median log time on that machine).
The index is a series of its own per machine: its steps are the machine-wide ones (a slower
machine, a loaded period, a change of the harness every row shares). A point's noise is the
largest of the spread of its frames (robust sd of their logs), the history's spread between runs
on that machine (robust sd of consecutive differences pooled over the machine's series, blended
with a prior while they are few: PRIOR_RUN_NOISE) and TIME_NOISE_FLOOR, over the square root of
the commit's runs (repeating runs narrows it).

Errors. Every error column (bench.gate.statistics.error_columns) of rows with images (ok or
cached), net of the reference noise floor for MSE and clamped at 0 for the error over frames, as
the gate compares them. A point's noise is the largest of the metric's absolute floor
(ERROR_ABS_FLOOR), the reference noise floor (MSE), the error over frames' own 95% interval over
pixels / 1.96, and ERROR_NOISE_FRACTION of the value (an image a changed seed stream redraws).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.gate.load import cell_float, cell_text, frame_samples
from bench.gate.statistics import (
    ERROR_ABS_FLOOR,
    error_columns,
    noise_floor,
    run_median,
)
from bench.history.load import RUNG_COLUMN, HistoryRun
from bench.history.steps import robust_sigma_of_differences
from bench.protocol.vocabulary import (
    DECOMPOSITION_METRICS,
    Status,
    interval_column,
    row_identity,
)

TIME_METRIC = "frame_ms"
MACHINE_METRIC = "machine index"
TIME_NOISE_FLOOR = 0.01          # 1% in log time: below it, timer and scheduling jitter
ERROR_NOISE_FRACTION = 0.01
MIN_ROWS_FOR_INDEX = 3           # a median over fewer rows follows the one row that changed
# The spread between runs is measured from the history itself, and until it holds many run-to-run
# differences that measure is itself uncertain: it is blended with PRIOR_RUN_NOISE (sd of log time)
# as if the prior were PRIOR_DIFFERENCES differences, sigma^2 = (n s^2 + n0 prior^2) / (n + n0). The
# prior is what the shared 2-core llvmpipe machine of the tests showed: a row's run median moved by
# 5-30% from one run to the next under other jobs' load (x2 at times: the shared passes, one
# measurement per view and run added to every row's frames, moved `direct` by x2 between two runs
# of unchanged code).
PRIOR_DIFFERENCES = 8
PRIOR_RUN_NOISE = 0.15
FACT_COLUMNS = ("method_version", "scene_hash", "params")


@dataclass
class Point:
    """A series at one commit: what the fit sees (`value`, `sigma`) and what a graph shows."""
    position: int
    commit: str
    value: float
    sigma: float
    shown: float               # frame ms (at the machine's usual speed) or the error value
    runs: list = field(default_factory=list)    # run folders
    links: list = field(default_factory=list)   # their reports
    facts: dict = field(default_factory=dict)   # method version, scene hash, params, references


@dataclass
class Series:
    kind: str                  # "time", "error" or "machine"
    metric: str
    row: tuple = ()            # (scene, view, method, rung, seed, width, height); () for a machine series
    machine: str = ""
    machine_label: str = ""
    points: list = field(default_factory=list)
    segments: list = field(default_factory=list)   # the fit (bench.history.steps.Segment), set by the detection

    @property
    def row_label(self) -> str:
        if not self.row:
            return f"every timed row on {self.machine_label}"
        scene, view, method, rung, seed, width, height = self.row
        label = f"{scene}/{view}/{method}" + ("" if rung == "{}" else f" {rung}")
        label += f" {width}x{height}" + ("" if seed == 0 else f" seed {seed}")
        return label

    @property
    def label(self) -> str:
        where = f" [{self.machine}]" if self.machine else ""
        return f"{self.row_label}: {self.metric}{where}"

    @property
    def log_scale(self) -> bool:
        return self.kind in ("time", "machine")


def row_key(rec: dict) -> tuple:
    """(scene, view, method, rung, seed, width, height): a series' row, by its declared rung."""
    scene, view, method, _, seed, width, height = row_identity(rec)
    return scene, view, method, str(rec.get(RUNG_COLUMN) or "{}"), seed, width, height


def _facts(rec: dict) -> dict:
    facts = {c: cell_text(rec, c) for c in FACT_COLUMNS}
    facts["references"] = ",".join(f"{k.split('.', 1)[1]}={cell_text(rec, k)}" for k in sorted(rec)
                                   if k.startswith("reference_key.") and cell_text(rec, k))
    return facts


def log_frame_spread(rec: dict) -> float:
    """Robust sd of a row's log frame times (1.4826 MAD; NaN with fewer than 2 frames)."""
    samples = [s for s in frame_samples(rec) if s > 0]
    if len(samples) < 2:
        return math.nan
    logs = np.log(samples)
    return float(1.4826 * np.median(np.abs(logs - np.median(logs))))


def _append(series: Series, position: int, commit: str, run: HistoryRun, value: float, spread: float,
            shown: float, rec: dict | None) -> None:
    """Add one run's value at a commit (several runs of one commit share its point)."""
    if series.points and series.points[-1].position == position:
        point = series.points[-1]
        n = len(point.runs)
        point.value = (point.value * n + value) / (n + 1)
        point.shown = (point.shown * n + shown) / (n + 1)
        point.sigma = max(point.sigma, spread) if math.isfinite(spread) else point.sigma
    else:
        point = Point(position, commit, value, spread if math.isfinite(spread) else 0.0, shown,
                      facts=_facts(rec) if rec is not None else {})
        series.points.append(point)
    point.runs.append(run.path)
    point.links.append(run.link)


# ---------------------------------------------------------------------------- timing
def _timed_rows(run: HistoryRun, relative_to: str | None) -> dict:
    """row key -> (log run time, log frame spread) of the rows rendered in this run (cached rows
    repeat an old timing), the yardstick's own rows excluded."""
    out = {}
    for rec in run.rows:
        if Status.kind(rec.get("status")) not in Status.MEASURED or str(rec.get("method")) == relative_to:
            continue
        t = run_median(rec)
        if math.isfinite(t) and t > 0:
            out.setdefault(row_key(rec), (math.log(t), log_frame_spread(rec), rec))
    return out


def _yardsticks(run: HistoryRun, relative_to: str) -> dict:
    """(scene, view, seed, width, height) -> log time of `relative_to`'s rendered row (its defaults
    first) in this run."""
    out = {}
    for rec in sorted(run.rows, key=lambda r: str(r.get(RUNG_COLUMN)) != "{}"):
        if str(rec.get("method")) != relative_to or Status.kind(rec.get("status")) not in Status.MEASURED:
            continue
        scene, view, _, _, seed, width, height = row_key(rec)
        t = run_median(rec)
        if math.isfinite(t) and t > 0:
            out.setdefault((scene, view, seed, width, height), math.log(t))
    return out


def _machine_indexes(runs: list[HistoryRun], timed: list, relative_to: str | None) -> tuple[list, int]:
    """Per run, row key -> the log time the row is taken relative to (the run's machine index, or
    the yardstick's log time on the row's view; NaN without one), and how many runs had too few
    timed rows for an index."""
    baseline: dict = {}
    for rows in timed:
        for key, (lt, _, _) in rows.items():
            baseline.setdefault(key, []).append(lt)
    baseline = {k: float(np.median(v)) for k, v in baseline.items()}
    indexes, few = [], 0
    for run, rows in zip(runs, timed):
        if relative_to is not None:
            sticks = _yardsticks(run, relative_to)
            indexes.append({k: sticks.get((k[0], k[1], k[4], k[5], k[6]), math.nan) for k in rows})
            continue
        deviations = [lt - baseline[k] for k, (lt, _, _) in rows.items()]
        few += 0 < len(deviations) < MIN_ROWS_FOR_INDEX
        index = float(np.median(deviations)) if len(deviations) >= MIN_ROWS_FOR_INDEX else 0.0
        indexes.append({k: index for k in rows})
    return indexes, few


def run_to_run_noise(series_list) -> float:
    """The sd of log time between runs, measured over consecutive points of a machine's series and
    blended with the prior (PRIOR_RUN_NOISE as PRIOR_DIFFERENCES differences)."""
    differences = [b.value - a.value for s in series_list for a, b in zip(s.points, s.points[1:])]
    measured = robust_sigma_of_differences(differences)
    measured = measured if math.isfinite(measured) else PRIOR_RUN_NOISE
    n = len(differences)
    return math.sqrt((n * measured ** 2 + PRIOR_DIFFERENCES * PRIOR_RUN_NOISE ** 2) / (n + PRIOR_DIFFERENCES))


def timing_series(runs: list[HistoryRun], position: dict, relative_to: str | None, notes: list) -> list[Series]:
    """The timing series (kind "time") and the machine series (kind "machine") of every machine."""
    out = []
    for machine in dict.fromkeys(r.machine for r in runs):
        mruns = sorted((r for r in runs if r.machine == machine), key=lambda r: position[r.commit])
        timed = [_timed_rows(r, relative_to) for r in mruns]
        label = mruns[0].machine_label
        indexes, few = _machine_indexes(mruns, timed, relative_to)
        if few:
            notes.append(f"{few} run(s) on {label} have fewer than {MIN_ROWS_FOR_INDEX} timed rows: their times "
                         f"are not taken relative to the machine, and a machine-wide step would show in each row")
        rows_series: dict = {}
        metric = TIME_METRIC if relative_to is None else f"{TIME_METRIC}/{relative_to}"
        machine_series = Series("machine", MACHINE_METRIC if relative_to is None else f"{relative_to} time",
                                machine=machine, machine_label=label)
        for run, rows, index in zip(mruns, timed, indexes):
            pos = position[run.commit]
            for key, (lt, spread, rec) in rows.items():
                if not math.isfinite(index[key]):
                    continue
                series = rows_series.setdefault(key, Series("time", metric, key, machine, label))
                _append(series, pos, run.commit, run, lt - index[key], spread, math.exp(lt - index[key]), rec)
            run_index = [v for v in index.values() if math.isfinite(v)]
            if run_index:
                level = float(np.median(run_index))
                _append(machine_series, pos, run.commit, run, level, math.nan, math.exp(level), None)
        pooled = run_to_run_noise(rows_series.values())
        for s in rows_series.values():
            for p in s.points:
                p.sigma = max(p.sigma, pooled, TIME_NOISE_FLOOR) / math.sqrt(len(p.runs))   # repeated runs average
        # the index's own noise: a median over the rows (with a yardstick, one row's); its own spread
        # once it has points enough to measure one
        own = robust_sigma_of_differences([b.value - a.value for a, b in zip(machine_series.points,
                                                                              machine_series.points[1:])])
        own = own if math.isfinite(own) and len(machine_series.points) >= 5 else 0.0
        of_median = pooled / math.sqrt(max(len(rows_series), 1)) if relative_to is None else pooled
        for p in machine_series.points:
            p.sigma = max(of_median, own, TIME_NOISE_FLOOR)
        out += list(rows_series.values())
        if machine_series.points and (relative_to is not None or any(len(i) >= MIN_ROWS_FOR_INDEX for i in indexes)):
            out.append(machine_series)
    return out


# ---------------------------------------------------------------------------- errors
def error_value(rec: dict, column: str) -> tuple[float, float]:
    """(value as the gate compares it, its noise sd) of an error cell; NaN when empty."""
    metric, component = column.split(".", 1)
    value = cell_float(rec, column)
    if not math.isfinite(value):
        return math.nan, math.nan
    sigma = ERROR_ABS_FLOOR.get(metric, 0.0)
    if metric == "mse":
        floor = noise_floor(rec, component)
        value = max(value - floor, 0.0)
        sigma = max(sigma, floor)
    elif metric in DECOMPOSITION_METRICS:
        value = max(value, 0.0)
        ci = abs(cell_float(rec, interval_column(metric, component)))
        sigma = max(sigma, ci / 1.96 if math.isfinite(ci) else 0.0)
    return value, max(sigma, ERROR_NOISE_FRACTION * abs(value))


def error_series(runs: list[HistoryRun], position: dict, metrics=None) -> list[Series]:
    """The error series of every error column (or of `metrics`), machines together."""
    out: dict = {}
    for run in sorted(runs, key=lambda r: position[r.commit]):
        columns = sorted({c for rec in run.rows for c in rec})
        wanted = error_columns(columns) if not metrics else [m for m in metrics if m in columns]
        for rec in run.rows:
            if not Status.has_images(rec.get("status")):
                continue
            key = row_key(rec)
            for column in wanted:
                value, sigma = error_value(rec, column)
                if not math.isfinite(value):
                    continue
                series = out.setdefault((key, column), Series("error", column, key))
                _append(series, position[run.commit], run.commit, run, value, sigma, value, rec)
    return list(out.values())
