"""The data of the report's tables, as plain lists and dicts for the section templates
(templates/sections/): the time-and-error overview (with the flicker column), the rows not
rendered, the bias/variance split of each view, per-stage timing, equal-error speed-ups, Pareto
fronts, cost vs triangles, scene facts, reference noise floors, the metric docs and the run's
record. A row without the error over frames (an old run, --error-frames 1) adds nothing to them."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from bench.analysis.compare import default_row
from bench.analysis.curves import SPEEDUP_COMPONENTS
from bench.analysis.metrics import EPS_RELMSE, METRICS
from bench.protocol.vocabulary import (BIAS_METRICS, DECOMPOSITION_METRICS, ERROR_COMPONENTS, METRIC_NAMES,
                                       REFERENCE_COMPONENTS, SHARED_STAGES, Status, interval_column)

from .render import fmt

# the tables list the direct component last: for most methods it is the same shared direct pass
TABLE_COMPONENTS = tuple(c for c in ERROR_COMPONENTS if c != "direct") + ("direct",)
_RELATIVE = f"per pixel over r^2 + {EPS_RELMSE} * mean(r^2), as relmse"
DECOMPOSITION_DOCS = {
    "bias2": "squared error of the mean of the K error frames, less that mean's own variance (variance / K) and the "
             "reference's noise: what accumulating frames cannot remove",
    "variance": "per-pixel variance over the K error frames (K - 1 denominator), averaged: the noise a temporal "
                "filter or a denoiser removes; 0 for a deterministic method",
    "flicker": "mean squared difference between consecutive error frames / 2: what a viewer sees change from frame "
               "to frame (the variance for independent frames, less for a method that reuses earlier frames)",
    "mse_accumulated": "MSE of the mean of the K error frames, less the reference's noise: what a temporal "
                       "accumulation of K frames reaches",
}
DECOMPOSITION_DOCS.update({f"rel_{m}": f"{m}, {_RELATIVE} (rel_bias2 + rel_variance estimates the expected "
                                       f"single-frame relmse)" for m in list(DECOMPOSITION_DOCS)})
METRIC_DOCS = dict(METRICS, mean_ratio="image mean / reference mean on covered pixels: 1 is unbiased in the mean "
                                       "(best: closest to 1)", **DECOMPOSITION_DOCS)
DEFAULT_METRICS = ("relmse.indirect", "mse.indirect", "mse.combined")
# the overview's flicker column and the component of each view's bias/variance split
FLICKER_COLUMN = "rel_flicker.indirect"
SPLIT_COMPONENT = "indirect"
SPLIT_METRICS = ("rel_bias2", "rel_variance", "rel_flicker", "rel_mse_accumulated")
# the error over frames in the overview's select: the relative forms (a table spans scenes of any
# brightness; the absolute ones are in sweep.csv and the gate): 40 views x 30 rows give 2.6 MB of overview
# tables (1.2 MB without the error over frames, 3.3 MB with every form)
OVERVIEW_DECOMPOSITION = tuple(m for m in DECOMPOSITION_METRICS if m.startswith("rel_"))


def _finite_min(values) -> float:
    a = np.asarray([v for v in values if v is not None], dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.min()) if a.size else float("nan")


def metric_columns(table: pd.DataFrame) -> list[str]:
    """The error columns of `table` that hold a number, by component then metric (the relative error
    over frames after the single-frame metrics)."""
    cols = []
    for comp in TABLE_COMPONENTS:
        for metric in METRIC_NAMES + OVERVIEW_DECOMPOSITION:
            col = f"{metric}.{comp}"
            if col in table.columns and pd.to_numeric(table[col], errors="coerce").notna().any():
                cols.append(col)
    return cols


def _badness(metric: str | None):
    """How far a value of `metric` is from the best: the value, or |log| of a bias ratio (best at 1)."""
    if metric and metric.split(".", 1)[0] in BIAS_METRICS:
        return lambda v: abs(np.log(v)) if v is not None and np.isfinite(v) and v > 0 else None
    return lambda v: v


def _has_numbers(table: pd.DataFrame, column: str) -> bool:
    return column in table.columns and bool(np.isfinite(pd.to_numeric(table[column], errors="coerce")).any())


def overview(table: pd.DataFrame, views: list[tuple[str, str]], facts: dict | None) -> dict:
    """Method x view tables of time and error, one per error column (the page shows one, chosen by a
    select), views headed with their triangle count like the FLC paper's Table 2; with a flicker
    column (FLICKER_COLUMN) beside each view's error when any row has it."""
    metric_cols = metric_columns(table) if views else []
    flicker = bool(views) and _has_numbers(table, FLICKER_COLUMN)
    labels = list(dict.fromkeys(table["label"])) if views else []
    lookup = {(r["label"], r["scene"], r["view"]): r for r in table.to_dict("records")}
    multi_view = len({s for s, _ in views}) < len(views)
    facts = facts or {}
    heads = []
    for s, v in views:
        tris = facts.get(s, {}).get("triangle_count")
        heads.append((f"{s}/{v}" if multi_view else s) + (f" ({fmt(tris)} tri.)" if tris is not None else ""))

    def one(metric: str | None) -> dict:
        best_t = {sv: _finite_min(lookup.get((l, *sv), {}).get("frame_ms") for l in labels) for sv in views}
        badness = _badness(metric)
        best_e = {sv: _finite_min(badness(lookup.get((l, *sv), {}).get(metric)) for l in labels) for sv in views} \
            if metric else {}
        best_f = {sv: _finite_min(lookup.get((l, *sv), {}).get(FLICKER_COLUMN) for l in labels) for sv in views} \
            if flicker else {}
        rows = []
        for label in labels:
            cells = []
            for sv in views:
                rec = lookup.get((label, *sv), {})
                t = rec.get("frame_ms")
                e = rec.get(metric) if metric else None
                f = rec.get(FLICKER_COLUMN) if flicker else None
                cells.append({"time": t, "time_best": t is not None and t == best_t[sv], "error": e,
                              "error_best": bool(metric) and e is not None and badness(e) == best_e[sv],
                              "flicker": f, "flicker_best": flicker and f is not None and f == best_f[sv]})
            rows.append({"label": label, "cells": cells})
        return {"metric": metric, "rows": rows}

    tables = ([one(m) for m in metric_cols] or [one(None)]) if views else []
    default = next((m for m in DEFAULT_METRICS if m in metric_cols), metric_cols[0] if metric_cols else None)
    return {"heads": heads, "metrics": metric_cols, "default_metric": default, "tables": tables,
            "flicker": FLICKER_COLUMN if flicker else None}


