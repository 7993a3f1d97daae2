"""The gate's presentation: a `GateResult` (bench.gate.compare) as a Markdown report."""
from __future__ import annotations

import math

import numpy as np

MAX_TABLE_ROWS = 60
_CORRECTION_NAMES = {"holm": "Holm", "bh": "Benjamini-Hochberg"}


def report_markdown(result) -> str:
    """The gate's report of a `GateResult`: its rules, findings, rows not compared, notes, verdict."""
    head = "FAIL" if result.exit_code == 1 else ("ERROR" if result.exit_code == 2 else "PASS")
    lines = [f"## gibench gate: {head}", ""]
    lines.append(f"- baseline: `{result.baseline_dir}` ({_describe(result.baseline_info, result.baseline_rows)})")
    lines.append(f"- candidate: `{result.candidate_dir}` ({_describe(result.candidate_info, result.candidate_rows)})")
    what = (f"per-run median frame time relative to `{result.relative_to}` in the same run" if result.relative_to
            else "per-run median frame time")
    lines.append(f"- timing ({result.baseline_runs} vs {result.candidate_runs} run(s); {what}): regression when the "
                 f"ratio of geometric means > {1 + result.time_threshold:.3g} (+{result.time_threshold * 100:.3g}%) "
                 f"and the one-sided Welch t-test on log times, {_CORRECTION_NAMES[result.correction]}-adjusted "
                 f"over rows, gives p < {result.alpha:g}; needs >= {result.min_runs} rendered runs per side")
    columns = f"{', '.join(f'`{m}`' for m in result.metrics)} only" if result.metrics else "every error column"
    lines.append(f"- error ({columns}): regression when a metric is worse by > {result.error_threshold * 100:.3g}% "
                 f"relative (and above its absolute floor; an error over frames also beyond its 95% interval); MSE "
                 f"minus the references' noise floor; only against identical references (key and spp)")
    lines.append("")
    if result.error:
        lines += [verdict_line(result), ""]
        return "\n".join(lines)
    finding_header = ["row", "check", "baseline", "candidate", "change", "p", "note"]
    for title, items in (("Regressions", result.regressions), ("Improvements", result.improvements)):
        lines.append(f"### {title} ({len(items)})")
        if items:
            lines += _by_row(items)
            lines.append("")
            shown = items[:MAX_TABLE_ROWS]
            lines += _table(finding_header, [[f.row, f.check, _fmt(f.baseline), _fmt(f.candidate), f.change,
                                              _fmt(f.p_value), f.note] for f in shown])
            if len(items) > len(shown):
                lines.append(f"... and {len(items) - len(shown)} more")
        lines.append("")
    if result.undecidable_timing:
        lines.append(f"### Timing not tested ({len(result.undecidable_timing)})")
        lines += _table(["row", "ratio", "rendered runs (baseline/candidate)", "reason"],
                        [[r, f"x{ratio:.3f}" if math.isfinite(ratio) else "–", f"{nb}/{nc}", why]
                         for r, ratio, nb, nc, why in result.undecidable_timing[:MAX_TABLE_ROWS]])
        if len(result.undecidable_timing) > MAX_TABLE_ROWS:
            lines.append(f"... and {len(result.undecidable_timing) - MAX_TABLE_ROWS} more")
        lines.append(f"Timing is gated on repetitions: give each side >= {result.min_runs} run folders "
                     f"(`gibench gate A1,A2,A3 B1,B2,B3`, runs interleaved in time, rendered with --force or "
                     f"without a shared row cache).")
        lines.append("")
    if result.not_comparable:
        lines.append(f"### Not comparable ({len(result.not_comparable)})")
        lines += _table(["row", "reason"], [list(x) for x in result.not_comparable])
        lines.append("")
    for title, items in (("Missing in candidate", result.missing), ("New in candidate", result.new)):
        if items:
            lines.append(f"### {title} ({len(items)})")
            lines += [f"- {r}" for r in items]
            lines.append("")
    if result.skipped_baseline:
        lines.append(f"### Baseline rows not ok, skipped ({len(result.skipped_baseline)})")
        lines += [f"- {r}: {s}" for r, s in result.skipped_baseline]
        lines.append("")
    if result.notes:
        lines.append("### Notes")
        lines += [f"- {n}" for n in result.notes]
        lines.append("")
    lines.append(verdict_line(result))
    return "\n".join(lines) + "\n"


