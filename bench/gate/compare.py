"""The regression gate: `gibench gate BASELINE CANDIDATE` compares two sides row by row.

Each side is one run folder or several (comma-separated on the command line): repetitions of
the same command. Rows are matched on (scene name, view, method, params, seed, resolution); a
row found only at another resolution is listed as not comparable. For each matched row:

* Status: a baseline row that is not ok/cached is skipped (nothing to compare against); a
  candidate row that no longer renders (failed or skipped) where the baseline rendered is a
  regression.
* Comparability: a different `method_version` (hash of the method's sources, shaders and the
  shared GL core), a different resolution, or different scene *content* (`scene_hash`: an
  edited scene file keeps its name) makes the row *not comparable*: it is listed with the
  reason, it is not a failure (asv's rule: results of edited code are never compared as if
  equal). Pass `compare_changed_versions=True` to compare rows whose method changed anyway
  (each finding is then marked "method changed"): that is the mode to gate a change *to* a
  method. Different frames, warm-up or stage clock make the row's *timing* not comparable.
* Timing, on repetitions: the unit of evidence is a run, not a frame. The K frames of one
  process share that run's load (a run slowed by background load separates completely from
  another at p ~ 0.004 on 5 vs 5 frames), so each run contributes one number per row: the
  median of its frame times, or, with `relative_to=METHOD`, that median divided by the
  median of METHOD's row on the same scene/view in the same run (load slows every method of
  a run alike). Only rows *rendered* in a run count (a cached row repeats old numbers). With
  at least `min_runs` (3) runs per side, a one-sided Welch t-test on the logarithms of those
  numbers gives a p-value per row; the p-values of all rows are adjusted for multiple testing
  (`correction`: "holm", family-wise error <= alpha, the default; or "bh", Benjamini-Hochberg
  false-discovery rate, `scipy.stats.false_discovery_control`). A regression needs the ratio of
  geometric means above 1 + time_threshold AND an adjusted p below alpha. Fewer runs: the row's
  timing is listed as not tested, never as a pass or fail. Interleave the runs of the two
  sides (A B A B A B) so that slow periods of the machine fall on both.
* Error: every `<metric>.<component>` column of bench.analysis.metrics.METRICS present in both runs,
  judged only when both rows were scored against the same references (same `reference_key`
  and `reference_spp` of every reference the component uses; otherwise the component is not
  comparable: refinement depends on which methods ran). MSE is compared after subtracting the
  references' noise floor (E[(x - r)^2] = (x - mu)^2 + Var r), clamped at 0. A regression when
  candidate > baseline * (1 + error_threshold) and candidate - baseline exceeds the metric's
  absolute floor (ERROR_ABS_FLOOR, so 0 vs 1e-12 is not a regression).
* Rows of the baseline missing from the candidate, and new rows, are listed, not failures (a
  candidate may run a subset).

Exit code: 0 pass, 1 at least one regression, 2 bad input or nothing compared (missing run
folder, no common row, every common row not comparable).
"""
from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.analysis.metrics import METRICS
from bench.protocol.results import load_results

