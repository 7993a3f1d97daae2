"""Report sections that compare methods with each other and with the papers' claims:
the equal-time / equal-error matrices (bench.analysis.compare) and the paper-reproduction table
(bench.analysis.reproduction). Both tables are also written as CSV beside the report's data."""
from __future__ import annotations

import pandas as pd

from bench.protocol import results as store
from bench.analysis.compare import comparison_table
from bench.analysis.reproduction import reproduction_table

MATRIX_ERROR = "mse.combined"
KINDS = (("error_at_equal_time", "Error at equal time",
          "row method's error at the column method's default frame time / the column method's error (< 1: the row "
          "method is more accurate in the same time)"),
         ("time_at_equal_error", "Time at equal error",
          "row method's time to reach the column method's default error / the column method's time (< 1: the row "
          "method is faster to the same error)"))


def _ratio_cell(rec, fmt, esc) -> str:
    if rec is None:
        return "<td class='missing'>\u2014</td>"
    text = fmt(rec["ratio"])
    if text == "\u2014":
        return "<td class='missing' title='outside the row method&#39;s curve'>\u2014</td>"
    lo, hi = rec["lo"], rec["hi"]
    title = f"interval {fmt(lo)} .. {fmt(hi)} (timing IQR, reference noise floor)"
    cls = ""
    if hi < 1:
        cls = "best"
    elif lo > 1:
        cls = "worse"
    # a capped value is an upper bound: the row method has no slower rung to spend that time on
    # (its best error is shown) or no faster rung to stop at (its fastest time is shown)
    mark = "&le;&thinsp;" if rec["capped"] else ""
    return f"<td class='{cls}' title='{esc(title)}'>{mark}{text}<span class='ival'> [{fmt(lo, 2)}, {fmt(hi, 2)}]</span></td>"


def between_methods_html(table: pd.DataFrame, run_dir, report_dir, fmt, esc, html_table) -> str:
    comp = comparison_table(table)
    if comp.empty:
        return "<p class='note'>Fewer than two methods with error figures on a view: nothing to compare.</p>"
    store.atomic_write_text(report_dir / "data" / "comparisons.csv", comp.to_csv(index=False))
    parts = ["<p class='note'>Each method's rows on a view (its quality-ladder rungs) make its time-vs-error curve "
             "(lower envelope, log-log interpolation, never extended past its rungs). Ratios are taken at each column "
             f"method's default rung, error = {esc(MATRIX_ERROR)} (the whole image against Mitsuba). Brackets: the "
             "interval over the timing IQRs and the reference noise floor; green: the interval is below 1, red: above "
             "1. &le;: an upper bound (the row method has no slower rung to use that time, or no faster rung to stop at "
             "that error). \u2014: the row method's curve does not reach that time (too slow) or that error. All pairs and both error columns: "
             "<a href='data/comparisons.csv'>comparisons.csv</a>.</p>"]
    sub = comp[comp["error"] == MATRIX_ERROR]
    for (scene, view), g in sub.groupby(["scene", "view"], sort=True):
        methods = list(dict.fromkeys(list(g["method_b"]) + list(g["method_a"])))
        parts.append(f"<h3>{esc(scene)} / {esc(view)}</h3>")
        for kind, title, doc in KINDS:
            k = g[g["kind"] == kind].set_index(["method_a", "method_b"])
            body = []
            for a in methods:
                cells = [f"<td class='l'>{esc(a)}</td>"]
                for b in methods:
                    if a == b:
                        cells.append("<td class='missing'>1</td>")
                        continue
                    rec = k.loc[(a, b)].to_dict() if (a, b) in k.index else None
                    if rec is not None:
                        rec["kind"] = kind
                    cells.append(_ratio_cell(rec, fmt, esc))
                body.append("<tr>" + "".join(cells) + "</tr>")
            parts.append(f"<p class='note'><b>{esc(title)}</b>: {esc(doc)}.</p>")
            parts.append(html_table([f"{title.lower()} \u2193 vs \u2192"] + methods, body, extra_class="matrix"))
    return "\n".join(parts)


def reproduction_html(table: pd.DataFrame, manifest: dict, report_dir, fmt, esc, html_table) -> str:
    facts = manifest.get("scene_facts", {}) or {}
    triangles = {name: f.get("triangle_count") for name, f in facts.items() if isinstance(f, dict)}
    rep = reproduction_table(table, triangles)
    if rep.empty:
        return "<p class='note'>No rows of the methods whose papers make checkable claims.</p>"
    store.atomic_write_text(report_dir / "data" / "reproduction.csv", rep.to_csv(index=False))
    body = []
    for r in rep.to_dict("records"):
        cls = {"reproduced": "best", "not reproduced": "worse"}.get(r["status"], "")
        body.append("<tr>" + f"<td class='l'>{esc(r['paper'])}</td><td class='l'>{esc(r['claim'])}</td>"
                    f"<td class='l'>{esc(r['scene'])}/{esc(r['view'])}</td><td>{fmt(r['paper_value'])}</td>"
                    f"<td>{fmt(r['run_value'])}</td><td class='l {cls}'>{esc(r['status'])}</td>"
                    f"<td class='l wrap'>{esc(r['note'])}</td></tr>")
    return ("<p class='note'>The papers' published figures beside this run's (ratios only: the papers used other GPUs "
            "and resolutions). Rules in <code>bench/reproduction.py</code>; table: "
            "<a href='data/reproduction.csv'>reproduction.csv</a>.</p>"
            + html_table(["paper", "claim", "view", "paper", "this run", "status", "note"], body, left=3))