def _number(rec: dict, column: str) -> float | None:
    try:
        v = float(rec.get(column))
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def bias_variance(rows: pd.DataFrame, component: str = SPLIT_COMPONENT) -> list[dict]:
    """One view's bias/variance split: per method, its default rung's rel_bias2, rel_variance,
    rel_flicker and rel_mse_accumulated of `component` with their intervals, its single-frame
    relmse and its error-frame count K; [] when no row has the split (old runs, --error-frames 1)."""
    bias, variance = f"rel_bias2.{component}", f"rel_variance.{component}"
    if rows.empty or not (_has_numbers(rows, bias) and _has_numbers(rows, variance)):
        return []
    out = []
    for method, group in rows.groupby("method", sort=False):
        rec = group.loc[default_row(group)].to_dict()
        b, v = _number(rec, bias), _number(rec, variance)
        if b is None or v is None:
            continue
        entry = {"label": rec["label"], "method": str(method), "error_frames": _number(rec, "extra.error_frames"),
                 "relmse": _number(rec, f"relmse.{component}"),
                 "bias_share": max(b, 0.0) / (max(b, 0.0) + v) if max(b, 0.0) + v > 0 else None}
        for metric in SPLIT_METRICS:
            entry[metric] = _number(rec, f"{metric}.{component}")
            entry[f"{metric}_ci"] = _number(rec, interval_column(metric, component))
        out.append(entry)
    return out


def not_rendered(df: pd.DataFrame) -> list[dict]:
    """The run's rows without images (skipped or failed), with their status."""
    if "status" not in df.columns:
        return []
    bad = df[~df["status"].map(Status.has_images)]
    return [{"view": f"{r['scene']}/{r['view']}", "method": r["method"], "status": r["status"]}
            for r in bad.to_dict("records")]


def stage_order(rows: pd.DataFrame) -> list[str]:
    """Stages in execution order: the shared passes first, then each method's in first-seen order."""
    seen: list[str] = []
    for raw in rows.get("samples.stage_ms", pd.Series(dtype=object)):
        try:
            names = list(json.loads(raw)) if isinstance(raw, str) else []
        except json.JSONDecodeError:
            names = []
        seen += [n for n in names if n not in seen]
    seen += [c.split(".", 1)[1] for c in rows.columns if c.startswith("stage_ms.") and c.split(".", 1)[1] not in seen
             and pd.to_numeric(rows[c], errors="coerce").notna().any()]
    shared = [s for s in SHARED_STAGES if s in seen]
    return shared + [s for s in seen if s not in shared]


def stage_rows(rows: pd.DataFrame, stages: list[str]) -> list[dict]:
    """Per row: its label, each stage's median ms (or skipped), the GPU total and the frame time with its IQR."""
    out = []
    for rec in rows.to_dict("records"):
        try:
            skipped = set(json.loads(rec.get("skipped_stages") or "[]"))
        except (TypeError, json.JSONDecodeError):
            skipped = set()
        out.append({"label": rec["label"],
                    "stages": [{"skipped": s in skipped, "ms": rec.get(f"stage_ms.{s}")} for s in stages],
                    "gpu_ms": rec.get("gpu_ms"), "frame_ms": rec.get("frame_ms"), "frame_ms_iqr": rec.get("frame_ms_iqr")})
    return out