def verdict_line(result) -> str:
    """The last line of the report: PASS, FAIL or ERROR and why (and what it could not see: an
    incomplete run, checks a side's table could not support)."""
    caveats = [f"{len(result.incomplete)} incomplete run(s)"] if result.incomplete else []
    caveats += [f"not checked: {what}" for what in result.unchecked]
    if result.error:
        return f"**Verdict: ERROR** — {result.error}"
    if result.regressions:
        rows = len({f.row for f in result.regressions})
        tail = f" ({', '.join(caveats)})" if caveats else ""
        return (f"**Verdict: FAIL** — {len(result.regressions)} regression(s) in {rows} of {result.compared} "
                f"compared row(s){tail}")
    extra = list(caveats)
    if result.not_comparable:
        extra.append(f"{len(result.not_comparable)} not comparable")
    if result.missing:
        extra.append(f"{len(result.missing)} missing in candidate")
    if result.undecidable_timing:
        extra.append(f"timing of {len(result.undecidable_timing)} row(s) not tested")
    tail = f" ({', '.join(extra)})" if extra else ""
    if result.compared == 0:
        return f"**Verdict: PASS, but nothing was compared**{tail}"
    timed = f" (timing of {result.timing_tested} tested)" if result.timing_tested else ""
    return f"**Verdict: PASS** — {result.compared} row(s) compared{timed}, no regression{tail}"


# ---------------------------------------------------------------------------- formatting
def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            return "–"
        return f"{v:.4g}"
    return str(v)


def _table(header: list, rows: list) -> list[str]:
    esc = lambda s: str(s).replace("|", "\\|")
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(esc(c) for c in r) + " |" for r in rows]
    return out


def _describe(info: dict, n_rows: int) -> str:
    parts = [f"{n_rows} rows"]
    if info.get("git_commit"):
        parts.append(f"commit {str(info['git_commit'])[:12]}")
    machine = info.get("machine") or {}
    if machine.get("gl_renderer"):
        parts.append(str(machine["gl_renderer"]))
    return ", ".join(parts)


def _by_row(items: list) -> list[str]:
    """One line per row: the timing finding, the status change, how many error columns moved."""
    rows: dict = {}
    for f in items:
        rows.setdefault(f.row, []).append(f)
    out = []
    for row, fs in rows.items():
        parts = []
        for f in fs:
            if f.check == "status":
                parts.append(f"status {f.baseline} -> {f.candidate}")
            elif f.check.startswith("frame_ms"):
                parts.append(f"frame time {f.change} (p={_fmt(f.p_value)})")
        errors = [f for f in fs if f.check != "status" and not f.check.startswith("frame_ms")]
        if errors:
            worst = max(errors, key=lambda f: _rel(f.baseline, f.candidate))
            parts.append(f"{len(errors)} error column(s), most: {worst.check} {_fmt(worst.baseline)} -> "
                         f"{_fmt(worst.candidate)} ({worst.change})")
        out.append(f"- **{row}**: " + "; ".join(parts))
    return out


def _rel(base, cand) -> float:
    try:
        b, c = float(base), float(cand)
    except (TypeError, ValueError):
        return 0.0
    return abs(c - b) / abs(b) if b != 0 else (math.inf if c != b else 0.0)


def percent_change(base: float, cand: float) -> str:
    """A finding's change of an error value: "+12.3%"."""
    if base == 0:
        return "+inf%" if cand > 0 else "0%"
    return f"{(cand - base) / abs(base) * 100:+.1f}%"
