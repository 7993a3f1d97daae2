"""The gate's comparison: matching the rows of two sides, deciding which are comparable, and the
findings (status, timing, error) of those that are (rules: bench.gate)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.gate.load import (cell_float, cell_text, check_distinct_runs, index_rows, load_run, method_index,
                             row_label, side_paths, status_text, without_method_index)
from bench.gate.presentation import percent_change, report_markdown, verdict_line
from bench.gate.statistics import (CORRECTIONS, MIN_RUNS, REFERENCE_FREE_METRICS, adjust_p_values, check_error_column,
                                   error_check, error_columns, noise_floor, per_run_times, timing_check)
from bench.protocol.results import run_progress
from bench.protocol.vocabulary import DECOMPOSITION_METRICS, REFERENCE_PARTS, Status, interval_column

ERROR_FRAMES = "extra.error_frames"   # how many frames a row's error over frames was measured on


@dataclass
class Finding:
    """One change the gate found in a row: a regression or an improvement."""
    row: str              # scene/view/method label (seed)
    check: str            # "frame_ms", "status" or an error column
    baseline: object
    candidate: object
    change: str           # "+12.3%" / "x1.50" / "ok -> failed"
    p_value: float | None = None
    note: str = ""


@dataclass
class GateResult:
    """What `compare_runs` found; `markdown()` is the report, `exit_code` the command's exit code."""
    baseline_dir: Path
    candidate_dir: Path
    time_threshold: float
    error_threshold: float
    alpha: float
    correction: str = "holm"
    min_runs: int = MIN_RUNS
    relative_to: str | None = None
    metrics: tuple = ()   # the error columns compared (--metric); () = every error column of both sides
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
    incomplete: list = field(default_factory=list)       # "baseline runs/x: incomplete: 5 of 20 rows (...)"
    unchecked: list = field(default_factory=list)        # checks that could not be made ("method versions of 2 rows")
    error: str | None = None
    baseline_info: dict = field(default_factory=dict)
    candidate_info: dict = field(default_factory=dict)

    @property
    def exit_code(self) -> int:
        if self.error:
            return 2
        return 1 if self.regressions else 0

    def verdict(self) -> str:
        return verdict_line(self)

    def markdown(self) -> str:
        return report_markdown(self)


