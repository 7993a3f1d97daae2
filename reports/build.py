"""Build the static HTML report of a run folder (works offline from file://).

Layout of the output folder (default `<run>/report/`):
  index.html            tables, plots, one comparison viewer per scene view
  assets/               viewer.js, report.css, colormap.js (copied from the package)
  data/view_<i>.js      linear images of one view as base64 float16 (identical images stored
                        once), loaded by <script src>
                        (browsers block fetch() of local files)
  data/*.csv            the between-method and paper-reproduction tables
  plots/*.svg           matplotlib figures (per view: time vs error, its single-frame and accumulated
                        curves; the bias/variance split; per-stage times)
  report.json           when the report was built, from which run, in how many seconds (the
                        report's own time lives here: the run folder it reads is never written)

The page is rendered from templates/index.html and one template per section
(templates/sections/); this module reads the run folder and hands the templates plain data. The
viewer tone-maps in JS (exposure in stops, sRGB), so the page keeps the linear data (viewdata.py).
Labels and parameter defaults come from the run's manifest (what each method declared when it
ran), never from today's method classes. The report reads result files only; it never renders.
A run that did not finish (bench.protocol.results.run_progress: interrupted, or still running)
is marked in the page's header: "incomplete: N of M rows".
"""
from __future__ import annotations

import datetime as _dt
import json
import shutil
import time
from importlib import resources
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from bench.protocol import results as store
from bench.analysis.curves import declared_defaults, load_curves, pareto_table, sweep_table
from bench.protocol.results import load_manifest, run_progress

from . import comparisons, plots, sequences, tables
from .render import write_page
from .stress import STRESS_TABLE, build_stress_report
from .viewdata import view_data, write_view_script

__all__ = ["build_report"]

# the sweep table's columns besides time and error that the page shows
KEEP_COLUMNS = ("image_dir", "skipped_stages", "samples.stage_ms", "width", "height", "stage_ms.", "reference_",
                "extra.error_frames")
TOC = (("overview", "Time and error"), ("decomposition", "Bias and variance"), ("scenes", "Scenes"),
       ("sequences", "Sequences"),
       ("timing", "Stages"), ("speedup", "Speed-up"), ("scaling", "Scaling"), ("between", "Between methods"),
       ("papers", "Papers"), ("scene-facts", "Scene facts"), ("references", "References"), ("metrics", "Metrics"),
       ("run", "Run"))


def _copy_assets(out_dir: Path) -> None:
    assets = out_dir / "assets"
    assets.mkdir(parents=True, exist_ok=True)
    static = resources.files(__package__) / "static"
    for name in ("viewer.js", "report.css"):
        (assets / name).write_text(static.joinpath(name).read_text(encoding="utf-8"), encoding="utf-8")
    lut = np.round(matplotlib.colormaps["inferno"](np.linspace(0, 1, 256))[:, :3] * 255).astype(int)
    (assets / "colormap.js").write_text("window.GIBENCH = window.GIBENCH || {};\nGIBENCH.colormap = "
                                        + json.dumps(lut.ravel().tolist(), separators=(",", ":")) + ";\n")


def _views(run_dir: Path, out_dir: Path, table: pd.DataFrame, views: list, curves: dict, manifest: dict) -> tuple:
    """Per view: its viewer data script and plots (written), the data of its scene block, its stage
    table and its speed-up table."""
    fronts = pareto_table(table) if len(table) else pd.DataFrame()
    scene_views, timing, speedups = [], [], []
    for i, (scene, view) in enumerate(views):
        rows = table[(table["scene"] == scene) & (table["view"] == view)]
        key = f"{scene}/{view}"
        write_view_script(out_dir / "data" / f"view_{i}.js", key, view_data(run_dir, rows))
        stages = tables.stage_order(rows)
        plot = plots.time_error_plot(table, curves, scene, view, out_dir / "plots" / f"time_error_{i}.svg")
        stage_plot = plots.stage_plot(rows, stages, out_dir / "plots" / f"stages_{i}.svg", f"{key}: per-stage GPU time")
        split = tables.bias_variance(rows)
        split_plot = plots.bias_variance_plot(split, out_dir / "plots" / f"bias_variance_{i}.svg",
                                              f"{key}: bias and variance (default rungs)")
        front = fronts[(fronts["scene"] == scene) & (fronts["view"] == view)] if len(fronts) else fronts
        scene_views.append({"index": i, "scene": scene, "view": view, "key": key,
                            "purpose": manifest.get("scene_purposes", {}).get(scene),
                            "time_error_plot": plot.name if plot is not None else None,
                            "stage_plot": stage_plot.name if stage_plot is not None else None,
                            "bias_variance": split, "bias_variance_plot": split_plot.name if split_plot else None,
                            "pareto": tables.pareto_rows(front)})
        timing.append({"scene": scene, "view": view, "stages": stages, "rows": tables.stage_rows(rows, stages)})
        speed = tables.speedup(rows)
        if speed is not None:
            speedups.append(dict(speed, scene=scene, view=view))
    return scene_views, timing, speedups


