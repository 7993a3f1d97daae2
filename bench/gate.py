"""The regression gate: `gibench gate BASELINE CANDIDATE` compares two runs row by row.

Rows are matched on (scene, view, method, params, seed). For each matched row:

* Status: a baseline row that is not ok/cached is skipped (nothing to compare against); a
  candidate row that no longer renders (failed or skipped) where the baseline rendered is a
  regression.
* Comparability: a different `method_version` (hash of the method's sources, shaders and the
  shared GL core) or a different resolution makes the row *not comparable*: it is listed, it is
  not a failure (asv's rule: results of edited code are never compared as if equal). Pass
  `compare_changed_versions=True` to compare such rows anyway (each finding is then marked
  "method changed"): that is the mode to gate a change *to* a method.
* Timing: a regression when the ratio of median frame times (candidate / baseline, CPU wall
  ms per frame with the GPU finished) exceeds 1 + time_threshold AND a one-sided Mann-Whitney
  U test (scipy, candidate > baseline on the per-frame samples) gives p < alpha. With n and m
  frames the smallest exact p is 1 / C(n + m, n): 3 vs 3 frames can never go below 0.05, so the
  gate needs >= 4 timed frames per row for alpha = 0.05; the summary says when it cannot decide.
  An improvement is the mirror image (ratio < 1 / (1 + threshold), p < alpha the other way).
* Error: every `<metric>.<component>` column of bench.metrics.METRICS present in both runs; a
  regression when candidate > baseline * (1 + error_threshold) and candidate - baseline exceeds
  the metric's absolute floor (ERROR_ABS_FLOOR, so 0 vs 1e-12 is not a regression). A baseline
  value of 0 with a candidate above the floor is a regression.
* Rows of the baseline missing from the candidate, and new rows, are listed, not failures (a
  candidate may run a subset). No matched row at all is bad input.

Exit code: 0 pass, 1 at least one regression, 2 bad input (missing run folder, no common row).
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.metrics import METRICS
from bench.results import load_results

OK_STATUSES = ("ok", "cached")
TIMING_COLUMN = "samples.frame_ms"
# Absolute floors below which an error change is noise, not a regression: float32 images give
# metric noise well below these; each is far below any error a GI method actually makes.
ERROR_ABS_FLOOR = {"mse": 1e-10, "relmse": 1e-8, "smape": 1e-6, "dssim": 1e-6, "flip_mean": 1e-6,
                   "flip_median": 1e-6, "ciede2000": 1e-4}
_ERROR_COLUMN = re.compile(r"^(%s)\.([A-Za-z0-9_]+)$" % "|".join(re.escape(m) for m in METRICS))


@dataclass
class Finding:
    row: str              # scene/view/method label (seed)
    check: str            # "frame_ms", "status" or an error column
    baseline: object
    candidate: object
    change: str           # "+12.3%" / "x1.50" / "ok -> failed"
    p_value: float | None = None
    note: str = ""


@dataclass
class GateResult:
    baseline_dir: Path
    candidate_dir: Path
    time_threshold: float
    error_threshold: float
    alpha: float
    compared: int = 0
    baseline_rows: int = 0
    candidate_rows: int = 0
    regressions: list = field(default_factory=list)
    improvements: list = field(default_factory=list)
    not_comparable: list = field(default_factory=list)   # (row, reason)
    missing: list = field(default_factory=list)          # rows of the baseline absent from the candidate
    new: list = field(default_factory=list)              # rows of the candidate absent from the baseline
    skipped_baseline: list = field(default_factory=list)  # (row, status) baseline rows not ok
    undecidable_timing: list = field(default_factory=list)  # (row, ratio, n_base, n_cand, min_p)
    notes: list = field(default_factory=list)
    error: str | None = None
    baseline_info: dict = field(default_factory=dict)
    candidate_info: dict = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        if self.error:
            return 2
        return 1 if self.regressions else 0

    def verdict(self) -> str:
        if self.error:
            return f"**Verdict: ERROR** — {self.error}"
        if self.regressions:
            rows = len({f.row for f in self.regressions})
            return (f"**Verdict: FAIL** — {len(self.regressions)} regression(s) in {rows} of {self.compared} "
                    f"compared row(s)")
        extra = []
        if self.not_comparable:
            extra.append(f"{len(self.not_comparable)} not comparable")
        if self.missing:
            extra.append(f"{len(self.missing)} missing in candidate")
        if self.undecidable_timing:
            extra.append(f"{len(self.undecidable_timing)} slower row(s) too few frames to test")
        tail = f" ({', '.join(extra)})" if extra else ""
        if self.compared == 0:
            return f"**Verdict: PASS, but nothing was compared**{tail}"
        return f"**Verdict: PASS** — {self.compared} row(s) compared, no regression{tail}"

    def markdown(self) -> str:
        head = "FAIL" if self.exit_code == 1 else ("ERROR" if self.exit_code == 2 else "PASS")
        lines = [f"## gibench gate: {head}", ""]
        lines.append(f"- baseline: `{self.baseline_dir}` ({_describe(self.baseline_info, self.baseline_rows)})")
        lines.append(f"- candidate: `{self.candidate_dir}` ({_describe(self.candidate_info, self.candidate_rows)})")
        lines.append(f"- timing: regression when median frame time ratio > {1 + self.time_threshold:.3g} "
                     f"(+{self.time_threshold * 100:.3g}%) and "
                     f"one-sided Mann-Whitney p < {self.alpha:g}")
        lines.append(f"- error: regression when a metric is worse by > {self.error_threshold * 100:.3g}% relative "
                     f"(and above its absolute floor)")
        lines.append("")
        if self.error:
            lines += [self.verdict(), ""]
            return "\n".join(lines)
        finding_header = ["row", "check", "baseline", "candidate", "change", "p", "note"]
        for title, items in (("Regressions", self.regressions), ("Improvements", self.improvements)):
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
        if self.undecidable_timing:
            lines.append(f"### Slower, but too few frames to test ({len(self.undecidable_timing)})")
            lines += _table(["row", "ratio", "frames (baseline/candidate)", "smallest p"],
                            [[r, f"x{ratio:.3f}", f"{nb}/{nc}", f"{mp:.3g}"]
                             for r, ratio, nb, nc, mp in self.undecidable_timing])
            lines.append(f"The Mann-Whitney test cannot reach p < {self.alpha:g} with these frame counts: run with "
                         f"more timed frames (--frames >= 4 for alpha = 0.05).")
            lines.append("")
        if self.not_comparable:
            lines.append(f"### Not comparable ({len(self.not_comparable)})")
            lines += _table(["row", "reason"], [list(x) for x in self.not_comparable])
            lines.append("")
        for title, items in (("Missing in candidate", self.missing), ("New in candidate", self.new)):
            if items:
                lines.append(f"### {title} ({len(items)})")
                lines += [f"- {r}" for r in items]
                lines.append("")
        if self.skipped_baseline:
            lines.append(f"### Baseline rows not ok, skipped ({len(self.skipped_baseline)})")
            lines += [f"- {r}: {s}" for r, s in self.skipped_baseline]
            lines.append("")
        if self.notes:
            lines.append("### Notes")
            lines += [f"- {n}" for n in self.notes]
            lines.append("")
        lines.append(self.verdict())
        return "\n".join(lines) + "\n"


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


MAX_TABLE_ROWS = 60


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


def _pct(base: float, cand: float) -> str:
    if base == 0:
        return "+inf%" if cand > 0 else "0%"
    return f"{(cand - base) / abs(base) * 100:+.1f}%"


# ---------------------------------------------------------------------------- loading
def _load_run(path: Path, role: str):
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{role} run folder not found: {path}")
    if not path.is_dir():
        raise FileNotFoundError(f"{role} is not a run folder: {path}")
    try:
        df = load_results(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{role} run folder {path} has no results.csv or results.parquet") from None
    manifest = {}
    mpath = path / "manifest.json"
    if mpath.is_file():
        try:
            manifest = json.loads(mpath.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{role} manifest {mpath} is not valid JSON ({exc.msg})") from None
    missing = [c for c in ("scene", "view", "method", "params", "seed", "status") if c not in df.columns]
    if missing and len(df):
        raise ValueError(f"{role} results in {path} lack column(s) {', '.join(missing)}")
    return df, manifest


def _canonical_params(value) -> str:
    if isinstance(value, str):
        try:
            return json.dumps(json.loads(value), sort_keys=True, separators=(",", ":"))
        except json.JSONDecodeError:
            return value
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, separators=(",", ":"))
    return "{}" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def _seed(value) -> int | str:
    try:
        f = float(value)
        return int(f) if math.isfinite(f) else str(value)
    except (TypeError, ValueError):
        return str(value)


def _key(rec: dict) -> tuple:
    return (str(rec["scene"]), str(rec["view"]), str(rec["method"]), _canonical_params(rec["params"]),
            _seed(rec["seed"]))


def _label(rec: dict) -> str:
    """scene/view/method[@params-hash] (seed N when not 0)."""
    method = str(rec["method"])
    image_dir = rec.get("image_dir")
    if isinstance(image_dir, str) and image_dir:
        method = Path(image_dir).name
    label = f"{rec['scene']}/{rec['view']}/{method}"
    seed = _seed(rec["seed"])
    return label if seed == 0 else f"{label} (seed {seed})"


def _index(df, role: str, notes: list) -> dict:
    out: dict = {}
    for rec in df.to_dict("records"):
        key = _key(rec)
        if key in out:
            notes.append(f"{role} has duplicate rows for {_label(rec)}; the first is used")
            continue
        out[key] = rec
    return out


def _status(rec: dict) -> str:
    s = rec.get("status")
    return "" if s is None or (isinstance(s, float) and math.isnan(s)) else str(s)


def _is_ok(rec: dict) -> bool:
    return _status(rec).split(":", 1)[0].strip() in OK_STATUSES


def _samples(rec: dict, column: str = TIMING_COLUMN) -> list[float]:
    raw = rec.get(column)
    if isinstance(raw, str):
        try:
            vals = json.loads(raw)
        except json.JSONDecodeError:
            return []
    elif isinstance(raw, (list, tuple, np.ndarray)):
        vals = list(raw)
    else:
        return []
    out = [float(v) for v in vals if v is not None]
    return [v for v in out if math.isfinite(v)]


def _float(rec: dict, column: str) -> float:
    v = rec.get(column)
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


# ---------------------------------------------------------------------------- the checks
def smallest_p(n_base: int, n_cand: int) -> float:
    """Smallest one-sided exact Mann-Whitney p with these sample sizes: 1 / C(n + m, n)."""
    return 1.0 / math.comb(n_base + n_cand, n_base)


def timing_check(base: list[float], cand: list[float], threshold: float, alpha: float) -> dict:
    """Ratio of medians and one-sided Mann-Whitney p-values; 'regression' / 'improvement' / None."""
    from scipy.stats import mannwhitneyu
    mb, mc = float(np.median(base)), float(np.median(cand))
    ratio = mc / mb if mb > 0 else (math.inf if mc > 0 else 1.0)
    p_slower = float(mannwhitneyu(cand, base, alternative="greater").pvalue)
    p_faster = float(mannwhitneyu(cand, base, alternative="less").pvalue)
    reachable = smallest_p(len(base), len(cand)) < alpha
    verdict = None
    if ratio > 1 + threshold and p_slower < alpha:
        verdict = "regression"
    elif ratio < 1 / (1 + threshold) and p_faster < alpha:
        verdict = "improvement"
    return {"median_base": mb, "median_cand": mc, "ratio": ratio, "p_slower": p_slower, "p_faster": p_faster,
            "reachable": reachable, "verdict": verdict}


def _stage_growth(b: dict, c: dict) -> str:
    """The stage whose median time grew most, for a timing finding's note."""
    best = None
    for col in b:
        if not col.startswith("stage_ms.") or col not in c:
            continue
        vb, vc = _float(b, col), _float(c, col)
        if math.isfinite(vb) and math.isfinite(vc) and vb > 0:
            growth = vc - vb
            if best is None or growth > best[0]:
                best = (growth, col.split(".", 1)[1], vb, vc)
    if best is None or best[0] <= 0:
        return ""
    _, stage, vb, vc = best
    return f"largest stage growth: {stage} {vb:.3g} -> {vc:.3g} ms (x{vc / vb:.2f})"