OK_STATUSES = ("ok", "cached")
RENDERED_STATUSES = ("ok",)   # rows whose timing was measured in that run (not copied from the cache)
TIMING_COLUMN = "samples.frame_ms"
MIN_RUNS = 3
CORRECTIONS = ("holm", "bh")
# which references an error column's component was judged against (bench.analysis.evaluation.COMPARISONS)
REFERENCE_PARTS = {"direct": ("direct",), "indirect": ("indirect_unshadowed",),
                   "indirect_visible": ("indirect_visible",), "combined": ("direct", "indirect_visible")}
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
    correction: str = "holm"
    min_runs: int = MIN_RUNS
    relative_to: str | None = None
    baseline_runs: int = 1
    candidate_runs: int = 1
    compared: int = 0
    timing_tested: int = 0
    baseline_rows: int = 0
    candidate_rows: int = 0
    regressions: list = field(default_factory=list)
    improvements: list = field(default_factory=list)
    not_comparable: list = field(default_factory=list)   # (row, reason)
    missing: list = field(default_factory=list)          # rows of the baseline absent from the candidate
    new: list = field(default_factory=list)              # rows of the candidate absent from the baseline
    skipped_baseline: list = field(default_factory=list)  # (row, status) baseline rows not ok
    undecidable_timing: list = field(default_factory=list)  # (row, ratio, runs base, runs cand, reason)
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
            extra.append(f"timing of {len(self.undecidable_timing)} row(s) not tested")
        tail = f" ({', '.join(extra)})" if extra else ""
        if self.compared == 0:
            return f"**Verdict: PASS, but nothing was compared**{tail}"
        timed = f" (timing of {self.timing_tested} tested)" if self.timing_tested else ""
        return f"**Verdict: PASS** — {self.compared} row(s) compared{timed}, no regression{tail}"

    def markdown(self) -> str:
        head = "FAIL" if self.exit_code == 1 else ("ERROR" if self.exit_code == 2 else "PASS")
        lines = [f"## gibench gate: {head}", ""]
        lines.append(f"- baseline: `{self.baseline_dir}` ({_describe(self.baseline_info, self.baseline_rows)})")
        lines.append(f"- candidate: `{self.candidate_dir}` ({_describe(self.candidate_info, self.candidate_rows)})")
        what = (f"per-run median frame time relative to `{self.relative_to}` in the same run" if self.relative_to
                else "per-run median frame time")
        lines.append(f"- timing ({self.baseline_runs} vs {self.candidate_runs} run(s); {what}): regression when the "
                     f"ratio of geometric means > {1 + self.time_threshold:.3g} (+{self.time_threshold * 100:.3g}%) "
                     f"and the one-sided Welch t-test on log times, {_CORRECTION_NAMES[self.correction]}-adjusted "
                     f"over rows, gives p < {self.alpha:g}; needs >= {self.min_runs} rendered runs per side")
        lines.append(f"- error: regression when a metric is worse by > {self.error_threshold * 100:.3g}% relative "
                     f"(and above its absolute floor); MSE minus the references' noise floor; only against "
                     f"identical references (key and spp)")
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
            lines.append(f"### Timing not tested ({len(self.undecidable_timing)})")
            lines += _table(["row", "ratio", "rendered runs (baseline/candidate)", "reason"],
                            [[r, f"x{ratio:.3f}" if math.isfinite(ratio) else "–", f"{nb}/{nc}", why]
                             for r, ratio, nb, nc, why in self.undecidable_timing[:MAX_TABLE_ROWS]])
            if len(self.undecidable_timing) > MAX_TABLE_ROWS:
                lines.append(f"... and {len(self.undecidable_timing) - MAX_TABLE_ROWS} more")
            lines.append(f"Timing is gated on repetitions: give each side >= {self.min_runs} run folders "
                         f"(`gibench gate A1,A2,A3 B1,B2,B3`, runs interleaved in time, rendered with --force or "
                         f"without a shared row cache).")
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
_CORRECTION_NAMES = {"holm": "Holm", "bh": "Benjamini-Hochberg"}


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
            manifest = json.loads(mpath.read_bytes())
        except ValueError:
            raise ValueError(f"{role} manifest {mpath} is not valid JSON") from None
        if not isinstance(manifest, dict):
            raise ValueError(f"{role} manifest {mpath} is not a JSON object")
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
    """(scene, view, method, params, seed, width, height): a run folder may hold several resolutions."""
    return (str(rec["scene"]), str(rec["view"]), str(rec["method"]), _canonical_params(rec["params"]),
            _seed(rec["seed"]), _seed(rec.get("width")), _seed(rec.get("height")))


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
def adjust_p_values(p_values, method: str = "holm") -> np.ndarray:
    """p-values adjusted over a family of tests: Holm's step-down (family-wise error) or
    Benjamini-Hochberg (false-discovery rate, scipy.stats.false_discovery_control)."""
    p = np.asarray(p_values, dtype=np.float64)
    if p.size == 0:
        return p
    if method == "bh":
        from scipy.stats import false_discovery_control
        return np.asarray(false_discovery_control(p, method="bh"), dtype=np.float64)
    if method != "holm":
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {method!r}")
    order = np.argsort(p, kind="stable")
    m = p.size
    stepped = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out = np.empty(m)
    out[order] = np.minimum(stepped, 1.0)
    return out


