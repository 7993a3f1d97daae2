"""The static HTML comparison report of a run (`gibench report RUN`): works offline from file://.

`build_report(run_dir, out_dir=None)` writes `<out_dir>/index.html` (default `<run_dir>/report/`)
with a comparison viewer per scene view, time/error and per-stage tables, time-vs-error plots
with Pareto fronts, equal-error speed-ups over Mitsuba, scene facts, reference noise floors and
the run's machine, versions and parameters. The page is rendered from Jinja2 templates
(templates/, one per section; render.py holds the environment and the number format); labels
and parameter defaults come from the run's manifest. The report reads run folders; it never renders.
"""
from .build import build_report

__all__ = ["build_report"]
