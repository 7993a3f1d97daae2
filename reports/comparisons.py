"""The data of the report sections that compare methods with each other and with the papers'
claims: the equal-time / equal-error matrices (bench.analysis.compare) and the paper-reproduction
table (bench.analysis.reproduction), rendered by templates/sections/between.html and papers.html.
Both tables are also written as CSV beside the report's data."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.protocol import results as store
from bench.analysis.compare import ERROR_COLUMNS, comparison_table
from bench.analysis.reproduction import reproduction_table

MATRIX_ERROR = "mse.combined"
KINDS = (("error_at_equal_time", "Error at equal time",
          "row method's error at the column method's default frame time / the column method's error (< 1: the row "
          "method is more accurate in the same time)"),
         ("time_at_equal_error", "Time at equal error",
          "row method's time to reach the column method's default error / the column method's time (< 1: the row "
          "method is faster to the same error)"))


def _ratio(kind_rows: pd.DataFrame, a: str, b: str) -> dict:
    """One matrix cell: `same` on the diagonal, `none` for a pair not compared, else the ratio,
    its interval and whether it is capped (an upper bound)."""
    if a == b:
        return {"kind": "same"}
    if (a, b) not in kind_rows.index:
        return {"kind": "none"}
    rec = kind_rows.loc[(a, b)]
    return {"kind": "ratio", "ratio": rec["ratio"], "lo": rec["lo"], "hi": rec["hi"], "capped": bool(rec["capped"])}


def between_methods(table: pd.DataFrame, report_dir: Path, errors: tuple = ERROR_COLUMNS,
                    matrix_error: str = MATRIX_ERROR) -> dict | None:
    """Per view, both matrices of ratios between the methods' curves on `matrix_error`; None when no
    view has two methods with error figures. Writes `data/comparisons.csv` (all pairs, every column
    of `errors`: any error column, e.g. "rel_bias2.indirect" or "variance.indirect" of the error over frames)."""
    errors = tuple(dict.fromkeys(tuple(errors) + (matrix_error,)))
    comp = comparison_table(table, errors=errors)
    if comp.empty:
        return None
    store.atomic_write_text(report_dir / "data" / "comparisons.csv", comp.to_csv(index=False))
    views = []
    for (scene, view), g in comp[comp["error"] == matrix_error].groupby(["scene", "view"], sort=True):
        methods = list(dict.fromkeys(list(g["method_b"]) + list(g["method_a"])))
        kinds = []
        for kind, title, doc in KINDS:
            k = g[g["kind"] == kind].set_index(["method_a", "method_b"])
            kinds.append({"title": title, "doc": doc,
                          "rows": [{"method": a, "cells": [_ratio(k, a, b) for b in methods]} for a in methods]})
        views.append({"scene": scene, "view": view, "methods": methods, "kinds": kinds})
    return {"error": matrix_error, "views": views}


def reproduction(table: pd.DataFrame, manifest: dict, report_dir: Path) -> list[dict]:
    """The papers' claims against this run (rows of bench.analysis.reproduction.COLUMNS); writes
    `data/reproduction.csv` when there is any."""
    facts = manifest.get("scene_facts", {}) or {}
    triangles = {name: f.get("triangle_count") for name, f in facts.items() if isinstance(f, dict)}
    rep = reproduction_table(table, triangles)
    if rep.empty:
        return []
    store.atomic_write_text(report_dir / "data" / "reproduction.csv", rep.to_csv(index=False))
    return rep.to_dict("records")