def timing_check(base: list[float], cand: list[float], threshold: float, alpha: float) -> dict:
    """One row's per-run times (one number per run and side): ratio of geometric means and
    one-sided Welch t-test p-values on their logarithms (unadjusted); verdict at `alpha`."""
    from scipy.stats import ttest_ind
    lb, lc = np.log(np.asarray(base, np.float64)), np.log(np.asarray(cand, np.float64))
    ratio = float(np.exp(lc.mean() - lb.mean()))
    if len(lb) < 2 or len(lc) < 2:
        p_slower = p_faster = 1.0
    else:
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")  # identical runs: scipy warns about precision loss
            p_slower = float(ttest_ind(lc, lb, equal_var=False, alternative="greater").pvalue)
            p_faster = float(ttest_ind(lc, lb, equal_var=False, alternative="less").pvalue)
        if not math.isfinite(p_slower) or not math.isfinite(p_faster):  # zero spread on both sides
            same = np.isclose(lc.mean(), lb.mean(), rtol=0, atol=1e-12)
            p_slower = 1.0 if same or ratio < 1 else 0.0
            p_faster = 1.0 if same or ratio > 1 else 0.0
    verdict = None
    if ratio > 1 + threshold and p_slower < alpha:
        verdict = "regression"
    elif ratio < 1 / (1 + threshold) and p_faster < alpha:
        verdict = "improvement"
    return {"base": [float(v) for v in base], "cand": [float(v) for v in cand], "ratio": ratio,
            "p_slower": p_slower, "p_faster": p_faster, "verdict": verdict}


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


def _text(rec: dict, column: str) -> str | None:
    """A cell as text; numbers in one form (64, 64.0 and "64" are "64"); None when empty."""
    v = rec.get(column)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        f = float(v)
        return str(int(f)) if f.is_integer() else repr(f)
    return str(v)


def _reference_difference(b: dict, c: dict, component: str) -> str | None:
    """Why a component's errors were judged against different references, or None."""
    for part in REFERENCE_PARTS.get(component, ()):
        for col, what in ((f"reference_key.{part}", "key"), (f"reference_spp.{part}", "spp")):
            vb, vc = _text(b, col), _text(c, col)
            if vb is None and vc is None:
                continue
            if vb != vc:
                short = lambda v: "none" if v is None else (v[:8] if what == "key" else v)
                return f"reference {part} {what} {short(vb)} -> {short(vc)}"
    return None


def _noise_floor(rec: dict, component: str) -> float:
    total = 0.0
    for part in REFERENCE_PARTS.get(component, ()):
        v = _float(rec, f"reference_noise_floor.{part}")
        if not math.isfinite(v):
            return 0.0
        total += v
    return total


def _timing_mismatch(b: dict, c: dict) -> str | None:
    for col in ("frames", "warmup", "stage_clock"):
        vb, vc = _text(b, col), _text(c, col)
        if vb is not None and vc is not None and vb != vc:
            return f"{col} {vb} -> {vc}"
    return None


def _run_median(rec: dict) -> float:
    samples = _samples(rec)
    if samples:
        return float(np.median(samples))
    return _float(rec, "frame_ms")


