"""The page of a `gibench stress` folder (`stress.csv`, `stress.json`): `stress.html`, rendered from
templates/stress.html with the verdict matrix per scene and the failure and row tables."""
from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from .render import MISSING, fmt, write_page

STRESS_TABLE = "stress.csv"
VERDICT_TEXT = {"pass": "pass", "fail": "FAIL", "documented": "doc.", "skipped": "skip"}
WORST_FIRST = ("fail", "documented", "pass", "skipped")
VERDICT_FIGURES = ("change", "change_indirect", "mean_change", "tolerance", "nan_pixels", "inf_pixels",
                   "negative_pixels", "error_change")
TEXT_COLUMNS = ("scene", "perturbation", "target", "name", "status", "params")
WRAP_COLUMNS = ("note", "criterion")
DETAIL_COLUMNS = ("scene", "perturbation", "target", "name", "params", "verdict", "nan_pixels", "inf_pixels",
                  "negative_pixels", "change", "change_indirect", "mean_change", "tolerance", "error_base", "error",
                  "error_change", "note")


def verdict_cell(rows: pd.DataFrame) -> dict | None:
    """One matrix cell: the worst verdict of `rows`, a short figure and every figure for the tooltip;
    None when there is no row."""
    if rows.empty:
        return None
    verdicts = [v for v in WORST_FIRST if v in set(rows["verdict"].astype(str))]
    worst = verdicts[0] if verdicts else "skipped"
    tips = []
    for r in rows.to_dict("records"):
        figures = ", ".join(f"{k} {fmt(r.get(k))}" for k in VERDICT_FIGURES if fmt(r.get(k)) != MISSING)
        tips.append(f"{r['perturbation']}: {r['verdict']}; {figures}; {r.get('note') or ''}")
    change = rows["change"] if "change" in rows.columns else pd.Series(dtype=float)
    shown = pd.to_numeric(change, errors="coerce").max() if len(rows) == 1 else None
    first_problem = str(rows["note"].iloc[0]).split(";")[0].strip() if len(rows) == 1 and "note" in rows else ""
    note = ""
    if worst in ("fail", "documented") and first_problem and " > " in first_problem:
        note = first_problem  # the figure that failed, with its tolerance
    elif shown is not None and np.isfinite(shown):
        note = fmt(shown, 2)
    if len(rows) > 1:
        note = ", ".join(f"{n} {v}" for v, n in rows["verdict"].astype(str).value_counts().items())
    return {"worst": worst, "text": VERDICT_TEXT.get(worst, worst), "note": note, "title": "\n".join(tips)}


def verdict_matrix(table: pd.DataFrame) -> list[dict]:
    """Per scene: a row per target (method or reference), a cell per perturbation, and the method's
    parameter extremes summed in the last cell."""
    out = []
    scene_rows = table[(table["scene"] != "-") & table["target"].isin(["method", "reference"])]
    for scene, g in scene_rows.groupby("scene", sort=False):
        columns = [p for p in dict.fromkeys(g["perturbation"]) if not str(p).startswith("params:")]
        rows = []
        for target, name in dict.fromkeys(zip(g["target"], g["name"])):
            mine = g[(g["target"] == target) & (g["name"] == name)]
            params = mine[mine["perturbation"].astype(str).str.startswith("params:")]
            rows.append({"label": name if target == "method" else f"reference: {name}",
                         "cells": [verdict_cell(mine[mine["perturbation"] == p]) for p in columns]
                         + [verdict_cell(params) if target == "method" else None]})
        out.append({"scene": scene, "view": g["view"].iloc[0], "header": ["target"] + columns + ["parameter extremes"],
                    "rows": rows})
    return out


def _kind(column: str) -> str:
    if column == "verdict":
        return "verdict"
    if column in TEXT_COLUMNS:
        return "text"
    return "wrap" if column in WRAP_COLUMNS else "num"


def row_table(rows: pd.DataFrame, columns: list[str]) -> dict:
    """Stress rows as (column, kind) pairs and cells of (kind, value); a missing note is empty."""
    kinds = [(c, _kind(c)) for c in columns]
    body = []
    for r in rows.to_dict("records"):
        cells = []
        for c, kind in kinds:
            v = r.get(c)
            cells.append((kind, "" if kind == "wrap" and (v is None or v != v) else v))
        body.append(cells)
    return {"columns": kinds, "rows": body}


def build_stress_report(run_dir, out_dir=None) -> Path:
    """The page of a `gibench stress` folder (`stress.csv`, `stress.json`): `<out_dir or run_dir>/stress.html`."""
    run_dir = Path(run_dir)
    table = pd.read_csv(run_dir / STRESS_TABLE, keep_default_na=True)
    for col in ("note", "criterion", "status", "params"):
        if col in table.columns:
            table[col] = table[col].astype(object).where(table[col].notna(), "").astype(str)
    meta_path = run_dir / "stress.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    out_dir = Path(out_dir) if out_dir is not None else run_dir
    assets = out_dir / "assets"
    assets.mkdir(parents=True, exist_ok=True)
    css = resources.files(__package__) / "static" / "report.css"
    (assets / "report.css").write_text(css.read_text(encoding="utf-8"), encoding="utf-8")

    counts = table["verdict"].astype(str).value_counts().to_dict() if len(table) else {}
    cfg = meta.get("config", {})
    detail = [c for c in DETAIL_COLUMNS if c in table.columns]
    bad = table[table["verdict"].isin(["fail", "documented"])]
    other = table[table["scene"] == "-"]
    context = {
        "title": f"gibench stress: {run_dir.resolve().name}",
        "counts": [(counts.get(k, 0), k) for k in ("pass", "fail", "documented", "skipped")],
        "scenes": ", ".join(map(str, cfg.get("scenes", []))), "width": cfg.get("width"), "height": cfg.get("height"),
        "quick": bool(cfg.get("quick")), "references": meta.get("references", "?"),
        "commit": str(meta.get("git_commit") or "?")[:12],
        "matrix": verdict_matrix(table),
        "other": row_table(other, ["perturbation", "target", "verdict", "criterion", "note"]) if len(other) else None,
        "failures": row_table(bad, detail) if len(bad) else None,
        "all_rows": row_table(table, detail + ["criterion"]),
        "tolerance_floor": meta.get("tolerance_floor"), "noise_factor": meta.get("noise_factor"),
        "meta": json.dumps(meta, indent=2, default=str),
    }
    return write_page(out_dir / "stress.html", "stress.html", **context)