def compare_runs(baseline, candidate, time_threshold: float = 0.10, error_threshold: float = 0.05,
                 alpha: float = 0.05, compare_changed_versions: bool = False, relative_to: str | None = None,
                 correction: str = "holm", min_runs: int = MIN_RUNS, allow_incomplete: bool = False,
                 metrics=None) -> GateResult:
    """Compare two sides, each a run folder or a list of run folders (repetitions). A run that did
    not finish (bench.protocol.results.run_progress) is bad input unless `allow_incomplete`, and
    then named in the verdict; one run listed twice on a side is bad input. `metrics`: the error
    columns to compare (any `<metric>.<component>` of error_metric_names(); an unknown one is bad
    input, one a side lacks is an error of the gate); None compares every error column both have."""
    for name, value in (("time_threshold", time_threshold), ("error_threshold", error_threshold)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    if not (0 < alpha < 1):
        raise ValueError(f"alpha must be in (0, 1), got {alpha!r}")
    if correction not in CORRECTIONS:
        raise ValueError(f"correction must be one of {', '.join(CORRECTIONS)}, got {correction!r}")
    if not (isinstance(min_runs, int) and min_runs >= 2):
        raise ValueError(f"min_runs must be an integer >= 2 (a spread needs two runs), got {min_runs!r}")
    metrics = tuple(dict.fromkeys(check_error_column(m) for m in ([metrics] if isinstance(metrics, str)
                                                                   else metrics or ())))
    bpaths, cpaths = side_paths(baseline), side_paths(candidate)
    if not bpaths or not cpaths:
        raise ValueError("each side of the gate needs at least one run folder")
    bruns = [load_run(p, "baseline") for p in bpaths]
    cruns = [load_run(p, "candidate") for p in cpaths]
    incomplete = []
    for role, paths, runs in (("baseline", bpaths, bruns), ("candidate", cpaths, cruns)):
        check_distinct_runs(role, paths, runs)
        for path in paths:
            progress = run_progress(path)
            if progress.complete:
                continue
            if not allow_incomplete:
                raise ValueError(f"{role} run {path} is {progress.describe()}; gate finished runs, or pass "
                                 f"--allow-incomplete to compare the rows it has")
            incomplete.append(f"{role} {path}: {progress.describe()}")
    (bdf, bman), (cdf, cman) = bruns[0], cruns[0]
    res = GateResult(bpaths[0] if len(bpaths) == 1 else Path(",".join(map(str, bpaths))),
                     cpaths[0] if len(cpaths) == 1 else Path(",".join(map(str, cpaths))),
                     float(time_threshold), float(error_threshold), float(alpha), correction=correction,
                     min_runs=min_runs, relative_to=relative_to, metrics=metrics, baseline_runs=len(bpaths),
                     candidate_runs=len(cpaths), baseline_rows=len(bdf), candidate_rows=len(cdf),
                     baseline_info=bman, candidate_info=cman, incomplete=incomplete)
    bside = [(index_rows(df, f"baseline {p}", res.notes), m) for p, (df, m) in zip(bpaths, bruns)]
    cside = [(index_rows(df, f"candidate {p}", res.notes), m) for p, (df, m) in zip(cpaths, cruns)]
    if relative_to is not None:
        bside = [({**idx, **method_index(idx)}, m) for idx, m in bside]
        cside = [({**idx, **method_index(idx)}, m) for idx, m in cside]
        if not any(k[2] == relative_to and k[3] is not None for idx, _ in bside for k in idx):
            raise ValueError(f"--relative-to {relative_to}: the baseline has no row of method '{relative_to}'")
    bidx, cidx = (without_method_index(bside[0][0]), without_method_index(cside[0][0]))

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
        if k in cidx or ck is None or ck in paired_c or not Status.has_images(bidx[k].get("status")):
            continue
        paired_b.add(k)
        paired_c.add(ck)
        res.not_comparable.append((row_label(bidx[k]), f"resolution changed ({k[5]}x{k[6]} -> {ck[5]}x{ck[6]})"))
        reasons["resolution changed"] = reasons.get("resolution changed", 0) + 1
    res.missing = [row_label(bidx[k]) for k in bidx
                   if k not in cidx and k not in paired_b and Status.has_images(bidx[k].get("status"))]
    res.new = [row_label(cidx[k]) for k in cidx if k not in bidx and k not in paired_c]
    if not bidx:
        res.error = f"the baseline run {bpaths[0]} has no rows"
        return res
    if not common and not reasons:
        res.error = "no row of the candidate matches a baseline row on (scene, view, method, params, seed)"
        return res

    err_cols = sorted(set(error_columns(bdf.columns)) & set(error_columns(cdf.columns)))
    if metrics:
        for role, df, paths in (("baseline", bdf, bpaths), ("candidate", cdf, cpaths)):
            lacking = [m for m in metrics if m not in df.columns]
            if lacking:
                over_frames = any(m.split(".", 1)[0] in DECOMPOSITION_METRICS for m in lacking)
                res.error = (f"the {role} {paths[0]} has no column {', '.join(lacking)} (error columns need references"
                             + (", an error over frames --error-frames >= 2 too)" if over_frames else ")"))
                return res
        err_cols = list(metrics)
    lost_errors, ref_differs, judged = 0, 0, 0
    unchecked = {"method_version": 0, "scene_hash": 0}   # compared rows whose column a side lacks
    timing: list = []   # (label, result of timing_check, note, base row, cand row)
    for key in common:
        b, c = bidx[key], cidx[key]
        label = row_label(b)
        if not Status.has_images(b.get("status")):
            res.skipped_baseline.append((label, status_text(b) or "no status"))
            continue
        if not Status.has_images(c.get("status")):
            res.regressions.append(Finding(label, "status", status_text(b), status_text(c) or "no status",
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
        bh, ch = cell_text(b, "scene_hash"), cell_text(c, "scene_hash")
        unchecked["method_version"] += not (isinstance(bv, str) and isinstance(cv, str))
        unchecked["scene_hash"] += bh is None or ch is None
        if bh is not None and ch is not None and bh != ch:
            res.not_comparable.append((label, f"scene content changed ({bh[:8]} -> {ch[:8]})"))
            reasons["scene content changed"] = reasons.get("scene content changed", 0) + 1
            continue
        bres = (cell_float(b, "width"), cell_float(b, "height"))
        cres = (cell_float(c, "width"), cell_float(c, "height"))
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
            tb = per_run_times(bside, key, b, relative_to)
            tc = per_run_times(cside, key, c, relative_to)
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
        frames_differ, frames_skipped = _error_frames_difference(b, c), False
        for col in err_cols:
            metric, component = col.split(".", 1)
            vb, vc = cell_float(b, col), cell_float(c, col)
            if not math.isfinite(vb):
                continue
            if not math.isfinite(vc):
                lost_errors += 1
                continue
            over_frames = metric in DECOMPOSITION_METRICS
            if over_frames and frames_differ:
                frames_skipped = True
                continue
            if metric not in REFERENCE_FREE_METRICS:
                if component not in skipped_components:
                    skipped_components[component] = _reference_difference(b, c, component)
                if skipped_components[component] is not None:
                    continue
            col_note, spread = note, 0.0
            if metric == "mse":
                fb, fc = noise_floor(b, component), noise_floor(c, component)
                if fb or fc:
                    vb, vc = max(vb - fb, 0.0), max(vc - fc, 0.0)
                    col_note = "; ".join(x for x in (note, "MSE minus the reference noise floor") if x)
            elif over_frames:
                # estimates of quantities >= 0 (bias2 of an unbiased method scatters about 0): compared
                # from 0, and a change within the two values' 95% intervals over pixels is no change
                vb, vc = max(vb, 0.0), max(vc, 0.0)
                cb, cc = (abs(cell_float(r, interval_column(metric, component))) for r in (b, c))
                spread = math.hypot(cb if math.isfinite(cb) else 0.0, cc if math.isfinite(cc) else 0.0)
                col_note = "; ".join(x for x in (note, f"95% interval of the change +-{spread:.3g}" if spread else "")
                                     if x)
            judged += 1
            verdict = error_check(metric, vb, vc, error_threshold, spread)
            if verdict:
                f = Finding(label, col, vb, vc, percent_change(vb, vc), None, col_note)
                (res.regressions if verdict == "regression" else res.improvements).append(f)
        differing = {comp: why for comp, why in skipped_components.items() if why}
        if differing:
            ref_differs += 1
            res.not_comparable.append((label, "errors of " + ", ".join(f"{comp} ({why})" for comp, why in
                                                                     sorted(differing.items())) + " not comparable"))
        if frames_skipped:
            res.not_comparable.append((label, f"errors over frames not comparable ({frames_differ})"))

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

    if metrics and res.compared and not judged and not res.regressions:
        res.error = (f"no compared row has a value of {', '.join(metrics)} on both sides (against the same "
                     f"references and error frames): nothing was judged")
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
    for column, what in (("method_version", "method versions"), ("scene_hash", "scene contents")):
        if unchecked[column]:
            res.unchecked.append(f"{what} of {unchecked[column]} row(s)")
            res.notes.append(f"{what} of {unchecked[column]} compared row(s) could not be checked (a side has no "
                             f"{column}, e.g. a hand-edited table): those rows were compared as if unchanged")
    res.notes += [f"{what} (compared with --allow-incomplete)" for what in res.incomplete]
    if reasons.get("method version changed") and not compare_changed_versions:
        res.notes.append("rows whose method version changed are not compared (edited code is not compared as if "
                         "equal); compare them anyway with compare_changed_versions=True")
    return res


# ---------------------------------------------------------------------------- comparability
def _reference_difference(b: dict, c: dict, component: str) -> str | None:
    """Why a component's errors were judged against different references, or None."""
    for part in REFERENCE_PARTS.get(component, ()):
        for col, what in ((f"reference_key.{part}", "key"), (f"reference_spp.{part}", "spp")):
            vb, vc = cell_text(b, col), cell_text(c, col)
            if vb is None and vc is None:
                continue
            if vb != vc:
                short = lambda v: "none" if v is None else (v[:8] if what == "key" else v)
                return f"reference {part} {what} {short(vb)} -> {short(vc)}"
    return None


def _error_frames_difference(b: dict, c: dict) -> str | None:
    """Why two rows' errors over frames were measured differently (another frame count K: the
    accumulated error is that of a K-frame mean, and a temporal method's spread changes with K), or None."""
    vb, vc = cell_text(b, ERROR_FRAMES), cell_text(c, ERROR_FRAMES)
    if vb is not None and vc is not None and vb != vc:
        return f"error frames {vb} -> {vc}"
    return None


def _timing_mismatch(b: dict, c: dict) -> str | None:
    """Why two rows' times were measured differently (frames, warm-up, stage clock), or None."""
    for col in ("frames", "warmup", "stage_clock"):
        vb, vc = cell_text(b, col), cell_text(c, col)
        if vb is not None and vc is not None and vb != vc:
            return f"{col} {vb} -> {vc}"
    return None


def _stage_growth(b: dict, c: dict) -> str:
    """The stage whose median time grew most, for a timing finding's note."""
    best = None
    for col in b:
        if not col.startswith("stage_ms.") or col not in c:
            continue
        vb, vc = cell_float(b, col), cell_float(c, col)
        if math.isfinite(vb) and math.isfinite(vc) and vb > 0:
            growth = vc - vb
            if best is None or growth > best[0]:
                best = (growth, col.split(".", 1)[1], vb, vc)
    if best is None or best[0] <= 0:
        return ""
    _, stage, vb, vc = best
    return f"largest stage growth: {stage} {vb:.3g} -> {vc:.3g} ms (x{vc / vb:.2f})"