def _per_run_times(side: list, key: tuple, primary: dict, relative_to: str | None) -> list[float]:
    """One number per run of a side in which the row was rendered (not cached) and matches the
    primary run's row (method version, scene content, resolution, frames, warm-up, clock)."""
    out = []
    for idx, _ in side:
        rec = idx.get(key)
        if rec is None or _status(rec).split(":", 1)[0].strip() not in RENDERED_STATUSES:
            continue
        if any(_text(rec, col) != _text(primary, col) for col in
               ("method_version", "scene_hash", "width", "height", "frames", "warmup", "stage_clock")):
            continue
        t = _run_median(rec)
        if relative_to is not None:
            ref = idx.get((key[0], key[1], relative_to, None) + tuple(key[4:]))
            t = t / _run_median(ref) if ref is not None else math.nan
        if math.isfinite(t) and t > 0:
            out.append(t)
    return out


def _method_index(idx: dict) -> dict:
    """(scene, view, method, None, seed, width, height) -> first row of that method rendered in this
    run (the relative_to lookup: a cached yardstick would repeat another run's timing)."""
    out = {}
    for key, rec in idx.items():
        short = (key[0], key[1], key[2], None) + tuple(key[4:])
        if short not in out and _status(rec).split(":", 1)[0].strip() in RENDERED_STATUSES:
            out[short] = rec
    return out


def _as_paths(value) -> list[Path]:
    if isinstance(value, (str, Path)):
        parts = [p for p in str(value).split(",") if p.strip()] if isinstance(value, str) else [value]
        return [Path(p.strip()) if isinstance(p, str) else Path(p) for p in parts]
    return [Path(v) for v in value]