def error_columns(columns) -> list[str]:
    return sorted(c for c in columns if _ERROR_COLUMN.match(str(c)))


def error_check(metric: str, base: float, cand: float, threshold: float) -> str | None:
    floor = ERROR_ABS_FLOOR.get(metric, 0.0)
    if cand - base > floor and (base <= 0 or (cand - base) / base > threshold):
        return "regression"
    if base - cand > floor and base > 0 and (base - cand) / base > threshold:
        return "improvement"
    return None


def compare_runs(baseline: Path, candidate: Path, time_threshold: float = 0.10, error_threshold: float = 0.05,
                 alpha: float = 0.05, compare_changed_versions: bool = False) -> GateResult:
    for name, value in (("time_threshold", time_threshold), ("error_threshold", error_threshold)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    if not (0 < alpha < 1):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    bdf, bman = _load_run(baseline, "baseline")
    cdf, cman = _load_run(candidate, "candidate")
    res = GateResult(Path(baseline), Path(candidate), float(time_threshold), float(error_threshold), float(alpha),
                     baseline_rows=len(bdf), candidate_rows=len(cdf), baseline_info=bman, candidate_info=cman)
    bidx, cidx = _index(bdf, "baseline", res.notes), _index(cdf, "candidate", res.notes)

    bm, cm = bman.get("machine") or {}, cman.get("machine") or {}
    for field_name in ("gl_renderer", "cpu"):
        if bm.get(field_name) and cm.get(field_name) and bm[field_name] != cm[field_name]:
            res.notes.append(f"machines differ ({field_name}: {bm[field_name]!r} vs {cm[field_name]!r}): "
                             f"timing changes may come from the machine")

    common = [k for k in bidx if k in cidx]
    res.missing = [_label(bidx[k]) for k in bidx if k not in cidx and _is_ok(bidx[k])]
    res.new = [_label(cidx[k]) for k in cidx if k not in bidx]
    if not bidx:
        res.error = f"the baseline run {baseline} has no rows"
        return res
    if not common:
        res.error = "no row of the candidate matches a baseline row on (scene, view, method, params, seed)"
        return res

    err_cols = sorted(set(error_columns(bdf.columns)) & set(error_columns(cdf.columns)))
    lost_errors, ref_changed = 0, 0
    untestable: dict = {}  # (n_base, n_cand) -> rows whose timing can never reach alpha
    for key in common:
        b, c = bidx[key], cidx[key]
        label = _label(b)
        if not _is_ok(b):
            res.skipped_baseline.append((label, _status(b) or "no status"))
            continue
        if not _is_ok(c):
            res.regressions.append(Finding(label, "status", _status(b), _status(c) or "no status",
                                           "no longer renders"))
            res.compared += 1
            continue
        note = ""
        bv, cv = b.get("method_version"), c.get("method_version")
        if isinstance(bv, str) and isinstance(cv, str) and bv != cv:
            if not compare_changed_versions:
                res.not_comparable.append((label, f"method version changed ({bv[:8]} -> {cv[:8]})"))
                continue
            note = "method changed"
        bres = (_float(b, "width"), _float(b, "height"))
        cres = (_float(c, "width"), _float(c, "height"))
        if all(map(math.isfinite, bres + cres)) and bres != cres:
            res.not_comparable.append((label, f"resolution changed ({int(bres[0])}x{int(bres[1])} -> "
                                              f"{int(cres[0])}x{int(cres[1])})"))
            continue
        res.compared += 1

        # timing
        sb, sc = _samples(b), _samples(c)
        if sb and sc:
            t = timing_check(sb, sc, time_threshold, alpha)
            if not t["reachable"]:
                untestable[(len(sb), len(sc))] = untestable.get((len(sb), len(sc)), 0) + 1
            growth = _stage_growth(b, c)
            finding = Finding(label, "frame_ms (median)", t["median_base"], t["median_cand"], f"x{t['ratio']:.3f}",
                              t["p_slower"] if t["ratio"] >= 1 else t["p_faster"],
                              "; ".join(x for x in (note, growth) if x))
            if t["verdict"] == "regression":
                res.regressions.append(finding)
            elif t["verdict"] == "improvement":
                res.improvements.append(finding)
            elif t["ratio"] > 1 + time_threshold and not t["reachable"]:
                res.undecidable_timing.append((label, t["ratio"], len(sb), len(sc), smallest_p(len(sb), len(sc))))
        elif sb and not sc:
            res.notes.append(f"{label}: the candidate row has no frame-time samples")

        # error
        for col in err_cols:
            vb, vc = _float(b, col), _float(c, col)
            if not math.isfinite(vb):
                continue
            if not math.isfinite(vc):
                lost_errors += 1
                continue
            verdict = error_check(col.split(".", 1)[0], vb, vc, error_threshold)
            if verdict:
                f = Finding(label, col, vb, vc, _pct(vb, vc), None, note)
                (res.regressions if verdict == "regression" else res.improvements).append(f)
        for col in b:
            if str(col).startswith("reference_key.") and col in c:
                if isinstance(b[col], str) and isinstance(c[col], str) and b[col] != c[col]:
                    ref_changed += 1
                    break

    for (nb, nc), count in sorted(untestable.items()):
        res.notes.append(f"timing of {count} row(s) cannot be judged: with {nb} vs {nc} frames the smallest "
                         f"Mann-Whitney p is {smallest_p(nb, nc):.3g}, not below alpha = {alpha:g} "
                         f"(the gate needs >= 4 timed frames per row for alpha = 0.05)")
    baseline_err = set(error_columns(bdf.columns))
    if baseline_err and not err_cols:
        res.notes.append("the candidate has no error columns (run without references?): errors were not compared")
    elif lost_errors:
        res.notes.append(f"{lost_errors} error value(s) of the baseline are empty in the candidate: not compared")
    if ref_changed:
        res.notes.append(f"{ref_changed} row(s) were judged against different references (reference_key differs)")
    if res.not_comparable and not compare_changed_versions:
        res.notes.append("rows whose method version changed are not compared (edited code is not compared as if "
                         "equal); compare them anyway with compare_changed_versions=True")
    return res