def _scaling(table: pd.DataFrame, manifest: dict, out_dir: Path) -> dict | None:
    """Cost vs triangles over the high-poly series (its plot written), or None without the series."""
    facts = manifest.get("scene_facts", {}) or {}
    triangles = {k: v.get("triangle_count") for k, v in facts.items() if isinstance(v, dict)}
    fits = plots.scaling_fits(table, triangles) if len(table) else {}
    if not fits:
        return None
    plot = plots.scaling_plot(fits, out_dir / "plots" / "scaling.svg")
    return {"plot": plot.name if plot is not None else None, "rows": tables.scaling_rows(fits)}


def build_report(run_dir, out_dir=None) -> Path:
    """Build the report of `run_dir` into `out_dir` (default `<run_dir>/report`); returns index.html."""
    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"run folder not found: {run_dir}")
    if (run_dir / STRESS_TABLE).is_file() and not (run_dir / "results.csv").is_file():
        return build_stress_report(run_dir, out_dir)  # a `gibench stress` folder
    progress = run_progress(run_dir)   # read before the table: a run still writing adds rows, never removes them
    df = store.load_results(run_dir)
    manifest = load_manifest(run_dir)
    curves = load_curves(run_dir)
    out_dir = Path(out_dir) if out_dir is not None else run_dir / "report"
    for sub in ("data", "plots"):
        if (out_dir / sub).exists():
            shutil.rmtree(out_dir / sub)
    (out_dir / "data").mkdir(parents=True, exist_ok=True)
    _copy_assets(out_dir)

    table = (sweep_table(df, curves, declared_defaults(manifest), keep=KEEP_COLUMNS) if len(df)
             else pd.DataFrame(columns=["scene", "view", "label", "frame_ms"]))
    views = list(dict.fromkeys(zip(table["scene"], table["view"]))) if len(table) else []
    overview = tables.overview(table, views, manifest.get("scene_facts"))
    scene_views, timing, speedups = _views(run_dir, out_dir, table, views, curves, manifest)
    scaling = _scaling(table, manifest, out_dir)
    sequence_blocks = sequences.sequence_blocks(run_dir, out_dir, df)
    metric_docs = tables.metric_docs(overview["metrics"])
    decomposition = any(v["bias_variance"] for v in scene_views) or overview["flicker"] is not None
    machine = manifest.get("machine", {})
    context = {
        "title": f"gibench report: {run_dir.resolve().name}",
        "subtitle": {"rows": len(table), "views": len(views), "methods": len(set(table["method"])) if len(table) else 0,
                     "renderer": machine.get("gl_renderer", "?"), "cpu": machine.get("cpu", "?"),
                     "commit": str(manifest.get("git_commit") or "?")[:12],
                     "incomplete": progress.describe()},
        "toc": [(a, t) for a, t in TOC if (metric_docs or a != "metrics") and (scaling or a != "scaling")
                and (decomposition or a != "decomposition") and (sequence_blocks or a != "sequences")],
        "sequences": sequence_blocks,
        "overview": overview, "not_rendered": tables.not_rendered(df), "decomposition": decomposition,
        "scene_views": scene_views, "timing": timing, "speedup": speedups, "scaling": scaling,
        "between": comparisons.between_methods(table, out_dir),
        "papers": comparisons.reproduction(table, manifest, out_dir),
        "scene_facts": tables.scene_facts(manifest), "noise_floors": tables.noise_floors(table),
        "metric_docs": metric_docs, "run": tables.run_info(manifest, run_dir),
        "data_scripts": [f"data/view_{i}.js" for i in range(len(views))],
    }
    index = write_page(out_dir / "index.html", "index.html", **context)
    store.atomic_write_text(out_dir / "report.json", json.dumps(
        {"run": str(run_dir.resolve()), "built": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
         "seconds": round(time.perf_counter() - t0, 3), "incomplete": progress.describe() or None}, indent=1))
    return index