def speedup(rows: pd.DataFrame) -> dict | None:
    """Equal-error speed-up over the Mitsuba path tracer per component of one view; None without any."""
    comps = [c for c in SPEEDUP_COMPONENTS if f"mse.{c}" in rows.columns
             and pd.to_numeric(rows[f"speedup.{c}"], errors="coerce").notna().any()]
    if not comps:
        return None
    body = [{"label": rec["label"], "frame_ms": rec.get("frame_ms"),
             "components": [{"mse": rec.get(f"mse.{c}"), "mitsuba_ms": rec.get(f"mitsuba_ms.{c}"),
                             "speedup": rec.get(f"speedup.{c}"),
                             "lower_bound": bool(rec.get(f"speedup_lower_bound.{c}")),
                             "extrapolated": bool(rec.get(f"speedup_extrapolated.{c}"))} for c in comps]}
            for rec in rows.to_dict("records")]
    return {"components": comps, "rows": body}


def pareto_rows(front: pd.DataFrame) -> list[dict]:
    return [{"label": r["label"], "frame_ms": r["frame_ms"], "mse": r["mse.indirect"]} for r in front.to_dict("records")]


def scaling_rows(fits: dict) -> list[dict]:
    """Per method: the fitted slope, the largest scene's triangle count and its frame time."""
    return [{"method": m, "slope": slope, "triangles": int(n.max()), "frame_ms": float(t.max())}
            for m, (n, t, slope) in fits.items()]


def scene_facts(manifest: dict) -> list[dict]:
    facts, purposes = manifest.get("scene_facts", {}), manifest.get("scene_purposes", {})
    keys = ("triangle_count", "vertex_count", "total_area_m2", "area_median_m2", "scene_radius", "closed",
            "divergent_count")
    return [dict({k: f.get(k) for k in keys}, name=name, purpose=purposes.get(name, "")) for name, f in facts.items()]


def noise_floors(table: pd.DataFrame) -> dict | None:
    """Per view, each reference component's noise floor MSE and spp; None without references."""
    cols = [c for c in REFERENCE_COMPONENTS if f"reference_noise_floor.{c}" in table.columns]
    if not cols:
        return None
    rows = []
    for (scene, view), g in table.groupby(["scene", "view"], sort=False):
        rec = g.iloc[0]
        rows.append({"view": f"{scene}/{view}", "cells": [{"floor": rec.get(f"reference_noise_floor.{c}"),
                                                           "spp": rec.get(f"reference_spp.{c}")} for c in cols]})
    return {"header": ["view"] + [h for c in cols for h in (f"noise floor MSE ({c})", "spp")], "rows": rows}


def metric_docs(metric_cols: list[str]) -> list[tuple[str, str]]:
    used = {c.split(".", 1)[0] for c in metric_cols}
    used |= {m[len("rel_"):] for m in used if m.startswith("rel_")}   # the absolute forms of the shown ones
    return [(m, METRIC_DOCS.get(m, "description unavailable")) for m in METRIC_NAMES + DECOMPOSITION_METRICS
            if m in METRICS or m in used]


def run_info(manifest: dict, run_dir: Path) -> dict:
    """The run's folder, dates, phases, machine, package versions and arguments, as (key, value) pairs."""
    general = {"run folder": run_dir.resolve(), "created": manifest.get("created"),
               "git commit": manifest.get("git_commit"), "results schema": manifest.get("schema_version")}
    phases = {k: f"{float(v):.1f} s" for k, v in (manifest.get("phases_s") or {}).items()}
    predicted = manifest.get("phases_predicted_vs_actual") or {}
    if predicted:   # the cost plan made before the run (bench.run.budget) beside what it took
        phases = {k: f"{v['actual_s']:.1f} s (predicted {v['predicted_s']:.1f} s)" for k, v in predicted.items()}
    plan = manifest.get("plan") or {}
    if plan.get("budget_s"):
        rows = ", ".join(f"{n} {status}" for status, n in sorted((plan.get("rows") or {}).items()))
        phases["budget"] = f"{float(plan['budget_s']):.0f} s ({rows})"
    if phases and manifest.get("harness_overhead") is not None:
        phases["harness overhead"] = f"{100 * float(manifest['harness_overhead']):.1f}% of the rendered rows' time"
    return {"general": list(general.items()), "phases": list(phases.items()),
            "machine": list(manifest.get("machine", {}).items()), "versions": list(manifest.get("versions", {}).items()),
            "arguments": json.dumps(manifest.get("arguments", {}), indent=2, default=str)}
