"""The history dashboard: a static site (offline, from file://) of a bench.history.History.

Layout of the output folder:
  index.html        one graph per series over commits (inline SVG): each point a run, linking to
                    that run's report; the fitted levels; the steps marked (red: regression, green:
                    improvement, grey: machine-wide)
  regressions.html  the changes, newest commit first, grouped by the commit that starts them
  regressions.md    the same list as Markdown, regressions.txt as plain text (CI logs)

Rendered from templates/history/ with the report's Jinja2 environment; graphs are computed here
as plain coordinates and drawn by the templates' SVG macro. Reads run folders only: never renders.
"""
from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

from bench.history.presentation import (
    change_line,
    check_line,
    commit_range,
    short,
    summary_line,
)
from bench.protocol import results as store

from .render import write_page

GRAPH_W, GRAPH_H = 620, 180
MARGIN = {"left": 64, "right": 12, "top": 14, "bottom": 30}
VERDICT_CLASS = {"regression": "regression", "improvement": "improvement", "machine slower": "machine",
                 "machine faster": "machine"}


def _link(target, out_dir: Path) -> str:
    """A link from the dashboard to a run's report, relative so that the site moves with its runs."""
    return Path(os.path.relpath(Path(target).resolve(), out_dir.resolve())).as_posix()


def _ticks(low: float, high: float, log: bool) -> list[float]:
    """About four readable axis values within [low, high]."""
    if log:
        low_e, high_e = math.floor(math.log10(low)), math.ceil(math.log10(high))
        candidates = [m * 10 ** e for e in range(low_e, high_e + 1) for m in (1, 2, 5)]
    else:
        step = 10 ** math.floor(math.log10(max(high - low, 1e-300) / 3))
        for m in (1, 2, 5, 10):
            if (high - low) / (step * m) <= 5:
                step *= m
                break
        candidates = [step * k for k in range(math.floor(low / step), math.ceil(high / step) + 1)]
    inside = [v for v in candidates if low <= v <= high]
    if len(inside) < 2 and log:   # a narrow range within one decade: linear ticks read better
        return _ticks(low, high, False)
    return inside if len(inside) >= 2 else [low, high]


def graph(series, commits: list, changes: list, out_dir: Path) -> dict:
    """Plain coordinates of one series' graph (points, fitted levels, step markers, axis ticks)."""
    n_commits = len(commits)
    shown = [p.shown for p in series.points]
    levels = [math.exp(s.level) if series.log_scale else s.level for s in series.segments]
    values = [v for v in shown + levels if math.isfinite(v) and (v > 0 or not series.log_scale)]
    low, high = (min(values), max(values)) if values else (0.0, 1.0)
    if series.log_scale:
        low, high = low / 1.15, high * 1.15
    else:
        pad = (high - low) * 0.1 or abs(high) * 0.1 or 1.0
        low, high = low - pad, high + pad
    fy = (lambda v: math.log(v)) if series.log_scale else (lambda v: v)
    inner_w = GRAPH_W - MARGIN["left"] - MARGIN["right"]
    inner_h = GRAPH_H - MARGIN["top"] - MARGIN["bottom"]

    def x(position: float) -> float:
        return round(MARGIN["left"] + inner_w * ((position + 0.5) / max(n_commits, 1)), 1)

    def y(value: float) -> float:
        t = (fy(value) - fy(low)) / ((fy(high) - fy(low)) or 1.0)
        return round(MARGIN["top"] + inner_h * (1 - t), 1)

    points = [{"x": x(p.position), "y": y(p.shown), "href": _link(p.links[0], out_dir),
               "title": f"{short(p.commit)}: {p.shown:.4g} ({len(p.runs)} run{'s' if len(p.runs) > 1 else ''})"}
              for p in series.points if math.isfinite(p.shown) and (p.shown > 0 or not series.log_scale)]
    fit = []
    for segment, level in zip(series.segments, levels):
        first, last = series.points[segment.start], series.points[segment.stop - 1]
        fit.append({"x1": x(first.position - 0.4), "x2": x(last.position + 0.4), "y": y(level)})
    marks = [{"x": x((c.series.points[c.before_index].position + c.series.points[c.after_index].position) / 2),
              "kind": VERDICT_CLASS[c.verdict], "title": f"{c.verdict}: {c.change_text()} in {commit_range(c)}"}
             for c in changes]
    return {"width": GRAPH_W, "height": GRAPH_H, "points": points, "fit": fit, "marks": marks,
            "top": MARGIN["top"], "bottom": GRAPH_H - MARGIN["bottom"], "left": MARGIN["left"],
            "right": GRAPH_W - MARGIN["right"],
            "yticks": [{"y": y(v), "label": f"{v:.3g}"} for v in _ticks(low, high, series.log_scale)],
            "xticks": [{"x": x(i), "label": short(c)[:7]} for i, c in enumerate(commits)
                       if i % max(math.ceil(n_commits / 8), 1) == 0 or i == n_commits - 1],
            "unit": _unit(series)}


def _unit(series) -> str:
    if series.kind == "machine":
        return "speed factor (1 = usual)" if series.metric.startswith("machine") else series.metric
    if series.kind == "time":
        _, _, yardstick = series.metric.partition("/")
        return f"frame time / {yardstick}'s" if yardstick else "frame ms, machine load removed"
    return series.metric


def series_id(series) -> str:
    """An HTML id for a series, the same on every build."""
    return "s" + hashlib.sha1(series.label.encode()).hexdigest()[:12]


def build_dashboard(history, out_dir) -> Path:
    """Write the dashboard of `history` into `out_dir`; returns its index.html."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    changes_of: dict = {}
    for change in history.changes:
        changes_of.setdefault(id(change.series), []).append(change)
    groups: dict = {}
    for series in sorted(history.series, key=lambda s: (s.kind != "machine", s.row_label, s.metric, s.machine)):
        title = ("Machines" if series.kind == "machine" else f"{series.row[0]}/{series.row[1]}")
        groups.setdefault(title, []).append({
            "id": series_id(series), "label": series.label, "kind": series.kind,
            "changes": [change_line(c) for c in changes_of.get(id(series), [])],
            "graph": graph(series, history.commits, changes_of.get(id(series), []), out_dir)})
    commits = [{"index": i, "commit": short(c)} for i, c in enumerate(history.commits)]
    by_commit = [{"commit": short(commit),
                  "changes": [{"line": change_line(c), "kind": VERDICT_CLASS[c.verdict], "rows": c.rows,
                               "series": series_id(c.series),
                               "before": _link(c.series.points[c.before_index].links[0], out_dir),
                               "after": _link(c.series.points[c.after_index].links[0], out_dir)}
                              for c in changes]}
                 for commit, changes in history.by_commit()]
    context = {"summary": summary_line(history), "check": check_line(history), "notes": history.notes,
               "commits": commits, "ordered_by": history.ordered_by, "groups": list(groups.items()),
               "by_commit": by_commit, "graphs": sum(len(v) for v in groups.values())}
    index = write_page(out_dir / "index.html", "history/index.html", **context)
    write_page(out_dir / "regressions.html", "history/regressions.html", **context)
    store.atomic_write_text(out_dir / "regressions.md", history.markdown())
    store.atomic_write_text(out_dir / "regressions.txt", history.text())
    return index
