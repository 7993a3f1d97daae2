"""A run's quick summary (Markdown + a plain HTML page), written at the end of every run:
one table of status, frame time and indirect error per scene and method (with the split of the
relative error over frames into bias2 and variance, and the flicker, when the rows have them).
The full comparison report with images and plots is `gibench report` (reports/)."""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np
import pandas as pd

from bench.protocol.results import load_manifest
from bench.protocol.results import atomic_write_text, load_results


def _fmt(v, digits=3) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


SUMMARY_ERRORS = ("mse.indirect", "relmse.indirect", "rel_bias2.indirect", "rel_variance.indirect",
                  "rel_flicker.indirect", "mse.combined")


def summary_table(df: pd.DataFrame) -> pd.DataFrame:
    cols = ["scene", "view", "method", "status", "frame_ms", "gpu_ms"]
    cols += [c for c in SUMMARY_ERRORS if c in df.columns]
    out = df[[c for c in cols if c in df.columns]].copy()
    if "image_dir" in df.columns:  # `<method>` for default parameters, `<method>@<hash>` otherwise
        out["method"] = df["image_dir"].map(lambda p: Path(str(p)).name if isinstance(p, str) else None).fillna(df["method"])
    return out


def to_markdown(table: pd.DataFrame) -> str:
    header = "| " + " | ".join(table.columns) + " |"
    sep = "|" + "|".join("---" for _ in table.columns) + "|"
    rows = ["| " + " | ".join(_fmt(v) for v in rec) + " |" for rec in table.itertuples(index=False)]
    return "\n".join([header, sep] + rows)


def write_summary(run_dir: Path) -> tuple[Path, Path]:
    run_dir = Path(run_dir)
    df = load_results(run_dir)
    manifest = load_manifest(run_dir)
    machine = manifest.get("machine", {})
    table = summary_table(df)
    md = (f"# gibench run {run_dir.name}\n\n"
          f"Machine: {machine.get('gl_renderer', '?')} on {machine.get('cpu', '?')}; "
          f"commit {manifest.get('git_commit', '?')}\n\n" + to_markdown(table) + "\n\n"
          "Times in ms (median over timed frames, GPU finished); errors against Mitsuba ('–': no reference).\n")
    md_path = run_dir / "summary.md"
    atomic_write_text(md_path, md)
    body = table.to_html(index=False, na_rep="–", float_format=lambda v: f"{v:.3g}", border=0)
    page = ("<!doctype html><meta charset='utf-8'><title>gibench " + html.escape(run_dir.name) + "</title>"
            "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
            "td,th{padding:.2em .6em;border-bottom:1px solid #ccc;text-align:right}"
            "td:nth-child(-n+4),th:nth-child(-n+4){text-align:left}</style>"
            f"<h1>gibench run {html.escape(run_dir.name)}</h1><p>{html.escape(machine.get('gl_renderer', ''))}"
            f" &middot; {html.escape(machine.get('cpu', ''))} &middot; commit {html.escape(str(manifest.get('git_commit', '')))}</p>"
            + body + "<p>Times in ms (median, GPU finished); errors against Mitsuba (&ndash;: no reference).</p>")
    html_path = run_dir / "summary.html"
    atomic_write_text(html_path, page)
    return md_path, html_path