def compare_runs(baseline, candidate, time_threshold: float = 0.10, error_threshold: float = 0.05,
                 alpha: float = 0.05, compare_changed_versions: bool = False, relative_to: str | None = None,
                 correction: str = "holm", min_runs: int = MIN_RUNS) -> GateResult:
    """Compare two sides, each a run folder or a list of run folders (repetitions)."""
    for name, value in (("time_threshold", time_threshold), ("error_threshold", error_threshold)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    if not (0 < alpha < 1):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    if correction not in CORRECTIONS:
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {correction!r}")
    if not (isinstance(min_runs, int) and min_runs >= 2):
        raise ValueError(f"min_runs must be an integer >= 2 (a spread needs two runs), got {min_runs!r}")
    bpaths, cpaths = _as_paths(baseline), _as_paths(candidate)
    if not bpaths or not cpaths:
        raise ValueError("each side of the gate needs at least one run folder")
    bruns = [_load_run(p, "baseline") for p in bpaths]
    cruns = [_load_run(p, "candidate") for p in cpaths]
    (bdf, bman), (cdf, cman) = bruns[0], cruns[0]
    res = GateResult(bpaths[0] if len(bpaths) == 1 else Path(",".join(map(str, bpaths))),
                     cpaths[0] if len(cpaths) == 1 else Path(",".join(map(str, cpaths))),
                     float(time_threshold), float(error_threshold), float(alpha), correction=correction,
                     min_runs=min_runs, relative_to=relative_to, baseline_runs=len(bpaths),
                     candidate_runs=len(cpaths), baseline_rows=len(bdf), candidate_rows=len(cdf),
                     baseline_info=bman, candidate_info=cman)
    bside = [(_index(df, f"baseline {p}", res.notes), m) for p, (df, m) in zip(bpaths, bruns)]
    cside = [(_index(df, f"candidate {p}", res.notes), m) for p, (df, m) in zip(cpaths, cruns)]
    if relative_to is not None:
        bside = [({**idx, **_method_index(idx)}, m) for idx, m in bside]
        cside = [({**idx, **_method_index(idx)}, m) for idx, m in cside]
        if not any(k[2] == relative_to and k[3] is not None for idx, _ in bside for k in idx):
            raise ValueError(f"--relative-to {relative_to}: the baseline has no row of method '{relative_to}'")
    bidx, cidx = (_strip(bside[0][0]), _strip(cside[0][0]))

    machines = [m.get("machine") or {} for _, m in bside + cside]
    for field_name in ("gl_renderer", "cpu"):
        values = {str(m[field_name]) for m in machines if m.get(field_name)}
        if len(values) > 1:
            res.notes.append(f"machines differ ({field_name}: {', '.join(repr(v) for v in sorted(values))}): "
                             f"timing changes may come from the machine")

    common = [k for k in bidx if k in cidx]
    reasons: dict = {}  # why rows were not comparable, for the notes
    # a row measured at another resolution is the same row, not comparable (not missing + new)
    other_res: dict = {}
    for k in cidx:
        if k not in bidx:
            other_res.setdefault(k[:5], k)
    paired_b, paired_c = set(), set()
    for k in bidx:
        ck = other_res.get(k[:5])
        if k in cidx or ck is None or ck in paired_c or not _is_ok(bidx[k]):
            continue
        paired_b.add(k)
        paired_c.add(ck)
        res.not_comparable.append((_label(bidx[k]), f"resolution changed ({k[5]}x{k[6]} -> {ck[5]}x{ck[6]})"))
        reasons["resolution changed"] = reasons.get("resolution changed", 0) + 1
    res.missing = [_label(bidx[k]) for k in bidx if k not in cidx and k not in paired_b and _is_ok(bidx[k])]
    res.new = [_label(cidx[k]) for k in cidx if k not in bidx and k not in paired_c]
    if not bidx:
        res.error = f"the baseline run {bpaths[0]} has no rows"
        return res
    if not common and not reasons:
        res.error = "no row of the candidate matches a baseline row on (scene, view, method, params, seed)"
        return res

    err_cols = sorted(set(error_columns(bdf.columns)) & set(error_columns(cdf.columns)))
    lost_errors, ref_differs = 0, 0
    timing: list = []   # (label, result of timing_check, note, base row, cand row)
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
                reasons["method version changed"] = reasons.get("method version changed", 0) + 1
                continue
            note = "method changed"
        bh, ch = _text(b, "scene_hash"), _text(c, "scene_hash")
        if bh is not None and ch is not None and bh != ch:
            res.not_comparable.append((label, f"scene content changed ({bh[:8]} -> {ch[:8]})"))
            reasons["scene content changed"] = reasons.get("scene content changed", 0) + 1
            continue
        bres = (_float(b, "width"), _float(b, "height"))
        cres = (_float(c, "width"), _float(c, "height"))
        if all(map(math.isfinite, bres + cres)) and bres != cres:
            res.not_comparable.append((label, f"resolution changed ({int(bres[0])}x{int(bres[1])} -> "
                                              f"{int(cres[0])}x{int(cres[1])})"))
            reasons["resolution changed"] = reasons.get("resolution changed", 0) + 1
            continue
        res.compared += 1

        # timing: one number per rendered run and side
        mismatch = _timing_mismatch(b, c)
        if relative_to is not None and key[2] == relative_to:
            pass  # the yardstick itself: its relative time is 1 by definition
        elif mismatch:
            res.not_comparable.append((label, f"timing not comparable ({mismatch})"))
        else:
            tb = _per_run_times(bside, key, b, relative_to)
            tc = _per_run_times(cside, key, c, relative_to)
            if len(tb) >= min_runs and len(tc) >= min_runs:
                timing.append((label, timing_check(tb, tc, time_threshold, alpha), note, b, c))
            elif tb and tc:
                ratio = float(np.exp(np.mean(np.log(tc)) - np.mean(np.log(tb))))
                res.undecidable_timing.append((label, ratio, len(tb), len(tc), f"fewer than {min_runs} rendered runs"))
            else:
                why = (f"no rendered run with a '{relative_to}' row" if relative_to is not None
                       else "no rendered run (cached rows repeat old timings)")
                res.undecidable_timing.append((label, math.nan, len(tb), len(tc), why))

        # error: only against the same references; MSE net of the references' noise floor
        skipped_components: dict = {}
        for col in err_cols:
            metric, component = col.split(".", 1)
            vb, vc = _float(b, col), _float(c, col)
            if not math.isfinite(vb):
                continue
            if not math.isfinite(vc):
                lost_errors += 1
                continue
            if component not in skipped_components:
                skipped_components[component] = _reference_difference(b, c, component)
            if skipped_components[component] is not None:
                continue
            col_note = note
            if metric == "mse":
                fb, fc = _noise_floor(b, component), _noise_floor(c, component)
                if fb or fc:
                    vb, vc = max(vb - fb, 0.0), max(vc - fc, 0.0)
                    col_note = "; ".join(x for x in (note, "MSE minus the reference noise floor") if x)
            verdict = error_check(metric, vb, vc, error_threshold)
            if verdict:
                f = Finding(label, col, vb, vc, _pct(vb, vc), None, col_note)
                (res.regressions if verdict == "regression" else res.improvements).append(f)
        differing = {comp: why for comp, why in skipped_components.items() if why}
        if differing:
            ref_differs += 1
            res.not_comparable.append((label, "errors of " + ", ".join(f"{comp} ({why})" for comp, why in
                                                                     sorted(differing.items())) + " not comparable"))

    # timing verdicts, adjusted over every tested row
    if timing:
        res.timing_tested = len(timing)
        slower = adjust_p_values([t["p_slower"] for _, t, _, _, _ in timing], correction)
        faster = adjust_p_values([t["p_faster"] for _, t, _, _, _ in timing], correction)
        for (label, t, note, b, c), ps, pf in zip(timing, slower, faster):
            ratio = t["ratio"]
            mb, mc = float(np.exp(np.mean(np.log(t["base"])))), float(np.exp(np.mean(np.log(t["cand"]))))
            extra = f"{len(t['base'])} vs {len(t['cand'])} runs"
            finding = Finding(label, "frame_ms (relative)" if relative_to else "frame_ms (median)", mb, mc,
                              f"x{ratio:.3f}", float(ps if ratio >= 1 else pf),
                              "; ".join(x for x in (note, extra, _stage_growth(b, c)) if x))
            if ratio > 1 + time_threshold and ps < alpha:
                res.regressions.append(finding)
            elif ratio < 1 / (1 + time_threshold) and pf < alpha:
                res.improvements.append(finding)

    if res.compared == 0:
        why = ", ".join(f"{n} {r}" for r, n in sorted(reasons.items())) or "every baseline row was skipped"
        res.error = f"nothing was compared: {len(common) + len(paired_b)} matched row(s), none comparable ({why})"
    baseline_err = set(error_columns(bdf.columns))
    if baseline_err and not err_cols:
        res.notes.append("the candidate has no error columns (run without references?): errors were not compared")
    elif lost_errors:
        res.notes.append(f"{lost_errors} error value(s) of the baseline are empty in the candidate: not compared")
    if ref_differs:
        res.notes.append(f"errors of {ref_differs} row(s) were not compared: the references differ (key or spp; "
                         f"refinement depends on which methods ran). Re-run both sides with the same methods.")
    if res.undecidable_timing and min(len(bpaths), len(cpaths)) < min_runs:
        res.notes.append(f"timing is gated on >= {min_runs} runs per side; this gate had {len(bpaths)} vs "
                         f"{len(cpaths)}: timing was not tested")
    if reasons.get("method version changed") and not compare_changed_versions:
        res.notes.append("rows whose method version changed are not compared (edited code is not compared as if "
                         "equal); compare them anyway with compare_changed_versions=True")
    return res


def _strip(idx: dict) -> dict:
    """An index without the relative_to lookup entries (params None)."""
    return {k: v for k, v in idx.items() if k[3] is not None}
